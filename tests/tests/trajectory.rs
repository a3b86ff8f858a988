//! Trajectories: a frame that starts from the last frame's neighbour
//! lists (`PeriodicVoronoi::after`) gives the cells of a frame computed
//! afresh, bit for bit — volumes, centroids, faces with their neighbours
//! and shifts, polyhedra — while it reuses the lists of the particles that
//! moved little, and none where they moved far, the radii changed or the
//! cell did.

use cvd::{geom::points, CpuBackend, FrameLists, ParticleCells, PeriodicBox, PeriodicCells, PeriodicVoronoi};

/// A triclinic cell of about `n` unit volumes (LAMMPS's tilts).
fn cell(n: usize) -> PeriodicBox {
    let l = (n as f64).cbrt();
    PeriodicBox::lammps([0.0; 3], [l; 3], [0.2 * l, -0.1 * l, 0.15 * l]).unwrap()
}

/// `n` particles in `b`: a crowd with a tight cluster (one tenth, 1e-2 of
/// the cell's size across) in it.
fn particles(b: &PeriodicBox, n: usize, seed: u64) -> Vec<[f64; 3]> {
    let crowd = points::uniform(n - n / 10, seed);
    let blob = points::clustered(n / 10, 1, 0.01, seed + 1);
    crowd.iter().chain(&blob).map(|&s| b.cartesian(s)).collect()
}

