//! Triangle surfaces: STL (binary and ASCII, through `stl_io`), OBJ
//! (`tobj`), PLY (binary and ASCII, `ply-rs`) and OFF (read here: a few
//! lines of text no maintained crate covers better than the project's
//! lexer, with its line-numbered errors).
//!
//! Polygons are cut into triangle fans. The crates' errors are reported
//! naming the file; a crate that panics on a hostile file (`ply-rs` does on
//! some malformed headers) is caught and reported the same way, so no file
//! makes the program fail other than with that error.

use super::lex::{Lexer, Tokens};
use cvd::error::{Error, Result};
use cvd::geom::surface::TriSurface;
use std::io::Cursor;
use std::path::Path;

/// Reads a triangle surface, choosing the format by the extension (any
/// case) from [`SURFACES`](super::formats::SURFACES). The surface is not
/// checked: [`TriSurface::into_closed`] does that.
pub fn read_surface(path: &Path) -> Result<TriSurface> {
    use super::formats::{find, unknown, SURFACES};
    match find(SURFACES, path) {
        Some(format) => format.read(path),
        None => {
            // The file is read first, as it always was: a missing file is
            // an I/O error whatever its extension.
            super::read_bytes(path)?;
            Err(unknown(SURFACES, "surface", path))
        }
    }
}

pub(super) fn text<'a>(bytes: &'a [u8], name: &str) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|e| Error::InvalidInput(format!("{name}: not a text file: {e}")))
}

/// Runs a third-party parser, turning its error or its panic into one
/// naming the file and the format.
pub(super) fn guarded<T, E: std::fmt::Display>(
    name: &str,
    format: &str,
    parse: impl FnOnce() -> std::result::Result<T, E>,
) -> Result<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(parse)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(Error::InvalidInput(format!("{name}: not a valid {format} file: {e}"))),
        Err(_) => Err(Error::InvalidInput(format!("{name}: not a valid {format} file (its reader gave up)"))),
    }
}

/// Triangles of a polygon `face` (a fan from its first vertex).
fn fan(face: &[u32], out: &mut Vec<[u32; 3]>) {
    for k in 1..face.len().saturating_sub(1) {
        out.push([face[0], face[k], face[k + 1]]);
    }
}

/// An STL file, binary or ASCII (equal vertices merged).
pub fn parse_stl(bytes: &[u8], name: &str) -> Result<TriSurface> {
    let mesh = guarded(name, "STL", || stl_io::read_stl(&mut Cursor::new(bytes)))?;
    let vertices = mesh.vertices.iter().map(|v| [v[0] as f64, v[1] as f64, v[2] as f64]).collect();
    let triangles = mesh.faces.iter().map(|f| f.vertices.map(|v| v as u32)).collect();
    TriSurface::new(vertices, triangles).map_err(|e| Error::InvalidInput(format!("{name}: {e}")))
}

/// An OBJ file: every object's faces (polygons as fans), positions in f64.
pub fn parse_obj(bytes: &[u8], name: &str) -> Result<TriSurface> {
    let options = tobj::LoadOptions { triangulate: false, single_index: false, ..Default::default() };
    let (models, _) = guarded(name, "OBJ", || {
        tobj::load_obj_buf(&mut Cursor::new(bytes), &options, |_| Err(tobj::LoadError::OpenFileFailed))
    })?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let base = vertices.len() as u32;
        vertices.extend(m.positions.as_chunks::<3>().0.iter().copied());
        let mut start = 0usize;
        let arities: Vec<u32> =
            if m.face_arities.is_empty() { vec![3; m.indices.len() / 3] } else { m.face_arities.clone() };
        for &n in &arities {
            let end = start + n as usize;
            let Some(face) = m.indices.get(start..end) else { break };
            let face: Vec<u32> = face.iter().map(|&v| v + base).collect();
            fan(&face, &mut triangles);
            start = end;
        }
    }
    if vertices.is_empty() {
        return Err(Error::InvalidInput(format!("{name}: the OBJ file has no vertices ('v x y z' lines)")));
    }
    TriSurface::new(vertices, triangles).map_err(|e| Error::InvalidInput(format!("{name}: {e}")))
}

