//! One small trait over the backends. It knows no implementation: the
//! backends ([`crate::backends`]) implement it, and open one.

use crate::cvt::LloydOutput;
use crate::diagram::voronoi::{ClipJob, ClipOutput};
use crate::error::Result;
use crate::job::knn::{KnnJob, Neighbors};

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
