//! One small trait over the CPU and Vulkan backends, and the options that
//! choose one. The trait knows no implementation; [`choose`], beside it,
//! opens them.

mod choose;

pub use choose::{auto_choice, choose, open, AutoChoice, Chosen};

use crate::cvt::LloydOutput;
use crate::diagram::voronoi::{ClipJob, ClipOutput};
use crate::error::Result;
use crate::knn::{KnnJob, Neighbors};
use crate::vulkan::VulkanOptions;

/// Something that runs the kernels.
pub trait Backend: Send + Sync {
    /// `cpu` or `vulkan`.
    fn kind(&self) -> &'static str;
    /// What it runs on: the GPU's name, or the CPU threads.
    fn device(&self) -> String;
    /// A human-readable name: backend and device.
    fn name(&self) -> String {
        format!("{} ({})", self.kind(), self.device())
    }
    /// Runs a k-NN job.
    fn knn(&self, job: &KnnJob) -> Result<Neighbors>;
    /// Runs a clipping job: pairing, clipping and accumulation.
    fn clip(&self, job: &ClipJob) -> Result<ClipOutput>;
    /// Runs `iterations` Lloyd iterations from the job's sites, calling
    /// `progress` with the number of iterations done so far (in batches)
    /// and the last one's energy (fixed point, as in the statistics).
    fn lloyd(&self, job: &ClipJob, iterations: usize, progress: &mut dyn FnMut(usize, i64)) -> Result<LloydOutput>;
    /// Seconds the driver has spent compiling kernels since the backend
    /// opened (on first use; 0 on the CPU). Not part of any job's timings.
    fn kernel_compile_seconds(&self) -> f64 {
        0.0
    }
}

/// Which backend to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendKind {
    /// Vulkan on a real GPU (discrete, integrated or virtual) if there is
    /// one, else the CPU backend. A Vulkan device that runs on the CPU
    /// (lavapipe, SwiftShader) is slower than the CPU backend: it is used
    /// only when asked for.
    #[default]
    Auto,
    /// The CPU backend (rayon).
    Cpu,
    /// The Vulkan backend on the best device (or `--device`), GPU or not;
    /// fails if there is none.
    Vulkan,
}

/// Options for choosing and configuring a backend.
#[derive(Clone, Debug, Default)]
pub struct BackendOptions {
    /// Which backend.
    pub kind: BackendKind,
    /// CPU threads (None: all cores).
    pub threads: Option<usize>,
    /// Vulkan device selection and validation.
    pub vulkan: VulkanOptions,
}
