//! `cargo xtask bench cvd`: the paper's Table 1 layout. For the built-in
//! cube, torus and joint and each model of the models folder that is present (torus_8k,
//! bunny_10k, fandisk_26k, joint_31k with the paper's 5k, 10k, 15k, 35k
//! sites, uniform inside the mesh, fixed seed): k, k-NN time, clip time and
//! total for tet-cell and cell-tet, on the CPU and on Vulkan, E_vol and the
//! counters.
//!
//! Options: `--models-dir DIR` (default: `$CVD_MODELS` or `../shared/models`)
//! `--threads N` `--device D` `--repeat R` `--only NAME` `--json PATH`.

mod common;

use cvd::cpu::CpuBackend;
use cvd::timing::timed;
use cvd::{points, Backend, ClippedVoronoi, Pairing, Strategy, TetMesh};
use std::path::PathBuf;

struct Options {
    models_dir: PathBuf,
    threads: Option<usize>,
    device: Option<String>,
    repeat: usize,
    only: Option<String>,
    json: Option<String>,
}

fn options() -> Options {
    let mut o = Options {
        models_dir: common::default_models_dir(),
        threads: None,
        device: None,
        repeat: 3,
        only: None,
        json: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--models-dir" => o.models_dir = value().into(),
            "--threads" => o.threads = Some(value().parse().expect("--threads N")),
            "--device" => o.device = Some(value()),
            "--repeat" => o.repeat = value().parse().expect("--repeat N"),
            "--only" => o.only = Some(value()),
            "--json" => o.json = Some(value()),
            "--bench" => {}
            other => panic!("unknown option {other}"),
        }
    }
    o
}

#[derive(serde::Serialize)]
struct Row {
    model: String,
    tets: usize,
    sites: usize,
    strategy: Strategy,
    pairing: Pairing,
    backend: String,
    k: usize,
    knn_ms: f64,
    clip_ms: f64,
    total_ms: f64,
    wall_ms: f64,
    e_vol: f64,
    counters: cvd::Counters,
}

fn main() {
    let o = options();
    let cpu = CpuBackend::new(o.threads).expect("CPU backend");
    let vulkan = common::warm_vulkan(o.device.clone());
    let mut models: Vec<(String, TetMesh, usize)> = Vec::new();
    for name in ["cube", "torus", "joint"] {
        let mesh = cvd::mesher::models::builtin(name, None).expect("built-in model");
        models.push((name.into(), mesh, cvd::mesher::models::default_sites(name).expect("built-in model")));
    }
    for (name, sites) in [("torus_8k", 5000), ("bunny_10k", 10_000), ("fandisk_26k", 15_000), ("joint_31k", 35_000)] {
        let path = o.models_dir.join(format!("{name}.mesh"));
        if !path.exists() {
            println!("{} not found: skipped", path.display());
            continue;
        }
        match cvd::io::read_mesh(&path) {
            Ok(mesh) => models.push((name.into(), mesh, sites)),
            Err(e) => println!("{e}: skipped"),
        }
    }
    let mut backends: Vec<&dyn Backend> = vec![&cpu];
    if let Some(v) = &vulkan {
        backends.push(v);
    }
    println!(
        "{:<12} {:>7} {:>6} {:<8} {:<6} {:<30} {:>4} {:>9} {:>9} {:>9} {:>9} {:>9}  counters",
        "model", "|T|", "|X|", "strategy", "pairs", "backend", "k", "knn ms", "clip ms", "total ms", "wall ms", "E_vol"
    );
    let mut rows = Vec::new();
    for (name, mesh, n) in &models {
        if o.only.as_ref().is_some_and(|only| only != name) {
            continue;
        }
        let sites = points::in_mesh(mesh, *n, 2020);
        for backend in &backends {
            let runs = [
                (Strategy::TetCell, Pairing::Flood),
                (Strategy::TetCell, Pairing::Knn),
                (Strategy::CellTet, Pairing::Knn),
            ];
            for (strategy, pairing) in runs {
                let cv = ClippedVoronoi::new(mesh, &sites).strategy(strategy).pairing(pairing).backend(*backend);
                let mut best = timed(|| cv.compute().expect("compute"));
                for _ in 1..o.repeat {
                    let r = timed(|| cv.compute().expect("compute"));
                    if r.1 < best.1 {
                        best = r;
                    }
                }
                let (cells, wall) = best;
                let t = &cells.timings;
                let knn = t.get("grid") + t.get("knn") + t.get("site knn") + t.get("tet knn");
                let clip = t.get("cells") + t.get("clip") + t.get("second pass") + t.get("host pass");
                let row = Row {
                    model: name.clone(),
                    tets: mesh.tets.len(),
                    sites: *n,
                    strategy,
                    pairing,
                    backend: backend.name(),
                    k: cells.k,
                    knn_ms: knn * 1e3,
                    clip_ms: clip * 1e3,
                    total_ms: (knn + clip) * 1e3,
                    wall_ms: wall * 1e3,
                    e_vol: cells.e_vol,
                    counters: cells.counters,
                };
                println!(
                    "{:<12} {:>7} {:>6} {:<8} {:<6} {:<30} {:>4} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.2e}  pairs {} nonempty {} clips {} security-missed {} overflow {} broken {} second-pass {} unresolved {}",
                    row.model,
                    row.tets,
                    row.sites,
                    format!("{strategy:?}"),
                    format!("{pairing:?}"),
                    row.backend.chars().take(30).collect::<String>(),
                    row.k,
                    row.knn_ms,
                    row.clip_ms,
                    row.total_ms,
                    row.wall_ms,
                    row.e_vol,
                    row.counters.pairs,
                    row.counters.nonempty,
                    row.counters.clips,
                    row.counters.security_missed,
                    row.counters.overflows,
                    row.counters.broken,
                    row.counters.second_pass,
                    row.counters.unresolved
                );
                rows.push(row);
            }
        }
    }
    if let Some(path) = &o.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows).expect("json"))
            .unwrap_or_else(|e| panic!("{path}: {e}"));
        println!("wrote {path}");
    }
}
