//! `cvd`: the command-line tool.

use clap::{Args, Parser, Subcommand};
use cvd::backends::distributed::Distributed;
use cvd::backends::vulkan::{self, VulkanOptions};
use cvd::backends::{self, BackendChoice, BackendOptions};
use cvd::cvt::transport::Transport;
use cvd::cvt::{Optimizer, SiteDiagram};
use cvd::exec::CpuBackend;
use cvd::mesher::models;
use cvd::{geom::points, ClippedVoronoi, KnnJob, KnnMethod, Pairing, PeriodicBox, PeriodicVoronoi, Strategy, TetMesh};
use cvd_io as output;
use cvd_io::{CvtRecord, PeriodicRecord, Section, Summary, TransportRecord};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(name = "cvd", version, about = "Clipped Voronoi diagrams on Vulkan GPUs and CPU cores")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the Vulkan devices (the index or a part of the name picks one with --device).
    Devices {
        /// As JSON: index, name, type and whether it is a real GPU (what
        /// `--backend auto` would use).
        #[arg(long)]
        json: bool,
    },
    /// The clipped Voronoi diagram of random sites in a model.
    Run(Box<RunArgs>),
    /// k nearest neighbours of random sites; checks the backend against the CPU.
    Knn(KnnArgs),
    /// Write the kernels as SPIR-V modules, one per entry point, and their
    /// manifest.json (docs/EMBEDDING.md).
    Spirv {
        /// Output folder.
        #[arg(long, default_value = "spirv")]
        out: PathBuf,
    },
}

#[derive(Args)]
struct RunArgs {
    /// Model: built-in `joint`, `torus`, `sphere` or `cube` (meshed on the
    /// fly), or NAME.mesh / NAME_*.mesh / NAME.tet in the models folder.
    #[arg(long, default_value = "joint")]
    model: String,
    /// Folder of model files (default: $CVD_MODELS); its files win over built-in models.
    #[arg(long)]
    models_dir: Option<PathBuf>,
    /// A tet mesh file (.mesh, .node/.ele, .tet, .msh) instead of --model.
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// A closed triangle surface (.stl, .obj, .off, .ply) whose volume is
    /// meshed into tets (isosurface stuffing, --resolution lattice cubes
    /// along its longest side; default 40) instead of --model.
    #[arg(long, conflicts_with = "mesh")]
    surface: Option<PathBuf>,
    /// With --surface: about this many tets (sets the resolution; instead
    /// of --resolution).
    #[arg(long, conflicts_with = "resolution")]
    tets: Option<usize>,
    /// Built-in model resolution: lattice cells along the longest side
    /// (cube: sub-cubes per side; default: joint 37, others 16).
    #[arg(long)]
    resolution: Option<u32>,
    /// Number of sites, uniform inside the mesh (default: joint 35000, as
    /// in the paper's Table 1; others 5000).
    #[arg(long)]
    sites: Option<usize>,
    /// Sites from a file: .npy (NumPy, an (N, 3) array of float64 or
    /// float32) or else .xyz (x y z per line, optional count line).
    #[arg(long)]
    sites_file: Option<PathBuf>,
    /// Random seed of the sites.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Tet-cell or cell-tet.
    #[arg(long, value_enum, default_value_t = Strategy::TetCell)]
    strategy: Strategy,
    /// Pairing of tets and sites: flood (exact; default for tet-cell) or knn
    /// (paper Eq. 6; default for cell-tet).
    #[arg(long, value_enum)]
    pairing: Option<Pairing>,
    /// Sites paired with each tet (default: the paper's Eq. 6).
    #[arg(long, short)]
    k: Option<usize>,
    /// Lloyd iterations before the final diagram (0: the diagram of the
    /// sites as given). On Vulkan the loop runs on the device.
    #[arg(long, default_value_t = 0)]
    iterations: usize,
    /// A density ρ(x, y, z) > 0 weighting volumes, centroids and energies,
    /// e.g. "1+10*x" (world coordinates; + - * / ^, exp sqrt abs sin cos),
    /// evaluated at the mesh vertices and linear inside each tet.
    #[arg(long, conflicts_with = "density_file")]
    density: Option<String>,
    /// A density per mesh vertex from a file: one number per line, in the
    /// mesh's vertex order (`#` comments allowed).
    #[arg(long)]
    density_file: Option<PathBuf>,
    /// Power (Laguerre) cells: a weight per site from a file, one number
    /// per line in the sites' order (`#` comments allowed), in squared
    /// units of length; site i's cell is where |x - x_i|² - w_i is least.
    /// Cells may be empty (counted). With --transport: where its Newton
    /// steps start.
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Optimal transport: find the power weights that give every cell the
    /// same mass (the mesh's volume, or mass under a density, over the
    /// sites), by damped Newton steps; writes weights.txt. With
    /// --iterations: the capacity-constrained CVT (transport, then sites
    /// to their cells' centroids, each iteration).
    #[arg(long)]
    transport: bool,
    /// Optimal transport to a capacity per site from a file (one positive
    /// number per line in the sites' order, normalised to the mesh's mass);
    /// implies --transport.
    #[arg(long, value_name = "PATH")]
    capacities: Option<PathBuf>,
    /// Optimal transport stops when every cell's mass is within this of
    /// its target, relative to it.
    #[arg(long, default_value_t = 1e-6)]
    tolerance: f64,
    /// Optimal transport's Newton steps at most (per solve).
    #[arg(long, default_value_t = 50)]
    newton_steps: usize,
    /// How the iterations minimise the CVT energy.
    #[arg(long, value_enum, default_value_t = Optimizer::Lloyd)]
    optimizer: Optimizer,
    /// Neighbours per site for its cell [default: 48 for flood pairing on
    /// the CPU (a piece its list does not settle walks the site grid), 90
    /// otherwise].
    #[arg(long)]
    k_site: Option<usize>,
    /// A periodic box: each site's cell in the space the box tiles, cut
    /// into the box (sites outside it are wrapped in); the box from --box,
    /// or the unit cube with --model cube. neighbors.csv gains each
    /// neighbour's image shift.
    #[arg(long)]
    periodic: bool,
    /// The periodic box's corners (implies --periodic).
    #[arg(long = "box", value_name = "X0,Y0,Z0,X1,Y1,Z1", value_delimiter = ',', allow_hyphen_values = true)]
    periodic_box: Option<Vec<f64>>,
    /// Output folder [default: out/<model or mesh file name>/].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write cells.csv (site, volume, centroid, energy) to PATH.
    #[arg(long, value_name = "PATH")]
    output: Option<PathBuf>,
    /// Also write summary.json to PATH.
    #[arg(long, value_name = "PATH")]
    json: Option<PathBuf>,
    /// Skip the cells' geometry: cells.vtu, walls.ply and the pictures.
    /// The geometry takes one more run on the CPU, which keeps every piece
    /// (each site's cell inside each tet) in memory to merge them.
    #[arg(long, alias = "no-pieces")]
    no_geometry: bool,
    /// Also write pieces.vtu: every piece (each site's cell inside each tet)
    /// as a VTK polyhedron (ASCII, several per tet: large).
    #[arg(long, conflicts_with = "no_geometry")]
    pieces: bool,
    /// Skip picture.png and cells.png (the cells cut by the plane through the
    /// middle of the mesh, and those below it in 3D).
    #[arg(long)]
    no_picture: bool,
    /// Skip neighbors.csv: the faces the cells share and their areas, and
    /// each cell's area on the domain's boundary (summed with the diagram).
    #[arg(long)]
    no_neighbors: bool,
    /// Compute the diagram once more before the timed run (caches, memory,
    /// the driver's kernel compilation), as benchmarks do.
    #[arg(long)]
    warm_up: bool,
    /// Compute in N parts by space, one after another, each with the sites
    /// of a halo around its tets: the same results to the bit, the lists and
    /// grids of one part in memory at a time. Started by `mpirun -np P`
    /// (a build with the `mpi` feature): N parts per rank, P x N in all.
    /// Cells only (cells.csv, sites.xyz, summary.json): no neighbours,
    /// polyhedra or transport yet. CPU backend.
    #[arg(long, value_name = "N")]
    parts: Option<usize>,
    /// In parts: the first round's halo, LISTED,BEYOND grid cells (about 5
    /// sites each) around a part's tets: the sites of the first get
    /// neighbour lists, those of both are held. Narrower halos hold fewer
    /// sites and leave more tets to later rounds; the results are the same.
    #[arg(long, value_name = "LISTED,BEYOND", value_parser = two_counts)]
    halo: Option<[u32; 2]>,
    #[command(flatten)]
    backend: BackendArgs,
}

