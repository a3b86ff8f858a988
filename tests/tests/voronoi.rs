//! Clipped Voronoi cells: both strategies on both backends against the
//! exact f64 reference, against each other, and the volume balance.

use cvd::cvt::SiteDiagram;
use cvd::exec::CpuBackend;
use cvd::{geom::points, Backend, Cells, ClippedVoronoi, Pairing, Strategy, TetMesh};
use cvd_tests::reference::clipped_cells;
use cvd_tests::{assert_no_validation_errors, backends, vulkan};
use cvd_tests::{Placement, Shape};
use proptest::prelude::*;

fn mesh(shape: Shape) -> TetMesh {
    shape.mesh()
}

fn compute(mesh: &TetMesh, sites: &[[f64; 3]], strategy: Strategy, backend: &dyn Backend) -> Cells {
    let n = sites.len();
    ClippedVoronoi::new(mesh, sites)
        .strategy(strategy)
        .k(Some(n))
        .k_site(n)
        .backend(backend)
        .compute()
        .unwrap_or_else(|e| panic!("{} {strategy:?}: {e}", backend.name()))
}

/// Per-cell volumes within `tol` of max(V_i, V_M / n) and centroids within
/// `tol` of the cell size, against expected volumes and centroids.
fn assert_cells_match(what: &str, got: &Cells, vol: &[f64], centroid: &[[f64; 3]], tol: f64) {
    let n = vol.len() as f64;
    let typical = got.mesh_volume / n;
    for i in 0..vol.len() {
        let scale = vol[i].max(typical);
        let dv = (got.volume[i] - vol[i]).abs();
        assert!(dv <= tol * scale, "{what}: cell {i} volume {} vs {} (diff {dv:.3e})", got.volume[i], vol[i]);
        if vol[i] > 1e-2 * typical {
            let size = vol[i].cbrt();
            let dc = (0..3).map(|a| (got.centroid[i][a] - centroid[i][a]).powi(2)).sum::<f64>().sqrt();
            assert!(dc <= tol * size, "{what}: cell {i} centroid off by {dc:.3e} (cell size {size:.3e})");
        }
    }
}

