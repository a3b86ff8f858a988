//! `cells.csv`: one row per input site, in input order —
//! `site,volume,cx,cy,cz,energy` — duplicates and empty cells included
//! (an empty cell has volume 0 and the site as its centroid). Numbers are
//! written so that they read back exactly.

use crate::error::{Error, Result};
use crate::io::write_file;
use crate::voronoi::Cells;
use std::path::Path;

/// The header line.
pub const HEADER: &str = "site,volume,cx,cy,cz,energy";

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
}

/// Writes `cells` as `cells.csv`.
pub fn write_cells_csv(path: &Path, cells: &Cells) -> Result<()> {
    write_file(path, |w| {
        writeln!(w, "{HEADER}")?;
        for (i, ((v, c), e)) in cells.volume.iter().zip(&cells.centroid).zip(&cells.energy).enumerate() {
            writeln!(w, "{i},{v:e},{},{},{},{e:e}", c[0], c[1], c[2])?;
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
    match lines.next() {
        Some((_, HEADER)) => {}
        Some((no, other)) => return Err(error(no, format!("expected the header {HEADER:?}, found {other:?}"))),
        None => return Err(error(1, format!("expected the header {HEADER:?}, found an empty file"))),
    }
    let mut rows = Vec::new();
    for (no, line) in lines.filter(|(_, l)| !l.is_empty()) {
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != 6 {
            return Err(error(no, format!("expected 6 comma-separated values, found {}", fields.len())));
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
        });
    }
    Ok(rows)
}
