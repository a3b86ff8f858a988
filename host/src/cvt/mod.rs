//! Centroidal Voronoi tessellations: sites that minimise the CVT energy
//! `F = Σ_i ∫_{Ω_i} |x - x_i|²`, whose gradient is `2 V_i (x_i - C_i)`.
//!
//! The optimisers know nothing of Voronoi but one trait, [`SiteDiagram`]:
//! a diagram whose sites can move, implemented by the clipped diagram
//! ([`clipped`]) and the periodic box ([`periodic`]).
//!
//! * Lloyd's iteration ([`lloyd`]) moves every site to its cell's
//!   centroid (`cvd_kernels::lloyd`). On the Vulkan backend the whole loop
//!   runs on the device and only a few numbers per iteration come back.
//! * L-BFGS ([`lbfgs`]) takes quasi-Newton steps from the same diagrams.
//! * Optimal transport ([`transport`]) finds the power weights that give
//!   every cell a prescribed mass, by damped Newton steps.
//!
//! [`Optimizer`] names them: a new optimiser is a file here and a variant.

pub mod clipped;
pub mod lbfgs;
pub mod lloyd;
pub mod periodic;
pub mod transport;

use crate::diagram::voronoi::Cells;
use crate::error::Result;

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

/// What an optimiser reads of one diagram: the CVT energy, its gradient
/// and the preconditioner `1 / 2V_i` (0 for empty cells) at some sites
/// (world coordinates, input order, flat), and the diagram's counters.
pub struct Evaluation {
    /// `Σ_i ∫ |x - x_i|²`.
    pub energy: f64,
    /// `2 V_i (x_i - C_i)`, three per site.
    pub gradient: Vec<f64>,
    /// `1 / 2V_i`, three per site.
    pub precondition: Vec<f64>,
    /// Sites whose cell is empty.
    pub empty: u64,
    /// Pieces the kernels' first pass left unfinished (finished after).
    pub second_pass: u64,
    /// Pieces not even the second pass could finish.
    pub unresolved: u64,
}

/// A diagram whose sites can move: all that Lloyd, L-BFGS and transport
/// know of Voronoi. Its settings (domain, weights, density, backend) stay;
/// the optimisers ask for its cells at other sites.
pub trait SiteDiagram: Sync {
    /// The sites the optimisers start from, in input order.
    fn starting_sites(&self) -> &[[f64; 3]];

    /// Where a site is reported and moved from: itself, or in a periodic
    /// box wrapped into it.
    fn place(&self, p: [f64; 3]) -> [f64; 3] {
        p
    }

    /// A periodic box's sides (a face's neighbour is the nearest image),
    /// or `None`.
    fn period(&self) -> Option<[f64; 3]> {
        None
    }

    /// The cells at `sites` (input order), with the diagram's own settings.
    fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells>;

    /// The power cells at `sites` with `weights`, with their faces (each
    /// face's mass `∫ρ dA` under a density): transport's diagram.
    fn power_cells_at(&self, sites: &[[f64; 3]], weights: &[f64]) -> Result<Cells>;

    /// The energy, gradient and preconditioner at flat coordinates `x`
    /// (a diagram without faces), and the seconds the diagram took.
    fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)>;

    /// `iterations` Lloyd iterations (see [`lloyd`]), calling `progress`
    /// with the iterations done and the energy the last one started from.
    /// By default one diagram per iteration ([`lloyd::by_diagrams`]); a
    /// diagram whose backend runs the loop itself overrides it.
    fn lloyd(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
        lloyd::by_diagrams(self, iterations, progress)
    }

    /// Minimises the CVT energy with L-BFGS for at most `iterations`
    /// iterations ([`lbfgs::run`]), calling `progress` after each.
    fn lbfgs(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
        lbfgs::run(self, iterations, progress)
    }
}

/// The CVT optimisers, by name.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Optimizer {
    /// Lloyd's iteration: every site to its cell's centroid (on Vulkan, the
    /// whole loop runs on the device).
    #[default]
    Lloyd,
    /// L-BFGS (memory 7) with a line search that only accepts decreases.
    Lbfgs,
}

impl Optimizer {
    /// Its name on the command line and in files: `lloyd`, `lbfgs`.
    pub fn name(self) -> &'static str {
        match self {
            Optimizer::Lloyd => "lloyd",
            Optimizer::Lbfgs => "lbfgs",
        }
    }

    /// Runs `iterations` iterations of this optimiser on `diagram`, calling
    /// `progress` with the iterations done and the energy the last one
    /// started from.
    pub fn run(
        self,
        diagram: &dyn SiteDiagram,
        iterations: usize,
        progress: &mut dyn FnMut(usize, f64),
    ) -> Result<CvtRun> {
        match self {
            Optimizer::Lloyd => diagram.lloyd(iterations, progress),
            Optimizer::Lbfgs => diagram.lbfgs(iterations, progress),
        }
    }
}

/// Flat `x, y, z` coordinates as points.
pub(crate) fn to_points(x: &[f64]) -> Vec<[f64; 3]> {
    x.as_chunks::<3>().0.to_vec()
}
