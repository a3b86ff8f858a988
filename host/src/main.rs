//! `cvd`: the command-line tool.

use clap::{Args, Parser, Subcommand};
use cvd::backend::{self, BackendKind, BackendOptions};
use cvd::vulkan::{self, VulkanOptions};
use cvd::{points, ClippedVoronoi, KnnJob, KnnMethod, Strategy, TetMesh};
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
    Run(RunArgs),
    /// k nearest neighbours of random sites; checks the backend against the CPU.
    Knn(KnnArgs),
}

#[derive(Args)]
struct RunArgs {
    /// Built-in model: cube.
    #[arg(long, default_value = "cube")]
    model: String,
    /// Model resolution (cube: sub-cubes per side).
    #[arg(long, default_value_t = 16)]
    resolution: usize,
    /// Number of sites, uniform in the model's bounding box.
    #[arg(long, default_value_t = 5000)]
    sites: usize,
    /// Random seed of the sites.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Tet-cell or cell-tet.
    #[arg(long, value_enum, default_value_t = Strategy::TetCell)]
    strategy: Strategy,
    /// Sites paired with each tet (default: the paper's Eq. 6).
    #[arg(long, short)]
    k: Option<usize>,
    /// Neighbours per site for its cell.
    #[arg(long, default_value_t = cvd::voronoi::DEFAULT_K_SITE)]
    k_site: usize,
    #[command(flatten)]
    backend: BackendArgs,
}

fn run(args: &RunArgs) -> cvd::Result<()> {
    let mesh = match args.model.as_str() {
        "cube" => TetMesh::cube(args.resolution),
        other => return Err(cvd::Error::InvalidInput(format!("unknown model '{other}'; built-in models: cube"))),
    };
    let backend = backend::open(&args.backend.options())?;
    let sites = points::uniform(args.sites, args.seed);
    println!(
        "{}: {} tets, {} sites, {:?}, on {}",
        args.model,
        mesh.tets.len(),
        sites.len(),
        args.strategy,
        backend.name()
    );
    let cv = ClippedVoronoi::new(&mesh, &sites).strategy(args.strategy).k(args.k).k_site(args.k_site);
    for attempt in ["first run", "second run"] {
        let cells = cv.backend(backend.as_ref()).compute()?;
        println!("{attempt}: {} (total {:.1} ms)", cells.timings, cells.timings.total() * 1e3);
        if attempt == "second run" {
            println!(
                "k = {}, k_site = {}; volume {:.6} of {:.6}, E_vol = {:.2e}; energy {:.6e}",
                cells.k,
                cells.k_site,
                cells.total_volume,
                cells.mesh_volume,
                cells.e_vol,
                cells.energy_total()
            );
            println!("counters: {:?}", cells.counters);
        }
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
