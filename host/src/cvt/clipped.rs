//! The clipped diagram as a [`SiteDiagram`]: its Lloyd iterations on its
//! backend, its cells at other sites, and the CVT energy's gradient
//! `2 V_i (x_i - C_i)`.

use super::{to_points, CvtRun, Evaluation, SiteDiagram};
use crate::diagram::voronoi::{Cells, ClippedVoronoi};
use crate::error::Result;

impl SiteDiagram for ClippedVoronoi<'_> {
    fn starting_sites(&self) -> &[[f64; 3]] {
        self.sites
    }

    fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells> {
        ClippedVoronoi { sites, ..*self }.compute()
    }

    fn power_cells_at(&self, sites: &[[f64; 3]], weights: &[f64]) -> Result<Cells> {
        ClippedVoronoi { sites, face_masses: true, ..self.weights(weights).faces(true) }.compute()
    }

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

    fn lloyd(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
        super::lloyd::on_backend(self, iterations, progress)
    }
}
