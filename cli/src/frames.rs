//! `cvd run --particles FILE`: the cells of every frame of a particle
//! trajectory (a LAMMPS dump, an extended XYZ), each in its own cell with
//! its periodic axes and radii, written as one `cells.csv` per frame in
//! `frames/` (`cells.<frame>.csv`, the `site` column holding the file's
//! particle ids where it has them) and one `summary.json` for the run.
//! Each frame starts from the last one's neighbour lists
//! (`cvd::diagram::trajectory`) unless `--rebuild-frames`.

use crate::args::{FrameRange, RunArgs};
use crate::progress::with_frames;
use cvd::{CpuBackend, ParticleCells, PeriodicVoronoi};
use cvd_io::{FrameRecord, TrajectorySummary};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Runs `cvd run --particles`.
pub fn run(args: &RunArgs, file: &Path) -> cvd::Result<u8> {
    let range = args.frames.unwrap_or(FrameRange { start: 0, end: None, step: 1 });
    let thresholds = args.index_thresholds()?;
    let name = file.file_stem().and_then(|s| s.to_str()).unwrap_or("particles").to_string();
    let dir = args.out.clone().unwrap_or_else(|| PathBuf::from("out").join(&name));
    let frames_dir = dir.join("frames");
    std::fs::create_dir_all(&frames_dir)
        .map_err(|source| cvd::Error::Write { path: frames_dir.display().to_string(), source })?;
    let mut reader = cvd_io::open_particles(file)?;
    let cpu = CpuBackend::new(args.backend.threads)?;
    let clock = Instant::now();
    let mut records = Vec::new();
    let mut diagram_seconds = 0.0;
    let mut last = None;
    println!(
        "{}: frames {}..{} every {}, on the CPU with {} threads",
        file.display(),
        range.start,
        range.end.map_or("the end".to_string(), |e| e.to_string()),
        range.step,
        cpu.threads()
    );
    with_frames(range.count(), |show| -> cvd::Result<()> {
        loop {
            let index = reader.next_index();
            if range.past(index) {
                return Ok(());
            }
            if !range.wants(index) {
                if !reader.skip_frame()? {
                    return Ok(());
                }
                continue;
            }
            let Some(frame) = reader.next() else { return Ok(()) };
            let frame = frame?;
            let weights = frame.radii.as_deref().map(cvd::diagram::particles::radii_weights).transpose()?;
            let started = Instant::now();
            let mut pv = PeriodicVoronoi::new(frame.domain, &frame.positions)
                .faces(!args.no_neighbors)
                .strategy(args.strategy)
                .backend(&cpu)
                .keep_lists(!args.rebuild_frames)
                .after(last.as_ref());
            if let Some(w) = &weights {
                pv = pv.weights(w);
            }
            let mut out = if args.voronoi_index { pv.compute_with_polyhedra(&cpu)? } else { pv.compute()? };
            last = out.lists.take();
            let particles = out.cells.polyhedra().map(|p| ParticleCells::of(frame.positions.len(), p, &thresholds));
            let seconds = started.elapsed().as_secs_f64();
            diagram_seconds += seconds;
            let file = format!("cells.{index:06}.csv");
            cvd_io::write_cells_csv_with(
                &frames_dir.join(&file),
                &out.cells,
                particles.as_ref(),
                frame.ids.as_deref(),
            )?;
            let c = &out.cells.counters;
            records.push(FrameRecord {
                frame: index,
                timestep: frame.timestep,
                particles: frame.positions.len(),
                periodic: frame.domain.periodic(),
                images: out.images,
                reused_cells: out.reused as u64,
                e_vol: out.cells.e_vol,
                empty_cells: c.empty_cells,
                second_pass: c.second_pass,
                unresolved: c.unresolved,
                seconds,
                file: format!("frames/{file}"),
            });
            show(records.len(), frame.positions.len());
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
