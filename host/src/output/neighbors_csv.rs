//! `neighbors.csv`: the clipped cells' faces — `site,neighbor,area,nx,ny,nz`,
//! one row per face a cell shares with a neighbour (each shared face
//! appears twice, once from each side, with the same area and opposite
//! normals), and one row per cell with area on the domain's boundary,
//! `neighbor` = -1, its area and the unit direction of its area vector
//! `∫ n dA` (the outward normal where that part of the boundary is flat). Rows by site, neighbours increasing, the
//! boundary last; numbers read back exactly.

use crate::diagram::faces::Adjacency;
use crate::error::Result;
use crate::io::write_file;
use std::path::Path;

/// The header line.
pub const HEADER: &str = "site,neighbor,area,nx,ny,nz";

/// Writes `adjacency` as `neighbors.csv`.
pub fn write_neighbors_csv(path: &Path, adjacency: &Adjacency) -> Result<()> {
    write_file(path, |w| {
        writeln!(w, "{HEADER}")?;
        for i in 0..adjacency.len() {
            for (j, area, n) in adjacency.of(i) {
                writeln!(w, "{i},{j},{area:e},{},{},{}", n[0], n[1], n[2])?;
            }
            let (b, v) = (adjacency.boundary[i], adjacency.boundary_vector[i]);
            if b > 0.0 {
                // The boundary part's mean outward normal, made unit.
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                let n = if len > 0.0 { v.map(|c| c / len) } else { [0.0; 3] };
                writeln!(w, "{i},-1,{b:e},{},{},{}", n[0], n[1], n[2])?;
            }
        }
        Ok(())
    })
}
