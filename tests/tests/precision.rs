//! Precision relative to each cell, wherever the domain sits and whatever
//! its size: inputs that defeat absolute f32 coordinates (sites on a plane
//! or a line, tight clusters in a crowd, a thin plate, sites on the
//! domain's faces and edges, a graded set), each in a box, against the f64
//! reference clipper (which works relative to each site) — and the uniform
//! set also against voro++ (through `voro_rs`; its absolute tolerances make
//! it no oracle for cells 1e-4 of its box) — each also translated by 1e6
//! and scaled by 1e-6 and 1e6, on both backends.
//!
//! Every cell larger than 1e-3 of the mean volume must be within
//! [`VOLUME_TOL`] of its exact volume, relative to itself, and the volumes
//! must add up to the box's within [`E_VOL_TOL`]. The results do not depend
//! on where the domain is or how large it is. What remains is the kernels'
//! f32 arithmetic: each piece is integrated around itself with its vertices
//! moved onto their planes, so what is left is a vertex's own rounding
//! relative to the piece, `ε L / h` for a needle of length `L` and width
//! `h` lying oblique to the axes (docs/BENCHMARKS.md, Precision).

use cvd::{geom::points, Cells, ClippedVoronoi, TetMesh};
use cvd_tests::reference::clipped_cells;
use cvd_tests::{assert_no_validation_errors, backends, Placement};
use voro_rs::prelude::*;

/// Largest volume error of a cell, relative to the cell (measured: 2e-6
/// at most, on the needle-shaped cells around the 2e-3 cluster; 8e-7 on
/// the others).
const VOLUME_TOL: f64 = 5e-6;
/// Largest `|Σ V_i - V| / V` (the goal; measured: 4e-8 at most).
const E_VOL_TOL: f64 = 1e-7;
/// Largest centroid error, relative to the cell's size `V^(1/3)`
/// (measured: 8.5e-6 at most).
const CENTROID_TOL: f64 = 2e-5;

/// An input: sites in the box `[0, 1] x [0, 1] x [0, depth]`.
struct Case {
    name: &'static str,
    depth: f64,
    sites: Vec<[f64; 3]>,
}

/// The exact cells of `sites` clipped to the box `lo..hi`, by voro++:
/// volumes and centroids, in input order.
fn voro_cells(lo: [f64; 3], hi: [f64; 3], sites: &[[f64; 3]]) -> (Vec<f64>, Vec<[f64; 3]>) {
    let n = sites.len() as f64;
    let ext = [0, 1, 2].map(|a| hi[a] - lo[a]);
    let side = (ext[0] * ext[1] * ext[2] / n * 5.0).cbrt();
    let blocks = ext.map(|e| ((e / side).ceil() as i32).clamp(1, 64));
    let mut con = ContainerStd::new(lo, hi, blocks, [false; 3]);
    for (i, &p) in sites.iter().enumerate() {
        con.put(i as i32, p, 0.0);
    }
    assert_eq!(con.total_particles() as usize, sites.len(), "voro++ rejected a site");
    let mut volume = vec![f64::NAN; sites.len()];
    let mut centroid = vec![[f64::NAN; 3]; sites.len()];
    let mut l = LoopAll::of_container_std(&mut con);
    assert!(l.start());
    loop {
        let id = l.particle_id() as usize;
        let mut cell: VoroCellSgl = con.compute_cell(&mut l).unwrap_or_else(|| panic!("voro++ lost cell {id}"));
        volume[id] = cell.volume();
        let (c, p) = (cell.centroid(), l.position());
        centroid[id] = [c[0] + p[0], c[1] + p[1], c[2] + p[2]];
        if !l.inc() {
            break;
        }
    }
    assert!(volume.iter().all(|v| !v.is_nan()), "voro++ skipped a site");
    (volume, centroid)
}

