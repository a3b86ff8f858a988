//! The `.tet` files of the paper's code (GitHub xh-liu-tech/3D-Voronoi-GPU).

use super::lex::{Lexer, Tokens};
use super::{build, TetList};
use cvd::error::Result;
use cvd::geom::mesh::TetMesh;

/// Parses a line `N vertices`, a line `M cells`, N lines `x y z` and M
/// lines `4 a b c d` (0-based vertex indices). Read line by line, so that
/// an entry with a number too few or too many is caught on its line.
pub fn parse_tet(text: &str, path: &str) -> Result<TetMesh> {
    let mut lex = Lexer::new(text, path);
    let n = header(&mut lex, "vertices")?;
    let m = header(&mut lex, "cells")?;
    let mut vertices = Vec::with_capacity(lex.capacity(n, 3));
    for i in 1..=n {
        let mut line = lex.expect_line(format_args!("vertex {i} of {n} (x y z)"))?;
        line.expect_len(3, format_args!("3 coordinates x y z for vertex {i} of {n}"))?;
        let mut p = [0.0; 3];
        for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
            *c = line.f64(format_args!("the {axis} coordinate of vertex {i} of {n}"))?;
        }
        vertices.push(p);
    }
    let mut tets = TetList::with_capacity(lex.capacity(m, 5));
    for t in 1..=m {
        let mut line = lex.expect_line(format_args!("tet {t} of {m} (4 a b c d)"))?;
        let count = line.expect("the vertex count")?;
        if count.text != "4" {
            return Err(
                count.unexpected(format_args!("4, the vertex count of tet {t} of {m} (only tets are supported)"))
            );
        }
        if line.len() != 5 {
            return Err(line.error(format!("expected 4 vertex indices after the count 4, found {}", line.len() - 1)));
        }
        let mut tet = [0; 4];
        for (k, v) in tet.iter_mut().enumerate() {
            *v = line.index(format_args!("vertex {} of tet {t} of {m}", k + 1), 0)?;
        }
        tets.push(tet, line.no);
    }
    lex.expect_end(format_args!("{n} vertices and {m} cells"))?;
    build(path, vertices, tets, 0, lex.last_line())
}

/// Reads a line `count word`.
fn header(lex: &mut Lexer, word: &str) -> Result<usize> {
    let mut line = lex.expect_line(format_args!("a line 'N {word}'"))?;
    let n = line.count(format_args!("the number of {word}"))?;
    let w = line.expect(format_args!("'{word}' after the number of {word}"))?;
    if !w.is(word) || line.len() != 2 {
        return Err(w.unexpected(format_args!("a line 'N {word}'")));
    }
    Ok(n)
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::{no_panic_on_mutations, parse_err, two_tets};
    use super::*;

    pub(in crate::read) const VALID: &str =
        "5 vertices\n2 cells\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n4 0 1 2 3\n4 1 2 3 4\n";

    #[test]
    fn valid() {
        assert_eq!(parse_tet(VALID, "v.tet").unwrap(), two_tets());
        assert_eq!(parse_tet(&VALID.replace('\n', "\r\n"), "v.tet").unwrap(), two_tets());
    }

    #[test]
    fn truncated() {
        let (line, m) = parse_err(parse_tet(&VALID[..VALID.len() - 10], "t.tet"));
        assert_eq!((line, m.as_str()), (8, "expected tet 2 of 2 (4 a b c d), found end of file"));
        let (line, m) = parse_err(parse_tet("1000000000000 vertices\n1 cells\n0 0 0\n", "t.tet"));
        assert_eq!((line, m.as_str()), (3, "expected vertex 2 of 1000000000000 (x y z), found end of file"));
    }

    #[test]
    fn wrong_number_of_values() {
        let (line, m) = parse_err(parse_tet(&VALID.replace("4 1 2 3 4", "4 1 2 3"), "w.tet"));
        assert_eq!((line, m.as_str()), (9, "expected 4 vertex indices after the count 4, found 3"));
        let (line, m) = parse_err(parse_tet(&VALID.replace("4 1 2 3 4", "8 1 2 3 4 5 6 7 8"), "w.tet"));
        assert_eq!(
            (line, m.as_str()),
            (9, "expected 4, the vertex count of tet 2 of 2 (only tets are supported), found \"8\"")
        );
        let (line, m) = parse_err(parse_tet(&VALID.replace("0 1 0\n", "0 1\n"), "w.tet"));
        assert_eq!((line, m.as_str()), (5, "expected 3 coordinates x y z for vertex 3 of 5, found 2 values"));
        let (line, m) = parse_err(parse_tet(&VALID.replace("2 cells", "2 tets"), "w.tet"));
        assert_eq!((line, m.as_str()), (2, "expected a line 'N cells', found \"tets\""));
    }

    #[test]
    fn bad_numbers_and_indices() {
        let (line, m) = parse_err(parse_tet(&VALID.replace("0 0 1\n", "0 0 1e400\n"), "b.tet"));
        assert_eq!(
            (line, m.as_str()),
            (6, "expected the z coordinate of vertex 4 of 5 (a finite number), found \"1e400\"")
        );
        let (line, m) = parse_err(parse_tet(&VALID.replace("4 1 2 3 4", "4 1 2 3 5"), "b.tet"));
        assert_eq!(
            (line, m.as_str()),
            (9, "tet 2 [1, 2, 3, 5] refers to vertex 5, but the file has 5 vertices, numbered 0 to 4")
        );
        let (line, m) = parse_err(parse_tet(&VALID.replace("4 1 2 3 4", "4 1 -2 3 4"), "b.tet"));
        assert_eq!(line, 9);
        assert!(m.starts_with("expected vertex 2 of tet 2 of 2 (an integer from 0 to 4294967295)"), "{m}");
    }

    #[test]
    fn count_mismatch() {
        let (line, m) = parse_err(parse_tet(&VALID.replace("2 cells", "1 cells"), "c.tet"));
        assert_eq!((line, m.as_str()), (9, "expected the end of the file after 5 vertices and 1 cells, found \"4\""));
        let (line, m) = parse_err(parse_tet(&VALID.replace("5 vertices", "6 vertices"), "c.tet"));
        assert_eq!((line, m.as_str()), (8, "expected 3 coordinates x y z for vertex 6 of 6, found 5 values"));
    }

    #[test]
    fn no_input_panics() {
        no_panic_on_mutations(VALID, |t| parse_tet(t, "f.tet"));
    }
}
