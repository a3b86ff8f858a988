//! Sites as `.xyz`: `x y z` per line, parsed in parallel.
//!
//! The text is cut just after line ends into pieces of about `PIECE`
//! bytes, parsed at once on rayon's threads, then joined in order. The
//! lines and points before a piece are known only when all pieces are
//! parsed, so a piece that fails (or passes the count line's count) is
//! parsed again knowing them: the first error of the file is reported as
//! the sequential reading would, with its line and point numbers.

use super::lex::{parse_error, Lexer, Line, Tokens};
use super::parts::CountLine;
use cvd::error::{Error, Result};
use rayon::prelude::*;
use std::borrow::Cow;
use std::ops::Range;

/// Bytes of text per piece: a task's overhead is nothing beside parsing a
/// megabyte (about 18 000 lines of full-precision sites), and a 10M-site
/// file makes hundreds of pieces to share among the threads.
const PIECE: usize = 1 << 20;

/// Parses points, `x y z` per line; `#` starts a comment and blank lines
/// are ignored. A first line holding a single number is the count of
/// points, which must then match. Coordinates are read as f64, exactly as
/// written (to the nearest f64); NaN and infinities are refused. Large
/// texts are parsed on all of rayon's threads, with the same results and
/// errors as one thread would give.
pub fn parse_xyz(text: &str, path: &str) -> Result<Vec<[f64; 3]>> {
    parse_pieces(text.as_bytes(), path, PIECE)
}

/// [`parse_xyz`] on a file's bytes, each piece checked as UTF-8 by the
/// thread that parses it: bytes that are not UTF-8 read as U+FFFD, as if
/// the whole file had been converted (pieces are cut after `\n`, which no
/// invalid sequence spans).
pub(super) fn parse_xyz_bytes(bytes: &[u8], path: &str) -> Result<Vec<[f64; 3]>> {
    parse_pieces(bytes, path, PIECE)
}

/// One piece's points, parsed without knowing what came before it.
struct Piece {
    points: Vec<[f64; 3]>,
    /// Whether every line of the piece is a valid point.
    ok: bool,
    /// Line ends in the piece.
    line_ends: usize,
    /// The line of the piece's last point, counted from 1 at its start.
    last: Option<usize>,
}

/// [`parse_xyz`] with pieces of about `piece` bytes (the tests cut small).
fn parse_pieces(bytes: &[u8], path: &str, piece: usize) -> Result<Vec<[f64; 3]>> {
    // The count line: the first line holding a token, when it holds one.
    let (mut start, mut first) = (0, 1);
    let mut count: Option<(usize, usize)> = None;
    while start < bytes.len() {
        let end = line_end(bytes, start);
        let text = text(&bytes[start..end]);
        if let Some(line) = Lexer::at_line(&text, path, first).line() {
            if line.len() == 1 {
                count = Some((line.first().count("a point count or 3 coordinates x y z")?, first));
                (start, first) = (end, first + 1);
            }
            break;
        }
        (start, first) = (end, first + 1);
    }
    let body = &bytes[start..];
    let cuts = cut_after_lines(body, piece);
    let scan = |r: &Range<usize>| {
        let text = text(&body[r.clone()]);
        let mut points = Vec::new();
        match points_of(&text, path, 1, 0, None, &mut points) {
            Ok((last, next)) => Piece { points, ok: true, line_ends: next - 1, last },
            Err(_) => Piece { points, ok: false, line_ends: 0, last: None },
        }
    };
    let pieces: Vec<Piece> =
        if cuts.len() > 1 { cuts.par_iter().map(scan).collect() } else { cuts.iter().map(scan).collect() };
    // The lines and points before each piece, and the first error.
    let mut total = 0;
    let mut last_line = count.map_or(1, |(_, at)| at);
    for (p, r) in pieces.iter().zip(&cuts) {
        if !p.ok || count.is_some_and(|(n, _)| total + p.points.len() > n) {
            let text = text(&body[r.clone()]);
            points_of(&text, path, first, total, count, &mut Vec::new())?;
            return Err(Error::Internal(format!("{path}: line {first}: a piece of the file failed once only")));
        }
        total += p.points.len();
        if let Some(last) = p.last {
            last_line = first + last - 1;
        }
        first += p.line_ends;
    }
    if let Some((n, at)) = count.filter(|&(n, _)| total < n) {
        return Err(parse_error(
            path,
            last_line,
            format!("expected {n} points (the count on line {at}), found {total}"),
        ));
    }
    let mut points = Vec::with_capacity(total);
    for p in pieces {
        points.extend_from_slice(&p.points);
    }
    Ok(points)
}

