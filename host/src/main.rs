//! `cvd`: the command-line tool.

use clap::{Args, Parser, Subcommand};
use cvd::backend::{self, BackendKind, BackendOptions};
use cvd::vulkan::{self, VulkanOptions};
use cvd::{points, KnnJob, KnnMethod};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "cvd",
    version,
    about = "Clipped Voronoi diagrams on Vulkan GPUs and CPU cores"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the Vulkan devices (the index or a part of the name picks one with --device).
    Devices,
    /// k nearest neighbours of random sites; checks the backend against the CPU.
    Knn(KnnArgs),
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
            vulkan: VulkanOptions {
                device: self.device.clone(),
                validation: self.validation,
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
    let backend = backend::open(&args.backend.options())?;
    let sites = points::uniform(args.sites, args.seed);
    let job = KnnJob::sites(&sites, args.k, args.method)?;
    println!(
        "k-NN of {} uniform sites, k = {}, {:?}, on {}",
        args.sites,
        job.params.k,
        args.method,
        backend.name()
    );
    let first = job.run(backend.as_ref())?;
    let again = job.run(backend.as_ref())?;
    println!("first run: {}", first.timings);
    println!(
        "second run: {} (total {:.3} ms)",
        again.timings,
        again.timings.total() * 1e3
    );
    let reference = job.run(&cvd::cpu::CpuBackend::new(args.backend.threads)?)?;
    let same = reference.indices == again.indices && reference.dist2 == again.dist2;
    println!(
        "same neighbours as the CPU backend: {}",
        if same { "yes" } else { "NO" }
    );
    if !same {
        return Err(cvd::Error::InvalidInput(
            "the backend disagrees with the CPU backend".into(),
        ));
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
