//! The clipped diagram as a [`SiteDiagram`]: its Lloyd iterations (by
//! diagrams for whole cells on the CPU, else on its backend), its cells at other sites, and the CVT energy's gradient
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
        // Whole cells on the CPU: one diagram per iteration, every site in
        // f64 (the same bits as a diagram in parts, `ClippedInParts`; it
        // costs about 2 % over the loop in the job's frame). The backend's
        // loop otherwise: on Vulkan the whole loop on the device.
        let on_cpu = self.backend.is_none_or(|b| b.kind() == crate::job::BackendKind::Cpu);
        if on_cpu && self.resolved_strategy() == crate::job::clip::Strategy::Whole {
            return super::lloyd::by_diagrams(self, iterations, progress);
        }
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
/// Lloyd, L-BFGS and optimal transport take on every rank the steps one
/// process takes with every site on the CPU, to the bit (Lloyd one diagram
/// per iteration, as one process takes it with whole cells; transport's
/// power cells with their faces, neighbours by input index). Whole cells.
pub struct ClippedInParts<'a> {
    diagram: ClippedVoronoi<'a>,
    comm: &'a dyn crate::backends::distributed::Reduce,
    /// The halos the last diagram's sub-parts took: the next starts there.
    halos: crate::diagram::mesh_parts::Halos,
}

impl<'a> ClippedInParts<'a> {
    /// `diagram` (its sites this rank's rows of the input) in parts over
    /// the ranks of `comm`.
    pub fn new(diagram: ClippedVoronoi<'a>, comm: &'a dyn crate::backends::distributed::Reduce) -> Self {
        Self { diagram, comm, halos: Default::default() }
    }

    /// The diagram at `sites`, starting each sub-part's halo where the
    /// last diagram's ended.
    fn at<'b>(&'b self, sites: &'b [[f64; 3]]) -> ClippedVoronoi<'b> {
        ClippedVoronoi { sites, halos: Some(&self.halos), ..self.diagram }
    }
}

