//! `cvd run --particles FILE`: the cells of every frame of a particle
//! trajectory (a LAMMPS dump, an extended XYZ), each in its own cell with
//! its periodic axes and radii, written as one `cells.csv` per frame in
//! `frames/` (`cells.<frame>.csv`, the `site` column holding the file's
//! particle ids where it has them) and one `summary.json` for the run.
//! Each frame starts from the last one's neighbour lists
//! (`cvd::diagram::trajectory`) unless `--rebuild-frames`.
//!
//! Under `mpirun`, every frame in parts: each rank reads only its share
//! of each frame's bytes (`FrameReader::next_in_parts`: the ranks count
//! the frame's line ends together, a share each, and each parses only its
//! own atom lines), the ranks put
//! the rows in order of their ids together (`sort_across`), and the frame's
//! cells are a periodic box in parts (`PeriodicVoronoi::compute_in_parts`),
//! each rank writing its rows of the frame's `cells.csv` at their place:
//! the same files as one process.

use crate::args::{FrameRange, RunArgs};
use crate::progress::with_frames;
use cvd::backends::distributed::{sort_across, Reduce};
use cvd::{CpuBackend, ParticleCells, PeriodicVoronoi};
use cvd_io::{FrameRecord, ParticleFrame, TrajectorySummary};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Runs `cvd run --particles`: in one process, or in parts over the ranks
/// of an MPI launch.
pub fn run(args: &RunArgs, file: &Path) -> cvd::Result<u8> {
    let (comm, warning) = cvd::backends::distributed::launched_comm()?;
    if let Some(warning) = warning {
        eprintln!("cvd: {warning}");
    }
    match comm {
        Some(comm) => crate::parts::ending_together(comm.as_ref(), |comm| frames(args, file, Some(comm))),
        None => frames(args, file, None),
    }
}

/// One frame's cells as written: the record for the summary.
struct FrameCells {
    /// Seconds computing the cells (reading and writing apart).
    seconds: f64,
    particles: usize,
    images: usize,
    reused: u64,
    cells: cvd::Cells,
}

/// The cells of every frame asked for, in one process (`comm`: none) or in
/// parts.
fn frames(args: &RunArgs, file: &Path, comm: Option<&dyn Reduce>) -> cvd::Result<u8> {
    let range = args.frames.unwrap_or(FrameRange { start: 0, end: None, step: 1 });
    let thresholds = args.index_thresholds()?;
    let name = file.file_stem().and_then(|s| s.to_str()).unwrap_or("particles").to_string();
    let dir = args.out.clone().unwrap_or_else(|| PathBuf::from("out").join(&name));
    let frames_dir = dir.join("frames");
    let rank = comm.map_or(0, |c| c.rank());
    if comm.is_some() {
        crate::parts::refuse_what_parts_lack(args)?;
        if rank != 0 {
            crate::progress::quiet_stdout();
        }
    }
    if rank == 0 {
        std::fs::create_dir_all(&frames_dir)
            .map_err(|source| cvd::Error::Write { path: frames_dir.display().to_string(), source })?;
    }
    let mut reader = cvd_io::open_particles(file)?;
    let cpu = CpuBackend::new(args.backend.threads)?;
    let clock = Instant::now();
    let mut records = Vec::new();
    let mut diagram_seconds = 0.0;
    let mut last = None;
    println!(
        "{}: frames {}..{} every {}, on the CPU with {} threads{}",
        file.display(),
        range.start,
        range.end.map_or("the end".to_string(), |e| e.to_string()),
        range.step,
        cpu.threads(),
        comm.map_or(String::new(), |c| format!(" per rank, each frame in parts over {}", c.describe()))
    );
    with_frames(range.count(), |show| -> cvd::Result<()> {
        loop {
            let index = reader.next_index();
            if range.past(index) {
                return Ok(());
            }
            if !range.wants(index) {
                let skipped = match comm {
                    None => reader.skip_frame()?,
                    Some(comm) => reader.skip_in_parts(comm)?,
                };
                if !skipped {
                    return Ok(());
                }
                continue;
            }
            let frame = match comm {
                None => reader.next(),
                Some(comm) => reader.next_in_parts(comm),
            };
            let Some(frame) = frame else { return Ok(()) };
            let frame = frame?;
            let (timestep, periodic) = (frame.timestep, frame.domain.periodic());
            let file = format!("cells.{index:06}.csv");
            let out = match comm {
                None => {
                    let weights = frame.radii.as_deref().map(cvd::diagram::particles::radii_weights).transpose()?;
                    let mut pv = PeriodicVoronoi::new(frame.domain, &frame.positions)
                        .faces(!args.no_neighbors)
                        .strategy(args.strategy)
                        .backend(&cpu)
                        .keep_lists(!args.rebuild_frames)
                        .after(last.as_ref());
                    if let Some(w) = &weights {
                        pv = pv.weights(w);
                    }
                    let started = Instant::now();
                    let mut out = if args.voronoi_index { pv.compute_with_polyhedra(&cpu)? } else { pv.compute()? };
                    let seconds = started.elapsed().as_secs_f64();
                    last = out.lists.take();
                    let particles =
                        out.cells.polyhedra().map(|p| ParticleCells::of(frame.positions.len(), p, &thresholds));
                    cvd_io::write_cells_csv_with(
                        &frames_dir.join(&file),
                        &out.cells,
                        particles.as_ref(),
                        frame.ids.as_deref(),
                    )?;
                    FrameCells {
                        seconds,
                        particles: frame.positions.len(),
                        images: out.images,
                        reused: out.reused as u64,
                        cells: out.cells,
                    }
                }
                Some(comm) => frame_in_parts(args, comm, &cpu, frame, &frames_dir.join(&file), &thresholds)?,
            };
            let seconds = out.seconds;
            diagram_seconds += seconds;
            let c = &out.cells.counters;
            records.push(FrameRecord {
                frame: index,
                timestep,
                particles: out.particles,
                periodic,
                images: out.images,
                reused_cells: out.reused,
                e_vol: out.cells.e_vol,
                empty_cells: c.empty_cells,
                second_pass: c.second_pass,
                unresolved: c.unresolved,
                seconds,
                file: format!("frames/{file}"),
            });
            show(records.len(), out.particles);
        }
    })?;
    if records.is_empty() {
        return Err(cvd::Error::InvalidInput(format!(
            "{}: no frame in {}..{} (every {})",
            file.display(),
            range.start,
            range.end.map_or("the end".to_string(), |e| e.to_string()),
            range.step
        )));
    }
    let total = clock.elapsed().as_secs_f64();
    if rank != 0 {
        return Ok(0);
    }
    let summary = TrajectorySummary {
        particles_file: file.display().to_string(),
        frames_per_second: records.len() as f64 / total,
        diagram_seconds,
        total_seconds: total,
        reused_cells: records.iter().map(|r| r.reused_cells).sum(),
        thresholds: args.voronoi_index.then_some([
            thresholds.edge,
            thresholds.relative_edge,
            thresholds.face,
            thresholds.relative_face,
        ]),
        frames: records,
    };
    summary.write_json(&dir.join("summary.json"))?;
    let n = summary.frames.len();
    let cells: usize = summary.frames.iter().map(|f| f.particles).sum();
    println!(
        "{n} frames: cells {:.3} s ({:.1} ms a frame), {:.3} s in all ({:.2} frames/s); {} of {cells} cells from \
         the last frame's lists",
        diagram_seconds,
        1e3 * diagram_seconds / n as f64,
        total,
        summary.frames_per_second,
        summary.reused_cells
    );
    let worst = summary.frames.iter().map(|f| f.e_vol).fold(0.0, f64::max);
    println!("E_vol at most {worst:.1e}; wrote {}: frames/cells.*.csv ({n}), summary.json", dir.display());
    Ok(0)
}

