//! `cells.csv`: one row per input site, in input order —
//! `site,volume,cx,cy,cz,energy`, and `area,neighbors` (the cell's surface
//! area and how many cells it shares a face with) when the faces were
//! computed, and the particles' quantities when asked for
//! (`coordination,max_face_order,n3,...,n10`: the faces counted above the
//! thresholds, the largest face order, and the Voronoi index, `n10` for 10
//! edges or more) — duplicates and empty cells included (an empty cell has
//! volume 0 and the site as its centroid). Numbers are written so that
//! they read back exactly.

use crate::numbers::{Dec, Exp};
use crate::read::{write_file, write_rows, Rows};
use cvd::diagram::voronoi::Cells;
use cvd::error::{Error, Result};
use cvd::{ParticleCells, INDEX_ORDERS};
use std::io::Write;
use std::path::Path;

/// The header line.
pub const HEADER: &str = "site,volume,cx,cy,cz,energy";
/// The header line with the faces' columns.
pub const HEADER_FACES: &str = "site,volume,cx,cy,cz,energy,area,neighbors";

/// The particles' columns, after the others.
pub const PARTICLE_COLUMNS: &str = "coordination,max_face_order,n3,n4,n5,n6,n7,n8,n9,n10";

/// A row's particle quantities.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParticleRow {
    /// Faces counted above the thresholds.
    pub coordination: u32,
    /// The most edges of a counted face.
    pub max_face_order: u32,
    /// Counted faces with 3, 4, ..., 10 or more edges.
    pub index: [u32; INDEX_ORDERS],
}

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
    /// Its particle quantities, when asked for.
    pub particle: Option<ParticleRow>,
}

/// Writes `cells` as `cells.csv`.
pub fn write_cells_csv(path: &Path, cells: &Cells) -> Result<()> {
    write_cells_csv_with(path, cells, None, None)
}

/// Writes `cells` as `cells.csv`, with the `particles`' columns if given,
/// and in the `site` column each row's id from `ids` if given (a particle
/// file's ids) instead of its index.
pub fn write_cells_csv_with(
    path: &Path,
    cells: &Cells,
    particles: Option<&ParticleCells>,
    ids: Option<&[u64]>,
) -> Result<()> {
    let rows = Rows::whole(cells.volume.len());
    write_file(path, |w| write_cells_csv_rows(w, cells, particles, ids, rows))
}

/// Writes the `rows` of `cells.csv` that `cells` holds (a part of a run in
/// parts: its rows from `rows.first`, the header with the first part's).
pub fn write_cells_csv_rows(
    w: &mut dyn Write,
    cells: &Cells,
    particles: Option<&ParticleCells>,
    ids: Option<&[u64]>,
    rows: Rows,
) -> std::io::Result<()> {
    let faces = cells.adjacency();
    if rows.first == 0 {
        write!(w, "{}", if faces.is_some() { HEADER_FACES } else { HEADER })?;
        match particles {
            Some(_) => writeln!(w, ",{PARTICLE_COLUMNS}")?,
            None => writeln!(w)?,
        }
    }
    write_rows(w, cells.volume.len(), |i, t| {
        let (v, c, e) = (cells.volume[i], cells.centroid[i], cells.energy[i]);
        let site = ids.map_or(rows.first + i as u64, |ids| ids[i]);
        write!(t, "{site},{},{},{},{},{}", Exp(v), Dec(c[0]), Dec(c[1]), Dec(c[2]), Exp(e))?;
        if let Some(a) = faces {
            write!(t, ",{},{}", Exp(a.surface_area(i)), a.offsets[i + 1] - a.offsets[i])?;
        }
        if let Some(p) = particles {
            write!(t, ",{},{}", p.coordination[i], p.max_face_order[i])?;
            for n in p.index[i] {
                write!(t, ",{n}")?;
            }
        }
        writeln!(t)
    })
}

