//! Centroidal Voronoi tessellations: sites that minimise the CVT energy
//! `F = Σ_i ∫_{Ω_i} |x - x_i|²`, whose gradient is `2 V_i (x_i - C_i)`.
//!
//! * Lloyd's iteration moves every site to its cell's centroid
//!   (`cvd_kernels::lloyd`). On the Vulkan backend the whole loop runs on
//!   the device — grid, k-NN, clipping, second pass, site update — and
//!   only a few numbers per iteration come back.
//! * L-BFGS (as Geogram's Newton iterations, memory 7) takes quasi-Newton
//!   steps from the same diagrams, preconditioned by `1 / 2V_i` so that its
//!   first step is Lloyd's, with a backtracking line search that only
//!   accepts steps that lower the energy.
//! * Optimal transport ([`transport`]) finds the power weights that give
//!   every cell a prescribed mass, by damped Newton steps.

pub mod transport;

use crate::backend::Backend;
use crate::diagram::voronoi::{ClipJob, ClippedVoronoi, Frame};
use crate::error::{Error, Result};
use cvd_kernels::abi::{lloyd_stat, LloydParams, SplitPoint};

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
    /// Newton steps of the iteration's optimal transport (capacity-
    /// constrained CVT; 0 otherwise).
    pub newton_steps: u32,
}

/// The result of a Lloyd run.
#[derive(Clone, Debug, Default)]
pub struct CvtRun {
    /// The sites after the last iteration, in input order.
    pub sites: Vec<[f64; 3]>,
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
    /// `progress` with the iterations done so far and the energy the last
    /// one started from (on Vulkan, once per batch of iterations).
    /// Duplicate sites keep their place (their cells are empty).
    pub fn lloyd(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
        // The faces are the final diagram's business, not the iterations'.
        let (job, map, frame) = self.faces(false).job()?;
        if job.pairing != crate::diagram::voronoi::Pairing::Flood {
            return Err(Error::InvalidInput("Lloyd iterations use flood pairing (tet-cell)".into()));
        }
        let cpu;
        let backend: &dyn Backend = match self.backend {
            Some(b) => b,
            None => {
                cpu = crate::exec::CpuBackend::new(None)?;
                &cpu
            }
        };
        let to_energy = energy_scale(&job, &frame);
        let out = backend.lloyd(&job, iterations, &mut |done, e| progress(done, e as f64 * to_energy))?;
        Ok(report(self.sites, &job, &map, &frame, &out))
    }
}