/// A PLY file, binary or ASCII: the `vertex` element's `x`, `y`, `z` and
/// the `face` element's `vertex_indices` (or `vertex_index`) lists.
pub fn parse_ply(bytes: &[u8], name: &str) -> Result<TriSurface> {
    use ply_rs::ply::Property;
    let parser = ply_rs::parser::Parser::<ply_rs::ply::DefaultElement>::new();
    let ply = guarded(name, "PLY", || parser.read_ply(&mut Cursor::new(bytes)))?;
    let number = |p: Option<&Property>| -> Option<f64> {
        match p? {
            Property::Float(x) => Some(*x as f64),
            Property::Double(x) => Some(*x),
            Property::Char(x) => Some(*x as f64),
            Property::UChar(x) => Some(*x as f64),
            Property::Short(x) => Some(*x as f64),
            Property::UShort(x) => Some(*x as f64),
            Property::Int(x) => Some(*x as f64),
            Property::UInt(x) => Some(*x as f64),
            _ => None,
        }
    };
    let list = |p: Option<&Property>| -> Option<Vec<i64>> {
        Some(match p? {
            Property::ListChar(v) => v.iter().map(|&x| x as i64).collect(),
            Property::ListUChar(v) => v.iter().map(|&x| x as i64).collect(),
            Property::ListShort(v) => v.iter().map(|&x| x as i64).collect(),
            Property::ListUShort(v) => v.iter().map(|&x| x as i64).collect(),
            Property::ListInt(v) => v.iter().map(|&x| x as i64).collect(),
            Property::ListUInt(v) => v.iter().map(|&x| x as i64).collect(),
            _ => return None,
        })
    };
    let Some(verts) = ply.payload.get("vertex") else {
        return Err(Error::InvalidInput(format!("{name}: the PLY file has no 'vertex' element")));
    };
    let mut vertices = Vec::with_capacity(verts.len());
    for (i, v) in verts.iter().enumerate() {
        let c = ["x", "y", "z"].map(|k| number(v.get(k)));
        let [Some(x), Some(y), Some(z)] = c else {
            return Err(Error::InvalidInput(format!("{name}: PLY vertex {i} lacks a numeric x, y or z")));
        };
        vertices.push([x, y, z]);
    }
    let mut triangles = Vec::new();
    for (f, face) in ply.payload.get("face").map_or(&[][..], |v| &v[..]).iter().enumerate() {
        let Some(idx) = list(face.get("vertex_indices").or_else(|| face.get("vertex_index"))) else {
            return Err(Error::InvalidInput(format!("{name}: PLY face {f} has no 'vertex_indices' list")));
        };
        if let Some(&bad) = idx.iter().find(|&&v| v < 0 || v >= vertices.len() as i64) {
            return Err(Error::InvalidInput(format!(
                "{name}: PLY face {f} refers to vertex {bad}, but the file has {} vertices",
                vertices.len()
            )));
        }
        let face: Vec<u32> = idx.iter().map(|&v| v as u32).collect();
        fan(&face, &mut triangles);
    }
    TriSurface::new(vertices, triangles).map_err(|e| Error::InvalidInput(format!("{name}: {e}")))
}