/// The text of whole lines: bytes that are not UTF-8 become U+FFFD.
fn text(bytes: &[u8]) -> Cow<'_, str> {
    // The check first: `from_utf8_lossy` alone is slower on ASCII.
    std::str::from_utf8(bytes).map_or_else(|_| String::from_utf8_lossy(bytes), Cow::Borrowed)
}

/// The index just after the line end at or after `start`, or the end.
fn line_end(bytes: &[u8], start: usize) -> usize {
    bytes[start..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |p| start + p + 1)
}

/// `bytes` cut into pieces of at least `piece` bytes, each ending just
/// after a line end (the last one at the end of `bytes`).
fn cut_after_lines(bytes: &[u8], piece: usize) -> Vec<Range<usize>> {
    let mut cuts = Vec::with_capacity(bytes.len() / piece.max(1) + 1);
    let mut start = 0;
    while start < bytes.len() {
        let end = line_end(bytes, (start + piece.max(1)).min(bytes.len()) - 1);
        cuts.push(start..end);
        start = end;
    }
    cuts
}

/// Appends to `points` the points of `text`: whole lines of the file after
/// any count line, the first being line `first`, with `before` points
/// earlier in the file; `count` is the count and its line, if given.
/// Returns the line of the last point read and the line after the text.
fn points_of(
    text: &str,
    path: &str,
    first: usize,
    before: usize,
    count: Option<(usize, usize)>,
    points: &mut Vec<[f64; 3]>,
) -> Result<(Option<usize>, usize)> {
    let mut lex = Lexer::at_line(text, path, first);
    let mut last = None;
    let start = points.len();
    while let Some(mut line) = lex.line() {
        let i = before + (points.len() - start) + 1;
        if let Some((n, at)) = count {
            if i > n {
                return Err(line
                    .first()
                    .unexpected(format_args!("the end of the file after {n} points (the count on line {at})")));
            }
        }
        // The line split once: three tokens, then none.
        let (Some(x), Some(y), Some(z), None) = (line.tok(), line.tok(), line.tok(), line.tok()) else {
            let wrong = line.expect_len(3, format_args!("3 coordinates x y z for point {i}")).err();
            return Err(wrong.unwrap_or_else(|| line.error("3 coordinates counted twice, differently")));
        };
        let mut p = [0.0; 3];
        for ((c, tok), axis) in p.iter_mut().zip([x, y, z]).zip(["x", "y", "z"]) {
            *c = tok.f64(format_args!("the {axis} coordinate of point {i}"))?;
        }
        points.push(p);
        last = Some(line.no);
    }
    Ok((last, lex.line_no()))
}

