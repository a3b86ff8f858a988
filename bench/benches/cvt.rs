//! `cargo xtask bench cvt`: centroidal Voronoi tessellations. For each
//! model — the built-in torus and joint, `torus_8k` and `joint_31k` of the models
//! folder when present, and the paper's Joint (`paper_joint.tet`) with its
//! own 3000 sites (`paper_joint_3000.xyz`) — Lloyd and L-BFGS on each
//! backend: time per iteration and the energy after 5, 20 and the last
//! iteration (120 by default).
//!
//! Writes a chart of the energy against the iteration for both optimisers
//! per model and backend into `--plots DIR` (default `bench-results/`).
//!
//! Options: `--models-dir DIR` (default: `$CVD_MODELS` or `../shared/models`)
//! `--iterations N` `--threads N` `--device D` `--only NAME` `--json PATH`
//! `--plots DIR`.

mod common;

use cvd::cvt::CvtRun;
use cvd::cvt::SiteDiagram;
use cvd::exec::CpuBackend;
use cvd::{geom::points, Backend, ClippedVoronoi, TetMesh};
use cvd_io::Series;
use std::path::PathBuf;

struct Options {
    models_dir: PathBuf,
    iterations: usize,
    threads: Option<usize>,
    device: Option<String>,
    only: Option<String>,
    json: Option<String>,
    plots: PathBuf,
}

fn options() -> Options {
    let mut o = Options {
        models_dir: common::default_models_dir(),
        iterations: 120,
        threads: None,
        device: None,
        only: None,
        json: None,
        plots: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("bench-results"),
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--models-dir" => o.models_dir = value().into(),
            "--iterations" => o.iterations = value().parse().expect("--iterations N"),
            "--threads" => o.threads = Some(value().parse().expect("--threads N")),
            "--device" => o.device = Some(value()),
            "--only" => o.only = Some(value()),
            "--json" => o.json = Some(value()),
            "--plots" => o.plots = value().into(),
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
    backend: String,
    optimizer: &'static str,
    iterations: usize,
    ms_per_iteration: f64,
    total_s: f64,
    /// Energy of the diagram each iteration started from.
    energy: Vec<f64>,
}

/// The energy after `i` iterations (the last one's when the run stopped
/// early at a minimum).
fn energy_after(run: &CvtRun, i: usize) -> f64 {
    run.iterations.get(i).or(run.iterations.last()).map_or(f64::NAN, |it| it.energy)
}

fn main() {
    let o = options();
    let cpu = CpuBackend::new(o.threads).expect("CPU backend");
    let vulkan = common::warm_vulkan(o.device.clone());
    let mut models: Vec<(String, TetMesh, Vec<[f64; 3]>)> = Vec::new();
    for name in ["torus", "joint"] {
        let mesh = cvd::mesher::models::builtin(name, None).expect("built-in model");
        let sites = points::in_mesh(&mesh, cvd::mesher::models::default_sites(name).expect("built-in model"), 2020);
        models.push((name.into(), mesh, sites));
    }
    for (name, n) in [("torus_8k", 5000), ("joint_31k", 35_000)] {
        let path = o.models_dir.join(format!("{name}.mesh"));
        match cvd_io::read_mesh(&path) {
            Ok(mesh) => {
                let sites = points::in_mesh(&mesh, n, 2020);
                models.push((name.into(), mesh, sites));
            }
            Err(e) => println!("{e}: skipped"),
        }
    }
    let (tet, xyz) = (o.models_dir.join("paper_joint.tet"), o.models_dir.join("paper_joint_3000.xyz"));
    match (cvd_io::read_mesh(&tet), cvd_io::read_sites(&xyz)) {
        (Ok(mesh), Ok(sites)) => models.push(("paper_joint".into(), mesh, sites)),
        (Err(e), _) | (_, Err(e)) => println!("{e}: paper_joint skipped"),
    }
    let mut backends: Vec<&dyn Backend> = vec![&cpu];
    if let Some(v) = &vulkan {
        backends.push(v);
    }
    let n = o.iterations;
    println!(
        "{:<12} {:>7} {:>6} {:<30} {:<6} {:>10} {:>9} {:>12} {:>12} {:>12} {:>12}",
        "model",
        "|T|",
        "|X|",
        "backend",
        "opt",
        "ms/iter",
        "total s",
        "E(0)",
        "E(5)",
        "E(20)",
        format!("E({n})")
    );
    let mut rows = Vec::new();
    for (name, mesh, sites) in &models {
        if o.only.as_ref().is_some_and(|only| only != name) {
            continue;
        }
        for backend in &backends {
            let mut curves = Vec::new();
            for optimizer in ["lloyd", "lbfgs"] {
                let cv = ClippedVoronoi::new(mesh, sites).backend(*backend);
                let start = std::time::Instant::now();
                let run = match optimizer {
                    "lloyd" => cv.lloyd(n, &mut |_, _| {}),
                    _ => cv.lbfgs(n, &mut |_, _| {}),
                }
                .expect("CVT run");
                let total = start.elapsed().as_secs_f64();
                let done = run.iterations.len().max(1);
                let row = Row {
                    model: name.clone(),
                    tets: mesh.tets.len(),
                    sites: sites.len(),
                    backend: backend.name(),
                    optimizer,
                    iterations: run.iterations.len(),
                    ms_per_iteration: 1e3 * total / done as f64,
                    total_s: total,
                    energy: run.iterations.iter().map(|i| i.energy).collect(),
                };
                println!(
                    "{:<12} {:>7} {:>6} {:<30} {:<6} {:>10.2} {:>9.3} {:>12.6e} {:>12.6e} {:>12.6e} {:>12.6e}",
                    row.model,
                    row.tets,
                    row.sites,
                    row.backend.chars().take(30).collect::<String>(),
                    optimizer,
                    row.ms_per_iteration,
                    row.total_s,
                    energy_after(&run, 0),
                    energy_after(&run, 5),
                    energy_after(&run, 20),
                    energy_after(&run, n - 1),
                );
                curves.push((optimizer, row.energy.clone()));
                rows.push(row);
            }
            // Energy against iteration, both optimisers: bench-results/.
            let colours = [[200, 40, 40], [40, 80, 200]];
            let series: Vec<Series> =
                curves.iter().zip(colours).map(|((name, values), rgb)| Series { name, values, x: &[], rgb }).collect();
            let kind = if backend.name().starts_with("cpu") { "cpu" } else { "vulkan" };
            let path = o.plots.join(format!("cvt_{name}_{kind}.png"));
            match std::fs::create_dir_all(&o.plots)
                .map_err(|e| e.to_string())
                .and_then(|_| cvd_io::write_line_chart_png(&path, "cvt energy", &series).map_err(|e| e.to_string()))
            {
                Ok(()) => println!("wrote {}", path.display()),
                Err(e) => println!("{}: {e}", path.display()),
            }
        }
    }
    if let Some(path) = &o.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows).expect("json"))
            .unwrap_or_else(|e| panic!("{path}: {e}"));
        println!("wrote {path}");
    }
}
