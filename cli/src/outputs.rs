//! What `cvd run` writes into its output folder: one table, [`OUTPUTS`],
//! in the order the files are written. A row names the file, says when it
//! is written and writes it from the run's [`Results`] through a writer of
//! `cvd-io`; a new output is a writer there and a row here.

use crate::args::RunArgs;
use crate::progress::with_bar;
use cvd::{Cells, ParticleCells, Pieces, TetMesh};
use cvd_io::{Section, Summary};
use std::path::{Path, PathBuf};

/// Pixels along the longer side of picture.png and cells.png.
pub(crate) const PICTURE_SIZE: usize = 1024;

/// What the outputs are written from.
pub struct Results<'a> {
    /// The run's arguments.
    pub args: &'a RunArgs,
    /// The mesh (none for a periodic box).
    pub mesh: Option<&'a TetMesh>,
    /// The final diagram's cells (with their polyhedra when drawn).
    pub cells: &'a Cells,
    /// The final diagram's sites.
    pub sites: &'a [[f64; 3]],
    /// The weights optimal transport found.
    pub weights: Option<&'a [f64]>,
    /// The pieces the polyhedra were merged from, when drawn.
    pub pieces: Option<&'a Pieces>,
    /// The particles' quantities (`--voronoi-index`).
    pub particles: Option<&'a ParticleCells>,
    /// The run in numbers.
    pub summary: &'a Summary,
}

/// A writer's progress: `(done, total)`.
pub type Progress<'a> = &'a mut dyn FnMut(u64, u64);

/// A file of the output folder.
pub struct Output {
    /// Its name.
    pub file: &'static str,
    /// What it holds (for the reader of this table).
    pub holds: &'static str,
    /// Whether this run writes it.
    pub when: fn(&Results) -> bool,
    /// Writes it, reporting its progress as `(done, total)`.
    pub write: fn(&Path, &Results, Progress) -> cvd::Result<()>,
    /// Slow enough for a progress bar.
    pub slow: bool,
}

/// Every output, in the order written.
pub const OUTPUTS: &[Output] = &[
    Output {
        file: "energy.png",
        holds: "the CVT energy against the iteration",
        when: |r| r.summary.cvt.is_some(),
        write: |path, r, _| match &r.summary.cvt {
            Some(record) => write_energy_chart(path, record),
            None => Ok(()),
        },
        slow: false,
    },
    Output {
        file: "cells.csv",
        holds: "per input site: volume, centroid, energy (with --voronoi-index: coordination, index)",
        when: |_| true,
        write: |path, r, _| cvd_io::write_cells_csv_with(path, r.cells, r.particles, None),
        slow: false,
    },
    Output {
        file: "neighbors.csv",
        holds: "the faces the cells share, their areas and normals, each cell's area on the boundary",
        when: |r| r.cells.adjacency().is_some(),
        write: |path, r, _| match r.cells.adjacency() {
            Some(adjacency) => cvd_io::write_neighbors_csv(path, adjacency),
            None => Ok(()),
        },
        slow: false,
    },
    Output {
        file: "sites.xyz",
        holds: "the sites of the diagram: as given, or where the iterations moved them",
        when: |_| true,
        write: |path, r, _| cvd_io::write_sites_xyz(path, r.sites),
        slow: false,
    },
    Output {
        file: "weights.txt",
        holds: "the power weights optimal transport found",
        when: |r| r.weights.is_some(),
        write: |path, r, _| cvd_io::write_values(path, r.weights.unwrap_or_default()),
        slow: false,
    },
    Output {
        file: "pieces.vtu",
        holds: "every piece (a cell inside one tet) as a VTK polyhedron, on request",
        when: |r| r.args.pieces && r.pieces.is_some(),
        write: |path, r, progress| match r.pieces {
            Some(pieces) => cvd_io::write_pieces_vtu(path, pieces, progress),
            None => Ok(()),
        },
        slow: true,
    },
    Output {
        file: "picture.png",
        holds: "the cells cut by the plane through the middle of the mesh",
        when: |r| !r.args.no_picture && r.pieces.is_some() && r.mesh.is_some(),
        write: |path, r, progress| match (r.mesh, r.pieces) {
            (Some(mesh), Some(pieces)) => {
                cvd_io::write_section_png(path, mesh, pieces, Section::middle(mesh), PICTURE_SIZE, progress)
            }
            _ => Ok(()),
        },
        slow: true,
    },
    Output {
        file: "cells.png",
        holds: "the cells below that plane, in 3D",
        when: |r| !r.args.no_picture && r.pieces.is_some() && r.mesh.is_some(),
        write: |path, r, progress| match (r.mesh, r.pieces) {
            (Some(mesh), Some(pieces)) => {
                let z = Section::middle(mesh).z;
                cvd_io::write_cells_view_png(path, mesh, pieces, z, PICTURE_SIZE, progress)
            }
            _ => Ok(()),
        },
        slow: true,
    },
    Output {
        file: "cells.vtu",
        holds: "each cell as one VTK polyhedron with its site, volume, centroid and energy",
        when: |r| r.cells.polyhedra().is_some(),
        write: |path, r, progress| {
            cvd_io::write_cells_vtu(path, r.cells, r.cells.polyhedra().unwrap_or_default(), progress)
        },
        slow: true,
    },
    Output {
        file: "walls.ply",
        holds: "every wall of the diagram once",
        when: |r| r.cells.polyhedra().is_some(),
        write: |path, r, _| cvd_io::write_walls_ply(path, r.cells.polyhedra().unwrap_or_default()).map(drop),
        slow: false,
    },
    Output {
        file: "summary.json",
        holds: "the run in numbers (also shown as a table)",
        when: |_| true,
        write: |path, r, _| r.summary.write_json(path),
        slow: false,
    },
];

