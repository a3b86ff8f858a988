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
        Ok((evaluation(&sites, &cells, cells.energy_total()), seconds))
    }

    fn lloyd(&self, iterations: usize, progress: &mut dyn FnMut(usize, f64)) -> Result<CvtRun> {
        super::lloyd::on_backend(self, iterations, progress)
    }
}

/// What the optimisers read of the cells at `sites` with the CVT energy
/// `energy`: the gradient `2 V (x - c)` and its preconditioner.
fn evaluation(sites: &[[f64; 3]], cells: &Cells, energy: f64) -> Evaluation {
    let mut gradient = vec![0.0; 3 * sites.len()];
    let mut precondition = vec![0.0; 3 * sites.len()];
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
    Evaluation {
        energy,
        gradient,
        precondition,
        empty: c.empty_cells,
        second_pass: c.second_pass,
        unresolved: c.unresolved,
    }
}

/// A mesh with its sites in parts ([`ClippedVoronoi::compute_in_parts`])
/// as a [`SiteDiagram`]: each rank of `comm` holds its own rows of the
/// sites and moves them (the next diagram gives each site to the rank
/// whose run of the curve it moved into), and every sum the optimisers
/// take is the total over the ranks ([`SiteDiagram::total`]), so that
/// L-BFGS takes on every rank the steps one process takes with every site,
/// to the bit. Lloyd moves each site to its centroid one diagram at a time
/// ([`super::lloyd::by_diagrams`]; one process's CPU backend runs its loop
/// in the job's frame: the same sites up to rounding, not to the bit).
/// Whole cells, no power cells yet.
pub struct ClippedInParts<'a> {
    diagram: ClippedVoronoi<'a>,
    comm: &'a dyn crate::backends::distributed::Reduce,
}

impl<'a> ClippedInParts<'a> {
    /// `diagram` (its sites this rank's rows of the input) in parts over
    /// the ranks of `comm`.
    pub fn new(diagram: ClippedVoronoi<'a>, comm: &'a dyn crate::backends::distributed::Reduce) -> Self {
        Self { diagram, comm }
    }
}

impl SiteDiagram for ClippedInParts<'_> {
    fn starting_sites(&self) -> &[[f64; 3]] {
        self.diagram.sites
    }

    fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells> {
        Ok(ClippedVoronoi { sites, ..self.diagram }.compute_in_parts(self.comm)?.0)
    }

    fn power_cells_at(&self, _sites: &[[f64; 3]], _weights: &[f64]) -> Result<Cells> {
        Err(crate::error::Error::InvalidInput(
            "power cells of a mesh with its sites in parts are not computed yet; give every rank the whole input"
                .into(),
        ))
    }

    fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)> {
        let sites = to_points(x);
        let start = std::time::Instant::now();
        let cells = ClippedVoronoi { sites: &sites, faces: false, ..self.diagram }.compute_in_parts(self.comm)?.0;
        let seconds = start.elapsed().as_secs_f64();
        let energy = super::total_of(self, &cells.energy)?;
        Ok((evaluation(&sites, &cells, energy), seconds))
    }

    fn comm(&self) -> Option<&dyn crate::backends::distributed::Reduce> {
        Some(self.comm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backends::distributed::InProcess;
    use crate::geom::mesh::TetMesh;
    use crate::geom::points;
    use crate::job::clip::Strategy;

    /// L-BFGS on a mesh with its sites in parts takes one process's steps:
    /// every rank's rows move to the bit as one process moves them.
    #[test]
    fn lbfgs_in_parts_moves_the_sites_of_one_process() {
        let mesh = TetMesh::voxels(8, |i, j, _| i < 4 || j < 4);
        let mut sites = points::in_mesh(&mesh, 3000, 41);
        sites.extend(points::clustered(500, 2, 0.02, 42).into_iter().map(|p| p.map(|x| 0.1 + 0.3 * x)));
        let cpu = crate::exec::CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).backend(&cpu);
        let one = one.lbfgs(4, &mut |_, _| {}).unwrap();
        for ranks in [2, 3] {
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs: Vec<CvtRun> = std::thread::scope(|scope| {
                let handles: Vec<_> = InProcess::ranks(ranks)
                    .into_iter()
                    .enumerate()
                    .map(|(r, comm)| {
                        let (mesh, mine) = (&mesh, &sites[rows(r)]);
                        scope.spawn(move || {
                            let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
                            let cv = ClippedVoronoi::new(mesh, mine).backend(&cpu).parts_per_rank(2);
                            ClippedInParts::new(cv, &comm).lbfgs(4, &mut |_, _| {}).unwrap()
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            for (r, run) in runs.iter().enumerate() {
                for (a, b) in one.sites[rows(r)].iter().zip(&run.sites) {
                    assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{ranks} ranks: rank {r}'s sites");
                }
                let energies = |run: &CvtRun| run.iterations.iter().map(|i| i.energy.to_bits()).collect::<Vec<_>>();
                assert_eq!(energies(&one), energies(run), "{ranks} ranks: the energies");
            }
        }
    }
}
