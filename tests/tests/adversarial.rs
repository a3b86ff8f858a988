//! Inputs chosen to break clipped Voronoi codes: clustered sites, perfect
//! lattices (cospherical and coplanar ties everywhere), many sites per tet,
//! parts of the domain that nearly touch, thin shells and slivers. On every
//! backend the volumes add up to the mesh's (E_vol <= 1e-6) and every cell
//! matches the exact f64 reference (all bisectors) to 1e-5 of
//! max(V_i, V_M / n).

use cvd::{geom::points, Cells, ClippedVoronoi, TetMesh};
use cvd_tests::reference::clipped_cells;
use cvd_tests::{assert_no_validation_errors, backends, Placement};

/// Default settings (flood pairing), every backend, against the reference;
/// then, on the CPU, the same input translated by 1e6 and scaled by 1e-6
/// and 1e6: the results, mapped back, match the reference just as well.
fn check(what: &str, mesh: &TetMesh, sites: &[[f64; 3]]) {
    let (vol, centroid) = clipped_cells(mesh, sites);
    for backend in backends() {
        let cells = ClippedVoronoi::new(mesh, sites)
            .backend(backend)
            .compute()
            .unwrap_or_else(|e| panic!("{what} on {}: {e}", backend.name()));
        let what = format!("{what} on {}", backend.name());
        assert_eq!(cells.counters.unresolved, 0, "{what}");
        assert!(cells.e_vol <= 1e-6, "{what}: E_vol {:e}", cells.e_vol);
        assert_matches(&what, &cells, &vol, &centroid);
    }
    assert_no_validation_errors();
    for at in Placement::MOVED {
        let what = format!("{what} at {at:?}");
        let cells =
            ClippedVoronoi::new(&at.mesh(mesh), &at.points(sites)).compute().unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(cells.counters.unresolved, 0, "{what}");
        assert!(cells.e_vol <= 1e-6, "{what}: E_vol {:e}", cells.e_vol);
        if at.offset == 0.0 {
            assert_matches(&what, &at.unplace(&cells), &vol, &centroid);
        } else {
            let (seen_mesh, seen) = at.seen(mesh, sites);
            let (vol, centroid) = clipped_cells(&seen_mesh, &seen);
            assert_matches(&what, &at.unplace(&cells), &vol, &centroid);
        }
    }
}

fn assert_matches(what: &str, got: &Cells, vol: &[f64], centroid: &[[f64; 3]]) {
    let typical = got.mesh_volume / vol.len() as f64;
    for i in 0..vol.len() {
        let scale = vol[i].max(typical);
        let dv = (got.volume[i] - vol[i]).abs();
        assert!(dv <= 1e-5 * scale, "{what}: cell {i} volume {} vs {} (diff {dv:.3e})", got.volume[i], vol[i]);
        if vol[i] > 1e-2 * typical {
            let d = (0..3).map(|a| (got.centroid[i][a] - centroid[i][a]).powi(2)).sum::<f64>().sqrt();
            assert!(d <= 1e-4 * vol[i].cbrt(), "{what}: cell {i} centroid off by {d:.3e}");
        }
    }
}

/// `mesh` moved by `offset` after scaling each axis by `scale`.
fn transformed(mesh: &TetMesh, scale: [f64; 3], offset: [f64; 3]) -> TetMesh {
    let vertices = mesh.vertices.iter().map(|v| [0, 1, 2].map(|a| v[a] * scale[a] + offset[a])).collect();
    TetMesh { vertices, tets: mesh.tets.clone() }
}

/// Both meshes as one (vertices not shared).
fn union(a: &TetMesh, b: &TetMesh) -> TetMesh {
    let n = a.vertices.len() as u32;
    let mut m = a.clone();
    m.vertices.extend(&b.vertices);
    m.tets.extend(b.tets.iter().map(|t| t.map(|v| v + n)));
    m
}

#[test]
fn clustered_sites() {
    let sites: Vec<[f64; 3]> =
        points::clustered(400, 4, 0.03, 7).into_iter().map(|p| p.map(|c| c.clamp(0.0, 1.0))).collect();
    check("4 tight blobs", &TetMesh::cube(5), &sites);
}

