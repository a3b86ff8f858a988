//! `cvd run`: one path for meshes and periodic boxes — inputs, backend,
//! the optimiser (CVT iterations or optimal transport), the final diagram,
//! then the outputs ([`crate::outputs`]).

use crate::args::RunArgs;
use crate::backend::{self, RunBackend};
use crate::inputs::{per_site, Domain, Inputs};
use crate::optimise::{transport, Optimised, NOT_CONVERGED};
use crate::outputs::{self, Results};
use crate::progress::{quiet_stdout, with_iterations, with_spinner};
use cvd::cvt::SiteDiagram;
use cvd::exec::CpuBackend;
use cvd::{Backend, Cells, ClippedVoronoi, JobShape, ParticleCells, PeriodicVoronoi, Pieces};
use cvd_io::{CvtRecord, ParticlesRecord, PeriodicRecord, Summary};

/// The final diagram.
struct Diagram {
    /// The cells (with their faces unless `--no-neighbors`).
    cells: Cells,
    /// The sites as the diagram holds them (a periodic box's wrapped).
    sites: Vec<[f64; 3]>,
    /// The pieces the cells' polyhedra were merged from, when drawn.
    pieces: Option<Pieces>,
    /// A periodic box's record.
    periodic: Option<PeriodicRecord>,
    /// The particles' quantities (`--voronoi-index`).
    particles: Option<ParticleCells>,
}

