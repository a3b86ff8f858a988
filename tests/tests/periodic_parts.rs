//! A periodic box in parts (`PeriodicVoronoi::compute_in_parts`): ranks
//! that each hold a run of the input rows, and only the sites near their
//! blocks, give every cell to the bit as the whole diagram in one process
//! — volumes, centroids, energies, faces with their neighbours, shifts and
//! walls — for 1 to 5 ranks (threads of one process here; MPI's ranks in
//! `cli/tests/mpi.rs`), on a crowd with a tight cluster in a triclinic
//! cell, a lattice (every distance a tie), a slab with walls and a box
//! with duplicated sites; and no rank holds all the sites. Lloyd and
//! L-BFGS in parts (`PeriodicInParts`) take the one process's steps: the
//! same sites and energies, to the bit. Power cells (weights) in parts are
//! the one process's too, and so is optimal transport in parts (each rank
//! its rows of the weights; the Laplacian's neighbours across ranks).

use cvd::backends::distributed::{InProcess, Reduce};
use cvd::cvt::periodic::PeriodicInParts;
use cvd::cvt::transport::{Transport, TransportRun};
use cvd::cvt::{CvtRun, Optimizer};
use cvd::diagram::periodic_parts::PartsReport;
use cvd::{geom::points, CpuBackend, IndexThresholds, ParticleCells, PeriodicBox, PeriodicCells, PeriodicVoronoi};

/// A crowd with a tight cluster (one tenth, 1e-2 of the cell across).
fn crowd(b: &PeriodicBox, n: usize, seed: u64) -> Vec<[f64; 3]> {
    let crowd = points::uniform(n - n / 10, seed);
    let blob = points::clustered(n / 10, 1, 0.01, seed + 1);
    crowd.iter().chain(&blob).map(|&s| b.cartesian(s)).collect()
}

