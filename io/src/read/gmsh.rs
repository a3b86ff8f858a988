//! Gmsh `.msh`, versions 2.2 and 4.1, ASCII.

use super::lex::{Lexer, Line, Tok, Tokens};
use super::{build, TetList};
use cvd::error::Result;
use cvd::geom::mesh::TetMesh;
use std::collections::HashMap;
use std::path::Path;

const CONVERT: &str = "convert it with `gmsh in.msh -0 -format msh22 -o out.msh`";

#[derive(Clone, Copy)]
enum Version {
    V2,
    V41,
}

/// Nodes read so far, and the vertex index of each node tag (tags are
/// arbitrary positive numbers).
#[derive(Default)]
struct Nodes {
    vertices: Vec<[f64; 3]>,
    ids: HashMap<usize, u32>,
}

impl Nodes {
    fn add(&mut self, tag: Tok, p: [f64; 3]) -> Result<()> {
        let id = tag.count("a node tag")?;
        let index = u32::try_from(self.vertices.len()).map_err(|_| tag.error("more than 2^32 nodes"))?;
        if self.ids.insert(id, index).is_some() {
            return Err(tag.error(format!("node tag {id} appears twice in $Nodes")));
        }
        self.vertices.push(p);
        Ok(())
    }

    /// The vertex index of the node tag on `line`, for element `element`.
    fn get(&self, line: &mut Line, element: &str) -> Result<u32> {
        let tag = line.expect(format_args!("a node tag of element {element}"))?;
        let id = tag.count(format_args!("a node tag of element {element}"))?;
        self.ids
            .get(&id)
            .copied()
            .ok_or_else(|| tag.error(format!("element {element} refers to node {id}, which is not in $Nodes")))
    }
}

/// Reads a `.msh` file, binary or ASCII as its `$MeshFormat` says.
pub(super) fn read_msh(path: &Path) -> Result<TetMesh> {
    let (bytes, name) = (super::read_bytes(path)?, path.display().to_string());
    if super::gmsh_binary::is_binary_gmsh(&bytes) {
        super::parse_gmsh_binary(&bytes, &name)
    } else {
        parse_gmsh(&String::from_utf8_lossy(&bytes), &name)
    }
}

/// Parses a Gmsh mesh in format 2.2 (also 2.0 and 2.1) or 4.1, ASCII. Of
/// the elements, 4-node tets (type 4) are kept, and the corners of 10-node
/// tets (type 11); those of lower dimension are skipped, other volume
/// elements are an error; sections are skipped other than
/// `$MeshFormat`, `$Nodes` and `$Elements`. Each entry is on its own line.
pub fn parse_gmsh(text: &str, path: &str) -> Result<TetMesh> {
    let mut lex = Lexer::new(text, path);
    let first = lex.expect_line("$MeshFormat")?.first();
    if first.text != "$MeshFormat" {
        let hint =
            if first.text == "$NOD" { format!(" (msh version 1 is not supported; {CONVERT})") } else { String::new() };
        return Err(first.unexpected(format_args!("$MeshFormat, the start of a Gmsh .msh file{hint}")));
    }
    let mut format = lex.expect_line("'version file-type data-size' after $MeshFormat")?;
    let version = format.expect("the version")?;
    let version = match version.text {
        "2" | "2.0" | "2.1" | "2.2" => Version::V2,
        "4.1" => Version::V41,
        v => return Err(version.error(format!("msh version {v} is not supported (only 2.2 and 4.1 ASCII); {CONVERT}"))),
    };
    let file_type = format.expect("the file type (0 for ASCII) after the version")?;
    if file_type.text != "0" {
        return Err(
            file_type.error(format!("binary .msh files are not supported (file type {}); {CONVERT}", file_type.text))
        );
    }
    format.expect("the data size after the file type")?;
    end(&mut lex, "$EndMeshFormat", "the version line")?;

    let mut nodes: Option<Nodes> = None;
    let mut tets: Option<TetList> = None;
    while let Some(line) = lex.line() {
        let head = line.first();
        match head.text {
            "$Nodes" if nodes.is_some() => return Err(head.error("expected one $Nodes section, found a second")),
            "$Nodes" => {
                nodes = Some(match version {
                    Version::V2 => nodes_v2(&mut lex)?,
                    Version::V41 => nodes_v41(&mut lex)?,
                })
            }
            "$Elements" if tets.is_some() => return Err(head.error("expected one $Elements section, found a second")),
            "$Elements" => {
                let Some(nodes) = &nodes else {
                    return Err(head.unexpected("$Nodes before $Elements"));
                };
                tets = Some(match version {
                    Version::V2 => elements_v2(&mut lex, nodes)?,
                    Version::V41 => elements_v41(&mut lex, nodes)?,
                })
            }
            name if name.starts_with('$') && !name.starts_with("$End") => {
                let close = format!("$End{}", &name[1..]);
                loop {
                    let line = lex.expect_line(format_args!("{close}, closing {name} of line {}", head.line))?;
                    if line.first().text == close {
                        break;
                    }
                }
            }
            _ => return Err(head.unexpected("a section such as $Nodes or $Elements")),
        }
    }
    let vertices = nodes.unwrap_or_default().vertices;
    build(path, vertices, tets.unwrap_or_default(), 0, lex.last_line())
}

