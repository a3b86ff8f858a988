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

use crate::numbers::{Dec, Exp};
use crate::read::{write_file, write_rows, Rows};
use cvd::error::Result;
use cvd::passes::faces::Adjacency;
use std::io::Write;
use std::path::Path;

/// The header line.
pub const HEADER: &str = "site,neighbor,area,nx,ny,nz";

/// The columns a periodic box adds.
pub const SHIFT_HEADER: &str = "shift_x,shift_y,shift_z";

/// Writes `adjacency` as `neighbors.csv`.
pub fn write_neighbors_csv(path: &Path, adjacency: &Adjacency) -> Result<()> {
    write_file(path, |w| write_neighbors_csv_rows(w, adjacency, Rows::whole(adjacency.len())))
}

/// Writes the rows of `neighbors.csv` of the cells `adjacency` holds (a
/// part of a run in parts: its sites from `rows.first`, the header with the
/// first part's).
pub fn write_neighbors_csv_rows(w: &mut dyn Write, adjacency: &Adjacency, rows: Rows) -> std::io::Result<()> {
    let periodic = !adjacency.shifts.is_empty() || rows.periodic;
    if rows.first == 0 {
        if periodic {
            writeln!(w, "{HEADER},{SHIFT_HEADER}")?;
        } else {
            writeln!(w, "{HEADER}")?;
        }
    }
    write_rows(w, adjacency.len(), |i, t| {
        let site = rows.first + i as u64;
        for (e, (j, area, n)) in (adjacency.offsets[i]..).zip(adjacency.of(i)) {
            write!(t, "{site},{j},{},{},{},{}", Exp(area), Dec(n[0]), Dec(n[1]), Dec(n[2]))?;
            if periodic {
                let s = adjacency.shift(e);
                write!(t, ",{},{},{}", s[0], s[1], s[2])?;
            }
            writeln!(t)?;
        }
        let (b, v) = (adjacency.boundary[i], adjacency.boundary_vector[i]);
        if b > 0.0 {
            // The boundary part's mean outward normal, made unit.
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let n = if len > 0.0 { v.map(|c| c / len) } else { [0.0; 3] };
            writeln!(t, "{site},-1,{},{},{},{}", Exp(b), Dec(n[0]), Dec(n[1]), Dec(n[2]))?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn temp_path(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("cvd-io-write-{}-{name}", std::process::id()))
    }

    fn written(adjacency: &Adjacency, name: &str) -> String {
        let path = temp_path(name);
        write_neighbors_csv(&path, adjacency).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        text
    }

    #[test]
    fn rows_by_site_with_the_boundary_last_and_made_unit() {
        let adjacency = Adjacency {
            offsets: vec![0, 2, 3, 4],
            neighbors: vec![1, 2, 0, 0],
            areas: vec![0.5, 0.25, 0.5, 0.25],
            normals: vec![[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            // Cell 1 has no boundary (no row); cell 2's area vector is zero
            // (a closed boundary part): a zero normal, not NaN.
            boundary: vec![0.75, 0.0, 0.125],
            boundary_vector: vec![[0.75, 0.0, 1.0], [0.0; 3], [0.0; 3]],
            shifts: Vec::new(),
        };
        let expected = "site,neighbor,area,nx,ny,nz\n\
                        0,1,5e-1,1,0,0\n\
                        0,2,2.5e-1,0,-1,0\n\
                        0,-1,7.5e-1,0.6,0,0.8\n\
                        1,0,5e-1,-1,0,0\n\
                        2,0,2.5e-1,0,1,0\n\
                        2,-1,1.25e-1,0,0,0\n";
        assert_eq!(written(&adjacency, "neighbors.csv"), expected);
    }

    #[test]
    fn a_periodic_box_adds_the_image_shifts() {
        // One site, its own neighbour through two opposite faces.
        let adjacency = Adjacency {
            offsets: vec![0, 2],
            neighbors: vec![0, 0],
            areas: vec![1.0, 1.0],
            normals: vec![[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
            boundary: vec![0.0],
            boundary_vector: vec![[0.0; 3]],
            shifts: vec![[-1, 0, 0], [1, 0, 0]],
        };
        let expected = "site,neighbor,area,nx,ny,nz,shift_x,shift_y,shift_z\n\
                        0,0,1e0,-1,0,0,-1,0,0\n\
                        0,0,1e0,1,0,0,1,0,0\n";
        assert_eq!(written(&adjacency, "neighbors-periodic.csv"), expected);
    }

    #[test]
    fn numbers_read_back_exactly() {
        let third = 1.0 / 3.0;
        let n = [0.1, -(1.0f64 - 0.01 - 0.0001f64).sqrt(), 0.01];
        let adjacency = Adjacency {
            offsets: vec![0, 1, 1],
            neighbors: vec![1],
            areas: vec![third],
            normals: vec![n],
            boundary: vec![0.0, 0.0],
            boundary_vector: vec![[0.0; 3]; 2],
            shifts: Vec::new(),
        };
        let text = written(&adjacency, "neighbors-exact.csv");
        let row: Vec<&str> = text.lines().nth(1).unwrap().split(',').collect();
        assert_eq!(row.len(), 6);
        assert_eq!(row[2].parse::<f64>().unwrap().to_bits(), third.to_bits());
        for a in 0..3 {
            assert_eq!(row[3 + a].parse::<f64>().unwrap().to_bits(), n[a].to_bits(), "{row:?}");
        }
        assert_eq!(text.lines().count(), 2, "no row for a cell without faces or boundary");
    }
}