#[test]
fn perfect_lattice() {
    // Every site on a 6³ lattice in the unit cube, the mesh on the same
    // kind of lattice: four-way ties at every Voronoi vertex, bisectors
    // through tet faces.
    let side = 6;
    let mut sites = Vec::new();
    for k in 0..side {
        for j in 0..side {
            for i in 0..side {
                sites.push([i, j, k].map(|c| (c as f64 + 0.5) / side as f64));
            }
        }
    }
    check("lattice of cell centres", &TetMesh::cube(6), &sites);
    // Sites on the mesh's own vertices.
    let mut sites: Vec<[f64; 3]> = Vec::new();
    for p in points::lattice(200, 5, 3) {
        let p = p.map(|c| c / 4.0);
        if !sites.contains(&p) {
            sites.push(p);
        }
    }
    check("sites on mesh vertices", &TetMesh::cube(4), &sites);
}

#[test]
fn many_sites_in_few_tets() {
    check("2000 sites in 48 tets", &TetMesh::cube(2), &points::uniform(2000, 13));
}

#[test]
fn nearly_touching_bars() {
    // Two bars 1e-3 apart: sites of one bar own space next to the other.
    let bar = transformed(&TetMesh::cube(4), [1.0, 0.2, 0.2], [0.0; 3]);
    let other = transformed(&bar, [1.0; 3], [0.0, 0.201, 0.0]);
    let mesh = union(&bar, &other);
    let sites = points::in_mesh(&mesh, 300, 5);
    check("two bars 1e-3 apart", &mesh, &sites);
}

#[test]
fn thin_shell() {
    // A hollow cube with walls one tenth thick.
    let mesh = TetMesh::voxels(10, |i, j, k| [i, j, k].iter().any(|&c| c == 0 || c == 9));
    let sites = points::in_mesh(&mesh, 400, 9);
    check("hollow cube", &mesh, &sites);
}

#[test]
fn slivers() {
    // A slab 1/100 thick cut into cube-split tets: dihedral angles under
    // one degree everywhere.
    let mesh = transformed(&TetMesh::cube(6), [1.0, 1.0, 0.01], [0.0; 3]);
    let min_dihedral = min_dihedral_degrees(&mesh);
    assert!(min_dihedral < 1.0, "not slivers: {min_dihedral}");
    let sites = points::in_mesh(&mesh, 300, 17);
    check("slab of slivers", &mesh, &sites);
}

fn min_dihedral_degrees(mesh: &TetMesh) -> f64 {
    let mut min = 180.0f64;
    for t in &mesh.tets {
        let p = t.map(|v| mesh.vertices[v as usize].map(f64::from));
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        };
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        // Outward face normals; the dihedral angle at an edge is pi minus
        // the angle between the normals of its two faces.
        let normal = |i: usize| {
            let (a, b, c) = (p[(i + 1) % 4], p[(i + 2) % 4], p[(i + 3) % 4]);
            let n = cross(sub(b, a), sub(c, a));
            let n = if dot(n, sub(p[i], a)) > 0.0 { n.map(|x| -x) } else { n };
            let l = dot(n, n).sqrt();
            n.map(|x| x / l)
        };
        for i in 0..4 {
            for j in i + 1..4 {
                let angle = 180.0 - dot(normal(i), normal(j)).clamp(-1.0, 1.0).acos().to_degrees();
                min = min.min(angle);
            }
        }
    }
    min
}

#[test]
fn knn_pairing_with_too_few_sites_per_tet_is_completed() {
    // k = 2 sites per tet misses owners of most tets: the certificate
    // (each tet's pieces add up to it) finds them and the host adds the
    // missing pieces; the paired ones were exact already.
    let mesh = TetMesh::voxels(4, |i, j, _| i < 2 || j < 2);
    let sites = points::in_mesh(&mesh, 250, 4);
    let (vol, centroid) = clipped_cells(&mesh, &sites);
    for backend in backends() {
        for strategy in [cvd::Strategy::TetCell, cvd::Strategy::CellTet] {
            let cells = ClippedVoronoi::new(&mesh, &sites)
                .strategy(strategy)
                .pairing(cvd::Pairing::Knn)
                .k(Some(2))
                .backend(backend)
                .compute()
                .unwrap();
            let what = format!("knn pairing, k = 2, {strategy:?} on {}", backend.name());
            assert!(cells.counters.missed_tets > 0, "{what}: the certificate found nothing to complete");
            assert_eq!(cells.counters.unresolved, 0, "{what}");
            assert!(cells.e_vol <= 1e-6, "{what}: E_vol {:e}", cells.e_vol);
            assert_matches(&what, &cells, &vol, &centroid);
        }
    }
    assert_no_validation_errors();
}
