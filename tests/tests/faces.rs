//! The cells' faces: which cells touch and over what area, and each cell's
//! area on the domain's boundary, against voro++'s neighbour cells
//! (through `voro_rs`) on a box, for random and lattice sites, both
//! strategies, both pairings, on every backend; and the properties that
//! hold on any domain (a shared face has one area seen from either side,
//! the boundary areas add up to the mesh's surface).

use cvd::{geom::points, ClippedVoronoi, Pairing, Strategy, TetMesh};
use cvd_tests::{assert_no_validation_errors, backends};
use std::collections::HashMap;
use voro_rs::prelude::*;

/// Per cell, voro++'s faces in the unit box: neighbour → area, the area
/// on the box's walls, and the walls' area vector `∫ n dA`.
fn voro_faces(sites: &[[f64; 3]]) -> Vec<(HashMap<u32, f64>, f64, [f64; 3])> {
    let blocks = [((sites.len() as f64 / 5.0).cbrt().ceil() as i32).clamp(1, 32); 3];
    let mut con = ContainerStd::new([0.0; 3], [1.0; 3], blocks, [false; 3]);
    for (i, &p) in sites.iter().enumerate() {
        con.put(i as i32, p, 0.0);
    }
    let mut out = vec![(HashMap::new(), 0.0, [0.0; 3]); sites.len()];
    let mut l = LoopAll::of_container_std(&mut con);
    assert!(l.start());
    loop {
        let id = l.particle_id() as usize;
        let mut cell: VoroCellNbr = con.compute_cell(&mut l).unwrap_or_else(|| panic!("voro++ lost cell {id}"));
        for (n, a) in cell.neighbors().into_iter().zip(cell.face_areas()) {
            if n >= 0 {
                *out[id].0.entry(n as u32).or_insert(0.0) += a;
            } else {
                // Walls -1..-6: x = 0, x = 1, y = 0, y = 1, z = 0, z = 1.
                let wall = (-n - 1) as usize;
                out[id].1 += a;
                out[id].2[wall / 2] += if wall.is_multiple_of(2) { -a } else { a };
            }
        }
        if !l.inc() {
            break;
        }
    }
    out
}

/// `n³` sites on a jittered lattice in the unit box (exact faces are the
/// lattice's, slightly moved: no four sites cospherical).
fn lattice(n: usize) -> Vec<[f64; 3]> {
    let mut rng = points::Rng::new(7);
    let h = 1.0 / n as f64;
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                out.push([i, j, k].map(|c| (c as f64 + 0.5) * h + 0.05 * h * (rng.unit() - 0.5)));
            }
        }
    }
    out
}

#[test]
fn faces_match_voro_plus_plus_in_a_box() {
    let mesh = TetMesh::cube(4);
    // The aligned lattice: faces on the tets' faces, which the clips leave
    // unchanged; the face is the bisector's all the same.
    for (name, sites) in
        [("random", points::uniform(400, 11)), ("lattice", lattice(6)), ("aligned lattice", cvd_tests::cube_lattice(4))]
    {
        let exact = voro_faces(&sites);
        for backend in backends() {
            for (strategy, pairing) in [
                (Strategy::TetCell, Pairing::Flood),
                (Strategy::TetCell, Pairing::Knn),
                (Strategy::CellTet, Pairing::Knn),
            ] {
                let what = format!("{name}, {strategy:?}/{pairing:?} on {}", backend.name());
                let cells = ClippedVoronoi::new(&mesh, &sites)
                    .strategy(strategy)
                    .pairing(pairing)
                    .faces(true)
                    .backend(backend)
                    .compute()
                    .unwrap();
                let adj = cells.adjacency().expect("faces were asked for");
                let mut worst = 0.0f64;
                for (i, (faces, wall, wall_vector)) in exact.iter().enumerate() {
                    let ours: HashMap<u32, f64> = adj.of(i).map(|(j, a, _)| (j, a)).collect();
                    let surface: f64 = faces.values().sum::<f64>() + wall;
                    // Every face of voro++ above rounding, and no other.
                    for (&j, &a) in faces {
                        let got = ours.get(&j).copied().unwrap_or(0.0);
                        worst = worst.max((got - a).abs() / surface);
                    }
                    for (&j, &a) in &ours {
                        assert!(faces.contains_key(&j) || a < 1e-6 * surface, "{what}: cell {i} has {j} ({a:e})");
                    }
                    worst = worst.max((adj.boundary[i] - wall).abs() / surface);
                    for (ours, exact) in adj.boundary_vector[i].iter().zip(wall_vector) {
                        worst = worst.max((ours - exact).abs() / surface);
                    }
                    assert!(
                        (adj.surface_area(i) - surface).abs() <= 1e-5 * surface,
                        "{what}: cell {i} surface {} vs {surface}",
                        adj.surface_area(i)
                    );
                }
                println!("{what}: worst face area error {worst:.2e} of the cell's surface");
                assert!(worst < 1e-5, "{what}: {worst:e}");
                // One area per face, seen from either side; normals along
                // the sites' difference.
                for i in 0..sites.len() {
                    for (j, a, n) in adj.of(i) {
                        let back = adj.of(j as usize).find(|f| f.0 == i as u32).expect("a face seen from one side");
                        assert_eq!(back.1, a);
                        assert!((n[0] + back.2[0]).abs() < 1e-12 && (n[2] + back.2[2]).abs() < 1e-12);
                    }
                }
                let boundary: f64 = adj.boundary.iter().sum();
                assert!((boundary - 6.0).abs() < 1e-6, "{what}: boundary {boundary}");
            }
        }
    }
    assert_no_validation_errors();
}

