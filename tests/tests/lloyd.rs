//! Lloyd's iteration on both backends: the energy goes down, a centroidal
//! tessellation is a fixed point, and the backends agree.

use cvd::cvt::CvtRun;
use cvd::cvt::SiteDiagram;
use cvd::{geom::points, Backend, ClippedVoronoi, TetMesh};
use cvd_tests::{assert_no_validation_errors, backends};

fn lloyd(mesh: &TetMesh, sites: &[[f64; 3]], iterations: usize, backend: &dyn Backend) -> CvtRun {
    let mut calls = Vec::new();
    let run = ClippedVoronoi::new(mesh, sites)
        .backend(backend)
        .lloyd(iterations, &mut |done, energy| calls.push((done, energy)))
        .unwrap_or_else(|e| panic!("{}: {e}", backend.name()));
    assert_eq!(run.iterations.len(), iterations);
    let last = calls.last().copied().unwrap_or_default();
    assert_eq!(last, (iterations, run.iterations[iterations - 1].energy), "{}: progress", backend.name());
    assert!(calls.windows(2).all(|w| w[0].0 < w[1].0), "{}: progress went backwards: {calls:?}", backend.name());
    // What the progress bar showed is what summary.json records.
    let record = cvd_io::CvtRecord::of("lloyd", &run.iterations);
    for &(done, energy) in &calls {
        assert_eq!(record.energy[done - 1], energy, "{}: iteration {done}", backend.name());
    }
    run
}

#[test]
fn energy_decreases_and_sites_stay_inside() {
    let mesh = TetMesh::voxels(4, |i, j, _| i < 2 || j < 2);
    let sites = points::in_mesh(&mesh, 150, 3);
    for backend in backends() {
        let run = lloyd(&mesh, &sites, 12, backend);
        let e: Vec<f64> = run.iterations.iter().map(|i| i.energy).collect();
        for w in e.windows(2) {
            assert!(w[1] <= w[0] * (1.0 + 1e-5), "{}: energy went up: {e:?}", backend.name());
        }
        assert!(e[e.len() - 1] < 0.8 * e[0], "{}: energy barely moved: {e:?}", backend.name());
        for it in &run.iterations {
            assert_eq!((it.unresolved, it.empty_cells), (0, 0), "{}: {it:?}", backend.name());
        }
        // Centroids of cells in the L-shaped mesh lie in its bounding box.
        assert!(run.sites.iter().all(|p| p.iter().all(|&c| (0.0..=1.0).contains(&c))), "{}", backend.name());
    }
    assert_no_validation_errors();
}

#[test]
fn a_centroidal_lattice_is_a_fixed_point() {
    // One site at the centre of each of the 4³ sub-cubes: each cell is its
    // sub-cube, whose centroid is the site (ties everywhere: a hard case).
    let n = 4;
    let mesh = TetMesh::cube(n);
    let h = 1.0 / n as f64;
    let mut sites = Vec::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                sites.push([(i as f64 + 0.5) * h, (j as f64 + 0.5) * h, (k as f64 + 0.5) * h]);
            }
        }
    }
    for backend in backends() {
        let run = lloyd(&mesh, &sites, 1, backend);
        for (a, b) in sites.iter().zip(&run.sites) {
            let d = (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f64>().sqrt();
            assert!(d <= 1e-5 * h, "{}: site {a:?} moved to {b:?}", backend.name());
        }
        // E = n³ sub-cubes x h⁵ / 4 (∫|x|² over a cube of side h is h⁵/4).
        let exact = (n * n * n) as f64 * h.powi(5) / 4.0;
        let e = run.iterations[0].energy;
        assert!((e - exact).abs() <= 1e-5 * exact, "{}: energy {e} vs {exact}", backend.name());
    }
    assert_no_validation_errors();
}

