//! Sites as `.xyz`: `x y z` per line.

use super::lex::{Lexer, Tokens};
use crate::error::Result;

/// Parses points, `x y z` per line; `#` starts a comment and blank lines
/// are ignored. A first line holding a single number is the count of
/// points, which must then match. Coordinates are read as f64, exactly as
/// written (to the nearest f64).
pub fn parse_xyz(text: &str, path: &str) -> Result<Vec<[f64; 3]>> {
    let mut lex = Lexer::new(text, path);
    let mut points = Vec::new();
    // The count and its line, when the file gives one.
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
        Some((n, at)) if points.len() < n => Err(
            lex.error(lex.last_line(), format!("expected {n} points (the count on line {at}), found {}", points.len()))
        ),
        _ => Ok(points),
    }
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
}
