//! Medit ASCII `.mesh` (the libMeshb format).

use super::lex::{Lexer, Tokens};
use super::{build, TetList};
use cvd::error::Result;
use cvd::geom::mesh::TetMesh;

/// Sections skipped by count, with the numbers in each entry (3D files).
const SKIPPED: &[(&str, usize)] = &[
    ("Edges", 3),
    ("Triangles", 4),
    ("Quadrilaterals", 5),
    ("Prisms", 7),
    ("Pentahedra", 7),
    ("Pyramids", 6),
    ("Hexahedra", 9),
    ("Corners", 1),
    ("Ridges", 1),
    ("RequiredVertices", 1),
    ("RequiredEdges", 1),
    ("RequiredTriangles", 1),
    ("RequiredQuadrilaterals", 1),
    ("RequiredTetrahedra", 1),
    ("Normals", 3),
    ("Tangents", 3),
    ("NormalAtVertices", 2),
    ("TangentAtVertices", 2),
    ("NormalAtTriangleVertices", 3),
    ("NormalAtQuadrilateralVertices", 4),
    ("TangentAtEdgeVertices", 3),
    ("EdgesP2", 4),
    ("TrianglesP2", 7),
    ("QuadrilateralsQ2", 10),
    ("TetrahedraP2", 11),
    ("HexahedraQ2", 28),
];

