//! Extended XYZ (`.extxyz`, as ASE, OVITO and GPUMD write it), read frame
//! by frame. A frame is a line with the atom count, a comment line of
//! `key=value` pairs, then one line per atom:
//!
//! ```text
//! 2
//! Lattice="10 0 0 0 10 0 0 0 10" Properties=species:S:1:pos:R:3:id:I:1 pbc="T T F" step=100
//! Ar 0.5 1.5 2.5 7
//! Ar 5.0 5.0 5.0 3
//! ```
//!
//! The comment line: pairs separated by whitespace, values quoted with
//! `"` (or `'`, with backslash escapes) or in `{}` when they hold spaces;
//! a key without a value is a flag (true). Read, with keys in any case:
//! `Lattice` (the cell's vectors `a`, `b`, `c`, 9 numbers; required, since
//! the particles' diagram needs a cell), `Origin` (the cell's corner, 3
//! numbers, default 0), `pbc` (3 of `T`/`F`, `True`/`False`, `1`/`0`,
//! default all periodic), `Properties` (the atom lines' columns as
//! `name:type:count` triples, types `S` string, `R` real, `I` integer,
//! `L` logical; default `species:S:1:pos:R:3`) and `step` or `timestep`.
//! Of the columns, `pos` (`R:3`) gives the Cartesian positions, `id`
//! (`I:1`) the ids (the rows are then sorted by them), `radius` or
//! `radii` (`R:1`) the radii; the others are not looked at.

use super::particles::{
    atoms_in_parts, box_message, count, finite, open_buffered, read_atoms, tokens, unsigned, Atoms, Columns, Field,
    FrameReader, Lines, ParticleFrame, PartsScan,
};
use cvd::backends::distributed::Reduce;
use cvd::error::Result;
use cvd::PeriodicBox;
use std::io::{BufRead, BufReader, Seek};
use std::path::Path;

/// The columns when the comment line names none.
const DEFAULT_PROPERTIES: &str = "species:S:1:pos:R:3";

/// A reader of an extended XYZ file's frames (see the module's notes for
/// what is read).
pub struct ExtxyzReader<R> {
    lines: Lines<R>,
    index: usize,
    done: bool,
    /// What reading in parts keeps from frame to frame.
    scan: PartsScan,
}

impl ExtxyzReader<BufReader<std::fs::File>> {
    /// Opens an extended XYZ file; its frames are read as the reader is
    /// iterated.
    pub fn open(path: &Path) -> Result<Self> {
        Ok(Self::new(open_buffered(path)?, path.display().to_string()))
    }
}

/// What a comment line gives.
struct Info {
    domain: PeriodicBox,
    columns: Columns,
    timestep: Option<u64>,
}

impl<R: BufRead + Seek> ExtxyzReader<R> {
    /// A reader of the file `reader` holds; `path` names it in errors.
    pub fn new(reader: R, path: impl Into<String>) -> Self {
        Self { lines: Lines::new(reader, path.into()), index: 0, done: false, scan: PartsScan::default() }
    }

    /// The next frame's atom count and its line, `None` at the end of the
    /// file (blank lines before a frame are passed over).
    fn count_line(&mut self) -> Result<Option<(usize, usize)>> {
        let lines = &mut self.lines;
        lines.frame = self.index;
        if !lines.next_nonblank()? {
            return Ok(None);
        }
        let t = tokens(lines, 1, "the atom count of a frame, alone on its line")?;
        Ok(Some((count(lines, t[0], "the atom count of a frame")?, lines.no())))
    }

    /// The comment line's name in errors when it is missing.
    fn comment_what(count_line: usize) -> String {
        format!("the comment line (Lattice=\"...\" ...) after the atom count on line {count_line}")
    }

    /// The next frame, or `None` at the end of the file: whole, or this
    /// rank's part of it over `comm`'s ranks.
    fn read(&mut self, comm: Option<&dyn Reduce>) -> Result<Option<ParticleFrame>> {
        let Some((count, count_line)) = self.count_line()? else { return Ok(None) };
        let lines = &mut self.lines;
        lines.expect(Self::comment_what(count_line))?;
        let info = info(lines)?;
        let atoms = Atoms { count, count_line, count_name: "the atom count", stop: None };
        let (rows, part) = match comm {
            None => (read_atoms(lines, &info.columns, &atoms, &info.domain)?, None),
            Some(comm) => {
                let parse = Some((&info.columns, &info.domain));
                let (rows, part) = atoms_in_parts(lines, &atoms, comm, parse, &mut self.scan)?;
                (rows, Some(part))
            }
        };
        let frame = ParticleFrame {
            index: self.index,
            timestep: info.timestep,
            domain: info.domain,
            positions: rows.positions,
            ids: rows.ids,
            radii: rows.radii,
            part,
        };
        self.index += 1;
        Ok(Some(frame))
    }