/// `n` sites uniform in `lo..hi`.
fn box_points(n: usize, lo: [f64; 3], hi: [f64; 3], seed: u64) -> Vec<[f64; 3]> {
    points::uniform(n, seed).into_iter().map(|p| [0, 1, 2].map(|a| lo[a] + p[a] * (hi[a] - lo[a]))).collect()
}

fn cases() -> Vec<Case> {
    let unit = |n, seed| box_points(n, [0.0; 3], [1.0; 3], seed);
    let mut cluster = unit(1600, 1);
    cluster.extend(box_points(400, [0.4; 3], [0.402; 3], 2));
    let mut tight = unit(1000, 3);
    tight.extend(box_points(50, [0.7; 3], [0.7001; 3], 4));
    let plane = box_points(600, [0.0, 0.0, 0.5], [1.0, 1.0, 0.5], 5);
    let line = box_points(80, [0.0, 0.5, 0.5], [1.0, 0.5, 0.5], 6);
    let plate = box_points(600, [0.0; 3], [1.0, 1.0, 1e-3], 7);
    let mut faces = unit(500, 8);
    faces.extend(box_points(200, [0.0; 3], [0.0, 1.0, 1.0], 9));
    faces.extend(box_points(60, [0.0; 3], [0.0, 0.0, 1.0], 10));
    faces.push([0.0; 3]);
    // Spacing from 1/10 to 1/1000 of the box: three nested sets.
    let mut graded = unit(1000, 11);
    graded.extend(box_points(1000, [0.0; 3], [0.1; 3], 12));
    graded.extend(box_points(1000, [0.0; 3], [0.01; 3], 13));
    vec![
        Case { name: "uniform", depth: 1.0, sites: unit(2000, 14) },
        Case { name: "cluster of side 2e-3 in a crowd", depth: 1.0, sites: cluster },
        Case { name: "cluster of side 1e-4 in a crowd", depth: 1.0, sites: tight },
        Case { name: "sites on one plane", depth: 1.0, sites: plane },
        Case { name: "sites on one line", depth: 1.0, sites: line },
        Case { name: "plate 1:1000", depth: 1e-3, sites: plate },
        Case { name: "sites on faces and edges", depth: 1.0, sites: faces },
        Case { name: "graded 100x", depth: 1.0, sites: graded },
    ]
}

/// As given, then moved (see [`Placement`]).
const PLACEMENTS: [Placement; 4] = [Placement::NONE, Placement::MOVED[0], Placement::MOVED[1], Placement::MOVED[2]];

/// The mesh of the box `[0, 1]² x [0, depth]`, placed.
fn box_mesh(depth: f64, at: Placement) -> TetMesh {
    let mut mesh = TetMesh::cube(3);
    for v in &mut mesh.vertices {
        v[2] *= depth;
    }
    at.mesh(&mesh)
}

/// Worst errors of `cells` (in the placed frame) against the exact cells
/// of the unplaced sites: relative volume error over the cells above 1e-3
/// of the mean, and centroid error relative to the cell's size.
fn worst(cells: &Cells, at: Placement, vol: &[f64], centroid: &[[f64; 3]]) -> (f64, f64, usize) {
    let mean = vol.iter().sum::<f64>() / vol.len() as f64;
    let (mut dv, mut dc, mut worst_cell) = (0.0f64, 0.0f64, 0);
    for i in 0..vol.len() {
        if vol[i] <= 1e-3 * mean {
            continue;
        }
        let v = cells.volume[i] / at.scale.powi(3);
        let c = at.back(&cells.centroid[i]);
        let e = (v - vol[i]).abs() / vol[i];
        if e > dv {
            (dv, worst_cell) = (e, i);
        }
        let d = (0..3).map(|a| (c[a] - centroid[i][a]).powi(2)).sum::<f64>().sqrt() / vol[i].cbrt();
        dc = dc.max(d);
    }
    (dv, dc, worst_cell)
}