fn sites_in_box(n: usize, seed: u64) -> Vec<[f64; 3]> {
    points::uniform(n, seed)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, failure_persistence: None, ..ProptestConfig::default() })]

    /// Both strategies, both backends, against the exact reference.
    #[test]
    fn cells_match_the_exact_reference(
        shape in prop_oneof![Just(Shape::Cube(4)), Just(Shape::Ell), Just(Shape::Holed)],
        n in 1usize..=150,
        seed in any::<u64>(),
    ) {
        let mesh = mesh(shape);
        let sites = sites_in_box(n, seed);
        let (vol, centroid) = clipped_cells(&mesh, &sites);
        let total: f64 = vol.iter().sum();
        prop_assert!((total - mesh.volume()).abs() <= 1e-9 * mesh.volume(), "reference loses volume: {total}");
        for backend in backends() {
            for strategy in [Strategy::TetCell, Strategy::CellTet] {
                let cells = compute(&mesh, &sites, strategy, backend);
                let what = format!("{shape:?} n={n} {} {strategy:?}", backend.name());
                assert_cells_match(&what, &cells, &vol, &centroid, 1e-4);
                prop_assert!(cells.e_vol <= 1e-5, "{what}: E_vol {}", cells.e_vol);
                prop_assert_eq!(cells.counters.overflows + cells.counters.broken, 0);
            }
            // Flood pairing needs no k at all.
            let cells = ClippedVoronoi::new(&mesh, &sites)
                .pairing(Pairing::Flood)
                .k_site(n)
                .backend(backend)
                .compute()
                .unwrap();
            let what = format!("{shape:?} n={n} {} flood", backend.name());
            assert_cells_match(&what, &cells, &vol, &centroid, 1e-4);
            prop_assert_eq!(cells.counters.unresolved, 0);
        }
        // The same input moved by 1e6 and scaled by 1e-6 and 1e6 (CPU).
        for at in Placement::MOVED {
            let exact;
            let (vol, centroid) = if at.offset == 0.0 {
                (&vol, &centroid)
            } else {
                let (seen_mesh, seen) = at.seen(&mesh, &sites);
                exact = clipped_cells(&seen_mesh, &seen);
                (&exact.0, &exact.1)
            };
            let cells = ClippedVoronoi::new(&at.mesh(&mesh), &at.points(&sites))
                .k_site(n)
                .backend(backends()[0])
                .compute()
                .unwrap();
            let what = format!("{shape:?} n={n} flood at {at:?}");
            assert_cells_match(&what, &at.unplace(&cells), vol, centroid, 1e-4);
            prop_assert_eq!(cells.counters.unresolved, 0);
        }
        assert_no_vulkan_errors();
    }

    /// CPU and Vulkan agree per cell to f32 precision; so do the strategies.
    #[test]
    fn backends_and_strategies_agree(n in 20usize..=2000, seed in any::<u64>(), resolution in 3usize..=8) {
        let mesh = TetMesh::cube(resolution);
        let sites = sites_in_box(n, seed);
        let cpu = CpuBackend::new(None).unwrap();
        // Both strategies with the same (k-nearest) pairs compute the same pieces.
        let run = |b: &dyn Backend, s| {
            ClippedVoronoi::new(&mesh, &sites).strategy(s).pairing(Pairing::Knn).backend(b).compute().unwrap()
        };
        let base = run(&cpu, Strategy::TetCell);
        let other = run(&cpu, Strategy::CellTet);
        // The strategies build each piece from different shapes (the cell,
        // the tet), so their f32 roundings differ: up to f32 epsilon times
        // the piece's distance from its site over its size (seen: 1.2e-5
        // of a cell's size for a centroid).
        assert_cells_match("cpu cell-tet vs tet-cell", &other, &base.volume, &base.centroid, 3e-5);
        let flood = ClippedVoronoi::new(&mesh, &sites).pairing(Pairing::Flood).backend(&cpu).compute().unwrap();
        prop_assert!(flood.e_vol <= 1e-5, "flood E_vol {}", flood.e_vol);
        if let Some(v) = vulkan() {
            let gpu = ClippedVoronoi::new(&mesh, &sites).pairing(Pairing::Flood).backend(v).compute().unwrap();
            assert_cells_match("vulkan flood vs cpu flood", &gpu, &flood.volume, &flood.centroid, 1e-5);
            prop_assert_eq!(gpu.counters.unresolved, 0);
            for s in [Strategy::TetCell, Strategy::CellTet] {
                let gpu = run(v, s);
                assert_cells_match(&format!("vulkan {s:?} vs cpu"), &gpu, &base.volume, &base.centroid, 1e-5);
                // Counters agree, but for the certificate's count of tets
                // completed on the host: a tet within rounding of its
                // threshold may go either way on either backend.
                let cpu_counters = if s == Strategy::TetCell { base.counters } else { other.counters };
                prop_assert_eq!(
                    cvd::Counters { missed_tets: 0, ..gpu.counters },
                    cvd::Counters { missed_tets: 0, ..cpu_counters }
                );
            }
            assert_no_vulkan_errors();
        }
    }
}

fn assert_no_vulkan_errors() {
    if vulkan().is_some() {
        assert_no_validation_errors();
    }
}

#[test]
fn volumes_sum_to_the_mesh_volume() {
    let mesh = TetMesh::cube(10);
    let sites = sites_in_box(3000, 5);
    for backend in backends() {
        for strategy in [Strategy::TetCell, Strategy::CellTet] {
            let cells = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).backend(backend).compute().unwrap();
            assert!(cells.e_vol <= 1e-5, "{} {strategy:?}: E_vol {}", backend.name(), cells.e_vol);
            assert_eq!(cells.counters.overflows + cells.counters.broken, 0);
            assert!(cells.counters.pairs > 0 && cells.counters.nonempty > 0);
        }
    }
}

#[test]
fn results_are_bit_identical_run_after_run() {
    let mesh = TetMesh::cube(5);
    let sites = sites_in_box(500, 9);
    for backend in backends() {
        // k_site 6 leaves many pieces to grid walks, which must not
        // depend on the order threads filled the grid.
        for k_site in [90, 6] {
            let run = || ClippedVoronoi::new(&mesh, &sites).k_site(k_site).backend(backend).compute().unwrap();
            let (a, b) = (run(), run());
            assert!(k_site == 90 || a.counters.walks > 0, "{}: no walk", backend.name());
            assert_eq!(a.volume, b.volume, "{} k_site {k_site}", backend.name());
            assert_eq!(a.centroid, b.centroid, "{} k_site {k_site}", backend.name());
        }
    }
}