/// energy.png: the CVT energy against the iteration.
pub fn write_energy_chart(path: &Path, record: &cvd_io::CvtRecord) -> cvd::Result<()> {
    let series = [cvd_io::Series { name: &record.optimizer, values: &record.energy, x: &[], rgb: [200, 40, 40] }];
    cvd_io::write_line_chart_png(path, "cvt energy", &series)
}

/// `--out`'s long help: the folder and what it receives, from the table.
pub fn help() -> String {
    let mut text = "Output folder [default: out/<model or mesh file name>/]. It receives:\n".to_string();
    for o in OUTPUTS {
        text += &format!("  {:<14} {}\n", o.file, o.holds);
    }
    text
}

/// Writes every output the run has into `dir`; returns the names written.
pub fn write_all(dir: &Path, results: &Results) -> cvd::Result<Vec<String>> {
    let mut written = Vec::new();
    for output in OUTPUTS.iter().filter(|o| (o.when)(results)) {
        let path: PathBuf = dir.join(output.file);
        if output.slow {
            with_bar(&format!("writing {}", output.file), |progress| (output.write)(&path, results, progress))?;
        } else {
            (output.write)(&path, results, &mut |_, _| {})?;
        }
        written.push(output.file.to_string());
    }
    Ok(written)
}

/// The copies `--output` (cells.csv) and `--json` (summary.json) ask for.
pub fn write_copies(results: &Results) -> cvd::Result<()> {
    if let Some(path) = &results.args.output {
        cvd_io::write_cells_csv_with(path, results.cells, results.particles, None)?;
        println!("wrote {} (cells.csv)", path.display());
    }
    if let Some(path) = &results.args.json {
        results.summary.write_json(path)?;
        println!("wrote {} (summary.json)", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::OUTPUTS;

    #[test]
    fn every_output_has_its_own_file() {
        let mut files: Vec<&str> = OUTPUTS.iter().map(|o| o.file).collect();
        files.sort_unstable();
        files.dedup();
        assert_eq!(files.len(), OUTPUTS.len());
        assert_eq!(OUTPUTS.last().map(|o| o.file), Some("summary.json"), "the summary is written last");
    }
}
