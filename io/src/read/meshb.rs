//! Medit binary meshes (`.meshb`, libMeshb versions 1 to 4): a header
//! (the integer 1, to tell the byte order, and the version), then
//! keywords, each with the file position of the next one. Version 1 stores
//! reals in f32, the others in f64; versions 1 to 3 store integers in 32
//! bits, version 4 in 64; positions take 32 bits up to version 2, 64
//! after. Vertices (keyword 4) and tetrahedra (keyword 8) make the mesh;
//! keywords of lower dimension are skipped; hexahedra, prisms and pyramids
//! are an error naming how many, so no part of a domain is lost silently.
//!
//! Read here: there is no Rust crate for libMeshb files on crates.io.

use super::binary::ByteReader;
use cvd::error::{Error, Result};
use cvd::geom::mesh::TetMesh;

const DIMENSION: u32 = 3;
const VERTICES: u32 = 4;
const TETRAHEDRA: u32 = 8;
const HEXAHEDRA: u32 = 10;
const PRISMS: u32 = 13;
const PYRAMIDS: u32 = 49;
const END: u32 = 54;

/// A `.meshb` file.
pub fn parse_meshb(bytes: &[u8], name: &str) -> Result<TetMesh> {
    let mut r = ByteReader::new(bytes, name);
    r.byte_order("the first integer (1) of a Medit binary file")?;
    let version = r.int(4, "the version")?;
    if !(1..=4).contains(&version) {
        return Err(r.error(format!("unsupported Medit binary version {version} (1 to 4 are)")));
    }
    let int = |r: &mut ByteReader, what: &str| r.int(if version >= 4 { 8 } else { 4 }, what);
    let real = |r: &mut ByteReader, what: &str| r.real(if version >= 2 { 8 } else { 4 }, what);
    let mut dimension = 3;
    let mut vertices: Option<Vec<[f64; 3]>> = None;
    let mut tets: Vec<[u32; 4]> = Vec::new();
    let mut others: Vec<(&str, i64)> = Vec::new();
    while r.pos < bytes.len() {
        let keyword = r.int(4, "a keyword")? as u32;
        if keyword == END {
            break;
        }
        let next = r.int(if version >= 3 { 8 } else { 4 }, "the next keyword's position")?;
        match keyword {
            DIMENSION => dimension = r.int(4, "the dimension")?,
            VERTICES | TETRAHEDRA | HEXAHEDRA | PRISMS | PYRAMIDS => {
                let count = int(&mut r, "a count")?;
                // Each entry takes at least 8 bytes: a count beyond what
                // the file holds is an error before any memory is taken.
                if count < 0 || count as usize > bytes.len() / 8 {
                    return Err(r.error(format!("a count of {count} entries does not fit in the file")));
                }
                let count = count as usize;
                match keyword {
                    VERTICES => {
                        if dimension != 3 {
                            return Err(r.error(format!("dimension {dimension}: only 3D meshes hold tets")));
                        }
                        let mut v = Vec::with_capacity(count);
                        for i in 0..count {
                            let what = format!("vertex {} of {count}", i + 1);
                            let p = [real(&mut r, &what)?, real(&mut r, &what)?, real(&mut r, &what)?];
                            int(&mut r, &what)?;
                            v.push(p);
                        }
                        vertices = Some(v);
                    }
                    TETRAHEDRA => {
                        tets.reserve(count);
                        for t in 0..count {
                            let what = format!("tetrahedron {} of {count}", t + 1);
                            let mut tet = [0u32; 4];
                            for c in &mut tet {
                                let v = int(&mut r, &what)?;
                                if v < 1 || v > u32::MAX as i64 {
                                    return Err(r.error(format!("{what} has vertex number {v}")));
                                }
                                *c = (v - 1) as u32;
                            }
                            int(&mut r, &what)?;
                            tets.push(tet);
                        }
                    }
                    HEXAHEDRA => others.push(("hexahedra", count as i64)),
                    PRISMS => others.push(("prisms", count as i64)),
                    _ => others.push(("pyramids", count as i64)),
                }
            }
            _ => {}
        }
        if next <= 0 {
            break;
        }
        if next as usize > bytes.len() || (next as usize) < r.pos {
            return Err(r.error(format!("keyword {keyword} points to position {next}, outside the file")));
        }
        r.pos = next as usize;
    }
    if let Some((kind, n)) = others.iter().find(|(_, n)| *n > 0) {
        return Err(Error::InvalidInput(format!(
            "{name}: only tetrahedra are supported as volume cells; the file also has {n} {kind}"
        )));
    }
    let Some(vertices) = vertices else {
        return Err(Error::InvalidInput(format!("{name}: no Vertices keyword")));
    };
    if let Some((t, tet)) = tets.iter().enumerate().find(|(_, t)| t.iter().any(|&v| v as usize >= vertices.len())) {
        return Err(Error::InvalidInput(format!(
            "{name}: tetrahedron {} refers to vertex {} of {}",
            t + 1,
            tet.iter().max().map_or(0, |&v| v as u64 + 1),
            vertices.len()
        )));
    }
    TetMesh::new(vertices, tets).map_err(|e| Error::InvalidInput(format!("{name}: {e}")))
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// Two tets in version `version`, little-endian.
    pub(in crate::read) fn two_tets(version: i32) -> Vec<u8> {
        let mut b = Vec::new();
        let int = |b: &mut Vec<u8>, x: i64| {
            if version >= 4 {
                b.extend(x.to_le_bytes())
            } else {
                b.extend((x as i32).to_le_bytes())
            }
        };
        let pos = |b: &mut Vec<u8>, x: usize| {
            if version >= 3 {
                b.extend((x as i64).to_le_bytes())
            } else {
                b.extend((x as i32).to_le_bytes())
            }
        };
        b.extend(1i32.to_le_bytes());
        b.extend(version.to_le_bytes());
        // Positions are patched once the sizes are known.
        let pw = if version >= 3 { 8 } else { 4 };
        b.extend(3i32.to_le_bytes());
        pos(&mut b, 4 + 4 + 4 + pw + 4);
        b.extend(3i32.to_le_bytes());
        b.extend(4i32.to_le_bytes());
        let patch = b.len();
        pos(&mut b, 0);
        int(&mut b, 5);
        for p in [[0.0f64, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]] {
            for c in p {
                if version >= 2 {
                    b.extend(c.to_le_bytes())
                } else {
                    b.extend((c as f32).to_le_bytes())
                }
            }
            int(&mut b, 0);
        }
        let here = b.len();
        b[patch..patch + pw].copy_from_slice(&(here as i64).to_le_bytes()[..pw]);
        b.extend(8i32.to_le_bytes());
        let patch = b.len();
        pos(&mut b, 0);
        int(&mut b, 2);
        for t in [[1, 2, 3, 4], [2, 3, 4, 5]] {
            for v in t {
                int(&mut b, v);
            }
            int(&mut b, 1);
        }
        let here = b.len();
        b[patch..patch + pw].copy_from_slice(&(here as i64).to_le_bytes()[..pw]);
        b.extend(54i32.to_le_bytes());
        b
    }

    #[test]
    fn every_version_reads() {
        for version in 1..=4 {
            let mesh = parse_meshb(&two_tets(version), "two.meshb").unwrap_or_else(|e| panic!("v{version}: {e}"));
            assert_eq!(mesh.tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]], "v{version}");
            assert!((mesh.volume() - 0.5).abs() < 1e-12, "v{version}");
        }
    }

    #[test]
    fn no_meshb_file_makes_the_reader_panic() {
        for version in 1..=4 {
            let b = two_tets(version);
            for cut in 0..b.len() {
                let _ = parse_meshb(&b[..cut], "cut.meshb");
            }
            for i in 0..b.len() {
                for x in [0u8, 1, 0x7f, 0xff] {
                    let mut m = b.clone();
                    m[i] = x;
                    let _ = parse_meshb(&m, "flip.meshb");
                }
            }
        }
        let e = parse_meshb(b"\x02\0\0\0\x02\0\0\0", "x.meshb").unwrap_err().to_string();
        assert!(e.contains("x.meshb") && e.contains("of a Medit binary file is not 1"), "{e}");
    }
}