impl SiteDiagram for ClippedInParts<'_> {
    fn starting_sites(&self) -> &[[f64; 3]] {
        self.diagram.sites
    }

    fn cells_at(&self, sites: &[[f64; 3]]) -> Result<Cells> {
        Ok(self.at(sites).compute_in_parts(self.comm)?.0)
    }

    fn power_cells_at(&self, sites: &[[f64; 3]], weights: &[f64]) -> Result<Cells> {
        let diagram = ClippedVoronoi { face_masses: true, ..self.at(sites).weights(weights).faces(true) };
        Ok(diagram.compute_in_parts(self.comm)?.0)
    }

    fn evaluate(&self, x: &[f64]) -> Result<(Evaluation, f64)> {
        let sites = to_points(x);
        let start = std::time::Instant::now();
        let cells = self.at(&sites).faces(false).compute_in_parts(self.comm)?.0;
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
    use crate::backends::distributed::{InProcess, Reduce as _};
    use crate::geom::mesh::TetMesh;
    use crate::geom::points;
    use crate::job::clip::Strategy;

    /// The rows of `n` sites rank `r` of `ranks` holds.
    fn rows(n: usize, ranks: usize, r: usize) -> std::ops::Range<usize> {
        n * r / ranks..n * (r + 1) / ranks
    }

    /// An L-shaped domain with a crowd and a tight cluster.
    fn crowd_and_cluster() -> (TetMesh, Vec<[f64; 3]>) {
        let mesh = TetMesh::voxels(8, |i, j, _| i < 4 || j < 4);
        let mut sites = points::in_mesh(&mesh, 3000, 41);
        sites.extend(points::clustered(500, 2, 0.02, 42).into_iter().map(|p| p.map(|x| 0.1 + 0.3 * x)));
        (mesh, sites)
    }

    fn bits(sites: &[[f64; 3]]) -> Vec<[u64; 3]> {
        sites.iter().map(|p| p.map(f64::to_bits)).collect()
    }

    fn energies(run: &CvtRun) -> Vec<u64> {
        run.iterations.iter().map(|i| i.energy.to_bits()).collect()
    }

    /// L-BFGS on a mesh with its sites in parts takes one process's steps:
    /// every rank's rows move to the bit as one process moves them.
    #[test]
    fn lbfgs_in_parts_moves_the_sites_of_one_process() {
        let (mesh, sites) = crowd_and_cluster();
        let cpu = crate::exec::CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).backend(&cpu);
        let one = one.lbfgs(4, &mut |_, _| {}).unwrap();
        for ranks in [2, 3] {
            let runs = InProcess::each(ranks, |comm| {
                let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
                let mine = &sites[rows(sites.len(), ranks, comm.rank())];
                let cv = ClippedVoronoi::new(&mesh, mine).backend(&cpu).parts_per_rank(2);
                ClippedInParts::new(cv, comm).lbfgs(4, &mut |_, _| {}).unwrap()
            });
            for (r, run) in runs.iter().enumerate() {
                let expected = &one.sites[rows(sites.len(), ranks, r)];
                assert_eq!(bits(expected), bits(&run.sites), "{ranks} ranks: rank {r}'s sites");
                assert_eq!(energies(&one), energies(run), "{ranks} ranks: the energies");
            }
        }
    }

    /// Lloyd on a mesh with its sites in parts moves every site as one
    /// process does on the CPU (one diagram per iteration), to the bit; the
    /// backend's loop in the job's frame (sites as pairs of f32, as on the
    /// device) up to rounding.
    #[test]
    fn lloyd_in_parts_moves_the_sites_of_one_process() {
        let (mesh, sites) = crowd_and_cluster();
        let cpu = crate::exec::CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).backend(&cpu);
        let lloyd = one.lloyd(3, &mut |_, _| {}).unwrap();
        let by_diagrams = super::super::lloyd::by_diagrams(&one, 3, &mut |_, _| {}).unwrap();
        assert_eq!(bits(&lloyd.sites), bits(&by_diagrams.sites), "one process: whole cells by diagrams");
        let on_backend = super::super::lloyd::on_backend(&one, 3, &mut |_, _| {}).unwrap();
        let apart = lloyd.sites.iter().zip(&on_backend.sites).flat_map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()));
        let apart = apart.fold(0.0, f64::max);
        assert!(apart < 1e-7, "by diagrams and the backend's loop {apart:e} apart in a unit domain");
        for (ranks, per_rank) in [(2, 1), (3, 2)] {
            let runs = InProcess::each(ranks, |comm| {
                let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
                let mine = &sites[rows(sites.len(), ranks, comm.rank())];
                let cv = ClippedVoronoi::new(&mesh, mine).backend(&cpu).parts_per_rank(per_rank);
                ClippedInParts::new(cv, comm).lloyd(3, &mut |_, _| {}).unwrap()
            });
            for (r, run) in runs.iter().enumerate() {
                let expected = &lloyd.sites[rows(sites.len(), ranks, r)];
                assert_eq!(bits(expected), bits(&run.sites), "{ranks} ranks: rank {r}'s sites");
                assert_eq!(energies(&lloyd), energies(run), "{ranks} ranks: the energies");
            }
        }
    }

    /// Lloyd under a density in parts: each centroid weighted by the
    /// density, one process's steps to the bit.
    #[test]
    fn lloyd_under_a_density_in_parts_moves_the_sites_of_one_process() {
        let (mesh, sites) = crowd_and_cluster();
        let sites = &sites[..2500];
        let rho: Vec<f64> = mesh.vertices.iter().map(|v| 1.0 + 9.0 * v[2].powi(2)).collect();
        let cpu = crate::exec::CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, sites).strategy(Strategy::Whole).density(Some(&rho)).backend(&cpu);
        let lloyd = one.lloyd(3, &mut |_, _| {}).unwrap();
        let plain = ClippedVoronoi::new(&mesh, sites).strategy(Strategy::Whole).backend(&cpu);
        let plain = plain.lloyd(3, &mut |_, _| {}).unwrap();
        let mean_z = |s: &[[f64; 3]]| s.iter().map(|p| p[2]).sum::<f64>() / s.len() as f64;
        assert!(mean_z(&lloyd.sites) > mean_z(&plain.sites) + 1e-3, "the density draws the sites up");
        for (ranks, per_rank) in [(2, 1), (3, 2)] {
            let runs = InProcess::each(ranks, |comm| {
                let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
                let mine = &sites[rows(sites.len(), ranks, comm.rank())];
                let cv = ClippedVoronoi::new(&mesh, mine).density(Some(&rho)).strategy(Strategy::Whole);
                let cv = cv.backend(&cpu).parts_per_rank(per_rank);
                ClippedInParts::new(cv, comm).lloyd(3, &mut |_, _| {}).unwrap()
            });
            for (r, run) in runs.iter().enumerate() {
                let expected = &lloyd.sites[rows(sites.len(), ranks, r)];
                assert_eq!(bits(expected), bits(&run.sites), "{ranks} ranks: rank {r}'s sites");
                assert_eq!(energies(&lloyd), energies(run), "{ranks} ranks: the energies");
            }
        }
    }

    /// Optimal transport on a mesh with its sites in parts finds one
    /// process's weights, Newton steps and masses, to the bit; a domain in
    /// two pieces is refused in parts as in one process.
    #[test]
    fn optimal_transport_in_parts_finds_the_one_process_weights() {
        use crate::cvt::transport::{Transport, TransportRun};
        let (mesh, sites) = crowd_and_cluster();
        let sites = &sites[..2000];
        let capacities: Vec<f64> = points::uniform(sites.len(), 43).iter().map(|p| 1.0 + 3.0 * p[0]).collect();
        let cpu = crate::exec::CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, sites).strategy(Strategy::Whole).backend(&cpu);
        let whole = Transport::new(one).capacities(&capacities).solve(&mut |_| true).unwrap();
        assert!(whole.converged && whole.steps.len() > 2, "one process: {}", whole.stopped);
        let steps = |r: &TransportRun| {
            r.steps.iter().map(|s| (s.max_error.to_bits(), s.step.to_bits(), s.cg_iterations)).collect::<Vec<_>>()
        };
        for ranks in [2, 3] {
            let runs = InProcess::each(ranks, |comm| {
                let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
                let mine = rows(sites.len(), ranks, comm.rank());
                let cv = ClippedVoronoi::new(&mesh, &sites[mine.clone()]).backend(&cpu).parts_per_rank(2);
                let diagram = ClippedInParts::new(cv, comm);
                Transport::new(diagram).capacities(&capacities[mine]).solve(&mut |_| true).unwrap()
            });
            let weights: Vec<u64> = runs.iter().flat_map(|r| &r.weights).map(|w| w.to_bits()).collect();
            assert!(weights == whole.weights.iter().map(|w| w.to_bits()).collect::<Vec<_>>(), "{ranks} ranks");
            let masses: Vec<u64> = runs.iter().flat_map(|r| &r.cells.volume).map(|m| m.to_bits()).collect();
            assert!(masses == whole.cells.volume.iter().map(|m| m.to_bits()).collect::<Vec<_>>(), "{ranks} ranks");
            for run in &runs {
                assert_eq!(steps(run), steps(&whole), "{ranks} ranks: the Newton steps");
            }
        }
        // Two cubes apart: the cells fall apart in two groups, on any rank.
        let mut two = TetMesh::cube(3);
        let cube = TetMesh::cube(3);
        let base = two.vertices.len() as u32;
        two.vertices.extend(cube.vertices.iter().map(|v| [v[0] + 2.0, v[1], v[2]]));
        two.tets.extend(cube.tets.iter().map(|t| t.map(|k| k + base)));
        let split: Vec<[f64; 3]> = points::uniform(400, 44)
            .into_iter()
            .map(|p| [p[0] + if p[1] > 0.5 { 2.0 } else { 0.0 }, p[1], p[2]])
            .collect();
        let errors = InProcess::each(3, |comm| {
            let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
            let cv = ClippedVoronoi::new(&two, &split[rows(400, 3, comm.rank())]).backend(&cpu);
            Transport::new(ClippedInParts::new(cv, comm)).solve(&mut |_| true).err().map(|e| e.to_string())
        });
        for e in errors {
            assert!(e.as_deref().is_some_and(|e| e.contains("2 groups")), "{e:?}");
        }
    }
}
