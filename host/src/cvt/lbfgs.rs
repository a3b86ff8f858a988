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
    run.sites = to_points(&x).into_iter().map(|p| diagram.place(p)).collect();
    Ok(run)
}
