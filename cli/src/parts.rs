//! `mpirun -np P cvd run --periodic ...`: a periodic box in parts. Each
//! rank reads (or makes) only its own rows of the sites, moves them by the
//! CVT iterations asked for (`PeriodicInParts`: the steps of one process),
//! computes the cells of its blocks of the box
//! (`PeriodicVoronoi::compute_in_parts`) and
//! writes its rows of `cells.csv`, `neighbors.csv` and `sites.xyz` at
//! their place in the file: the same bytes as one process. Rank 0 writes
//! `summary.json`, with every rank's numbers.

use crate::args::RunArgs;
use crate::optimise::Optimised;
use crate::progress::with_iterations;
use cvd::backends::distributed::{Parcels, Reduce};
use cvd::cvt::periodic::PeriodicInParts;
use cvd::geom::exact_sum::ExactSum;
use cvd::PeriodicVoronoi;
use cvd_io::{CvtRecord, RankRecord, Rows, Summary};
use std::path::Path;

/// Runs a periodic box in parts over `comm`'s ranks.
pub fn run(args: &RunArgs, comm: &dyn Reduce) -> cvd::Result<u8> {
    ending_together(comm, |comm| in_parts(args, comm))
}

/// Runs `job` on this rank of `comm`. An error on one rank (a bad line in
/// its part of the file) ends them all, after it is said: the others would
/// wait for it.
pub(crate) fn ending_together(comm: &dyn Reduce, job: impl FnOnce(&dyn Reduce) -> cvd::Result<u8>) -> cvd::Result<u8> {
    job(comm).inspect_err(|e| {
        if comm.size() > 1 {
            eprintln!("cvd: rank {}: {e}", comm.rank());
            comm.abort(if e.is_input_error() { 2 } else { 1 });
        }
    })
}

