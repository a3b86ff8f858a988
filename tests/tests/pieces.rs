//! The pieces of a diagram: closed polyhedra with outward faces, inside
//! their tets, nearer their sites than any other, and whose volumes —
//! computed here from the face loops — add up to each tet, to each site's
//! cell and to the mesh.

use cvd::exec::CpuBackend;
use cvd::{geom::points, Cells, ClippedVoronoi, Pairing, Piece, Strategy, TetMesh};
use cvd_tests::Shape;
use proptest::prelude::*;
use std::collections::{HashMap, HashSet};

type P = [f64; 3];

fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: P, b: P) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: P, b: P) -> P {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// The mean of the vertices: inside a convex polyhedron.
fn centre(piece: &Piece) -> P {
    let n = piece.vertices.len() as f64;
    piece.vertices.iter().fold([0.0; 3], |c, v| [c[0] + v[0] / n, c[1] + v[1] / n, c[2] + v[2] / n])
}

/// The volume as a sum of cones from the centre over the faces' fan
/// triangles (the library's own uses the divergence theorem).
fn volume(piece: &Piece) -> f64 {
    let c = centre(piece);
    let mut v = 0.0;
    for face in piece.faces() {
        let a = sub(piece.vertices[face[0] as usize], c);
        for w in face[1..].windows(2) {
            let (b, d) = (sub(piece.vertices[w[0] as usize], c), sub(piece.vertices[w[1] as usize], c));
            v += dot(a, cross(b, d)) / 6.0;
        }
    }
    v
}

/// Every face loop is closed into a surface (each edge walked once each
/// way), every vertex is on a face, and every face's normal points away
/// from the centre.
fn assert_closed_and_outward(piece: &Piece) {
    let what = format!("piece of site {} in tet {}", piece.site, piece.tet);
    let mut edges = HashSet::new();
    let mut used = vec![false; piece.vertices.len()];
    let c = centre(piece);
    let size = piece.vertices.iter().map(|&v| dot(sub(v, c), sub(v, c)).sqrt()).fold(0.0, f64::max);
    let place = piece.vertices.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!(piece.faces().count() >= 4, "{what}: {} faces", piece.faces().count());
    for face in piece.faces() {
        assert!(face.len() >= 3, "{what}: a face of {} vertices", face.len());
        for (k, &a) in face.iter().enumerate() {
            let b = face[(k + 1) % face.len()];
            assert!(edges.insert((a, b)), "{what}: edge {a} -> {b} twice");
            used[a as usize] = true;
        }
        // Newell's normal (twice the area vector) and the face's centre.
        let mut n = [0.0; 3];
        let mut f = [0.0; 3];
        for (k, &a) in face.iter().enumerate() {
            let (p, q) = (piece.vertices[a as usize], piece.vertices[face[(k + 1) % face.len()] as usize]);
            n = [0, 1, 2].map(|i| n[i] + cross(sub(p, c), sub(q, c))[i]);
            f = [0, 1, 2].map(|i| f[i] + p[i] / face.len() as f64);
        }
        let out = dot(n, sub(f, c));
        let area = dot(n, n).sqrt();
        // A face of f32-rounding size (where four or more planes meet at a
        // point, the vertex is a tiny face) has no orientation to check.
        // Rounding is relative to the coordinates, not to the piece: a
        // small piece far from the origin has faces an ulp of its place.
        let rounding = (f32::EPSILON as f64 * size.max(place)).powi(2);
        assert!(
            area <= 1e3 * rounding || out >= -1e-6 * area * size,
            "{what}: a face faces inward ({out:e}, area {area:e})"
        );
    }
    for &(a, b) in &edges {
        assert!(edges.contains(&(b, a)), "{what}: edge {a} -> {b} has no twin: the surface is open");
    }
    assert!(used.iter().all(|&u| u), "{what}: a vertex on no face");
}

fn barycentric_inside(mesh: &TetMesh, t: usize, p: P, tol: f64) -> bool {
    let v = mesh.tets[t].map(|i| mesh.vertices[i as usize].map(f64::from));
    let vol = |a: P, b: P, c: P, d: P| dot(sub(b, a), cross(sub(c, a), sub(d, a)));
    let whole = vol(v[0], v[1], v[2], v[3]);
    let parts =
        [vol(p, v[1], v[2], v[3]), vol(v[0], p, v[2], v[3]), vol(v[0], v[1], p, v[3]), vol(v[0], v[1], v[2], p)];
    parts.iter().all(|&w| w / whole >= -tol)
}

/// Checks every property of `pieces` against `cells`, `mesh` and `sites`.
fn assert_pieces(what: &str, mesh: &TetMesh, sites: &[[f64; 3]], cells: &Cells, pieces: &[Piece]) {
    let n = sites.len();
    let size = mesh.volume().cbrt();
    let mut per_site = vec![0.0; n];
    let mut per_tet = vec![0.0; mesh.tets.len()];
    let mut seen = HashSet::new();
    // Whole cells (the default strategy) are one piece of no tet.
    let any_whole = pieces.iter().any(|p| p.tet == Piece::WHOLE);
    for piece in pieces {
        let (s, t) = (piece.site as usize, piece.tet as usize);
        let whole = piece.tet == Piece::WHOLE;
        assert!(s < n && (whole || t < mesh.tets.len()), "{what}: site {s} or tet {t} out of range");
        assert!(seen.insert((s, t)), "{what}: site {s} has two pieces in tet {t}");
        assert_closed_and_outward(piece);
        let v = volume(piece);
        assert!(v > 0.0, "{what}: piece of site {s} in tet {t} has volume {v:e}");
        assert!(
            (v - piece.volume()).abs() <= 1e-9 * size.powi(3),
            "{what}: {v:e} vs the library's {:e}",
            piece.volume()
        );
        per_site[s] += v;
        if whole {
            continue;
        }
        per_tet[t] += v;
        // In its tet, and nearer its site than any other (to f32 precision).
        let x = sites[s].map(f64::from);
        for &p in &piece.vertices {
            assert!(
                barycentric_inside(mesh, t, p, 1e-5),
                "{what}: vertex {p:?} of site {s}'s piece is outside tet {t}"
            );
            let d = dot(sub(p, x), sub(p, x)).sqrt();
            for (j, y) in sites.iter().enumerate() {
                let y = y.map(f64::from);
                let dj = dot(sub(p, y), sub(p, y)).sqrt();
                assert!(d <= dj + 1e-5 * size, "{what}: vertex {p:?} of site {s}'s piece is nearer site {j}");
            }
        }
    }
    let total: f64 = per_site.iter().sum();
    assert!((total - mesh.volume()).abs() <= 1e-5 * mesh.volume(), "{what}: pieces add up to {total}");
    for (t, v) in per_tet.iter().enumerate().filter(|_| !any_whole) {
        let tet = mesh.tet_volume(t).abs();
        assert!((v - tet).abs() <= 1e-4 * tet, "{what}: tet {t}'s pieces add up to {v:e}, the tet is {tet:e}");
    }
    let typical = mesh.volume() / n as f64;
    for (i, (&got, &cell)) in per_site.iter().zip(&cells.volume).enumerate() {
        let d = (got - cell).abs();
        assert!(d <= 1e-5 * cell.max(typical), "{what}: site {i}: pieces {got:e}, cell {cell:e}");
    }
}

fn cpu() -> &'static CpuBackend {
    static CPU: std::sync::OnceLock<CpuBackend> = std::sync::OnceLock::new();
    CPU.get_or_init(|| CpuBackend::new(None).unwrap())
}

