//! The periodic box as a [`SiteDiagram`]: sites move through the box's
//! faces and are reported wrapped into it; the gradient `2 V_i (x_i -
//! C_i)` takes the centroid unwrapped around the site.

use super::{to_points, Evaluation, SiteDiagram};
use crate::diagram::periodic::PeriodicVoronoi;
use crate::diagram::voronoi::Cells;
use crate::error::Result;
use std::time::Instant;

impl SiteDiagram for PeriodicVoronoi<'_> {
    fn starting_sites(&self) -> &[[f64; 3]] {
        self.input_sites()
    }

    fn place(&self, p: [f64; 3]) -> [f64; 3] {
        self.domain().wrap(p)
    }

    fn period(&self) -> Option<crate::geom::periodic_box::PeriodicBox> {
        Some(self.domain())
    }

    fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells> {
        Ok(self.sites(sites).compute()?.cells)
    }

    fn power_cells_at(&self, sites: &[[f64; 3]], weights: &[f64]) -> Result<Cells> {
        Ok(self.sites(sites).weights(weights).faces(true).compute()?.cells)
    }

    fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)> {
        let sites = to_points(x);
        let clock = Instant::now();
        let out = self.sites(&sites).faces(false).compute()?;
        let seconds = clock.elapsed().as_secs_f64();
        let c = &out.cells;
        let mut gradient = vec![0.0; x.len()];
        let mut precondition = vec![0.0; x.len()];
        for (i, &v) in c.volume.iter().enumerate() {
            if v > 0.0 {
                for a in 0..3 {
                    // 2 V (x - c): the centroid unwrapped around the site.
                    gradient[3 * i + a] = -2.0 * v * out.offsets[i][a];
                    precondition[3 * i + a] = 1.0 / (2.0 * v);
                }
            }
        }
        let eval = Evaluation {
            energy: c.energy_total(),
            gradient,
            precondition,
            empty: c.counters.empty_cells,
            second_pass: c.counters.second_pass,
            unresolved: c.counters.unresolved,
        };
        Ok((eval, seconds))
    }
}