fn in_parts(args: &RunArgs, comm: &dyn Reduce) -> cvd::Result<u8> {
    refuse_what_parts_lack(args)?;
    let clock = std::time::Instant::now();
    let rank = comm.rank();
    let domain = crate::inputs::periodic_box(args)?;
    let dir = args.out.clone().unwrap_or_else(|| Path::new("out").join(crate::inputs::PERIODIC_DIR));
    if rank == 0 {
        std::fs::create_dir_all(&dir)
            .map_err(|source| cvd::Error::Write { path: dir.display().to_string(), source })?;
    } else {
        crate::progress::quiet_stdout();
    }
    // This rank's rows: its part of the file, or of the sites made.
    let (sites, total) = rows_of_sites(args, comm, args.sites.unwrap_or(5000) as u64, |rows| {
        let unit = cvd::geom::points::uniform_rows(rows, args.seed);
        unit.iter().map(|&p| domain.cartesian(p)).collect()
    })?;
    let first: u64 = comm.gather_u64(sites.len() as u64)?[..rank].iter().sum();
    let weights = weights_of_rows(args, comm, sites.len(), first, total)?;
    // The cells on the backend asked for (a device's too: each part one
    // windowed whole-cell job); the polyhedra on the CPU.
    let backends = crate::backend::PartsBackends::open(&args.backend)?;
    let (cpu, backend, why) = (&backends.cpu, backends.cells(), &backends.why);
    println!(
        "periodic box {:?} to {:?}: {total} sites in parts over {}, whole cells on {} per rank — {why}",
        domain.lo(),
        domain.hi(),
        comm.describe(),
        backends.on()
    );
    if let Some(warning) = crate::backend::threads_beyond_cores(args.backend.threads).filter(|_| rank == 0) {
        eprintln!("cvd: {warning}");
    }
    // The optimiser, each rank moving its own rows (and finding their
    // weights): the steps of one process.
    let iterated = PeriodicVoronoi::new(domain, &sites)
        .k_site(args.k_site)
        .memory_budget(args.cpu_memory_budget())
        .backend(backend);
    let iterated = PeriodicInParts::new(iterated, comm);
    let optimised = optimise_in_parts(args, comm, iterated, weights.as_deref(), first, total)?;
    let Optimised { sites, cvt, weights, transport } =
        optimised.unwrap_or(Optimised { sites, cvt: None, weights, transport: None });
    let faces = !args.no_neighbors;
    let diagram = PeriodicVoronoi::new(domain, &sites)
        .k_site(args.k_site)
        .faces(faces)
        .memory_budget(args.cpu_memory_budget())
        .backend(backend);
    let diagram = match &weights {
        Some(w) => diagram.weights(w),
        None => diagram,
    };
    // With --voronoi-index, each cell's polyhedron measured where it is
    // built; its numbers travel with its row.
    let (out, particles, built, report) = match args.voronoi_index {
        true => {
            let thresholds = args.index_thresholds()?;
            let parts = diagram.compute_in_parts_with_index(comm, cpu, &thresholds)?;
            (parts.cells, Some(parts.particles), Some(parts.built), parts.report)
        }
        false => {
            let (out, report) = diagram.compute_in_parts(comm)?;
            (out, None, None, report)
        }
    };
    drop(sites);
    let rows = Rows { first: report.first, total, periodic: true };
    let mut written = vec!["cells.csv"];
    let cells_csv =
        |w: &mut dyn std::io::Write| cvd_io::write_cells_csv_rows(w, &out.cells, particles.as_ref(), None, rows);
    write_part(comm, &dir.join("cells.csv"), cells_csv)?;
    if let Some(a) = out.cells.adjacency() {
        write_part(comm, &dir.join("neighbors.csv"), |w| cvd_io::write_neighbors_csv_rows(w, a, rows))?;
        written.push("neighbors.csv");
    }
    write_part(comm, &dir.join("sites.xyz"), |w| cvd_io::write_sites_xyz_rows(w, &out.sites, rows))?;
    written.push("sites.xyz");
    // The cells' polyhedra: each rank's as a piece, cells.pvtu the whole.
    if let Some(built) = &built {
        let numbers = |k: usize| built.numbers[k];
        written.extend(write_polyhedra(comm, &dir, &built.polyhedra, &numbers)?);
    }
    if let (Some(w), Some(_)) = (&weights, &transport) {
        write_part(comm, &dir.join("weights.txt"), |out| cvd_io::write_values_rows(out, w))?;
        written.push("weights.txt");
    }

    // The run's numbers: totals from every rank, each rank's record.
    let (energy, records) = totals_and_records(comm, &out.cells, &report, clock)?;
    let indices = match &particles {
        Some(p) => Some(particles_record(comm, p, &args.index_thresholds()?)?),
        None => None,
    };
    let status = match &transport {
        Some(t) if !t.converged => crate::optimise::NOT_CONVERGED,
        _ => 0,
    };
    if rank != 0 {
        return Ok(status);
    }
    let mesh = domain.mesh(cvd::diagram::periodic::WHOLE_FRAME_TETS);
    let mut summary = Summary::new("periodic box", &mesh, total as usize, out.cells.strategy, backend, &out.cells);
    summary.energy = energy;
    if let Some(record) = cvt {
        crate::outputs::write_energy_chart(&dir.join("energy.png"), &record)?;
        written.insert(0, "energy.png");
        summary.cvt = Some(record);
    }
    summary.transport = transport;
    summary.periodic = Some(cvd_io::PeriodicRecord::of(&domain, &out));
    summary.particles = indices;
    summary.ranks = Some(records);
    summary.write_json(&dir.join("summary.json"))?;
    written.push("summary.json");
    print!("{summary}");
    print_ranks(&summary, "blocks");
    println!("wrote {}: {}", dir.display(), written.join(", "));
    write_copies(args, &dir)?;
    Ok(status)
}

/// What `--output` and `--json` ask for, as one process writes them:
/// copies of the folder's `cells.csv` and `summary.json` (by rank 0, once
/// every rank has written its part).
pub(crate) fn write_copies(args: &RunArgs, dir: &Path) -> cvd::Result<()> {
    for (copy, file) in [(&args.output, "cells.csv"), (&args.json, "summary.json")] {
        if let Some(path) = copy {
            std::fs::copy(dir.join(file), path)
                .map_err(|source| cvd::Error::Write { path: path.display().to_string(), source })?;
            println!("wrote {} ({file})", path.display());
        }
    }
    Ok(())
}

/// The energy of every rank's `cells` (its rows'), and every rank's record
/// (its `report`, the seconds since `clock` and its peak memory).
pub(crate) fn totals_and_records(
    comm: &dyn Reduce,
    cells: &cvd::Cells,
    report: &cvd::diagram::periodic_parts::PartsReport,
    clock: std::time::Instant,
) -> cvd::Result<(f64, Vec<RankRecord>)> {
    let energy = comm.exact_total(&ExactSum::of(&cells.energy))?.value();
    let mine = RankRecord {
        rank: comm.rank(),
        rows: report.read,
        blocks: report.blocks[1],
        owned: report.owned,
        held: report.held,
        halo: report.halo,
        widened: report.widened as u64,
        rebuilt: report.rebuilt,
        grid_cells: report.grid_cells,
        tets: report.tets,
        parts: report.parts,
        sent_bytes: report.sent,
        seconds: clock.elapsed().as_secs_f64(),
        peak_memory_bytes: cvd::job::memory::peak().unwrap_or(0),
    };
    let records = comm.all_gather(&record_bytes(&mine))?;
    Ok((energy, records.iter().map(|b| record_of(b)).collect()))
}

