//! Semi-discrete optimal transport: the power weights for which every
//! clipped cell gets a prescribed mass (its capacity).
//!
//! The masses `m_i(w)` of the power cells are the gradient of a concave
//! function of the weights (Kantorovich's dual), whose Hessian is a graph
//! Laplacian over the cells' shared faces: `∂m_i/∂w_j = -A_ij / 2|x_i -
//! x_j|` for neighbours (`A_ij` the face's area, or its mass `∫ρ` under a
//! density), and `∂m_i/∂w_i = Σ_j A_ij / 2|x_i - x_j|`. Each Newton step
//! solves `L δ = targets - m(w)` by conjugate gradients (Jacobi
//! preconditioned, the constant vector being `L`'s kernel), and is damped
//! as Kitagawa, Mérigot and Thibert (2019) prove convergent: halved until
//! no cell's mass falls below half the smallest of the targets and the
//! starting masses, and the error's norm drops by at least `1 - α/2` (or
//! every mass is within the tolerance); each step tries twice the last
//! one's `α` first, at most 1.
//! Every trial is one diagram, with faces, on the diagram's backend.

use crate::cvt::across::{Across, Ghosts};
use crate::cvt::{CvtRun, Iteration, SiteDiagram};
use crate::diagram::voronoi::Cells;
use crate::error::{Error, Result};
use crate::geom::periodic_box::PeriodicBox;
use rayon::prelude::*;
use std::time::Instant;

/// One Newton step, as reported.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NewtonStep {
    /// `max_i |m_i - t_i| / t_i` of the diagram the step started from.
    pub max_error: f64,
    /// The damping `α` of the step taken (1 for a full Newton step; 0 when
    /// the solve stopped at this diagram).
    pub step: f64,
    /// Diagrams this step computed: its trials (1 + those rejected), and
    /// for the first step the starting diagram too.
    pub diagrams: u32,
    /// Conjugate-gradient iterations of the linear solve.
    pub cg_iterations: u32,
    /// Seconds the step took: its diagrams and its solve.
    pub seconds: f64,
}

impl std::fmt::Display for NewtonStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "max mass error {:.2e}, step {}, {} CG iterations, {} diagrams, {:.3} s",
            self.max_error, self.step, self.cg_iterations, self.diagrams, self.seconds
        )
    }
}

/// The result of an optimal-transport solve.
#[derive(Clone, Debug, Default)]
pub struct TransportRun {
    /// The weights found, one per site in input order, in squared units of
    /// length (their mean is zero).
    pub weights: Vec<f64>,
    /// The target mass of each cell.
    pub targets: Vec<f64>,
    /// The power cells of the last diagram, with their faces (under a
    /// density, each face's mass `∫ρ dA` in place of its area).
    pub cells: Cells,
    /// Every Newton step; the last one's `max_error` is the final error.
    pub steps: Vec<NewtonStep>,
    /// Whether `max_error` reached the tolerance.
    pub converged: bool,
    /// What stopped the solve, said for a person: the tolerance reached,
    /// the steps used up, stopped by the caller, or why no step along
    /// Newton's direction was accepted (the cell that would fall below the
    /// mass floor, or the error's norm that did not drop enough, at the
    /// shortest step tried).
    pub stopped: String,
}

impl TransportRun {
    /// The final `max_i |m_i - t_i| / t_i`.
    pub fn max_error(&self) -> f64 {
        self.steps.last().map_or(f64::INFINITY, |s| s.max_error)
    }
}

/// Builder of an optimal-transport solve on a diagram (a clipped one: its
/// mesh, sites, density and backend; or a periodic box), with power
/// weights found so that each cell gets its target mass.
#[derive(Clone, Copy)]
pub struct Transport<'a, D> {
    diagram: D,
    capacities: Option<&'a [f64]>,
    start: Option<&'a [f64]>,
    tolerance: f64,
    max_steps: usize,
}

/// Halvings of a Newton step before the solve says it cannot go on.
const MAX_HALVINGS: u32 = 30;