#[test]
fn duplicate_sites_lowest_index_owns_the_cell() {
    let mesh = TetMesh::cube(3);
    let mut sites = sites_in_box(40, 2);
    sites.push(sites[3]);
    sites.push(sites[0]);
    let (vol, centroid) = clipped_cells(&mesh, &sites);
    for backend in backends() {
        let cells = compute(&mesh, &sites, Strategy::TetCell, backend);
        assert_eq!(cells.counters.duplicate_sites, 2);
        assert_eq!(cells.volume[40], 0.0);
        assert_eq!(cells.volume[41], 0.0);
        assert_cells_match("duplicates", &cells, &vol, &centroid, 1e-4);
    }
}

#[test]
fn sites_outside_and_very_few_sites() {
    let mesh = mesh(Shape::Ell);
    for sites in [
        vec![[0.5f64, 0.5, 0.5]],
        vec![[0.9, 0.9, 0.5], [0.1, 0.1, 0.1]],
        vec![[3.0, 3.0, 3.0], [-1.0, 0.2, 0.3]],
        // The last one is outside and crowded out by the first.
        vec![[0.2, 0.2, 0.5], [0.25, 0.25, 0.5], [-2.0, -2.0, 0.5]],
    ] {
        let (vol, centroid) = clipped_cells(&mesh, &sites);
        for backend in backends() {
            for strategy in [Strategy::TetCell, Strategy::CellTet] {
                let cells = compute(&mesh, &sites, strategy, backend);
                assert_cells_match(&format!("{sites:?}"), &cells, &vol, &centroid, 1e-4);
                let empty = vol.iter().filter(|&&v| v == 0.0).count() as u64;
                assert_eq!(cells.counters.empty_cells, empty, "{sites:?}");
            }
        }
    }
}

#[test]
fn paper_k_follows_eq_6() {
    use cvd::job::clip::paper_k;
    assert_eq!(paper_k(5, 1000), 5);
    assert_eq!(paper_k(19, 1000), 19);
    assert_eq!(paper_k(20, 100_000), 20);
    // 35k sites in 31k tets: 10 * ceil(8 * log10(7 * 1.13 + 1)) = 80.
    assert_eq!(paper_k(35_000, 31_000), 80);
}

#[test]
fn bad_input_is_rejected_by_name() {
    let err = TetMesh::new(vec![[0.0; 3]; 3], vec![[0, 1, 2, 3]]).unwrap_err().to_string();
    assert!(err.contains("tet 0 refers to vertex 3"), "{err}");
    let flat = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    let err = TetMesh::new(flat, vec![[0, 1, 2, 3]]).unwrap_err().to_string();
    assert!(err.contains("zero volume"), "{err}");
    let mesh = TetMesh::cube(2);
    let err = ClippedVoronoi::new(&mesh, &[[0.5, 0.5, 0.5]])
        .strategy(Strategy::CellTet)
        .pairing(Pairing::Flood)
        .compute()
        .unwrap_err()
        .to_string();
    assert!(err.contains("tet-cell"), "{err}");
    let err = ClippedVoronoi::new(&mesh, &[[f64::NAN, 0.0, 0.0]]).compute().unwrap_err().to_string();
    assert!(err.contains("site 0"), "{err}");
    assert!(ClippedVoronoi::new(&mesh, &[]).compute().is_err());
}

/// A neighbour budget far too small: the kernels leave most pieces
/// unfinished and the second pass must finish every one of them exactly
/// (whole tets, for flood pairing).
/// Pieces a short list does not settle are finished by a walk (flood) or
/// in the second pass (knn pairing), the same on every backend.
#[test]
fn short_lists_lose_nothing() {
    let mesh = mesh(Shape::Ell);
    let sites = sites_in_box(120, 11);
    let (vol, centroid) = clipped_cells(&mesh, &sites);
    let mut flood_counters = Vec::new();
    for backend in backends() {
        for (strategy, pairing) in
            [(Strategy::TetCell, Pairing::Knn), (Strategy::CellTet, Pairing::Knn), (Strategy::TetCell, Pairing::Flood)]
        {
            let cells = ClippedVoronoi::new(&mesh, &sites)
                .strategy(strategy)
                .pairing(pairing)
                .k(Some(120))
                .k_site(3)
                .backend(backend)
                .compute()
                .unwrap();
            let what = format!("{} {strategy:?} {pairing:?} k_site 3", backend.name());
            if pairing == Pairing::Flood {
                assert!(cells.counters.walks > 0, "{what}: no piece walked");
                assert_eq!(cells.counters.security_missed, 0, "{what}");
                flood_counters.push(cells.counters);
            } else {
                assert!(cells.counters.second_pass > 0, "{what}: nothing went to the second pass");
            }
            assert_eq!(cells.counters.unresolved, 0, "{what}");
            assert_cells_match(&what, &cells, &vol, &centroid, 1e-4);
        }
    }
    // The same walks, clips and pieces on every backend.
    assert!(flood_counters.windows(2).all(|w| w[0] == w[1]), "{flood_counters:?}");
    assert_no_vulkan_errors();
}