/// Each particle moved by up to `step` along each axis (in any
/// direction; across the cell's sides too, unwrapped), kept `margin` of
/// the height inside any wall.
fn moved(b: &PeriodicBox, p: &[[f64; 3]], step: f64, seed: u64) -> Vec<[f64; 3]> {
    let d = points::uniform(p.len(), seed);
    p.iter()
        .zip(d)
        .map(|(x, d)| {
            let q = [0, 1, 2].map(|a| x[a] + step * (2.0 * d[a] - 1.0));
            let mut s = b.fractional(q);
            for a in (0..3).filter(|&a| !b.periodic()[a]) {
                s[a] = s[a].clamp(0.01, 0.99);
            }
            b.cartesian(s)
        })
        .collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// The same cells, bit for bit.
fn assert_same(a: &PeriodicCells, b: &PeriodicCells, what: &str) {
    assert_eq!(bits(&a.cells.volume), bits(&b.cells.volume), "{what}: volumes");
    let c = |x: &PeriodicCells| x.cells.centroid.iter().flat_map(|c| c.map(f64::to_bits)).collect::<Vec<_>>();
    assert_eq!(c(a), c(b), "{what}: centroids");
    match (a.cells.adjacency(), b.cells.adjacency()) {
        (Some(x), Some(y)) => {
            assert_eq!((&x.offsets, &x.neighbors, &x.shifts), (&y.offsets, &y.neighbors, &y.shifts), "{what}");
            assert_eq!(bits(&x.areas), bits(&y.areas), "{what}: face areas");
            assert_eq!(bits(&x.boundary), bits(&y.boundary), "{what}: walls");
        }
        (None, None) => {}
        _ => panic!("{what}: faces on one side only"),
    }
}

/// Runs `frames` through a trajectory that keeps its lists, each frame
/// against the same frame afresh; returns the cells reused per frame.
fn run(b: PeriodicBox, frames: &[Vec<[f64; 3]>], weights: Option<&[Vec<f64>]>, what: &str) -> Vec<usize> {
    let mut last: Option<FrameLists> = None;
    let mut reused = Vec::new();
    for (f, p) in frames.iter().enumerate() {
        let mut fresh = PeriodicVoronoi::new(b, p).faces(true);
        if let Some(w) = weights {
            fresh = fresh.weights(&w[f]);
        }
        let again = fresh.keep_lists(true).after(last.as_ref()).compute().unwrap();
        let fresh = fresh.compute().unwrap();
        assert_same(&again, &fresh, &format!("{what}, frame {f}"));
        assert!(fresh.lists.is_none() && fresh.reused == 0, "{what}: nothing kept unless asked");
        let lists = again.lists.expect("the lists kept");
        assert_eq!(lists.len(), p.len());
        reused.push(again.reused);
        last = Some(lists);
    }
    println!("{what}: reused {reused:?} of {}", frames[0].len());
    reused
}

#[test]
fn frames_from_the_last_frames_lists_are_the_frames_computed_afresh() {
    let n = 3000;
    let b = cell(n);
    let mut frames = vec![particles(&b, n, 1)];
    // Small steps (a few hundredths of the spacing), then a jump of two
    // spacings, then small steps again.
    for (f, step) in [0.02, 0.02, 0.03, 2.0, 0.02, 0.02].into_iter().enumerate() {
        let next = moved(&b, frames.last().unwrap(), step, 10 + f as u64);
        frames.push(next);
    }
    let reused = run(b, &frames, None, "triclinic");
    assert_eq!(reused[0], 0, "the first frame has no lists to start from");
    // The crowd's lists (nine tenths) hold; the cluster's particles moved
    // many times their spacing.
    for f in [1, 2, 3, 6] {
        assert!(reused[f] > n * 8 / 10, "frame {f}: {} of {n} reused", reused[f]);
    }
    // The jump certifies no list, and keeps no spare neighbours: the
    // frame after it has none to reuse.
    assert_eq!(reused[4..6], [0, 0], "a jump of two spacings");
}

#[test]
fn particles_crossing_the_sides_keep_their_neighbours() {
    // Every particle near a side, moving across it: the lists follow them
    // through their wrapped positions.
    let n = 2000;
    let b = cell(n);
    let l = (n as f64).cbrt();
    let start: Vec<[f64; 3]> = particles(&b, n, 3)
        .into_iter()
        .map(|p| {
            let s = b.fractional(p);
            b.cartesian([s[0] * 0.02 + 0.99, s[1], s[2] * 0.02 - 0.01])
        })
        .collect();
    // The particles are dense there (a spacing of about 0.08): steps of a
    // twentieth of it.
    let frames: Vec<Vec<[f64; 3]>> = (0..4)
        .map(|f| start.iter().map(|p| [p[0] + 3e-4 * l * f as f64, p[1], p[2] + 1e-3 * f as f64]).collect())
        .collect();
    let wrapped = |p: &[[f64; 3]]| PeriodicVoronoi::new(b, p).compute().unwrap().sites;
    let (first, last) = (wrapped(&frames[0]), wrapped(&frames[3]));
    let crossed = first.iter().zip(&last).filter(|(a, b)| (0..3).any(|k| (a[k] - b[k]).abs() > 0.5 * l)).count();
    assert!(crossed > n / 50, "{crossed} particles crossed a side");
    let reused = run(b, &frames, None, "across the sides");
    assert!(reused[1..].iter().all(|&r| r > n * 8 / 10), "{reused:?}");
}

#[test]
fn walls_radii_and_changed_cells() {
    let n = 2000;
    let slab = cell(n).with_periodic([true, true, false]);
    let mut frames = vec![particles(&slab, n, 5)];
    for f in 0..3 {
        let next = moved(&slab, frames.last().unwrap(), 0.02, 20 + f);
        frames.push(next);
    }
    let reused = run(slab, &frames, None, "slab");
    assert!(reused[1..].iter().all(|&r| r > n * 8 / 10), "{reused:?}");
    // Radii: the same on frames 0-1 and 2-3, changed at 2.
    let r = points::uniform(n, 7);
    let radii = |s: f64| r.iter().map(|x| (0.3 + 0.2 * x[0] * s).powi(2)).collect::<Vec<f64>>();
    let weights = [radii(1.0), radii(1.0), radii(1.5), radii(1.5)];
    let reused = run(slab, &frames, Some(&weights), "slab with radii");
    assert!(reused[1] > n * 8 / 10 && reused[3] > n * 8 / 10, "{reused:?}");
    assert_eq!(reused[2], 0, "other radii: no list is reused");
    // Another cell: none either.
    let b = cell(n);
    let p = &frames[0];
    let first = PeriodicVoronoi::new(b, p).keep_lists(true).compute().unwrap();
    let bigger = PeriodicBox::lammps([0.0; 3], [1.01 * (n as f64).cbrt(); 3], [0.0; 3]).unwrap();
    let other = PeriodicVoronoi::new(bigger, p).keep_lists(true).after(first.lists.as_ref()).compute().unwrap();
    assert_eq!(other.reused, 0);
}

#[test]
fn particle_quantities_from_reused_lists_are_the_same() {
    // The per-particle path (polyhedra, Voronoi index) through reuse.
    let n = 2000;
    let b = cell(n).with_periodic([true, false, true]);
    let cpu = CpuBackend::new(None).unwrap();
    let a = particles(&b, n, 9);
    let c = moved(&b, &a, 0.02, 30);
    let first = PeriodicVoronoi::new(b, &a).faces(true).keep_lists(true).compute_with_polyhedra(&cpu).unwrap();
    let again = PeriodicVoronoi::new(b, &c)
        .faces(true)
        .keep_lists(true)
        .after(first.lists.as_ref())
        .compute_with_polyhedra(&cpu)
        .unwrap();
    let fresh = PeriodicVoronoi::new(b, &c).faces(true).compute_with_polyhedra(&cpu).unwrap();
    assert!(again.reused > n * 8 / 10, "{}", again.reused);
    assert_same(&again, &fresh, "polyhedra");
    let of = |c: &PeriodicCells| ParticleCells::of(n, c.cells.polyhedra().unwrap(), &Default::default());
    let (x, y) = (of(&again), of(&fresh));
    assert_eq!((x.index, x.coordination), (y.index, y.coordination));
    assert_eq!(bits(&x.area), bits(&y.area));
}

#[test]
fn one_particle_and_walls_everywhere_keep_their_lists_too() {
    // One particle in a box with walls on every side: its only other
    // points are its mirrors. And two particles, periodic.
    let b = PeriodicBox::new([0.0; 3], [1.0, 2.0, 3.0]).unwrap().with_periodic([false; 3]);
    let one = [[0.3, 0.9, 1.1]];
    let first = PeriodicVoronoi::new(b, &one).keep_lists(true).compute().unwrap();
    let again =
        PeriodicVoronoi::new(b, &[[0.31, 0.9, 1.1]]).keep_lists(true).after(first.lists.as_ref()).compute().unwrap();
    let fresh = PeriodicVoronoi::new(b, &[[0.31, 0.9, 1.1]]).compute().unwrap();
    assert_eq!(bits(&again.cells.volume), bits(&fresh.cells.volume));
    assert!((again.cells.volume[0] - 6.0).abs() < 6e-6, "the whole box: {}", again.cells.volume[0]);
    let b = PeriodicBox::new([0.0; 3], [1.0; 3]).unwrap();
    let two = [[0.2, 0.2, 0.2], [0.7, 0.6, 0.8]];
    let first = PeriodicVoronoi::new(b, &two).keep_lists(true).compute().unwrap();
    let again = PeriodicVoronoi::new(b, &two).keep_lists(true).after(first.lists.as_ref()).compute().unwrap();
    let fresh = PeriodicVoronoi::new(b, &two).compute().unwrap();
    assert_eq!(bits(&again.cells.volume), bits(&fresh.cells.volume));
}
