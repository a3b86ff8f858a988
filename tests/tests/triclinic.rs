//! Triclinic cells and walls: the periodic diagram in a cell given by
//! three lattice vectors, and in boxes periodic along some axes only.
//!
//! A triclinic cell that is not its lattice's own (vectors that are whole
//! combinations of a cube's) tiles space with the same sites as the cube:
//! its cells must be voro++'s periodic cube cells, site by site. Walls are
//! checked against voro++'s containers periodic along the same axes. Exact
//! lattices (FCC, BCC, HCP) in cells that are not their own give every
//! cell the lattice's volume and faces.

use cvd::{
    geom::points, CpuBackend, IndexThresholds, ParticleCells, PeriodicBox, PeriodicCells, PeriodicVoronoi, Strategy,
};
use cvd_tests::backends;
use cvd_tests::voro::{partly_periodic_power_cells, periodic_power_cells};

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// The cube's sites in the triclinic cell `a = (1,0,0)`, `b = (1,1,0)`,
/// `c = (-1,1,1)` (volume 1: the cube's lattice) at an odd origin.
fn sheared() -> PeriodicBox {
    PeriodicBox::triclinic([0.3, -0.2, 0.1], [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 1.0]]).unwrap()
}

/// Every cell's volume against `volume` within `tol` and its centroid's
/// offset from its site against `offset` within `3 tol`, relative to the
/// cell's size (at least the mean). Centroids of cells below 1e-3 of the
/// mean volume are not compared: the kernels sum first moments in fixed
/// point, 2^-56 of the frame's scale to the fourth, which is 1e-5 of the
/// mean size for a cell 1e-7 of the mean in the sheared cell's frame (its
/// bounding box is 6 times its volume).
fn check(out: &PeriodicCells, volume: &[f64], offset: &[Option<[f64; 3]>], tol: f64, what: &str) {
    let n = volume.len();
    let mean = volume.iter().sum::<f64>() / n as f64;
    let mut worst = (0.0f64, 0.0f64);
    for i in 0..n {
        let size = volume[i].max(mean);
        let dv = (out.cells.volume[i] - volume[i]).abs() / size;
        assert!(dv <= tol, "{what}: cell {i} volume {} against {}", out.cells.volume[i], volume[i]);
        worst.0 = worst.0.max(dv);
        if let Some(o) = offset[i].filter(|_| volume[i] > 1e-3 * mean) {
            let d = norm([0, 1, 2].map(|a| out.offsets[i][a] - o[a])) / size.cbrt();
            assert!(
                d <= 3.0 * tol,
                "{what}: cell {i} centroid offset {:?} against {o:?}; volume {} against {}, site {:?}",
                out.offsets[i],
                out.cells.volume[i],
                volume[i],
                out.sites[i]
            );
            worst.1 = worst.1.max(d);
        }
    }
    println!(
        "{what}: {} images ({} mirrors), worst volume {:.1e}, centroid {:.1e}",
        out.images, out.mirrors, worst.0, worst.1
    );
}

#[test]
fn a_sheared_cell_of_the_cube_lattice_gives_voro_plus_plus_cube_cells() {
    let domain = sheared();
    assert!((domain.volume() - 1.0).abs() < 1e-15);
    let random = points::uniform(500, 301);
    let clustered = points::clustered(500, 5, 0.06, 302);
    for (name, sites) in [("random", &random), ("clustered", &clustered)] {
        let spacing = (1.0 / sites.len() as f64).cbrt();
        let weights: Vec<f64> = points::uniform(sites.len(), 303).iter().map(|p| p[0] * spacing * spacing).collect();
        for w in [vec![0.0; sites.len()], weights] {
            let (vol, centroid) = periodic_power_cells([0.0; 3], [1.0; 3], sites, &w);
            // voro++'s centroid about its site, through the cube's sides.
            let offset: Vec<Option<[f64; 3]>> = centroid
                .iter()
                .zip(sites.iter())
                .map(|(c, p)| c.map(|c| [0, 1, 2].map(|a| c[a] - p[a] - (c[a] - p[a]).round())))
                .collect();
            for backend in backends() {
                for strategy in [Strategy::Whole, Strategy::TetCell] {
                    let out = PeriodicVoronoi::new(domain, sites)
                        .weights(&w)
                        .backend(backend)
                        .strategy(strategy)
                        .compute()
                        .unwrap();
                    let what = format!("{name}, weights {}, {}, {strategy:?}", w[0] != w[1], backend.kind());
                    // Wrapped in the cell's own coordinates.
                    for p in &out.sites {
                        let s = domain.fractional(*p);
                        assert!(s.iter().all(|x| (0.0..1.0).contains(x)), "{what}: {p:?} at {s:?}");
                    }
                    assert!(out.wrapped > sites.len() / 4, "{what}: {} wrapped", out.wrapped);
                    assert!(out.cells.e_vol < 1e-6, "{what}: the cells fill {}", out.cells.total_volume);
                    // lavapipe rounds the power cells whole cells rebuild in
                    // a frame about their centre as a product and a sum
                    // (Vulkan's Fma need not be fused): measured 1.6e-6.
                    let cpu = backend.name().starts_with("cpu");
                    let tol = if cpu || strategy != Strategy::Whole || w[0] == w[1] { 1e-6 } else { 5e-6 };
                    check(&out, &vol, &offset, tol, &what);
                }
            }
        }
    }
}