    /// Passes over the next frame: its count line is read, the comment
    /// and atom lines only counted (in parts over `comm`'s ranks, each
    /// counting a share of the atom lines).
    fn skip(&mut self, comm: Option<&dyn Reduce>) -> Result<bool> {
        let Some((count, count_line)) = self.count_line()? else { return Ok(false) };
        let lines = &mut self.lines;
        let atoms = Atoms { count, count_line, count_name: "the atom count", stop: None };
        match comm {
            None => match lines.skip(count.saturating_add(1))? {
                0 => return Err(lines.missing(Self::comment_what(count_line))),
                n if n - 1 < count => return Err(atoms.cut_short(lines, n - 1)),
                _ => {}
            },
            Some(comm) => {
                lines.expect(Self::comment_what(count_line))?;
                atoms_in_parts(lines, &atoms, comm, None, &mut self.scan)?;
            }
        }
        self.index += 1;
        Ok(true)
    }
}

/// Reads the comment line (the current line).
fn info<R: BufRead>(lines: &Lines<R>) -> Result<Info> {
    let pairs = key_values(lines.text()).map_err(|m| lines.error(m))?;
    // The last value given for a key, in any case.
    let get = |key: &str| pairs.iter().rev().find(|(k, _)| k.eq_ignore_ascii_case(key)).map(|(_, v)| v.as_str());
    let Some(lattice) = get("Lattice") else {
        return Err(lines.error(
            "expected Lattice=\"ax ay az bx by bz cx cy cz\" on the comment line (the particles' cell), found none",
        ));
    };
    let l: [f64; 9] = numbers(lines, lattice, "Lattice=\"ax ay az bx by bz cx cy cz\"")?;
    let origin = match get("Origin") {
        Some(o) => numbers(lines, o, "Origin=\"x y z\"")?,
        None => [0.0; 3],
    };
    let periodic = match get("pbc") {
        Some(p) => flags(lines, p)?,
        None => [true; 3],
    };
    let timestep = match get("step").or_else(|| get("timestep")) {
        Some(t) => Some(unsigned(lines, t, "the step")?),
        None => None,
    };
    let columns = properties(lines, get("Properties").unwrap_or(DEFAULT_PROPERTIES))?;
    let vectors = [[l[0], l[1], l[2]], [l[3], l[4], l[5]], [l[6], l[7], l[8]]];
    let domain = PeriodicBox::triclinic(origin, vectors)
        .map_err(|e| lines.error(format_args!("Lattice gives no cell: {}", box_message(e))))?
        .with_periodic(periodic);
    Ok(Info { domain, columns, timestep })
}

/// `N` finite numbers separated by spaces (`what` names the key).
fn numbers<R: BufRead, const N: usize>(lines: &Lines<R>, value: &str, what: &str) -> Result<[f64; N]> {
    let toks: Vec<&str> = value.split_ascii_whitespace().collect();
    let mut out = [0.0; N];
    if toks.len() != N {
        return Err(lines.unexpected(value, format_args!("{what} ({N} finite numbers)")));
    }
    for (x, tok) in out.iter_mut().zip(toks) {
        *x = finite(lines, tok, format_args!("a number of {what}"))?;
    }
    Ok(out)
}

/// `pbc`'s three flags.
fn flags<R: BufRead>(lines: &Lines<R>, value: &str) -> Result<[bool; 3]> {
    let flag = |t: &str| match t.to_ascii_lowercase().as_str() {
        "t" | "true" | "1" => Some(true),
        "f" | "false" | "0" => Some(false),
        _ => None,
    };
    match value.split_ascii_whitespace().map(flag).collect::<Vec<_>>().as_slice() {
        [Some(a), Some(b), Some(c)] => Ok([*a, *b, *c]),
        _ => Err(lines.unexpected(value, "pbc=\"T T F\" (3 of T, F, True, False, 1, 0)")),
    }
}

