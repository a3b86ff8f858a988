//! `cvd`: the command-line tool.

use clap::{Args, Parser, Subcommand};
use cvd::backend::{self, BackendKind, BackendOptions};
use cvd::mesher::models;
use cvd::vulkan::{self, VulkanOptions};
use cvd::{points, ClippedVoronoi, KnnJob, KnnMethod, Pairing, Strategy, TetMesh};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "cvd", version, about = "Clipped Voronoi diagrams on Vulkan GPUs and CPU cores")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the Vulkan devices (the index or a part of the name picks one with --device).
    Devices,
    /// The clipped Voronoi diagram of random sites in a model.
    Run(Box<RunArgs>),
    /// k nearest neighbours of random sites; checks the backend against the CPU.
    Knn(KnnArgs),
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
    /// Built-in model resolution: lattice cells along the longest side
    /// (cube: sub-cubes per side; default: joint 37, others 16).
    #[arg(long)]
    resolution: Option<u32>,
    /// Number of sites, uniform inside the mesh (default: joint 35000, as
    /// in the paper's Table 1; others 5000).
    #[arg(long)]
    sites: Option<usize>,
    /// Sites from a file (.xyz: x y z per line, optional count line).
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
    /// How the iterations minimise the CVT energy.
    #[arg(long, value_enum, default_value_t = Optimizer::Lloyd)]
    optimizer: Optimizer,
    /// Neighbours per site for its cell.
    #[arg(long, default_value_t = cvd::voronoi::DEFAULT_K_SITE)]
    k_site: usize,
    /// Write per-site results as CSV (index, site, volume, centroid, energy).
    #[arg(long)]
    output: Option<PathBuf>,
    #[command(flatten)]
    backend: BackendArgs,
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

/// The model's mesh as found, before any repair.
fn find_model(args: &RunArgs) -> cvd::Result<(String, TetMesh)> {
    if let Some(path) = &args.mesh {
        return Ok((path.display().to_string(), cvd::io::read_mesh(path)?));
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
            return Ok((path.display().to_string(), cvd::io::read_mesh(&path)?));
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

fn write_cells(path: &std::path::Path, sites: &[[f32; 3]], cells: &cvd::Cells) -> cvd::Result<()> {
    use std::io::Write;
    let io_err = |source| cvd::Error::Io { path: path.display().to_string(), source };
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).map_err(io_err)?);
    writeln!(out, "index,x,y,z,volume,cx,cy,cz,energy").map_err(io_err)?;
    for (i, s) in sites.iter().enumerate() {
        let c = cells.centroid[i];
        writeln!(
            out,
            "{i},{},{},{},{:e},{},{},{},{:e}",
            s[0], s[1], s[2], cells.volume[i], c[0], c[1], c[2], cells.energy[i]
        )
        .map_err(io_err)?;
    }
    out.flush().map_err(io_err)
}

/// The density per mesh vertex the arguments ask for, if any.
fn density(args: &RunArgs, mesh: &TetMesh) -> cvd::Result<Option<Vec<f32>>> {
    if let Some(text) = &args.density {
        return Ok(Some(cvd::density::Expr::parse(text)?.at_vertices(mesh, text)?));
    }
    let Some(path) = &args.density_file else { return Ok(None) };
    let values = cvd::io::read_values(path)?;
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

/// CVT optimisers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Optimizer {
    /// Lloyd's iteration: every site to its cell's centroid (on Vulkan, the
    /// whole loop runs on the device).
    Lloyd,
    /// L-BFGS (memory 7) with a line search that only accepts decreases.
    Lbfgs,
}

/// Runs the CVT iterations with a progress bar; returns the final sites.
fn lloyd(args: &RunArgs, mesh: &TetMesh, sites: &[[f32; 3]], backend: &dyn cvd::Backend) -> cvd::Result<Vec<[f32; 3]>> {
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
    let run = match args.optimizer {
        Optimizer::Lloyd => cv.lloyd(args.iterations, &mut |done, energy| show(done, energy))?,
        Optimizer::Lbfgs => cv.lbfgs(args.iterations, &mut |done, energy| show(done, energy))?,
    };
    bar.finish_and_clear();
    let total: f64 = run.iterations.iter().map(|i| i.seconds).sum();
    let (first, last) = (run.iterations[0], run.iterations[run.iterations.len() - 1]);
    println!(
        "{:?}: {} iterations in {:.3} s ({:.2} ms per iteration); energy {:.6e} -> {:.6e}",
        args.optimizer,
        run.iterations.len(),
        total,
        1e3 * total / run.iterations.len() as f64,
        first.energy,
        last.energy
    );
    let unresolved: u64 = run.iterations.iter().map(|i| i.unresolved).sum();
    let empty = run.iterations.iter().map(|i| i.empty_cells).max().unwrap_or(0);
    if unresolved > 0 || empty > 0 {
        println!(
            "Lloyd: up to {empty} empty cells in an iteration (their sites stayed); {unresolved} pieces unresolved"
        );
    }
    Ok(run.sites)
}

