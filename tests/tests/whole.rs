//! Whole cells (the default strategy on the CPU backend): each cell built
//! once, integrated whole inside the domain, clipped by tets where the
//! boundary may cut it — against the f64 reference and the pieces' sums
//! (tet-cell), cell by cell, relative to each cell's own volume.

use cvd::{geom::points, Cells, ClippedVoronoi, Strategy, TetMesh};
use cvd_tests::reference::clipped_cells;

fn run(mesh: &TetMesh, sites: &[[f64; 3]], strategy: Strategy) -> Cells {
    ClippedVoronoi::new(mesh, sites).strategy(strategy).compute().unwrap()
}

fn box_points(n: usize, lo: [f64; 3], hi: [f64; 3], seed: u64) -> Vec<[f64; 3]> {
    points::uniform(n, seed).into_iter().map(|p| [0, 1, 2].map(|a| lo[a] + p[a] * (hi[a] - lo[a]))).collect()
}

/// Each cell's volume error relative to itself, worst first, with the
/// cell's volume relative to the mean.
fn errors(cells: &Cells, exact: &[f64]) -> Vec<(f64, usize, f64)> {
    let mean = exact.iter().sum::<f64>() / exact.len() as f64;
    let mut e: Vec<(f64, usize, f64)> = (0..exact.len())
        .map(|i| {
            let d = (cells.volume[i] - exact[i]).abs();
            (if exact[i] > 0.0 { d / exact[i] } else { d / mean }, i, exact[i] / mean)
        })
        .collect();
    e.sort_by(|a, b| b.0.total_cmp(&a.0));
    e
}

fn show(what: &str, e: &[(f64, usize, f64)]) -> String {
    let worst: Vec<String> =
        e.iter().take(4).map(|(d, i, v)| format!("cell {i} ({v:.1e} of the mean) {d:.2e}")).collect();
    format!("{what}: {}", worst.join(", "))
}

/// Tight clusters inside a crowd, in a unit box: the cells of the cluster
/// lie far from the boundary and are whole. Every cell of at least 1e-11
/// of the box is within 5e-6 of its own volume (measured: 2.9e-6 at most,
/// on the needle-shaped cells at the 2e-3 cluster's rim: f32 vertices).
/// The 1e-4 cluster's rim cells are needles of aspect 1:800, whose f32
/// vertices leave `ε L / h` (measured: 2.8e-5); its inner cells, of 1e-14
/// of the box, meet the fixed-point sums' step (2^-56 of the unit frame,
/// 1.4e-17).
#[test]
fn clusters_in_a_crowd_are_exact_cell_by_cell() {
    let mesh = TetMesh::cube(3);
    for (side, n, at, tol) in [(2e-3, 400, 0.4, 5e-6), (1e-4, 50, 0.7, 5e-5)] {
        let mut sites = box_points(1600, [0.0; 3], [1.0; 3], 1);
        sites.extend(box_points(n, [at; 3], [at + side; 3], 2));
        let (exact, _) = clipped_cells(&mesh, &sites);
        let whole = run(&mesh, &sites, Strategy::Whole);
        let pieces = run(&mesh, &sites, Strategy::TetCell);
        let (ew, ep) = (errors(&whole, &exact), errors(&pieces, &exact));
        let c = &whole.counters;
        println!("cluster of side {side:e}: {} whole, {} cut", c.whole_cells, c.cut_cells);
        println!("{}\n{}", show("  whole", &ew), show("  tet-cell", &ep));
        assert!(c.whole_cells >= n as u64, "the cluster's cells are whole: {c:?}");
        assert_eq!(c.unresolved, 0);
        for &(d, i, v) in &ew {
            let volume = exact[i];
            let tol = tol + 1.4e-17 / volume;
            assert!(d < tol, "cell {i} ({v:.1e} of the mean, {volume:.1e}): {d:.2e}");
        }
    }
}

