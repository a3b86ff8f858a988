//! Each cell as one closed polyhedron (its pieces merged): on a box
//! against voro++'s cells (through `voro_rs`: the same faces, neighbours
//! and vertices), and on a non-convex domain against the cells' own
//! numbers: closed and oriented outwards, each point once, the volume of
//! the cell, the faces' areas those of the adjacency, the boundary faces
//! adding up to the mesh's surface.

use cvd::passes::polyhedra::CellPolyhedron;
use cvd::{geom::points, Cells, ClippedVoronoi, TetMesh};
use std::collections::{BTreeSet, HashMap};
use voro_rs::prelude::*;

/// Per cell, voro++'s cell in the unit box: vertex count, and the
/// neighbours (negative: the box's walls), one per face.
fn voro_cells(sites: &[[f64; 3]]) -> Vec<(usize, Vec<i32>)> {
    let blocks = [((sites.len() as f64 / 5.0).cbrt().ceil() as i32).clamp(1, 32); 3];
    let mut con = ContainerStd::new([0.0; 3], [1.0; 3], blocks, [false; 3]);
    for (i, &p) in sites.iter().enumerate() {
        con.put(i as i32, p, 0.0);
    }
    let mut out = vec![(0, Vec::new()); sites.len()];
    let mut l = LoopAll::of_container_std(&mut con);
    assert!(l.start());
    loop {
        let id = l.particle_id() as usize;
        let mut cell: VoroCellNbr = con.compute_cell(&mut l).unwrap_or_else(|| panic!("voro++ lost cell {id}"));
        out[id] = (cell.vertex_orders().len(), cell.neighbors());
        if !l.inc() {
            break;
        }
    }
    out
}

/// Every directed edge of `cell` has its reverse exactly once, no face
/// repeats a point and every point is used: closed, consistently
/// oriented, welded.
fn assert_closed(cell: &CellPolyhedron, what: &str) {
    let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
    let mut used = vec![false; cell.vertices.len()];
    for face in cell.faces() {
        assert!(face.len() >= 3, "{what}: a face of {} points", face.len());
        let distinct: BTreeSet<u32> = face.iter().copied().collect();
        assert_eq!(distinct.len(), face.len(), "{what}: a face passes a point twice");
        for k in 0..face.len() {
            *edges.entry((face[k], face[(k + 1) % face.len()])).or_insert(0) += 1;
            used[face[k] as usize] = true;
        }
    }
    for (&(a, b), &n) in &edges {
        assert_eq!(n, 1, "{what}: edge {a}-{b} in {n} faces the same way");
        assert_eq!(edges.get(&(b, a)), Some(&1), "{what}: edge {a}-{b} has no reverse");
    }
    assert!(used.iter().all(|&u| u), "{what}: unused points");
    let diag = cvd::geom::vec3::bounding_box(&cell.vertices);
    let size = cvd::geom::vec3::norm(cvd::geom::vec3::sub(diag.1, diag.0));
    for (i, p) in cell.vertices.iter().enumerate() {
        for q in &cell.vertices[i + 1..] {
            assert!(
                cvd::geom::vec3::norm(cvd::geom::vec3::sub(*p, *q)) > 1e-7 * size,
                "{what}: two points at one place"
            );
        }
    }
}

/// Checks every polyhedron against the cells' numbers; returns the worst
/// volume and face-area errors, relative to the cell's volume and surface.
fn check_against_cells(cells: &Cells, what: &str) -> (f64, f64) {
    let adj = cells.adjacency().expect("faces were asked for");
    let polyhedra = cells.polyhedra().expect("polyhedra were asked for");
    let with_volume = cells.volume.iter().filter(|&&v| v > 0.0).count();
    assert_eq!(polyhedra.len(), with_volume, "{what}: one polyhedron per cell with a volume");
    let (mut dv, mut da) = (0.0f64, 0.0f64);
    let repaired: u32 = polyhedra.iter().map(|c| c.repaired_holes).sum();
    println!("{what}: {repaired} holes closed in {} cells", polyhedra.iter().filter(|c| c.repaired_holes > 0).count());
    for cell in polyhedra {
        assert_eq!(cell.open_edges, 0, "{what}: cell {} open", cell.site);
        let i = cell.site as usize;
        let what = format!("{what}, cell {i}");
        assert_closed(cell, &what);
        let e = (cell.volume() - cells.volume[i]).abs() / cells.volume[i];
        dv = dv.max(e);
        let mut by_neighbor: HashMap<i64, f64> = HashMap::new();
        for (&n, a) in cell.face_neighbors.iter().zip(cell.face_areas()) {
            *by_neighbor.entry(n).or_insert(0.0) += a;
        }
        let surface = adj.surface_area(i);
        let boundary = by_neighbor.remove(&-1).unwrap_or(0.0);
        // Lids (-2) close holes the pieces left: counted, and small.
        let lids = cell.face_neighbors.iter().filter(|&&n| n == -2).count() as u32;
        assert_eq!(lids, cell.repaired_holes, "{what}: lids");
        let lid_area = by_neighbor.remove(&-2).unwrap_or(0.0);
        assert!(lid_area <= 1e-5 * surface, "{what}: lids of area {lid_area:.2e}");
        da = da.max((boundary - adj.boundary[i]).abs() / surface);
        for (j, a, _) in adj.of(i) {
            let ours = by_neighbor.remove(&(j as i64)).unwrap_or(0.0);
            da = da.max((ours - a).abs() / surface);
        }
        // Faces with a neighbour the adjacency has not: none of any size.
        for (j, a) in by_neighbor {
            assert!(a <= 1e-6 * surface, "{what}: a face of area {a:.2e} towards {j}, not in the adjacency");
        }
    }
    (dv, da)
}