/// `A,B`: two whole numbers.
fn two_counts(s: &str) -> Result<[u32; 2], String> {
    let v: Vec<&str> = s.split(',').collect();
    match v[..] {
        [a, b] => match (a.trim().parse(), b.trim().parse()) {
            (Ok(a), Ok(b)) => Ok([a, b]),
            _ => Err(format!("'{s}': expected two whole numbers of cells, such as 2,3")),
        },
        _ => Err(format!("'{s}': expected two numbers of cells separated by a comma, such as 2,3")),
    }
}

/// The backend of a run: one process's, or this rank's of a distributed run.
enum RunBackend {
    One(Box<dyn cvd::Backend>),
    Parts(Box<Distributed>),
}

impl RunBackend {
    fn get(&self) -> &dyn cvd::Backend {
        match self {
            RunBackend::One(b) => b.as_ref(),
            RunBackend::Parts(d) => d.as_ref(),
        }
    }

    /// This process's rank (0 without MPI).
    fn rank(&self) -> usize {
        match self {
            RunBackend::One(_) => 0,
            RunBackend::Parts(d) => d.rank(),
        }
    }
}

/// The backend `--backend` and `--parts` ask for (and MPI, when this
/// process was started by an MPI launcher), and why.
fn open_backend(args: &RunArgs) -> cvd::Result<(RunBackend, String)> {
    let (comm, warning) = cvd::backends::distributed::launched_comm()?;
    if let Some(warning) = warning {
        eprintln!("cvd: {warning}");
    }
    if comm.is_none() && args.parts.is_none() {
        let backends::Chosen { backend, why } = backends::choose(&args.backend.options())?;
        return Ok((RunBackend::One(backend), why));
    }
    if args.backend.backend == BackendChoice::Vulkan {
        return Err(cvd::Error::InvalidInput("a run in parts uses the CPU backend: drop --backend vulkan".into()));
    }
    if transports(args) {
        return Err(cvd::Error::InvalidInput("optimal transport does not run in parts yet".into()));
    }
    let comm = comm.unwrap_or_else(|| Box::new(cvd::backends::distributed::Alone));
    let why = format!("{} part(s) per rank, {}", args.parts.unwrap_or(1), comm.describe());
    let cpu = CpuBackend::new(args.backend.threads)?;
    let mut d = Distributed::new(cpu, comm, args.parts.unwrap_or(1))?;
    if let Some([listed, beyond]) = args.halo {
        d = d.with_halo(listed, beyond);
    }
    Ok((RunBackend::Parts(Box::new(d)), why))
}