/// Sites at the centres of a lattice's cubes, mesh vertices at its
/// corners: every interior vertex is equidistant from 8 sites, exactly (the
/// quantization is by a power of two), and the cells' faces lie on the
/// tets' faces. Nothing is lost, on any backend, with either pairing.
#[test]
fn lattice_sites_tied_at_every_mesh_vertex() {
    let mesh = TetMesh::cube(4);
    let c = |i: usize| (2 * i + 1) as f64 / 8.0;
    let sites: Vec<[f64; 3]> = (0..64).map(|i| [c(i % 4), c(i / 4 % 4), c(i / 16)]).collect();
    let (vol, centroid) = clipped_cells(&mesh, &sites);
    for backend in backends() {
        for (strategy, pairing) in
            [(Strategy::Whole, Pairing::Flood), (Strategy::TetCell, Pairing::Flood), (Strategy::TetCell, Pairing::Knn)]
        {
            let cv = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).pairing(pairing);
            let cells = cv.backend(backend).compute().unwrap();
            let what = format!("{} {strategy:?} {pairing:?} lattice sites", backend.name());
            assert_eq!(cells.counters.unresolved, 0, "{what}");
            assert!(cells.e_vol < 1e-6, "{what}: E_vol {}", cells.e_vol);
            assert_cells_match(&what, &cells, &vol, &centroid, 1e-4);
        }
    }
    assert_no_vulkan_errors();
}

#[test]
fn many_sites_per_tet() {
    // 600 sites in 6 tets: about 100 cells meet each tet, more than any
    // flood queue of the kernels holds, so the host finishes those tets
    // (tet-cell; whole cells are each built on their own).
    let mesh = TetMesh::cube(1);
    let sites = sites_in_box(600, 5);
    let (vol, centroid) = clipped_cells(&mesh, &sites);
    for backend in backends() {
        let cv = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::TetCell);
        let cells = cv.backend(backend).compute().unwrap();
        let what = format!("{} 600 sites in 6 tets", backend.name());
        assert!(cells.counters.second_pass > 0, "{what}: nothing went to the second pass");
        let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).backend(backend).compute().unwrap();
        assert_eq!(whole.counters.unresolved, 0, "{what}, whole cells");
        assert_cells_match(&format!("{what}, whole cells"), &whole, &vol, &centroid, 1e-4);
        assert_eq!(cells.counters.unresolved, 0, "{what}");
        assert!(cells.e_vol < 1e-6, "{what}: E_vol {}", cells.e_vol);
        assert_cells_match(&what, &cells, &vol, &centroid, 1e-4);
    }
    assert_no_vulkan_errors();
}

/// Sets `backend`'s memory budget to the smallest (to 64 KiB) that `cv`
/// fits, so that it runs in several parts; returns that budget.
fn tighten(backend: &cvd::backends::vulkan::VulkanBackend, cv: ClippedVoronoi) -> u64 {
    let fits = |budget: u64| {
        backend.set_memory_budget(budget);
        match cv.backend(backend).compute() {
            Ok(_) => true,
            // Too small a budget is an error that says so, never a crash.
            Err(e) => {
                assert!(e.to_string().contains("budget"), "{e}");
                false
            }
        }
    };
    let (mut lo, mut hi) = (1u64, 1u64 << 9);
    assert!(!fits(lo << 16) && fits(hi << 16));
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if fits(mid << 16) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    backend.set_memory_budget(hi << 16);
    hi << 16
}