#[test]
fn backends_give_the_same_iterates() {
    let mesh = TetMesh::cube(5);
    let sites = points::uniform(300, 8);
    let runs: Vec<CvtRun> = backends().into_iter().map(|b| lloyd(&mesh, &sites, 4, b)).collect();
    if runs.len() < 2 {
        return;
    }
    let (cpu, gpu) = (&runs[0], &runs[1]);
    for (a, b) in cpu.iterations.iter().zip(&gpu.iterations) {
        assert!((a.energy - b.energy).abs() <= 1e-5 * a.energy, "energies {} vs {}", a.energy, b.energy);
    }
    let spacing = (1.0f64 / 300.0).cbrt();
    for (a, b) in cpu.sites.iter().zip(&gpu.sites) {
        let d = (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f64>().sqrt();
        assert!(d <= 1e-4 * spacing, "sites {a:?} vs {b:?}");
    }
    assert_no_validation_errors();
}

#[test]
fn lbfgs_decreases_the_energy_and_ends_no_worse_than_lloyd() {
    let mesh = TetMesh::cube(6);
    let sites = points::uniform(500, 21);
    for backend in backends() {
        let lloyd = lloyd(&mesh, &sites, 100, backend);
        let mut calls = Vec::new();
        let lbfgs =
            ClippedVoronoi::new(&mesh, &sites).backend(backend).lbfgs(100, &mut |d, e| calls.push((d, e))).unwrap();
        // One progress call per iteration, showing what the record keeps.
        let record = cvd_io::CvtRecord::of("lbfgs", &lbfgs.iterations);
        let shown: Vec<(usize, f64)> = record.energy.iter().enumerate().map(|(i, &e)| (i + 1, e)).collect();
        assert_eq!(calls, shown, "{}", backend.name());
        let e: Vec<f64> = lbfgs.iterations.iter().map(|i| i.energy).collect();
        assert!(e.windows(2).all(|w| w[1] < w[0]), "{}: L-BFGS energy did not decrease: {e:?}", backend.name());
        // Final energies: of the sites each run ends with.
        let final_energy =
            |sites: &[[f64; 3]]| ClippedVoronoi::new(&mesh, sites).backend(backend).compute().unwrap().energy_total();
        let (el, eb) = (final_energy(&lloyd.sites), final_energy(&lbfgs.sites));
        assert!(eb <= el * 1.005, "{}: L-BFGS {eb} vs Lloyd {el}", backend.name());
    }
    assert_no_validation_errors();
}

#[test]
fn a_linear_density_weights_cells_as_the_closed_form_says() {
    // Density 1 + 10x in the unit cube. One site: its cell is the cube,
    // mass 6, centre of mass x = 23/36, energy about the centre 3/2. Two
    // sites splitting the cube at x = 1/2: the left half has mass 7/4 and
    // centre of mass x = (1/8 + 5/12) / (7/4).
    let mesh = TetMesh::cube(3);
    let rho: Vec<f64> = mesh.vertices.iter().map(|v| 1.0 + 10.0 * v[0]).collect();
    for backend in backends() {
        let one = [[0.5f64, 0.5, 0.5]];
        let cells = ClippedVoronoi::new(&mesh, &one).density(Some(&rho)).backend(backend).compute().unwrap();
        let what = backend.name();
        assert!((cells.volume[0] - 6.0).abs() < 1e-5, "{what}: mass {}", cells.volume[0]);
        assert!((cells.mesh_volume - 6.0).abs() < 1e-6 && cells.e_vol < 1e-6, "{what}: {cells:?}");
        let c = cells.centroid[0];
        assert!((c[0] - 23.0 / 36.0).abs() < 1e-5 && (c[1] - 0.5).abs() < 1e-5, "{what}: {c:?}");
        assert!((cells.energy[0] - 1.5).abs() < 1e-5, "{what}: energy {}", cells.energy[0]);
        let two = [[0.25f64, 0.5, 0.5], [0.75, 0.5, 0.5]];
        let cells = ClippedVoronoi::new(&mesh, &two).density(Some(&rho)).backend(backend).compute().unwrap();
        assert!((cells.volume[0] - 1.75).abs() < 1e-5, "{what}: {:?}", cells.volume);
        let cx = (0.125 + 10.0 / 24.0) / 1.75;
        assert!((cells.centroid[0][0] - cx).abs() < 1e-5, "{what}: {:?}", cells.centroid[0]);
        // Lloyd moves both sites toward the dense side.
        let run =
            ClippedVoronoi::new(&mesh, &two).density(Some(&rho)).backend(backend).lloyd(1, &mut |_, _| {}).unwrap();
        assert!((run.sites[0][0] - cx).abs() < 1e-5, "{what}: {:?}", run.sites);
    }
    assert_no_validation_errors();
}