/// voro++'s containers periodic along some axes, walls along the others:
/// the same cells; a site's area on the walls is its boundary.
#[test]
fn walls_along_some_axes_give_voro_plus_plus_partly_periodic_cells() {
    let (lo, hi) = ([-0.5, 0.0, 1.0], [1.5, 1.0, 2.5]);
    let unit = points::uniform(600, 311);
    let sites: Vec<[f64; 3]> = unit.iter().map(|p| [0, 1, 2].map(|a| lo[a] + p[a] * (hi[a] - lo[a]))).collect();
    let spacing = (3.0 / sites.len() as f64).cbrt();
    let weights: Vec<f64> = points::uniform(sites.len(), 312).iter().map(|p| p[1] * spacing * spacing).collect();
    for periodic in [[true, true, false], [false, true, false], [true, false, true], [false; 3]] {
        let domain = PeriodicBox::new(lo, hi).unwrap().with_periodic(periodic);
        for w in [vec![0.0; sites.len()], weights.clone()] {
            let (vol, centroid) = partly_periodic_power_cells(lo, hi, periodic, &sites, &w);
            let offset: Vec<Option<[f64; 3]>> =
                centroid.iter().zip(&sites).map(|(c, p)| c.map(|c| [0, 1, 2].map(|a| c[a] - p[a]))).collect();
            for backend in backends() {
                let out =
                    PeriodicVoronoi::new(domain, &sites).weights(&w).faces(true).backend(backend).compute().unwrap();
                let what = format!("periodic {periodic:?}, weights {}, {}", w[0] != w[1], backend.kind());
                assert!(out.cells.e_vol < 1e-6, "{what}: the cells fill {}", out.cells.total_volume);
                check(&out, &vol, &offset, 1e-6, &what);
                // The walls' area: two faces of the box per walled axis.
                let adj = out.cells.adjacency.as_ref().unwrap();
                let l = domain.lengths();
                let walls: f64 = (0..3).filter(|&a| !periodic[a]).map(|a| 2.0 * l[(a + 1) % 3] * l[(a + 2) % 3]).sum();
                let boundary: f64 = adj.boundary.iter().sum();
                assert!((boundary - walls).abs() < 1e-6 * walls.max(1.0), "{what}: walls {boundary} against {walls}");
                // Each cell closed: shared faces and wall faces cancel.
                for i in 0..sites.len() {
                    let mut closure = adj.boundary_vector[i];
                    for e in adj.offsets[i]..adj.offsets[i + 1] {
                        for (c, n) in closure.iter_mut().zip(adj.normals[e]) {
                            *c += adj.areas[e] * n;
                        }
                    }
                    // Relative to the surface, at least the mean cell's, as
                    // the volumes.
                    let surface = (adj.surface_area(i) + adj.boundary[i]).max(6.0 * spacing * spacing);
                    assert!(
                        norm(closure) <= 1e-5 * surface,
                        "{what}: cell {i} open by {closure:?}, surface {surface}, wall {}, volume {}",
                        adj.boundary[i],
                        out.cells.volume[i]
                    );
                }
            }
        }
        // Other strategies do not take walls.
        if periodic != [true; 3] {
            let e = PeriodicVoronoi::new(domain, &sites).strategy(Strategy::TetCell).compute().unwrap_err().to_string();
            assert!(e.contains("whole cells"), "{e}");
        }
    }
}