/// An OFF file: `OFF`, then `nv nf ne` (on the same line or the next),
/// `nv` lines `x y z` (anything after is ignored: colours), `nf` lines
/// `n i_1 .. i_n` (0-based; polygons as fans; anything after the indices
/// is ignored). `#` starts a comment.
pub fn parse_off(text: &str, path: &str) -> Result<TriSurface> {
    let mut lex = Lexer::new(text, path);
    let mut line = lex.expect_line("the header 'OFF'")?;
    let head = line.expect("the header 'OFF'")?;
    if !head.is("OFF") {
        return Err(head.unexpected("the header 'OFF'"));
    }
    if line.len() == 1 {
        line = lex.expect_line("the counts 'vertices faces edges'")?;
    }
    let nv = line.count("the number of vertices")?;
    let nf = line.count("the number of faces")?;
    let mut vertices = Vec::with_capacity(lex.capacity(nv, 3));
    for i in 1..=nv {
        let mut line = lex.expect_line(format_args!("vertex {i} of {nv} (x y z)"))?;
        let mut p = [0.0; 3];
        for (c, axis) in p.iter_mut().zip(["x", "y", "z"]) {
            *c = line.f64(format_args!("the {axis} coordinate of vertex {i} of {nv}"))?;
        }
        vertices.push(p);
    }
    let mut triangles = Vec::with_capacity(lex.capacity(nf, 4));
    let mut face = Vec::new();
    for f in 1..=nf {
        let mut line = lex.expect_line(format_args!("face {f} of {nf} (n i_1 .. i_n)"))?;
        let n = line.count(format_args!("the vertex count of face {f} of {nf}"))?;
        if n < 3 {
            return Err(line.error(format!("face {f} of {nf} has {n} vertices; a face needs at least 3")));
        }
        face.clear();
        for k in 1..=n {
            let v = line.index(format_args!("vertex {k} of face {f} of {nf}"), 0)?;
            if v as usize >= nv {
                return Err(line.error(format!("face {f} refers to vertex {v}, but the file has {nv} vertices")));
            }
            face.push(v);
        }
        fan(&face, &mut triangles);
    }
    lex.expect_end(format_args!("{nv} vertices and {nf} faces"))?;
    TriSurface::new(vertices, triangles)
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::no_panic_on_mutations;
    use super::*;
    use cvd::geom::surface::TriSurface;

    fn unit_box() -> TriSurface {
        TriSurface::cuboid([0.0; 3], [1.0, 2.0, 3.0])
    }

    pub(in crate::read) fn as_off(s: &TriSurface) -> String {
        let mut t = format!("OFF\n{} {} 0\n", s.vertices.len(), s.triangles.len());
        for v in &s.vertices {
            t += &format!("{} {} {}\n", v[0], v[1], v[2]);
        }
        for f in &s.triangles {
            t += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
        }
        t
    }

    pub(in crate::read) fn as_obj(s: &TriSurface) -> String {
        let mut t = String::from("# a box\no box\n");
        for v in &s.vertices {
            t += &format!("v {} {} {}\n", v[0], v[1], v[2]);
        }
        for f in &s.triangles {
            t += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
        }
        t
    }

    pub(in crate::read) fn as_ply_ascii(s: &TriSurface) -> String {
        let mut t = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            s.vertices.len(),
            s.triangles.len()
        );
        for v in &s.vertices {
            t += &format!("{} {} {}\n", v[0], v[1], v[2]);
        }
        for f in &s.triangles {
            t += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
        }
        t
    }

    pub(in crate::read) fn as_ply_binary(s: &TriSurface) -> Vec<u8> {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
             property float z\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
            s.vertices.len(),
            s.triangles.len()
        )
        .into_bytes();
        for v in &s.vertices {
            for c in v {
                b.extend((*c as f32).to_le_bytes());
            }
        }
        for f in &s.triangles {
            b.push(3);
            for i in f {
                b.extend(i.to_le_bytes());
            }
        }
        b
    }

    pub(in crate::read) fn as_stl(s: &TriSurface, binary: bool) -> Vec<u8> {
        let tris: Vec<stl_io::Triangle> = s
            .triangles
            .iter()
            .map(|t| {
                let v = t.map(|i| s.vertices[i as usize].map(|c| c as f32));
                stl_io::Triangle { normal: stl_io::Normal::new([0.0; 3]), vertices: v.map(stl_io::Vertex::new) }
            })
            .collect();
        if binary {
            let mut out = Vec::new();
            stl_io::write_stl(&mut out, tris.iter()).unwrap();
            out
        } else {
            let mut t = String::from("solid box\n");
            for tri in &tris {
                t += "  facet normal 0 0 0\n    outer loop\n";
                for v in &tri.vertices {
                    t += &format!("      vertex {} {} {}\n", v[0], v[1], v[2]);
                }
                t += "    endloop\n  endfacet\n";
            }
            (t + "endsolid box\n").into_bytes()
        }
    }

    /// The same closed box from every format, with its volume.
    #[test]
    fn every_format_reads_the_same_box() {
        let s = unit_box();
        let files: Vec<(&str, Result<TriSurface>)> = vec![
            ("off", parse_off(&as_off(&s), "box.off")),
            ("obj", parse_obj(as_obj(&s).as_bytes(), "box.obj")),
            ("ply ascii", parse_ply(as_ply_ascii(&s).as_bytes(), "box.ply")),
            ("ply binary", parse_ply(&as_ply_binary(&s), "box.ply")),
            ("stl ascii", parse_stl(&as_stl(&s, false), "box.stl")),
            ("stl binary", parse_stl(&as_stl(&s, true), "box.stl")),
        ];
        for (what, read) in files {
            let read = read.unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!(read.triangles.len(), 12, "{what}");
            assert_eq!(read.vertices.len(), 8, "{what}: equal vertices are one");
            let (closed, report) = read.into_closed(what).unwrap();
            assert!((report.volume - 6.0).abs() < 1e-12, "{what}: {}", report.volume);
            assert!((closed.area() - 22.0).abs() < 1e-12, "{what}");
        }
    }

    #[test]
    fn bad_files_are_named_errors() {
        let s = unit_box();
        let stl = as_stl(&s, true);
        for cut in [0, 10, 84, 84 + 50, stl.len() - 1] {
            let e = parse_stl(&stl[..cut], "cut.stl");
            if let Err(e) = &e {
                assert!(e.to_string().contains("cut.stl"), "{e}");
            }
            // A cut that still holds whole triangles may read as fewer.
            if let Ok(m) = e {
                assert!(m.triangles.len() < 12, "cut at {cut}");
            }
        }
        let e = parse_off("", "empty.off").unwrap_err().to_string();
        assert!(e.contains("empty.off") && e.contains("OFF"), "{e}");
        let e = parse_off("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "bad.off").unwrap_err().to_string();
        assert!(e.contains("bad.off:6") && e.contains("vertex 7"), "{e}");
        let e = parse_ply(b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n", "x.ply").unwrap_err();
        assert!(e.to_string().contains("x.ply"), "{e}");
        let e = parse_obj(b"garbage\n", "x.obj").unwrap_err().to_string();
        assert!(e.contains("x.obj"), "{e}");
    }

    #[test]
    fn no_reader_panics_on_mutated_files() {
        let s = unit_box();
        no_panic_on_mutations(&as_off(&s), |t| parse_off(t, "m.off"));
        no_panic_on_mutations(&as_obj(&s), |t| parse_obj(t.as_bytes(), "m.obj"));
        no_panic_on_mutations(&as_ply_ascii(&s), |t| parse_ply(t.as_bytes(), "m.ply"));
        let stl = String::from_utf8(as_stl(&s, false)).unwrap();
        no_panic_on_mutations(&stl, |t| parse_stl(t.as_bytes(), "m.stl"));
        let bin = as_ply_binary(&s);
        for cut in 0..bin.len() {
            let _ = parse_ply(&bin[..cut], "cut.ply");
        }
    }
}