/// Runs `cvd run`; the exit status: 0, or [`NOT_CONVERGED`].
pub fn run(args: &RunArgs) -> cvd::Result<u8> {
    if let Some(file) = &args.particles {
        return crate::frames::run(args, file);
    }
    // A periodic box started by an MPI launcher: in parts, each rank with
    // its own rows.
    if args.periodic() {
        let (comm, warning) = cvd::backends::distributed::launched_comm()?;
        if let Some(warning) = warning {
            eprintln!("cvd: {warning}");
        }
        if let Some(comm) = comm {
            return crate::parts::run(args, comm.as_ref());
        }
    } else if crate::mesh_parts::lacking(args).is_none() {
        // A mesh started by an MPI launcher: each rank with its own rows
        // (what that does not take yet runs with the whole input on every
        // rank, below).
        if let (Some(comm), _) = cvd::backends::distributed::launched_comm()? {
            return crate::mesh_parts::run(args, comm.as_ref());
        }
    }
    let inputs = Inputs::read(args)?;
    let dir = inputs.out_dir(args);
    let (run_backend, why) = backend::open(args)?;
    let backend = run_backend.get();
    // Every rank computes; rank 0 writes and speaks.
    let writes = run_backend.rank() == 0;
    if !writes {
        quiet_stdout();
    }
    if let Some(warning) = backend::threads_beyond_cores(args.backend.threads).filter(|_| writes) {
        eprintln!("cvd: {warning}");
    }
    // Before the long part: a folder that cannot be made fails now.
    if writes {
        create_dir(&dir)?;
    }
    let tets = match &inputs.domain {
        Domain::Mesh(mesh) => mesh.tets.len(),
        Domain::Box(_) => cvd::diagram::periodic::WHOLE_FRAME_TETS,
    };
    let shape = JobShape { density: inputs.density.is_some(), sites: inputs.sites.len(), tets };
    let strategy = args.strategy.unwrap_or_else(|| backend.default_strategy(shape));
    match &inputs.domain {
        Domain::Mesh(mesh) => {
            // What parts leave out (said, not dropped silently).
            let whole = strategy == cvd::Strategy::Whole;
            if run_backend.in_parts() && !whole && !(args.no_neighbors && args.no_geometry) {
                println!("in parts: tet-cell gives cells only (no neighbors.csv, cells.vtu, walls.ply or pictures)");
            }
            if let Some(what) =
                crate::mesh_parts::lacking(args).filter(|_| run_backend.parts().is_some_and(|d| d.comm().size() > 1))
            {
                println!("in parts: every rank reads the whole input ({what} is not yet run with the sites in parts)");
            }
            let (tets, sites, name) = (mesh.tets.len(), inputs.sites.len(), backend.name());
            println!("{}: {tets} tets, {sites} sites, {} on {name} — {why}", inputs.name, strategy.name());
        }
        Domain::Box(b) => {
            let (lo, hi, sites, name) = (b.lo(), b.hi(), inputs.sites.len(), backend.name());
            println!("{} {lo:?} to {hi:?}: {sites} sites, {} on {name} — {why}", inputs.name, strategy.name());
        }
    }
    let optimised = optimise(args, &inputs, backend)?;
    let mut diagram = final_diagram(args, &inputs, &optimised, &run_backend)?;
    let (mut written_in_parts, mut pieces_in_parts): (Vec<&str>, _) = (Vec::new(), None);
    let compiled = backend.kernel_compile_seconds();
    if compiled > 0.0 {
        println!("kernels: the driver compiled them in {compiled:.2} s on first use (not in the times below)");
    }
    let status = match &optimised.transport {
        Some(t) if !t.converged => NOT_CONVERGED,
        _ => 0,
    };
    // In parts, every rank writes the polyhedra of the cells it built and
    // draws their pieces; the ranks' drawings are combined.
    let parts = run_backend.parts();
    if let Some((parts, polyhedra)) = parts.and_then(|p| Some((p, diagram.cells.polyhedra.take()?))) {
        let cells = &diagram.cells;
        let numbers = |k: usize| {
            let i = polyhedra[k].site as usize;
            (cells.volume[i], cells.centroid[i], cells.energy[i])
        };
        let mut wrote = crate::parts::write_polyhedra(parts.comm(), &dir, &polyhedra, &numbers)?;
        if let (Domain::Mesh(mesh), Some(pieces)) = (&inputs.domain, &diagram.pieces) {
            if let Some(mut pictures) = crate::pictures::PartsPictures::asked(args, mesh, &dir) {
                pictures.visit(pieces, parts.rank())?;
                wrote.extend(pictures.finish(parts.comm(), &dir)?);
            }
        }
        let lids: u64 = polyhedra.iter().map(|p| p.repaired_holes as u64).sum();
        let mut tally = [diagram.pieces.take().map_or(0, |p| p.len()) as i64, lids as i64];
        parts.comm().sum(&mut tally)?;
        pieces_in_parts = Some((tally[0] as usize, tally[1] as u64));
        written_in_parts.extend(wrote);
    }
    if !writes {
        return Ok(status);
    }
    let box_mesh;
    let mesh = match &inputs.domain {
        Domain::Mesh(mesh) => mesh,
        Domain::Box(b) => {
            box_mesh = b.mesh(inputs.sites.len());
            &box_mesh
        }
    };
    let mut summary =
        Summary::new(&inputs.name, mesh, diagram.sites.len(), diagram.cells.strategy, backend, &diagram.cells);
    summary.cvt = optimised.cvt;
    summary.transport = optimised.transport;
    summary.parts = run_backend.parts().map(|d| d.report());
    summary.periodic = diagram.periodic.map(|p| PeriodicRecord { wrapped: inputs.wrapped, ..p });
    if let Some(p) = &diagram.particles {
        summary.particles = Some(ParticlesRecord::of(p, &args.index_thresholds()?));
    }
    let polyhedra = diagram.cells.polyhedra();
    if let (Some(pieces), Some(polyhedra)) = (&diagram.pieces, polyhedra) {
        summary.pieces = Some(pieces.len());
        summary.lids = Some(polyhedra.iter().map(|p| p.repaired_holes as u64).sum());
    }
    if let Some((pieces, lids)) = pieces_in_parts {
        (summary.pieces, summary.lids) = (Some(pieces), Some(lids));
    }
    let results = Results {
        args,
        mesh: match &inputs.domain {
            Domain::Mesh(mesh) => Some(mesh),
            Domain::Box(_) => None,
        },
        cells: &diagram.cells,
        sites: &diagram.sites,
        weights: optimised.weights.as_deref().filter(|_| summary.transport.is_some()),
        pieces: diagram.pieces.as_ref(),
        particles: diagram.particles.as_ref(),
        summary: &summary,
    };
    let mut written = outputs::write_all(&dir, &results)?;
    written.extend(written_in_parts.iter().map(|w| w.to_string()));
    print!("{summary}");
    if inputs.wrapped > 0 {
        println!("{} sites were outside the box: wrapped into it (sites.xyz holds them wrapped)", inputs.wrapped);
    }
    if matches!(inputs.domain, Domain::Box(_)) && !args.no_geometry && diagram.cells.polyhedra().is_none() {
        println!("the cells' geometry (cells.vtu, walls.ply) of a periodic box is drawn with --voronoi-index");
    }
    println!("wrote {}: {}", dir.display(), written.join(", "));
    outputs::write_copies(&results)?;
    if status == NOT_CONVERGED {
        eprintln!("cvd: optimal transport did not reach its tolerance (exit status {NOT_CONVERGED})");
    }
    Ok(status)
}

