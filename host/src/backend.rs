//! One small trait over the backends. It knows no implementation: the
//! backends (the `backends` module) implement it, and open one.

use crate::error::Result;
use crate::job::clip::{ClipJob, ClipOutput, JobShape, Strategy};
use crate::job::knn::{KnnJob, Neighbors};
use crate::job::lloyd::{lloyd_params, LloydOutput};
use crate::job::BackendKind;
use cvd_kernels::abi::lloyd_stat;
use cvd_kernels::buffers::DeviceSums;
use cvd_kernels::clip::NoPieces;
use std::sync::Mutex;

/// Something that runs the kernels.
pub trait Backend: Send + Sync {
    /// What runs them: CPU cores or a Vulkan device.
    fn kind(&self) -> BackendKind;
    /// What it runs on: the GPU's name, or the CPU threads.
    fn device(&self) -> String;
    /// A human-readable name: backend and device.
    fn name(&self) -> String {
        format!("{} ({})", self.kind(), self.device())
    }
    /// The strategy a computation runs here when none is asked for
    /// ([`Strategy::auto`]).
    fn default_strategy(&self, shape: JobShape) -> Strategy {
        Strategy::auto(self.kind(), shape)
    }
    /// Runs a k-NN job.
    fn knn(&self, job: &KnnJob) -> Result<Neighbors>;
    /// Runs a clipping job: pairing, clipping and accumulation.
    fn clip(&self, job: &ClipJob) -> Result<ClipOutput>;
    /// Runs `iterations` Lloyd iterations from the job's sites, calling
    /// `progress` with the number of iterations done so far (in batches)
    /// and the last one's energy (fixed point, as in the statistics).
    ///
    /// By default each iteration is a diagram from [`Self::clip`] (its
    /// second pass, then the host's) and every site moves to its centroid
    /// by the kernels' own `move_site` on the host; a backend that runs the
    /// whole loop itself (Vulkan, on the device) overrides it.
    fn lloyd(&self, job: &ClipJob, iterations: usize, progress: &mut dyn FnMut(usize, i64)) -> Result<LloydOutput> {
        let mut job = job.clone();
        let mut stats = vec![0i64; iterations * lloyd_stat::COUNT];
        let mut seconds = Vec::with_capacity(iterations);
        for it in 0..iterations {
            let start = std::time::Instant::now();
            let mut out = self.clip(&job)?;
            let first = out.refined + out.unresolved + out.unfinished.len() as u64;
            let none = Mutex::new(Vec::<NoPieces>::new());
            let redone = crate::passes::second_pass::run(&job, &mut out, &none)?;
            let p = lloyd_params(&job, it);
            let mut quant = job.site_knn.sites.to_vec();
            let (unfinished, still) = ([first as u32], [(out.unresolved + redone.unresolved) as u32]);
            for i in 0..job.params.n_sites as usize {
                let (sites, q) = (&mut job.sites[..], &mut quant[..]);
                cvd_kernels::lloyd::move_site(
                    i,
                    &p,
                    &out.sums,
                    &unfinished,
                    &still,
                    sites,
                    q,
                    &mut DeviceSums(&mut stats),
                );
            }
            let quant: crate::job::knn::Points = quant.into();
            job.site_knn.queries = quant.clone();
            job.tet_knn.sites = quant.clone();
            job.site_knn.sites = quant;
            seconds.push(start.elapsed().as_secs_f64());
            progress(it + 1, stats[it * lloyd_stat::COUNT + lloyd_stat::ENERGY]);
        }
        Ok(LloydOutput { sites: job.sites, stats, seconds })
    }
    /// Seconds the driver has spent compiling kernels since the backend
    /// opened (on first use; 0 on the CPU). Not part of any job's timings.
    fn kernel_compile_seconds(&self) -> f64 {
        0.0
    }
}

impl KnnJob {
    /// Runs the job on a backend.
    pub fn run(&self, backend: &dyn Backend) -> Result<Neighbors> {
        if self.params.k == 0 || self.queries.is_empty() {
            return Ok(Neighbors { k: self.params.k as usize, ..Default::default() });
        }
        backend.knn(self)
    }
}