fn mesh(shape: Shape) -> TetMesh {
    shape.mesh()
}

/// The diagram with its pieces, checked against the plain computation.
fn pieces_of(cv: ClippedVoronoi<'_>) -> (Cells, Vec<Piece>) {
    let (cells, pieces) = cv.compute_with_pieces(cpu()).unwrap();
    let plain = cv.backend(cpu()).compute().unwrap();
    // Fixed-point sums: the same pieces give the same bits.
    assert_eq!(cells.volume, plain.volume);
    assert_eq!(cells.energy, plain.energy);
    (cells, pieces.to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 8, failure_persistence: None, ..ProptestConfig::default() })]

    /// Every strategy and pairing, convex and non-convex meshes.
    #[test]
    fn pieces_tile_the_mesh_and_each_cell(
        shape in prop_oneof![Just(Shape::Cube(3)), Just(Shape::Ell), Just(Shape::Holed)],
        n in 1usize..=120,
        seed in any::<u64>(),
    ) {
        let mesh = mesh(shape);
        let sites = points::uniform(n, seed);
        for (strategy, pairing) in [(Strategy::Whole, Pairing::Flood), (Strategy::TetCell, Pairing::Flood), (Strategy::TetCell, Pairing::Knn), (Strategy::CellTet, Pairing::Knn)] {
            let cv = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).pairing(pairing).k(Some(n));
            let (cells, pieces) = pieces_of(cv);
            let what = format!("{shape:?} n={n} {strategy:?} {pairing:?}");
            assert_pieces(&what, &mesh, &sites, &cells, &pieces);
        }
    }
}