/// Halvings once every cell is within this of its target: closer, the
/// masses' own rounding (about 1e-6 of a cell in f32 kernels) is what a
/// step that does not improve them meets, and halving on finds nothing.
const NEAR: (f64, u32) = (1e-4, 3);

impl<'a, D: SiteDiagram> Transport<'a, D> {
    /// Optimal transport on `diagram`'s sites (a clipped diagram: its mesh,
    /// density and backend; or a periodic box; its weights, if any, are
    /// ignored: see [`Self::start`]): by default every cell gets the same
    /// mass, the domain's mass over the sites, or its share by
    /// [`Self::capacities`].
    pub fn new(diagram: D) -> Self {
        Self { diagram, capacities: None, start: None, tolerance: 1e-6, max_steps: 50 }
    }

    /// A capacity per site (positive; normalised so that they sum to the
    /// mesh's mass).
    pub fn capacities(mut self, capacities: &'a [f64]) -> Self {
        self.capacities = Some(capacities);
        self
    }

    /// The weights to start from (default: zero, the Voronoi cells). Every
    /// starting cell must have mass.
    pub fn start(mut self, weights: &'a [f64]) -> Self {
        self.start = Some(weights);
        self
    }

    /// Stop when every cell's mass is within `tolerance` of its target,
    /// relative to it (default 1e-6).
    pub fn tolerance(mut self, tolerance: f64) -> Self {
        self.tolerance = tolerance;
        self
    }

    /// Newton steps at most (default 50).
    pub fn max_steps(mut self, max_steps: usize) -> Self {
        self.max_steps = max_steps;
        self
    }

    /// The targets of the sites' rows (`across`) from the capacities (or
    /// uniform) and the domain's mass.
    fn targets(&self, across: &Across, mass: f64) -> Result<Vec<f64>> {
        let n = across.len;
        let Some(c) = self.capacities else { return Ok(vec![mass / across.total as f64; n]) };
        if c.len() != n {
            return Err(Error::InvalidInput(format!("{} capacities for {n} sites", c.len())));
        }
        let bad = c.iter().position(|&x| !(x.is_finite() && x > 0.0));
        let first_bad = across.min(bad.map_or(f64::INFINITY, |i| (across.first + i as u64) as f64))?;
        if first_bad.is_finite() {
            let value = bad.filter(|&i| (across.first + i as u64) as f64 == first_bad).map(|i| format!(" is {}", c[i]));
            return Err(Error::InvalidInput(format!(
                "site {first_bad}'s capacity{}: capacities must be positive",
                value.unwrap_or_default()
            )));
        }
        let total = across.sum(c)?;
        Ok(c.iter().map(|x| x / total * mass).collect())
    }

