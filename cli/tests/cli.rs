//! `cvd run` as a user runs it: the files it writes, and its exit codes
//! (0 success, 2 bad input or arguments, 1 anything else).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh folder in the temporary directory.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cvd-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `cvd run` on the CPU with `args` (the built-in cube unless they name a
/// model or a mesh), in folder `cwd`.
fn cvd_run(cwd: &Path, args: &[&str]) -> Output {
    let model: &[&str] =
        if args.iter().any(|a| ["--model", "--mesh", "--surface"].contains(a)) { &[] } else { &["--model", "cube"] };
    Command::new(env!("CARGO_BIN_EXE_cvd"))
        .current_dir(cwd)
        .args(["run", "--backend", "cpu", "--threads", "2"])
        .args(model)
        .args(args)
        .output()
        .unwrap()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn run_writes_every_output() {
    let dir = temp_dir("all");
    let json = dir.join("copy.json");
    let out = cvd_run(&dir, &["--sites", "150", "--resolution", "3", "--json", json.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let folder = dir.join("out").join("cube");
    for file in ["cells.csv", "neighbors.csv", "sites.xyz", "cells.vtu", "walls.ply", "picture.png", "cells.png"] {
        assert!(folder.join(file).is_file(), "{file} missing");
    }
    assert!(folder.join("summary.json").is_file());
    assert!(!folder.join("pieces.vtu").exists(), "pieces.vtu only with --pieces");
    // neighbors.csv: each shared face from both sides with one area; the
    // boundary rows cover the cube's surface.
    let text_of = std::fs::read_to_string(folder.join("neighbors.csv")).unwrap();
    let mut lines = text_of.lines();
    assert_eq!(lines.next(), Some("site,neighbor,area,nx,ny,nz"));
    let mut faces = std::collections::HashMap::new();
    let mut boundary = 0.0;
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 6, "{line}");
        let (i, j, area): (u32, i64, f64) = (f[0].parse().unwrap(), f[1].parse().unwrap(), f[2].parse().unwrap());
        if j < 0 {
            boundary += area;
        } else {
            faces.insert((i, j as u32), f[2].to_string());
        }
    }
    assert!(!faces.is_empty() && faces.iter().all(|(&(i, j), a)| faces.get(&(j, i)) == Some(a)));
    let surface = cvd::mesher::models::builtin("cube", Some(3)).unwrap().boundary().area();
    assert!((boundary - surface).abs() < 1e-5 * surface, "boundary {boundary} vs {surface}");
    let rows = cvd_io::read_cells_csv(&folder.join("cells.csv")).unwrap();
    assert_eq!(rows.len(), 150);
    let sites = cvd_io::read_sites(&folder.join("sites.xyz")).unwrap();
    let cube = cvd::mesher::models::builtin("cube", Some(3)).unwrap();
    let generated: Vec<[f64; 3]> = cvd::geom::points::in_mesh(&cube, 150, 1).iter().map(|p| p.map(f64::from)).collect();
    assert_eq!(sites, generated, "sites.xyz holds the sites used");
    let summary = std::fs::read_to_string(folder.join("summary.json")).unwrap();
    assert_eq!(std::fs::read_to_string(&json).unwrap(), summary, "--json writes the same summary");
    let stdout = text(&out.stdout);
    for part in ["E_vol", "k-NN", "cpu on 2 threads", "strategy", "pieces", "wrote"] {
        assert!(stdout.contains(part), "the table lacks {part}:\n{stdout}");
    }
}

#[test]
fn no_geometry_skips_the_polyhedra_and_the_pictures() {
    let dir = temp_dir("no-geometry");
    // `--no-pieces`, its name before the cells' polyhedra, still works.
    for (flag, out) in [("--no-geometry", "here"), ("--no-pieces", "also")] {
        let run = cvd_run(&dir, &["--sites", "50", "--resolution", "2", "--out", out, flag]);
        assert!(run.status.success(), "{}", text(&run.stderr));
        let folder = dir.join(out);
        assert!(folder.join("cells.csv").is_file() && folder.join("summary.json").is_file());
        for file in ["cells.vtu", "walls.ply", "pieces.vtu", "picture.png", "cells.png"] {
            assert!(!folder.join(file).exists(), "{flag} wrote {file}");
        }
    }
    let out = cvd_run(&dir, &["--sites", "50", "--resolution", "2", "--out", "all", "--pieces", "--no-picture"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(dir.join("all/pieces.vtu").is_file() && dir.join("all/cells.vtu").is_file());
    let out = cvd_run(&dir, &["--sites", "50", "--resolution", "2", "--out", "plain", "--no-neighbors"]);
    assert!(out.status.success() && !dir.join("plain/neighbors.csv").exists(), "{}", text(&out.stderr));
    let out = cvd_run(&dir, &["--sites", "50", "--resolution", "2", "--out", "there", "--no-picture"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(dir.join("there/cells.vtu").is_file() && !dir.join("there/picture.png").exists());
    assert!(!dir.join("there/cells.png").exists());
}

#[test]
fn the_mesh_file_names_the_output_folder() {
    let dir = temp_dir("mesh-name");
    cvd_io::write_medit(&dir.join("block.mesh"), &cvd::TetMesh::cube(2)).unwrap();
    let out = cvd_run(&dir, &["--mesh", "block.mesh", "--sites", "20", "--no-pieces"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(dir.join("out/block/cells.csv").is_file());
}

#[test]
fn bad_input_exits_2_naming_the_file() {
    let dir = temp_dir("bad-input");
    std::fs::write(dir.join("broken.mesh"), "MeshVersionFormatted 1\nDimension 3\nVertices\nx\n").unwrap();
    std::fs::write(dir.join("sites.xyz"), "0 0\n").unwrap();
    let cases: [&[&str]; 5] = [
        &["--mesh", "missing.mesh"],
        &["--mesh", "broken.mesh"],
        &["--sites-file", "sites.xyz"],
        &["--model", "no-such-model"],
        &["--sites", "0"],
    ];
    for args in cases {
        let out = cvd_run(&dir, args);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.starts_with("cvd: "), "{args:?}: {stderr}");
        if let Some(file) = args.get(1).filter(|a| a.contains('.')) {
            assert!(stderr.contains(file), "{args:?}: the error does not name {file}: {stderr}");
        }
    }
}

#[test]
fn bad_arguments_exit_2() {
    let dir = temp_dir("bad-args");
    for args in [&["--strategy", "sideways"][..], &["--no-such-option"], &["--sites", "many"]] {
        let out = cvd_run(&dir, args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", text(&out.stderr));
    }
}

#[test]
fn an_unknown_device_is_named_not_a_crash() {
    let dir = temp_dir("no-device");
    let out = Command::new(env!("CARGO_BIN_EXE_cvd"))
        .current_dir(&dir)
        .args(["run", "--model", "cube", "--resolution", "2", "--sites", "20", "--backend", "vulkan"])
        .args(["--device", "no-such-gpu"])
        .output()
        .unwrap();
    let stderr = text(&out.stderr);
    // Exit 2 naming the device where Vulkan exists; exit 1 without a loader.
    assert!(matches!(out.status.code(), Some(1 | 2)), "{:?}: {stderr}", out.status);
    assert!(stderr.contains("no-such-gpu") || stderr.contains("Vulkan is not available"), "{stderr}");
}

#[test]
fn an_unwritable_output_exits_1() {
    let dir = temp_dir("unwritable");
    std::fs::write(dir.join("file"), "").unwrap();
    let out = cvd_run(&dir, &["--sites", "20", "--resolution", "2", "--out", "file/sub"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot write file/sub"), "{stderr}");
}

/// The numbers of `key` in a JSON object, as f64.
fn numbers(v: &serde_json::Value, key: &str) -> Vec<f64> {
    v[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} is not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[test]
fn a_cvt_run_records_every_iteration_in_the_summary() {
    let dir = temp_dir("cvt-record");
    for (optimizer, iterations) in [("lloyd", 6), ("lbfgs", 4)] {
        let json = dir.join(format!("{optimizer}.json"));
        let args = ["--sites", "60", "--resolution", "3", "--no-pieces", "--iterations", &iterations.to_string()];
        let out = cvd_run(&dir, &[&args[..], &["--optimizer", optimizer, "--json", json.to_str().unwrap()]].concat());
        assert!(out.status.success(), "{}", text(&out.stderr));
        let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let cvt = &summary["cvt"];
        assert_eq!(cvt["optimizer"], optimizer);
        let n = cvt["iterations"].as_u64().unwrap() as usize;
        assert!(n >= 1 && n <= iterations, "{cvt}");
        let energy = numbers(cvt, "energy");
        let seconds = numbers(cvt, "seconds");
        assert_eq!((energy.len(), seconds.len(), numbers(cvt, "empty_cells").len()), (n, n, n), "{cvt}");
        // Both optimisers only lower the energy, down to the final diagram's.
        let last = summary["energy"].as_f64().unwrap();
        for w in energy.windows(2) {
            assert!(w[1] <= w[0], "{optimizer}: the energy rose: {energy:?}");
        }
        assert!(last <= energy[n - 1] && last > 0.0, "{optimizer}: final {last} after {energy:?}");
        let total = cvt["total_s"].as_f64().unwrap();
        assert!((total - seconds.iter().sum::<f64>()).abs() <= 1e-9 * total.max(1.0), "{cvt}");
        assert!((cvt["per_iteration_s"].as_f64().unwrap() - total / n as f64).abs() <= 1e-12, "{cvt}");
        // The table says the same as the record.
        let stdout = text(&out.stdout);
        let row = stdout.lines().find(|l| l.trim_start().starts_with(optimizer)).expect("a cvt row");
        assert!(row.contains(&format!("{n} iterations")), "{row}");
        assert!(row.contains(&format!("energy {:.6e} -> {last:.6e}", energy[0])), "{row}");
    }
    // A plain run has no record.
    let json = dir.join("plain.json");
    let out = cvd_run(&dir, &["--sites", "30", "--resolution", "2", "--no-pieces", "--json", json.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(summary.get("cvt").is_none(), "{summary}");
}

#[test]
fn the_header_says_which_backend_and_why() {
    let dir = temp_dir("why");
    let out = cvd_run(&dir, &["--sites", "30", "--resolution", "2", "--no-pieces"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("on cpu (2 threads) — asked for"), "{stdout}");
    // The diagram is computed once unless a warm-up is asked for.
    assert!(!stdout.contains("warm-up"), "{stdout}");
    let out = cvd_run(&dir, &["--sites", "30", "--resolution", "2", "--no-pieces", "--warm-up"]);
    assert!(out.status.success() && text(&out.stdout).contains("warm-up run: "), "{}", text(&out.stdout));
}

#[test]
fn auto_does_not_pick_vulkan_on_the_cpu() {
    // `cvd devices --json` says which devices are GPUs; auto runs on the
    // CPU backend unless one is.
    let listing = Command::new(env!("CARGO_BIN_EXE_cvd")).args(["devices", "--json"]).output().unwrap();
    assert!(listing.status.success(), "{}", text(&listing.stderr));
    let devices: serde_json::Value = serde_json::from_slice(&listing.stdout).unwrap();
    let devices = devices.as_array().unwrap();
    for d in devices {
        assert_eq!(d["gpu"].as_bool().unwrap(), d["type"].as_str().unwrap().ends_with("GPU"), "{d}");
    }
    let dir = temp_dir("auto");
    let out = Command::new(env!("CARGO_BIN_EXE_cvd"))
        .current_dir(&dir)
        .args(["run", "--model", "cube", "--resolution", "2", "--sites", "30", "--no-pieces"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let header = stdout.lines().find(|l| l.starts_with("cube: ")).expect("the run's header");
    if devices.iter().any(|d| d["gpu"] == true) {
        assert!(header.contains("on vulkan") && header.contains("— auto: the GPU "), "{header}");
    } else {
        assert!(header.contains("on cpu") && header.contains("— auto: no "), "{header}");
    }
}

#[test]
fn a_sites_file_is_written_back_digit_for_digit() {
    // UTM-like coordinates: sites.xyz holds exactly what was read.
    let dir = temp_dir("round-trip");
    let file = "4\n1000000.0145585263 4649776.224345621 12.5\n1000000.9 4649776.5 12.25\n\
                1000000.25 4649776.125 12.75\n1000000.5 4649776.875 12.0625\n";
    std::fs::write(dir.join("utm.xyz"), file).unwrap();
    let given = cvd_io::read_sites(&dir.join("utm.xyz")).unwrap();
    assert_eq!(given[0], [1000000.0145585263, 4649776.224345621, 12.5]);
    let (lo, hi) = ([1000000.0, 4649776.0, 12.0], [1000001.0, 4649777.0, 13.0]);
    let mut cube = cvd::TetMesh::cube(2);
    for v in &mut cube.vertices {
        for a in 0..3 {
            v[a] = lo[a] + v[a] * (hi[a] - lo[a]);
        }
    }
    cvd_io::write_medit(&dir.join("box.mesh"), &cube).unwrap();
    let out = cvd_run(&dir, &["--mesh", "box.mesh", "--sites-file", "utm.xyz", "--no-pieces", "--out", "o"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(cvd_io::read_sites(&dir.join("o/sites.xyz")).unwrap(), given);
}

#[test]
fn weights_give_power_cells_and_are_checked() {
    let dir = temp_dir("weights");
    // Two sites in the unit cube: the heavier one's cell grows by
    // (w_1 - w_0) / 2d = 0.04 / (2 * 0.5) = 0.04 past the middle.
    std::fs::write(dir.join("two.xyz"), "0.25 0.5 0.5\n0.75 0.5 0.5\n").unwrap();
    std::fs::write(dir.join("w.txt"), "# weights\n0.01\n0.05\n").unwrap();
    let out = cvd_run(&dir, &["--sites-file", "two.xyz", "--weights", "w.txt", "--no-geometry", "--out", "o"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let csv = std::fs::read_to_string(dir.join("o/cells.csv")).unwrap();
    let volumes: Vec<f64> = csv.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    assert!((volumes[0] - 0.46).abs() < 1e-6 && (volumes[1] - 0.54).abs() < 1e-6, "{volumes:?}");
    // One weight too few: named, exit 2.
    std::fs::write(dir.join("short.txt"), "0.01\n").unwrap();
    let out = cvd_run(&dir, &["--sites-file", "two.xyz", "--weights", "short.txt", "--out", "o2"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("short.txt: 1 weights for 2 sites"), "{}", text(&out.stderr));
    let out = cvd_run(&dir, &["--sites-file", "two.xyz", "--weights", "w.txt", "--iterations", "2", "--out", "o3"]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
}

/// `--transport`: every cell the same volume, the weights in weights.txt
/// (reading them back gives the same cells), the Newton record in
/// summary.json; `--capacities` counted and checked; the capacity-
/// constrained CVT's iterations recorded.
#[test]
fn transport_writes_weights_that_give_equal_cells() {
    let dir = temp_dir("transport");
    let common = ["--model", "cube", "--resolution", "6", "--sites", "200", "--no-geometry"];
    let run = |extra: &[&str]| cvd_run(&dir, &[&common[..], extra].concat());
    let out = run(&["--transport", "--out", "o"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("Newton step 1:"), "{}", text(&out.stdout));
    let volumes = |path: &str| -> Vec<f64> {
        let csv = std::fs::read_to_string(dir.join(path)).unwrap();
        csv.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect()
    };
    let v = volumes("o/cells.csv");
    assert!(v.iter().all(|v| (v * 200.0 - 1.0).abs() <= 1e-6), "{:?}", &v[..5]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("o/summary.json")).unwrap()).unwrap();
    let t = &summary["transport"];
    assert_eq!(t["targets"], "uniform");
    assert_eq!(t["converged"], true, "{t}");
    assert!(t["max_error"].as_f64().unwrap() <= 1e-6, "{t}");
    let steps = t["steps"].as_u64().unwrap() as usize;
    assert!((1..=15).contains(&steps), "{t}");
    assert_eq!(numbers(t, "step_length").len(), steps);
    assert_eq!(numbers(t, "step_max_error").len(), steps + 1);
    // The weights written give those cells again.
    let out = cvd_run(
        &dir,
        &["--model", "cube", "--resolution", "6", "--sites-file", "o/sites.xyz"]
            .iter()
            .chain(&["--weights", "o/weights.txt", "--no-geometry", "--out", "again"])
            .copied()
            .collect::<Vec<_>>(),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(volumes("again/cells.csv"), v);
    // Capacities: one per site, positive.
    std::fs::write(dir.join("c.txt"), "1\n".repeat(199)).unwrap();
    let out = run(&["--capacities", "c.txt", "--out", "c"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("c.txt: 199 capacities for 200 sites"), "{}", text(&out.stderr));
    std::fs::write(dir.join("c.txt"), "1\n".repeat(100) + &"3\n".repeat(100)).unwrap();
    let out = run(&["--capacities", "c.txt", "--out", "c"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let v = volumes("c/cells.csv");
    assert!((v[0] * 400.0 - 1.0).abs() <= 1e-6 && (v[199] * 400.0 - 3.0).abs() <= 3e-6, "{} {}", v[0], v[199]);
    // The capacity-constrained CVT.
    let out = run(&["--transport", "--iterations", "3", "--out", "cvt"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("cvt/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["cvt"]["optimizer"], "lloyd-transport");
    assert_eq!(numbers(&summary["cvt"], "newton_steps").len(), 3);
    assert!(volumes("cvt/cells.csv").iter().all(|v| (v * 200.0 - 1.0).abs() <= 1e-6));
    let out = run(&["--transport", "--iterations", "2", "--optimizer", "lbfgs", "--out", "x"]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    // Volumes from a law: log-normal, seeded (the same cells again), the
    // cells' log-volumes spread as drawn; a bad law refused by name.
    let out = run(&["--volumes", "lognormal:0,1", "--tolerance", "1e-5", "--out", "ln"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let v = volumes("ln/cells.csv");
    let logs: Vec<f64> = v.iter().map(|x| x.ln()).collect();
    let mean = logs.iter().sum::<f64>() / 200.0;
    let sd = (logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / 200.0).sqrt();
    assert!((sd - 1.0).abs() < 0.2, "log-volumes' deviation {sd}");
    let drawn = cvd::cvt::transport::VolumeLaw::LogNormal { mu: 0.0, sigma: 1.0 }.draw(200, 1);
    let total: f64 = drawn.iter().sum();
    for (v, d) in v.iter().zip(&drawn) {
        assert!((v / (d / total) - 1.0).abs() <= 1e-5, "{v} against {}", d / total);
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("ln/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["transport"]["targets"], "lognormal:0,1");
    let out = run(&["--volumes", "lognormal:1", "--out", "bad"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("expected lognormal:MU,SIGMA"), "{}", text(&out.stderr));
    // Not converged: exit 3, the outputs written, and what stopped it said.
    let out = run(&["--transport", "--newton-steps", "1", "--out", "short"]);
    assert_eq!(out.status.code(), Some(3), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(err.contains("out of Newton steps (1)") && err.contains("exit status 3"), "{err}");
    assert!(dir.join("short/weights.txt").is_file() && dir.join("short/cells.csv").is_file());
}

/// A closed box as an OFF file; `open` leaves one triangle out.
fn box_off(path: &Path, open: bool) {
    let mut t = String::from("OFF\n8 12 0\n");
    for i in 0..8 {
        t += &format!("{} {} {}\n", i & 1, (i >> 1) & 1, (i >> 2) & 1);
    }
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let tris: Vec<[u32; 3]> = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    let n = if open { 11 } else { 12 };
    t = t.replace("8 12 0", &format!("8 {n} 0"));
    for f in &tris[..n] {
        t += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
    }
    std::fs::write(path, t).unwrap();
}

#[test]
fn a_surface_is_meshed_and_an_open_one_refused() {
    let dir = temp_dir("surface");
    box_off(&dir.join("box.off"), false);
    let out =
        cvd_run(&dir, &["--surface", "box.off", "--resolution", "8", "--sites", "100", "--no-pieces", "--out", "o"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("box.off: 12 triangles, 1 shells, volume 1.000000e0"), "{stdout}");
    assert!(stdout.contains("meshed at resolution 8"), "{stdout}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("o/summary.json")).unwrap()).unwrap();
    assert!(summary["e_vol"].as_f64().unwrap() <= 1e-6, "{summary}");
    let out = cvd_run(&dir, &["--surface", "box.off", "--tets", "20000", "--sites", "50", "--no-pieces", "--out", "t"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let tets = std::fs::read_to_string(dir.join("t/summary.json")).unwrap();
    let tets: serde_json::Value = serde_json::from_str(&tets).unwrap();
    let n = tets["tets"].as_f64().unwrap();
    assert!((n - 20000.0).abs() < 0.3 * 20000.0, "--tets 20000 gave {n} tets");
    box_off(&dir.join("open.off"), true);
    let out = cvd_run(&dir, &["--surface", "open.off", "--sites", "10", "--no-pieces"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = text(&out.stderr);
    assert!(stderr.contains("open.off") && stderr.contains("3 boundary (open) edges"), "{stderr}");
}

#[test]
fn a_periodic_box_fills_with_cells_whose_faces_carry_image_shifts() {
    let dir = temp_dir("periodic");
    // Sites outside the box are wrapped into it, and said so.
    std::fs::write(dir.join("s.xyz"), "0.5 0.5 0.5\n2.5 0.25 0.1\n-0.75 0.1 0.3\n0.1 0.9 0.9\n0.3 0.3 0.7\n").unwrap();
    let out = cvd_run(&dir, &["--box", "-1,0,0,1,1,0.5", "--sites-file", "s.xyz", "--iterations", "3", "--out", "o"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    // Three outside, and one on the box's upper face (the box holds its
    // lower faces, not its upper ones).
    assert!(stdout.contains("4 sites were outside the box"), "{stdout}");
    let csv = std::fs::read_to_string(dir.join("o/cells.csv")).unwrap();
    let total: f64 = csv.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse::<f64>().unwrap()).sum();
    assert!((total - 1.0).abs() < 1e-6, "the cells fill the box: {total}");
    let neighbors = std::fs::read_to_string(dir.join("o/neighbors.csv")).unwrap();
    assert!(neighbors.starts_with("site,neighbor,area,nx,ny,nz,shift_x,shift_y,shift_z\n"), "{neighbors}");
    // Five sites in a box: some faces are shared with images.
    assert!(neighbors.lines().skip(1).any(|l| !l.ends_with(",0,0,0")), "{neighbors}");
    assert!(neighbors.lines().skip(1).all(|l| l.split(',').nth(1) != Some("-1")), "no boundary rows");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("o/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["periodic"]["wrapped"], 4, "{summary}");
    assert_eq!(summary["cvt"]["iterations"], 3, "{summary}");
    // Refused by name: a box of five numbers, a model that is not a box.
    let out = cvd_run(&dir, &["--box", "0,0,0,1,1", "--out", "bad"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("--box takes six numbers"), "{}", text(&out.stderr));
    let out = cvd_run(&dir, &["--periodic", "--model", "torus", "--out", "bad"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("--model cube"), "{}", text(&out.stderr));
}

/// An FCC crystal in a LAMMPS triclinic box that is not its own cell,
/// walls along z: every inner cell is FCC's rhombic dodecahedron, Voronoi
/// index <0,12,0,0>; radii as power weights; bad boxes refused by name.
#[test]
fn a_triclinic_slab_gives_particle_quantities_and_bad_boxes_are_refused() {
    let dir = temp_dir("triclinic");
    // FCC of cube side 1: 4 x 4 cubes along x and y, tilted by one cube
    // (a whole lattice vector), 3 cubes along z between walls.
    let mut text_sites = String::new();
    for k in 0..3 {
        for j in 0..4 {
            for i in 0..4 {
                for o in [[0.25, 0.25, 0.25], [0.75, 0.75, 0.25], [0.75, 0.25, 0.75], [0.25, 0.75, 0.75]] {
                    let p = [i as f64 + o[0], j as f64 + o[1], k as f64 + o[2]];
                    text_sites.push_str(&format!("{} {} {}\n", p[0], p[1], p[2]));
                }
            }
        }
    }
    std::fs::write(dir.join("fcc.xyz"), &text_sites).unwrap();
    let radii = "0.5\n".repeat(192);
    std::fs::write(dir.join("r.txt"), radii).unwrap();
    let args = [
        "--box",
        "0,0,0,4,4,3",
        "--tilt",
        "1,0,0",
        "--periodic-axes",
        "xy",
        "--sites-file",
        "fcc.xyz",
        "--radii",
        "r.txt",
        "--voronoi-index",
        "--out",
        "o",
    ];
    let out = cvd_run(&dir, &args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let rows = cvd_io::read_cells_csv(&dir.join("o/cells.csv")).unwrap();
    assert_eq!(rows.len(), 192);
    let inner = rows.iter().filter(|r| r.site / 64 == 1);
    for r in inner {
        let p = r.particle.unwrap();
        assert_eq!(p.index, [0, 12, 0, 0, 0, 0, 0, 0], "site {}", r.site);
        assert!((r.volume - 0.25).abs() < 1e-6, "site {}: {}", r.site, r.volume);
    }
    let total: f64 = rows.iter().map(|r| r.volume).sum();
    assert!((total - 48.0).abs() < 1e-5, "the cells fill the slab: {total}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("o/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["periodic"]["periodic"], serde_json::json!([true, true, false]), "{summary}");
    assert_eq!(summary["particles"]["top_indices"][0][0], "<0,12,0,0>", "{summary}");
    for (args, says) in [
        (&["--lattice", "1,0,0,0,1,0,0,0"][..], "--lattice takes nine numbers"),
        (&["--lattice", "1,0,0,0,0,1,0,1,0"][..], "right-handed"),
        (&["--box", "0,0,0,1,1,1", "--periodic-axes", "xw"][..], "--periodic-axes"),
        (&["--box", "0,0,0,1,1,1", "--tilt", "1,2"][..], "--tilt takes three numbers"),
        (&["--box", "0,0,0,4,4,1", "--sites-file", "fcc.xyz", "--periodic-axes", "xy"][..], "outside the walls"),
    ] {
        let out = cvd_run(&dir, &[args, &["--out", "bad"]].concat());
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(text(&out.stderr).contains(says), "{args:?}: {}", text(&out.stderr));
    }
}

/// The bits of each coordinate.
fn bits(sites: &[[f64; 3]]) -> Vec<u64> {
    sites.iter().flatten().map(|c| c.to_bits()).collect()
}

#[test]
fn a_npy_sites_file_gives_the_cells_of_the_same_xyz() {
    let dir = temp_dir("npy");
    let sites = cvd::geom::points::in_mesh(&cvd::TetMesh::cube(3), 300, 5);
    cvd_io::write_sites_npy(&dir.join("s.npy"), &sites).unwrap();
    cvd_io::write_sites_xyz(&dir.join("s.xyz"), &sites).unwrap();
    for (file, out) in [("s.npy", "npy"), ("s.xyz", "xyz")] {
        let run = cvd_run(&dir, &["--resolution", "3", "--sites-file", file, "--no-geometry", "--out", out]);
        assert!(run.status.success(), "{file}: {}", text(&run.stderr));
    }
    let read = |p: &str| std::fs::read_to_string(dir.join(p)).unwrap();
    assert_eq!(read("npy/cells.csv"), read("xyz/cells.csv"));
    assert_eq!(read("npy/sites.xyz"), read("xyz/sites.xyz"));
    assert_eq!(bits(&cvd_io::read_sites(&dir.join("npy/sites.xyz")).unwrap()), bits(&sites));
    // A bad array: exit 2, naming the file and what was expected.
    std::fs::write(dir.join("bad.npy"), b"\x93NUMPY\x01\x00\x11\x00{'descr': '<f8'}\n").unwrap();
    let run = cvd_run(&dir, &["--resolution", "3", "--sites-file", "bad.npy", "--out", "bad"]);
    let stderr = text(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("bad.npy") && stderr.contains("found no 'fortran_order'"), "{stderr}");
}

#[test]
fn parts_give_the_cells_of_one_run_and_bad_counts_are_refused() {
    let dir = temp_dir("parts");
    // Parts run tet-cell: so does the run they are compared with.
    let args = ["--sites", "3000", "--resolution", "8", "--no-geometry", "--no-neighbors", "--strategy", "tet-cell"];
    let one = cvd_run(&dir, &[&args[..], &["--out", "one"]].concat());
    assert!(one.status.success(), "{}", text(&one.stderr));
    let parts = cvd_run(&dir, &[&args[..], &["--out", "parts", "--parts", "3", "--halo", "1,0"]].concat());
    assert!(parts.status.success(), "{}", text(&parts.stderr));
    let read = |d: &str| std::fs::read(dir.join(d).join("cells.csv")).unwrap();
    assert_eq!(read("one"), read("parts"), "3 parts: the same cells.csv");
    assert!(text(&parts.stdout).contains("3 parts on 1 rank(s)"), "{}", text(&parts.stdout));
    for bad in [&["--parts", "0"][..], &["--parts", "2", "--halo", "1"], &["--parts", "2", "--halo", "a,2"]] {
        let out = cvd_run(&dir, &[&args[..], bad].concat());
        assert_eq!(out.status.code(), Some(2), "{bad:?}: {}", text(&out.stderr));
    }
}

#[test]
fn a_trajectory_reuses_the_last_frames_lists_and_writes_the_same_cells() {
    let dir = temp_dir("trajectory");
    // 1 000 particles drifting slowly in a triclinic cell, 5 frames of
    // extended XYZ.
    let mut seed = 12345u64;
    let mut unit = move || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let l = 10.0;
    let mut p: Vec<[f64; 3]> = (0..1000).map(|_| [unit() * l, unit() * l, unit() * l]).collect();
    let mut xyz = String::new();
    for _ in 0..5 {
        xyz.push_str(&format!(
            "1000\nLattice=\"{l} 0 0 2 {l} 0 -1 1.5 {l}\" Properties=species:S:1:pos:R:3 pbc=\"T T T\"\n"
        ));
        for q in &p {
            // Sheared into the cell: fractional (x, y, z) / l.
            let s = q.map(|c| c / l);
            let r = [s[0] * l + s[1] * 2.0 - s[2], s[1] * l + s[2] * 1.5, s[2] * l];
            xyz.push_str(&format!("Ar {} {} {}\n", r[0], r[1], r[2]));
        }
        for q in &mut p {
            for c in q.iter_mut() {
                *c += 0.04 * (unit() - 0.5);
            }
        }
    }
    std::fs::write(dir.join("drift.extxyz"), xyz).unwrap();
    let summary = |out: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join(out).join("summary.json")).unwrap()).unwrap()
    };
    for (out, extra) in [("reuse", &[][..]), ("rebuild", &["--rebuild-frames"][..])] {
        let args = [&["--particles", "drift.extxyz", "--voronoi-index", "--out", out][..], extra].concat();
        let run = Command::new(env!("CARGO_BIN_EXE_cvd"))
            .current_dir(&dir)
            .args(["run", "--backend", "cpu", "--threads", "2"])
            .args(&args)
            .output()
            .unwrap();
        assert!(run.status.success(), "{}", text(&run.stderr));
    }
    let (reuse, rebuild) = (summary("reuse"), summary("rebuild"));
    let reused: Vec<u64> = (0..5).map(|f| reuse["frames"][f]["reused_cells"].as_u64().unwrap()).collect();
    assert_eq!(reused[0], 0, "{reused:?}");
    assert!(reused[1..].iter().all(|&r| r > 800), "slow particles keep their lists: {reused:?}");
    assert_eq!(reuse["reused_cells"].as_u64(), Some(reused.iter().sum()));
    assert_eq!(rebuild["reused_cells"].as_u64(), Some(0));
    for f in 0..5 {
        let name = format!("frames/cells.{f:06}.csv");
        let (a, b) = (
            std::fs::read(dir.join("reuse").join(&name)).unwrap(),
            std::fs::read(dir.join("rebuild").join(&name)).unwrap(),
        );
        assert!(a == b, "frame {f}: the same cells.csv, byte for byte");
    }
}

#[test]
fn jobs_too_large_for_the_memory_are_refused_before_they_start() {
    let dir = temp_dir("memory");
    let refused = |args: &[&str], says: &[&str]| {
        let out = cvd_run(&dir, &[args, &["--out", "o"]].concat());
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        for s in says {
            assert!(err.contains(s), "{args:?}: {err}");
        }
        assert!(!err.contains("memory allocation") && !err.contains("panicked"), "{err}");
    };
    // An absurd number of sites: refused before they are made.
    refused(&["--sites", "10000000000"], &["10000000000 sites", "needs about", "TB", "available"]);
    refused(&["--box", "0,0,0,1,1,1", "--sites", "10000000000"], &["needs about", "available"]);
    // A modest job under a CPU budget of 1 MiB.
    refused(&["--sites", "20000", "--memory-budget", "1"], &["needs about", "1.0 MB", "--memory-budget"]);
    let out = cvd_run(&dir, &["--sites", "2000", "--memory-budget", "64", "--no-geometry", "--out", "ok"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Files larger than the memory (sparse: no disk is taken), refused by
    // name before they are read.
    let Some(available) = cvd::job::memory::available() else {
        eprintln!("SKIPPED the files: the machine does not say how much memory it has");
        return;
    };
    let huge = dir.join("huge.xyz");
    std::fs::File::create(&huge).unwrap().set_len(2 * available).unwrap();
    refused(&["--sites-file", "huge.xyz"], &["huge.xyz", "needs about", "available"]);
    let n = 2 * available / 24;
    let dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({n}, 3), }}");
    let mut header = b"\x93NUMPY\x01\x00".to_vec();
    let padded = (10 + dict.len() + 1).div_ceil(64) * 64;
    header.extend_from_slice(&((padded - 10) as u16).to_le_bytes());
    header.extend_from_slice(dict.as_bytes());
    header.resize(padded - 1, b' ');
    header.push(b'\n');
    let npy = dir.join("huge.npy");
    std::fs::write(&npy, &header).unwrap();
    std::fs::OpenOptions::new().write(true).open(&npy).unwrap().set_len(padded as u64 + n * 24).unwrap();
    refused(&["--sites-file", "huge.npy"], &["huge.npy", &format!("the {n} sites"), "available"]);
}

#[test]
fn more_threads_than_the_process_may_use_are_said() {
    // A process bound to one core (as an MPI launcher binds a rank) asked
    // for 2 threads: said, with the way out; the run goes on.
    let dir = temp_dir("bound");
    let out = dir.join("out");
    let args = ["-c", "0", env!("CARGO_BIN_EXE_cvd"), "run", "--periodic", "--box", "0,0,0,9,9,9"];
    let run =
        match Command::new("taskset").args(args).args(["--sites", "700", "--threads", "2", "--out"]).arg(&out).output()
        {
            Ok(run) => run,
            Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("CI=true: taskset is needed: {e}"),
            Err(e) => return eprintln!("skipped: no taskset ({e})"),
        };
    assert!(run.status.success(), "{}", text(&run.stderr));
    let said = text(&run.stderr);
    assert!(said.contains("--threads 2") && said.contains("1 core") && said.contains("--bind-to none"), "{said}");
    // Within the cores it may use: nothing said.
    let run = Command::new(env!("CARGO_BIN_EXE_cvd"))
        .args(["run", "--periodic", "--box", "0,0,0,9,9,9", "--sites", "700", "--threads", "1", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success() && !text(&run.stderr).contains("core(s) only"), "{}", text(&run.stderr));
    let _ = std::fs::remove_dir_all(&dir);
}