/// The model's mesh: an explicit file, a file of that name in the models
/// folder, or a built-in model.
fn load_model(args: &RunArgs) -> cvd::Result<(String, TetMesh)> {
    let (name, mut mesh) = find_model(args)?;
    let flipped = mesh.orient_positively();
    if flipped > 0 {
        eprintln!("{name}: {flipped} inverted tets, reoriented");
    }
    Ok((name, mesh))
}

/// Reads, checks and meshes a closed surface, saying what was fixed and how
/// good the mesh is.
fn mesh_surface_file(
    path: &std::path::Path,
    resolution: Option<u32>,
    tets: Option<usize>,
) -> cvd::Result<(String, TetMesh)> {
    let name = path.display().to_string();
    let (surface, r) = cvd_io::read_surface(path)?.into_closed(&name)?;
    let mut fixed = Vec::new();
    for (n, what) in [
        (r.dropped, "triangles with a repeated vertex dropped"),
        (r.reoriented, "triangles turned to agree with their neighbours"),
        (r.flipped_shells, "shells turned outward"),
        (r.zero_area, "triangles of zero area"),
    ] {
        if n > 0 {
            fixed.push(format!("{n} {what}"));
        }
    }
    if r.open_edges > 0 {
        fixed.push(format!(
            "{} open edges in {} cracks up to {:.2e} across, let through (the sign across them is the winding number's)",
            r.open_edges, r.cracks, r.widest_crack
        ));
    }
    let holes = if r.holes > 0 { format!(" ({} holes)", r.holes) } else { String::new() };
    println!(
        "{name}: {} triangles, {} shells{holes}, volume {:.6e}{}",
        r.triangles,
        r.shells,
        r.volume,
        if fixed.is_empty() { String::new() } else { format!("; {}", fixed.join(", ")) }
    );
    let resolution = match (resolution, tets) {
        (Some(r), _) => r,
        (None, Some(n)) => cvd::mesher::resolution_for_tets(&surface, n)?,
        (None, None) => cvd::mesher::DEFAULT_SURFACE_RESOLUTION,
    };
    let mesh = cvd::mesher::mesh_surface(&surface, resolution)?;
    let q = cvd::mesher::quality::Quality::of(&mesh);
    println!(
        "meshed at resolution {resolution}: {} tets, dihedral angles {:.1}..{:.1} degrees, volume {:+.3} % of the surface's",
        mesh.tets.len(),
        q.min_dihedral,
        q.max_dihedral,
        100.0 * (mesh.volume() - r.volume) / r.volume
    );
    Ok((name, mesh))
}

/// The model's mesh as found, before any repair.
fn find_model(args: &RunArgs) -> cvd::Result<(String, TetMesh)> {
    if let Some(path) = &args.mesh {
        return Ok((path.display().to_string(), cvd_io::read_mesh(path)?));
    }
    if let Some(path) = &args.surface {
        return mesh_surface_file(path, args.resolution, args.tets);
    }
    let dir = args.models_dir.clone().or_else(|| std::env::var_os("CVD_MODELS").map(PathBuf::from));
    if let Some(dir) = dir {
        let name = &args.model;
        let mut candidates = vec![dir.join(format!("{name}.mesh")), dir.join(format!("{name}.tet"))];
        if let Ok(entries) = std::fs::read_dir(&dir) {
            let mut more: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    let file = p.file_name().and_then(|f| f.to_str()).unwrap_or("");
                    file.starts_with(&format!("{name}_")) && file.ends_with(".mesh")
                })
                .collect();
            // joint_31k before joint_100k: numbers compare as numbers.
            more.sort_by_key(|p| natural_key(&p.to_string_lossy()));
            candidates.extend(more);
        }
        if let Some(path) = candidates.into_iter().find(|p| p.is_file()) {
            return Ok((path.display().to_string(), cvd_io::read_mesh(&path)?));
        }
        let surfaces = ["stl", "obj", "off", "ply"].map(|e| dir.join(format!("{name}.{e}")));
        if let Some(path) = surfaces.into_iter().find(|p| p.is_file()) {
            return mesh_surface_file(&path, args.resolution, args.tets);
        }
    }
    let name = args.model.as_str();
    if !models::NAMES.contains(&name) {
        return Err(cvd::Error::InvalidInput(format!(
            "unknown model '{name}': built-in models: {}; or give --mesh PATH, or --models-dir DIR holding {name}.mesh",
            models::NAMES.join(", ")
        )));
    }
    let mesh = models::builtin(name, args.resolution)?;
    let resolution = args.resolution.map_or_else(|| models::default_resolution(name), Ok)?;
    println!("{name} (built-in, resolution {resolution}): {}", cvd::mesher::quality::Quality::of(&mesh));
    Ok((name.to_string(), mesh))
}