/// Few neighbours per site leave pieces to grid walks (flood) or to the
/// second pass (knn pairing): their pieces come out too, once.
#[test]
fn pieces_beyond_short_lists_come_out_once() {
    let mesh = TetMesh::cube(4);
    let sites = points::in_mesh(&mesh, 300, 7);
    for (strategy, pairing) in
        [(Strategy::TetCell, Pairing::Flood), (Strategy::TetCell, Pairing::Knn), (Strategy::CellTet, Pairing::Knn)]
    {
        let cv = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).pairing(pairing).k_site(4);
        let (cells, pieces) = pieces_of(cv);
        let beyond = if pairing == Pairing::Flood { cells.counters.walks } else { cells.counters.second_pass };
        assert!(beyond > 0, "{strategy:?} {pairing:?}: every piece was settled by its list");
        assert_eq!(cells.counters.unresolved, 0);
        assert_pieces(&format!("k_site 4, {strategy:?} {pairing:?}"), &mesh, &sites, &cells, &pieces);
    }
}

/// A tet with more owners than the kernel's flood holds fails after
/// building many pieces: those must be taken back, and the second pass's
/// pieces of the tet come out instead.
#[test]
fn failed_floods_take_their_pieces_back() {
    let mesh = TetMesh::cube(1);
    let sites = points::in_mesh(&mesh, 400, 5);
    let cv = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::TetCell).pairing(Pairing::Flood);
    let (cells, pieces) = pieces_of(cv);
    assert_eq!(cells.counters.second_pass, mesh.tets.len() as u64, "every tet should overflow the kernel's flood");
    assert_pieces("6 tets, 400 sites", &mesh, &sites, &cells, &pieces);
}

/// A duplicated site's cell belongs to its first copy, which gets all the
/// pieces.
#[test]
fn duplicates_give_their_pieces_to_the_first_copy() {
    let mesh = TetMesh::cube(3);
    let mut sites = points::uniform(40, 3);
    sites.insert(5, sites[20]);
    sites.push(sites[0]);
    let (cells, pieces) = pieces_of(ClippedVoronoi::new(&mesh, &sites));
    assert_eq!(cells.counters.duplicate_sites, 2);
    let owners: HashSet<u32> = pieces.iter().map(|p| p.site).collect();
    assert!(owners.contains(&5) && owners.contains(&0), "the first copies own pieces");
    assert!(!owners.contains(&21) && !owners.contains(&41), "a later copy owns a piece");
    assert_pieces("duplicates", &mesh, &sites, &cells, &pieces);
}

/// Pieces are sorted by site, then tet, and every site's cell that has a
/// volume has pieces.
#[test]
fn pieces_are_sorted_and_cover_every_cell() {
    let mesh = TetMesh::voxels(4, |i, j, _| i < 2 || j < 2);
    let sites = points::in_mesh(&mesh, 150, 11);
    let (cells, pieces) = pieces_of(ClippedVoronoi::new(&mesh, &sites));
    assert!(pieces.windows(2).all(|w| (w[0].site, w[0].tet) < (w[1].site, w[1].tet)));
    let mut count: HashMap<u32, usize> = HashMap::new();
    for p in &pieces {
        *count.entry(p.site).or_default() += 1;
    }
    for (i, v) in cells.volume.iter().enumerate() {
        assert_eq!(*v > 0.0, count.contains_key(&(i as u32)), "site {i} volume {v:e}");
    }
}

/// Sites whose bisectors meet four at a point in a piece: the point is a
/// face of rounding size (three vertices an ulp apart), found by
/// `pieces_tile_the_mesh_and_each_cell` (Ell, 71 sites, this seed); the
/// pieces must still be closed, outward where a face has a size, and tile.
#[test]
fn a_point_where_four_bisectors_meet() {
    let mesh = mesh(Shape::Ell);
    let sites = points::uniform(71, 5517126888292707477);
    let (cells, pieces) = pieces_of(ClippedVoronoi::new(&mesh, &sites).pairing(Pairing::Flood));
    assert_pieces("Ell n=71 flood", &mesh, &sites, &cells, &pieces);
}

/// A face of rounding size in a small piece (Holed, 78 sites, this seed,
/// found by `pieces_tile_the_mesh_and_each_cell`): its vertices are an ulp
/// of the mesh's coordinates apart, far more than an ulp of the piece.
#[test]
fn a_rounding_face_in_a_small_piece() {
    let mesh = mesh(Shape::Holed);
    let sites = points::uniform(78, 3752133699944985363);
    for (strategy, pairing) in
        [(Strategy::TetCell, Pairing::Flood), (Strategy::TetCell, Pairing::Knn), (Strategy::CellTet, Pairing::Knn)]
    {
        let cv = ClippedVoronoi::new(&mesh, &sites).strategy(strategy).pairing(pairing).k(Some(78));
        let (cells, pieces) = pieces_of(cv);
        assert_pieces(&format!("Holed n=78 {strategy:?} {pairing:?}"), &mesh, &sites, &cells, &pieces);
    }
}