/// Requires the line `close` next; `after` says what came before it.
fn end(lex: &mut Lexer, close: &str, after: impl std::fmt::Display + Copy) -> Result<()> {
    let line = lex.expect_line(format_args!("{close} after {after}"))?;
    if line.first().text == close {
        Ok(())
    } else {
        Err(line.first().unexpected(format_args!("{close} after {after}")))
    }
}

/// Reads x y z, the first three values of `line`.
fn xyz(line: &mut Line, node: impl std::fmt::Display + Copy) -> Result<[f64; 3]> {
    let mut p = [0.0; 3];
    for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
        *c = line.f64(format_args!("the {axis} coordinate of node {node}"))?;
    }
    Ok(p)
}

/// Nodes per element of each Gmsh element type, and its dimension.
pub(super) fn element_kind(t: i64) -> Option<(usize, u8)> {
    Some(match t {
        15 => (1, 0),
        1 => (2, 1),
        8 => (3, 1),
        2 => (3, 2),
        3 => (4, 2),
        9 => (6, 2),
        16 => (8, 2),
        10 => (9, 2),
        4 => (4, 3),
        11 => (10, 3),
        5 => (8, 3),
        6 => (6, 3),
        7 => (5, 3),
        17 => (20, 3),
        12 => (27, 3),
        18 => (15, 3),
        13 => (18, 3),
        19 => (13, 3),
        14 => (14, 3),
        _ => return None,
    })
}

/// How many node tags of an element type to read, and how many to keep.
fn tet_nodes(element_type: i64) -> Option<usize> {
    match element_type {
        4 => Some(4),
        11 => Some(10),
        _ => None,
    }
}

/// Elements of lower dimension are skipped; another volume element (a
/// hexahedron, prism, pyramid, a higher-order one) is an error, so no part
/// of the domain is lost silently.
fn refuse_volume_element(line: &Line, ty: i64, id: &str) -> Result<()> {
    match element_kind(ty) {
        Some((_, 3)) => Err(line.error(format!(
            "element {id} is of type {ty}, a volume element other than a tet: only tetrahedra are supported"
        ))),
        _ => Ok(()),
    }
}

/// `$Nodes` of 2.2: the count, then `tag x y z` per line.
fn nodes_v2(lex: &mut Lexer) -> Result<Nodes> {
    let n = lex.expect_line("the number of nodes after $Nodes")?.count("the number of nodes")?;
    let mut nodes =
        Nodes { vertices: Vec::with_capacity(lex.capacity(n, 4)), ids: HashMap::with_capacity(lex.capacity(n, 4)) };
    for i in 1..=n {
        let mut line = lex.expect_line(format_args!("node {i} of {n}"))?;
        line.expect_len(4, format_args!("tag x y z for node {i} of {n}"))?;
        let tag = line.expect("a node tag")?;
        let p = xyz(&mut line, tag.text)?;
        nodes.add(tag, p)?;
    }
    end(lex, "$EndNodes", format_args!("{n} nodes"))?;
    Ok(nodes)
}