/// A sort key in which runs of digits compare by value.
fn natural_key(s: &str) -> Vec<(String, u64)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = s.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut n = c.to_digit(10).unwrap_or(0) as u64;
            while let Some(d) = chars.peek().and_then(|d| d.to_digit(10)) {
                n = n.saturating_mul(10).saturating_add(d as u64);
                chars.next();
            }
            key.push((std::mem::take(&mut text), n));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// `out/<name>`: the model's name, or the mesh file's name without extension.
fn default_out_dir(model: &str) -> PathBuf {
    let stem = Path::new(model).file_stem().map(|s| s.to_string_lossy().into_owned());
    Path::new("out").join(stem.filter(|s| !s.is_empty()).unwrap_or_else(|| "model".into()))
}

/// Runs `f` under a spinner saying `what` (shown only on a terminal).
fn with_spinner<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let spinner = ProgressBar::new_spinner().with_message(what.to_string());
    spinner.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}").unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    spinner.enable_steady_tick(Duration::from_millis(100));
    let out = f();
    spinner.finish_and_clear();
    out
}

/// Runs `f` with a progress bar saying `what`, fed through `f`'s progress
/// callback (shown only on a terminal).
fn with_bar<T>(what: &str, f: impl FnOnce(&mut dyn FnMut(u64, u64)) -> T) -> T {
    let bar = ProgressBar::new(1).with_message(what.to_string());
    bar.set_style(
        ProgressStyle::with_template("{msg:<24} [{bar:40}] {percent:>3}% {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let out = f(&mut |done, total| {
        bar.set_length(total.max(1));
        bar.set_position(done);
    });
    bar.finish_and_clear();
    out
}

fn create_dir(dir: &Path) -> cvd::Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| cvd::Error::Write { path: dir.display().to_string(), source })
}

/// The density per mesh vertex the arguments ask for, if any.
fn density(args: &RunArgs, mesh: &TetMesh) -> cvd::Result<Option<Vec<f64>>> {
    if let Some(text) = &args.density {
        return Ok(Some(cvd::geom::density::Expr::parse(text)?.at_vertices(mesh, text)?));
    }
    let Some(path) = &args.density_file else { return Ok(None) };
    let values = cvd_io::read_values(path)?;
    if values.len() != mesh.vertices.len() {
        return Err(cvd::Error::InvalidInput(format!(
            "{}: {} density values for {} mesh vertices",
            path.display(),
            values.len(),
            mesh.vertices.len()
        )));
    }
    Ok(Some(values))
}

/// The power weights the arguments give, if any: one per site.
fn weights(args: &RunArgs, n_sites: usize) -> cvd::Result<Option<Vec<f64>>> {
    let Some(path) = &args.weights else { return Ok(None) };
    if args.iterations > 0 && !transports(args) {
        return Err(cvd::Error::InvalidInput(
            "--weights with --iterations: CVT iterations keep power weights only with --transport \
             (the capacity-constrained CVT)"
                .into(),
        ));
    }
    per_site(path, "weights", n_sites).map(Some)
}

/// One value per site from `path`, the count checked.
fn per_site(path: &Path, what: &str, n_sites: usize) -> cvd::Result<Vec<f64>> {
    let values = cvd_io::read_values(path)?;
    if values.len() != n_sites {
        return Err(cvd::Error::InvalidInput(format!(
            "{}: {} {what} for {n_sites} sites",
            path.display(),
            values.len()
        )));
    }
    Ok(values)
}

/// Whether the arguments ask for optimal transport.
fn transports(args: &RunArgs) -> bool {
    args.transport || args.capacities.is_some()
}

/// What an optimal transport run gives the final diagram.
struct Transported {
    /// The sites (moved by the capacity-constrained CVT's iterations).
    sites: Vec<[f64; 3]>,
    /// The CVT's record, with iterations.
    cvt: Option<CvtRecord>,
    /// The weights found for `sites`.
    weights: Vec<f64>,
    /// The last solve's record.
    record: TransportRecord,
}

/// The optimal transport the arguments ask for, from the weights `start`
/// (if any): the weights that give every cell its target mass, with the
/// solve's record; with --iterations, the capacity-constrained CVT first
/// (its moved sites and record). Prints each Newton step of the final
/// solve.
fn transport(
    args: &RunArgs,
    mesh: &TetMesh,
    sites: &[[f64; 3]],
    start: Option<&[f64]>,
    backend: &dyn cvd::Backend,
    periodic: Option<PeriodicBox>,
) -> cvd::Result<Transported> {
    if args.optimizer != Optimizer::Lloyd {
        return Err(cvd::Error::InvalidInput(
            "--transport with --optimizer lbfgs: the capacity-constrained CVT moves sites by Lloyd steps".into(),
        ));
    }
    let capacities = args.capacities.as_deref().map(|p| per_site(p, "capacities", sites.len())).transpose()?;
    let density = density(args, mesh)?;
    let cv = ClippedVoronoi::new(mesh, sites).k_site(args.k_site).backend(backend).density(density.as_deref());
    match periodic {
        Some(domain) => {
            let pv = PeriodicVoronoi::new(domain, sites).k_site(args.k_site).backend(backend);
            transport_on(args, pv, start, capacities.as_deref())
        }
        None => transport_on(args, cv, start, capacities.as_deref()),
    }
}