#[test]
fn cells_are_exact_relative_to_themselves_wherever_the_domain_is() {
    let mut failures = Vec::new();
    for case in cases() {
        let mesh = box_mesh(case.depth, PLACEMENTS[0]);
        let exact = clipped_cells(&mesh, &case.sites);
        if case.name == "uniform" {
            // The reference agrees with voro++ where voro++ is exact.
            let (vol, _) = voro_cells([0.0; 3], [1.0, 1.0, case.depth], &case.sites);
            let d = vol.iter().zip(&exact.0).map(|(a, b)| (a - b).abs() / a).fold(0.0, f64::max);
            assert!(d < 1e-10, "the reference and voro++ differ by {d:.2e}");
        }
        for at in PLACEMENTS {
            // The sites as placed (rounded to f64 there); the reference
            // gets them mapped back, so both see the same points (a scaling
            // moves them by 1e-16 of themselves: the unplaced result holds).
            let placed = at.points(&case.sites);
            let moved;
            let (vol, centroid) = if at.offset == 0.0 {
                (&exact.0, &exact.1)
            } else {
                let (seen_mesh, seen) = at.seen(&mesh, &case.sites);
                moved = clipped_cells(&seen_mesh, &seen);
                (&moved.0, &moved.1)
            };
            let mesh = box_mesh(case.depth, at);
            for backend in backends() {
                let cells = ClippedVoronoi::new(&mesh, &placed).backend(backend).compute().unwrap();
                let (dv, dc, i) = worst(&cells, at, vol, centroid);
                let what = format!("{} at {at:?} on {}", case.name, backend.name());
                let c = &cells.counters;
                let report = format!(
                    "{what}: volume {dv:.2e} (cell {i}), centroid {dc:.2e}, E_vol {:.2e}, unresolved {}",
                    cells.e_vol, c.unresolved
                );
                println!("{report}");
                assert_eq!(c.duplicate_sites, 0, "{what}");
                if dv > VOLUME_TOL || dc > CENTROID_TOL || cells.e_vol > E_VOL_TOL || c.unresolved > 0 {
                    failures.push(report);
                }
            }
        }
    }
    assert_no_validation_errors();
    assert!(failures.is_empty(), "{} runs out of tolerance:\n{}", failures.len(), failures.join("\n"));
}

/// A cell of 1e-9 of the domain keeps its volume to 1e-6 relative in the
/// fixed-point sums. The domain: a unit cube with one site, and far from it
/// a cube of side 3e-3 in tets of its cells' size, holding a lattice of 27
/// sites of spacing 1e-3: its corner cell is the cube `[0, 1e-3]³`.
#[test]
fn a_cell_of_1e_9_of_the_domain_keeps_its_volume() {
    let h = 1e-3;
    let mut mesh = TetMesh::cube(3);
    for v in &mut mesh.vertices {
        *v = v.map(|c| 3.0 * h * c);
    }
    let big = TetMesh::cube(2);
    let n = mesh.vertices.len() as u32;
    mesh.vertices.extend(big.vertices.iter().map(|v| [v[0] + 2.0, v[1], v[2]]));
    mesh.tets.extend(big.tets.iter().map(|t| t.map(|v| v + n)));
    let mut sites = Vec::new();
    for k in 0..3 {
        for j in 0..3 {
            for i in 0..3 {
                sites.push([i, j, k].map(|c| (c as f64 + 0.5) * h));
            }
        }
    }
    sites.push([2.5, 0.5, 0.5]);
    for backend in backends() {
        let cells = ClippedVoronoi::new(&mesh, &sites).backend(backend).compute().unwrap();
        let what = backend.name();
        let dv = (cells.volume[0] - h * h * h).abs() / (h * h * h);
        println!("{what}: corner cell {:e} ({dv:.2e} relative)", cells.volume[0]);
        assert!(dv <= 1e-6, "{what}: the corner cell's volume is {:e}", cells.volume[0]);
        let dc = (0..3).map(|a| (cells.centroid[0][a] - 0.5 * h).abs()).fold(0.0, f64::max) / h;
        assert!(dc <= 1e-6, "{what}: the corner cell's centroid is {:?}", cells.centroid[0]);
        assert!(cells.e_vol <= 1e-7, "{what}: E_vol {:e}", cells.e_vol);
    }
    assert_no_validation_errors();
}

