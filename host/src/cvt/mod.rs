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
//! Each takes its sums over all sites through `across`, so that a diagram
//! in parts ([`SiteDiagram::comm`]) takes one process's steps to the bit.

pub(crate) mod across;
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

    /// The periodic box (a face's neighbour is an image through its
    /// shift), or `None`.
    fn period(&self) -> Option<crate::geom::periodic_box::PeriodicBox> {
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

    /// The processes that each hold a run of the sites' rows (a diagram in
    /// parts: its sites, cells and weights are this process's rows, its
    /// neighbours by global row), or `None` (one process holds them all).
    /// The optimisers take every sum over all sites through `across`:
    /// exact, so each process takes one process's steps to the bit.
    fn comm(&self) -> Option<&dyn crate::backends::distributed::Reduce> {
        None
    }

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

/// The exact sum of `terms` over every process `diagram` runs on (see
/// [`SiteDiagram::comm`]).
pub(crate) fn total_of(diagram: &(impl SiteDiagram + ?Sized), terms: &[f64]) -> Result<f64> {
    across::Across::of(diagram, terms.len())?.sum(terms)
}

/// Flat `x, y, z` coordinates as points.
pub(crate) fn to_points(x: &[f64]) -> Vec<[f64; 3]> {
    x.as_chunks::<3>().0.to_vec()
}

#[cfg(test)]
pub(super) mod tests {
    //! A mock diagram for the optimisers' own tests ([`Quadratic`]), and
    //! [`Optimizer`]'s names and dispatch.

    use super::*;
    use crate::diagram::voronoi::Counters;
    use std::sync::Mutex;

    /// A diagram whose "cells" have volume 1 and centroid `centre[i]`
    /// (volume 0 and a bogus centroid where `empty[i]`), with the energy
    /// `Σ_k a_k (x_k - c_k)²` over flat coordinates (`a` = `stiffness`),
    /// its exact gradient (negated with `lie`) and the preconditioner
    /// `1 / 2V` = 1/2. It records every set of sites it is asked about.
    pub(in crate::cvt) struct Quadratic {
        pub start: Vec<[f64; 3]>,
        pub centre: Vec<[f64; 3]>,
        pub stiffness: Vec<f64>,
        pub empty: Vec<bool>,
        /// `place` wraps into `[0, 1)³`.
        pub wrap: bool,
        /// Reports the gradient with the wrong sign.
        pub lie: bool,
        /// Every set of sites asked about (`cells_at` and `evaluate`), with
        /// the energy there.
        pub asked: Mutex<Vec<(Vec<[f64; 3]>, f64)>>,
    }

    /// The centroid reported for an empty cell: never a place to move to.
    pub(in crate::cvt) const BOGUS: [f64; 3] = [9.0, 9.0, 9.0];

    impl Quadratic {
        pub fn new(start: Vec<[f64; 3]>, centre: Vec<[f64; 3]>) -> Self {
            let n = start.len();
            assert_eq!(centre.len(), n);
            Self {
                start,
                centre,
                stiffness: vec![1.0; 3 * n],
                empty: vec![false; n],
                wrap: false,
                lie: false,
                asked: Mutex::new(Vec::new()),
            }
        }

        /// Each cell's energy at `sites`.
        pub fn energies(&self, sites: &[[f64; 3]]) -> Vec<f64> {
            (0..sites.len())
                .map(|i| {
                    if self.empty[i] {
                        return 0.0;
                    }
                    (0..3).map(|a| self.stiffness[3 * i + a] * (sites[i][a] - self.centre[i][a]).powi(2)).sum()
                })
                .collect()
        }

        pub fn energy(&self, sites: &[[f64; 3]]) -> f64 {
            self.energies(sites).iter().sum()
        }

        fn record(&self, sites: &[[f64; 3]]) {
            let e = self.energy(sites);
            self.asked.lock().unwrap().push((sites.to_vec(), e));
        }

        pub fn asked(&self) -> Vec<(Vec<[f64; 3]>, f64)> {
            self.asked.lock().unwrap().clone()
        }
    }

    impl SiteDiagram for Quadratic {
        fn starting_sites(&self) -> &[[f64; 3]] {
            &self.start
        }

        fn place(&self, p: [f64; 3]) -> [f64; 3] {
            if self.wrap {
                p.map(|c| c.rem_euclid(1.0))
            } else {
                p
            }
        }

        fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells> {
            assert_eq!(sites.len(), self.start.len());
            self.record(sites);
            let empty = self.empty.iter().filter(|&&e| e).count() as u64;
            Ok(Cells {
                volume: self.empty.iter().map(|&e| if e { 0.0 } else { 1.0 }).collect(),
                centroid: (0..sites.len()).map(|i| if self.empty[i] { BOGUS } else { self.centre[i] }).collect(),
                energy: self.energies(sites),
                counters: Counters { empty_cells: empty, second_pass: 3, unresolved: 1, ..Default::default() },
                ..Default::default()
            })
        }

        fn power_cells_at(&self, _: &[[f64; 3]], _: &[f64]) -> Result<Cells> {
            unreachable!("no transport here")
        }

        fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)> {
            let sites = to_points(x);
            assert_eq!(sites.len(), self.start.len());
            self.record(&sites);
            let sign = if self.lie { -1.0 } else { 1.0 };
            let mut gradient = vec![0.0; x.len()];
            let mut precondition = vec![0.0; x.len()];
            for k in 0..x.len() {
                if !self.empty[k / 3] {
                    gradient[k] = sign * 2.0 * self.stiffness[k] * (x[k] - self.centre[k / 3][k % 3]);
                    precondition[k] = 0.5;
                }
            }
            let empty = self.empty.iter().filter(|&&e| e).count() as u64;
            let eval = Evaluation {
                energy: self.energy(&sites),
                gradient,
                precondition,
                empty,
                second_pass: 3,
                unresolved: 1,
            };
            Ok((eval, 0.0))
        }
    }

    /// Answers `lloyd` and `lbfgs` itself with a mark: which one ran, and
    /// with how many iterations.
    struct Marked;

    impl SiteDiagram for Marked {
        fn starting_sites(&self) -> &[[f64; 3]] {
            &[[0.0; 3]]
        }
        fn cells_at(&self, _: &[[f64; 3]]) -> Result<Cells> {
            unreachable!("the overrides answer")
        }
        fn power_cells_at(&self, _: &[[f64; 3]], _: &[f64]) -> Result<Cells> {
            unreachable!("the overrides answer")
        }
        fn evaluate(&self, _: &[f64]) -> Result<(Evaluation, f64)> {
            unreachable!("the overrides answer")
        }
        fn lloyd(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
            progress(iterations, 1.0);
            Ok(CvtRun { sites: vec![[1.0, iterations as f64, 0.0]], iterations: Vec::new() })
        }
        fn lbfgs(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
            progress(iterations, 2.0);
            Ok(CvtRun { sites: vec![[2.0, iterations as f64, 0.0]], iterations: Vec::new() })
        }
    }

    #[test]
    fn optimizers_have_their_command_line_names() {
        assert_eq!(Optimizer::Lloyd.name(), "lloyd");
        assert_eq!(Optimizer::Lbfgs.name(), "lbfgs");
        assert_eq!(Optimizer::default(), Optimizer::Lloyd);
    }

    #[test]
    fn run_dispatches_to_the_diagrams_own_method() {
        for (optimizer, mark) in [(Optimizer::Lloyd, 1.0), (Optimizer::Lbfgs, 2.0)] {
            let mut calls = Vec::new();
            let run = optimizer.run(&Marked, 5, &mut |done, e| calls.push((done, e))).unwrap();
            assert_eq!(run.sites, vec![[mark, 5.0, 0.0]], "{optimizer:?}");
            assert_eq!(calls, vec![(5, mark)], "{optimizer:?}: progress");
        }
    }

    #[test]
    fn run_defaults_to_lloyd_by_diagrams_and_lbfgs_run() {
        let start = vec![[0.5, 0.25, 0.0], [0.0, 0.5, 0.75]];
        let centre = vec![[0.25, 0.25, 0.5], [0.5, 0.5, 0.5]];
        let mut stiff = Quadratic::new(start.clone(), centre.clone());
        // Anisotropic: the preconditioned step overshoots, so L-BFGS and
        // Lloyd take different paths.
        stiff.stiffness = vec![1.0, 4.0, 0.5, 2.0, 1.0, 3.0];
        let by_name = Optimizer::Lloyd.run(&stiff, 2, &mut |_, _| {}).unwrap();
        let direct = lloyd::by_diagrams(&stiff, 2, &mut |_, _| {}).unwrap();
        assert_eq!(by_name.sites, direct.sites);
        assert_eq!(by_name.iterations.len(), 2);
        assert_eq!(by_name.sites, centre, "Lloyd: at the centroids");
        let by_name = Optimizer::Lbfgs.run(&stiff, 3, &mut |_, _| {}).unwrap();
        let direct = lbfgs::run(&stiff, 3, &mut |_, _| {}).unwrap();
        assert_eq!(by_name.sites, direct.sites);
        assert_eq!(
            by_name.iterations.iter().map(|i| i.energy).collect::<Vec<_>>(),
            direct.iterations.iter().map(|i| i.energy).collect::<Vec<_>>()
        );
        assert_ne!(by_name.sites, by_diagrams_sites(&stiff), "L-BFGS is not Lloyd here");
    }

    fn by_diagrams_sites(d: &Quadratic) -> Vec<[f64; 3]> {
        lloyd::by_diagrams(d, 3, &mut |_, _| {}).unwrap().sites
    }

    #[test]
    fn to_points_groups_by_three() {
        assert_eq!(to_points(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]), vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert!(to_points(&[]).is_empty());
    }
}
