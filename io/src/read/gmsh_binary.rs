//! Gmsh `.msh` binary files, versions 2.2 and 4.1 (file type 1 in
//! `$MeshFormat`), in the byte order the file's check integer shows.
//!
//! As for ASCII files: 4-node tets are kept, and the corners of 10-node
//! tets; elements of lower dimension are skipped; other volume elements
//! are an error naming how many, so no part of a domain is lost silently.
//! Sections other than `$MeshFormat`, `$Nodes` and `$Elements` are skipped
//! up to their `$End` line.
//!
//! Read here rather than through a crate: the Rust crate for these files
//! (`mshio` 0.4, last released in 2020) reads version 4.1 only, not the
//! 2.2 that meshio, older Gmsh and many pipelines still write, and does not
//! check that elements refer to nodes that exist.

use super::binary::ByteReader;
use super::gmsh::element_kind;
use cvd::error::{Error, Result};
use cvd::geom::mesh::TetMesh;
use std::collections::HashMap;

impl ByteReader<'_> {
    /// A count that the rest of the file could hold at `bytes` each.
    fn count(&mut self, size: usize, bytes: usize, what: &str) -> Result<usize> {
        let n = self.int(size, what)?;
        if n < 0 || n as usize > (self.bytes.len() - self.pos) / bytes.max(1) {
            return Err(self.error(format!("{what} {n} does not fit in the rest of the file")));
        }
        Ok(n as usize)
    }

    /// Skips to just after the line `end`.
    fn skip_to(&mut self, end: &str) -> Result<()> {
        let needle = format!("\n{end}");
        let rest = &self.bytes[self.pos.saturating_sub(1)..];
        match rest.windows(needle.len()).position(|w| w == needle.as_bytes()) {
            Some(i) => {
                self.pos = self.pos.saturating_sub(1) + i + needle.len();
                self.line();
                Ok(())
            }
            None => Err(self.error(format!("expected {end}, found the end of the file"))),
        }
    }
}

/// Whether `bytes` is a binary `.msh` file (its `$MeshFormat` says file type 1).
pub fn is_binary_gmsh(bytes: &[u8]) -> bool {
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(64)]).into_owned();
    let mut lines = head.lines();
    lines.next().map(str::trim) == Some("$MeshFormat")
        && lines.next().and_then(|l| l.split_ascii_whitespace().nth(1)) == Some("1")
}