/// Distinct f64 sites are never merged: two sites 1e-12 apart both get
/// cells (half of a slab each); two whose difference is below what the
/// kernels' `hi + lo` pairs hold (2^-53 of the frame, next to a remainder
/// of 2^-26) are refused, by index; equal sites are duplicates.
#[test]
fn close_sites_are_kept_or_refused_by_name_never_merged() {
    let mesh = TetMesh::cube(2);
    let (a, b) = ([0.25, 0.5, 0.5], [0.75, 0.5, 0.5]);
    let close = [a, b, [0.5, 0.5, 0.5], [0.5 + 1e-12, 0.5, 0.5]];
    let cells = ClippedVoronoi::new(&mesh, &close).compute().unwrap();
    assert_eq!(cells.counters.duplicate_sites, 0);
    assert!(cells.volume[2] > 0.0 && cells.volume[3] > 0.0, "{:?}", cells.volume);
    // The two close sites share the slab between the bisectors with a
    // and b: x in [0.375, 0.625], split at their own bisector.
    let slab = cells.volume[2] + cells.volume[3];
    assert!((slab - 0.25).abs() <= 1e-6, "{slab}");
    assert!((cells.volume[2] - 0.125).abs() <= 1e-6, "{}", cells.volume[2]);

    let x = 0.5 + 2f64.powi(-26);
    let inseparable = [a, b, [x, 0.5, 0.5], [x + 2f64.powi(-53), 0.5, 0.5]];
    let err = ClippedVoronoi::new(&mesh, &inseparable).compute().unwrap_err().to_string();
    assert!(err.contains("sites 2") && err.contains("and 3") && err.contains("too close"), "{err}");

    let equal = [a, b, a];
    let cells = ClippedVoronoi::new(&mesh, &equal).compute().unwrap();
    assert_eq!(cells.counters.duplicate_sites, 1);
    assert_eq!(cells.volume[2], 0.0);
}

/// The shared models (`../shared/models`, when present) with 2 000 sites
/// (`CVD_PRECISION_SITES`) uniform inside, against the reference: every
/// cell larger than 1e-3 of the mean. Minutes in a debug build: run with
/// `cargo test --release -p cvd-tests --test precision -- --ignored --nocapture`
/// (docs/BENCHMARKS.md, Precision, records the output).
#[test]
#[ignore = "minutes of reference clipping; a measurement, run by hand"]
fn shared_models_against_the_reference() {
    for (name, mesh) in cvd_tests::shared_models() {
        let n = std::env::var("CVD_PRECISION_SITES").ok().and_then(|s| s.parse().ok()).unwrap_or(2000);
        let sites = points::in_mesh(&mesh, n, 2020);
        let (vol, centroid) = clipped_cells(&mesh, &sites);
        for backend in backends() {
            let cells = ClippedVoronoi::new(&mesh, &sites).backend(backend).compute().unwrap();
            let at = PLACEMENTS[0];
            let (dv, dc, i) = worst(&cells, at, &vol, &centroid);
            let mean = vol.iter().sum::<f64>() / vol.len() as f64;
            let over = |tol: f64| {
                (0..vol.len())
                    .filter(|&i| vol[i] > 1e-3 * mean && (cells.volume[i] - vol[i]).abs() > tol * vol[i])
                    .count()
            };
            println!(
                "{name}, {n} sites, on {}: worst volume {dv:.2e} (cell {i}), centroid {dc:.2e}, cells over 1e-6: {}, over 1e-5: {}, E_vol {:.2e}",
                backend.name(),
                over(1e-6),
                over(1e-5),
                cells.e_vol
            );
        }
    }
}