/// On a model with concave parts and holes, from sites in its bounding box
/// (many outside it, many cells cut): whole cells and cut cells against
/// the reference, and against the pieces.
#[test]
fn whole_and_cut_cells_match_the_reference_on_a_model() {
    let mesh = cvd::mesher::models::builtin("joint", None).unwrap();
    let (lo, hi) = mesh.bounding_box();
    let sites = box_points(3000, lo, hi, 5);
    let whole = run(&mesh, &sites, Strategy::Whole);
    let pieces = run(&mesh, &sites, Strategy::TetCell);
    let (exact, _) = clipped_cells(&mesh, &sites);
    let (ew, ep) = (errors(&whole, &exact), errors(&pieces, &exact));
    let c = &whole.counters;
    println!("joint: {} whole, {} cut\n{}\n{}", c.whole_cells, c.cut_cells, show("whole", &ew), show("tet-cell", &ep));
    assert!(c.whole_cells > 200 && c.cut_cells > 200, "{c:?}");
    assert_eq!(c.whole_cells + c.cut_cells, 3000);
    // Cells above 1e-3 of the mean within 5e-6; the slivers the boundary
    // cuts from cells whose site lies outside (down to 1e-6 of the mean)
    // keep the pieces' precision.
    for &(d, i, v) in &ew {
        let tol = if v > 1e-3 { 5e-6 } else { 2e-4 };
        assert!(d < tol, "cell {i} ({v:.1e} of the mean): {d:.2e}");
    }
    assert!((whole.total_volume - mesh.volume()).abs() < 1e-7 * mesh.volume());
}

/// A few sites in a large domain: each cell is cut into thousands of
/// pieces (one site: every tet of the mesh), summed exactly (each piece in
/// fixed point, as the other strategies' atomics sum them). Every cell
/// within 1e-6 of the reference, with and without weights.
#[test]
fn few_sites_cut_into_thousands_of_pieces_sum_exactly() {
    use cvd_tests::reference::clipped_power_cells;
    for model in ["cube", "joint", "torus"] {
        let mesh = cvd::mesher::models::builtin(model, None).unwrap();
        for n in [1, 2, 5, 20] {
            let sites = points::in_mesh(&mesh, n, 3);
            let w: Vec<f64> = (0..n).map(|i| 1e-3 * (i % 3) as f64).collect();
            for weights in [None, Some(&w)] {
                let mut cv = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole);
                let exact = match weights {
                    Some(w) => {
                        cv = cv.weights(w);
                        clipped_power_cells(&mesh, &sites, w).0
                    }
                    None => clipped_cells(&mesh, &sites).0,
                };
                let cells = cv.compute().unwrap();
                let e = errors(&cells, &exact);
                let what = format!("{model}, {n} sites, weights {}", weights.is_some());
                println!("{}", show(&what, &e));
                let c = &cells.counters;
                assert!(c.cut_cells > 0 && c.whole_cells + c.cut_cells == n as u64, "{what}: {c:?}");
                assert!(e[0].0 < 1e-6, "{}", show(&what, &e));
                assert!(cells.e_vol < 1e-6, "{what}: E_vol {:.1e}", cells.e_vol);
            }
        }
    }
}

/// The same kernel body on Vulkan (lavapipe here): the same cells whole
/// and cut, and the same volumes to f32 rounding.
#[test]
fn vulkan_runs_the_same_whole_cells() {
    let Some(vulkan) = cvd_tests::vulkan() else { return };
    let mesh = cvd::mesher::models::builtin("torus", None).unwrap();
    let sites = points::in_mesh(&mesh, 2000, 3);
    let cv = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).k_site(90usize);
    let cpu = cv.compute().unwrap();
    let gpu = cv.backend(vulkan).compute().unwrap();
    let (c, g) = (&cpu.counters, &gpu.counters);
    assert_eq!((c.whole_cells, c.cut_cells), (g.whole_cells, g.cut_cells));
    assert!(c.whole_cells > 0 && c.cut_cells > 0, "{c:?}");
    assert_eq!((g.unresolved, g.overflows, g.broken), (0, 0, 0));
    let worst = (0..sites.len()).map(|i| (cpu.volume[i] - gpu.volume[i]).abs() / cpu.volume[i]).fold(0.0, f64::max);
    println!("CPU and Vulkan whole cells: volumes within {worst:.2e}");
    assert!(worst < 1e-5, "{worst:.2e}");
    cvd_tests::assert_no_validation_errors();
}

