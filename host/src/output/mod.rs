//! What `cvd run` writes into its output folder:
//!
//! * `cells.csv` — per input site: volume, centroid, energy ([`cells_csv`]);
//! * `sites.xyz` — the sites, readable back by [`crate::io::read_sites`];
//! * `pieces.vtu` — every piece as a VTK polyhedron ([`vtu`]);
//! * `picture.png` — the cells cut by a plane ([`picture`]);
//! * `summary.json` — the run in numbers ([`summary`]), also shown as a
//!   table on the terminal.
//!
//! Writers that may take a while report their progress as `(done, total)`.

pub mod cells_csv;
pub mod picture;
pub mod plot;
pub mod summary;
pub mod vtu;

pub use cells_csv::{read_cells_csv, write_cells_csv, CellRow};
pub use picture::{write_section_png, Section};
pub use plot::{write_line_chart_png, Series};
pub use summary::{Summary, Times};
pub use vtu::write_pieces_vtu;

/// A progress report: `(done, total)`, in units the writer chooses.
pub type Progress<'a> = &'a mut dyn FnMut(u64, u64);