/// A binary Gmsh `.msh` file, version 2.2 or 4.1.
pub fn parse_gmsh_binary(bytes: &[u8], name: &str) -> Result<TetMesh> {
    let mut r = ByteReader::new(bytes, name);
    r.line();
    let format = r.line().unwrap_or("");
    let words: Vec<&str> = format.split_ascii_whitespace().collect();
    let v41 = match words.first().copied() {
        Some("4.1") => true,
        Some(v) if v.starts_with("2.") => false,
        other => {
            return Err(r.error(format!(
                "msh version {} is not supported in binary (2.2 and 4.1 are)",
                other.unwrap_or("(none)")
            )))
        }
    };
    let size_t = match words.get(2).and_then(|w| w.parse::<usize>().ok()) {
        Some(s @ (4 | 8)) => s,
        _ => return Err(r.error("expected a data size of 4 or 8 in $MeshFormat")),
    };
    r.byte_order("the byte-order check integer")?;
    r.skip_to("$EndMeshFormat")?;
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut index: HashMap<i64, u32> = HashMap::new();
    let mut tets: Vec<[u32; 4]> = Vec::new();
    let mut others = 0usize;
    let mut seen_elements = false;
    while let Some(line) = r.line() {
        match line {
            "" => {}
            "$Nodes" => {
                let mut add = |r: &ByteReader, tag: i64, p: [f64; 3]| -> Result<()> {
                    let i = u32::try_from(vertices.len()).map_err(|_| r.error("more than 2^32 nodes"))?;
                    if index.insert(tag, i).is_some() {
                        return Err(r.error(format!("node tag {tag} appears twice")));
                    }
                    vertices.push(p);
                    Ok(())
                };
                if v41 {
                    let blocks = r.count(size_t, 16, "the number of node blocks")?;
                    for _ in 0..4 - 1 {
                        r.int(size_t, "the node counts")?;
                    }
                    for _ in 0..blocks {
                        r.int(4, "a block's entity dimension")?;
                        r.int(4, "a block's entity tag")?;
                        let parametric = r.int(4, "a block's parametric flag")?;
                        if parametric != 0 {
                            return Err(r.error("parametric node coordinates are not supported"));
                        }
                        let n = r.count(size_t, size_t + 24, "a block's node count")?;
                        let mut tags = Vec::with_capacity(n);
                        for _ in 0..n {
                            tags.push(r.int(size_t, "a node tag")?);
                        }
                        for tag in tags {
                            let p =
                                [r.real(8, "a coordinate")?, r.real(8, "a coordinate")?, r.real(8, "a coordinate")?];
                            add(&r, tag, p)?;
                        }
                    }
                } else {
                    let n: usize =
                        r.line().and_then(|l| l.parse().ok()).ok_or_else(|| r.error("expected the node count"))?;
                    if n > bytes.len() / 28 {
                        return Err(r.error(format!("{n} nodes do not fit in the file")));
                    }
                    for _ in 0..n {
                        let tag = r.int(4, "a node tag")?;
                        let p = [r.real(8, "a coordinate")?, r.real(8, "a coordinate")?, r.real(8, "a coordinate")?];
                        add(&r, tag, p)?;
                    }
                }
                r.skip_to("$EndNodes")?;
            }
            "$Elements" => {
                seen_elements = true;
                let mut keep = |r: &ByteReader, kind: i64, nodes: &[i64]| -> Result<()> {
                    let Some((_, dim)) = element_kind(kind) else {
                        return Err(r.error(format!("unknown element type {kind}")));
                    };
                    if kind == 4 || kind == 11 {
                        let mut tet = [0u32; 4];
                        for (c, tag) in tet.iter_mut().zip(nodes) {
                            *c = *index.get(tag).ok_or_else(|| {
                                r.error(format!("an element refers to node {tag}, which is not in $Nodes"))
                            })?;
                        }
                        tets.push(tet);
                    } else if dim == 3 {
                        others += 1;
                    }
                    Ok(())
                };
                if v41 {
                    let blocks = r.count(size_t, 16, "the number of element blocks")?;
                    for _ in 0..3 {
                        r.int(size_t, "the element counts")?;
                    }
                    for _ in 0..blocks {
                        r.int(4, "a block's entity dimension")?;
                        r.int(4, "a block's entity tag")?;
                        let kind = r.int(4, "a block's element type")?;
                        let Some((per, _)) = element_kind(kind) else {
                            return Err(r.error(format!("unknown element type {kind}")));
                        };
                        let n = r.count(size_t, size_t * (per + 1), "a block's element count")?;
                        let mut nodes = vec![0i64; per];
                        for _ in 0..n {
                            r.int(size_t, "an element tag")?;
                            for v in nodes.iter_mut() {
                                *v = r.int(size_t, "an element's node")?;
                            }
                            keep(&r, kind, &nodes)?;
                        }
                    }
                } else {
                    let total: usize =
                        r.line().and_then(|l| l.parse().ok()).ok_or_else(|| r.error("expected the element count"))?;
                    if total > bytes.len() / 8 {
                        return Err(r.error(format!("{total} elements do not fit in the file")));
                    }
                    let mut done = 0;
                    while done < total {
                        let kind = r.int(4, "an element block's type")?;
                        let n = r.count(4, 8, "an element block's count")?;
                        let tags = r.count(4, 4, "an element block's tag count")?;
                        let Some((per, _)) = element_kind(kind) else {
                            return Err(r.error(format!("unknown element type {kind}")));
                        };
                        let mut nodes = vec![0i64; per];
                        for _ in 0..n {
                            r.int(4, "an element number")?;
                            for _ in 0..tags {
                                r.int(4, "an element tag")?;
                            }
                            for v in nodes.iter_mut() {
                                *v = r.int(4, "an element's node")?;
                            }
                            keep(&r, kind, &nodes)?;
                        }
                        done += n.max(1);
                    }
                }
                r.skip_to("$EndElements")?;
            }
            section if section.starts_with('$') && !section.starts_with("$End") => {
                r.skip_to(&format!("$End{}", &section[1..]))?;
            }
            other => {
                return Err(r.error(format!(
                    "expected a section ($Nodes, $Elements, ...), found \"{}\"",
                    super::lex::shown(other)
                )))
            }
        }
    }
    if !seen_elements {
        return Err(Error::InvalidInput(format!("{name}: no $Elements section")));
    }
    if others > 0 {
        return Err(Error::InvalidInput(format!(
            "{name}: only tetrahedra are supported as volume elements; the file also has {others} others (hexahedra, prisms, pyramids or higher-order ones)"
        )));
    }
    TetMesh::new(vertices, tets).map_err(|e| Error::InvalidInput(format!("{name}: {e}")))
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// Two tets (and a triangle) as a binary msh 2.2 file, little-endian.
    pub(in crate::read) fn two_tets() -> Vec<u8> {
        let mut b = b"$MeshFormat\n2.2 1 8\n".to_vec();
        b.extend(1i32.to_le_bytes());
        b.extend(b"\n$EndMeshFormat\n$Nodes\n5\n");
        for (tag, p) in
            [[0.0f64, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]].iter().enumerate()
        {
            b.extend((tag as i32 + 1).to_le_bytes());
            p.iter().for_each(|c| b.extend(c.to_le_bytes()));
        }
        b.extend(b"\n$EndNodes\n$Elements\n3\n");
        // A block of two tets with 2 tags each, then one triangle.
        for x in [4i32, 2, 2] {
            b.extend(x.to_le_bytes());
        }
        for (id, nodes) in [(1i32, [1i32, 2, 3, 4]), (2, [2, 3, 4, 5])] {
            b.extend(id.to_le_bytes());
            b.extend(0i32.to_le_bytes());
            b.extend(7i32.to_le_bytes());
            nodes.iter().for_each(|v| b.extend(v.to_le_bytes()));
        }
        for x in [2i32, 1, 0, 3, 2, 3, 4] {
            b.extend(x.to_le_bytes());
        }
        b.extend(b"\n$EndElements\n");
        b
    }

    #[test]
    fn a_binary_22_file_reads() {
        let b = two_tets();
        assert!(is_binary_gmsh(&b));
        let mesh = parse_gmsh_binary(&b, "two.msh").unwrap();
        assert_eq!(mesh.tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]]);
        assert!((mesh.volume() - 0.5).abs() < 1e-12);
    }

    #[test]
    fn no_binary_msh_makes_the_reader_panic() {
        let b = two_tets();
        for cut in 0..b.len() {
            let _ = parse_gmsh_binary(&b[..cut], "cut.msh");
        }
        for i in 0..b.len() {
            for x in [0u8, 1, b'\n', b'$', 0x7f, 0xff] {
                let mut m = b.clone();
                m[i] = x;
                let _ = parse_gmsh_binary(&m, "flip.msh");
            }
        }
    }
}