/// `$Elements` of 2.2: the count, then `tag type ntags tags... nodes...`.
fn elements_v2(lex: &mut Lexer, nodes: &Nodes) -> Result<TetList> {
    let n = lex.expect_line("the number of elements after $Elements")?.count("the number of elements")?;
    let mut tets = TetList::with_capacity(lex.capacity(n, 7));
    for i in 1..=n {
        let mut line = lex.expect_line(format_args!("element {i} of {n}"))?;
        let id = line.expect("an element tag")?.text;
        let ty = line.int(format_args!("the type of element {id}"))?;
        let ntags = line.count(format_args!("the number of tags of element {id}"))?;
        let Some(corners) = tet_nodes(ty) else {
            refuse_volume_element(&line, ty, id)?;
            continue;
        };
        let after = line.len().saturating_sub(3);
        if ntags.checked_add(corners) != Some(after) {
            let message = format!(
                "expected {ntags} tags and {corners} node tags for element {id} of type {ty}, found {after} values"
            );
            return Err(line.error(message));
        }
        for _ in 0..ntags {
            line.tok();
        }
        let mut tet = [0; 4];
        for v in &mut tet {
            *v = nodes.get(&mut line, id)?;
        }
        tets.push(tet, line.no);
    }
    end(lex, "$EndElements", format_args!("{n} elements"))?;
    Ok(tets)
}

/// The header of a 4.1 section: `blocks total min-tag max-tag`.
fn header_v41(lex: &mut Lexer, what: &str) -> Result<(usize, usize)> {
    let mut line = lex.expect_line(format_args!("'blocks {what} min-tag max-tag' after the section start"))?;
    line.expect_len(4, format_args!("'blocks {what} min-tag max-tag'"))?;
    Ok((line.count("the number of entity blocks")?, line.count(format_args!("the number of {what}"))?))
}

/// The header of a 4.1 entity block: `dim tag x count` (x: parametric or
/// element type), with `count` checked against what the section announced.
fn block_v41(lex: &mut Lexer, b: usize, blocks: usize, seen: &mut usize, total: usize) -> Result<(i64, i64, usize)> {
    let mut line = lex.expect_line(format_args!("entity block {b} of {blocks}"))?;
    line.expect_len(4, format_args!("4 values for the header of entity block {b} of {blocks}"))?;
    let dim = line.int("the entity dimension")?;
    line.int("the entity tag")?;
    let kind = line.int("the parametric flag or element type")?;
    let count = line.count("the number of entries in the block")?;
    *seen = seen.saturating_add(count);
    if *seen > total {
        return Err(line.error(format!("expected {total} entries in all (the section's header), found more")));
    }
    Ok((dim, kind, count))
}

/// `$Nodes` of 4.1: entity blocks, each with its node tags and then one
/// line of coordinates per node.
fn nodes_v41(lex: &mut Lexer) -> Result<Nodes> {
    let (blocks, n) = header_v41(lex, "nodes")?;
    let mut nodes =
        Nodes { vertices: Vec::with_capacity(lex.capacity(n, 4)), ids: HashMap::with_capacity(lex.capacity(n, 4)) };
    let mut seen = 0;
    for b in 1..=blocks {
        let (dim, parametric, count) = block_v41(lex, b, blocks, &mut seen, n)?;
        let values = 3 + if parametric == 1 { dim.clamp(0, 3) as usize } else { 0 };
        let mut tags = Vec::with_capacity(lex.capacity(count, 1));
        while tags.len() < count {
            let mut line =
                lex.expect_line(format_args!("node tag {} of {count} in entity block {b}", tags.len() + 1))?;
            while let Some(tag) = line.tok() {
                if tags.len() == count {
                    return Err(tag.unexpected(format_args!("{count} node tags in entity block {b}")));
                }
                tags.push(tag);
            }
        }
        for tag in tags {
            let mut line = lex.expect_line(format_args!("the coordinates of node {}", tag.text))?;
            line.expect_len(values, format_args!("{values} coordinates for node {}", tag.text))?;
            let p = xyz(&mut line, tag.text)?;
            nodes.add(tag, p)?;
        }
    }
    if seen < n {
        return Err(lex.error(lex.last_line(), format!("expected {n} nodes (the section's header), found {seen}")));
    }
    end(lex, "$EndNodes", format_args!("{n} nodes"))?;
    Ok(nodes)
}

