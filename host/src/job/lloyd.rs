//! Lloyd's iterations as a backend runs them: the site update's
//! parameters ([`lloyd_params`]) and what a run returns ([`LloydOutput`]).

use crate::job::clip::ClipJob;
use cvd_kernels::abi::{LloydParams, SplitPoint};

/// What a backend returns for a Lloyd run, in the job's frame and order.
#[derive(Clone, Debug, Default)]
pub struct LloydOutput {
    /// The sites after the last iteration (normalised, `hi + lo`).
    pub sites: Vec<SplitPoint>,
    /// [`lloyd_stat::COUNT`] statistics per iteration.
    pub stats: Vec<i64>,
    /// Seconds per iteration.
    pub seconds: Vec<f64>,
}

/// The site update's parameters for `job` (quantization of moved sites).
pub fn lloyd_params(job: &ClipJob, iteration: usize) -> LloydParams {
    let q = job.site_knn.quantizer;
    let o = q.origin();
    LloydParams {
        n_sites: job.params.n_sites,
        fixed_scale: job.params.fixed_scale,
        iteration: iteration as u32,
        quant_scale: q.scale() as f32,
        quant_origin_x: o[0] as f32,
        quant_origin_y: o[1] as f32,
        quant_origin_z: o[2] as f32,
        _pad: 0,
    }
}
