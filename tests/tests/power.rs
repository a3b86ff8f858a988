//! Power (Laguerre) cells. The exact reference — the f64 reference clipper
//! with weights, `cvd_tests::reference::clipped_power_cells` — against
//! voro++'s radical tessellation (through `voro_rs`, an oracle that shares
//! no code with this project) on a box, with weights that empty some
//! cells; the power diagram's own invariance (a constant added to every
//! weight changes nothing); then the kernels' power cells on both backends,
//! both strategies and both pairings against those references, zero
//! weights against the Voronoi cells.

use cvd::{geom::points, Backend, ClippedVoronoi, Pairing, Strategy, TetMesh};
use cvd_tests::l_mesh;
use cvd_tests::reference::clipped_power_cells;
use cvd_tests::voro::power_cells;
use voro_rs::prelude::*;

/// Random weights in `[0, top)`, one per site.
fn weights(n: usize, top: f64, seed: u64) -> Vec<f64> {
    points::uniform(n, seed).into_iter().map(|p| p[0] * top).collect()
}

#[test]
fn the_reference_power_cells_are_voro_plus_plus_radical_cells() {
    let mesh = TetMesh::cube(3);
    let sites = points::uniform(300, 21);
    // Spacing about 0.15: weights up to 0.02 (radii up to 0.14) empty some
    // cells and push others off their sites.
    let w = weights(sites.len(), 0.02, 22);
    let (vol, centroid) = clipped_power_cells(&mesh, &sites, &w);
    let (voro_vol, voro_centroid) = power_cells([0.0; 3], [1.0; 3], &sites, &w);
    let empty = vol.iter().filter(|&&v| v == 0.0).count();
    let voro_empty = voro_vol.iter().filter(|&&v| v == 0.0).count();
    assert!(empty > 0, "the weights empty no cell: the test shows nothing about empty cells");
    assert_eq!(empty, voro_empty, "empty cells");
    let total: f64 = vol.iter().sum();
    assert!((total - 1.0).abs() < 1e-12, "the cells fill the box: {total}");
    let mean = total / sites.len() as f64;
    let outside = (0..sites.len())
        .filter(|&i| {
            vol[i] > 0.0 && {
                let c = centroid[i];
                let s = sites[i];
                // A cell that misses its site: its centroid is far from it.
                (0..3).map(|a| (c[a] - s[a]).powi(2)).sum::<f64>().sqrt() > 2.0 * vol[i].cbrt()
            }
        })
        .count();
    println!("power cells: {empty} empty, {outside} far from their sites, of {}", sites.len());
    for i in 0..sites.len() {
        assert!((vol[i] - voro_vol[i]).abs() <= 1e-10 * mean, "cell {i}: {} vs voro++ {}", vol[i], voro_vol[i]);
        if vol[i] > 1e-3 * mean {
            let c = voro_centroid[i].unwrap_or_else(|| panic!("voro++ has no cell {i}"));
            let d = (0..3).map(|a| (centroid[i][a] - c[a]).powi(2)).sum::<f64>().sqrt();
            assert!(d <= 1e-9 * vol[i].cbrt(), "cell {i}: centroid {:?} vs voro++ {c:?}", centroid[i]);
        }
    }
}

/// On a non-convex mesh (an L of three cubes): a constant added to every
/// weight gives the same cells, and they fill the mesh.
#[test]
fn a_constant_added_to_every_weight_changes_nothing() {
    let mesh = l_mesh(2);
    let sites: Vec<[f64; 3]> = points::in_mesh(&mesh, 120, 23);
    let w = weights(sites.len(), 0.05, 24);
    let (vol, centroid) = clipped_power_cells(&mesh, &sites, &w);
    let shifted: Vec<f64> = w.iter().map(|x| x + 3.5).collect();
    let (vol2, centroid2) = clipped_power_cells(&mesh, &sites, &shifted);
    let mean = 3.0 / sites.len() as f64;
    assert!(vol.iter().filter(|&&v| v == 0.0).count() > 0, "no cell is empty");
    for i in 0..sites.len() {
        assert!((vol[i] - vol2[i]).abs() <= 1e-12 * mean, "cell {i}: {} vs {}", vol[i], vol2[i]);
        if vol[i] > 1e-3 * mean {
            let d = (0..3).map(|a| (centroid[i][a] - centroid2[i][a]).powi(2)).sum::<f64>().sqrt();
            assert!(d <= 1e-10 * vol[i].cbrt(), "cell {i}");
        }
    }
    let total: f64 = vol.iter().sum();
    assert!((total - 3.0).abs() < 1e-12, "the cells fill the mesh: {total}");
}

/// Every way the kernels run: each backend, whole cells, tet-cell with
/// flood and with knn pairing, cell-tet.
fn runs() -> Vec<(&'static dyn Backend, Strategy, Pairing)> {
    let mut runs = Vec::new();
    for b in cvd_tests::backends() {
        for (s, p) in [
            (Strategy::Whole, Pairing::Flood),
            (Strategy::TetCell, Pairing::Flood),
            (Strategy::TetCell, Pairing::Knn),
            (Strategy::CellTet, Pairing::Knn),
        ] {
            runs.push((b, s, p));
        }
    }
    runs
}