/// The atom lines' columns from `Properties`.
fn properties<R: BufRead>(lines: &Lines<R>, spec: &str) -> Result<Columns> {
    let parts: Vec<&str> = spec.split(':').collect();
    let bad = |why: &str| {
        lines.unexpected(
            spec,
            format_args!("Properties=name:type:count:... (triples such as species:S:1:pos:R:3; {why})"),
        )
    };
    if !parts.len().is_multiple_of(3) || parts.iter().any(|p| p.is_empty()) {
        return Err(bad("three fields each"));
    }
    let mut fields = Vec::new();
    let (mut column, mut pos) = (0usize, false);
    let (mut id, mut radius) = (false, false);
    for triple in parts.chunks(3) {
        let (name, kind) = (triple[0], triple[1].to_ascii_uppercase());
        if !["S", "R", "I", "L"].contains(&kind.as_str()) {
            return Err(bad("types S, R, I or L"));
        }
        let n = match triple[2].parse::<usize>() {
            Ok(n) if n > 0 => n,
            _ => return Err(bad("counts of at least 1")),
        };
        let wrong = |expected: &str| {
            let found = triple.join(":");
            lines.error(format_args!("expected the property {expected} in Properties, found {found}"))
        };
        match name.to_ascii_lowercase().as_str() {
            "pos" if !pos => {
                if (kind.as_str(), n) != ("R", 3) {
                    return Err(wrong("pos:R:3"));
                }
                fields.extend((0..3).map(|k| (column + k, Field::Position(k))));
                pos = true;
            }
            "id" if !id => {
                if (kind.as_str(), n) != ("I", 1) {
                    return Err(wrong("id:I:1"));
                }
                fields.push((column, Field::Id));
                id = true;
            }
            "radius" | "radii" if !radius => {
                if (kind.as_str(), n) != ("R", 1) {
                    return Err(wrong(&format!("{name}:R:1")));
                }
                fields.push((column, Field::Radius));
                radius = true;
            }
            _ => {}
        }
        column = column.checked_add(n).ok_or_else(|| bad("fewer columns"))?;
    }
    if !pos {
        return Err(lines.unexpected(spec, "Properties with the positions, pos:R:3"));
    }
    Ok(Columns::new(column, fields, false, format!("Properties={spec}")))
}

/// The comment line's `key=value` pairs, in order; a key without `=` is a
/// flag, its value `T`. The error is a message.
fn key_values(text: &str) -> std::result::Result<Vec<(String, String)>, String> {
    let b = text.as_bytes();
    let skip_space = |mut i: usize| {
        while b.get(i).is_some_and(|c| c.is_ascii_whitespace()) {
            i += 1;
        }
        i
    };
    let mut pairs = Vec::new();
    let mut i = skip_space(0);
    while i < b.len() {
        let (key, end) = word(text, i, true)?;
        let j = skip_space(end);
        if b.get(j) == Some(&b'=') {
            let (value, end) = word(text, skip_space(j + 1), false)?;
            pairs.push((key, value));
            i = skip_space(end);
        } else {
            pairs.push((key, "T".to_string()));
            i = j;
        }
    }
    Ok(pairs)
}

/// The word of `text` starting at byte `start` and the byte after it: a
/// quoted string (unquoted, escapes resolved), the inside of `{...}`, or
/// up to the next space (or `=`, for a key).
fn word(text: &str, start: usize, key: bool) -> std::result::Result<(String, usize), String> {
    let b = text.as_bytes();
    let column = || text[..start].chars().count() + 1;
    match b.get(start) {
        Some(&q @ (b'"' | b'\'')) => {
            let mut out = String::new();
            let mut chars = text[start + 1..].char_indices();
            while let Some((k, c)) = chars.next() {
                match c {
                    '\\' => match chars.next() {
                        Some((_, 'n')) => out.push('\n'),
                        Some((_, e)) => out.push(e),
                        None => break,
                    },
                    c if c == q as char => return Ok((out, start + 1 + k + 1)),
                    c => out.push(c),
                }
            }
            Err(format!(
                "expected a closing {} for the quote at character {} of the comment line, found the end of \
                 the line",
                q as char,
                column()
            ))
        }
        Some(b'{') if !key => match text[start..].find('}') {
            Some(k) => Ok((text[start + 1..start + k].to_string(), start + k + 1)),
            None => Err(format!(
                "expected a closing }} for the {{ at character {} of the comment line, found the end of the line",
                column()
            )),
        },
        _ => {
            let end = b[start..]
                .iter()
                .position(|&c| c.is_ascii_whitespace() || (key && c == b'='))
                .map_or(b.len(), |e| start + e);
            Ok((text[start..end].to_string(), end))
        }
    }
}