fn run(args: &RunArgs) -> cvd::Result<()> {
    let (model, mesh) = load_model(args)?;
    let sites = match &args.sites_file {
        Some(path) => cvd::io::read_sites(path)?,
        None => {
            let n = match args.sites {
                Some(n) => n,
                None => models::default_sites(&args.model).unwrap_or(5000),
            };
            points::in_mesh(&mesh, n, args.seed)
        }
    };
    let backend = backend::open(&args.backend.options())?;
    println!(
        "{model}: {} tets (volume {:.6}), {} sites, {:?}, on {}",
        mesh.tets.len(),
        mesh.volume(),
        sites.len(),
        args.strategy,
        backend.name()
    );
    let sites = if args.iterations > 0 { lloyd(args, &mesh, &sites, backend.as_ref())? } else { sites };
    let density = density(args, &mesh)?;
    let mut cv = ClippedVoronoi::new(&mesh, &sites)
        .strategy(args.strategy)
        .k(args.k)
        .k_site(args.k_site)
        .density(density.as_deref());
    if let Some(pairing) = args.pairing {
        cv = cv.pairing(pairing);
    }
    let first = cv.backend(backend.as_ref()).compute()?;
    println!("first run: {} (total {:.1} ms)", first.timings, first.timings.total() * 1e3);
    let cells = cv.backend(backend.as_ref()).compute()?;
    println!("second run: {} (total {:.1} ms)", cells.timings, cells.timings.total() * 1e3);
    println!(
        "{:?} pairing, k = {}, k_site = {}; volume {:.6} of {:.6}, E_vol = {:.2e}; energy {:.6e}",
        cells.pairing,
        cells.k,
        cells.k_site,
        cells.total_volume,
        cells.mesh_volume,
        cells.e_vol,
        cells.energy_total()
    );
    let c = &cells.counters;
    println!(
        "pairs {} (non-empty {}, dropped before clipping {}), clips {}; unfinished by the kernels: security radius {}, overflows {}, broken {}; \
         finished by the second pass {}, unresolved {}; duplicate sites {}, other empty cells {}",
        c.pairs,
        c.nonempty,
        c.filtered,
        c.clips,
        c.security_missed,
        c.overflows,
        c.broken,
        c.second_pass,
        c.unresolved,
        c.duplicate_sites,
        c.empty_cells
    );
    if let Some(path) = &args.output {
        write_cells(path, &sites, &cells)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[derive(Args, Clone)]
struct BackendArgs {
    /// Where the kernels run.
    #[arg(long, value_enum, default_value_t = BackendKind::Auto)]
    backend: BackendKind,
    /// CPU backend threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Vulkan device: an index from `cvd devices` or part of its name.
    #[arg(long)]
    device: Option<String>,
    /// Enable the Vulkan validation layer.
    #[arg(long)]
    validation: bool,
}

impl BackendArgs {
    fn options(&self) -> BackendOptions {
        BackendOptions {
            kind: self.backend,
            threads: self.threads,
            vulkan: VulkanOptions { device: self.device.clone(), validation: self.validation },
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
    let backend = backend::open(&args.backend.options())?;
    let sites = points::uniform(args.sites, args.seed);
    let job = KnnJob::sites(&sites, args.k, args.method)?;
    println!("k-NN of {} uniform sites, k = {}, {:?}, on {}", args.sites, job.params.k, args.method, backend.name());
    let first = job.run(backend.as_ref())?;
    let again = job.run(backend.as_ref())?;
    println!("first run: {}", first.timings);
    println!("second run: {} (total {:.3} ms)", again.timings, again.timings.total() * 1e3);
    let reference = job.run(&cvd::cpu::CpuBackend::new(args.backend.threads)?)?;
    let same = reference.indices == again.indices && reference.dist2 == again.dist2;
    println!("same neighbours as the CPU backend: {}", if same { "yes" } else { "NO" });
    if !same {
        return Err(cvd::Error::InvalidInput("the backend disagrees with the CPU backend".into()));
    }
    Ok(())
}

fn main() -> ExitCode {
    // Die quietly when the reader of our output goes away (`cvd ... | head`).
    #[cfg(unix)]
    // SAFETY: restoring the default action of a signal at start-up.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Devices => vulkan::list_devices().map(|devices| {
            for d in devices {
                println!("{}: {} ({:?})", d.index, d.name, d.kind);
            }
        }),
        Command::Run(args) => run(args),
        Command::Knn(args) => knn(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cvd: {e}");
            ExitCode::FAILURE
        }
    }
}