    /// The capacity-constrained CVT (as blue noise through optimal
    /// transport, de Goes et al. 2012): `iterations` times, the weights
    /// that give every cell its target mass (warm-started from the last
    /// ones), then every site to its power cell's centroid; `progress` is
    /// called with the iterations done and the energy the last one started
    /// from. Returns the moved sites with each iteration's record (its
    /// seconds include its Newton steps), and the transport solved once
    /// more at the moved sites, so that the weights are theirs.
    pub fn cvt(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<(CvtRun, TransportRun)> {
        let mut sites = self.diagram.starting_sites().to_vec();
        let mut weights = self.start.map(<[f64]>::to_vec);
        // The last weights may empty a moved site's cell: then from zero.
        let solve = |sites: &[[f64; 3]], weights: Option<&[f64]>| self.solve_at(sites, weights, true, &mut |_| true);
        let mut run = CvtRun::default();
        for it in 0..iterations {
            let solved = solve(&sites, weights.as_deref())?;
            let c = &solved.cells;
            let energy = super::total_of(&self.diagram, &c.energy)?;
            run.iterations.push(Iteration {
                energy,
                empty_cells: c.counters.empty_cells,
                second_pass: c.counters.second_pass,
                unresolved: c.counters.unresolved,
                seconds: solved.steps.iter().map(|s| s.seconds).sum(),
                newton_steps: solved.steps.len() as u32 - 1,
            });
            progress(it + 1, energy);
            for (s, (c, &m)) in sites.iter_mut().zip(c.centroid.iter().zip(&c.volume)) {
                if m > 0.0 {
                    *s = *c;
                }
            }
            weights = Some(solved.weights);
        }
        let solved = solve(&sites, weights.as_deref())?;
        run.sites = sites;
        Ok((run, solved))
    }

    /// Finds the weights, calling `progress` with each step's record (and
    /// the last diagram's); `progress` returning false stops the solve
    /// after that step (not converged).
    pub fn solve(&self, progress: &mut dyn FnMut(&NewtonStep) -> bool) -> Result<TransportRun> {
        self.solve_at(self.diagram.starting_sites(), self.start, false, progress)
    }

    /// [`Self::solve`] at `sites`, from weights `start` (zero if none; with
    /// `restart`, zero if they empty a cell).
    fn solve_at(
        &self,
        sites: &[[f64; 3]],
        start: Option<&[f64]>,
        restart: bool,
        progress: &mut dyn FnMut(&NewtonStep) -> bool,
    ) -> Result<TransportRun> {
        let n = sites.len();
        // This process's rows of all sites (all of them, in one process):
        // every sum, extreme and neighbour's value taken across the rows.
        let across = Across::of(&self.diagram, n)?;
        let mut w = match start {
            Some(s) if s.len() != n => {
                return Err(Error::InvalidInput(format!("{} starting weights for {n} sites", s.len())));
            }
            Some(s) => s.to_vec(),
            None => vec![0.0; n],
        };
        if self.tolerance.is_nan() || self.tolerance <= 0.0 {
            return Err(Error::InvalidInput(format!("the tolerance must be positive, not {}", self.tolerance)));
        }
        let clock = Instant::now();
        // The sites as the diagram sees them (wrapped into a periodic box),
        // and the box, if periodic.
        let frame: (Vec<[f64; 3]>, _) = (sites.iter().map(|&x| self.diagram.place(x)).collect(), self.diagram.period());
        let at = |w: &[f64]| self.diagram.power_cells_at(sites, w);
        let mut cells = at(&w)?;
        if restart && start.is_some() && across.any(cells.volume.iter().any(|&m| m.is_nan() || m <= 0.0))? {
            w = vec![0.0; n];
            cells = at(&w)?;
        }
        if cells.counters.duplicate_sites > 0 {
            return Err(Error::InvalidInput(format!(
                "{}: optimal transport needs distinct sites (an equal site's cell is always empty)",
                equal_sites(sites)
            )));
        }
        let targets = self.targets(&across, cells.mesh_volume)?;
        let empty = cells.volume.iter().position(|&m| m.is_nan() || m <= 0.0);
        let first_empty = across.min(empty.map_or(f64::INFINITY, |i| (across.first + i as u64) as f64))?;
        if first_empty.is_finite() {
            let at =
                empty.filter(|&i| (across.first + i as u64) as f64 == first_empty).map(|i| format!(" {:?}", sites[i]));
            return Err(Error::InvalidInput(format!(
                "site {first_empty}'s cell{} is empty with the starting weights: optimal transport starts from \
                 cells that all have mass (move the site into the domain, or start from other weights)",
                at.unwrap_or_default()
            )));
        }
        // No cell may fall below this mass (Kitagawa, Mérigot, Thibert).
        let floor = 0.5 * across.min(targets.iter().chain(&cells.volume).copied().fold(f64::INFINITY, f64::min))?;
        let mut run = TransportRun { targets, ..Default::default() };
        let mut seconds = clock.elapsed().as_secs_f64();
        let mut starting = 1;
        // Each step's first trial: twice the last step's length (at most
        // 1), so that a run of damped steps does not retry the full step
        // every time; the acceptance test is the same.
        let mut first = 1.0f64;
        loop {
            let clock = Instant::now();
            let residual: Vec<f64> = run.targets.iter().zip(&cells.volume).map(|(t, m)| t - m).collect();
            let max_error = across.max(worst(&run.targets, &cells.volume))?;
            let mut record = NewtonStep { max_error, diagrams: starting, ..Default::default() };
            starting = 0;
            if max_error <= self.tolerance || run.steps.len() == self.max_steps {
                record.seconds = seconds;
                run.converged = max_error <= self.tolerance;
                run.stopped = if run.converged {
                    format!("every cell within {:.0e} of its target", self.tolerance)
                } else {
                    format!("out of Newton steps ({})", self.max_steps)
                };
                run.steps.push(record);
                progress(&record);
                break;
            }
            let laplacian = Laplacian::of(&cells, &frame.0, frame.1, across)?;
            // Forcing term: a solve as accurate as the step can use.
            // Forcing term, per cell as the error is: the linear model's
            // residual at most a tenth of the current error times the
            // smaller of the cell's target and mass, in every cell (a norm
            // over all cells lets the big cells' residuals hide the small
            // ones', whose step may then empty them).
            let goal: Vec<f64> =
                run.targets.iter().zip(&cells.volume).map(|(t, m)| 0.1 * max_error.min(1.0) * t.min(*m)).collect();
            let (delta, iterations) = laplacian.solve(&residual, &goal, &run.targets)?;
            record.cg_iterations = iterations;
            seconds += clock.elapsed().as_secs_f64();
            // The error's norm, relative per cell as the tolerance is: with
            // targets spanning decades, an absolute norm is the big cells'
            // alone, and the small cells' errors never count. (Kitagawa,
            // Mérigot and Thibert's decrease test holds in any fixed norm:
            // along Newton's direction the residual is (1 - α) times itself
            // to first order.)
            let targets = &run.targets;
            let norm = |r: &[f64]| -> Result<f64> {
                let squares: Vec<f64> = r.iter().zip(targets).map(|(x, t)| (x / t).powi(2)).collect();
                Ok(across.sum(&squares)?.sqrt())
            };
            let before = norm(&residual)?;
            let mut alpha = first;
            let mut accepted = None;
            let mut rejected = String::new();
            let halvings = if max_error < NEAR.0 { NEAR.1 } else { MAX_HALVINGS };
            for _ in 0..=halvings {
                let clock = Instant::now();
                let trial: Vec<f64> = w.iter().zip(&delta).map(|(w, d)| w + alpha * d).collect();
                let next = at(&trial)?;
                record.diagrams += 1;
                seconds += clock.elapsed().as_secs_f64();
                let after = norm(&run.targets.iter().zip(&next.volume).map(|(t, m)| t - m).collect::<Vec<_>>())?;
                let lightest = across.min(next.volume.iter().copied().fold(f64::INFINITY, f64::min))?;
                // A step that reaches the tolerance is taken (there, the
                // norm is the masses' rounding, which need not halve).
                let reached = across.max(worst(&run.targets, &next.volume))? <= self.tolerance;
                if lightest >= floor && (after <= (1.0 - 0.5 * alpha) * before || reached) {
                    accepted = Some((trial, next));
                    break;
                }
                rejected = if lightest < floor {
                    let here = next.volume.iter().position(|&m| m == lightest);
                    let i = across.min(here.map_or(f64::INFINITY, |i| (across.first + i as u64) as f64))?;
                    format!(
                        "at step {alpha:e}, site {i}'s cell would fall to mass {lightest:.3e}, below the floor \
                         {floor:.3e} (half the smallest of the targets and the starting masses)"
                    )
                } else {
                    format!(
                        "at step {alpha:e}, the error's norm went from {before:.3e} to {after:.3e}, not below \
                         (1 - step/2) times it (the masses' own rounding is about 1e-6 of a cell)"
                    )
                };
                alpha *= 0.5;
            }
            record.seconds = seconds;
            seconds = 0.0;
            let Some((trial, next)) = accepted else {
                // No length along the step was accepted: said with the
                // shortest one's reason.
                run.stopped = format!("no step along Newton's direction was accepted; {rejected}");
                record.step = 0.0;
                run.steps.push(record);
                progress(&record);
                break;
            };
            record.step = alpha;
            first = (2.0 * alpha).min(1.0);
            run.steps.push(record);
            w = trial;
            cells = next;
            if !progress(&record) {
                // Stopped: the diagram reached is the last one's.
                run.stopped = "stopped before converging (interrupted)".into();
                let max_error = across.max(worst(&run.targets, &cells.volume))?;
                run.steps.push(NewtonStep { max_error, ..Default::default() });
                break;
            }
        }
        let mean = across.sum(&w)? / across.total as f64;
        run.weights = w.iter().map(|x| x - mean).collect();
        run.cells = cells;
        Ok(run)
    }
}

/// A law to draw the cells' target volumes from, as grain generators
/// for materials do (Laguerre tessellations of polycrystals): one volume
/// per site, then scaled to the domain's mass like any capacities.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum VolumeLaw {
    /// `ln V` normal with mean `mu` and deviation `sigma`.
    LogNormal {
        /// Mean of `ln V`.
        mu: f64,
        /// Deviation of `ln V` (at least 0).
        sigma: f64,
    },
}

