//! The backend of a run: one process's, or this rank's of a job in parts.

use crate::args::RunArgs;
use cvd::backends::distributed::{Distributed, OneProcess};
use cvd::backends::{self, BackendChoice};
use cvd::exec::CpuBackend;
use cvd::Backend;

/// The backend of a run: one process's, or this rank's of a distributed run.
pub enum RunBackend {
    /// The whole job in this process.
    One(Box<dyn Backend>),
    /// The job in parts (and over MPI ranks).
    Parts(Box<Distributed>),
}

impl RunBackend {
    /// The backend, as the diagrams take it.
    pub fn get(&self) -> &dyn Backend {
        match self {
            RunBackend::One(b) => b.as_ref(),
            RunBackend::Parts(d) => d.as_ref(),
        }
    }

    /// This process's rank (0 without MPI).
    pub fn rank(&self) -> usize {
        match self {
            RunBackend::One(_) => 0,
            RunBackend::Parts(d) => d.rank(),
        }
    }

    /// Whether the job runs in parts.
    pub fn in_parts(&self) -> bool {
        matches!(self, RunBackend::Parts(_))
    }

    /// The job in parts, if it runs so.
    pub fn parts(&self) -> Option<&Distributed> {
        match self {
            RunBackend::One(_) => None,
            RunBackend::Parts(d) => Some(d),
        }
    }
}

/// The backend `--backend` and `--parts` ask for (and MPI, when this
/// process was started by an MPI launcher), and why. A periodic box runs
/// in one process.
pub fn open(args: &RunArgs) -> cvd::Result<(RunBackend, String)> {
    if args.periodic() {
        if args.parts.is_some() {
            return Err(cvd::Error::InvalidInput("--parts: a periodic box runs in one process".into()));
        }
        let backends::Chosen { backend, why } = backends::choose(&args.backend.options())?;
        return Ok((RunBackend::One(backend), why));
    }
    let (comm, warning) = cvd::backends::distributed::launched_comm()?;
    if let Some(warning) = warning {
        eprintln!("cvd: {warning}");
    }
    if comm.is_none() && args.parts.is_none() {
        let backends::Chosen { backend, why } = backends::choose(&args.backend.options())?;
        return Ok((RunBackend::One(backend), why));
    }
    if args.backend.backend == BackendChoice::Vulkan {
        return Err(cvd::Error::InvalidInput(
            "tets in parts run on the CPU backend: drop --backend vulkan (a mesh's whole cells with the sites in \
             parts run on it: --strategy whole, without --output and --json)"
                .into(),
        ));
    }
    if args.transports() && args.strategy.is_some_and(|s| s != cvd::Strategy::Whole) {
        return Err(cvd::Error::InvalidInput(
            "optimal transport in parts needs the faces of whole cells: drop --strategy".into(),
        ));
    }
    let comm = comm.unwrap_or_else(|| Box::new(OneProcess));
    let why = format!("{} part(s) per rank, {}", args.parts.unwrap_or(1), comm.describe());
    let cpu = CpuBackend::new(args.backend.threads)?;
    let mut d = Distributed::new(cpu, comm, args.parts.unwrap_or(1))?;
    if let Some([listed, beyond]) = args.halo {
        d = d.with_halo(listed, beyond);
    }
    Ok((RunBackend::Parts(Box::new(d)), why))
}

/// What to say when `--threads` asks for more threads than the cores this
/// process may run on (its CPU affinity, as the OS reports it): an MPI
/// launcher binds each rank to one core unless told (Open MPI's default
/// for a few ranks), and the threads then share that core.
pub fn threads_beyond_cores(threads: Option<usize>) -> Option<String> {
    let threads = threads?;
    let cores = std::thread::available_parallelism().ok()?.get();
    (threads > cores).then(|| {
        format!(
            "--threads {threads}, but this process may run on {cores} core(s) only (its CPU affinity: an MPI \
             launcher binds each rank to one core unless told); start it with `mpirun --bind-to none` or \
             `mpirun --map-by slot:PE={threads}` (Slurm: --cpus-per-task={threads})"
        )
    })
}

/// A rank's backends in a job split by sites (a periodic box's, a mesh's
/// whole cells): the cells on a device where one is asked for or chosen,
/// else on the CPU pool; the polyhedra always on the CPU pool.
pub struct PartsBackends {
    /// The CPU pool (`--threads`).
    pub cpu: CpuBackend,
    /// The device, if the choice took one.
    device: Option<Box<backends::vulkan::VulkanBackend>>,
    /// Why this backend (as one process's header says it).
    pub why: String,
    threads: Option<usize>,
}

impl PartsBackends {
    /// Opens the CPU pool, and the device `--backend` asks for or the
    /// automatic choice takes.
    pub fn open(args: &crate::args::BackendArgs) -> cvd::Result<Self> {
        let cpu = CpuBackend::new(args.threads)?;
        let (device, why) = match backends::decide(&args.options())? {
            backends::Decided::Cpu(why) => (None, why),
            backends::Decided::Vulkan(device, why) => (Some(device), why),
        };
        Ok(Self { cpu, device, why, threads: args.threads })
    }

    /// Where the cells are built.
    pub fn cells(&self) -> &dyn Backend {
        match &self.device {
            Some(device) => device.as_ref(),
            None => &self.cpu,
        }
    }

    /// Where the cells are built, in words: the device's name, or the CPU
    /// threads.
    pub fn on(&self) -> String {
        match &self.device {
            Some(device) => device.name(),
            None => format!("{} CPU thread(s)", self.threads.map_or("all".to_string(), |t| t.to_string())),
        }
    }
}
