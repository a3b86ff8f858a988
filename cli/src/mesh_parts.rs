//! `mpirun -np P cvd run --mesh domain.mesh --sites-file sites.npy`: a
//! mesh with its sites in parts. Every rank reads the mesh (small beside
//! the sites it is cut into); each reads (or makes) only its own rows of
//! the sites, computes the whole cells of its run of the curve
//! (`ClippedVoronoi::compute_in_parts`), and writes its rows of
//! `cells.csv`, `neighbors.csv` and `sites.xyz` at their place in the
//! files, and the polyhedra of the cells it built as its piece of
//! `cells.pvtu` and its section of `walls.ply`: the same bytes as one
//! process. The pictures are drawn as the pieces are made (see
//! [`crate::pictures`]). Power cells (each rank its rows of `--weights` or `--radii`),
//! a density (`--density`, `--density-file`: per mesh vertex, every rank
//! all of it), Lloyd, L-BFGS and optimal transport (`weights.txt`
//! likewise) too, on the CPU or a Vulkan device (`--backend`: the cells on
//! the device, the polyhedra on the CPU). Rank 0 writes `summary.json`,
//! with every rank's numbers.
//!
//! What it does not take yet ([`lacking`]) runs with every rank reading the
//! whole input (`cvd::backends::distributed`), and says so.

use crate::args::RunArgs;
use crate::optimise::Optimised;
use crate::parts::{optimise_in_parts, rows_of_sites, weights_of_rows, write_part, write_polyhedra};
use crate::pictures::PartsPictures;
use cvd::backends::distributed::Reduce;
use cvd::{ClippedVoronoi, ParticleCells};
use cvd_io::{Rows, Summary};

/// Writes a batch of a rank's rows (their cells, their particles'
/// quantities if asked for) to a file's part.
type WriteBatch<'a> =
    dyn Fn(&mut dyn std::io::Write, &cvd::Cells, Option<&ParticleCells>, Rows) -> std::io::Result<()> + 'a;

/// What a mesh with its sites in parts does not take yet, if `args` asks
/// for any of it: then every rank reads the whole input.
pub fn lacking(args: &RunArgs) -> Option<&'static str> {
    args.strategy.is_some_and(|s| s != cvd::Strategy::Whole).then_some("a strategy other than whole cells")
}

/// Runs a mesh with its sites in parts over `comm`'s ranks.
pub fn run(args: &RunArgs, comm: &dyn Reduce) -> cvd::Result<u8> {
    crate::parts::ending_together(comm, |comm| in_parts(args, comm))
}