/// The CVT iterations or optimal transport the arguments ask for, if any.
fn optimise(args: &RunArgs, inputs: &Inputs, backend: &dyn Backend) -> cvd::Result<Optimised> {
    let sites = &inputs.sites;
    match &inputs.domain {
        Domain::Mesh(mesh) => {
            let cv = ClippedVoronoi::new(mesh, sites).strategy(args.strategy).k_site(args.k_site).backend(backend);
            let cv = cv.density(inputs.density.as_deref());
            optimise_on(args, inputs, &cv, cv)
        }
        Domain::Box(b) => {
            let pv = PeriodicVoronoi::new(*b, sites).strategy(args.strategy).k_site(args.k_site);
            let pv = pv.faces(!args.no_neighbors).backend(backend);
            let ot = PeriodicVoronoi::new(*b, sites).strategy(args.strategy).k_site(args.k_site).backend(backend);
            optimise_on(args, inputs, &pv, ot)
        }
    }
}

/// [`optimise`] with the diagram the optimisers iterate on, and the one
/// optimal transport solves on.
fn optimise_on<D: SiteDiagram>(
    args: &RunArgs,
    inputs: &Inputs,
    iterated: &dyn SiteDiagram,
    transported: D,
) -> cvd::Result<Optimised> {
    let weights = inputs.weights.clone();
    if args.transports() {
        let n = inputs.sites.len();
        let capacities = match (&args.capacities, args.volumes) {
            (Some(p), _) => Some(per_site(p, "capacities", n)?),
            (None, Some(law)) => Some(law.draw(n, args.seed)),
            (None, None) => None,
        };
        return transport(args, transported, weights.as_deref(), capacities);
    }
    if args.iterations == 0 {
        return Ok(Optimised { sites: inputs.sites.clone(), cvt: None, weights, transport: None });
    }
    let name = args.optimizer.name();
    let run = with_iterations(name, args.iterations, |show| args.optimizer.run(iterated, args.iterations, show))?;
    let record = CvtRecord::of(name, &run.iterations);
    // The table shows the empty cells; what no pass could finish is said here.
    let unresolved: u64 = record.unresolved.iter().sum();
    if unresolved > 0 {
        println!("{name}: {unresolved} pieces unresolved over the iterations (their volume was missing)");
    }
    Ok(Optimised { sites: run.sites, cvt: Some(record), weights, transport: None })
}