/// `summary.json`'s record of the Voronoi indices (`--voronoi-index`) of
/// every rank's rows, `particles` this rank's: each rank's counts added
/// (whole numbers: one process's record). Every rank calls it; the record
/// on all.
pub(crate) fn particles_record(
    comm: &dyn Reduce,
    particles: &cvd::ParticleCells,
    thresholds: &cvd::IndexThresholds,
) -> cvd::Result<cvd_io::ParticlesRecord> {
    let mut counts = cvd_io::IndexCounts::default();
    for bytes in comm.all_gather(&cvd_io::IndexCounts::of(particles).to_bytes())? {
        let got = cvd_io::IndexCounts::from_bytes(&bytes)
            .ok_or_else(|| cvd::Error::Internal("a rank's Voronoi index counts came garbled".into()))?;
        counts.add(&got);
    }
    Ok(cvd_io::ParticlesRecord::of_counts(&counts, thresholds))
}

/// This rank's rows of the sites and how many there are in all: its part
/// of `--sites-file` (bytes snapped to rows, `cvd_io::read_sites_part`),
/// or its rows of the `n` sites `make` makes.
pub(crate) fn rows_of_sites(
    args: &RunArgs,
    comm: &dyn Reduce,
    n: u64,
    make: impl FnOnce(std::ops::Range<u64>) -> Vec<[f64; 3]>,
) -> cvd::Result<(Vec<[f64; 3]>, u64)> {
    let (rank, ranks) = (comm.rank(), comm.size());
    match &args.sites_file {
        Some(path) => {
            let mut part = cvd_io::read_sites_part(path, rank, ranks)?;
            let summaries = comm.all_gather(&part.summary().to_bytes())?;
            let summaries: Vec<cvd_io::SitesPartSummary> = summaries
                .iter()
                .map(|b| cvd_io::SitesPartSummary::from_bytes(b))
                .collect::<Option<_>>()
                .ok_or_else(|| cvd::Error::Internal("a rank's part summary did not come through".into()))?;
            part.join(path, &summaries, rank)?;
            let total = part.total.ok_or_else(|| cvd::Error::Internal("a part without its file's count".into()))?;
            Ok((part.sites, total))
        }
        None => {
            let rows = n * rank as u64 / ranks as u64..n * (rank as u64 + 1) / ranks as u64;
            Ok((make(rows), n))
        }
    }
}

/// Prints each rank's line of `summary` (its parts called `parts`).
pub(crate) fn print_ranks(summary: &Summary, parts: &str) {
    for r in summary.ranks.iter().flatten() {
        println!(
            "rank {}: {} rows read, {} sites owned in {} {parts}, {} points held (halo {:.3}{}; grid cells {} of {}{}), \
             {} sent, {:.2} s, peak memory {}",
            r.rank,
            r.rows,
            r.owned,
            r.blocks,
            r.held,
            r.halo,
            match (r.widened, r.rebuilt) {
                (0, _) => String::new(),
                (1, 0) => ", widened once".to_string(),
                (n, 0) => format!(", widened {n} times"),
                (1, c) => format!(", widened once: {c} cells built again"),
                (n, c) => format!(", widened {n} times: {c} cells built again"),
            },
            r.grid_cells[0],
            r.grid_cells[1],
            match r.tets {
                [_, 0] => String::new(),
                [part, all] =>
                    format!("; tets {part} of {all}; in {} part{}", r.parts, if r.parts == 1 { "" } else { "s" }),
            },
            cvd::error::human(r.sent_bytes),
            r.seconds,
            cvd::error::human(r.peak_memory_bytes)
        );
    }
}