/// `$Elements` of 4.1: entity blocks of one element type each, one
/// `tag nodes...` line per element.
fn elements_v41(lex: &mut Lexer, nodes: &Nodes) -> Result<TetList> {
    let (blocks, n) = header_v41(lex, "elements")?;
    let mut tets = TetList::with_capacity(lex.capacity(n, 5));
    let mut seen = 0;
    for b in 1..=blocks {
        let (_, ty, count) = block_v41(lex, b, blocks, &mut seen, n)?;
        let corners = tet_nodes(ty);
        for i in 1..=count {
            let mut line = lex.expect_line(format_args!("element {i} of {count} in entity block {b}"))?;
            let Some(corners) = corners else {
                refuse_volume_element(&line, ty, line.first().text)?;
                continue;
            };
            let id = line.first().text;
            line.expect_len(1 + corners, format_args!("a tag and {corners} node tags for element {id} of type {ty}"))?;
            line.tok();
            let mut tet = [0; 4];
            for v in &mut tet {
                *v = nodes.get(&mut line, id)?;
            }
            tets.push(tet, line.no);
        }
    }
    if seen < n {
        return Err(lex.error(lex.last_line(), format!("expected {n} elements (the section's header), found {seen}")));
    }
    end(lex, "$EndElements", format_args!("{n} elements"))?;
    Ok(tets)
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::{no_panic_on_mutations, parse_err, two_tets};
    use super::*;

    pub(in crate::read) const V22: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n\
        $PhysicalNames\n1\n3 1 \"inside # not a comment\"\n$EndPhysicalNames\n\
        $Nodes\n5\n10 0 0 0\n20 1 0 0\n30 0 1 0\n40 0 0 1\n50 1 1 1\n$EndNodes\n\
        $Elements\n4\n1 15 2 0 1 10\n2 2 2 0 1 10 20 30\n3 4 2 0 1 10 20 30 40\n4 4 3 0 1 2 20 30 40 50\n$EndElements\n";

    pub(in crate::read) const V41: &str = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n\
        $Entities\n0 0 0 1\n1 0 0 0 1 1 1 0 0\n$EndEntities\n\
        $Nodes\n2 5 1 5\n0 1 0 1\n1\n0 0 0\n3 1 1 4\n2 3\n4\n5\n1 0 0 0.5 0.5 0.5\n0 1 0 1 1 1\n0 0 1 2 2 2\n1 1 1 3 3 3\n$EndNodes\n\
        $Elements\n2 3 1 3\n2 1 2 1\n1 1 2 3\n3 1 4 2\n2 1 2 3 4\n3 2 3 4 5\n$EndElements\n";

    #[test]
    fn valid_2_2() {
        assert_eq!(parse_gmsh(V22, "v.msh").unwrap(), two_tets());
    }

    #[test]
    fn other_volume_elements_are_refused() {
        let hexa = V22.replace("3 4 2 0 1 10 20 30 40", "3 5 2 0 1 10 20 30 40 50 10 20 30");
        let (line, m) = parse_err(parse_gmsh(&hexa, "h.msh"));
        assert_eq!(line, 20, "{m}");
        assert!(m.contains("element 3 is of type 5"), "{m}");
    }

    #[test]
    fn valid_4_1() {
        assert_eq!(parse_gmsh(V41, "v.msh").unwrap(), two_tets());
    }

    #[test]
    fn tet10_keeps_the_corners() {
        let text = V22.replace("4 4 3 0 1 2 20 30 40 50", "4 11 2 0 1 20 30 40 50 10 10 10 10 10 10");
        assert_eq!(parse_gmsh(&text, "v.msh").unwrap(), two_tets());
    }

    #[test]
    fn unsupported_versions() {
        let (line, m) = parse_err(parse_gmsh(&V22.replace("2.2 0 8", "4.0 0 8"), "u.msh"));
        assert_eq!(line, 2);
        assert!(m.starts_with("msh version 4.0 is not supported") && m.contains("-format msh22"), "{m}");
        let (line, m) = parse_err(parse_gmsh(&V22.replace("2.2 0 8", "2.2 1 8"), "u.msh"));
        assert_eq!(line, 2);
        assert!(m.starts_with("binary .msh files are not supported"), "{m}");
        let (line, m) = parse_err(parse_gmsh("$NOD\n1\n1 0 0 0\n$ENDNOD\n", "u.msh"));
        assert_eq!(line, 1);
        assert!(m.contains("msh version 1 is not supported"), "{m}");
    }

    #[test]
    fn truncated() {
        let text = &V22[..V22.find("4 4 3").unwrap()];
        let (line, m) = parse_err(parse_gmsh(text, "t.msh"));
        assert_eq!((line, m.as_str()), (20, "expected element 4 of 4, found end of file"));
        let text = &V41[..V41.find("0 0 1 2 2 2").unwrap()];
        let (line, m) = parse_err(parse_gmsh(text, "t.msh"));
        assert_eq!((line, m.as_str()), (18, "expected the coordinates of node 4, found end of file"));
        let (line, m) = parse_err(parse_gmsh("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Comments\nabc\n", "t.msh"));
        assert_eq!((line, m.as_str()), (5, "expected $EndComments, closing $Comments of line 4, found end of file"));
    }

    #[test]
    fn bad_values() {
        let (line, m) = parse_err(parse_gmsh(&V22.replace("40 0 0 1", "40 0 0 inf"), "b.msh"));
        assert_eq!((line, m.as_str()), (13, "expected the z coordinate of node 40 (a finite number), found \"inf\""));
        let (line, m) = parse_err(parse_gmsh(&V22.replace("3 4 2 0 1 10 20 30 40", "3 4 2 0 1 10 20 30"), "b.msh"));
        assert_eq!((line, m.as_str()), (20, "expected 2 tags and 4 node tags for element 3 of type 4, found 5 values"));
        let (line, m) =
            parse_err(parse_gmsh(&V22.replace("4 4 3 0 1 2 20 30 40 50", "4 4 3 0 1 2 20 30 40 60"), "b.msh"));
        assert_eq!((line, m.as_str()), (21, "element 4 refers to node 60, which is not in $Nodes"));
        let (line, m) = parse_err(parse_gmsh(&V22.replace("30 0 1 0", "20 0 1 0"), "b.msh"));
        assert_eq!((line, m.as_str()), (12, "node tag 20 appears twice in $Nodes"));
        let (line, m) = parse_err(parse_gmsh(&V41.replace("3 2 3 4 5", "3 2 3 4 5 6"), "b.msh"));
        assert_eq!((line, m.as_str()), (28, "expected a tag and 4 node tags for element 3 of type 4, found 6 values"));
    }

    #[test]
    fn count_mismatch() {
        let (line, m) = parse_err(parse_gmsh(&V22.replace("$Elements\n4", "$Elements\n3"), "c.msh"));
        assert_eq!((line, m.as_str()), (21, "expected $EndElements after 3 elements, found \"4\""));
        let (line, m) = parse_err(parse_gmsh(&V22.replace("$Nodes\n5", "$Nodes\n6"), "c.msh"));
        assert_eq!((line, m.as_str()), (15, "expected tag x y z for node 6 of 6, found 1 value"));
        let (line, m) = parse_err(parse_gmsh(&V41.replace("2 5 1 5", "2 4 1 5"), "c.msh"));
        assert_eq!((line, m.as_str()), (13, "expected 4 entries in all (the section's header), found more"));
        let (line, m) = parse_err(parse_gmsh(&V41.replace("2 5 1 5", "2 6 1 5"), "c.msh"));
        assert_eq!((line, m.as_str()), (20, "expected 6 nodes (the section's header), found 5"));
    }

    #[test]
    fn missing_sections() {
        let no_elements = &V22[..V22.find("$Elements").unwrap()];
        let (line, m) = parse_err(parse_gmsh(no_elements, "m.msh"));
        assert_eq!((line, m.as_str()), (15, "expected tetrahedra, found none (a surface mesh?)"));
        let no_nodes = V22.replace(&V22[V22.find("$Nodes").unwrap()..V22.find("$Elements").unwrap()], "");
        let (line, m) = parse_err(parse_gmsh(&no_nodes, "m.msh"));
        assert_eq!((line, m.as_str()), (8, "expected $Nodes before $Elements, found \"$Elements\""));
        assert_eq!(parse_err(parse_gmsh("", "m.msh")), (1, "expected $MeshFormat, found end of file".to_string()));
    }

    #[test]
    fn no_input_panics() {
        no_panic_on_mutations(V22, |t| parse_gmsh(t, "f.msh"));
        no_panic_on_mutations(V41, |t| parse_gmsh(t, "f.msh"));
    }
}
