//! The exact reference for power (Laguerre) cells — the f64 reference
//! clipper with weights, `cvd_tests::reference::clipped_power_cells` —
//! against voro++'s radical tessellation (through `voro_rs`, an oracle that
//! shares no code with this project) on a box, with weights that empty
//! some cells; and the power diagram's own invariance: a constant added to
//! every weight changes nothing.

use cvd::{points, TetMesh};
use cvd_tests::reference::clipped_power_cells;
use voro_rs::prelude::*;

/// voro++'s radical cells of `sites` with weights `w = r²` in the box
/// `lo..hi`: volumes and centroids in input order (an empty cell: volume 0,
/// no centroid).
fn voro_power_cells(lo: [f64; 3], hi: [f64; 3], sites: &[[f64; 3]], w: &[f64]) -> (Vec<f64>, Vec<Option<[f64; 3]>>) {
    let mut con = ContainerRad::new(lo, hi, [6, 6, 6], [false; 3]);
    for (i, (&p, &wi)) in sites.iter().zip(w).enumerate() {
        con.put(i as i32, p, wi.sqrt());
    }
    assert_eq!(con.total_particles() as usize, sites.len(), "voro++ rejected a site");
    let mut volume = vec![0.0; sites.len()];
    let mut centroid = vec![None; sites.len()];
    let mut l = LoopAll::of_container_rad(&mut con);
    assert!(l.start());
    loop {
        let id = l.particle_id() as usize;
        if let Some(mut cell) = con.compute_cell(&mut l) {
            let cell: &mut VoroCellSgl = &mut cell;
            volume[id] = cell.volume();
            let (c, p) = (cell.centroid(), l.position());
            centroid[id] = Some([c[0] + p[0], c[1] + p[1], c[2] + p[2]]);
        }
        if !l.inc() {
            break;
        }
    }
    (volume, centroid)
}

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
    let (voro_vol, voro_centroid) = voro_power_cells([0.0; 3], [1.0; 3], &sites, &w);
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
    let mut mesh = TetMesh::cube(2);
    let n_vertices = mesh.vertices.len() as u32;
    for shift in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        let base = mesh.vertices.len() as u32;
        let cube = TetMesh::cube(2);
        mesh.vertices.extend(cube.vertices.iter().map(|v| [v[0] + shift[0], v[1] + shift[1], v[2]]));
        mesh.tets.extend(cube.tets.iter().map(|t| t.map(|k| k + base)));
    }
    assert_eq!(mesh.vertices.len() as u32, 3 * n_vertices);
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