/// `iterations` Lloyd iterations from `job`'s sites, each a diagram from
/// `backend` (its second pass, then the host's) and every site moved to
/// its centroid by the kernels' own `move_site` on the host: what a
/// backend that does not run the whole loop itself does.
pub(crate) fn lloyd_by_diagrams(
    backend: &dyn Backend,
    job: &ClipJob,
    iterations: usize,
    progress: &mut dyn FnMut(usize, i64),
) -> Result<LloydOutput> {
    use cvd_kernels::buffers::DeviceSums;
    let mut job = job.clone();
    let mut stats = vec![0i64; iterations * lloyd_stat::COUNT];
    let mut seconds = Vec::with_capacity(iterations);
    for it in 0..iterations {
        let start = std::time::Instant::now();
        let mut out = backend.clip(&job)?;
        let first = out.refined + out.unresolved + out.unfinished.len() as u64;
        let none = std::sync::Mutex::new(Vec::<cvd_kernels::clip::NoPieces>::new());
        let redone = crate::passes::second_pass::run(&job, &mut out, &none)?;
        let p = params(&job, it);
        let mut quant = job.site_knn.sites.to_vec();
        let (unfinished, still) = ([first as u32], [(out.unresolved + redone.unresolved) as u32]);
        for i in 0..job.params.n_sites as usize {
            let (sites, q) = (&mut job.sites[..], &mut quant[..]);
            cvd_kernels::lloyd::move_site(i, &p, &out.sums, &unfinished, &still, sites, q, &mut DeviceSums(&mut stats));
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

/// World energy per unit of a fixed-point energy sum.
fn energy_scale(job: &ClipJob, frame: &Frame) -> f64 {
    frame.scale.powi(5) / job.params.fixed_scale as f64
}

fn report(
    input: &[[f64; 3]],
    job: &ClipJob,
    map: &crate::job::sites::SiteMap,
    frame: &Frame,
    out: &LloydOutput,
) -> CvtRun {
    let to_energy = energy_scale(job, frame);
    let iterations = out
        .stats
        .as_chunks::<{ lloyd_stat::COUNT }>()
        .0
        .iter()
        .zip(&out.seconds)
        .map(|(s, &seconds)| Iteration {
            energy: s[lloyd_stat::ENERGY] as f64 * to_energy,
            empty_cells: s[lloyd_stat::EMPTY].max(0) as u64,
            second_pass: (s[lloyd_stat::UNFINISHED] - s[lloyd_stat::STILL]).max(0) as u64,
            unresolved: s[lloyd_stat::STILL].max(0) as u64,
            seconds,
            newton_steps: 0,
        })
        .collect();
    let sites = map
        .iter()
        .zip(input)
        .map(|(m, &p)| match m {
            Some(u) => frame.to_world(out.sites[u].to_f64()),
            None => p,
        })
        .collect();
    CvtRun { sites, iterations }
}

/// Steps remembered by L-BFGS.
const LBFGS_MEMORY: usize = 7;

/// The energy and its gradient at some sites (world coordinates, input
/// order), and the preconditioner `1 / 2V_i` (0 for empty cells).
pub(crate) struct Evaluation {
    pub(crate) energy: f64,
    pub(crate) gradient: Vec<f64>,
    pub(crate) precondition: Vec<f64>,
    pub(crate) empty: u64,
    pub(crate) second_pass: u64,
    pub(crate) unresolved: u64,
}

impl ClippedVoronoi<'_> {
    fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)> {
        let sites = to_points(x);
        let start = std::time::Instant::now();
        let cells = ClippedVoronoi { sites: &sites, faces: false, ..*self }.compute()?;
        let seconds = start.elapsed().as_secs_f64();
        let mut gradient = vec![0.0; x.len()];
        let mut precondition = vec![0.0; x.len()];
        for i in 0..sites.len() {
            let v = cells.volume[i];
            if v > 0.0 {
                for a in 0..3 {
                    gradient[3 * i + a] = 2.0 * v * (sites[i][a] - cells.centroid[i][a]);
                    precondition[3 * i + a] = 1.0 / (2.0 * v);
                }
            }
        }
        let c = &cells.counters;
        let eval = Evaluation {
            energy: cells.energy_total(),
            gradient,
            precondition,
            empty: c.empty_cells,
            second_pass: c.second_pass,
            unresolved: c.unresolved,
        };
        Ok((eval, seconds))
    }

    /// Minimises the CVT energy with L-BFGS for `iterations` iterations (see
    /// the module's documentation), calling `progress` after each. Every
    /// iteration lowers the energy or stops the run early (at a minimum to
    /// float precision).
    pub fn lbfgs(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
        lbfgs(self.sites, iterations, &|x| self.evaluate(x), progress)
    }
}

/// The energy, gradient and preconditioner at flat coordinates, and the
/// seconds the diagram took.
pub(crate) type Evaluate<'a> = dyn Fn(&[f64]) -> Result<(Evaluation, f64)> + 'a;

/// L-BFGS on the CVT energy from `sites` (see [`ClippedVoronoi::lbfgs`]),
/// `evaluate` giving the energy, gradient and preconditioner at flat
/// coordinates, and the seconds the diagram took.
pub(crate) fn lbfgs(
    sites: &[[f64; 3]],
    iterations: usize,
    evaluate: &Evaluate,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<CvtRun> {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut x: Vec<f64> = sites.iter().flatten().copied().collect();
    let (mut at, mut seconds) = evaluate(&x)?;
    let mut memory: Vec<(Vec<f64>, Vec<f64>, f64)> = Vec::new();
    let mut run = CvtRun::default();
    for it in 0..iterations {
        // Two-loop recursion with the diagonal preconditioner as H0.
        let mut d: Vec<f64> = at.gradient.iter().map(|g| -g).collect();
        let mut alphas = Vec::with_capacity(memory.len());
        for (s, y, rho) in memory.iter().rev() {
            let a = rho * dot(s, &d);
            d.iter_mut().zip(y).for_each(|(di, yi)| *di -= a * yi);
            alphas.push(a);
        }
        d.iter_mut().zip(&at.precondition).for_each(|(di, h)| *di *= h);
        for ((s, y, rho), a) in memory.iter().zip(alphas.iter().rev()) {
            let b = rho * dot(y, &d);
            d.iter_mut().zip(s).for_each(|(di, si)| *di += (a - b) * si);
        }
        let mut slope = dot(&at.gradient, &d);
        if slope >= 0.0 {
            // Not a descent direction: fall back to the Lloyd step.
            d = at.gradient.iter().zip(&at.precondition).map(|(g, h)| -g * h).collect();
            slope = dot(&at.gradient, &d);
            memory.clear();
        }
        let record = Iteration {
            energy: at.energy,
            empty_cells: at.empty,
            second_pass: at.second_pass,
            unresolved: at.unresolved,
            seconds,
            newton_steps: 0,
        };
        // Backtracking (Armijo): halve the step until the energy drops.
        let mut t = 1.0;
        let mut next = None;
        for _ in 0..12 {
            let trial: Vec<f64> = x.iter().zip(&d).map(|(xi, di)| xi + t * di).collect();
            let (eval, s) = evaluate(&trial)?;
            seconds += s;
            if eval.energy <= at.energy + 1e-4 * t * slope && eval.energy < at.energy {
                next = Some((trial, eval));
                break;
            }
            t *= 0.5;
        }
        run.iterations.push(Iteration { seconds, ..record });
        progress(it + 1, record.energy);
        let Some((trial, eval)) = next else {
            // No step lowers the energy at float precision: a minimum.
            break;
        };
        let s: Vec<f64> = trial.iter().zip(&x).map(|(a, b)| a - b).collect();
        let y: Vec<f64> = eval.gradient.iter().zip(&at.gradient).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        if sy > 0.0 {
            if memory.len() == LBFGS_MEMORY {
                memory.remove(0);
            }
            memory.push((s, y, 1.0 / sy));
        }
        x = trial;
        at = eval;
        seconds = 0.0;
    }
    run.sites = to_points(&x);
    Ok(run)
}

/// Flat `x, y, z` coordinates as points.
pub(crate) fn to_points(x: &[f64]) -> Vec<[f64; 3]> {
    x.as_chunks::<3>().0.to_vec()
}
