//! `cargo xtask bench transport`: optimal transport with uniform targets.
//! On one model (`--model NAME` from the models folder, default
//! `joint_100k`; a built-in model when the folder lacks it) with `--sites
//! N` uniform sites (default 100 000), on `--backend cpu|vulkan`: the
//! Voronoi diagram and the power diagram at the weights found, each plain
//! and with faces, alternated and best of `--repeat R` (default 3); then
//! the solve, step by step; then the ratios of the solve's time to both
//! diagrams'.
//!
//! Options: `--models-dir DIR` (default: `$CVD_MODELS` or
//! `../shared/models`) `--threads N` `--device D` `--json PATH`.

mod common;

use cvd::cvt::transport::Transport;
use cvd::exec::CpuBackend;
use cvd::{geom::points, Backend, ClippedVoronoi, TetMesh};
use std::path::PathBuf;
use std::time::Instant;

struct Options {
    models_dir: PathBuf,
    model: String,
    sites: usize,
    backend: String,
    repeat: usize,
    threads: Option<usize>,
    device: Option<String>,
    json: Option<String>,
}

fn options() -> Options {
    let mut o = Options {
        models_dir: common::default_models_dir(),
        model: "joint_100k".into(),
        sites: 100_000,
        backend: "cpu".into(),
        repeat: 3,
        threads: None,
        device: None,
        json: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--models-dir" => o.models_dir = value().into(),
            "--model" => o.model = value(),
            "--sites" => o.sites = value().parse().expect("--sites N"),
            "--backend" => o.backend = value(),
            "--repeat" => o.repeat = value().parse().expect("--repeat R"),
            "--threads" => o.threads = Some(value().parse().expect("--threads N")),
            "--device" => o.device = Some(value()),
            "--json" => o.json = Some(value()),
            "--bench" => {}
            other => panic!("unknown option {other}"),
        }
    }
    o
}

/// The model's mesh: `NAME.mesh` in the models folder, else the built-in
/// model of that name (or the joint).
fn mesh(o: &Options) -> (String, TetMesh) {
    let path = o.models_dir.join(format!("{}.mesh", o.model));
    if path.is_file() {
        return (o.model.clone(), cvd_io::read_mesh(&path).expect("the model reads"));
    }
    let name = if cvd::mesher::models::NAMES.contains(&o.model.as_str()) { o.model.as_str() } else { "joint" };
    println!("{} not found: the built-in {name}", path.display());
    (name.to_string(), cvd::mesher::models::builtin(name, None).expect("a built-in model"))
}

/// Seconds of the fastest of `times`.
fn best(times: &[f64]) -> f64 {
    times.iter().copied().fold(f64::INFINITY, f64::min)
}

fn main() {
    let o = options();
    let (name, mesh) = mesh(&o);
    let sites = points::in_mesh(&mesh, o.sites, 1);
    let vulkan;
    let cpu;
    let backend: &dyn Backend = if o.backend == "vulkan" {
        vulkan = common::warm_vulkan(o.device.clone()).expect("a Vulkan device");
        &vulkan
    } else {
        cpu = CpuBackend::new(o.threads).expect("the CPU backend");
        &cpu
    };
    println!("{name}: {} tets, {} sites, on {}", mesh.tets.len(), sites.len(), backend.name());
    let cv = ClippedVoronoi::new(&mesh, &sites).backend(backend);
    let clock = Instant::now();
    let mut step = 0;
    let run = Transport::new(cv)
        .solve(&mut |s| {
            if s.step > 0.0 {
                step += 1;
                println!("  step {step:>2}: {s}");
            }
            true
        })
        .expect("the solve");
    let solve = clock.elapsed().as_secs_f64();
    let steps = run.steps.len() - 1;
    let diagrams: u32 = run.steps.iter().map(|s| s.diagrams).sum();
    println!(
        "  solve: {solve:.3} s, {steps} Newton steps, {diagrams} diagrams, max error {:.2e}{}",
        run.max_error(),
        if run.converged { "" } else { " (NOT converged)" }
    );
    // The diagrams, alternated: Voronoi and power, plain and with faces.
    let power = cv.weights(&run.weights);
    let mut times = [(); 4].map(|_| Vec::new());
    for _ in 0..o.repeat {
        for (k, c) in [cv, cv.faces(true), power, power.faces(true)].iter().enumerate() {
            let clock = Instant::now();
            c.compute().expect("a diagram");
            times[k].push(clock.elapsed().as_secs_f64());
        }
    }
    let [voronoi, voronoi_faces, power, power_faces] = times.map(|t| best(&t));
    println!(
        "  diagrams (best of {}): Voronoi {voronoi:.3} s, with faces {voronoi_faces:.3} s; power {power:.3} s ({:.2}x), with faces {power_faces:.3} s",
        o.repeat,
        power / voronoi
    );
    println!(
        "  the solve in diagram times: {:.1} Voronoi diagrams, {:.1} power diagrams with faces",
        solve / voronoi,
        solve / power_faces
    );
    if let Some(path) = &o.json {
        let row = serde_json::json!({
            "model": name, "tets": mesh.tets.len(), "sites": sites.len(), "backend": backend.name(),
            "solve_s": solve, "steps": steps, "diagrams": diagrams, "max_error": run.max_error(),
            "converged": run.converged, "voronoi_s": voronoi, "voronoi_faces_s": voronoi_faces,
            "power_s": power, "power_faces_s": power_faces,
            "step_seconds": run.steps.iter().map(|s| s.seconds).collect::<Vec<_>>(),
            "step_max_error": run.steps.iter().map(|s| s.max_error).collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&row).expect("json")).expect("the json file");
        println!("wrote {path}");
    }
}