super::particles::frame_reader!(ExtxyzReader);

#[cfg(test)]
pub(crate) mod tests {
    use super::super::particles::tests::{fails_at, read_all_frames, replace_line};
    use super::super::particles::FramePart;
    use super::super::tests::no_panic_on_mutations;
    use super::*;

    /// Two frames: the first with every key read, extra columns and
    /// quoted values, ids out of order; the second with the default
    /// columns, keys in other cases and an origin. Frame 0 is lines 1 to
    /// 5, frame 1 lines 6 to 9.
    pub const VALID: &str = r#"3
Lattice="10 0 0 0 10 0 0 0 10" Properties=species:S:1:pos:R:3:id:I:1:forces:R:3:radius:R:1:fixed:L:1 pbc="T T F" energy=-3.5 config_type="bulk fcc" Step=10 note="say \"hi\" = {x}"
Ar 1.5 2.5 3.5 3 0.1 0.2 0.3 0.5 T
Ar 0.5 0.25 -1 1 0 0 0 0.25 F
Kr 9 9 4 2 1 1 1 1 T
2
lattice="4 0 0 1 3 0 0.5 0.5 5" origin="1 2 -1" PBC="F T T" time=0.5
H 0 0 0
O 1 1 1
"#;

    fn read_all(text: &str) -> Result<Vec<ParticleFrame>> {
        ExtxyzReader::new(std::io::Cursor::new(text.as_bytes()), "t.extxyz").collect()
    }

    /// Reading `text` fails at `line` of frame `frame`, the message holding
    /// `part`.
    #[track_caller]
    fn fails(text: &str, line: usize, frame: usize, part: &str) {
        fails_at(read_all(text), "t.extxyz", line, frame, part);
    }

    /// `VALID` with its line `line` (1-based) replaced.
    fn with_line(line: usize, text: &str) -> String {
        replace_line(VALID, line, text)
    }

    /// A frame of the default columns in the cell `lattice`.
    fn frame(comment: &str, points: &[[f64; 3]]) -> String {
        let mut out = format!("{}\n{comment}\n", points.len());
        for [x, y, z] in points {
            out += &format!("Si {x} {y} {z}\n");
        }
        out
    }

    #[test]
    fn two_frames() {
        let frames = read_all(VALID).unwrap();
        assert_eq!(frames.len(), 2);
        let f = &frames[0];
        assert_eq!((f.index, f.timestep), (0, Some(10)));
        let cell = PeriodicBox::triclinic([0.0; 3], [[10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]]).unwrap();
        assert_eq!(f.domain, cell.with_periodic([true, true, false]));
        assert!(f.domain.is_aligned() && f.domain.hi() == [10.0; 3]);
        assert_eq!(f.positions, [[0.5, 0.25, -1.0], [9.0, 9.0, 4.0], [1.5, 2.5, 3.5]]);
        assert_eq!(f.ids, Some(vec![1, 2, 3]));
        assert_eq!(f.radii, Some(vec![0.25, 1.0, 0.5]));
        let f = &frames[1];
        assert_eq!((f.index, f.timestep, &f.ids, &f.radii), (1, None, &None, &None));
        let cell = PeriodicBox::triclinic([1.0, 2.0, -1.0], [[4.0, 0.0, 0.0], [1.0, 3.0, 0.0], [0.5, 0.5, 5.0]]);
        assert_eq!(f.domain, cell.unwrap().with_periodic([false, true, true]));
        assert_eq!(f.positions, [[0.0; 3], [1.0; 3]]);
    }

    /// An atom as read: its id, position and radius.
    type Row = (u64, [f64; 3], Option<f64>);