/// The kernels' power cells of `sites` with weights `w` in `mesh`, on every
/// run, against `(volume, centroid)` (exact): every cell larger than 1e-3
/// of the mean within `tol` of its volume and centroid (relative to its
/// size), the empty ones empty (at most 1e-9 of the mean), nothing left
/// unresolved, and the cells filling the mesh to 1e-7.
fn check_power_cells(mesh: &TetMesh, sites: &[[f64; 3]], w: &[f64], exact: &(Vec<f64>, Vec<[f64; 3]>), tol: f64) {
    let (vol, centroid) = exact;
    let mean = mesh.volume() / sites.len() as f64;
    let empty = vol.iter().filter(|&&v| v == 0.0).count();
    for (backend, strategy, pairing) in runs() {
        let what = format!("{} {strategy:?} {pairing:?}", backend.name());
        // lavapipe rounds the power cells whole cells rebuild in a frame
        // at their centre less finely than the CPU (its fused multiply-add
        // need not be fused; measured 6.4e-6 on the L below).
        let tol = if backend.name().starts_with("cpu") || strategy != Strategy::Whole { tol } else { tol.max(1e-5) };
        let cells = ClippedVoronoi::new(mesh, sites)
            .weights(w)
            .strategy(strategy)
            .pairing(pairing)
            .backend(backend)
            .compute()
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(cells.counters.unresolved, 0, "{what}");
        assert!(cells.e_vol <= 1e-7, "{what}: E_vol {:e}", cells.e_vol);
        assert_eq!(cells.counters.empty_cells as usize, empty, "{what}: empty cells");
        let mut worst = 0.0f64;
        for i in 0..sites.len() {
            if vol[i] == 0.0 {
                assert!(cells.volume[i] <= 1e-9 * mean, "{what}: cell {i} should be empty: {}", cells.volume[i]);
                assert_eq!(cells.centroid[i], sites[i], "{what}: an empty cell's centroid is its site");
                continue;
            }
            if vol[i] < 1e-3 * mean {
                continue;
            }
            let dv = (cells.volume[i] - vol[i]).abs() / vol[i];
            let dc =
                (0..3).map(|a| (cells.centroid[i][a] - centroid[i][a]).powi(2)).sum::<f64>().sqrt() / vol[i].cbrt();
            worst = worst.max(dv).max(dc);
            assert!(dv <= tol, "{what}: cell {i}: volume {} vs exact {}", cells.volume[i], vol[i]);
            assert!(dc <= tol, "{what}: cell {i}: centroid {:?} vs exact {:?}", cells.centroid[i], centroid[i]);
        }
        println!("{what}: {empty} empty cells, worst relative error {worst:.1e}, E_vol {:.1e}", cells.e_vol);
    }
}

/// The kernels' power cells on a box against voro++'s radical cells.
#[test]
fn power_cells_match_voro_plus_plus_on_a_box() {
    let mesh = TetMesh::cube(6);
    let sites = points::uniform(400, 31);
    let w = weights(sites.len(), 0.02, 32);
    let (vol, centroid) = power_cells([0.0; 3], [1.0; 3], &sites, &w);
    let centroid: Vec<[f64; 3]> = centroid.into_iter().zip(&sites).map(|(c, s)| c.unwrap_or(*s)).collect();
    check_power_cells(&mesh, &sites, &w, &(vol, centroid), 5e-6);
}

/// The kernels' power cells on a non-convex mesh against the f64 reference,
/// with weights from small (no empty cell but a few) to large (a third of
/// the cells emptied, many cells away from their sites).
#[test]
fn power_cells_match_the_reference_on_a_non_convex_mesh() {
    let mesh = l_mesh(5);
    let sites = points::in_mesh(&mesh, 600, 33);
    for (top, seed) in [(0.01, 34), (0.05, 35)] {
        let w = weights(sites.len(), top, seed);
        let exact = clipped_power_cells(&mesh, &sites, &w);
        assert!(exact.0.contains(&0.0), "the weights empty no cell");
        check_power_cells(&mesh, &sites, &w, &exact, 5e-6);
    }
}

/// Zero weights are the Voronoi cells, bit for bit; equal weights too (a
/// constant changes nothing); a constant added to random weights changes
/// no cell.
#[test]
fn zero_or_shifted_weights_change_nothing() {
    let mesh = l_mesh(4);
    let sites = points::in_mesh(&mesh, 500, 36);
    let w = weights(sites.len(), 0.02, 37);
    let shifted: Vec<f64> = w.iter().map(|x| x - 7.25).collect();
    for (backend, strategy, pairing) in runs() {
        let what = format!("{} {strategy:?} {pairing:?}", backend.name());
        let cv = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).pairing(pairing).backend(backend);
        let voronoi = cv.compute().unwrap();
        for constant in [0.0, 3.0] {
            let same = vec![constant; sites.len()];
            let cells = cv.weights(&same).compute().unwrap();
            assert_eq!(cells.volume, voronoi.volume, "{what}: weights {constant}");
            assert_eq!(cells.centroid, voronoi.centroid, "{what}: weights {constant}");
        }
        let a = cv.weights(&w).compute().unwrap();
        let b = cv.weights(&shifted).compute().unwrap();
        let mean = mesh.volume() / sites.len() as f64;
        for i in 0..sites.len() {
            assert!((a.volume[i] - b.volume[i]).abs() <= 1e-9 * mean, "{what}: cell {i}");
        }
    }
}