/// Reads a `cells.csv` back; errors name the line and what was expected.
pub fn read_cells_csv(path: &Path) -> Result<Vec<CellRow>> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io { path: name.clone(), source })?;
    let error = |line: usize, message: String| Error::Parse { path: name.clone(), line, message };
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end()));
    let (base, extra) = match lines.next() {
        Some((_, header)) => {
            let (base, particles) = match header.strip_suffix(PARTICLE_COLUMNS).and_then(|h| h.strip_suffix(',')) {
                Some(base) => (base, 2 + INDEX_ORDERS),
                None => (header, 0),
            };
            match base {
                HEADER => (6, particles),
                HEADER_FACES => (8, particles),
                _ => {
                    return Err(error(
                        1,
                        format!(
                            "expected the header {HEADER:?} or {HEADER_FACES:?} (either then \
                             \",{PARTICLE_COLUMNS}\"), found {header:?}"
                        ),
                    ))
                }
            }
        }
        None => return Err(error(1, format!("expected the header {HEADER:?}, found an empty file"))),
    };
    let columns = base + extra;
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
            area: if base == 8 { Some(number(6)?) } else { None },
            neighbors: if base == 8 {
                Some(fields[7].parse::<usize>().map_err(|_| {
                    error(no, format!("expected a number of neighbours in column 8, found {:?}", fields[7]))
                })?)
            } else {
                None
            },
            particle: if extra > 0 {
                let count = |k: usize| -> Result<u32> {
                    fields[k]
                        .parse::<u32>()
                        .map_err(|_| error(no, format!("expected a count in column {}, found {:?}", k + 1, fields[k])))
                };
                let mut index = [0; INDEX_ORDERS];
                for (k, n) in index.iter_mut().enumerate() {
                    *n = count(base + 2 + k)?;
                }
                Some(ParticleRow { coordination: count(base)?, max_face_order: count(base + 1)?, index })
            } else {
                None
            },
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cvd::passes::faces::Adjacency;
    use std::path::PathBuf;

    fn temp_path(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("cvd-io-write-{}-{name}", std::process::id()))
    }

    /// Values that print and parse badly if the writer is careless: signed
    /// zero, subnormals, extremes, and fractions with no short decimal.
    const AWKWARD: [f64; 10] =
        [0.0, -0.0, 5e-324, f64::MIN_POSITIVE, f64::MAX, -1e-300, 1.0 / 3.0, 0.1 + 0.2, -2.5e17, 123456.789e-10];

    fn awkward_cells(n: usize) -> Cells {
        let v = |i: usize| AWKWARD[i % AWKWARD.len()];
        Cells {
            volume: (0..n).map(|i| v(i).abs()).collect(),
            centroid: (0..n).map(|i| [v(i + 1), v(i + 2), v(i + 7)]).collect(),
            energy: (0..n).map(|i| v(i + 5)).collect(),
            ..Default::default()
        }
    }

    fn same_bits(a: f64, b: f64) -> bool {
        a.to_bits() == b.to_bits()
    }

    #[test]
    fn particle_columns_read_back_with_or_without_faces() {
        let cells = awkward_cells(3);
        let particles = ParticleCells {
            area: vec![1.0, 2.0, 0.0],
            coordination: vec![12, 14, 0],
            index: vec![[0, 12, 0, 0, 0, 0, 0, 0], [0, 6, 0, 8, 0, 0, 0, 0], [0; INDEX_ORDERS]],
            max_face_order: vec![4, 6, 0],
        };
        let path = temp_path("cells-particles.csv");
        write_cells_csv_with(&path, &cells, Some(&particles), Some(&[7, 8, 90])).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(&format!("{HEADER},{PARTICLE_COLUMNS}\n")), "{text}");
        let rows = read_cells_csv(&path).unwrap();
        assert_eq!(
            rows[1].particle,
            Some(ParticleRow { coordination: 14, max_face_order: 6, index: particles.index[1] })
        );
        assert_eq!((rows[1].area, rows[2].particle.unwrap().coordination), (None, 0));
        assert_eq!(rows.iter().map(|r| r.site).collect::<Vec<_>>(), [7, 8, 90], "the ids");
        std::fs::write(&path, text.replacen(",12,4,", ",x,4,", 1)).unwrap();
        let e = read_cells_csv(&path).unwrap_err().to_string();
        assert!(e.contains(":2:") && e.contains("column 7"), "{e}");
        std::fs::remove_file(&path).ok();
    }

    #[test]
    fn every_value_reads_back_bit_for_bit() {
        let cells = awkward_cells(23);
        let path = temp_path("cells-bits.csv");
        write_cells_csv(&path, &cells).unwrap();
        let rows = read_cells_csv(&path).unwrap();
        assert_eq!(rows.len(), 23);
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(r.site, i);
            assert!(same_bits(r.volume, cells.volume[i]), "row {i}: volume {} vs {}", r.volume, cells.volume[i]);
            assert!(same_bits(r.energy, cells.energy[i]), "row {i}: energy {} vs {}", r.energy, cells.energy[i]);
            for a in 0..3 {
                assert!(
                    same_bits(r.centroid[a], cells.centroid[i][a]),
                    "row {i}: {:?} vs {:?}",
                    r.centroid,
                    cells.centroid[i]
                );
            }
            assert_eq!((r.area, r.neighbors), (None, None));
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn faces_add_the_surface_area_and_the_neighbour_count() {
        let mut cells = awkward_cells(3);
        // Cell 0 shares faces with 1 and 2, cell 1 with 0, cell 2 none but
        // the boundary.
        cells.adjacency = Some(Adjacency {
            offsets: vec![0, 2, 3, 3],
            neighbors: vec![1, 2, 0],
            areas: vec![1.0 / 3.0, 0.1, 1.0 / 3.0],
            normals: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
            boundary: vec![0.2, 0.0, 5e-324],
            boundary_vector: vec![[0.0; 3]; 3],
            shifts: Vec::new(),
        });
        let path = temp_path("cells-faces.csv");
        write_cells_csv(&path, &cells).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with(&format!("{HEADER_FACES}\n")));
        let rows = read_cells_csv(&path).unwrap();
        let a = cells.adjacency().unwrap();
        for (i, n) in [(0, 2), (1, 1), (2, 0)] {
            assert!(same_bits(rows[i].area.unwrap(), a.surface_area(i)), "row {i}");
            assert_eq!(rows[i].neighbors, Some(n), "row {i}");
        }
        assert!(same_bits(rows[0].area.unwrap(), 1.0 / 3.0 + 0.1 + 0.2));
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn windows_line_ends_and_blank_lines_are_read() {
        let path = temp_path("cells-crlf.csv");
        std::fs::write(&path, format!("{HEADER}\r\n0,1e0,0.5,-0,2,3e-1\r\n\r\n1,0e0,1,2,3,0e0\r\n\n")).unwrap();
        let rows = read_cells_csv(&path).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!((rows[0].volume, rows[0].centroid, rows[0].energy), (1.0, [0.5, -0.0, 2.0], 0.3));
        assert!(rows[0].centroid[1].is_sign_negative());
        assert_eq!((rows[1].site, rows[1].volume), (1, 0.0));
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn an_empty_or_missing_file_is_an_error_naming_it() {
        let path = temp_path("cells-empty.csv");
        std::fs::write(&path, "").unwrap();
        match read_cells_csv(&path) {
            Err(Error::Parse { line: 1, message, .. }) => assert!(message.contains("empty file"), "{message}"),
            other => panic!("{other:?}"),
        }
        std::fs::write(&path, format!("{HEADER}\n")).unwrap();
        assert!(read_cells_csv(&path).unwrap().is_empty(), "a header alone: no rows");
        std::fs::write(&path, format!("{HEADER}\n-1,1,2,3,4,5\n")).unwrap();
        match read_cells_csv(&path) {
            Err(Error::Parse { line: 2, message, .. }) => assert!(message.contains("site index"), "{message}"),
            other => panic!("{other:?}"),
        }
        std::fs::remove_file(&path).unwrap();
        match read_cells_csv(&path) {
            Err(Error::Io { path: p, .. }) => assert!(p.ends_with("cells-empty.csv"), "{p}"),
            other => panic!("{other:?}"),
        }
        let nowhere = temp_path("no-such-folder").join("cells.csv");
        match write_cells_csv(&nowhere, &awkward_cells(1)) {
            Err(Error::Write { path: p, .. }) => assert!(p.ends_with("cells.csv"), "{p}"),
            other => panic!("{other:?}"),
        }
    }
}