/// Whole cells in parts on Vulkan (lavapipe here): ranks (threads of this
/// process), each with a run of the input's rows, build their cells on the
/// device in a window of held grid cells — the kernel's walks kept inside
/// it, the lists' distances read back for the part's certificate — and
/// every row is the device's one-process cell to the bit: volume,
/// centroid, energy, faces with their neighbours, boundary. A non-convex
/// domain, a tight cluster in a crowd, a duplicate. With polyhedra (from
/// the CPU, as one process takes a device's), they are one process's.
#[test]
fn vulkan_whole_cells_in_parts_are_its_one_process_cells() {
    use cvd::backends::distributed::{InProcess, Reduce};
    let Some(vulkan) = cvd_tests::vulkan() else { return };
    let mesh = TetMesh::voxels(10, |i, j, _| i < 5 || j < 5);
    let mut sites: Vec<[f64; 3]> =
        points::in_mesh(&mesh, 6000, 51).into_iter().filter(|p| p[0] < 0.5 || p[1] < 0.1).collect();
    sites.extend(points::in_mesh(&mesh, 400, 53).into_iter().filter(|p| p[0] >= 0.5));
    sites.extend(points::clustered(1500, 2, 0.01, 52).into_iter().map(|p| p.map(|x| 0.05 + 0.4 * x)));
    sites.push(sites[23]);
    let n = sites.len();
    let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true);
    let one = whole.backend(vulkan).compute().unwrap();
    assert!(one.counters.cut_cells > 0 && one.counters.whole_cells > 0, "{:?}", one.counters);
    let cpu = cvd::CpuBackend::new(Some(2)).unwrap();
    let (on_cpu, _) = whole.backend(vulkan).compute_with_geometry(&cpu).unwrap();
    let a = one.adjacency().unwrap();
    let mut unheld = 0;
    for (ranks, per_rank, polyhedra) in [(1, 1, false), (2, 1, true), (3, 2, false), (2, 3, false), (4, 1, false)] {
        let what = format!("{ranks} ranks x {per_rank} parts");
        let rows = |r: usize| n * r / ranks..n * (r + 1) / ranks;
        let runs = InProcess::each(ranks, |comm| {
            let cv = ClippedVoronoi::new(&mesh, &sites[rows(comm.rank())]).strategy(Strategy::Whole).faces(true);
            let cv = cv.backend(vulkan);
            let cv = cv.parts_per_rank(per_rank);
            match polyhedra {
                true => {
                    let cpu = cvd::CpuBackend::new(Some(1)).unwrap();
                    let (cells, built, report) = cv.compute_in_parts_with_polyhedra(comm, &cpu).unwrap();
                    (cells, report, Some(built))
                }
                false => {
                    let (cells, report) = cv.compute_in_parts(comm).unwrap();
                    (cells, report, None)
                }
            }
        });
        let mut built: Vec<_> =
            runs.iter().flat_map(|r| r.2.iter().flat_map(|b| b.polyhedra.iter().cloned())).collect();
        built.sort_by_key(|p| p.site);
        if polyhedra {
            let expected = on_cpu.polyhedra.as_ref().unwrap();
            assert_eq!(built.len(), expected.len(), "{what}: every polyhedron once");
            for (p, q) in built.iter().zip(expected) {
                assert!(p == q, "{what}: the polyhedron of {} is one process's", q.site);
            }
        }
        if ranks > 1 {
            assert!(runs.iter().any(|r| r.1.widened > 0), "{what}: no part widened its halo");
        }
        unheld += runs.iter().map(|r| r.1.unheld_cells).sum::<u64>();
        let owned: u64 = runs.iter().map(|r| r.1.owned).sum();
        assert_eq!(owned, n as u64, "{what}: every site owned once");
        for (r, (cells, _, _)) in runs.iter().enumerate() {
            assert_eq!(one.total_volume.to_bits(), cells.total_volume.to_bits(), "{what}: total volume");
            let b = cells.adjacency().unwrap();
            for (k, i) in rows(r).enumerate() {
                let bits = |x: f64| x.to_bits();
                assert_eq!(bits(one.volume[i]), bits(cells.volume[k]), "{what}: volume of {i}");
                assert_eq!(bits(one.energy[i]), bits(cells.energy[k]), "{what}: energy of {i}");
                assert_eq!(one.centroid[i].map(bits), cells.centroid[k].map(bits), "{what}: centroid of {i}");
                let (x, y): (Vec<_>, Vec<_>) = (a.of(i).collect(), b.of(k).collect());
                assert_eq!(x, y, "{what}: faces of {i}");
                assert_eq!(bits(a.boundary[i]), bits(b.boundary[k]), "{what}: boundary of {i}");
            }
        }
    }
    // Some part's box held cells it did not (marked on the device too).
    assert!(unheld > 0, "no part's box held a cell it did not hold");
    cvd_tests::assert_no_validation_errors();
}