fn in_parts(args: &RunArgs, comm: &dyn Reduce) -> cvd::Result<u8> {
    let clock = std::time::Instant::now();
    let (rank, ranks) = (comm.rank(), comm.size());
    let (name, mesh) = crate::inputs::load_model(args)?;
    let dir = crate::inputs::out_dir(args, &name);
    if rank == 0 {
        std::fs::create_dir_all(&dir)
            .map_err(|source| cvd::Error::Write { path: dir.display().to_string(), source })?;
    } else {
        crate::progress::quiet_stdout();
    }
    if let Some(scratch) = args.scratch.as_deref().filter(|s| !s.is_dir()) {
        return Err(cvd::Error::InvalidInput(format!(
            "--scratch {}: no such folder (each rank keeps the rows it will write in a file there)",
            scratch.display()
        )));
    }
    let n = args.sites.unwrap_or_else(|| cvd::mesher::models::default_sites(&args.model).unwrap_or(5000)) as u64;
    if args.sites_file.is_none() {
        crate::inputs::check_memory(args, n.div_ceil(ranks as u64), mesh.tets.len() as u64)?;
    }
    if args.weights.is_some() && args.iterations > 0 && !args.transports() {
        return Err(cvd::Error::InvalidInput(
            "--weights with --iterations: CVT iterations keep power weights only with --transport \
             (the capacity-constrained CVT)"
                .into(),
        ));
    }
    if args.voronoi_index && args.no_geometry {
        return Err(cvd::Error::InvalidInput(
            "--voronoi-index needs the cells' polyhedra: not with --no-geometry".into(),
        ));
    }
    let (sites, total) = rows_of_sites(args, comm, n, |rows| cvd::geom::points::in_mesh_rows(&mesh, rows, args.seed))?;
    let first: u64 = comm.gather_u64(sites.len() as u64)?[..rank].iter().sum();
    let weights = weights_of_rows(args, comm, sites.len(), first, total)?;
    // The cells on the backend asked for (a device's too: the whole-cell
    // kernel in a part's window); the polyhedra on the CPU.
    let backends = crate::backend::PartsBackends::open(&args.backend)?;
    let (cpu, backend, why, on) = (&backends.cpu, backends.cells(), &backends.why, backends.on());
    println!(
        "{name}: {} tets, {total} sites in parts over {} (each rank reading its rows), whole cells on {on} per rank \
         — {why}",
        mesh.tets.len(),
        comm.describe(),
    );
    // In parts, whole cells (asked for, or not): where one process would
    // take tet-cell, said.
    // A density: every rank the whole mesh's, as it holds the mesh.
    let density = crate::inputs::density(args, &mesh)?;
    let shape = cvd::JobShape { density: density.is_some(), sites: total as usize, tets: mesh.tets.len() };
    if args.strategy.is_none() && cvd::Strategy::auto(cvd::BackendKind::Cpu, shape) != cvd::Strategy::Whole {
        let why = match density {
            Some(_) => "under a density".to_string(),
            None => format!("{:.1} tets a site", mesh.tets.len() as f64 / total.max(1) as f64),
        };
        println!(
            "in parts: whole cells, where one process takes tet-cell ({why}): the cells agree to rounding, not to \
             the bit; --strategy tet-cell splits the tets instead, every rank reading the whole input"
        );
    }
    if let Some(warning) = crate::backend::threads_beyond_cores(args.backend.threads).filter(|_| rank == 0) {
        eprintln!("cvd: {warning}");
    }
    // The optimiser, each rank moving its own rows (and finding their
    // weights): one process's steps (Lloyd: one process's by diagrams).
    let iterated = ClippedVoronoi::new(&mesh, &sites)
        .strategy(cvd::Strategy::Whole)
        .density(density.as_deref())
        .k_site(args.k_site)
        .memory_budget(args.cpu_memory_budget())
        .backend(backend);
    let iterated = cvd::cvt::clipped::ClippedInParts::new(parts_asked(iterated, args.parts), comm);
    let optimised = optimise_in_parts(args, comm, iterated, weights.as_deref(), first, total)?;
    let Optimised { sites, cvt, weights, transport } =
        optimised.unwrap_or(Optimised { sites, cvt: None, weights, transport: None });
    let faces = !args.no_neighbors;
    // The rows' faces wait for their writing in a file, not in memory.
    let scratch = args.scratch.as_deref().unwrap_or(&dir);
    let diagram = ClippedVoronoi::new(&mesh, &sites)
        .strategy(cvd::Strategy::Whole)
        .density(density.as_deref())
        .k_site(args.k_site)
        .faces(faces)
        .memory_budget(args.cpu_memory_budget())
        .spill_rows_to(scratch)
        .backend(backend);
    let diagram = match &weights {
        Some(w) => parts_asked(diagram.weights(w), args.parts),
        None => parts_asked(diagram, args.parts),
    };
    let geometry = (!args.no_geometry).then_some(cpu);
    // The pictures drawn (and pieces written) as each sub-part's pieces
    // are made.
    let mut pictures = geometry.and_then(|_| PartsPictures::asked(args, &mesh, &dir));
    let out = match (geometry, &mut pictures) {
        (Some(cpu), Some(p)) => diagram.compute_in_parts_visiting(comm, cpu, &mut |pieces| p.visit(pieces, rank))?,
        _ => diagram.compute_in_parts_by_rows(comm, geometry)?,
    };
    // With --voronoi-index, each cell's polyhedron measured where it was
    // built; its numbers sent to its row's rank.
    let particles = match args.voronoi_index {
        true => Some(out.particles(comm, &args.index_thresholds()?)?),
        false => None,
    };
    let cvd::diagram::mesh_parts::MeshInParts { cells, rows: by_rows, built, pieces, report } = out;
    // The rows with their faces in batches, read back from the scratch
    // file: a rank holds a batch's faces at a time.
    let batches = |w: &mut dyn std::io::Write, write: &WriteBatch| {
        // At least one batch: rank 0 writes the header with no rows too.
        for start in (0..by_rows.len().max(1)).step_by(1 << 16) {
            let range = start..(start + (1 << 16)).min(by_rows.len());
            let batch = by_rows.cells(&cells, range.clone()).map_err(std::io::Error::other)?;
            let particles = particles.as_ref().map(|p| p.rows(range));
            write(w, &batch, particles.as_ref(), Rows { first: first + start as u64, total, periodic: false })?;
        }
        Ok(())
    };
    let rows = Rows { first, total, periodic: false };
    let mut written = vec!["cells.csv"];
    write_part(comm, &dir.join("cells.csv"), |w| {
        batches(w, &|w, c, p, rows| cvd_io::write_cells_csv_rows(w, c, p, None, rows))
    })?;
    if faces {
        write_part(comm, &dir.join("neighbors.csv"), |w| {
            batches(w, &|w, c, _, rows| match c.adjacency() {
                Some(a) => cvd_io::write_neighbors_csv_rows(w, a, rows),
                None => Ok(()),
            })
        })?;
        written.push("neighbors.csv");
    }
    write_part(comm, &dir.join("sites.xyz"), |w| cvd_io::write_sites_xyz_rows(w, &sites, rows))?;
    written.push("sites.xyz");
    if let (Some(w), Some(_)) = (&weights, &transport) {
        write_part(comm, &dir.join("weights.txt"), |out| cvd_io::write_values_rows(out, w))?;
        written.push("weights.txt");
    }
    let mut pieces_and_lids = None;
    if let Some(built) = &built {
        let numbers = |k: usize| built.numbers[k];
        written.extend(write_polyhedra(comm, &dir, &built.polyhedra, &numbers)?);
        let lids: u64 = built.polyhedra.iter().map(|p| p.repaired_holes as u64).sum();
        let mut tally = [pieces as i64, lids as i64];
        comm.sum(&mut tally)?;
        pieces_and_lids = Some((tally[0] as usize, tally[1] as u64));
    }
    if let Some(pictures) = pictures {
        written.extend(pictures.finish(comm, &dir)?);
    }

    // The run's numbers: totals from every rank, each rank's record.
    let (energy, records) = crate::parts::totals_and_records(comm, &cells, &report, clock)?;
    let indices = match &particles {
        Some(p) => Some(crate::parts::particles_record(comm, p, &args.index_thresholds()?)?),
        None => None,
    };
    let status = match &transport {
        Some(t) if !t.converged => crate::optimise::NOT_CONVERGED,
        _ => 0,
    };
    if rank != 0 {
        return Ok(status);
    }
    let mut summary = Summary::new(&name, &mesh, total as usize, cells.strategy, backend, &cells);
    summary.energy = energy;
    if let Some(record) = cvt {
        crate::outputs::write_energy_chart(&dir.join("energy.png"), &record)?;
        written.insert(0, "energy.png");
        summary.cvt = Some(record);
    }
    summary.transport = transport;
    summary.particles = indices;
    summary.ranks = Some(records);
    if let Some((pieces, lids)) = pieces_and_lids {
        (summary.pieces, summary.lids) = (Some(pieces), Some(lids));
    }
    summary.write_json(&dir.join("summary.json"))?;
    written.push("summary.json");
    print!("{summary}");
    crate::parts::print_ranks(&summary, "buckets of the curve");
    println!("wrote {}: {}", dir.display(), written.join(", "));
    crate::parts::write_copies(args, &dir)?;
    Ok(status)
}

/// `diagram` with `--parts` per rank where asked for (else the engine's
/// choice: [`cvd::diagram::mesh_parts::auto_parts`]).
fn parts_asked(diagram: ClippedVoronoi<'_>, parts: Option<usize>) -> ClippedVoronoi<'_> {
    match parts {
        Some(n) => diagram.parts_per_rank(n),
        None => diagram,
    }
}
