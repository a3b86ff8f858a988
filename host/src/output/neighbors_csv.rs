//! `neighbors.csv`: the clipped cells' faces — `site,neighbor,area,nx,ny,nz`,
//! one row per face a cell shares with a neighbour (each shared face
//! appears twice, once from each side, with the same area and opposite
//! normals), and one row per cell with area on the domain's boundary,
//! `neighbor` = -1 and no normal. Rows by site, neighbours increasing, the
//! boundary last; numbers read back exactly.

use crate::error::Result;
use crate::faces::Adjacency;
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
            let b = adjacency.boundary[i];
            if b > 0.0 {
                writeln!(w, "{i},-1,{b:e},,,")?;
            }
        }
        Ok(())
    })
}