/// An atom of a frame read in parts, on its way to the rank of its row:
/// its id, the line it was read from, its position and radius (bits).
type Atom = [u64; 6];

/// A frame's cells in parts: this rank's part of its atom lines put in
/// order of their ids with the other ranks' (as one process sorts them),
/// the cells of its rows computed as a periodic box in parts, and its rows
/// of the frame's `cells.csv` written at their place in `path`.
fn frame_in_parts(
    args: &RunArgs,
    comm: &dyn Reduce,
    cpu: &CpuBackend,
    mut frame: ParticleFrame,
    path: &Path,
    thresholds: &cvd::IndexThresholds,
) -> cvd::Result<FrameCells> {
    let part = frame.part.ok_or_else(|| cvd::Error::Internal("a frame read in parts without its part".into()))?;
    let (positions, radii, ids) = match frame.ids.take() {
        None => (frame.positions, frame.radii, None),
        Some(ids) => {
            let atoms: Vec<Atom> = (0..frame.positions.len())
                .map(|i| {
                    let [x, y, z] = frame.positions[i].map(f64::to_bits);
                    let radius = frame.radii.as_ref().map_or(0.0, |r| r[i]).to_bits();
                    [ids[i], (part.first_line + i) as u64, x, y, z, radius]
                })
                .collect();
            let atoms = sort_across(comm, atoms, |a| a[0])?;
            // Equal ids meet on one rank, in the file's order.
            if let Some(w) = atoms.windows(2).find(|w| w[0][0] == w[1][0]) {
                return Err(cvd::Error::Parse {
                    path: args.particles.as_ref().map_or(String::new(), |p| p.display().to_string()),
                    line: w[1][1] as usize,
                    message: format!(
                        "frame {}: atom id {} again (it is on line {} too)",
                        frame.index, w[0][0], w[0][1]
                    ),
                });
            }
            let at = |a: &Atom| [a[2], a[3], a[4]].map(f64::from_bits);
            let radii = frame.radii.is_some().then(|| atoms.iter().map(|a| f64::from_bits(a[5])).collect());
            (atoms.iter().map(at).collect(), radii, Some(atoms.iter().map(|a| a[0]).collect::<Vec<u64>>()))
        }
    };
    let weights = radii.as_deref().map(cvd::diagram::particles::radii_weights).transpose()?;
    let mut pv = PeriodicVoronoi::new(frame.domain, &positions).faces(!args.no_neighbors).backend(cpu);
    if let Some(w) = &weights {
        pv = pv.weights(w);
    }
    let started = Instant::now();
    let (out, particles, report) = match args.voronoi_index {
        true => {
            let parts = pv.compute_in_parts_with_index(comm, cpu, thresholds)?;
            (parts.cells, Some(parts.particles), parts.report)
        }
        false => {
            let (out, report) = pv.compute_in_parts(comm)?;
            (out, None, report)
        }
    };
    let seconds = started.elapsed().as_secs_f64();
    let rows = cvd_io::Rows { first: report.first, total: part.total as u64, periodic: true };
    crate::parts::write_part(comm, path, |w| {
        cvd_io::write_cells_csv_rows(w, &out.cells, particles.as_ref(), ids.as_deref(), rows)
    })?;
    Ok(FrameCells { seconds, particles: part.total, images: out.images, reused: 0, cells: out.cells })
}
