//! `picture.png`, `cells.png` and `pieces.vtu` from a run in parts. Each
//! rank draws the pieces of the cells it builds as they are made (a
//! sub-part's at a time: no rank holds every piece) into images of the
//! one frame, which the ranks then combine pixel by pixel (an all-reduce
//! of a few megabytes); rank 0 writes them. A pixel's site or colour does
//! not depend on the order the pieces are drawn in, so the pictures are
//! one process's, byte for byte. With `--pieces`, each rank writes each
//! sub-part's pieces as `pieces/RANK-K.vtu`, and rank 0 a `pieces.pvtu`
//! that lists them all.

use crate::args::RunArgs;
use crate::outputs::PICTURE_SIZE;
use cvd::backends::distributed::Reduce;
use cvd::{Pieces, TetMesh};
use cvd_io::{CellsView, Section, SectionImage};
use std::path::{Path, PathBuf};

/// The pictures and pieces' files a rank is drawing and writing.
pub struct PartsPictures {
    section: Option<SectionImage>,
    view: Option<CellsView>,
    /// Where this rank's pieces' files go (`--pieces`), and how many it
    /// wrote.
    pieces: Option<PathBuf>,
    written: u64,
}

impl PartsPictures {
    /// What `args` asks for, of `mesh`'s diagram, into `dir`; `None`
    /// when nothing is.
    pub fn asked(args: &RunArgs, mesh: &TetMesh, dir: &Path) -> Option<Self> {
        let pictures = !args.no_picture && !args.no_geometry;
        let section = Section::middle(mesh);
        let this = Self {
            section: pictures.then(|| SectionImage::new(mesh, section, PICTURE_SIZE)),
            view: pictures.then(|| CellsView::new(mesh, section.z, PICTURE_SIZE)),
            pieces: (args.pieces && !args.no_geometry).then(|| dir.join("pieces")),
            written: 0,
        };
        (pictures || this.pieces.is_some()).then_some(this)
    }

    /// Draws (and writes) some of this rank's pieces.
    pub fn visit(&mut self, pieces: &Pieces, rank: usize) -> cvd::Result<()> {
        if let Some(image) = &mut self.section {
            image.draw(pieces, &mut |_, _| {});
        }
        if let Some(view) = &mut self.view {
            view.draw(pieces, &mut |_, _| {});
        }
        if let Some(dir) = &self.pieces {
            std::fs::create_dir_all(dir)
                .map_err(|source| cvd::Error::Write { path: dir.display().to_string(), source })?;
            cvd_io::write_pieces_vtu(&dir.join(piece_file(rank, self.written)), pieces, &mut |_, _| {})?;
            self.written += 1;
        }
        Ok(())
    }

    /// Combines every rank's drawing; rank 0 writes the pictures and
    /// `pieces.pvtu`. Returns the files written.
    pub fn finish(self, comm: &dyn Reduce, dir: &Path) -> cvd::Result<Vec<&'static str>> {
        let mut written = Vec::new();
        let mut max = |values: &mut [f64]| comm.max(values);
        let rank = comm.rank();
        if let Some(mut image) = self.section {
            image.combine(&mut max)?;
            if rank == 0 {
                image.write_png(&dir.join("picture.png"))?;
            }
            written.push("picture.png");
        }
        if let Some(mut view) = self.view {
            view.combine(&mut max)?;
            if rank == 0 {
                view.write_png(&dir.join("cells.png"))?;
            }
            written.push("cells.png");
        }
        if self.pieces.is_some() {
            let counts = comm.gather_u64(self.written)?;
            if rank == 0 {
                let files: Vec<String> = (0..counts.len())
                    .flat_map(|r| (0..counts[r]).map(move |k| format!("pieces/{}", piece_file(r, k))))
                    .collect();
                cvd_io::write_pieces_pvtu(&dir.join("pieces.pvtu"), &files)?;
                println!("in parts: pieces.pvtu holds each rank's pieces, a file per sub-part (pieces/RANK-K.vtu)");
            }
            written.push("pieces.pvtu");
        }
        Ok(written)
    }
}

/// The name of rank `rank`'s `k`-th pieces' file.
fn piece_file(rank: usize, k: u64) -> String {
    format!("{rank}-{k}.vtu")
}
