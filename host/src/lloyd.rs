//! Centroidal Voronoi tessellations by Lloyd's iteration: every iteration
//! computes the clipped diagram and moves each site to its cell's centroid
//! (`cvd_kernels::lloyd`). On the Vulkan backend the whole loop runs on the
//! device — grid, k-NN, clipping, second pass, site update — and only a
//! few numbers per iteration come back.

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::voronoi::{ClipJob, ClippedVoronoi, Frame};
use cvd_kernels::abi::{lloyd_stat, LloydParams};

/// What a backend returns for a Lloyd run, in the job's frame and order.
#[derive(Clone, Debug, Default)]
pub struct LloydOutput {
    /// The sites after the last iteration (`[x, y, z, 0]`, normalised).
    pub sites: Vec<[f32; 4]>,
    /// [`lloyd_stat::COUNT`] statistics per iteration.
    pub stats: Vec<i64>,
    /// Seconds per iteration.
    pub seconds: Vec<f64>,
}

/// One iteration, as reported.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Iteration {
    /// CVT energy `Σ ∫|x - x_i|²` of the diagram the iteration started from.
    pub energy: f64,
    /// Sites whose cell was empty (they did not move).
    pub empty_cells: u64,
    /// Pieces or tets the first pass left unfinished (finished by the
    /// second pass).
    pub second_pass: u64,
    /// Entries not even the second pass could finish: their volume is
    /// missing from that iteration (0 unless a tet meets very many cells).
    pub unresolved: u64,
    /// Seconds the iteration took on the backend.
    pub seconds: f64,
}

/// The result of a Lloyd run.
#[derive(Clone, Debug, Default)]
pub struct LloydRun {
    /// The sites after the last iteration, in input order.
    pub sites: Vec<[f32; 3]>,
    /// Every iteration.
    pub iterations: Vec<Iteration>,
}

/// The site update's parameters for `job` (quantization of moved sites).
pub(crate) fn params(job: &ClipJob, iteration: usize) -> LloydParams {
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

impl ClippedVoronoi<'_> {
    /// Runs `iterations` Lloyd iterations (flood pairing, tet-cell), calling
    /// `progress` with the iterations done so far. Duplicate sites keep
    /// their place (their cells are empty).
    pub fn lloyd(&self, iterations: usize, progress: &mut dyn FnMut(usize)) -> Result<LloydRun> {
        let (job, map, frame) = self.job()?;
        if job.pairing != crate::voronoi::Pairing::Flood {
            return Err(Error::InvalidInput("Lloyd iterations use flood pairing (tet-cell)".into()));
        }
        let cpu;
        let backend: &dyn Backend = match self.backend {
            Some(b) => b,
            None => {
                cpu = crate::cpu::CpuBackend::new(None)?;
                &cpu
            }
        };
        let out = backend.lloyd(&job, iterations, progress)?;
        Ok(report(self.sites, &job, &map, &frame, &out))
    }
}

fn report(input: &[[f32; 3]], job: &ClipJob, map: &[Option<usize>], frame: &Frame, out: &LloydOutput) -> LloydRun {
    let l = frame.scale;
    let inv = 1.0 / job.params.fixed_scale as f64;
    let iterations = out
        .stats
        .as_chunks::<{ lloyd_stat::COUNT }>()
        .0
        .iter()
        .zip(&out.seconds)
        .map(|(s, &seconds)| Iteration {
            energy: s[lloyd_stat::ENERGY] as f64 * inv * l.powi(5),
            empty_cells: s[lloyd_stat::EMPTY].max(0) as u64,
            second_pass: (s[lloyd_stat::UNFINISHED] - s[lloyd_stat::STILL]).max(0) as u64,
            unresolved: s[lloyd_stat::STILL].max(0) as u64,
            seconds,
        })
        .collect();
    let sites = map
        .iter()
        .zip(input)
        .map(|(m, &p)| match m {
            Some(u) => frame.to_world(out.sites[*u]),
            None => p,
        })
        .collect();
    LloydRun { sites, iterations }
}