/// The diagram of the optimised sites: its cells, and on a mesh, unless
/// `--no-geometry` (or in parts), each cell's polyhedron.
fn final_diagram(args: &RunArgs, inputs: &Inputs, o: &Optimised, run: &RunBackend) -> cvd::Result<Diagram> {
    let backend = run.get();
    match &inputs.domain {
        Domain::Mesh(mesh) => {
            let mut cv = ClippedVoronoi::new(mesh, &o.sites)
                .strategy(args.strategy)
                .k(args.k)
                .k_site(args.k_site)
                .density(inputs.density.as_deref())
                .memory_budget(args.cpu_memory_budget());
            if let Some(w) = &o.weights {
                cv = cv.weights(w);
            }
            if let Some(pairing) = args.pairing {
                cv = cv.pairing(pairing);
            }
            let cv = cv.backend(backend);
            // Parts sum faces with whole cells only.
            let cv =
                cv.faces(!args.no_neighbors && !(run.in_parts() && cv.resolved_strategy() != cvd::Strategy::Whole));
            if args.warm_up {
                let first = with_spinner("warm-up run", || cv.compute())?;
                println!("warm-up run: {:.1} ms; the table shows the next", first.timings.total() * 1e3);
            }
            let parts = run.parts().filter(|_| cv.resolved_strategy() == cvd::Strategy::Whole);
            let (cells, pieces) = if let (Some(parts), false) = (parts, args.no_geometry) {
                // Each rank the polyhedra of the cells it built.
                let what = "clipped Voronoi diagram and its cells' polyhedra, in parts";
                let (cells, pieces) = with_spinner(what, || cv.compute_with_geometry_in_parts(parts))?;
                (cells, Some(pieces))
            } else if args.no_geometry || run.in_parts() {
                (with_spinner("clipped Voronoi diagram", || cv.compute())?, None)
            } else {
                // On the CPU backend the polyhedra come from the diagram's
                // own run (its times then include collecting the pieces and
                // merging them); another backend's, from a run on the CPU.
                let cpu = CpuBackend::new(args.backend.threads)?;
                let what = "clipped Voronoi diagram and its cells' polyhedra";
                let (cells, pieces) = with_spinner(what, || cv.compute_with_geometry(&cpu))?;
                (cells, Some(pieces))
            };
            let particles = particles(args, &cells, o.sites.len())?;
            Ok(Diagram { cells, sites: o.sites.clone(), pieces, periodic: None, particles })
        }
        Domain::Box(b) => {
            let mut pv = PeriodicVoronoi::new(*b, &o.sites)
                .strategy(args.strategy)
                .k_site(args.k_site)
                .faces(!args.no_neighbors)
                .memory_budget(args.cpu_memory_budget())
                .backend(backend);
            if let Some(w) = &o.weights {
                pv = pv.weights(w);
            }
            if args.warm_up {
                let first = with_spinner("warm-up run", || pv.compute())?;
                println!("warm-up run: {:.1} ms; the table shows the next", first.cells.timings.total() * 1e3);
            }
            let out = if args.voronoi_index {
                let cpu = CpuBackend::new(args.backend.threads)?;
                with_spinner("periodic Voronoi diagram and its cells' polyhedra", || pv.compute_with_polyhedra(&cpu))?
            } else {
                with_spinner("periodic Voronoi diagram", || pv.compute())?
            };
            let periodic = PeriodicRecord::of(b, &out);
            let particles = particles(args, &out.cells, out.sites.len())?;
            Ok(Diagram { cells: out.cells, sites: out.sites, pieces: None, periodic: Some(periodic), particles })
        }
    }
}

/// The particles' quantities of `cells` (`--voronoi-index`), from their
/// polyhedra.
fn particles(args: &RunArgs, cells: &Cells, n: usize) -> cvd::Result<Option<ParticleCells>> {
    if !args.voronoi_index {
        return Ok(None);
    }
    let Some(polyhedra) = cells.polyhedra() else {
        return Err(cvd::Error::InvalidInput(
            "--voronoi-index needs the cells' polyhedra: not with --no-geometry or in parts".into(),
        ));
    };
    Ok(Some(ParticleCells::of(n, polyhedra, &args.index_thresholds()?)))
}

fn create_dir(dir: &std::path::Path) -> cvd::Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| cvd::Error::Write { path: dir.display().to_string(), source })
}
