//! What `cvd run` writes into its output folder:
//!
//! * `cells.csv` — per input site: volume, centroid, energy ([`cells_csv`]);
//! * `sites.xyz` — the sites, readable back by [`crate::read::read_sites`];
//! * `neighbors.csv` — the faces the cells share ([`neighbors_csv`]);
//! * `cells.vtu` — each cell as one VTK polyhedron, binary ([`cells_vtu`]);
//! * `walls.ply` — every wall of the diagram once ([`walls_ply`]);
//! * `pieces.vtu` — every piece (a cell inside one tet) as a VTK
//!   polyhedron, on request ([`vtu`]);
//! * `picture.png` — the cells cut by a plane ([`picture`]);
//! * `summary.json` — the run in numbers ([`summary`]), also shown as a
//!   table on the terminal.
//!
//! Writers that may take a while report their progress as `(done, total)`.

pub mod cells_csv;
pub mod cells_vtu;
pub mod neighbors_csv;
pub mod picture;
pub mod plot;
pub mod summary;
pub mod trajectory;
pub mod view;
pub mod vtu;
pub mod walls_ply;

pub use cells_csv::{
    read_cells_csv, write_cells_csv, write_cells_csv_rows, write_cells_csv_with, CellRow, ParticleRow,
};
pub use cells_vtu::{write_cells_pvtu, write_cells_vtu, write_cells_vtu_with, write_pieces_pvtu, CellNumbers};
pub use neighbors_csv::{write_neighbors_csv, write_neighbors_csv_rows};
pub use picture::{write_section_png, Section, SectionImage};
pub use plot::{write_chart_png, write_line_chart_png, Axes, Series};
pub use summary::{
    CvtRecord, IndexCounts, ParticlesRecord, PeriodicRecord, RankRecord, Summary, Times, TransportRecord,
};
pub use trajectory::{FrameRecord, TrajectorySummary};
pub use view::{write_cells_view_png, CellsView};
pub use vtu::write_pieces_vtu;
pub use walls_ply::{write_walls_ply, Walls};

/// A progress report: `(done, total)`, in units the writer chooses.
pub type Progress<'a> = &'a mut dyn FnMut(u64, u64);

/// Writes 8-bit RGB `pixels` (`width` x `height`) as a PNG.
pub(crate) fn write_png(path: &std::path::Path, width: usize, height: usize, pixels: &[u8]) -> cvd::Result<()> {
    let io = |source| cvd::Error::Write { path: path.display().to_string(), source };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let png_error = |e: png::EncodingError| match e {
        png::EncodingError::IoError(source) => io(source),
        other => io(std::io::Error::other(other)),
    };
    let mut writer = encoder.write_header().map_err(png_error)?;
    writer.write_image_data(pixels).map_err(png_error)?;
    writer.finish().map_err(png_error)
}