/// The lists' distances a whole-cell job keeps for a part's certificate
/// (`ClipJob::keep` without entries) come back from the device as the
/// CPU finds them — exact integers, list by list — for every site and for
/// a run of them (a part's answered sites), with every list on the device
/// at once and, under the tightest memory budget, listed in chunks.
#[test]
fn vulkan_keeps_the_lists_distances_the_cpu_finds() {
    use cvd::job::kept::Keep;
    use cvd::Backend;
    let Some(roomy) = cvd_tests::vulkan() else { return };
    let options =
        cvd::backends::vulkan::VulkanOptions { device: std::env::var("CVD_TEST_DEVICE").ok(), ..Default::default() };
    let tight = cvd::backends::vulkan::VulkanBackend::new(&options).unwrap();
    let mesh = TetMesh::voxels(8, |i, j, _| i < 4 || j < 4);
    let mut sites = points::in_mesh(&mesh, 2500, 61);
    sites.extend(points::clustered(800, 2, 0.01, 62).into_iter().map(|p| p.map(|x| 0.05 + 0.3 * x)));
    let n = sites.len();
    let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).job().unwrap();
    let cpu = cvd::CpuBackend::new(Some(2)).unwrap();
    for range in [0..n, 700..2900] {
        let mut part = if range.len() == n { job.clone() } else { job.answering(range.clone()).unwrap() };
        part.keep = Some(Keep { k: part.site_knn.params.k, candidates: None, entries: false });
        let on_cpu = cpu.clip(&part).unwrap();
        let c = on_cpu.kept.as_ref().unwrap();
        assert_eq!(c.kth2.len(), range.len());
        assert!(c.kth2.iter().all(|&d| 0 < d && d < u64::MAX), "{range:?}: every list full");
        // The smallest budget the job fits (in 64 KiB steps): its lists in
        // chunks.
        let fits = |budget: u64| {
            tight.set_memory_budget(budget << 16);
            tight.clip(&part).is_ok()
        };
        let (mut lo, mut hi) = (1u64, 1u64 << 12);
        assert!(!fits(lo) && fits(hi), "{range:?}");
        while hi - lo > 1 {
            let mid = (lo + hi) / 2;
            *if fits(mid) { &mut hi } else { &mut lo } = mid;
        }
        tight.set_memory_budget(hi << 16);
        for (device, what) in [(roomy, "every list at once"), (&tight, "the tightest budget")] {
            let out = device.clip(&part).unwrap();
            let g = out.kept.as_ref().unwrap();
            let what = format!("{range:?}, {what}");
            assert_eq!((g.k, &g.kth2, &g.last2), (c.k, &c.kth2, &c.last2), "{what}");
            // The cells those lists build: the CPU's to f32 rounding.
            let (x, y) = (&on_cpu.sums, &out.sums);
            let worst = (0..range.len())
                .map(|u| {
                    let i = (range.start + u) * cvd_kernels::abi::ACCUM_PER_SITE;
                    (x[i] - y[i]).abs() as f64 / x[i].abs().max(1) as f64
                })
                .fold(0.0, f64::max);
            assert!(worst < 1e-5, "{what}: volumes within {worst:.1e}");
        }
    }
    cvd_tests::assert_no_validation_errors();
}