/// The sites of a part of a text sites file (see
/// [`read_sites_part`](super::read_sites_part)): `bytes` being whole lines
/// starting at byte `offset` of the file, parsed as [`parse_xyz`] parses
/// them, except that the part's first line holding a token, if it holds a
/// single one, is returned (as a [`CountLine`]) rather than judged: it
/// is the file's count line only if no earlier part holds a token. Errors
/// name the file and the line's byte offset, in pieces parsed on all of
/// rayon's threads.
pub(super) fn parse_xyz_part(bytes: &[u8], offset: u64, path: &str) -> Result<(Vec<[f64; 3]>, Option<CountLine>)> {
    let mut start = 0;
    let mut count = None;
    while start < bytes.len() {
        let end = line_end(bytes, start);
        let line_bytes = &bytes[start..end];
        let text = text(line_bytes);
        if let Some(line) = Lexer::new(&text, path).line() {
            if line.len() == 1 {
                let n = line.first().count("a point count or 3 coordinates x y z");
                let n = n.map_err(|e| at_byte(e, line_bytes, offset + start as u64, path))?;
                count = Some(CountLine { offset: offset + start as u64, count: n as u64 });
                start = end;
            }
            break;
        }
        start = end;
    }
    let body = &bytes[start..];
    let offset = offset + start as u64;
    let scan = |r: &Range<usize>| {
        let piece = &body[r.clone()];
        let text = text(piece);
        let mut lex = Lexer::new(&text, path);
        let mut points = Vec::new();
        while let Some(mut line) = lex.line() {
            let p = point(&mut line).map_err(|e| at_byte(e, piece, offset + r.start as u64, path))?;
            points.push(p);
        }
        Ok(points)
    };
    let cuts = cut_after_lines(body, PIECE);
    let pieces: Vec<Result<Vec<[f64; 3]>>> =
        if cuts.len() > 1 { cuts.par_iter().map(scan).collect() } else { cuts.iter().map(scan).collect() };
    let mut points = Vec::new();
    for p in pieces {
        let p = p?;
        if points.is_empty() {
            points = p;
        } else {
            points.extend_from_slice(&p);
        }
    }
    Ok((points, count))
}

/// A point: a line of 3 finite coordinates (errors without the point's
/// number, which a part does not know).
fn point(line: &mut Line) -> Result<[f64; 3]> {
    let (Some(x), Some(y), Some(z), None) = (line.tok(), line.tok(), line.tok(), line.tok()) else {
        let wrong = line.expect_len(3, "3 coordinates x y z").err();
        return Err(wrong.unwrap_or_else(|| line.error("3 coordinates counted twice, differently")));
    };
    let mut p = [0.0; 3];
    for ((c, tok), axis) in p.iter_mut().zip([x, y, z]).zip(["x", "y", "z"]) {
        *c = tok.f64(format_args!("the {axis} coordinate"))?;
    }
    Ok(p)
}

/// A parse error of a line of `bytes` (its number counted from 1 at their
/// start, which is byte `offset` of the file) as an error naming the
/// file and the line's byte offset: "PATH: the line at byte B: ...".
fn at_byte(e: Error, bytes: &[u8], offset: u64, path: &str) -> Error {
    match e {
        Error::Parse { line, message, .. } => {
            let start = match line.checked_sub(2) {
                None => 0,
                Some(ends) => {
                    bytes.iter().enumerate().filter(|&(_, &b)| b == b'\n').nth(ends).map_or(0, |(i, _)| i + 1)
                }
            };
            Error::InvalidInput(format!("{path}: the line at byte {}: {message}", offset + start as u64))
        }
        other => other,
    }
}

/// The values of a part of a file of one number per line: `bytes` from
/// byte `offset` of the file, whole lines. Errors name the file and the
/// line's byte offset (a part does not know its lines' numbers).
pub(super) fn parse_values_part(bytes: &[u8], offset: u64, path: &str) -> Result<Vec<f64>> {
    let text = text(bytes);
    let mut lex = Lexer::new(&text, path);
    let mut values = Vec::new();
    while let Some(line) = lex.line() {
        let value = line.expect_len(1, "one number").and_then(|()| line.first().f64("a value"));
        values.push(value.map_err(|e| at_byte(e, bytes, offset, path))?);
    }
    Ok(values)
}

/// Parses one number per line (per-vertex values such as a density); `#`
/// starts a comment and blank lines are ignored.
pub fn parse_values(text: &str, path: &str) -> Result<Vec<f64>> {
    let mut lex = Lexer::new(text, path);
    let mut values = Vec::new();
    while let Some(mut line) = lex.line() {
        let i = values.len() + 1;
        line.expect_len(1, format_args!("one number (value {i})"))?;
        values.push(line.f64(format_args!("value {i}"))?);
    }
    Ok(values)
}