/// The options a periodic box in parts does not take yet, refused by name.
pub(crate) fn refuse_what_parts_lack(args: &RunArgs) -> cvd::Result<()> {
    let lacking = [
        (
            args.weights.is_some() && args.iterations > 0 && !args.transports(),
            "--weights with --iterations (CVT iterations keep power weights only with --transport)",
        ),
        (args.parts.is_some(), "--parts (the ranks are the parts)"),
        (args.strategy.is_some_and(|s| s != cvd::Strategy::Whole), "--strategy other than whole"),
    ];
    match lacking.iter().find(|(asked, _)| *asked) {
        Some((_, what)) => Err(cvd::Error::InvalidInput(format!(
            "a periodic box in parts over MPI does not take {what}; run it in one process (without mpirun)"
        ))),
        None => Ok(()),
    }
}

/// This rank's power weights (its `len` rows from `first` of `total`): its
/// rows of `--weights`, or of `--radii` squared.
pub(crate) fn weights_of_rows(
    args: &RunArgs,
    comm: &dyn Reduce,
    len: usize,
    first: u64,
    total: u64,
) -> cvd::Result<Option<Vec<f64>>> {
    Ok(match (&args.weights, &args.radii) {
        (Some(path), _) => Some(values_for_rows(comm, path, "weights", len, total)?),
        (None, Some(path)) => {
            let radii = values_for_rows(comm, path, "radii", len, total)?;
            Some(cvd::diagram::particles::radii_weights(&radii).map_err(|_| {
                let i = radii.iter().position(|r| !(r.is_finite() && *r >= 0.0)).unwrap_or(0);
                cvd::Error::InvalidInput(format!(
                    "{}: particle {}'s radius is {}; radii must be numbers >= 0",
                    path.display(),
                    first + i as u64,
                    radii[i]
                ))
            })?)
        }
        (None, None) => None,
    })
}

/// What the arguments ask the optimisers of a diagram in parts
/// (`iterated`, its sites this rank's rows from `first` of `total`):
/// optimal transport from `weights` (its capacities this rank's rows of
/// `--capacities`, or drawn by `--volumes` for its rows), or CVT
/// iterations, or `None`; each rank moving its own rows (and finding their
/// weights), the steps of one process.
pub(crate) fn optimise_in_parts(
    args: &RunArgs,
    comm: &dyn Reduce,
    iterated: impl cvd::cvt::SiteDiagram,
    weights: Option<&[f64]>,
    first: u64,
    total: u64,
) -> cvd::Result<Option<Optimised>> {
    let len = iterated.starting_sites().len();
    if args.transports() {
        let capacities = match (&args.capacities, args.volumes) {
            (Some(p), _) => Some(values_for_rows(comm, p, "capacities", len, total)?),
            (None, Some(law)) => Some(law.draw_rows(first..first + len as u64, args.seed)),
            (None, None) => None,
        };
        return crate::optimise::transport(args, iterated, weights, capacities).map(Some);
    }
    if args.iterations == 0 {
        return Ok(None);
    }
    let (name, iterations) = (args.optimizer.name(), args.iterations);
    let run = with_iterations(name, iterations, |show| args.optimizer.run(&iterated, iterations, show))?;
    let cvt = Some(CvtRecord::of(name, &run.iterations));
    Ok(Some(Optimised { sites: run.sites, cvt, weights: weights.map(<[f64]>::to_vec), transport: None }))
}

/// This rank's `len` rows of a file of one value per site (`what`: weights,
/// radii) for `total` sites: each rank reads a part of the file's bytes
/// (`cvd_io::read_values_part`), and each value goes to the rank that
/// holds its site's row.
fn values_for_rows(comm: &dyn Reduce, path: &Path, what: &str, len: usize, total: u64) -> cvd::Result<Vec<f64>> {
    let (rank, ranks) = (comm.rank(), comm.size());
    let read = cvd_io::read_values_part(path, rank, ranks)?;
    let counts = comm.gather_u64(read.len() as u64)?;
    let found: u64 = counts.iter().sum();
    if found != total {
        return Err(cvd::Error::InvalidInput(format!("{}: {found} {what} for {total} sites", path.display())));
    }
    // Each rank's rows of the sites, and where this rank's values start.
    let rows = comm.gather_u64(len as u64)?;
    let starts: Vec<u64> = rows.iter().scan(0, |at, &n| Some(std::mem::replace(at, *at + n))).collect();
    let at: u64 = counts[..rank].iter().sum();
    let mut to = vec![Vec::new(); ranks];
    for (r, (&start, &n)) in starts.iter().zip(&rows).enumerate() {
        // The values read here that are rank r's rows.
        let (first, end) = (at.max(start), (at + read.len() as u64).min(start + n));
        if first < end {
            let from = (first - at) as usize;
            to[r] = read[from..from + (end - first) as usize].iter().flat_map(|v| v.to_le_bytes()).collect();
        }
    }
    let got = comm.exchange(Parcels::of(to))?;
    let values: Vec<f64> = got.bytes.as_chunks::<8>().0.iter().map(|b| f64::from_le_bytes(*b)).collect();
    if values.len() != len {
        return Err(cvd::Error::Internal(format!("{} of {len} {what} came to rank {rank}", values.len())));
    }
    Ok(values)
}

