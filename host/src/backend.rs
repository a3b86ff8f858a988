//! One small trait over the CPU and Vulkan backends, and how one is chosen.

use crate::cpu::CpuBackend;
use crate::cvt::LloydOutput;
use crate::error::Result;
use crate::knn::{KnnJob, Neighbors};
use crate::voronoi::{ClipJob, ClipOutput};
use crate::vulkan::{VulkanBackend, VulkanOptions};

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
}

/// Which backend to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendKind {
    /// Vulkan if a device is available, else the CPU (saying so).
    #[default]
    Auto,
    /// The CPU backend (rayon).
    Cpu,
    /// The Vulkan backend; fails if there is no device.
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

/// Opens the backend the options ask for. With `Auto`, a missing Vulkan is
/// reported in one line on stderr and the CPU backend serves.
pub fn open(options: &BackendOptions) -> Result<Box<dyn Backend>> {
    match options.kind {
        BackendKind::Cpu => Ok(Box::new(CpuBackend::new(options.threads)?)),
        BackendKind::Vulkan => Ok(Box::new(VulkanBackend::new(&options.vulkan)?)),
        BackendKind::Auto => match VulkanBackend::new(&options.vulkan) {
            Ok(vk) => Ok(Box::new(vk)),
            Err(e) => {
                eprintln!("cvd: {e}; using the CPU backend");
                Ok(Box::new(CpuBackend::new(options.threads)?))
            }
        },
    }
}
