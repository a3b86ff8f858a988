//! `walls.ply`: every wall of the diagram once, as a binary
//! (little-endian) PLY polygon mesh for rendering and printing: the faces
//! two cells share (written from the cell of the lower site) and the
//! cells' faces on the domain's boundary. Each face carries `site` and
//! `neighbor` (the other cell, or -1 on the boundary). A wall's points are
//! its cell's: walls of different cells do not share points.

use cvd::error::{Error, Result};
use cvd::passes::polyhedra::CellPolyhedron;
use std::io::Write;
use std::path::Path;

/// Writes the walls of `polyhedra` to `path`; returns how many.
pub fn write_walls_ply(path: &Path, polyhedra: &[CellPolyhedron]) -> Result<usize> {
    // Per cell: the faces it writes, and the points they use, renumbered.
    let mut points: Vec<[f64; 3]> = Vec::new();
    let mut faces: Vec<(Vec<u32>, i32, i32)> = Vec::new();
    for cell in polyhedra {
        let mut number = vec![u32::MAX; cell.vertices.len()];
        for (face, &j) in cell.faces().zip(&cell.face_neighbors) {
            let mine = j == -1 || (j >= 0 && (cell.site as i64) < j);
            if !mine {
                continue;
            }
            let ring: Vec<u32> = face
                .iter()
                .map(|&v| {
                    let v = v as usize;
                    if number[v] == u32::MAX {
                        number[v] = points.len() as u32;
                        points.push(cell.vertices[v]);
                    }
                    number[v]
                })
                .collect();
            // A PLY list counts in a byte here: longer loops as fans.
            if ring.len() <= 255 {
                faces.push((ring, cell.site as i32, j as i32));
            } else {
                for k in (1..ring.len() - 1).step_by(253) {
                    let end = (k + 254).min(ring.len());
                    let mut part = vec![ring[0]];
                    part.extend_from_slice(&ring[k..end]);
                    faces.push((part, cell.site as i32, j as i32));
                }
            }
        }
    }
    let io = |source| Error::Write { path: path.display().to_string(), source };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
    let mut body = || -> std::io::Result<()> {
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment cvd: the walls of a clipped Voronoi diagram\n\
             element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             element face {}\nproperty list uchar int vertex_indices\nproperty int site\nproperty int neighbor\n\
             end_header\n",
            points.len(),
            faces.len()
        )?;
        for p in &points {
            for c in p {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        for (ring, a, b) in &faces {
            w.write_all(&[ring.len() as u8])?;
            for v in ring {
                w.write_all(&(*v as i32).to_le_bytes())?;
            }
            w.write_all(&a.to_le_bytes())?;
            w.write_all(&b.to_le_bytes())?;
        }
        w.flush()
    };
    body().map_err(io)?;
    Ok(faces.len())
}