/// Writes this rank's part of a file (what `body` writes) at its place:
/// after the parts of the ranks before it. Rank 0 makes the file first;
/// every rank has written its part when this returns.
pub(crate) fn write_part(
    comm: &dyn Reduce,
    path: &Path,
    body: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> cvd::Result<()> {
    write_section(comm, path, false, body)
}

/// The polyhedra of the cells this rank built (`numbers(k)`: the volume,
/// centroid and energy of `polyhedra[k]`'s cell) as its piece of
/// `cells.pvtu` (`cells/RANK.vtu`, rank 0 writing `cells.pvtu`), and their
/// walls as its section of `walls.ply` (a shared face from the cell of the
/// lower site, as one process writes it; its points and faces after the
/// ranks' before it, the header from rank 0). Returns the files' names.
pub(crate) fn write_polyhedra(
    comm: &dyn Reduce,
    dir: &Path,
    polyhedra: &[cvd::passes::polyhedra::CellPolyhedron],
    numbers: &(dyn Fn(usize) -> cvd_io::CellNumbers + Sync),
) -> cvd::Result<Vec<&'static str>> {
    let (rank, ranks) = (comm.rank(), comm.size());
    let piece = format!("cells/{rank}.vtu");
    if rank == 0 {
        let made = dir.join("cells");
        std::fs::create_dir_all(&made)
            .map_err(|source| cvd::Error::Write { path: made.display().to_string(), source })?;
    }
    comm.sum(&mut [0i64])?;
    let wrote = cvd_io::write_cells_vtu_with(&dir.join(&piece), polyhedra, numbers, &mut |_, _| {});
    let mut failed = [wrote.is_err() as i64];
    comm.sum(&mut failed)?;
    wrote?;
    if failed[0] != 0 {
        return Err(cvd::Error::InvalidInput("another rank could not write its piece of cells.pvtu".into()));
    }
    if rank == 0 {
        let pieces: Vec<String> = (0..ranks).map(|r| format!("cells/{r}.vtu")).collect();
        cvd_io::write_cells_pvtu(&dir.join("cells.pvtu"), &pieces)?;
        println!("in parts: cells.pvtu holds each rank's cells.vtu (cells/RANK.vtu)");
    }
    let walls = cvd_io::Walls::of(polyhedra);
    let counts =
        comm.all_gather(&[walls.points.len() as u64, walls.faces.len() as u64].map(u64::to_le_bytes).concat())?;
    let count = |b: &Vec<u8>, k: usize| u64::from_le_bytes(b[8 * k..8 * k + 8].try_into().unwrap_or([0; 8]));
    let (points, faces) = (counts.iter().map(|b| count(b, 0)).sum(), counts.iter().map(|b| count(b, 1)).sum());
    let first_point: u64 = counts[..rank].iter().map(|b| count(b, 0)).sum();
    let path = dir.join("walls.ply");
    write_part(comm, &path, |w| {
        if rank == 0 {
            w.write_all(cvd_io::Walls::header(points, faces).as_bytes())?;
        }
        walls.write_points(w)
    })?;
    write_section(comm, &path, true, |w| walls.write_faces(w, first_point))?;
    Ok(vec!["cells.pvtu", "walls.ply"])
}

