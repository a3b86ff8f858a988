//! The periodic box as a [`SiteDiagram`]: sites move through the box's
//! faces and are reported wrapped into it; the gradient `2 V_i (x_i -
//! C_i)` takes the centroid unwrapped around the site. In one process
//! ([`PeriodicVoronoi`]) or in parts over the ranks of a run
//! ([`PeriodicInParts`]).

use super::{to_points, Evaluation, SiteDiagram};
use crate::backends::distributed::Reduce;
use crate::diagram::periodic::{PeriodicCells, PeriodicVoronoi};
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
        Ok((evaluation(&out, out.cells.energy_total()), seconds))
    }
}

/// A periodic box in parts ([`PeriodicVoronoi::compute_in_parts`]) as a
/// [`SiteDiagram`]: each rank of `comm` holds its own rows of the sites
/// and moves them, and every sum the optimisers take is the total over
/// the ranks ([`SiteDiagram::total`]), so that Lloyd and L-BFGS take on
/// every rank the steps one process takes with every site, to the bit.
/// The iterations' cells have no faces; optimal transport's power cells
/// do (each row's faces, neighbours by global row).
pub struct PeriodicInParts<'a> {
    diagram: PeriodicVoronoi<'a>,
    comm: &'a dyn Reduce,
}

impl<'a> PeriodicInParts<'a> {
    /// `diagram` (its sites this rank's rows of the input) in parts over
    /// the ranks of `comm`.
    pub fn new(diagram: PeriodicVoronoi<'a>, comm: &'a dyn Reduce) -> Self {
        Self { diagram, comm }
    }

    fn cells(&self, sites: &[[f64; 3]]) -> Result<PeriodicCells> {
        Ok(self.diagram.sites(sites).faces(false).compute_in_parts(self.comm)?.0)
    }
}

impl SiteDiagram for PeriodicInParts<'_> {
    fn starting_sites(&self) -> &[[f64; 3]] {
        self.diagram.input_sites()
    }

    fn place(&self, p: [f64; 3]) -> [f64; 3] {
        self.diagram.domain().wrap(p)
    }

    fn period(&self) -> Option<crate::geom::periodic_box::PeriodicBox> {
        Some(self.diagram.domain())
    }

    fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells> {
        Ok(self.cells(sites)?.cells)
    }

    fn power_cells_at(&self, sites: &[[f64; 3]], weights: &[f64]) -> Result<Cells> {
        Ok(self.diagram.sites(sites).weights(weights).faces(true).compute_in_parts(self.comm)?.0.cells)
    }

    fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)> {
        let clock = Instant::now();
        let out = self.cells(&to_points(x))?;
        let seconds = clock.elapsed().as_secs_f64();
        let energy = super::total_of(self, &out.cells.energy)?;
        Ok((evaluation(&out, energy), seconds))
    }

    fn comm(&self) -> Option<&dyn Reduce> {
        Some(self.comm)
    }
}

/// What the optimisers read of a periodic diagram with `energy`: the
/// gradient `2 V (x - c)`, the centroid unwrapped around the site.
fn evaluation(out: &PeriodicCells, energy: f64) -> Evaluation {
    let c = &out.cells;
    let n = c.volume.len();
    let mut gradient = vec![0.0; 3 * n];
    let mut precondition = vec![0.0; 3 * n];
    for (i, &v) in c.volume.iter().enumerate() {
        if v > 0.0 {
            for a in 0..3 {
                gradient[3 * i + a] = -2.0 * v * out.offsets[i][a];
                precondition[3 * i + a] = 1.0 / (2.0 * v);
            }
        }
    }
    Evaluation {
        energy,
        gradient,
        precondition,
        empty: c.counters.empty_cells,
        second_pass: c.counters.second_pass,
        unresolved: c.counters.unresolved,
    }
}