/// `job` on `ranks` ranks (threads of this process), each with its run of
/// the rows of `sites` (rank `r` the rows `n r / ranks ..`) and a CPU
/// backend of one thread; what each rank returned, by rank.
fn on_ranks<T: Send>(
    sites: &[[f64; 3]],
    ranks: usize,
    job: impl Fn(&InProcess, &[[f64; 3]], &CpuBackend) -> T + Sync,
) -> Vec<T> {
    let n = sites.len();
    let job = &job;
    std::thread::scope(|scope| {
        let handles: Vec<_> = InProcess::ranks(ranks)
            .into_iter()
            .enumerate()
            .map(|(r, comm)| {
                let rows = &sites[n * r / ranks..n * (r + 1) / ranks];
                scope.spawn(move || job(&comm, rows, &CpuBackend::new(Some(1)).unwrap()))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

/// The diagram of `sites` (power cells with `weights`) in `ranks` parts.
fn in_parts(
    b: PeriodicBox,
    sites: &[[f64; 3]],
    weights: Option<&[f64]>,
    ranks: usize,
) -> Vec<(PeriodicCells, PartsReport)> {
    let n = sites.len();
    on_ranks(sites, ranks, |comm, rows, cpu| {
        let diagram = PeriodicVoronoi::new(b, rows).faces(true).backend(cpu);
        let first = n * comm.rank() / ranks;
        match weights {
            Some(w) => diagram.weights(&w[first..first + rows.len()]).compute_in_parts(comm),
            None => diagram.compute_in_parts(comm),
        }
        .unwrap()
    })
}

/// Every row of the parts, in order, equals the one process's, bit for bit.
fn same_cells(name: &str, whole: &PeriodicCells, parts: &[(PeriodicCells, PartsReport)], weighted: bool) {
    let a = whole.cells.adjacency().unwrap();
    let mut i = 0;
    for (part, report) in parts {
        assert_eq!(report.first, i as u64, "{name}: rank {}'s first row", report.rank);
        let p = part.cells.adjacency().unwrap();
        for r in 0..part.cells.volume.len() {
            let bits = |x: f64| x.to_bits();
            assert_eq!(bits(part.cells.volume[r]), bits(whole.cells.volume[i]), "{name}: site {i}'s volume");
            assert_eq!(part.cells.centroid[r].map(bits), whole.cells.centroid[i].map(bits), "{name}: site {i}");
            assert_eq!(bits(part.cells.energy[r]), bits(whole.cells.energy[i]), "{name}: site {i}'s energy");
            assert_eq!(part.offsets[r].map(bits), whole.offsets[i].map(bits), "{name}: site {i}'s offset");
            assert_eq!(part.sites[r].map(bits), whole.sites[i].map(bits), "{name}: site {i} wrapped");
            let (x, y) = (p.offsets[r]..p.offsets[r + 1], a.offsets[i]..a.offsets[i + 1]);
            assert_eq!(p.neighbors[x.clone()], a.neighbors[y.clone()], "{name}: site {i}'s neighbours");
            assert_eq!(p.shifts[x.clone()], a.shifts[y.clone()], "{name}: site {i}'s shifts");
            let areas = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(areas(&p.areas[x.clone()]), areas(&a.areas[y.clone()]), "{name}: site {i}'s areas");
            let normals = |v: &[[f64; 3]]| v.iter().map(|n| n.map(f64::to_bits)).collect::<Vec<_>>();
            assert_eq!(normals(&p.normals[x]), normals(&a.normals[y]), "{name}: site {i}'s normals");
            assert_eq!(bits(p.boundary[r]), bits(a.boundary[i]), "{name}: site {i}'s wall area");
            assert_eq!(p.boundary_vector[r].map(bits), a.boundary_vector[i].map(bits), "{name}: site {i}");
            i += 1;
        }
        // With weights, a part bounds the weights near a cell from those it
        // holds (all that can cut its cells), on a grid of its own: the
        // same cells, proved final after a few more or fewer grid walks.
        let (mut counted, mut expected) = (part.cells.counters, whole.cells.counters);
        if weighted {
            let (a, b) = (counted.walks as f64, expected.walks as f64);
            assert!((a - b).abs() <= 0.01 * b + 2.0, "{name}: {a} walks, one process {b}");
            (counted.walks, expected.walks) = (0, 0);
        }
        assert_eq!(counted, expected, "{name}: counters, rank {}", report.rank);
        assert_eq!((part.images, part.mirrors, part.wrapped), (whole.images, whole.mirrors, whole.wrapped), "{name}");
        assert_eq!(part.halo.to_bits(), whole.halo.to_bits(), "{name}: the halo");
        assert!((part.cells.total_volume - whole.cells.total_volume).abs() <= 1e-12 * whole.cells.total_volume);
    }
    assert_eq!(i, whole.cells.volume.len(), "{name}: every row");
}

fn check(name: &str, b: PeriodicBox, sites: &[[f64; 3]], most_ranks: usize) {
    check_weighted(name, b, sites, None, most_ranks)
}

fn check_weighted(name: &str, b: PeriodicBox, sites: &[[f64; 3]], weights: Option<&[f64]>, most_ranks: usize) {
    let cpu = CpuBackend::new(Some(1)).unwrap();
    let one = PeriodicVoronoi::new(b, sites).faces(true).backend(&cpu);
    let whole = match weights {
        Some(w) => one.weights(w).compute(),
        None => one.compute(),
    }
    .unwrap();
    for ranks in 1..=most_ranks {
        let parts = in_parts(b, sites, weights, ranks);
        same_cells(&format!("{name}, {ranks} ranks"), &whole, &parts, weights.is_some());
        let owned: u64 = parts.iter().map(|p| p.1.owned).sum();
        assert_eq!(owned, sites.len() as u64, "{name}: every site owned once");
        if ranks > 1 {
            for (_, r) in &parts {
                assert!(r.held < sites.len() as u64 + whole.images as u64, "{name}: rank {} holds {}", r.rank, r.held);
                assert!(r.owned < sites.len() as u64, "{name}: rank {} owns every site", r.rank);
                // Its grid's table: a window of the whole grid, never left.
                assert_eq!(r.windows_dropped, 0, "{name}: rank {}", r.rank);
                assert!(r.grid_cells[0] <= r.grid_cells[1], "{name}: rank {}: {:?}", r.rank, r.grid_cells);
            }
        }
        if ranks >= 3 {
            let held: u64 = parts.iter().map(|p| p.1.grid_cells[0]).sum();
            let whole_grid: u64 = parts.iter().map(|p| p.1.grid_cells[1]).sum();
            assert!(held < whole_grid, "{name}, {ranks} ranks: every rank's table the whole grid ({held} cells)");
        }
    }
}

#[test]
fn a_crowd_with_a_cluster_in_a_triclinic_cell_in_parts_is_the_one_process_diagram() {
    let n = 6000;
    let l = (n as f64).cbrt();
    let b = PeriodicBox::lammps([0.0; 3], [l; 3], [0.2 * l, -0.1 * l, 0.15 * l]).unwrap();
    let mut sites = crowd(&b, n, 5);
    // Some given outside the cell (wrapped), and a few duplicated.
    for i in (0..n).step_by(97) {
        sites[i] = b.shifted(sites[i], [1, -2, 0]);
    }
    for i in (1..n).step_by(501) {
        sites[i] = sites[i - 1];
    }
    check("crowd", b, &sites, 5);
}

#[test]
fn a_lattice_in_parts_is_the_one_process_diagram() {
    // FCC, 12^3 cells: every site's neighbours at equal distances.
    let m = 12;
    let b = PeriodicBox::new([0.0; 3], [m as f64; 3]).unwrap();
    let mut sites = Vec::new();
    for z in 0..m {
        for y in 0..m {
            for x in 0..m {
                for o in [[0.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.5, 0.0, 0.5], [0.0, 0.5, 0.5]] {
                    sites.push([x as f64 + o[0], y as f64 + o[1], z as f64 + o[2]]);
                }
            }
        }
    }
    check("fcc", b, &sites, 4);
}

#[test]
fn a_slab_with_walls_in_parts_is_the_one_process_diagram() {
    let n = 4000;
    let b = PeriodicBox::new([0.0; 3], [20.0, 20.0, 10.0]).unwrap().with_periodic([true, true, false]);
    let sites: Vec<[f64; 3]> = points::uniform(n, 8).iter().map(|p| b.cartesian(*p)).collect();
    check("slab", b, &sites, 3);
}

#[test]
fn power_cells_in_parts_are_the_one_process_cells() {
    // Polydisperse particles (radii 0.3 to 1.2 of the spacing, weights r²,
    // as voro++'s radical cells) in a triclinic cell with a cluster, and
    // in a slab with walls.
    let n = 5000;
    let l = (n as f64).cbrt();
    let b = PeriodicBox::lammps([0.0; 3], [l; 3], [0.15 * l, 0.1 * l, -0.2 * l]).unwrap();
    let sites = crowd(&b, n, 21);
    let radii = |n: usize, seed: u64| -> Vec<f64> {
        points::uniform(n, seed).iter().map(|p| (0.3 + 0.9 * p[0]).powi(2)).collect()
    };
    let w = radii(n, 22);
    check_weighted("power crowd", b, &sites, Some(&w), 4);
    let slab = PeriodicBox::new([0.0; 3], [18.0, 16.0, 9.0]).unwrap().with_periodic([true, false, true]);
    let sites: Vec<[f64; 3]> = points::uniform(2500, 23).iter().map(|p| slab.cartesian(*p)).collect();
    check_weighted("power slab", slab, &sites, Some(&radii(2500, 24)), 3);
}

#[test]
fn power_cells_of_drifting_weights_in_parts_are_the_one_process_cells() {
    // Weights drifting across a cube, noisy, over a few spacings² and then
    // far wider (many cells emptied): each part bounds its points' weights
    // from the one process's grid of largest weights. (The halo grows with
    // the weights' range: a rank may hold every point.)
    let cube = PeriodicBox::new([0.0; 3], [16.0; 3]).unwrap();
    let sites = crowd(&cube, 4000, 25);
    let noise = points::uniform(sites.len(), 26);
    let cpu = CpuBackend::new(Some(1)).unwrap();
    for spread in [0.5, 1.5, 4.0, 60.0] {
        let w: Vec<f64> =
            sites.iter().zip(&noise).map(|(p, e)| spread * (p[0] / 16.0 + 0.5 * p[2] / 16.0 + e[0])).collect();
        let whole = PeriodicVoronoi::new(cube, &sites).faces(true).backend(&cpu).weights(&w).compute().unwrap();
        assert!(whole.cells.counters.empty_cells > 0 || spread < 10.0, "spread {spread}: some cells emptied");
        for ranks in 2..=4 {
            let parts = in_parts(cube, &sites, Some(&w), ranks);
            same_cells(&format!("drift {spread}, {ranks} ranks"), &whole, &parts, true);
        }
    }
}

#[test]
fn ranks_that_read_no_rows_take_part_all_the_same() {
    // All rows read by one rank (or by the last), the others none: a
    // frame of few particles, or ids that sort away from a rank.
    let b = PeriodicBox::new([0.0; 3], [8.0; 3]).unwrap();
    let sites: Vec<[f64; 3]> = points::uniform(500, 12).iter().map(|p| b.cartesian(*p)).collect();
    let cpu = CpuBackend::new(Some(1)).unwrap();
    let whole = PeriodicVoronoi::new(b, &sites).faces(true).backend(&cpu).compute().unwrap();
    for reader in [0, 2] {
        let parts: Vec<(PeriodicCells, PartsReport)> = std::thread::scope(|scope| {
            let handles: Vec<_> = InProcess::ranks(3)
                .into_iter()
                .enumerate()
                .map(|(r, comm)| {
                    let rows: &[[f64; 3]] = if r == reader { &sites } else { &[] };
                    scope.spawn(move || {
                        let cpu = CpuBackend::new(Some(1)).unwrap();
                        PeriodicVoronoi::new(b, rows).faces(true).backend(&cpu).compute_in_parts(&comm).unwrap()
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        same_cells(&format!("rows on rank {reader} only"), &whole, &parts, false);
        assert_eq!(parts.iter().map(|p| p.1.owned).sum::<u64>(), 500, "every cell built once");
    }
}

/// `iterations` of `optimizer` in one process and in 1 to `most_ranks`
/// parts: the same sites, energies and counters, to the bit (the sums
/// the optimisers take are exact, so their order does not matter).
fn same_steps(name: &str, b: PeriodicBox, sites: &[[f64; 3]], most_ranks: usize) {
    let cpu = CpuBackend::new(Some(1)).unwrap();
    for optimizer in [Optimizer::Lloyd, Optimizer::Lbfgs] {
        // The one process's iterations with faces, the parts' without.
        let one = PeriodicVoronoi::new(b, sites).faces(true).backend(&cpu);
        let whole = optimizer.run(&one, 3, &mut |_, _| {}).unwrap();
        assert_eq!(whole.iterations.len(), 3);
        let bits = |run: &CvtRun| run.iterations.iter().map(|i| i.energy.to_bits()).collect::<Vec<_>>();
        for ranks in 1..=most_ranks {
            let what = format!("{name}, {}, {ranks} ranks", optimizer.name());
            let runs = on_ranks(sites, ranks, |comm, rows, cpu| {
                let diagram = PeriodicInParts::new(PeriodicVoronoi::new(b, rows).backend(cpu), comm);
                optimizer.run(&diagram, 3, &mut |_, _| {}).unwrap()
            });
            let moved: Vec<[u64; 3]> = runs.iter().flat_map(|r| &r.sites).map(|p| p.map(f64::to_bits)).collect();
            let expected: Vec<[u64; 3]> = whole.sites.iter().map(|p| p.map(f64::to_bits)).collect();
            assert_eq!(moved.len(), expected.len(), "{what}: every site");
            if let Some(i) = (0..moved.len()).find(|&i| moved[i] != expected[i]) {
                panic!("{what}: site {i} moved to {:?}, in one process to {:?}", runs_site(&runs, i), whole.sites[i]);
            }
            for run in &runs {
                assert_eq!(bits(run), bits(&whole), "{what}: the energies");
                let counts =
                    |r: &CvtRun| r.iterations.iter().map(|i| (i.empty_cells, i.unresolved)).collect::<Vec<_>>();
                assert_eq!(counts(run), counts(&whole), "{what}: empty cells and unresolved");
            }
        }
        let e = &whole.iterations;
        assert!(e[2].energy < e[0].energy, "{name}: {} did not lower the energy", optimizer.name());
    }
}

fn runs_site(runs: &[CvtRun], i: usize) -> [f64; 3] {
    runs.iter().flat_map(|r| &r.sites).nth(i).copied().unwrap_or_default()
}

#[test]
fn lloyd_and_lbfgs_in_parts_take_the_one_process_steps() {
    let n = 3000;
    let l = (n as f64).cbrt();
    let b = PeriodicBox::lammps([0.0; 3], [l; 3], [0.2 * l, -0.1 * l, 0.15 * l]).unwrap();
    let mut sites = crowd(&b, n, 11);
    for i in (1..n).step_by(501) {
        sites[i] = sites[i - 1];
    }
    same_steps("crowd", b, &sites, 4);
    let slab = PeriodicBox::new([0.0; 3], [15.0, 15.0, 8.0]).unwrap().with_periodic([true, true, false]);
    let sites: Vec<[f64; 3]> = points::uniform(1800, 3).iter().map(|p| slab.cartesian(*p)).collect();
    same_steps("slab", slab, &sites, 3);
}

#[test]
fn optimal_transport_in_parts_finds_the_one_process_weights() {
    // Capacities spanning a factor 4 on sites in a triclinic cell: the
    // same weights, steps and masses, to the bit.
    let n = 2000;
    let l = (n as f64).cbrt();
    let b = PeriodicBox::lammps([0.0; 3], [l; 3], [0.1 * l, 0.2 * l, -0.1 * l]).unwrap();
    let sites: Vec<[f64; 3]> = points::uniform(n, 41).iter().map(|p| b.cartesian(*p)).collect();
    let capacities: Vec<f64> = points::uniform(n, 42).iter().map(|p| 1.0 + 3.0 * p[0]).collect();
    let cpu = CpuBackend::new(Some(1)).unwrap();
    let one = Transport::new(PeriodicVoronoi::new(b, &sites).backend(&cpu)).capacities(&capacities);
    let whole = one.solve(&mut |_| true).unwrap();
    assert!(whole.converged, "one process: {}", whole.stopped);
    let steps = |r: &TransportRun| {
        r.steps
            .iter()
            .map(|s| (s.max_error.to_bits(), s.step.to_bits(), s.cg_iterations, s.diagrams))
            .collect::<Vec<_>>()
    };
    for ranks in 2..=4 {
        let runs = on_ranks(&sites, ranks, |comm, rows, cpu| {
            let first = n * comm.rank() / ranks;
            let diagram = PeriodicInParts::new(PeriodicVoronoi::new(b, rows).backend(cpu), comm);
            Transport::new(diagram).capacities(&capacities[first..first + rows.len()]).solve(&mut |_| true).unwrap()
        });
        for run in &runs {
            assert_eq!(steps(run), steps(&whole), "{ranks} ranks: the Newton steps");
            assert_eq!(run.stopped, whole.stopped);
        }
        let weights: Vec<u64> = runs.iter().flat_map(|r| &r.weights).map(|w| w.to_bits()).collect();
        let expected: Vec<u64> = whole.weights.iter().map(|w| w.to_bits()).collect();
        assert!(weights == expected, "{ranks} ranks: the weights differ from one process's");
        let masses: Vec<u64> = runs.iter().flat_map(|r| &r.cells.volume).map(|m| m.to_bits()).collect();
        assert!(masses == whole.cells.volume.iter().map(|m| m.to_bits()).collect::<Vec<_>>(), "{ranks} ranks: masses");
    }
}

#[test]
fn the_voronoi_index_in_parts_is_the_one_process_index() {
    // Each cell's polyhedron built and measured on the rank that built the
    // cell: the same areas, coordinations and indices as one process's
    // polyhedra, on a crowd with a cluster in a triclinic cell, a slab with
    // walls (a wall one face) and power cells; OVITO's thresholds on.
    let thresholds = IndexThresholds { relative_face: 0.01, ..Default::default() };
    let n = 3000;
    let l = (n as f64).cbrt();
    let tilted = PeriodicBox::lammps([0.0; 3], [l; 3], [0.2 * l, 0.1 * l, -0.1 * l]).unwrap();
    let slab = PeriodicBox::new([0.0; 3], [14.0, 15.0, 13.0]).unwrap().with_periodic([true, true, false]);
    let radii: Vec<f64> = points::uniform(n, 62).iter().map(|p| (0.3 + 0.5 * p[0]).powi(2)).collect();
    let cases = [
        ("crowd", tilted, crowd(&tilted, n, 61), None),
        ("slab", slab, points::uniform(n, 63).iter().map(|p| slab.cartesian(*p)).collect(), None),
        ("power", tilted, crowd(&tilted, n, 64), Some(radii)),
    ];
    let cpu = CpuBackend::new(Some(1)).unwrap();
    for (name, b, sites, weights) in &cases {
        let one = PeriodicVoronoi::new(*b, sites).backend(&cpu);
        let one = match weights {
            Some(w) => one.weights(w),
            None => one,
        };
        let whole = one.compute_with_polyhedra(&cpu).unwrap();
        let expected = ParticleCells::of(n, whole.cells.polyhedra().unwrap(), &thresholds);
        assert!(expected.coordination.iter().filter(|&&c| c > 0).count() > n * 9 / 10, "{name}: cells counted");
        for ranks in [2, 3] {
            let parts = on_ranks(sites, ranks, |comm, rows, cpu| {
                let first = n * comm.rank() / ranks;
                let diagram = PeriodicVoronoi::new(*b, rows).backend(cpu);
                let diagram = match weights {
                    Some(w) => diagram.weights(&w[first..first + rows.len()]),
                    None => diagram,
                };
                diagram.compute_in_parts_with_index(comm, cpu, &thresholds).unwrap()
            });
            let area: Vec<u64> = parts.iter().flat_map(|p| &p.particles.area).map(|a| a.to_bits()).collect();
            assert!(area == expected.area.iter().map(|a| a.to_bits()).collect::<Vec<_>>(), "{name}, {ranks}: areas");
            let counts = |q: &ParticleCells| (q.coordination.clone(), q.index.clone(), q.max_face_order.clone());
            let got = parts.iter().fold((Vec::new(), Vec::new(), Vec::new()), |mut acc, p| {
                let c = counts(&p.particles);
                acc.0.extend(c.0);
                acc.1.extend(c.1);
                acc.2.extend(c.2);
                acc
            });
            assert!(got == counts(&expected), "{name}, {ranks} ranks: coordination, index or orders differ");
            // Every cell's polyhedron once, on the rank that built it.
            // with its cell's numbers.
            let built: usize = parts.iter().map(|p| p.built.polyhedra.len()).sum();
            assert_eq!(built, whole.cells.polyhedra().unwrap().len(), "{name}, {ranks} ranks: polyhedra");
            for p in &parts {
                for (poly, &(volume, centroid, _)) in p.built.polyhedra.iter().zip(&p.built.numbers) {
                    let i = poly.site as usize;
                    assert_eq!(volume.to_bits(), whole.cells.volume[i].to_bits(), "{name}: site {i}'s volume");
                    assert_eq!(centroid.map(f64::to_bits), whole.cells.centroid[i].map(f64::to_bits), "{name}");
                }
            }
        }
    }
}

/// On a device (lavapipe here) each rank's part is one windowed whole-cell
/// job, its lists' distances read back for the halo's certificate: every
/// row is the device's one-process cell to the bit — plain and power
/// cells, a cluster and duplicates in a triclinic cell, and a slab with
/// walls.
#[test]
fn a_periodic_box_in_parts_on_vulkan_is_its_one_process_diagram() {
    let Some(vulkan) = cvd_tests::vulkan() else { return };
    let n = 6000;
    let l = (n as f64).cbrt();
    let b = PeriodicBox::lammps([0.0; 3], [l; 3], [0.2 * l, -0.1 * l, 0.15 * l]).unwrap();
    let mut sites = crowd(&b, n, 31);
    for i in (1..n).step_by(401) {
        sites[i] = sites[i - 1];
    }
    let radii: Vec<f64> = points::uniform(n, 32).iter().map(|p| (0.3 + 0.9 * p[0]).powi(2)).collect();
    let slab = PeriodicBox::new([0.0; 3], [20.0, 20.0, 10.0]).unwrap().with_periodic([true, false, true]);
    let slab_sites: Vec<[f64; 3]> = points::uniform(4000, 33).iter().map(|p| slab.cartesian(*p)).collect();
    // A name, the box, its sites and their weights.
    type Case<'a> = (&'a str, PeriodicBox, &'a [[f64; 3]], Option<&'a [f64]>);
    let cases: [Case; 3] =
        [("crowd", b, &sites, None), ("power crowd", b, &sites, Some(&radii)), ("slab", slab, &slab_sites, None)];
    for (name, b, sites, weights) in cases {
        // (A device takes tet-cell by default; the parts whole cells.)
        let one = PeriodicVoronoi::new(b, sites).faces(true).backend(vulkan).strategy(cvd::Strategy::Whole);
        let whole = match weights {
            Some(w) => one.weights(w).compute(),
            None => one.compute(),
        }
        .unwrap();
        for ranks in [1, 2, 3] {
            let n = sites.len();
            let parts = on_ranks(sites, ranks, |comm, rows, _| {
                let diagram = PeriodicVoronoi::new(b, rows).faces(true).backend(vulkan);
                let first = n * comm.rank() / ranks;
                match weights {
                    Some(w) => diagram.weights(&w[first..first + rows.len()]).compute_in_parts(comm),
                    None => diagram.compute_in_parts(comm),
                }
                .unwrap()
            });
            same_cells(&format!("{name} on vulkan, {ranks} ranks"), &whole, &parts, weights.is_some());
            for (_, r) in &parts {
                assert_eq!(r.windows_dropped, 0, "{name}, {ranks} ranks: rank {}", r.rank);
                if ranks > 1 {
                    assert!(r.held < (n + whole.images) as u64, "{name}, {ranks} ranks: rank {} holds all", r.rank);
                }
            }
        }
        // The particles' quantities: the device's cells, each polyhedron
        // from a run on the CPU, as one process takes them.
        let thresholds = IndexThresholds { relative_face: 0.01, ..Default::default() };
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let one = PeriodicVoronoi::new(b, sites).backend(vulkan);
        let one = match weights {
            Some(w) => one.weights(w).compute_with_polyhedra(&cpu),
            None => one.compute_with_polyhedra(&cpu),
        }
        .unwrap();
        let expected = ParticleCells::of(sites.len(), one.cells.polyhedra().unwrap(), &thresholds);
        let n = sites.len();
        let parts = on_ranks(sites, 2, |comm, rows, cpu| {
            let diagram = PeriodicVoronoi::new(b, rows).backend(vulkan);
            let first = n * comm.rank() / 2;
            let diagram = match weights {
                Some(w) => diagram.weights(&w[first..first + rows.len()]),
                None => diagram,
            };
            diagram.compute_in_parts_with_index(comm, cpu, &thresholds).unwrap()
        });
        let areas: Vec<u64> = parts.iter().flat_map(|p| &p.particles.area).map(|a| a.to_bits()).collect();
        assert!(areas == expected.area.iter().map(|a| a.to_bits()).collect::<Vec<_>>(), "{name}: areas");
        let index: Vec<_> = parts.iter().flat_map(|p| p.particles.index.iter().copied()).collect();
        assert!(index == expected.index, "{name}: Voronoi indices");
        let mut volumes = 0;
        for p in &parts {
            let rows = p.cells.cells.volume.iter().zip(&one.cells.volume[p.report.first as usize..]);
            assert!(rows.clone().all(|(a, b)| a.to_bits() == b.to_bits()), "{name}: the device's volumes");
            for (poly, &(volume, _, _)) in p.built.polyhedra.iter().zip(&p.built.numbers) {
                assert_eq!(volume.to_bits(), one.cells.volume[poly.site as usize].to_bits(), "{name}: {}", poly.site);
                volumes += 1;
            }
        }
        assert_eq!(volumes, one.cells.polyhedra().unwrap().len(), "{name}: every polyhedron once");
    }
    cvd_tests::assert_no_validation_errors();
}