/// Faces made by sites outside a site's neighbour list (a short list
/// here) are summed apart by the kernels and completed on the host: the
/// adjacency is the one a long list gives.
#[test]
fn faces_beyond_the_lists_are_completed() {
    let mesh = TetMesh::cube(3);
    let sites = points::uniform(300, 21);
    for backend in backends() {
        let full = ClippedVoronoi::new(&mesh, &sites).faces(true).backend(backend).compute().unwrap();
        let short = ClippedVoronoi::new(&mesh, &sites).faces(true).k_site(5).backend(backend).compute().unwrap();
        // The short lists overflow the spill slots of some sites: counted.
        assert!(short.counters.faces_redone > 0 && full.counters.faces_redone == 0, "{:?}", short.counters);
        let (a, b) = (full.adjacency().unwrap(), short.adjacency().unwrap());
        assert_eq!(a.neighbors, b.neighbors, "{}", backend.name());
        // The same faces, clipped in another order (f32 rounding): equal
        // relative to the cell's surface.
        for i in 0..sites.len() {
            let surface = a.surface_area(i);
            let rows = a.of(i).zip(b.of(i)).map(|(x, y)| (x.1, y.1));
            for (x, y) in rows.chain([(a.boundary[i], b.boundary[i])]) {
                assert!((x - y).abs() <= 1e-6 * surface, "{}: cell {i}: {x} vs {y}", backend.name());
            }
        }
    }
}

/// On a non-convex domain (the built-in joint): the boundary areas add up
/// to the mesh's surface and the adjacency is symmetric; a duplicated
/// site gets an empty row.
#[test]
fn faces_close_on_a_non_convex_domain() {
    let mesh = cvd::mesher::models::builtin("joint", Some(12)).unwrap();
    let mut sites = points::in_mesh(&mesh, 300, 5);
    sites.push(sites[10]);
    let surface = mesh.boundary().area();
    for backend in backends() {
        let cells = ClippedVoronoi::new(&mesh, &sites).faces(true).backend(backend).compute().unwrap();
        let adj = cells.adjacency().unwrap();
        assert_eq!(adj.len(), sites.len());
        assert_eq!(adj.of(300).count(), 0, "the duplicate's row");
        let boundary: f64 = adj.boundary.iter().sum();
        assert!((boundary - surface).abs() < 1e-5 * surface, "{}: {boundary} vs {surface}", backend.name());
        for i in 0..300 {
            for (j, a, _) in adj.of(i) {
                assert!(adj.of(j as usize).any(|f| f.0 == i as u32 && f.1 == a));
            }
        }
    }
    assert_no_validation_errors();
}

/// The pieces name what made each of their faces; summed over a cell's
/// pieces, the faces on each neighbour's bisector and on the boundary have
/// the adjacency's areas.
#[test]
fn the_pieces_faces_name_their_makers() {
    let mesh = cvd::mesher::models::builtin("joint", Some(10)).unwrap();
    let sites = points::in_mesh(&mesh, 200, 8);
    let cpu = cvd::exec::CpuBackend::new(None).unwrap();
    let cv = ClippedVoronoi::new(&mesh, &sites).faces(true);
    let (cells, pieces) = cv.compute_with_pieces(&cpu).unwrap();
    let adj = cells.adjacency().unwrap();
    let area = |piece: &cvd::Piece, face: &[u32]| {
        let p: Vec<[f64; 3]> = face.iter().map(|&k| piece.vertices[k as usize]).collect();
        let mut n = [0.0; 3];
        for k in 1..p.len() - 1 {
            let (a, b) = ([0, 1, 2].map(|c| p[k][c] - p[0][c]), [0, 1, 2].map(|c| p[k + 1][c] - p[0][c]));
            n = [n[0] + a[1] * b[2] - a[2] * b[1], n[1] + a[2] * b[0] - a[0] * b[2], n[2] + a[0] * b[1] - a[1] * b[0]];
        }
        0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
    };
    let mut sums: HashMap<(u32, i64), f64> = HashMap::new();
    for piece in pieces.iter() {
        assert_eq!(piece.face_makers.len(), piece.face_ends.len());
        for (face, &maker) in piece.faces().zip(&piece.face_makers) {
            *sums.entry((piece.site, maker)).or_insert(0.0) += area(&piece, face);
        }
    }
    for i in 0..sites.len() {
        let surface = adj.surface_area(i);
        for (j, a, _) in adj.of(i) {
            let got = sums.get(&(i as u32, j as i64)).copied().unwrap_or(0.0);
            assert!((got - a).abs() <= 1e-5 * surface, "cell {i}, neighbour {j}: {got} vs {a}");
        }
        let boundary = sums.get(&(i as u32, cvd::passes::pieces::ON_BOUNDARY)).copied().unwrap_or(0.0);
        assert!((boundary - adj.boundary[i]).abs() <= 1e-5 * surface, "cell {i}: {boundary} vs {}", adj.boundary[i]);
    }
}