/// A lattice whose sites lie on the walls: each is moved 1e-9 of the height
/// inside (counted), its cell cut by the wall.
#[test]
fn sites_on_walls_are_moved_inside_and_counted_and_sites_beyond_them_refused() {
    let domain = PeriodicBox::new([0.0; 3], [1.0; 3]).unwrap().with_periodic([true, true, false]);
    let m = 5;
    let sites: Vec<[f64; 3]> = (0..m * m * (m + 1))
        .map(|i| {
            [(i % m) as f64 / m as f64 + 0.1, ((i / m) % m) as f64 / m as f64 + 0.1, (i / (m * m)) as f64 / m as f64]
        })
        .collect();
    for backend in backends() {
        let out = PeriodicVoronoi::new(domain, &sites).backend(backend).compute().unwrap();
        assert_eq!(out.on_walls, 2 * m * m, "{}", backend.kind());
        let v = 1.0 / (m * m * m) as f64;
        for (i, p) in sites.iter().enumerate() {
            // Half cells on the walls.
            let expect = if p[2] == 0.0 || p[2] == 1.0 { v / 2.0 } else { v };
            assert!((out.cells.volume[i] - expect).abs() < 1e-6 * expect, "site {i} {p:?}: {}", out.cells.volume[i]);
        }
    }
    let e = PeriodicVoronoi::new(domain, &[[0.5, 0.5, 1.01], [0.5, 0.5, 0.5]]).compute().unwrap_err().to_string();
    assert!(e.contains("site 0") && e.contains("c (z)"), "{e}");
    // Periodic axes wrap whatever lies outside.
    assert!(PeriodicVoronoi::new(domain, &[[3.5, -0.5, 0.5], [0.5, 0.5, 0.5]]).compute().is_ok());
}

/// The lattice's sites in a supercell `m` (rows: whole multiples of the
/// lattice vectors `lattice`), with `basis` (fractional in the lattice):
/// every lattice point inside it, wrapped there.
fn lattice_in(lattice: [[f64; 3]; 3], basis: &[[f64; 3]], m: [[i32; 3]; 3]) -> (PeriodicBox, Vec<[f64; 3]>) {
    let vectors = m.map(|row| [0, 1, 2].map(|k| (0..3).map(|j| row[j] as f64 * lattice[j][k]).sum::<f64>()));
    let domain = PeriodicBox::triclinic([0.1, 0.2, -0.3], vectors).unwrap();
    let reach = m.iter().flatten().map(|x| x.abs()).sum::<i32>() + 1;
    let mut sites = Vec::new();
    for i in -reach..=reach {
        for j in -reach..=reach {
            for k in -reach..=reach {
                for b in basis {
                    let t = [i as f64 + b[0], j as f64 + b[1], k as f64 + b[2]];
                    let p = [0, 1, 2].map(|a| 0.1 + (0..3).map(|l| t[l] * lattice[l][a]).sum::<f64>());
                    // A little off the cell's sides, so that no site falls
                    // on one twice.
                    let p = [p[0] + 1e-3, p[1] + 2e-3, p[2] + 3e-3];
                    let s = domain.fractional(p);
                    if s.iter().all(|x| (0.0..1.0).contains(x)) {
                        sites.push(p);
                    }
                }
            }
        }
    }
    (domain, sites)
}

/// Each cell's faces larger than 1e-6 of its surface (the lattices' cells
/// meet several at a vertex: zero-area faces may appear there).
fn face_counts(out: &PeriodicCells) -> Vec<usize> {
    let adj = out.cells.adjacency.as_ref().unwrap();
    (0..out.sites.len())
        .map(|i| {
            let surface = adj.surface_area(i);
            adj.of(i).filter(|f| f.1 > 1e-6 * surface).count()
        })
        .collect()
}