/// Parses a Medit ASCII mesh: `Vertices` (x y z ref) and `Tetrahedra`
/// (four 1-based indices and a ref) are kept; the other known sections are
/// skipped by their counts; `End` or the end of the text ends it. Tokens
/// may be split across lines at will; `#` starts a comment.
pub fn parse_medit(text: &str, path: &str) -> Result<TetMesh> {
    let mut lex = Lexer::new(text, path);
    let mut vertices: Option<(Vec<[f64; 3]>, usize)> = None;
    let mut tets: Option<(TetList, usize)> = None;
    while let Some(kw) = lex.tok() {
        if kw.is("End") {
            break;
        } else if kw.is("MeshVersionFormatted") {
            lex.int("the version after MeshVersionFormatted")?;
        } else if kw.is("Dimension") {
            let dim = lex.expect("the dimension after Dimension")?;
            if dim.text != "3" {
                return Err(dim.unexpected("Dimension 3 (only 3D meshes are supported)"));
            }
        } else if kw.is("Vertices") {
            if let Some((_, first)) = vertices {
                return Err(
                    kw.error(format!("expected one Vertices section, found a second (the first is on line {first})"))
                );
            }
            let n = lex.count("the number of vertices after Vertices")?;
            let mut v = Vec::with_capacity(lex.capacity(n, 4));
            for i in 1..=n {
                let mut p = [0.0; 3];
                for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
                    *c = lex.f64(format_args!("the {axis} coordinate of vertex {i} of {n}"))?;
                }
                v.push(p);
                lex.int(format_args!("the reference after x y z of vertex {i} of {n}"))?;
            }
            vertices = Some((v, kw.line));
        } else if kw.is("Tetrahedra") {
            if let Some((_, first)) = tets {
                return Err(
                    kw.error(format!("expected one Tetrahedra section, found a second (the first is on line {first})"))
                );
            }
            let n = lex.count("the number of tets after Tetrahedra")?;
            let mut list = TetList::with_capacity(lex.capacity(n, 5));
            for t in 1..=n {
                let first = lex.expect(format_args!("tet {t} of {n} (4 vertex numbers and a reference)"))?;
                let mut tet = [first.index(format_args!("vertex 1 of tet {t} of {n}"), 1)?, 0, 0, 0];
                for (k, v) in tet.iter_mut().enumerate().skip(1) {
                    *v = lex.index(format_args!("vertex {} of tet {t} of {n}", k + 1), 1)?;
                }
                lex.int(format_args!("the reference after the 4 vertices of tet {t} of {n}"))?;
                list.push(tet, first.line);
            }
            tets = Some((list, kw.line));
        } else if kw.is("AngleOfCornerBound") {
            lex.f32("the angle after AngleOfCornerBound")?;
        } else if let Some(&(name, width)) = SKIPPED.iter().find(|(name, _)| kw.is(name)) {
            let n = lex.count(format_args!("the number of entries after {name}"))?;
            for i in 1..=n {
                for _ in 0..width {
                    lex.expect(format_args!("entry {i} of {n} of {name} (line {}: {width} numbers each)", kw.line))?;
                }
            }
        } else {
            let hint = match kw.text.parse::<f64>() {
                Ok(_) => " (a section with more entries than its count?)",
                Err(_) => " (an unknown section)",
            };
            return Err(
                kw.unexpected(format_args!("a section keyword (Vertices, Tetrahedra, Triangles, ..., End){hint}"))
            );
        }
    }
    let vertices = vertices.map_or_else(Vec::new, |(v, _)| v);
    let tets = tets.map_or_else(TetList::default, |(t, _)| t);
    build(path, vertices, tets, 1, lex.last_line())
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::{no_panic_on_mutations, parse_err, two_tets};
    use super::*;

    pub(in crate::read) const VALID: &str = "MeshVersionFormatted 2\nDimension 3\n\
        # a comment\nVertices\n5\n0 0 0 1\n1 0 0 1\n0 1 0 1\n0 0 1 1\n1 1 1 2\n\
        Triangles 2\n1 2 3 0\n2 3 4 0\nTetrahedra\n2\n1 2 3 4 1\n2 3 4 5 1\nEnd\n";

    #[test]
    fn valid() {
        assert_eq!(parse_medit(VALID, "v.mesh").unwrap(), two_tets());
    }

    #[test]
    fn tokens_may_be_split_across_lines_and_sections_reordered() {
        let text = "MeshVersionFormatted\n1 Dimension\n3 Edges 1 1 2 # comment\n7\n\
            Tetrahedra 2 1 2 3\n4 1 2 3 4 5 1 Corners 2 1 2 Vertices 5 0 0 0 1 1 0 0 1 0 1 0 1 0 0\n1 1 1 1 1 2";
        assert_eq!(parse_medit(text, "v.mesh").unwrap(), two_tets());
    }

    #[test]
    fn skips_every_known_section() {
        for &(name, width) in SKIPPED {
            let entries = vec!["7"; 2 * width].join(" ");
            let text = VALID.replace("Triangles 2\n1 2 3 0\n2 3 4 0", &format!("{name}\n2\n{entries}"));
            assert_eq!(parse_medit(&text, "v.mesh").unwrap(), two_tets(), "{name}");
        }
    }

    #[test]
    fn truncated() {
        let text = &VALID[..VALID.find("2 3 4 5").unwrap() + 5];
        let (line, m) = parse_err(parse_medit(text, "t.mesh"));
        assert_eq!((line, m.as_str()), (17, "expected vertex 4 of tet 2 of 2, found end of file"));
        let (line, m) = parse_err(parse_medit("Vertices 1000000000000\n0 0 0 0\n", "t.mesh"));
        assert_eq!(
            (line, m.as_str()),
            (2, "expected the x coordinate of vertex 2 of 1000000000000, found end of file")
        );
    }

    #[test]
    fn bad_numbers() {
        let (line, m) = parse_err(parse_medit(&VALID.replace("1 1 1 2", "1 1 nan 2"), "b.mesh"));
        assert_eq!(
            (line, m.as_str()),
            (10, "expected the z coordinate of vertex 5 of 5 (a finite number), found \"nan\"")
        );
        let (line, m) = parse_err(parse_medit(&VALID.replace("2 3 4 5 1", "2 3 4 -5 1"), "b.mesh"));
        assert_eq!(line, 17);
        assert!(
            m.starts_with("expected vertex 4 of tet 2 of 2 (an integer from 1 to 4294967296), found \"-5\""),
            "{m}"
        );
        let (line, m) = parse_err(parse_medit(&VALID.replace("Vertices\n5", "Vertices\n-5"), "b.mesh"));
        assert_eq!(
            (line, m.as_str()),
            (5, "expected the number of vertices after Vertices (a non-negative integer), found \"-5\"")
        );
        // A vertex without its reference shifts the numbers until one fails.
        let (line, m) = parse_err(parse_medit(&VALID.replace("0 0 0 1\n", "0 0 0\n"), "b.mesh"));
        assert_eq!(
            (line, m.as_str()),
            (11, "expected the reference after x y z of vertex 5 of 5 (an integer), found \"Triangles\"")
        );
    }

    #[test]
    fn index_out_of_range_names_the_tet() {
        let (line, m) = parse_err(parse_medit(&VALID.replace("2 3 4 5 1", "2 3 4 6 1"), "r.mesh"));
        assert_eq!(
            (line, m.as_str()),
            (17, "tet 2 [2, 3, 4, 6] refers to vertex 6, but the file has 5 vertices, numbered 1 to 5")
        );
    }

    #[test]
    fn count_mismatch_and_unknown_sections() {
        let (line, m) = parse_err(parse_medit(&VALID.replace("Vertices\n5", "Vertices\n4"), "c.mesh"));
        assert_eq!(line, 10);
        assert!(m.starts_with("expected a section keyword") && m.contains("more entries than its count"), "{m}");
        let (line, m) = parse_err(parse_medit(&VALID.replace("Triangles", "Triangels"), "c.mesh"));
        assert_eq!(line, 11);
        assert!(m.contains("found \"Triangels\"") && m.contains("unknown section"), "{m}");
        let (line, m) = parse_err(parse_medit(&VALID.replace("Dimension 3", "Dimension 2"), "c.mesh"));
        assert_eq!((line, m.as_str()), (2, "expected Dimension 3 (only 3D meshes are supported), found \"2\""));
        let (line, m) = parse_err(parse_medit(&VALID.replace("End", "Vertices 0"), "c.mesh"));
        assert_eq!(line, 18);
        assert!(m.contains("found a second (the first is on line 4)"), "{m}");
    }

    #[test]
    fn missing_sections() {
        let no_tets = &VALID[..VALID.find("Tetrahedra").unwrap()];
        let (line, m) = parse_err(parse_medit(no_tets, "m.mesh"));
        assert_eq!((line, m.as_str()), (13, "expected tetrahedra, found none (a surface mesh?)"));
        let no_vertices = &VALID[VALID.find("Tetrahedra").unwrap()..];
        let (line, m) = parse_err(parse_medit(no_vertices, "m.mesh"));
        assert_eq!((line, m.as_str()), (3, "tet 1 [1, 2, 3, 4] refers to vertex 1, but the file has no vertices"));
        assert_eq!(parse_err(parse_medit("", "m.mesh")).0, 1);
    }

    #[test]
    fn no_input_panics() {
        no_panic_on_mutations(VALID, |t| parse_medit(t, "f.mesh"));
    }
}