#[cfg(test)]
mod tests {
    use super::super::tests::{no_panic_on_mutations, parse_err};
    use super::*;
    use proptest::prelude::*;
    use std::fmt::Write;

    #[test]
    fn values_one_per_line() {
        assert_eq!(parse_values("# density\n1\n 2.5 \n\n3e-1\n", "d.txt").unwrap(), vec![1.0, 2.5, 0.3]);
        let (line, m) = parse_err(parse_values("1\n2 3\n", "d.txt"));
        assert_eq!(line, 2);
        assert!(m.contains("one number (value 2)"), "{m}");
        let (line, m) = parse_err(parse_values("1\nnan\n", "d.txt"));
        assert_eq!(line, 2);
        assert!(m.contains("value 2 (a finite number)"), "{m}");
    }

    #[test]
    fn valid_with_and_without_count() {
        let points = vec![[0.5, -1.0, 2.0], [1e-3, 0.0, 3.25]];
        assert_eq!(parse_xyz("0.5 -1 2\n\n# comment\n1e-3 0 3.25 # trailing\n", "s.xyz").unwrap(), points);
        assert_eq!(parse_xyz("# sites\n2\n0.5 -1 2\r\n1e-3 0 3.25\r\n", "s.xyz").unwrap(), points);
        assert!(parse_xyz("0\n", "s.xyz").unwrap().is_empty());
        assert!(parse_xyz("", "s.xyz").unwrap().is_empty());
    }

    #[test]
    fn count_mismatch() {
        let (line, m) = parse_err(parse_xyz("3\n0 0 0\n1 1 1\n", "c.xyz"));
        assert_eq!((line, m.as_str()), (3, "expected 3 points (the count on line 1), found 2"));
        let (line, m) = parse_err(parse_xyz("1\n0 0 0\n1 1 1\n", "c.xyz"));
        assert_eq!(
            (line, m.as_str()),
            (3, "expected the end of the file after 1 points (the count on line 1), found \"1\"")
        );
        let (line, m) = parse_err(parse_xyz("1000000000000\n0 0 0\n", "c.xyz"));
        assert_eq!((line, m.as_str()), (2, "expected 1000000000000 points (the count on line 1), found 1"));
    }

    #[test]
    fn bad_lines() {
        let (line, m) = parse_err(parse_xyz("0 0 0\n1 1\n", "b.xyz"));
        assert_eq!((line, m.as_str()), (2, "expected 3 coordinates x y z for point 2, found 2 values"));
        let (line, m) = parse_err(parse_xyz("0 0 0\n1 NaN 1\n", "b.xyz"));
        assert_eq!((line, m.as_str()), (2, "expected the y coordinate of point 2 (a finite number), found \"NaN\""));
        let (line, m) = parse_err(parse_xyz("0.5\n1 1 1\n", "b.xyz"));
        assert_eq!(
            (line, m.as_str()),
            (1, "expected a point count or 3 coordinates x y z (a non-negative integer), found \"0.5\"")
        );
        let (line, m) = parse_err(parse_xyz("0 0 0\n7\n", "b.xyz"));
        assert_eq!((line, m.as_str()), (2, "expected 3 coordinates x y z for point 2, found 1 value"));
    }

    #[test]
    fn no_input_panics() {
        no_panic_on_mutations("# c\n2\n0.5 -1 2\n1e-3 0 3.25\n", |t| parse_xyz(t, "f.xyz"));
    }