    #[test]
    fn frames_read_in_parts_are_the_frames_rows() {
        // Frame 0: 3 atoms on lines 3-5, ids out of order; frame 1: 2 atoms
        // on lines 8-9, no ids; frame 0 passed over or not; chunks of 1
        // and 16 bytes (many rounds) and as sized for a run.
        let whole = read_all(VALID).unwrap();
        for parts in 1..=4 {
            for chunk in [Some(1), Some(16), None] {
                for skip in [false, true] {
                    let by_part = cvd::backends::distributed::InProcess::each(parts, |comm| {
                        let mut reader = ExtxyzReader::new(std::io::Cursor::new(VALID.as_bytes()), "t.extxyz");
                        reader.scan.chunk = chunk;
                        if skip {
                            assert!(reader.skip_in_parts(comm).unwrap());
                        }
                        std::iter::from_fn(|| reader.next_in_parts(comm)).collect::<Result<Vec<_>>>().unwrap()
                    });
                    let mut rows: [Vec<Row>; 2] = Default::default();
                    for (p, frames) in by_part.iter().enumerate() {
                        assert_eq!(frames.len(), 2 - skip as usize);
                        for f in frames {
                            let n = whole[f.index].len();
                            let lo = n * p / parts;
                            let first_line = [3, 8][f.index] + lo;
                            assert_eq!(f.part, Some(FramePart { total: n, first: lo, first_line }));
                            assert_eq!((f.domain, f.timestep), (whole[f.index].domain, whole[f.index].timestep));
                            for i in 0..f.len() {
                                let id = f.ids.as_ref().map_or((lo + i) as u64, |ids| ids[i]);
                                rows[f.index].push((id, f.positions[i], f.radii.as_ref().map(|r| r[i])));
                            }
                        }
                    }
                    for (f, mut rows) in whole.iter().zip(rows).skip(skip as usize) {
                        rows.sort_by_key(|r| r.0);
                        assert_eq!(rows.iter().map(|r| r.1).collect::<Vec<_>>(), f.positions, "{parts} parts");
                        assert_eq!(rows.iter().map(|r| r.2).collect::<Option<Vec<_>>>(), f.radii);
                    }
                }
            }
        }
    }