/// [`transport`] on `diagram`.
fn transport_on<D: SiteDiagram>(
    args: &RunArgs,
    diagram: D,
    start: Option<&[f64]>,
    capacities: Option<&[f64]>,
) -> cvd::Result<Transported> {
    let sites = diagram.starting_sites().to_vec();
    let mut ot = Transport::new(diagram).tolerance(args.tolerance).max_steps(args.newton_steps);
    if let Some(c) = capacities {
        ot = ot.capacities(c);
    }
    if let Some(w) = start {
        ot = ot.start(w);
    }
    let targets = if capacities.is_some() { "capacities" } else { "uniform" };
    let (sites, cvt, run) = if args.iterations > 0 {
        let bar = indicatif::ProgressBar::new(args.iterations as u64).with_style(
            indicatif::ProgressStyle::with_template("{msg} {bar:30} {pos}/{len} iterations, {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message("capacity-constrained CVT");
        let (cvt, run) = ot.cvt(args.iterations, &mut |done, energy| {
            bar.set_position(done as u64);
            bar.set_message(format!("capacity-constrained CVT, energy {energy:.6e}"));
        })?;
        bar.finish_and_clear();
        let record = CvtRecord::of("lloyd-transport", &cvt.iterations);
        (cvt.sites, Some(record), run)
    } else {
        let mut step = 0;
        let run = ot.solve(&mut |s| {
            if s.step > 0.0 {
                step += 1;
                println!("transport: Newton step {step}: {s}");
            }
            true
        })?;
        (sites, None, run)
    };
    let record = TransportRecord::of(targets, args.tolerance, &run);
    if !run.converged {
        eprintln!(
            "transport: the masses came within {:.2e} of their targets, not {:.0e}: {}",
            record.max_error,
            args.tolerance,
            if record.steps == args.newton_steps {
                "out of Newton steps (--newton-steps)"
            } else {
                "no step along Newton's direction improved them (the diagram's precision, about 1e-6 of a cell)"
            }
        );
    }
    Ok(Transported { sites, cvt, weights: run.weights, record })
}

/// Runs the CVT iterations with a progress bar; returns the final sites and
/// the optimiser's record.
fn lloyd(
    args: &RunArgs,
    mesh: &TetMesh,
    sites: &[[f64; 3]],
    backend: &dyn cvd::Backend,
) -> cvd::Result<(Vec<[f64; 3]>, CvtRecord)> {
    let bar = indicatif::ProgressBar::new(args.iterations as u64).with_style(
        indicatif::ProgressStyle::with_template("{msg} {bar:30} {pos}/{len} iterations, {elapsed} ({per_sec})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(format!("{:?}", args.optimizer));
    let density = density(args, mesh)?;
    let cv = ClippedVoronoi::new(mesh, sites).k_site(args.k_site).backend(backend).density(density.as_deref());
    let show = |done: usize, energy: f64| {
        bar.set_position(done as u64);
        bar.set_message(format!("{:?}, energy {energy:.6e}", args.optimizer));
    };
    let run = args.optimizer.run(&cv, args.iterations, &mut |done, energy| show(done, energy))?;
    bar.finish_and_clear();
    let name = args.optimizer.name().to_string();
    let record = CvtRecord::of(&name, &run.iterations);
    // The table shows the empty cells; what no pass could finish is said here.
    let unresolved: u64 = record.unresolved.iter().sum();
    if unresolved > 0 {
        println!("{name}: {unresolved} pieces unresolved over the iterations (their volume was missing)");
    }
    Ok((run.sites, record))
}

fn run(args: &RunArgs) -> cvd::Result<()> {
    if args.periodic || args.periodic_box.is_some() {
        return run_periodic(args);
    }
    let (model, mesh) = load_model(args)?;
    // The sites as given (a file's coordinates to the last digit).
    let sites: Vec<[f64; 3]> = match &args.sites_file {
        Some(path) => cvd_io::read_sites(path)?,
        None => {
            let n = match args.sites {
                Some(n) => n,
                None => models::default_sites(&args.model).unwrap_or(5000),
            };
            points::in_mesh(&mesh, n, args.seed)
        }
    };
    let weights = weights(args, sites.len())?;
    let dir = args.out.clone().unwrap_or_else(|| default_out_dir(&model));
    let (run_backend, why) = open_backend(args)?;
    let backend = run_backend.get();
    // Every rank computes; rank 0 writes and speaks.
    let writes = run_backend.rank() == 0;
    if !writes {
        quiet_stdout();
    }
    // Before the long part: a folder that cannot be made fails now.
    if writes {
        create_dir(&dir)?;
    }
    // Cells only in parts (said, not dropped silently).
    let parts = matches!(run_backend, RunBackend::Parts(_));
    let (no_neighbors, no_geometry) = (args.no_neighbors || parts, args.no_geometry || parts);
    if parts && !(args.no_neighbors && args.no_geometry) {
        println!("in parts: cells only (no neighbors.csv, cells.vtu, walls.ply or pictures yet)");
    }
    println!(
        "{model}: {} tets, {} sites, {} on {} — {why}",
        mesh.tets.len(),
        sites.len(),
        args.strategy.name(),
        backend.name()
    );
    let (sites, record, weights, transported) = if transports(args) {
        let t = transport(args, &mesh, &sites, weights.as_deref(), backend, None)?;
        (t.sites, t.cvt, Some(t.weights), Some(t.record))
    } else if args.iterations > 0 {
        let (sites, record) = lloyd(args, &mesh, &sites, backend)?;
        (sites, Some(record), weights, None)
    } else {
        (sites, None, weights, None)
    };
    // The energy against the iteration.
    if let (Some(record), true) = (&record, writes) {
        let series = [output::Series { name: &record.optimizer, values: &record.energy, x: &[], rgb: [200, 40, 40] }];
        output::write_line_chart_png(&dir.join("energy.png"), "cvt energy", &series)?;
    }
    let density = density(args, &mesh)?;
    let mut cv = ClippedVoronoi::new(&mesh, &sites)
        .strategy(args.strategy)
        .k(args.k)
        .k_site(args.k_site)
        .density(density.as_deref())
        .faces(!no_neighbors);
    if let Some(w) = &weights {
        cv = cv.weights(w);
    }
    if let Some(pairing) = args.pairing {
        cv = cv.pairing(pairing);
    }
    let cv = cv.backend(backend);
    if args.warm_up {
        let first = with_spinner("warm-up run", || cv.compute())?;
        println!("warm-up run: {:.1} ms; the table shows the next", first.timings.total() * 1e3);
    }
    // On the CPU backend the cells' polyhedra come from the diagram's own
    // run (its times then include collecting the pieces and merging them);
    // another backend's pieces stay on its device, so the CPU makes them
    // in a second run below.
    let cpu_geometry = !no_geometry && backend.kind() == cvd::BackendKind::Cpu;
    let (cells, geometry) = if cpu_geometry {
        let cpu = CpuBackend::new(args.backend.threads)?;
        let (cells, pieces) =
            with_spinner("clipped Voronoi diagram and its cells' polyhedra", || cv.compute_with_polyhedra(&cpu))?;
        (cells, Some(pieces))
    } else {
        (with_spinner("clipped Voronoi diagram", || cv.compute())?, None)
    };
    let compiled = backend.kernel_compile_seconds();
    if compiled > 0.0 {
        println!("kernels: the driver compiled them in {compiled:.2} s on first use (not in the times below)");
    }
    if !writes {
        return Ok(());
    }
    let mut summary = Summary::new(&model, &mesh, sites.len(), args.strategy, backend, &cells);
    summary.cvt = record;
    summary.transport = transported;
    if let RunBackend::Parts(d) = &run_backend {
        summary.parts = Some(d.report());
    }

    let mut written = Vec::new();
    let mut file = |name: &str| {
        written.push(name.to_string());
        dir.join(name)
    };
    output::write_cells_csv(&file("cells.csv"), &cells)?;
    if let Some(adjacency) = cells.adjacency() {
        output::write_neighbors_csv(&file("neighbors.csv"), adjacency)?;
    }
    // The sites of the diagram: as given, or where the iterations moved them.
    cvd_io::write_sites_xyz(&file("sites.xyz"), &sites)?;
    if let (Some(w), Some(_)) = (&weights, &summary.transport) {
        cvd_io::write_values(&file("weights.txt"), w)?;
    }
    if !no_geometry {
        let (with_polyhedra, pieces) = match geometry {
            Some(pieces) => (None, pieces),
            None => {
                let cpu = CpuBackend::new(args.backend.threads)?;
                // The adjacency came with the diagram above; the polyhedra's
                // run needs only the pieces.
                let (cells, pieces) =
                    with_spinner("cells' polyhedra, on the CPU", || cv.faces(false).compute_with_polyhedra(&cpu))?;
                (Some(cells), pieces)
            }
        };
        summary.pieces = Some(pieces.len());
        if args.pieces {
            let path = file("pieces.vtu");
            with_bar("writing pieces.vtu", |progress| output::write_pieces_vtu(&path, &pieces, progress))?;
        }
        if !args.no_picture {
            let path = file("picture.png");
            let section = Section::middle(&mesh);
            with_bar("drawing picture.png", |progress| {
                output::write_section_png(&path, &mesh, &pieces, section, PICTURE_SIZE, progress)
            })?;
            let path = file("cells.png");
            with_bar("drawing cells.png", |progress| {
                output::write_cells_view_png(&path, &pieces, &sites, section.z, PICTURE_SIZE, progress)
            })?;
        }
        drop(pieces);
        let polyhedra = with_polyhedra.as_ref().unwrap_or(&cells).polyhedra().unwrap_or_default();
        summary.lids = Some(polyhedra.iter().map(|p| p.repaired_holes as u64).sum());
        let path = file("cells.vtu");
        with_bar("writing cells.vtu", |progress| output::write_cells_vtu(&path, &cells, polyhedra, progress))?;
        output::write_walls_ply(&file("walls.ply"), polyhedra)?;
    }
    summary.write_json(&file("summary.json"))?;
    print!("{summary}");
    println!("wrote {}: {}", dir.display(), written.join(", "));
    if let Some(path) = &args.output {
        output::write_cells_csv(path, &cells)?;
        println!("wrote {} (cells.csv)", path.display());
    }
    if let Some(path) = &args.json {
        summary.write_json(path)?;
        println!("wrote {} (summary.json)", path.display());
    }
    Ok(())
}

/// The periodic box of `--periodic` / `--box`.
fn periodic_box(args: &RunArgs) -> cvd::Result<PeriodicBox> {
    let refuse = |what: &str| Err(cvd::Error::InvalidInput(format!("--periodic: {what}")));
    let given = [
        (args.mesh.is_some(), "--mesh"),
        (args.surface.is_some(), "--surface"),
        (args.density.is_some() || args.density_file.is_some(), "a density"),
        (args.pieces, "--pieces"),
    ];
    if let Some((_, what)) = given.iter().find(|g| g.0) {
        return refuse(&format!("{what} is not available in a periodic box yet"));
    }
    match &args.periodic_box {
        Some(c) if c.len() == 6 => PeriodicBox::new([c[0], c[1], c[2]], [c[3], c[4], c[5]]),
        Some(c) => refuse(&format!("--box takes six numbers, X0,Y0,Z0,X1,Y1,Z1, not {}", c.len())),
        None if args.model == "cube" => Ok(PeriodicBox::unit()),
        None => refuse(&format!(
            "give the box (--box X0,Y0,Z0,X1,Y1,Z1), or --model cube for the unit cube, not --model {}",
            args.model
        )),
    }
}

/// `cvd run --periodic`: the cells of a periodic box (see
/// [`cvd::PeriodicVoronoi`]), with Lloyd's iterations first if asked.
fn run_periodic(args: &RunArgs) -> cvd::Result<()> {
    let domain = periodic_box(args)?;
    let sites: Vec<[f64; 3]> = match &args.sites_file {
        Some(path) => cvd_io::read_sites(path)?,
        None => {
            let (lo, l) = (domain.lo(), domain.lengths());
            let unit = points::uniform(args.sites.unwrap_or(5000), args.seed);
            unit.iter().map(|p| [0, 1, 2].map(|a| lo[a] + p[a] * l[a])).collect()
        }
    };
    let weights = weights(args, sites.len())?;
    // Said of the sites as given (the iterations move wrapped ones).
    let wrapped = sites.iter().filter(|&&p| domain.wrap(p) != p).count();
    let model = "periodic box".to_string();
    let dir = args.out.clone().unwrap_or_else(|| default_out_dir("periodic"));
    create_dir(&dir)?;
    let backends::Chosen { backend, why } = backends::choose(&args.backend.options())?;
    let pv = PeriodicVoronoi::new(domain, &sites)
        .strategy(args.strategy)
        .k_site(args.k_site)
        .faces(!args.no_neighbors)
        .backend(backend.as_ref());
    println!(
        "{model} {:?} to {:?}: {} sites, {} on {} — {why}",
        domain.lo(),
        domain.hi(),
        sites.len(),
        args.strategy.name(),
        backend.name()
    );
    let mesh = domain.mesh(sites.len());
    let (moved, record, weights, transported) = if transports(args) {
        let t = transport(args, &mesh, &sites, weights.as_deref(), backend.as_ref(), Some(domain))?;
        (Some(t.sites), t.cvt, Some(t.weights), Some(t.record))
    } else if args.iterations > 0 {
        let name = args.optimizer.name().to_string();
        let bar = indicatif::ProgressBar::new(args.iterations as u64);
        let mut show = |done: usize, energy: f64| {
            bar.set_position(done as u64);
            bar.set_message(format!("{name}, energy {energy:.6e}"));
        };
        let run = args.optimizer.run(&pv, args.iterations, &mut show)?;
        bar.finish_and_clear();
        (Some(run.sites), Some(CvtRecord::of(&name, &run.iterations)), weights, None)
    } else {
        (None, None, weights, None)
    };
    if let Some(record) = &record {
        let series = [output::Series { name: &record.optimizer, values: &record.energy, x: &[], rgb: [200, 40, 40] }];
        output::write_line_chart_png(&dir.join("energy.png"), "cvt energy", &series)?;
    }
    let sites = moved.as_deref().unwrap_or(&sites);
    let mut pv = pv.sites(sites);
    if let Some(w) = &weights {
        pv = pv.weights(w);
    }
    if args.warm_up {
        let first = with_spinner("warm-up run", || pv.compute())?;
        println!("warm-up run: {:.1} ms; the table shows the next", first.cells.timings.total() * 1e3);
    }
    let out = with_spinner("periodic Voronoi diagram", || pv.compute())?;
    let cells = &out.cells;
    let mut summary = Summary::new(&model, &mesh, sites.len(), args.strategy, backend.as_ref(), cells);
    summary.cvt = record;
    summary.transport = transported;
    summary.periodic = Some(PeriodicRecord { wrapped, ..PeriodicRecord::of(&domain, &out) });
    let mut written = Vec::new();
    let mut file = |name: &str| {
        written.push(name.to_string());
        dir.join(name)
    };
    output::write_cells_csv(&file("cells.csv"), cells)?;
    if let Some(adjacency) = cells.adjacency() {
        output::write_neighbors_csv(&file("neighbors.csv"), adjacency)?;
    }
    cvd_io::write_sites_xyz(&file("sites.xyz"), &out.sites)?;
    if let (Some(w), Some(_)) = (&weights, &summary.transport) {
        cvd_io::write_values(&file("weights.txt"), w)?;
    }
    summary.write_json(&file("summary.json"))?;
    print!("{summary}");
    if wrapped > 0 {
        println!("{wrapped} sites were outside the box: wrapped into it (sites.xyz holds them wrapped)");
    }
    if !args.no_geometry {
        println!("the cells' geometry (cells.vtu, walls.ply, the pictures) is not drawn for periodic boxes");
    }
    println!("wrote {}: {}", dir.display(), written.join(", "));
    if let Some(path) = &args.output {
        output::write_cells_csv(path, cells)?;
        println!("wrote {} (cells.csv)", path.display());
    }
    if let Some(path) = &args.json {
        summary.write_json(path)?;
        println!("wrote {} (summary.json)", path.display());
    }
    Ok(())
}

/// Pixels along the longer side of picture.png.
const PICTURE_SIZE: usize = 1024;

#[derive(Args, Clone)]
struct BackendArgs {
    /// Where the kernels run.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    backend: BackendChoice,
    /// CPU backend threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Vulkan device: an index from `cvd devices` or part of its name (named
    /// devices are used by `--backend auto` too, GPU or not).
    #[arg(long)]
    device: Option<String>,
    /// Enable the Vulkan validation layer.
    #[arg(long)]
    validation: bool,
    /// Most device memory a job may hold, in MiB (default: 80 % of the
    /// device's memory); larger jobs run in chunks.
    #[arg(long, value_name = "MIB")]
    memory_budget: Option<u64>,
}

impl BackendArgs {
    fn options(&self) -> BackendOptions {
        BackendOptions {
            choice: self.backend,
            threads: self.threads,
            vulkan: VulkanOptions {
                device: self.device.clone(),
                validation: self.validation,
                memory_budget: self.memory_budget.map(|mib| mib << 20),
            },
        }
    }
}

#[derive(Args)]
struct KnnArgs {
    /// Number of sites, uniform in the unit cube.
    #[arg(long, default_value_t = 35_000)]
    sites: usize,
    /// Neighbours per site.
    #[arg(long, short, default_value_t = 90)]
    k: usize,
    /// Search method.
    #[arg(long, value_enum, default_value_t = KnnMethod::Grid)]
    method: KnnMethod,
    /// Random seed of the sites.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[command(flatten)]
    backend: BackendArgs,
}

fn knn(args: &KnnArgs) -> cvd::Result<()> {
    let backend = backends::open(&args.backend.options())?;
    let sites = points::uniform(args.sites, args.seed);
    let job = KnnJob::sites(&sites, args.k, args.method)?;
    println!("k-NN of {} uniform sites, k = {}, {:?}, on {}", args.sites, job.params.k, args.method, backend.name());
    let first = job.run(backend.as_ref())?;
    let again = job.run(backend.as_ref())?;
    println!("first run: {}", first.timings);
    println!("second run: {} (total {:.3} ms)", again.timings, again.timings.total() * 1e3);
    let reference = job.run(&cvd::exec::CpuBackend::new(args.backend.threads)?)?;
    let same = reference.indices == again.indices && reference.dist2 == again.dist2;
    println!("same neighbours as the CPU backend: {}", if same { "yes" } else { "NO" });
    if !same {
        return Err(cvd::Error::Internal("the backend disagrees with the CPU backend".into()));
    }
    Ok(())
}

/// `cvd devices`: the Vulkan devices, or none (no loader, no driver).
fn devices(json: bool) -> cvd::Result<()> {
    let devices = match vulkan::list_devices() {
        Ok(devices) => devices,
        Err(cvd::Error::VulkanUnavailable(why)) => {
            if !json {
                println!("no Vulkan device: {why}");
            }
            Vec::new()
        }
        Err(e) => return Err(e),
    };
    if json {
        let list: Vec<serde_json::Value> = devices
            .iter()
            .map(|d| serde_json::json!({ "index": d.index, "name": d.name, "type": d.kind_name(), "gpu": d.is_gpu() }))
            .collect();
        let text = serde_json::to_string_pretty(&list).map_err(|e| cvd::Error::Internal(e.to_string()))?;
        println!("{text}");
        return Ok(());
    }
    for d in &devices {
        println!("{}: {} ({})", d.index, d.name, d.kind_name());
    }
    if !vulkan::HAS_KERNELS {
        println!("(this build has no SPIR-V kernels: it runs on the CPU backend only)");
    }
    Ok(())
}

/// Sends this process's standard output to nowhere: the ranks of a
/// distributed run other than 0 compute without speaking.
fn quiet_stdout() {
    #[cfg(unix)]
    if let Ok(null) = std::fs::OpenOptions::new().write(true).open("/dev/null") {
        use std::os::fd::AsRawFd;
        // SAFETY: redirecting fd 1 to a file opened here; both stay valid.
        unsafe {
            libc::dup2(null.as_raw_fd(), 1);
        }
    }
}

fn cvd_kernels_abi_version() -> u64 {
    cvd::spirv::manifest()["abi_version"].as_u64().unwrap_or(0)
}

fn main() -> ExitCode {
    // Die quietly when the reader of our output goes away (`cvd ... | head`).
    #[cfg(unix)]
    // SAFETY: restoring the default action of a signal at start-up.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Large buffers straight from the system and back to it when freed:
    // glibc's default raises its mmap threshold after the first large free,
    // and the job's freed temporaries then stay resident under the buffers
    // that follow (about 90 MB of 575 MB at 1M sites).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: a malloc tuning call at start-up, before any other thread.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Devices { json } => devices(*json),
        Command::Run(args) => run(args),
        Command::Knn(args) => knn(args),
        Command::Spirv { out } => cvd::spirv::export(out).map(|files| {
            println!("wrote {} files into {} (ABI version {})", files.len(), out.display(), cvd_kernels_abi_version());
        }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cvd: {e}");
            // Like clap's own errors: 2 for what the user gave, 1 for the rest.
            ExitCode::from(if e.is_input_error() { 2 } else { 1 })
        }
    }
}