#[test]
fn a_memory_budget_splits_the_job_and_changes_nothing() {
    let Some(roomy) = vulkan() else { return };
    let options =
        cvd::backends::vulkan::VulkanOptions { device: std::env::var("CVD_TEST_DEVICE").ok(), ..Default::default() };
    let tight = cvd::backends::vulkan::VulkanBackend::new(&options).unwrap();
    let mesh = TetMesh::cube(10);
    let sites = sites_in_box(1500, 21);
    let runs = [
        (Strategy::TetCell, Pairing::Flood, 90),
        (Strategy::TetCell, Pairing::Knn, 12),
        (Strategy::CellTet, Pairing::Knn, 90),
    ];
    let mut budgets = Vec::new();
    for (strategy, pairing, k_site) in runs {
        let cv = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).pairing(pairing).k_site(k_site);
        let budget = tighten(&tight, cv);
        budgets.push(budget);
        let (whole, tightest) = (cv.backend(roomy).compute().unwrap(), cv.backend(&tight).compute().unwrap());
        let what = format!("{strategy:?} {pairing:?} k_site {k_site}, budget {budget}");
        assert_eq!(whole.chunks, 1, "{what}");
        // The tightest budget takes tet-cell's site lists in windows (one
        // site k-NN each). Knn pairs are clipped by the window that holds
        // their site's list: the same pieces. Floods take the sites in
        // slabs, in another order: the same pieces to rounding.
        let windows = tightest.timings.phases.iter().filter(|(phase, _)| phase == "site knn").count();
        assert_eq!(windows > 1, strategy == Strategy::TetCell, "{what}: {windows} windows");
        let parts = if pairing == Pairing::Flood {
            assert!(tightest.chunks > 1, "{what}: not split");
            assert_eq!(tightest.counters.unresolved, 0, "{what}");
            assert_cells_match(&what, &tightest, &whole.volume, &whole.centroid, 1e-6);
            // With room for every list, only the tets and the k-NN are
            // split: nothing changes at all.
            tight.set_memory_budget(budget + 4 * sites.len() as u64 * k_site as u64);
            cv.backend(&tight).compute().unwrap()
        } else {
            tightest
        };
        assert!(parts.chunks > 1, "{what}: not split");
        assert_eq!(whole.volume, parts.volume, "{what}");
        assert_eq!(whole.centroid, parts.centroid, "{what}");
        assert_eq!(whole.counters, parts.counters, "{what}");
        assert!(parts.e_vol <= 1e-5, "{what}: E_vol {}", parts.e_vol);
    }
    // The Lloyd loop on the device needs the whole job: it says so.
    tight.set_memory_budget(budgets[0]);
    let e = ClippedVoronoi::new(&mesh, &sites).backend(&tight).lloyd(2, &mut |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("memory budget"), "{e}");
    assert_no_vulkan_errors();
}

/// Knn pairing with k = 1: the site paired with every tet, just inside a
/// corner of the cube, borders a site just outside it that owns a corner
/// of volume δ³/6 — 1e-6 of each tet it cuts, below any tolerance a sum
/// of f32 volumes could be checked to. The faces give it away; the host
/// adds the corner.
#[test]
fn knn_pairing_misses_no_corner_however_small() {
    let mesh = TetMesh::cube(1);
    let delta = 0.01f64;
    // The bisector is the plane x + y + z = 3 - δ.
    let b = 0.01;
    let (outside, inside) = (1.0 + b, 1.0 - b - 2.0 / 3.0 * delta);
    let sites = vec![[inside; 3], [outside; 3]];
    let corner = delta.powi(3) / 6.0;
    for backend in backends() {
        for strategy in [Strategy::TetCell, Strategy::CellTet] {
            let what = format!("{} {strategy:?}", backend.name());
            let cells = ClippedVoronoi::new(&mesh, &sites)
                .strategy(strategy)
                .pairing(Pairing::Knn)
                .k(Some(1))
                .backend(backend)
                .compute()
                .unwrap_or_else(|e| panic!("{what}: {e}"));
            assert!(cells.counters.missed_tets > 0, "{what}: no tet found incomplete");
            assert!(
                (cells.volume[1] - corner).abs() <= 1e-3 * corner,
                "{what}: corner {} vs {corner}",
                cells.volume[1]
            );
            assert!((cells.volume[0] + cells.volume[1] - 1.0).abs() <= 1e-6, "{what}: {:?}", cells.volume);
        }
    }
}