#[test]
fn fcc_bcc_and_hcp_in_cells_that_are_not_their_own() {
    let h = 0.75f64.sqrt();
    let c = (8.0f64 / 3.0).sqrt();
    let fcc_primitive = [[0.0, 0.5, 0.5], [0.5, 0.0, 0.5], [0.5, 0.5, 0.0]];
    let bcc_primitive = [[0.5, 0.5, -0.5], [-0.5, 0.5, 0.5], [0.5, -0.5, 0.5]];
    let hex = [[1.0, 0.0, 0.0], [0.5, h, 0.0], [0.0, 0.0, c]];
    let cases = [
        // name, lattice, basis, supercell, cell volume, faces, Voronoi index
        ("FCC", fcc_primitive, vec![[0.0; 3]], [[3, 0, 0], [1, 3, 0], [0, 1, 2]], 0.25, 12, [0, 12, 0, 0]),
        ("BCC", bcc_primitive, vec![[0.0; 3]], [[2, 1, 0], [0, 3, 0], [1, 0, 3]], 0.5, 14, [0, 6, 0, 8]),
        (
            "HCP",
            hex,
            vec![[0.0; 3], [1.0 / 3.0, 1.0 / 3.0, 0.5]],
            [[3, 0, 0], [1, 3, 0], [0, 0, 2]],
            h * c / 2.0,
            12,
            [0, 12, 0, 0],
        ),
    ];
    let cpu = CpuBackend::new(None).unwrap();
    for (name, lattice, basis, m, volume, faces, index) in cases {
        let (domain, sites) = lattice_in(lattice, &basis, m);
        let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        assert_eq!(sites.len(), det as usize * basis.len(), "{name}: sites in the supercell");
        for backend in backends() {
            let out = PeriodicVoronoi::new(domain, &sites).faces(true).backend(backend).compute().unwrap();
            let what = format!("{name}, {}", backend.kind());
            for (i, v) in out.cells.volume.iter().enumerate() {
                assert!((v - volume).abs() < 1e-6 * volume, "{what}: cell {i} volume {v} against {volume}");
            }
            let counts = face_counts(&out);
            assert!(counts.iter().all(|&f| f == faces), "{what}: faces {counts:?}, not {faces}");
            // The Voronoi index with no threshold: the lattice's vertices
            // where more than three cells meet are one point.
            let out = PeriodicVoronoi::new(domain, &sites).backend(backend).compute_with_polyhedra(&cpu).unwrap();
            let q = ParticleCells::of(sites.len(), out.cells.polyhedra().unwrap(), &IndexThresholds::default());
            for i in 0..sites.len() {
                assert_eq!(q.index[i][..4], index, "{what}: cell {i}'s Voronoi index");
                assert_eq!((q.coordination[i], q.max_face_order[i]), (faces as u32, if name == "BCC" { 6 } else { 4 }));
            }
        }
    }
}

/// A perfect icosahedral cluster in a triclinic cell among particles kept
/// away from it: the centre's cell is the regular dodecahedron, Voronoi
/// index <0,0,12,0>.
#[test]
fn an_icosahedral_cluster_gives_its_centre_twelve_pentagons() {
    let domain = PeriodicBox::lammps([0.0; 3], [6.0, 5.5, 5.0], [1.5, -1.0, 0.75]).unwrap();
    let centre = domain.cartesian([0.5; 3]);
    let g = (1.0 + 5.0f64.sqrt()) / 2.0;
    let scale = 1.0 / (1.0 + g * g).sqrt();
    let mut sites = vec![centre];
    for (a, b) in [(1.0, g), (1.0, -g), (-1.0, g), (-1.0, -g)] {
        for v in [[0.0, a, b], [a, b, 0.0], [b, 0.0, a]] {
            sites.push([0, 1, 2].map(|k| centre[k] + scale * v[k]));
        }
    }
    // Others at least 2.5 from the centre, which the dodecahedron (circumradius
    // 0.63) does not reach.
    for p in points::uniform(400, 331) {
        let q = domain.cartesian(p);
        if (0..3).map(|k| (q[k] - centre[k]).powi(2)).sum::<f64>().sqrt() > 2.5 {
            sites.push(q);
        }
    }
    // The dodecahedron of inradius 1/2: edge 1 / sqrt(5/2 + 11 sqrt(5) / 10).
    let edge = 1.0 / (2.5 + 1.1 * 5.0f64.sqrt()).sqrt();
    let volume = (15.0 + 7.0 * 5.0f64.sqrt()) / 4.0 * edge.powi(3);
    let cpu = CpuBackend::new(None).unwrap();
    for backend in backends() {
        let out = PeriodicVoronoi::new(domain, &sites).backend(backend).compute_with_polyhedra(&cpu).unwrap();
        assert!((out.cells.volume[0] - volume).abs() < 1e-6 * volume, "{}: {}", backend.kind(), out.cells.volume[0]);
        let q = ParticleCells::of(sites.len(), out.cells.polyhedra().unwrap(), &IndexThresholds::default());
        assert_eq!(q.index[0], [0, 0, 12, 0, 0, 0, 0, 0], "{}", backend.kind());
        assert_eq!((q.coordination[0], q.max_face_order[0]), (12, 5));
        // Twelve pentagons of edge `edge`.
        let area = 3.0 * (25.0 + 10.0 * 5.0f64.sqrt()).sqrt() * edge * edge;
        assert!((q.area[0] - area).abs() < 1e-6 * area, "{}: area {} against {area}", backend.kind(), q.area[0]);
        assert_eq!(out.cells.volume.len(), sites.len());
    }
}