impl VolumeLaw {
    /// `n` volumes drawn with `seed` (the same seed, the same volumes).
    pub fn draw(&self, n: usize, seed: u64) -> Vec<f64> {
        self.draw_rows(0..n as u64, seed)
    }

    /// The volumes `rows` of [`Self::draw`]`(n, seed)` for any `n` past
    /// them, without drawing the others (a part of a run in parts).
    pub fn draw_rows(&self, rows: std::ops::Range<u64>, seed: u64) -> Vec<f64> {
        let Self::LogNormal { mu, sigma } = *self;
        // Box-Muller on uniform pairs in (0, 1].
        crate::geom::points::uniform_rows(rows, seed)
            .iter()
            .map(|p| {
                let z = (-2.0 * (1.0 - p[0]).ln()).sqrt() * (std::f64::consts::TAU * p[1]).cos();
                (mu + sigma * z).exp()
            })
            .collect()
    }
}

impl std::str::FromStr for VolumeLaw {
    type Err = String;

    /// `lognormal:MU,SIGMA`.
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        let expected = "expected lognormal:MU,SIGMA (ln of a volume normal with mean MU and deviation SIGMA >= 0)";
        let Some(args) = text.strip_prefix("lognormal:") else {
            return Err(format!("unknown volume law {text:?}: {expected}"));
        };
        let numbers: Vec<f64> = args
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| format!("{text:?}: {expected}"))?;
        match numbers[..] {
            [mu, sigma] if mu.is_finite() && sigma.is_finite() && sigma >= 0.0 => Ok(Self::LogNormal { mu, sigma }),
            _ => Err(format!("{text:?}: {expected}")),
        }
    }
}

