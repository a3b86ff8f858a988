//! `cargo xtask bench periodic`: periodic boxes against the same box
//! without periodicity, and against voro++'s periodic container.
//!
//! For each `--sites N` (default 35 000 and 1 000 000; uniform in the unit
//! cube, seed 1), alternated `--repeat R` times (default 3), best of each:
//! the diagram of the sites in the unit cube's mesh (`PeriodicBox::mesh`,
//! about a tet per site) without periodicity, the periodic diagram (the
//! same mesh with the sites' images), both on the CPU backend with
//! `--threads T` (default: all cores) and with one thread, and voro++'s
//! periodic container (`voro_rs`, one thread: it has no others) computing
//! every cell's volume and centroid. Prints the ratios and the images.
//! `--json PATH` writes the rows.

use cvd::exec::CpuBackend;
use cvd::{geom::points, Backend, ClippedVoronoi, PeriodicBox, PeriodicVoronoi};
use std::time::Instant;
use voro_rs::prelude::*;

struct Options {
    sites: Vec<usize>,
    repeat: usize,
    threads: Option<usize>,
    json: Option<String>,
}

fn options() -> Options {
    let mut o = Options { sites: vec![35_000, 1_000_000], repeat: 3, threads: None, json: None };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--sites" => o.sites = value().split(',').map(|s| s.parse().expect("--sites N,M,...")).collect(),
            "--repeat" => o.repeat = value().parse().expect("--repeat R"),
            "--threads" => o.threads = Some(value().parse().expect("--threads N")),
            "--json" => o.json = Some(value()),
            "--bench" => {}
            other => panic!("unknown option {other}"),
        }
    }
    o
}

/// voro++'s periodic cells of `sites` in the unit cube: the seconds, and
/// the volumes' sum.
fn voro(sites: &[[f64; 3]]) -> (f64, f64) {
    let clock = Instant::now();
    let blocks = ((sites.len() as f64 / 5.0).cbrt().ceil() as i32).max(1);
    let mut con = ContainerStd::new([0.0; 3], [1.0; 3], [blocks; 3], [true; 3]);
    for (i, &p) in sites.iter().enumerate() {
        con.put(i as i32, p, 0.0);
    }
    let mut total = 0.0;
    let mut centroid_sum = 0.0;
    let mut l = LoopAll::of_container_std(&mut con);
    if l.start() {
        loop {
            if let Some(mut cell) = con.compute_cell(&mut l) {
                let cell: &mut VoroCellSgl = &mut cell;
                total += cell.volume();
                centroid_sum += cell.centroid()[0];
            }
            if !l.inc() {
                break;
            }
        }
    }
    std::hint::black_box(centroid_sum);
    (clock.elapsed().as_secs_f64(), total)
}

fn main() {
    let o = options();
    let cpu = CpuBackend::new(o.threads).expect("CPU backend");
    let one = CpuBackend::new(Some(1)).expect("CPU backend");
    println!("CPU backend: {} threads; voro++ one thread", cpu.threads());
    let domain = PeriodicBox::unit();
    let mut rows = Vec::new();
    for &n in &o.sites {
        let sites = points::uniform(n, 1);
        let mesh = domain.mesh(n);
        let mut best = [f64::INFINITY; 5];
        let mut images = 0;
        let mut e_vol = [0.0f64; 2];
        for round in 0..o.repeat {
            let backends: [&dyn Backend; 2] = [&cpu, &one];
            for (b, backend) in backends.iter().enumerate() {
                let clock = Instant::now();
                let plain = ClippedVoronoi::new(&mesh, &sites).backend(*backend).compute().expect("diagram");
                best[2 * b] = best[2 * b].min(clock.elapsed().as_secs_f64());
                let clock = Instant::now();
                let periodic = PeriodicVoronoi::new(domain, &sites).backend(*backend).compute().expect("periodic");
                best[2 * b + 1] = best[2 * b + 1].min(clock.elapsed().as_secs_f64());
                images = periodic.images;
                e_vol = [plain.e_vol, periodic.cells.e_vol];
            }
            let (t, total) = voro(&sites);
            assert!((total - 1.0).abs() < 1e-6, "voro++'s cells fill {total} of the box");
            best[4] = best[4].min(t);
            println!("  {n} sites, round {}: done", round + 1);
        }
        println!(
            "{n} sites, {} tets, {images} images ({:.1} % of the sites): plain {:.3} s, periodic {:.3} s ({:.2}x); \
             one thread: plain {:.3} s, periodic {:.3} s ({:.2}x); voro++ periodic (one thread) {:.3} s: \
             periodic / voro++ {:.2} ({} threads), {:.2} (one); E_vol {:.1e} / {:.1e}",
            mesh.tets.len(),
            100.0 * images as f64 / n as f64,
            best[0],
            best[1],
            best[1] / best[0],
            best[2],
            best[3],
            best[3] / best[2],
            best[4],
            best[1] / best[4],
            cpu.threads(),
            best[3] / best[4],
            e_vol[0],
            e_vol[1]
        );
        rows.push(serde_json::json!({
            "sites": n, "tets": mesh.tets.len(), "images": images, "threads": cpu.threads(),
            "plain_s": best[0], "periodic_s": best[1], "plain_1_thread_s": best[2], "periodic_1_thread_s": best[3],
            "voro_periodic_s": best[4], "periodic_over_plain": best[1] / best[0],
            "periodic_over_voro": best[1] / best[4], "periodic_1_thread_over_voro": best[3] / best[4],
        }));
    }
    if let Some(path) = &o.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows).expect("json")).expect("write --json");
        println!("wrote {path}");
    }
}