/// Weights are checked: one per site, finite; equal sites go to the larger
/// weight.
#[test]
fn weights_are_checked_and_equal_sites_go_to_the_larger_weight() {
    let mesh = TetMesh::cube(2);
    let sites = vec![[0.25, 0.5, 0.5], [0.75, 0.5, 0.5], [0.75, 0.5, 0.5]];
    let err = ClippedVoronoi::new(&mesh, &sites).weights(&[0.0, 1.0]).compute().unwrap_err().to_string();
    assert!(err.contains("2 weights for 3 sites"), "{err}");
    let err = ClippedVoronoi::new(&mesh, &sites).weights(&[0.0, f64::NAN, 0.0]).compute().unwrap_err().to_string();
    assert!(err.contains("site 1"), "{err}");
    // Site 2 equals site 1 with a larger weight: it owns the cell.
    let cells = ClippedVoronoi::new(&mesh, &sites).weights(&[0.0, 0.01, 0.02]).compute().unwrap();
    assert_eq!(cells.volume[1], 0.0);
    assert!(cells.volume[2] > 0.5, "{:?}", cells.volume);
    assert_eq!(cells.counters.duplicate_sites, 1);
    // The bisector moves by (w_1 - w_0) / 2d towards site 0: x = 0.5 - 0.02 / (2 * 0.5) = 0.48.
    assert!((cells.volume[0] - 0.48).abs() < 1e-6, "{:?}", cells.volume);
}

/// voro++'s radical cells' faces in the unit box: per cell, neighbour →
/// area, and the area on the box's walls.
fn voro_power_faces(sites: &[[f64; 3]], w: &[f64]) -> Vec<(std::collections::HashMap<u32, f64>, f64)> {
    let mut con = ContainerRad::new([0.0; 3], [1.0; 3], [6, 6, 6], [false; 3]);
    for (i, (&p, &wi)) in sites.iter().zip(w).enumerate() {
        con.put(i as i32, p, wi.sqrt());
    }
    let mut out = vec![(std::collections::HashMap::new(), 0.0); sites.len()];
    let mut l = LoopAll::of_container_rad(&mut con);
    assert!(l.start());
    loop {
        let id = l.particle_id() as usize;
        if let Some(mut cell) = con.compute_cell(&mut l) {
            let cell: &mut VoroCellNbr = &mut cell;
            for (n, a) in cell.neighbors().into_iter().zip(cell.face_areas()) {
                if n >= 0 {
                    *out[id].0.entry(n as u32).or_insert(0.0) += a;
                } else {
                    out[id].1 += a;
                }
            }
        }
        if !l.inc() {
            break;
        }
    }
    out
}

/// The power cells' faces (what optimal transport's Newton steps are made
/// of) against voro++'s radical faces: every shared face's area and each
/// cell's wall area within 1e-5 of the cell's surface, no face voro++ does
/// not have, one area per face from either side; every run.
#[test]
fn power_faces_match_voro_plus_plus_on_a_box() {
    let mesh = TetMesh::cube(6);
    let sites = points::uniform(400, 41);
    let w = weights(sites.len(), 0.02, 42);
    let exact = voro_power_faces(&sites, &w);
    for (backend, strategy, pairing) in runs() {
        let what = format!("{} {strategy:?} {pairing:?}", backend.name());
        let cells = ClippedVoronoi::new(&mesh, &sites)
            .weights(&w)
            .strategy(strategy)
            .pairing(pairing)
            .faces(true)
            .backend(backend)
            .compute()
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        let adj = cells.adjacency().expect("faces were asked for");
        let mut worst = 0.0f64;
        for (i, (faces, wall)) in exact.iter().enumerate() {
            let surface: f64 = faces.values().sum::<f64>() + wall;
            let ours: std::collections::HashMap<u32, f64> = adj.of(i).map(|(j, a, _)| (j, a)).collect();
            for (&j, &a) in faces {
                worst = worst.max((ours.get(&j).copied().unwrap_or(0.0) - a).abs() / surface);
            }
            for (&j, &a) in &ours {
                assert!(faces.contains_key(&j) || a <= 1e-6 * surface, "{what}: cell {i} has {j} ({a:e})");
                let back = adj.of(j as usize).find(|f| f.0 == i as u32).map(|f| f.1);
                assert_eq!(back, Some(a), "{what}: face {i}-{j} seen from one side");
            }
            if surface > 0.0 {
                worst = worst.max((adj.boundary[i] - wall).abs() / surface);
            } else {
                assert!(ours.is_empty() && adj.boundary[i] == 0.0, "{what}: empty cell {i} has faces");
            }
        }
        println!("{what}: worst face area error {worst:.2e} of the cell's surface");
        assert!(worst < 1e-5, "{what}: {worst:e}");
    }
}