/// `max_i |m_i - t_i| / t_i`.
fn worst(targets: &[f64], masses: &[f64]) -> f64 {
    targets.iter().zip(masses).map(|(t, m)| ((t - m) / t).abs()).fold(0.0, f64::max)
}

/// The first two equal sites, named.
fn equal_sites(sites: &[[f64; 3]]) -> String {
    let mut seen = std::collections::HashMap::with_capacity(sites.len());
    for (i, p) in sites.iter().enumerate() {
        if let Some(j) = seen.insert(p.map(|c| (c + 0.0).to_bits()), i) {
            return format!("sites {j} and {i} are equal ({p:?})");
        }
    }
    "two sites are equal".into()
}

/// The Hessian of the masses in the weights: a weighted graph Laplacian
/// (CSR, the diagonal apart) over this process's rows; its columns are
/// local slots, the other processes' rows after the own ([`Ghosts`]).
struct Laplacian<'a> {
    offsets: Vec<usize>,
    columns: Vec<u32>,
    values: Vec<f64>,
    diagonal: Vec<f64>,
    ghosts: Ghosts<'a>,
    across: Across<'a>,
}

impl<'a> Laplacian<'a> {
    /// From the cells' faces: `A_ij / 2|x_i - x_j|` per shared face (`A_ij`
    /// its area, or its mass under a density; in a periodic box
    /// `period`, `x_j` the image the face is shared with).
    /// Refuses a diagram whose cells fall apart into separate groups (a
    /// domain in pieces), counted over every process's rows.
    fn of(cells: &Cells, sites: &[[f64; 3]], period: Option<PeriodicBox>, across: Across<'a>) -> Result<Self> {
        let adj = cells.adjacency().ok_or_else(|| Error::Internal("a transport diagram without faces".into()))?;
        let mut columns = adj.neighbors.clone();
        let ghosts = Ghosts::of(across, &mut columns)?;
        // The neighbours' sites: this process's, then the others'.
        let mut others = [Vec::new(), Vec::new(), Vec::new()];
        for (a, out) in others.iter_mut().enumerate() {
            ghosts.fill(&sites.iter().map(|p| p[a]).collect::<Vec<_>>(), out)?;
        }
        let site = |u: usize| [others[0][u], others[1][u], others[2][u]];
        let rows: Vec<u32> =
            adj.offsets.windows(2).enumerate().flat_map(|(i, r)| std::iter::repeat_n(i as u32, r[1] - r[0])).collect();
        let values: Vec<f64> = (0..adj.neighbors.len())
            .into_par_iter()
            .map(|e| {
                let (p, mut q) = (sites[rows[e] as usize], site(columns[e] as usize));
                if let Some(b) = period {
                    q = b.shifted(q, adj.shift(e));
                }
                let dist = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                adj.areas[e] / (2.0 * dist)
            })
            .collect();
        let diagonal = adj.offsets.par_windows(2).map(|r| values[r[0]..r[1]].iter().sum()).collect();
        let laplacian = Self { offsets: adj.offsets.clone(), columns, values, diagonal, ghosts, across };
        let groups = laplacian.groups()?;
        if groups > 1 {
            return Err(Error::InvalidInput(format!(
                "the cells fall apart into {groups} groups that share no face (a domain in separate pieces): \
                 optimal transport moves mass only across shared faces"
            )));
        }
        Ok(laplacian)
    }

