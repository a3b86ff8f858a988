//! `cells.csv`: one row per input site, in input order —
//! `site,volume,cx,cy,cz,energy`, and `area,neighbors` (the cell's surface
//! area and how many cells it shares a face with) when the faces were
//! computed — duplicates and empty cells included (an empty cell has
//! volume 0 and the site as its centroid). Numbers are written so that
//! they read back exactly.

use crate::read::write_file;
use cvd::diagram::voronoi::Cells;
use cvd::error::{Error, Result};
use std::path::Path;

/// The header line.
pub const HEADER: &str = "site,volume,cx,cy,cz,energy";
/// The header line with the faces' columns.
pub const HEADER_FACES: &str = "site,volume,cx,cy,cz,energy,area,neighbors";

/// One row of `cells.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellRow {
    /// The site's index in the input.
    pub site: usize,
    /// The clipped cell's volume.
    pub volume: f64,
    /// Its centroid.
    pub centroid: [f64; 3],
    /// `∫ |x - x_site|²` over it.
    pub energy: f64,
    /// Its surface area, when the faces were computed.
    pub area: Option<f64>,
    /// How many cells it shares a face with, when the faces were computed.
    pub neighbors: Option<usize>,
}

/// Writes `cells` as `cells.csv`.
pub fn write_cells_csv(path: &Path, cells: &Cells) -> Result<()> {
    write_file(path, |w| {
        let faces = cells.adjacency();
        writeln!(w, "{}", if faces.is_some() { HEADER_FACES } else { HEADER })?;
        for (i, ((v, c), e)) in cells.volume.iter().zip(&cells.centroid).zip(&cells.energy).enumerate() {
            write!(w, "{i},{v:e},{},{},{},{e:e}", c[0], c[1], c[2])?;
            match faces {
                Some(a) => writeln!(w, ",{:e},{}", a.surface_area(i), a.offsets[i + 1] - a.offsets[i])?,
                None => writeln!(w)?,
            }
        }
        Ok(())
    })
}

/// Reads a `cells.csv` back; errors name the line and what was expected.
pub fn read_cells_csv(path: &Path) -> Result<Vec<CellRow>> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io { path: name.clone(), source })?;
    let error = |line: usize, message: String| Error::Parse { path: name.clone(), line, message };
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end()));
    let columns = match lines.next() {
        Some((_, HEADER)) => 6,
        Some((_, HEADER_FACES)) => 8,
        Some((no, other)) => {
            return Err(error(no, format!("expected the header {HEADER:?} or {HEADER_FACES:?}, found {other:?}")))
        }
        None => return Err(error(1, format!("expected the header {HEADER:?}, found an empty file"))),
    };
    let mut rows = Vec::new();
    for (no, line) in lines.filter(|(_, l)| !l.is_empty()) {
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != columns {
            return Err(error(no, format!("expected {columns} comma-separated values, found {}", fields.len())));
        }
        let number = |k: usize| -> Result<f64> {
            fields[k]
                .parse::<f64>()
                .map_err(|_| error(no, format!("expected a number in column {}, found {:?}", k + 1, fields[k])))
        };
        let site = fields[0]
            .parse::<usize>()
            .map_err(|_| error(no, format!("expected a site index, found {:?}", fields[0])))?;
        rows.push(CellRow {
            site,
            volume: number(1)?,
            centroid: [number(2)?, number(3)?, number(4)?],
            energy: number(5)?,
            area: if columns == 8 { Some(number(6)?) } else { None },
            neighbors: if columns == 8 {
                Some(fields[7].parse::<usize>().map_err(|_| {
                    error(no, format!("expected a number of neighbours in column 8, found {:?}", fields[7]))
                })?)
            } else {
                None
            },
        });
    }
    Ok(rows)
}