    /// The reading of `.xyz` before pieces (one pass over the whole text):
    /// what the pieces must give, values and errors alike.
    fn sequential_xyz(text: &str, path: &str) -> Result<Vec<[f64; 3]>> {
        let mut lex = Lexer::new(text, path);
        let mut points = Vec::new();
        let mut count: Option<(usize, usize)> = None;
        while let Some(mut line) = lex.line() {
            if points.is_empty() && count.is_none() && line.len() == 1 {
                let n = line.first().count("a point count or 3 coordinates x y z")?;
                points.reserve(lex.capacity(n, 3));
                count = Some((n, line.no));
                continue;
            }
            let i = points.len() + 1;
            if let Some((n, at)) = count {
                if i > n {
                    return Err(line
                        .first()
                        .unexpected(format_args!("the end of the file after {n} points (the count on line {at})")));
                }
            }
            line.expect_len(3, format_args!("3 coordinates x y z for point {i}"))?;
            let mut p = [0.0; 3];
            for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
                *c = line.f64(format_args!("the {axis} coordinate of point {i}"))?;
            }
            points.push(p);
        }
        match count {
            Some((n, at)) if points.len() < n => Err(lex.error(
                lex.last_line(),
                format!("expected {n} points (the count on line {at}), found {}", points.len()),
            )),
            _ => Ok(points),
        }
    }

    /// A result to compare: the points' bits, or the error's text.
    fn outcome(r: Result<Vec<[f64; 3]>>) -> std::result::Result<Vec<[u64; 3]>, String> {
        r.map(|points| points.iter().map(|p| p.map(f64::to_bits)).collect()).map_err(|e| e.to_string())
    }

    /// Pieces of every size from 1 byte (a piece a line) to the default
    /// give what one pass gives.
    fn check_pieces(bytes: &[u8]) {
        let expected = outcome(sequential_xyz(&String::from_utf8_lossy(bytes), "p.xyz"));
        for piece in [1, 2, 3, 5, 8, 13, 21, 34, 55, 89, 4096, PIECE] {
            assert_eq!(outcome(parse_pieces(bytes, "p.xyz", piece)), expected, "pieces of {piece} bytes");
        }
        if let Ok(text) = std::str::from_utf8(bytes) {
            assert_eq!(outcome(parse_xyz(text, "p.xyz")), expected);
        }
    }

    /// One line of a site file: mostly points, written in several ways.
    fn line() -> impl Strategy<Value = String> {
        let coordinate = prop_oneof![
            any::<f64>().prop_filter("finite", |x| x.is_finite()).prop_map(|x| x.to_string()),
            (-1e6f64..1e6).prop_map(|x| format!("{x:e}")),
            "-?[0-9]{1,3}\\.[0-9]{15,30}",
            "[0-9]{1,25}",
        ];
        let point = [coordinate.clone(), coordinate.clone(), coordinate].prop_map(|[x, y, z]| format!("{x} {y} {z}"));
        prop_oneof![
            20 => point.clone().prop_map(|p| p + "\n"),
            3 => point.clone().prop_map(|p| format!("  {p}\t# here\r\n")),
            2 => prop::sample::select(vec!["\n", "   \n", "\r\n", "# comment 1 2 3\n", "#\n"]).prop_map(String::from),
            1 => prop::sample::select(vec![
                "1 2\n", "1 nan 2\n", "x 0 0\n", "0 0 0 0\n", "1e400 0 0\n", "5\n", "0 inf 1\n", "\u{fffd} 1 1\n",
            ])
            .prop_map(String::from),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

        /// Random files, with or without a count line (right, one short,
        /// one over) and a last line end, give the same points, bit for
        /// bit, or the same first error as one pass.
        #[test]
        fn pieces_parse_as_one_pass(
            lines in prop::collection::vec(line(), 0..60),
            head in prop::sample::select(vec!["", "# sites\n", "\n\n"]),
            count in prop::option::of(-1i64..=1),
            last_end in any::<bool>(),
        ) {
            let mut text = head.to_string();
            if let Some(delta) = count {
                let points = lines.iter().filter(|l| l.split('#').next().unwrap().split_ascii_whitespace().count() > 1);
                writeln!(text, "{}", (points.count() as i64 + delta).max(0)).unwrap();
            }
            text.extend(lines);
            if !last_end && text.ends_with('\n') {
                text.pop();
            }
            check_pieces(text.as_bytes());
        }
    }

    #[test]
    fn pieces_of_files_that_are_not_utf8_read_as_one_pass() {
        let texts: [&[u8]; 6] = [
            b"# caf\xe9\n2\n0 0 0 # \xff\xfe\n1 1 1\n",
            b"0 0 0\n1 \xe2\x82 1\n",
            b"\xe2\n0 0 0\n",
            b"\xf0\x9f\x98\n\xf0\x9f\x98\x80 0 0\n",
            b"3\n0 0 0\n\x80\n",
            b"# \xe2\x82\xac fine\n0.5 0.25 \xc3\xa9\n",
        ];
        for bytes in texts {
            check_pieces(bytes);
        }
    }

    #[test]
    fn errors_far_into_a_file_name_their_line() {
        // Point i on line i + 2, in hundreds of pieces.
        let n = 100_000;
        let points: Vec<String> = (1..=n).map(|i| format!("{} {} 0.5", i as f64 / 7.0, -(i as f64) * 1e-3)).collect();
        let file = |count: usize, points: &[String]| format!("# many sites\n{count}\n{}\n", points.join("\n"));
        let text = file(n, &points);
        assert!(cut_after_lines(text.as_bytes(), 4096).len() > 500);
        let read = |text: &str| {
            let r = parse_pieces(text.as_bytes(), "far.xyz", 4096);
            assert_eq!(
                outcome(sequential_xyz(text, "far.xyz")),
                outcome(parse_pieces(text.as_bytes(), "far.xyz", 4096))
            );
            r
        };
        assert_eq!(read(&text).unwrap().len(), n);
        let mut bad = points.clone();
        bad[77_776] = "1 nan 2".into();
        let (line, m) = parse_err(read(&file(n, &bad)));
        assert_eq!(
            (line, m.as_str()),
            (77_779, "expected the y coordinate of point 77777 (a finite number), found \"nan\"")
        );
        // The first of two errors.
        bad[49_999] = "1 2".into();
        let (line, m) = parse_err(read(&file(n, &bad)));
        assert_eq!((line, m.as_str()), (50_002, "expected 3 coordinates x y z for point 50000, found 2 values"));
        // A count too small is found where it is passed, before a later
        // error; an earlier error comes first.
        let mut late = points.clone();
        late[89_999] = "x 0 0".into();
        let (line, m) = parse_err(read(&file(60_000, &late)));
        assert_eq!(line, 60_003);
        assert!(
            m.starts_with("expected the end of the file after 60000 points (the count on line 2), found \""),
            "{m}"
        );
        assert_eq!(parse_err(read(&file(60_000, &bad))).0, 50_002);
        let (line, m) = parse_err(read(&file(60_000, &points)));
        assert_eq!((line, m.contains("after 60000 points")), (60_003, true));
        // A count too large: on the last line.
        let (line, m) = parse_err(read(&file(n + 1, &points)));
        assert_eq!((line, m.as_str()), (n + 2, "expected 100001 points (the count on line 2), found 100000"));
        // Comments and blank lines after the last point do not move it.
        let (line, _) = parse_err(read(&(file(n + 1, &points) + "\n# end\n\n")));
        assert_eq!(line, n + 2);
    }

    #[test]
    fn a_count_line_after_long_comments_and_pieces_of_one_line() {
        let mut text = "# a long header\n".repeat(1000);
        text += "\n3\n0 0 0\n\n1 1 1\n2 2 2";
        let cuts = cut_after_lines(text.as_bytes(), 1);
        assert_eq!(cuts.len(), text.lines().count());
        assert!(cuts.iter().all(|r| text[r.clone()].lines().count() == 1));
        check_pieces(text.as_bytes());
        assert_eq!(parse_pieces(text.as_bytes(), "h.xyz", 1).unwrap().len(), 3);
    }
}
