//! L-BFGS on the CVT energy (as Geogram's Newton iterations, memory 7):
//! quasi-Newton steps preconditioned by `1 / 2V_i`, so that the first step
//! is Lloyd's, with a backtracking line search that only accepts steps
//! that lower the energy.

use super::{to_points, CvtRun, Iteration, SiteDiagram};
use crate::error::Result;

/// Steps remembered by L-BFGS.
const LBFGS_MEMORY: usize = 7;

/// L-BFGS on the CVT energy of `diagram` from its sites, for at most
/// `iterations` iterations (see the module's documentation), calling
/// `progress` after each. Every iteration lowers the energy or stops the
/// run early (at a minimum to float precision). The sites come back as the
/// diagram places them ([`SiteDiagram::place`]).
pub fn run<D: SiteDiagram + ?Sized>(
    diagram: &D,
    iterations: usize,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<CvtRun> {
    let sites = diagram.starting_sites();
    let evaluate = |x: &[f64]| diagram.evaluate(x);
    // Exact dot products: the same steps in parts as in one process.
    let across = super::across::Across::of(diagram, 3 * sites.len())?;
    let dot = |a: &[f64], b: &[f64]| across.dot(a, b);
    let mut x: Vec<f64> = sites.iter().flatten().copied().collect();
    let (mut at, mut seconds) = evaluate(&x)?;
    let mut memory: Vec<(Vec<f64>, Vec<f64>, f64)> = Vec::new();
    let mut run = CvtRun::default();
    for it in 0..iterations {
        // Two-loop recursion with the diagonal preconditioner as H0.
        let mut d: Vec<f64> = at.gradient.iter().map(|g| -g).collect();
        let mut alphas = Vec::with_capacity(memory.len());
        for (s, y, rho) in memory.iter().rev() {
            let a = rho * dot(s, &d)?;
            d.iter_mut().zip(y).for_each(|(di, yi)| *di -= a * yi);
            alphas.push(a);
        }
        d.iter_mut().zip(&at.precondition).for_each(|(di, h)| *di *= h);
        for ((s, y, rho), a) in memory.iter().zip(alphas.iter().rev()) {
            let b = rho * dot(y, &d)?;
            d.iter_mut().zip(s).for_each(|(di, si)| *di += (a - b) * si);
        }
        let mut slope = dot(&at.gradient, &d)?;
        if slope >= 0.0 {
            // Not a descent direction: fall back to the Lloyd step.
            d = at.gradient.iter().zip(&at.precondition).map(|(g, h)| -g * h).collect();
            slope = dot(&at.gradient, &d)?;
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
        let sy = dot(&s, &y)?;
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
    run.sites = to_points(&x).into_iter().map(|p| diagram.place(p)).collect();
    Ok(run)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cvt::tests::Quadratic;

    fn energies(run: &CvtRun) -> Vec<f64> {
        run.iterations.iter().map(|i| i.energy).collect()
    }

    /// Four sites with a different stiffness along every coordinate: the
    /// diagonal preconditioner is wrong by up to 8 times.
    fn anisotropic() -> Quadratic {
        let start = vec![[0.1, 0.9, 0.3], [0.7, 0.2, 0.8], [0.4, 0.4, 0.1], [0.95, 0.05, 0.5]];
        let centre = vec![[0.3, 0.6, 0.5], [0.5, 0.5, 0.5], [0.2, 0.7, 0.4], [0.8, 0.3, 0.6]];
        let mut q = Quadratic::new(start, centre);
        q.stiffness = vec![1.0, 4.0, 0.5, 2.0, 8.0, 1.0, 0.25, 3.0, 1.5, 6.0, 1.0, 0.75];
        q
    }

    #[test]
    fn reaches_the_minimiser_and_stops_there() {
        let q = anisotropic();
        let mut calls = Vec::new();
        let run = run(&q, 500, &mut |done, e| calls.push((done, e))).unwrap();
        let n = run.iterations.len();
        assert!(n < 500, "did not stop early at the minimum");
        for (s, c) in run.sites.iter().zip(&q.centre) {
            for a in 0..3 {
                assert!((s[a] - c[a]).abs() < 1e-7, "site {s:?}, minimiser {c:?}");
            }
        }
        assert!(q.energy(&run.sites) < 1e-15, "final energy {}", q.energy(&run.sites));
        let e = energies(&run);
        assert!(e.windows(2).all(|w| w[1] < w[0]), "energy not strictly decreasing: {e:?}");
        assert_eq!(e[0], q.energy(&q.start), "the first record is the starting energy");
        let expected: Vec<(usize, f64)> = e.iter().enumerate().map(|(i, &e)| (i + 1, e)).collect();
        assert_eq!(calls, expected, "progress after each iteration");
    }

    #[test]
    fn every_accepted_step_lowers_the_energy() {
        let q = anisotropic();
        let run = run(&q, 6, &mut |_, _| {}).unwrap();
        assert_eq!(run.iterations.len(), 6, "far from the minimum after 6");
        // The iterates the run settled on are the starting points of the
        // records; each was a trial whose energy beat the one before.
        let e = energies(&run);
        assert!(e.windows(2).all(|w| w[1] < w[0]), "{e:?}");
        assert!(q.energy(&run.sites) < e[5], "the last step lowered it too");
        // Trials that raised the energy were evaluated but not taken: some
        // were (the full step overshoots the stiff coordinates).
        let asked = q.asked();
        assert!(asked.iter().any(|(_, ae)| *ae > e[0]), "no step was ever rejected");
    }

    #[test]
    fn the_first_step_is_lloyds_and_a_minimum_stops_the_run() {
        // Dyadic coordinates: the preconditioned step lands exactly.
        let start = vec![[0.5, 0.25, 0.0], [0.0, 0.5, 0.75]];
        let centre = vec![[0.25, 0.25, 0.5], [0.5, 0.125, 0.5]];
        let q = Quadratic::new(start, centre.clone());
        let one = run(&q, 1, &mut |_, _| {}).unwrap();
        assert_eq!(one.sites, centre);
        let q = Quadratic::new(q.start.clone(), centre.clone());
        let run = run(&q, 10, &mut |_, _| {}).unwrap();
        assert_eq!(run.sites, centre);
        assert_eq!(energies(&run), vec![q.energy(&q.start), 0.0], "stops at the first iteration that cannot improve");
        // One evaluation at the start, one accepted trial, then 12 halvings
        // that do not lower a zero energy.
        assert_eq!(q.asked().len(), 1 + 1 + 12);
    }

    #[test]
    fn a_step_that_raises_the_energy_is_never_taken() {
        // A gradient with the wrong sign: every trial goes uphill.
        let mut q = anisotropic();
        q.lie = true;
        let mut calls = Vec::new();
        let run = run(&q, 20, &mut |done, e| calls.push((done, e))).unwrap();
        assert_eq!(run.sites, q.start, "the sites moved uphill");
        let e0 = q.energy(&q.start);
        assert_eq!(energies(&run), vec![e0]);
        assert_eq!(calls, vec![(1, e0)]);
        let asked = q.asked();
        assert_eq!(asked.len(), 1 + 12, "the start and 12 halvings");
        assert!(asked[1..].iter().all(|(_, e)| *e > e0), "a trial went downhill: {asked:?}");
    }

    #[test]
    fn empty_cells_do_not_move_and_are_counted() {
        let mut q = anisotropic();
        q.empty[2] = true;
        let run = run(&q, 500, &mut |_, _| {}).unwrap();
        assert_eq!(run.sites[2], q.start[2], "an empty cell's site moved");
        for i in [0, 1, 3] {
            assert!((0..3).all(|a| (run.sites[i][a] - q.centre[i][a]).abs() < 1e-7), "{:?}", run.sites[i]);
        }
        for it in &run.iterations {
            assert_eq!((it.empty_cells, it.second_pass, it.unresolved, it.newton_steps), (1, 3, 1, 0));
        }
    }

    #[test]
    fn sites_come_back_placed_but_move_unwrapped() {
        // The minimiser lies outside the unit box the mock wraps into.
        let start = vec![[0.5, 0.5, 0.5]];
        let centre = vec![[1.25, -0.5, 0.75]];
        let mut q = Quadratic::new(start, centre);
        q.wrap = true;
        let run = run(&q, 1, &mut |_, _| {}).unwrap();
        assert_eq!(run.sites, vec![[0.25, 0.5, 0.75]]);
        let asked = q.asked();
        assert_eq!(asked.last().unwrap().0, vec![[1.25, -0.5, 0.75]], "the trial itself is not wrapped");
    }

    #[test]
    fn no_iterations_give_the_placed_start() {
        let mut q = Quadratic::new(vec![[1.5, 0.25, -0.25]], vec![[0.0; 3]]);
        q.wrap = true;
        let mut called = false;
        let run = run(&q, 0, &mut |_, _| called = true).unwrap();
        assert_eq!(run.sites, vec![[0.5, 0.25, 0.75]]);
        assert!(run.iterations.is_empty() && !called);
    }
}
