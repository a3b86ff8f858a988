//! `neighbors.csv`: the clipped cells' faces — `site,neighbor,area,nx,ny,nz`,
//! one row per face a cell shares with a neighbour (each shared face
//! appears twice, once from each side, with the same area and opposite
//! normals), and one row per cell with area on the domain's boundary,
//! `neighbor` = -1, its area and the unit direction of its area vector
//! `∫ n dA` (the outward normal where that part of the boundary is flat). Rows by site, neighbours increasing, the
//! boundary last; numbers read back exactly. In a periodic box three more
//! columns, `shift_x,shift_y,shift_z`, give the image of the neighbour the
//! face is shared with (its site plus that many box lengths; see
//! [`Adjacency::shifts`]), and there is no boundary.

use crate::read::write_file;
use cvd::error::Result;
use cvd::passes::faces::Adjacency;
use std::path::Path;

/// The header line.
pub const HEADER: &str = "site,neighbor,area,nx,ny,nz";

/// The columns a periodic box adds.
pub const SHIFT_HEADER: &str = "shift_x,shift_y,shift_z";

/// Writes `adjacency` as `neighbors.csv`.
pub fn write_neighbors_csv(path: &Path, adjacency: &Adjacency) -> Result<()> {
    write_file(path, |w| {
        let periodic = !adjacency.shifts.is_empty();
        if periodic {
            writeln!(w, "{HEADER},{SHIFT_HEADER}")?;
        } else {
            writeln!(w, "{HEADER}")?;
        }
        for i in 0..adjacency.len() {
            for (e, (j, area, n)) in (adjacency.offsets[i]..).zip(adjacency.of(i)) {
                write!(w, "{i},{j},{area:e},{},{},{}", n[0], n[1], n[2])?;
                if periodic {
                    let s = adjacency.shift(e);
                    write!(w, ",{},{},{}", s[0], s[1], s[2])?;
                }
                writeln!(w)?;
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