    #[test]
    fn comment_lines() {
        let pairs = |t: &str| key_values(t).unwrap();
        let own = |v: &[(&str, &str)]| v.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect::<Vec<_>>();
        assert_eq!(
            pairs(r#"a=1 b = "x y"  c='q \' r' d={1 2 3} flag "quoted key"=v e="" f= g"#),
            own(&[
                ("a", "1"),
                ("b", "x y"),
                ("c", "q ' r"),
                ("d", "1 2 3"),
                ("flag", "T"),
                ("quoted key", "v"),
                ("e", ""),
                ("f", "g")
            ])
        );
        assert_eq!(pairs("  "), own(&[]));
        assert_eq!(pairs("x=a=b é=ü"), own(&[("x", "a=b"), ("é", "ü")]));
        assert_eq!(pairs("k="), own(&[("k", "")]));
        let e = key_values(r#"Lattice="1 0 0"#).unwrap_err();
        assert_eq!(
            e,
            "expected a closing \" for the quote at character 9 of the comment line, found the end of the line"
        );
        assert!(key_values("a={1 2").unwrap_err().contains("expected a closing } for the { at character 3"));
        // The last value of a key counts; pbc in every spelling.
        let text = frame(r#"Lattice="1 0 0 0 1 0 0 0 1" Lattice="2 0 0 0 2 0 0 0 2" pbc="true False 1""#, &[]);
        let f = read_all(&text).unwrap().remove(0);
        assert_eq!((f.domain.hi(), f.domain.periodic()), ([2.0; 3], [true, false, true]));
        let text = frame(r#"Lattice="1 0 0 0 1 0 0 0 1" pbc="f t 0" timestep=7"#, &[]);
        let f = read_all(&text).unwrap().remove(0);
        assert_eq!((f.domain.periodic(), f.timestep), ([false, true, false], Some(7)));
        // No pbc: periodic; radii by their other name.
        let text = "1\nLattice=\"1 0 0 0 1 0 0 0 1\" Properties=pos:R:3:radii:R:1\n0.5 0.5 0.5 0.125\n";
        let f = read_all(text).unwrap().remove(0);
        assert_eq!((f.domain.periodic(), f.radii, f.positions), ([true; 3], Some(vec![0.125]), vec![[0.5; 3]]));
    }

    #[test]
    fn zero_atoms_and_blank_lines() {
        let text = frame(r#"Lattice="1 0 0 0 1 0 0 0 1" Properties=species:S:1:pos:R:3:id:I:1"#, &[]) + "\n\n" + VALID;
        let frames = read_all(&text).unwrap();
        assert_eq!(frames.len(), 3);
        assert!(frames[0].is_empty() && frames[0].ids == Some(vec![]));
        assert_eq!(frames[1].positions, read_all(VALID).unwrap()[0].positions);
        assert_eq!(read_all(&VALID.replace('\n', "\r\n")).unwrap(), read_all(VALID).unwrap());
        assert!(read_all("").unwrap().is_empty() && read_all("\n\n").unwrap().is_empty());
    }

    #[test]
    fn skipped_frames_are_counted_for_later_errors() {
        // Five frames of 3 atoms (5 lines each), the fifth with a bad line.
        let mut text = String::new();
        for k in 0..5 {
            let points: Vec<[f64; 3]> = (1..=3).map(|i| [k as f64, i as f64, 0.5]).collect();
            text += &frame(&format!("Lattice=\"9 0 0 0 9 0 0 0 9\" step={k}"), &points);
        }
        let bad = text.replacen("Si 4 3 0.5", "Si 4 3", 1);
        let mut r = ExtxyzReader::new(std::io::Cursor::new(bad.as_bytes()), "t.extxyz");
        assert!(r.skip_frame().unwrap() && r.skip_frame().unwrap());
        let f = r.next().unwrap().unwrap();
        assert_eq!((f.index, f.timestep, f.positions[0]), (2, Some(2), [2.0, 1.0, 0.5]));
        assert!(r.skip_frame().unwrap());
        assert_eq!(r.next_index(), 4);
        let e = r.next().unwrap().unwrap_err().to_string();
        assert_eq!(e, "t.extxyz:25: frame 4: expected 4 values (Properties=species:S:1:pos:R:3) for atom 3, found 3");
        assert!(r.next().is_none() && !r.skip_frame().unwrap());
        let mut r = ExtxyzReader::new(std::io::Cursor::new(bad.as_bytes()), "t.extxyz");
        assert_eq!(r.nth(3).unwrap().unwrap().timestep, Some(3));
        assert!(r.skip_frame().unwrap() && !r.skip_frame().unwrap());
        // Cut short while skipping: in the atoms, after the count.
        let cut = &text[..text.len() - "Si 4 3 0.5\n".len()];
        let mut r = ExtxyzReader::new(std::io::Cursor::new(cut.as_bytes()), "t.extxyz");
        assert!((0..4).all(|_| r.skip_frame().unwrap()));
        let e = r.skip_frame().unwrap_err().to_string();
        assert_eq!(
            e,
            "t.extxyz:24: frame 4: expected 3 atom lines (the atom count on line 21), found 2: the file ends (cut \
             short?)"
        );
        let mut r = ExtxyzReader::new(std::io::Cursor::new("2\n".as_bytes()), "t.extxyz");
        let e = r.skip_frame().unwrap_err().to_string();
        assert_eq!(e, "t.extxyz:1: frame 0: expected the comment line (Lattice=\"...\" ...) after the atom count on line 1, found end of file");
    }

    #[test]
    fn errors_name_the_file_line_and_frame() {
        fails(&with_line(7, "origin=\"1 2 -1\""), 7, 1, "expected Lattice=\"ax ay az bx by bz cx cy cz\" on the");
        fails(&with_line(7, ""), 7, 1, "expected Lattice=");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0\""), 7, 1, "(9 finite numbers), found \"1 0 0 0 1 0 0 0\"");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0 nan\""), 7, 1, "expected a number of Lattice=");
        fails(&with_line(7, "Lattice=\"1 0 0 0 0 1 0 1 0\""), 7, 1, "Lattice gives no cell: the lattice vectors");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0 1\" pbc=\"T T\""), 7, 1, "expected pbc=\"T T F\"");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0 1\" pbc=\"T T X\""), 7, 1, "(3 of T, F, True, False, 1, 0)");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0 1\" Origin=\"0 0\""), 7, 1, "expected Origin=\"x y z\"");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0 1\" step=1.5"), 7, 1, "expected the step (a non-negative");
        fails(&with_line(7, "Lattice=\"1 0 0 0 1 0 0 0 1\" comment=\"cut"), 7, 1, "expected a closing \"");
        let props = |p: &str| with_line(2, &format!("Lattice=\"10 0 0 0 10 0 0 0 10\" Properties={p}"));
        fails(&props("species:S:1"), 2, 0, "expected Properties with the positions, pos:R:3");
        fails(&props("species:S:1:pos:I:3"), 2, 0, "expected the property pos:R:3 in Properties, found pos:I:3");
        fails(&props("species:S:1:pos:R:2"), 2, 0, "found pos:R:2");
        fails(&props("pos:R:3:id:R:1"), 2, 0, "expected the property id:I:1 in Properties, found id:R:1");
        fails(&props("pos:R:3:radius:R:2"), 2, 0, "expected the property radius:R:1");
        fails(&props("species:S"), 2, 0, "(triples such as species:S:1:pos:R:3; three fields each)");
        fails(&props("species:S:1:pos:R:3::"), 2, 0, "three fields each");
        fails(&props("species:X:1:pos:R:3"), 2, 0, "types S, R, I or L");
        fails(&props("species:S:0:pos:R:3"), 2, 0, "counts of at least 1");
        fails(&props("x:R:18446744073709551615:pos:R:3"), 2, 0, "fewer columns");
        // Atom lines.
        let line_4 = "for atom 2, found 9";
        fails(&with_line(4, "Ar 0.5 0.25 -1 1 0 0 0 0.25"), 4, 0, line_4);
        fails(
            &with_line(4, "Ar 0.5 0.25"),
            4,
            0,
            "expected 10 values (Properties=species:S:1:pos:R:3:id:I:1:forces:R:3:radius:R:1:fixed:L:1) for atom 2, found 3",
        );
        fails(&with_line(5, "Kr 9 nan 4 2 1 1 1 1 T"), 5, 0, "expected y of atom 3 (a finite number), found \"nan\"");
        fails(&with_line(5, "Kr 9 9 -inf 2 1 1 1 1 T"), 5, 0, "expected z of atom 3 (a finite number), found \"-inf\"");
        fails(&with_line(9, "O 1 one 1"), 9, 1, "expected y of atom 2 (a finite number), found \"one\"");
        fails(&with_line(3, "Ar 1.5 2.5 3.5 x 0.1 0.2 0.3 0.5 T"), 3, 0, "expected the id of atom 1 (a non-negative");
        fails(&with_line(5, "Kr 9 9 4 3 1 1 1 1 T"), 5, 0, "atom id 3 again (it is on line 3 too)");
        fails(&with_line(5, "Kr 9 9 4 2 1 1 1 inf T"), 5, 0, "expected the radius of atom 3");
        // Count lines, and files cut short.
        fails(
            &with_line(6, "2 atoms"),
            6,
            1,
            "expected 1 value (the atom count of a frame, alone on its line), found 2",
        );
        fails(&with_line(6, "-2"), 6, 1, "expected the atom count of a frame (a non-negative integer), found \"-2\"");
        fails(&with_line(1, "4"), 6, 0, "expected 10 values");
        fails("3\n", 1, 0, "expected the comment line (Lattice=\"...\" ...) after the atom count on line 1, found end");
        let cut = &VALID[..VALID.len() - "O 1 1 1\n".len()];
        fails(cut, 8, 1, "expected 2 atom lines (the atom count on line 6), found 1: the file ends (cut short?)");
    }

    #[test]
    fn truncated_files() {
        let lines: Vec<&str> = VALID.lines().collect();
        for k in 0..=lines.len() {
            let text: String = lines[..k].iter().map(|l| format!("{l}\n")).collect();
            let r = read_all(&text);
            match k {
                0 | 5 | 9 => assert_eq!(r.unwrap().len(), [0, 0, 0, 0, 0, 1, 0, 0, 0, 2][k]),
                _ => {
                    let e = r.unwrap_err().to_string();
                    let frame = (k > 5) as usize;
                    assert!(e.starts_with(&format!("t.extxyz:{k}: frame {frame}: expected ")), "{k} lines: {e}");
                }
            }
        }
    }

    #[test]
    fn no_input_panics() {
        no_panic_on_mutations(VALID, |t| {
            read_all_frames(t, |b| ExtxyzReader::new(b, "f.extxyz"));
            read_all(t)
        });
    }
}
