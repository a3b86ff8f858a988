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

/// The walls of some cells, as `walls.ply` holds them: the points, and
/// each face's loop of point numbers with its site and neighbour.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Walls {
    /// The walls' points (a cell's own: walls of different cells share none).
    pub points: Vec<[f64; 3]>,
    /// Each wall: its loop (numbers into `points`), its cell's site and the
    /// other side's (-1 on the boundary).
    pub faces: Vec<(Vec<u32>, i32, i32)>,
}

impl Walls {
    /// The walls `polyhedra` write: each face two cells share from the cell
    /// of the lower site, and every face on the boundary.
    pub fn of(polyhedra: &[CellPolyhedron]) -> Self {
        let mut walls = Self::default();
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
                            number[v] = walls.points.len() as u32;
                            walls.points.push(cell.vertices[v]);
                        }
                        number[v]
                    })
                    .collect();
                // A PLY list counts in a byte here: longer loops as fans.
                if ring.len() <= 255 {
                    walls.faces.push((ring, cell.site as i32, j as i32));
                } else {
                    for k in (1..ring.len() - 1).step_by(253) {
                        let end = (k + 254).min(ring.len());
                        let mut part = vec![ring[0]];
                        part.extend_from_slice(&ring[k..end]);
                        walls.faces.push((part, cell.site as i32, j as i32));
                    }
                }
            }
        }
        walls
    }

    /// The file's header, for `points` points and `faces` faces in all.
    pub fn header(points: u64, faces: u64) -> String {
        format!(
            "ply\nformat binary_little_endian 1.0\ncomment cvd: the walls of a clipped Voronoi diagram\n\
             element vertex {points}\nproperty double x\nproperty double y\nproperty double z\n\
             element face {faces}\nproperty list uchar int vertex_indices\nproperty int site\nproperty int neighbor\n\
             end_header\n"
        )
    }

    /// The points' records.
    pub fn write_points(&self, w: &mut dyn Write) -> std::io::Result<()> {
        for p in &self.points {
            for c in p {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        Ok(())
    }

    /// The faces' records, their point numbers from `first` (the points of
    /// the walls written before these: a part of a file written in parts).
    pub fn write_faces(&self, w: &mut dyn Write, first: u64) -> std::io::Result<()> {
        for (ring, a, b) in &self.faces {
            w.write_all(&[ring.len() as u8])?;
            for v in ring {
                w.write_all(&((first + *v as u64) as i32).to_le_bytes())?;
            }
            w.write_all(&a.to_le_bytes())?;
            w.write_all(&b.to_le_bytes())?;
        }
        Ok(())
    }
}

/// Writes the walls of `polyhedra` to `path`; returns how many.
pub fn write_walls_ply(path: &Path, polyhedra: &[CellPolyhedron]) -> Result<usize> {
    let walls = Walls::of(polyhedra);
    let io = |source| Error::Write { path: path.display().to_string(), source };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
    let mut body = || -> std::io::Result<()> {
        w.write_all(Walls::header(walls.points.len() as u64, walls.faces.len() as u64).as_bytes())?;
        walls.write_points(&mut w)?;
        walls.write_faces(&mut w, 0)?;
        w.flush()
    };
    body().map_err(io)?;
    Ok(walls.faces.len())
}
