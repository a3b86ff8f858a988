//! Lloyd's iteration: every site to its cell's centroid. A clipped
//! diagram runs the loop on its backend ([`on_backend`]: on Vulkan the
//! whole loop runs on the device — grid, k-NN, clipping, second pass, site
//! update — and only a few numbers per iteration come back); any other
//! diagram one diagram per iteration ([`by_diagrams`]).

use super::{CvtRun, Iteration, SiteDiagram};
use crate::backend::Backend;
use crate::diagram::voronoi::ClippedVoronoi;
use crate::error::{Error, Result};
use crate::job::clip::{ClipJob, Frame, Pairing};
use crate::job::lloyd::LloydOutput;
use crate::job::sites::SiteMap;
use cvd_kernels::abi::lloyd_stat;
use std::time::Instant;

/// `iterations` Lloyd iterations of `diagram` from its sites as it places
/// them, one diagram each: every site with a cell to its centroid (as the
/// diagram's cells give it: a periodic box's are wrapped); `progress`
/// is called with the iterations done and the energy the last one started
/// from. Returns the sites reached and each iteration's record.
pub fn by_diagrams<D: SiteDiagram + ?Sized>(
    diagram: &D,
    iterations: usize,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<CvtRun> {
    let mut sites: Vec<[f64; 3]> = diagram.starting_sites().iter().map(|&p| diagram.place(p)).collect();
    let mut run = CvtRun::default();
    for it in 0..iterations {
        let clock = Instant::now();
        let c = diagram.cells_at(&sites)?;
        let energy = super::total_of(diagram, &c.energy)?;
        for (s, (&centroid, &m)) in sites.iter_mut().zip(c.centroid.iter().zip(&c.volume)) {
            if m > 0.0 {
                *s = centroid;
            }
        }
        run.iterations.push(Iteration {
            energy,
            empty_cells: c.counters.empty_cells,
            second_pass: c.counters.second_pass,
            unresolved: c.counters.unresolved,
            seconds: clock.elapsed().as_secs_f64(),
            newton_steps: 0,
        });
        progress(it + 1, energy);
    }
    run.sites = sites;
    Ok(run)
}

/// Lloyd's iterations of a clipped diagram on its backend (flood pairing,
/// tet-cell), calling `progress` with the iterations done so far and the
/// energy the last one started from (on Vulkan, once per batch of
/// iterations). Duplicate sites keep their place (their cells are empty).
pub(crate) fn on_backend(
    diagram: &ClippedVoronoi,
    iterations: usize,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<CvtRun> {
    // The faces are the final diagram's business, not the iterations'.
    let (job, map, frame) = diagram.faces(false).job()?;
    if job.pairing != Pairing::Flood {
        return Err(Error::InvalidInput("Lloyd iterations use flood pairing (tet-cell)".into()));
    }
    let cpu;
    let backend: &dyn Backend = match diagram.backend {
        Some(b) => b,
        None => {
            cpu = crate::exec::CpuBackend::new(None)?;
            &cpu
        }
    };
    let to_energy = energy_scale(&job, &frame);
    let out = backend.lloyd(&job, iterations, &mut |done, e| progress(done, e as f64 * to_energy))?;
    Ok(report(diagram.sites, &job, &map, &frame, &out))
}

/// World energy per unit of a fixed-point energy sum.
fn energy_scale(job: &ClipJob, frame: &Frame) -> f64 {
    frame.scale.powi(5) / job.params.fixed_scale as f64
}

fn report(input: &[[f64; 3]], job: &ClipJob, map: &SiteMap, frame: &Frame, out: &LloydOutput) -> CvtRun {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cvt::tests::{Quadratic, BOGUS};

    #[test]
    fn sites_move_to_their_centroids() {
        let start = vec![[0.1, 0.9, 0.3], [0.7, 0.2, 0.8], [0.4, 0.4, 0.1]];
        let centre = vec![[0.3, 0.6, 0.5], [0.5, 0.5, 0.5], [0.2, 0.7, 0.4]];
        let q = Quadratic::new(start.clone(), centre.clone());
        let mut calls = Vec::new();
        let run = by_diagrams(&q, 3, &mut |done, e| calls.push((done, e))).unwrap();
        assert_eq!(run.sites, centre);
        let e0 = q.energy(&start);
        let energies: Vec<f64> = run.iterations.iter().map(|i| i.energy).collect();
        assert_eq!(energies, vec![e0, 0.0, 0.0], "the energy each iteration started from");
        assert_eq!(calls, vec![(1, e0), (2, 0.0), (3, 0.0)]);
        let asked: Vec<Vec<[f64; 3]>> = q.asked().into_iter().map(|(s, _)| s).collect();
        assert_eq!(asked, vec![start, centre.clone(), centre], "one diagram per iteration");
        for it in &run.iterations {
            assert_eq!((it.empty_cells, it.second_pass, it.unresolved, it.newton_steps), (0, 3, 1, 0));
        }
    }

    #[test]
    fn a_site_whose_cell_is_empty_stays() {
        let start = vec![[0.1, 0.9, 0.3], [0.7, 0.2, 0.8]];
        let centre = vec![[0.3, 0.6, 0.5], [0.5, 0.5, 0.5]];
        let mut q = Quadratic::new(start.clone(), centre.clone());
        q.empty[1] = true;
        let run = by_diagrams(&q, 2, &mut |_, _| {}).unwrap();
        assert_eq!(run.sites, vec![centre[0], start[1]], "moved to the empty cell's centroid {BOGUS:?}?");
        assert!(run.iterations.iter().all(|i| i.empty_cells == 1));
    }

    #[test]
    fn the_starting_sites_are_placed_first() {
        let start = vec![[1.25, -0.5, 0.5], [0.5, 2.75, -3.0]];
        let centre = vec![[0.25, 0.5, 0.5], [0.5, 0.75, 0.0]];
        let mut q = Quadratic::new(start, centre.clone());
        q.wrap = true;
        let run = by_diagrams(&q, 0, &mut |_, _| {}).unwrap();
        assert_eq!(run.sites, centre, "no iterations: the placed start");
        assert!(run.iterations.is_empty() && q.asked().is_empty());
        // The first diagram is asked at the placed sites, not the given ones.
        let run = by_diagrams(&q, 1, &mut |_, _| {}).unwrap();
        assert_eq!(q.asked()[0].0, centre);
        assert_eq!(run.iterations[0].energy, 0.0, "the placed start is the centroids already");
    }
}