/// `n` sites uniform in the built-in joint (resolution 16: a manifold
/// boundary), and their cells with the adjacency and the polyhedra.
fn joint_cells(n: usize, seed: u64) -> (TetMesh, Vec<[f64; 3]>, Cells) {
    let mesh = cvd::mesher::models::builtin("joint", Some(16)).unwrap();
    let sites = points::in_mesh(&mesh, n, seed);
    let cpu = cvd::exec::CpuBackend::new(None).unwrap();
    let (cells, _) = ClippedVoronoi::new(&mesh, &sites).faces(true).compute_with_polyhedra(&cpu).unwrap();
    (mesh, sites, cells)
}

/// A path for `name` in a folder of this test run's own.
fn temp_file(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("cvd-polyhedra-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn merged_cells_are_voro_plus_plus_cells_in_a_box() {
    let mesh = TetMesh::cube(4);
    let sites = points::uniform(400, 11);
    let exact = voro_cells(&sites);
    let cpu = cvd::exec::CpuBackend::new(None).unwrap();
    let (cells, _) = ClippedVoronoi::new(&mesh, &sites).faces(true).compute_with_polyhedra(&cpu).unwrap();
    let (dv, da) = check_against_cells(&cells, "box");
    println!("box: volume {dv:.2e}, face areas {da:.2e}");
    assert!(dv < 1e-6 && da < 1e-6, "volume {dv:.2e}, face areas {da:.2e}");
    for cell in cells.polyhedra().unwrap() {
        let (vertices, neighbors) = &exact[cell.site as usize];
        let what = format!("cell {}", cell.site);
        assert_eq!(cell.vertices.len(), *vertices, "{what}: points");
        // The same faces: one per neighbour and one per wall of the box.
        let ours: BTreeSet<i64> = cell.face_neighbors.iter().filter(|&&n| n >= 0).copied().collect();
        let theirs: BTreeSet<i64> = neighbors.iter().filter(|&&n| n >= 0).map(|&n| n as i64).collect();
        assert_eq!(ours, theirs, "{what}: neighbours");
        assert_eq!(cell.face_ends.len(), neighbors.len(), "{what}: faces");
    }
}

/// A cubic lattice's cells are cubes: 8 points where 8 cells meet (every
/// vertex degenerate), 6 square faces, welded from the pieces' copies.
#[test]
fn a_lattice_gives_cubes() {
    let n = 5;
    let h = 1.0 / n as f64;
    let sites = cvd_tests::cube_lattice(n);
    let mesh = TetMesh::cube(4);
    let cpu = cvd::exec::CpuBackend::new(None).unwrap();
    let (cells, _) = ClippedVoronoi::new(&mesh, &sites).faces(true).compute_with_polyhedra(&cpu).unwrap();
    let (dv, da) = check_against_cells(&cells, "lattice");
    assert!(dv < 1e-6 && da < 1e-6, "volume {dv:.2e}, face areas {da:.2e}");
    for cell in cells.polyhedra().unwrap() {
        let what = format!("cell {}", cell.site);
        assert_eq!((cell.vertices.len(), cell.face_ends.len()), (8, 6), "{what}: points and faces");
        assert!((cell.volume() - h * h * h).abs() < 1e-6 * h * h * h, "{what}: volume {}", cell.volume());
        for a in cell.face_areas() {
            assert!((a - h * h).abs() < 1e-6 * h * h, "{what}: a face of area {a}");
        }
    }
}

#[test]
fn merged_cells_are_closed_on_a_non_convex_domain() {
    let (mesh, _, cells) = joint_cells(600, 5);
    let (dv, da) = check_against_cells(&cells, "joint");
    println!("joint: volume {dv:.2e}, face areas {da:.2e}");
    // The adjacency's areas are the kernels' (f32, within 2.4e-6 of
    // voro++'s in tests/tests/faces.rs).
    assert!(dv < 1e-6 && da < 5e-6, "volume {dv:.2e}, face areas {da:.2e}");
    let boundary: f64 = cells
        .polyhedra()
        .unwrap()
        .iter()
        .flat_map(|c| c.face_neighbors.iter().zip(c.face_areas()).filter(|(&n, _)| n < 0).map(|(_, a)| a))
        .sum();
    let surface = mesh.boundary().area();
    assert!((boundary - surface).abs() < 1e-6 * surface, "boundary faces {boundary} against the mesh's {surface}");
}

/// The joint's cells, written as `cells.vtu` and read back by VTK: one
/// polyhedron per cell with a volume, whose faces enclose, by VTK's own
/// `vtkMassProperties`, the cell's volume.
#[test]
fn vtk_reads_cells_vtu_back() {
    let (_, _, cells) = joint_cells(600, 5);
    let path = temp_file("cells.vtu");
    let polyhedra = cells.polyhedra().unwrap();
    cvd_io::write_cells_vtu(&path, &cells, polyhedra, &mut |_, _| {}).unwrap();
    let script = cvd_tests::script("read_cells_vtu.py");
    let Some(out) = cvd_tests::python(&[script.as_os_str(), path.as_os_str()], "vtk") else { return };
    let read: serde_json::Value = serde_json::from_slice(&out).unwrap();
    let read = read["cells"].as_array().unwrap();
    assert_eq!(read.len(), polyhedra.len());
    let mut worst = 0.0f64;
    for c in read {
        let i = c["site"].as_u64().unwrap() as usize;
        assert_eq!(c["volume"].as_f64(), Some(cells.volume[i]), "site {i}: the stored volume");
        let p = polyhedra.iter().find(|p| p.site as usize == i).unwrap();
        assert_eq!(c["faces"].as_u64(), Some(p.face_ends.len() as u64), "site {i}: faces");
        worst = worst.max((c["vtk_volume"].as_f64().unwrap() - cells.volume[i]).abs() / cells.volume[i]);
    }
    println!("VTK's volumes against the cells': {worst:.2e}");
    assert!(worst < 1e-6, "VTK measures the cells' volumes to {worst:.2e}");
}

/// `walls.ply`, read back by `ply-rs`: each wall once, the walls between
/// two cells with the adjacency's areas, the boundary's adding up to the
/// mesh's surface.
#[test]
fn walls_ply_has_every_wall_once() {
    use ply_rs::parser::Parser;
    use ply_rs::ply::{DefaultElement, Property};
    let (mesh, sites, cells) = joint_cells(400, 8);
    let path = temp_file("walls.ply");
    let written = cvd_io::write_walls_ply(&path, cells.polyhedra().unwrap()).unwrap();
    let mut file = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
    let ply = Parser::<DefaultElement>::new().read_ply(&mut file).unwrap();
    let xyz = |e: &DefaultElement| {
        ["x", "y", "z"].map(|k| match e[k] {
            Property::Double(v) => v,
            _ => panic!("{k}"),
        })
    };
    let vertices: Vec<[f64; 3]> = ply.payload["vertex"].iter().map(xyz).collect();
    let faces = &ply.payload["face"];
    assert_eq!(faces.len(), written);
    let int = |e: &DefaultElement, k: &str| match e[k] {
        Property::Int(v) => v,
        _ => panic!("{k}"),
    };
    let mut by_pair: HashMap<(i32, i32), f64> = HashMap::new();
    for f in faces {
        let Property::ListInt(ref ring) = f["vertex_indices"] else { panic!("vertex_indices") };
        let (a, b) = (int(f, "site"), int(f, "neighbor"));
        assert!(b == -1 || a < b, "wall {a}-{b} written from the higher site");
        let o = vertices[ring[0] as usize];
        let mut n = [0.0; 3];
        for k in 1..ring.len() - 1 {
            let (p, q) = (vertices[ring[k] as usize], vertices[ring[k + 1] as usize]);
            n = cvd::geom::vec3::add(n, cvd::geom::vec3::cross(cvd::geom::vec3::sub(p, o), cvd::geom::vec3::sub(q, o)));
        }
        *by_pair.entry((a, b)).or_insert(0.0) += cvd::geom::vec3::norm(n) / 2.0;
    }
    let adj = cells.adjacency().unwrap();
    let mut worst = 0.0f64;
    for i in 0..sites.len() {
        for (j, area, _) in adj.of(i).filter(|&(j, _, _)| j as usize > i) {
            let ours = by_pair.remove(&(i as i32, j as i32)).unwrap_or(0.0);
            worst = worst.max((ours - area).abs() / adj.surface_area(i));
        }
    }
    let boundary: f64 = by_pair.iter().filter(|((_, b), _)| *b == -1).map(|(_, a)| a).sum();
    by_pair.retain(|(_, b), _| *b != -1);
    assert!(by_pair.values().all(|&a| a < 1e-9), "walls not in the adjacency: {by_pair:?}");
    let surface = mesh.boundary().area();
    println!("walls against the adjacency: {worst:.2e}; boundary {boundary} of {surface}");
    assert!(worst < 5e-6, "wall areas off by {worst:.2e}");
    assert!((boundary - surface).abs() < 1e-6 * surface);
}