    /// Connected groups of cells over every process's rows: each
    /// process's own rows grouped by their faces (union-find: a group's
    /// root its smallest row), each group labelled with its smallest global
    /// row, then lowered to the smallest label across its faces to other
    /// processes' rows until no label lowers; a group is counted at the row
    /// that keeps its own number.
    fn groups(&self) -> Result<u64> {
        let n = self.diagonal.len();
        let edges = |i: usize| {
            (self.offsets[i]..self.offsets[i + 1]).filter(|&e| self.values[e] > 0.0).map(|e| self.columns[e] as usize)
        };
        let mut parent: Vec<usize> = (0..n).collect();
        fn find(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for i in 0..n {
            for j in edges(i).filter(|&j| j < n) {
                let (a, b) = (find(&mut parent, i), find(&mut parent, j));
                parent[a.max(b)] = a.min(b);
            }
        }
        let root: Vec<usize> = (0..n).map(|i| find(&mut parent, i)).collect();
        let first = self.across.first as f64;
        let mut label: Vec<f64> = root.iter().map(|&r| first + r as f64).collect();
        if self.across.in_parts() {
            let mut all = Vec::new();
            loop {
                self.ghosts.fill(&label, &mut all)?;
                let mut lowest = label.clone();
                for i in 0..n {
                    for j in edges(i).filter(|&j| j >= n) {
                        lowest[root[i]] = lowest[root[i]].min(all[j]);
                    }
                }
                let mut lowered = false;
                for i in 0..n {
                    if lowest[root[i]] < label[i] {
                        (label[i], lowered) = (lowest[root[i]], true);
                    }
                }
                if !self.across.any(lowered)? {
                    break;
                }
            }
        }
        let counted: Vec<f64> = (0..n).map(|i| (label[i] == first + i as f64) as u8 as f64).collect();
        Ok(self.across.sum(&counted)? as u64)
    }

    /// `out = L x`.
    fn apply(&self, x: &[f64], out: &mut [f64]) {
        out.par_iter_mut().enumerate().with_min_len(1024).for_each(|(i, o)| {
            let mut s = self.diagonal[i] * x[i];
            for e in self.offsets[i]..self.offsets[i + 1] {
                s -= self.values[e] * x[self.columns[e] as usize];
            }
            *o = s;
        });
    }

    /// Solves `L δ = b` by Jacobi-preconditioned conjugate gradients until
    /// every cell's residual is within its `goal`; `δ` has mean zero.
    /// Returns it and the iterations. `b` is taken on `L`'s range (the
    /// constant vector is its kernel, so the range sums to zero): what it
    /// sums to — the masses' total rounding, as the domain fixes their sum
    /// — is taken off each cell in proportion to its `share` (its target),
    /// not evenly: an even part of the total rounding of thousands of
    /// cells is many times a cell 10⁻⁶ of the others' size, whose step it
    /// would then turn the wrong way.
    fn solve(&self, b: &[f64], goal: &[f64], share: &[f64]) -> Result<(Vec<f64>, u32)> {
        let n = b.len();
        let across = self.across;
        let dot = |a: &[f64], b: &[f64]| across.dot(a, b);
        let excess = across.sum(b)? / across.sum(share)?;
        let mut r: Vec<f64> = b.iter().zip(share).map(|(x, s)| x - excess * s).collect();
        let inverse: Vec<f64> = self.diagonal.iter().map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 }).collect();
        let mut x = vec![0.0; n];
        let mut z: Vec<f64> = r.iter().zip(&inverse).map(|(r, m)| r * m).collect();
        let mut p = z.clone();
        let mut q = vec![0.0; n];
        let mut rz = dot(&r, &z)?;
        let above = |r: &[f64]| across.any(r.par_iter().zip(goal).with_min_len(4096).any(|(r, g)| r.abs() > *g));
        let mut iterations = 0;
        // p with its values at the other processes' rows.
        let mut reach = Vec::with_capacity(n + self.ghosts.count);
        while (iterations as u64) < 20 * across.total + 100 && above(&r)? {
            self.ghosts.fill(&p, &mut reach)?;
            self.apply(&reach, &mut q);
            let pq = dot(&p, &q)?;
            if pq.is_nan() || pq <= 0.0 {
                break;
            }
            let a = rz / pq;
            x.par_iter_mut().zip(&p).for_each(|(x, p)| *x += a * p);
            r.par_iter_mut().zip(&q).for_each(|(r, q)| *r -= a * q);
            z.par_iter_mut().zip(&r).zip(&inverse).for_each(|((z, r), m)| *z = r * m);
            let rz_next = dot(&r, &z)?;
            let beta = rz_next / rz;
            rz = rz_next;
            p.par_iter_mut().zip(&z).for_each(|(p, z)| *p = z + beta * *p);
            iterations += 1;
        }
        let mean = across.sum(&x)? / across.total as f64;
        x.iter_mut().for_each(|v| *v -= mean);
        Ok((x, iterations))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Laplacian from undirected weighted edges.
    fn laplacian(n: usize, edges: &[(u32, u32, f64)]) -> Laplacian<'static> {
        let mut rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n];
        for &(i, j, w) in edges {
            rows[i as usize].push((j, w));
            rows[j as usize].push((i, w));
        }
        let mut offsets = vec![0];
        let (mut columns, mut values) = (Vec::new(), Vec::new());
        for row in &rows {
            columns.extend(row.iter().map(|e| e.0));
            values.extend(row.iter().map(|e| e.1));
            offsets.push(columns.len());
        }
        let diagonal = rows.iter().map(|r| r.iter().map(|e| e.1).sum()).collect();
        let across = Across::alone(n);
        Laplacian { offsets, columns, values, diagonal, ghosts: Ghosts::of(across, &mut []).unwrap(), across }
    }

    #[test]
    fn volume_laws_parse_and_draw_seeded_log_normal_volumes() {
        let law: VolumeLaw = "lognormal:0.5,1".parse().unwrap();
        assert_eq!(law, VolumeLaw::LogNormal { mu: 0.5, sigma: 1.0 });
        let v = law.draw(20_000, 7);
        assert_eq!(v, law.draw(20_000, 7), "seeded");
        let logs: Vec<f64> = v.iter().map(|x| x.ln()).collect();
        let mean = logs.iter().sum::<f64>() / logs.len() as f64;
        let sd = (logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / logs.len() as f64).sqrt();
        assert!((mean - 0.5).abs() < 0.03 && (sd - 1.0).abs() < 0.03, "{mean} {sd}");
        for bad in ["normal:0,1", "lognormal:0", "lognormal:0,-1", "lognormal:a,1", "lognormal:0,1,2"] {
            let e = bad.parse::<VolumeLaw>().unwrap_err();
            assert!(e.contains("expected lognormal:MU,SIGMA"), "{bad}: {e}");
        }
    }

    #[test]
    fn groups_count_the_parts_that_share_no_face() {
        let path = laplacian(4, &[(0, 1, 1.0), (1, 2, 2.0), (2, 3, 0.5)]);
        assert_eq!(path.groups().unwrap(), 1);
        let apart = laplacian(5, &[(0, 1, 1.0), (2, 3, 1.0)]);
        assert_eq!(apart.groups().unwrap(), 3, "{{0,1}}, {{2,3}} and {{4}}");
        // A face of zero area joins nothing.
        let zero = laplacian(3, &[(0, 1, 1.0), (1, 2, 0.0)]);
        assert_eq!(zero.groups().unwrap(), 2);
    }

    #[test]
    fn the_conjugate_gradients_solve_a_weighted_path_exactly() {
        // A path 0-1-2-3 with weights 1, 2, 4: L x = b for x = (3, 1, 0, -4)
        // shifted to mean zero.
        let l = laplacian(4, &[(0, 1, 1.0), (1, 2, 2.0), (2, 3, 4.0)]);
        let x: [f64; 4] = [3.0, 1.0, 0.0, -4.0];
        let mut b = [0.0; 4];
        l.apply(&x, &mut b);
        assert!(b.iter().sum::<f64>().abs() < 1e-12, "L's range sums to zero");
        let (solved, iterations) = l.solve(&b, &[1e-12; 4], &[1.0; 4]).unwrap();
        let mean = x.iter().sum::<f64>() / 4.0;
        for (s, x) in solved.iter().zip(x) {
            assert!((s - (x - mean)).abs() < 1e-9, "{solved:?} against {x} - {mean}");
        }
        assert!(iterations <= 4, "CG ends in n steps in exact arithmetic, here {iterations}");
    }

    #[test]
    fn the_right_hand_side_is_taken_on_the_laplacians_range() {
        // b with a constant part: the solve drops it (the masses' sum is
        // fixed by the domain, so Newton's system only sees differences).
        let l = laplacian(3, &[(0, 1, 1.0), (1, 2, 1.0)]);
        let (a, _) = l.solve(&[1.0, 0.0, -1.0], &[1e-12; 3], &[1.0; 3]).unwrap();
        let (b, _) = l.solve(&[6.0, 5.0, 4.0], &[1e-12; 3], &[1.0; 3]).unwrap();
        for (a, b) in a.iter().zip(&b) {
            assert!((a - b).abs() < 1e-9);
        }
        assert!(a.iter().sum::<f64>().abs() < 1e-12);
        // What b sums to is taken off in proportion to the shares: a cell
        // of share 10⁻⁶ with nothing to change keeps (almost) nothing to
        // change, where an even split would ask it for a third of the sum.
        let shares = [1.0, 1.0, 1e-6];
        let (c, _) = l.solve(&[1.0, -1.0 + 3e-9, 0.0], &[1e-15; 3], &shares).unwrap();
        let mut lc = [0.0; 3];
        l.apply(&c, &mut lc);
        assert!(lc[2].abs() < 1e-14, "the small cell's share of the excess: {:e}", lc[2]);
    }

    #[test]
    fn the_error_is_the_worst_relative_one_and_equal_sites_are_named() {
        assert_eq!(worst(&[1.0, 2.0, 4.0], &[1.0, 1.0, 5.0]), 0.5);
        assert_eq!(worst(&[1.0], &[1.0]), 0.0);
        let sites = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-0.0, 0.0, 0.0]];
        assert_eq!(equal_sites(&sites), "sites 0 and 2 are equal ([-0.0, 0.0, 0.0])");
    }
}