/// [`write_part`] of a section of the file: the file made anew, or (with
/// `append`) the section after what the file holds.
fn write_section(
    comm: &dyn Reduce,
    path: &Path,
    append: bool,
    body: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> cvd::Result<()> {
    use std::io::{Seek, Write};
    let io = |source| cvd::Error::Write { path: path.display().to_string(), source };
    // Written first to a file of this rank's own beside it (a part's text
    // may be larger than the numbers it is made from: a million cells'
    // faces are 1.4 GB), then copied into place once every rank's length
    // is known. Rank 0's own file, at the start of a new file, becomes the
    // file: only the others' parts are copied (into one file at once, the
    // copies contend for it).
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let own = path.with_file_name(format!(".{name}.{}.part", comm.rank()));
    let own_io = |source| cvd::Error::Write { path: own.display().to_string(), source };
    let becomes_the_file = comm.rank() == 0 && !append;
    let written =
        std::fs::File::options().read(true).write(true).create(true).truncate(true).open(&own).and_then(|f| {
            let mut out = std::io::BufWriter::with_capacity(1 << 20, f);
            body(&mut out)?;
            out.flush()?;
            let mut f = out.into_inner().map_err(|e| e.into_error())?;
            let length = f.stream_position()?;
            f.rewind()?;
            Ok((f, length))
        });
    if !becomes_the_file || written.is_err() {
        let _ = std::fs::remove_file(&own);
    }
    let (mut part, length) = match written {
        Ok(w) => (Some(w.0), w.1),
        Err(e) => {
            eprintln!("cvd: rank {}: {}", comm.rank(), own_io(e));
            (None, u64::MAX)
        }
    };
    let lengths = comm.gather_u64(length)?;
    if lengths.contains(&u64::MAX) {
        if becomes_the_file {
            let _ = std::fs::remove_file(&own);
        }
        return Err(cvd::Error::InvalidInput(format!("{}: a rank could not write its part", path.display())));
    }
    let total: u64 = lengths.iter().sum();
    // Rank 0 makes (or lengthens) the file; every rank learns whether it
    // could, and where the section starts, and stops together.
    let mut made = [0i64; 2];
    let mut failure = None;
    if comm.rank() == 0 {
        let sized = if append {
            std::fs::OpenOptions::new().write(true).open(path).and_then(|f| {
                let base = f.metadata()?.len();
                f.set_len(base + total).map(|()| base)
            })
        } else {
            // Rank 0's own part, made the file and lengthened.
            std::fs::rename(&own, path)
                .and_then(|()| std::fs::OpenOptions::new().write(true).open(path))
                .and_then(|f| f.set_len(total))
                .map(|()| 0)
                .inspect_err(|_| {
                    let _ = std::fs::remove_file(&own);
                })
        };
        match sized {
            Ok(base) => made[1] = base as i64,
            Err(e) => (made[0], failure) = (1, Some(e)),
        }
    }
    comm.sum(&mut made)?;
    if let Some(e) = failure {
        return Err(io(e));
    }
    if made[0] != 0 {
        return Err(cvd::Error::InvalidInput(format!("{}: rank 0 could not make the file", path.display())));
    }
    let at = made[1] as u64 + lengths[..comm.rank()].iter().sum::<u64>();
    let mut failed = [0i64];
    let wrote = std::fs::OpenOptions::new().write(true).open(path).and_then(|mut f| {
        f.seek(std::io::SeekFrom::Start(at))?;
        let copied = match part.as_mut() {
            Some(_) if becomes_the_file => length,
            Some(part) => std::io::copy(part, &mut f)?,
            None => 0,
        };
        match copied == length {
            true => Ok(()),
            false => Err(std::io::Error::other(format!("copied {copied} of a part's {length} bytes"))),
        }
    });
    failed[0] = wrote.is_err() as i64;
    comm.sum(&mut failed)?;
    wrote.map_err(io)?;
    if failed[0] != 0 {
        return Err(cvd::Error::InvalidInput(format!("{}: another rank could not write its part", path.display())));
    }
    Ok(())
}

/// A rank's record as bytes (numbers in a fixed order), and back.
fn record_bytes(r: &RankRecord) -> Vec<u8> {
    let words = [
        r.rank as u64,
        r.rows,
        r.blocks,
        r.owned,
        r.held,
        r.halo.to_bits(),
        r.sent_bytes,
        r.seconds.to_bits(),
        r.peak_memory_bytes,
        r.grid_cells[0],
        r.grid_cells[1],
        r.tets[0],
        r.tets[1],
        r.parts,
        r.widened,
        r.rebuilt,
    ];
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

fn record_of(b: &[u8]) -> RankRecord {
    let w = |k: usize| b.get(8 * k..8 * k + 8).map_or(0, |s| u64::from_le_bytes(s.try_into().unwrap_or([0; 8])));
    RankRecord {
        rank: w(0) as usize,
        rows: w(1),
        blocks: w(2),
        owned: w(3),
        held: w(4),
        halo: f64::from_bits(w(5)),
        sent_bytes: w(6),
        seconds: f64::from_bits(w(7)),
        peak_memory_bytes: w(8),
        grid_cells: [w(9), w(10)],
        tets: [w(11), w(12)],
        parts: w(13),
        widened: w(14),
        rebuilt: w(15),
    }
}
