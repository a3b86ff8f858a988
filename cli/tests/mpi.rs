//! `mpirun -np P cvd run ...` as a user runs it: the same cells to the bit
//! as one process, for P = 1 to 4 ranks on this machine. Needs a build with
//! the `mpi` feature (`cargo xtask test` adds it where MPI is installed,
//! which `xtask/install-deps test` does) and `mpirun`; skipped, saying
//! why, without them — and failing under `CI=true`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cvd-mpi-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Whether MPI runs can be tested here; if not, a skip or (CI) a failure.
fn mpi_here() -> bool {
    let why = if !cvd::backends::distributed::HAS_MPI {
        "this cvd was built without the `mpi` feature (cargo xtask test adds it where MPI is installed)".to_string()
    } else {
        match Command::new("mpirun").arg("--version").output() {
            Ok(o) if o.status.success() => return true,
            Ok(o) => format!("mpirun --version failed: {}", String::from_utf8_lossy(&o.stderr).trim()),
            Err(e) => format!("no mpirun: {e}"),
        }
    };
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("CI=true but {why}");
    }
    eprintln!("SKIPPED ({why})");
    false
}

const JOB: &[&str] =
    &["run", "--model", "cube", "--resolution", "10", "--backend", "cpu", "--no-geometry", "--no-neighbors"];

fn cvd(out: &Path, args: &[&str]) -> Output {
    cvd_job(JOB, out, args)
}

/// One process running `job` with `args`.
fn cvd_job(job: &[&str], out: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cvd")).args(job).args(args).arg("--out").arg(out).output().unwrap()
}

/// `ranks` ranks of one thread each (Open MPI: more ranks than cores, and
/// as root in containers, when asked).
fn mpirun(ranks: usize, out: &Path, args: &[&str]) -> Output {
    mpirun_job(JOB, ranks, out, args)
}

/// [`mpirun`] of `job` with `args`.
fn mpirun_job(job: &[&str], ranks: usize, out: &Path, args: &[&str]) -> Output {
    mpirun_env(job, ranks, out, args, &[])
}

/// [`mpirun_job`] with environment variables for the ranks.
/// Every run is bounded (coreutils' `timeout`, status 124): ranks that wait
/// for one another forever fail the test instead of hanging it. The ranks
/// are not bound to one core each (Open MPI's default): lavapipe's threads
/// of a rank bound so share its one core, and a device run of seconds
/// takes minutes.
fn mpirun_env(job: &[&str], ranks: usize, out: &Path, args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new("timeout")
        .args(["600", "mpirun"])
        .envs(env.iter().copied())
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .env("OMPI_MCA_hwloc_base_binding_policy", "none")
        .args(["-np", &ranks.to_string(), env!("CARGO_BIN_EXE_cvd")])
        .args(job)
        .args(["--threads", "1"])
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

fn ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what}: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `files` of the run in `out` are byte for byte those of the run in `one`.
fn same_files(one: &Path, out: &Path, files: &[&str], what: &str) {
    for file in files {
        assert!(read(&one.join(file)) == read(&out.join(file)), "{what}: {file} differs");
    }
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn mpirun_gives_the_cells_of_one_process() {
    if !mpi_here() {
        return;
    }
    let dir = temp_dir("cells");
    // Clustered-like unevenness is the library tests' business; here the
    // processes, the files and the reduction.
    // Parts run tet-cell: so does the one process they are compared with.
    let sites = ["--sites", "40000", "--strategy", "tet-cell"];
    let one = dir.join("one");
    ok(&cvd(&one, &sites), "one process");
    for ranks in 1..=4 {
        let out = dir.join(format!("ranks{ranks}"));
        let o = mpirun(ranks, &out, &sites);
        ok(&o, &format!("{ranks} ranks"));
        assert_eq!(read(&one.join("cells.csv")), read(&out.join("cells.csv")), "{ranks} ranks: cells.csv");
        let summary: serde_json::Value = serde_json::from_slice(&read(&out.join("summary.json"))).unwrap();
        assert_eq!(summary["parts"]["ranks"], ranks, "{ranks} ranks: summary.json");
        assert_eq!(summary["parts"]["all"].as_array().map(|a| a.len()), Some(ranks));
        let tets: u64 = summary["parts"]["all"].as_array().unwrap().iter().map(|r| r["tets"].as_u64().unwrap()).sum();
        assert_eq!(tets, summary["tets"].as_u64().unwrap(), "{ranks} ranks: every tet in one part");
        // Rank 0 alone speaks.
        let said = String::from_utf8_lossy(&o.stdout);
        assert_eq!(said.matches("wrote ").count(), 1, "{said}");
    }
}

/// Whole cells, the default, over ranks: each rank builds a share of the
/// cells and the ranks add their sums and faces. A torus (its curved,
/// non-convex boundary cuts many cells) holding a crowd with a tight
/// cluster, given as a file: cells.csv and neighbors.csv byte for byte one
/// process's; after Lloyd's and L-BFGS's iterations the sites too; the
/// polyhedra (each rank's piece of cells.pvtu, walls.ply); power cells;
/// optimal transport's weights; the Voronoi index — each rank reading its
/// own rows. Tet-cell
/// with every rank reading the whole input, said.
#[test]
fn mpirun_gives_whole_cells_and_neighbours_of_one_process() {
    if !mpi_here() {
        return;
    }
    let dir = temp_dir("whole");
    let mesh = cvd::mesher::models::builtin("torus", Some(12)).unwrap();
    let mut sites = cvd::geom::points::in_mesh(&mesh, 9000, 31);
    let at = mesh.vertices[mesh.tets[mesh.tets.len() / 2][0] as usize];
    let blob = cvd::geom::points::clustered(3000, 1, 0.01, 32);
    sites.extend(blob.iter().map(|p| [0, 1, 2].map(|a| at[a] + 0.1 * (p[a] - 0.5))));
    let file = dir.join("sites.xyz");
    cvd_io::write_sites_xyz(&file, &sites).unwrap();
    // Power weights that drift along the torus over about a spacing²
    // (5e-4), noisy.
    let noise = cvd::geom::points::uniform(sites.len(), 33);
    let weights: Vec<f64> = sites.iter().zip(&noise).map(|(p, n)| 2e-4 * (p[0] + n[0])).collect();
    let weights_file = dir.join("weights.txt");
    cvd_io::write_values(&weights_file, &weights).unwrap();
    let (file, weights_file) = (file.to_str().unwrap(), weights_file.to_str().unwrap());
    let torus = ["run", "--model", "torus", "--resolution", "12", "--backend", "cpu"];
    // Where the ranks of the first case keep their rows until written.
    let scratch = dir.join("scratch");
    std::fs::create_dir_all(&scratch).unwrap();
    let scratch = scratch.to_str().unwrap();
    let cases: [(&str, Vec<&str>); 8] = [
        ("cells", vec!["--sites-file", file, "--no-geometry", "--scratch", scratch]),
        ("lbfgs", vec!["--sites", "6000", "--iterations", "3", "--optimizer", "lbfgs", "--no-geometry"]),
        ("lloyd", vec!["--sites", "6000", "--iterations", "3", "--no-geometry"]),
        ("geometry", vec!["--sites-file", file, "--pieces"]),
        ("power", vec!["--sites-file", file, "--weights", weights_file, "--no-geometry"]),
        ("index", vec!["--sites", "5000", "--voronoi-index", "--relative-face-threshold", "0.01", "--no-picture"]),
        ("transport", vec!["--sites", "3000", "--volumes", "lognormal:0,0.5", "--no-geometry"]),
        ("tet-cell", vec!["--sites", "3000", "--strategy", "tet-cell", "--no-geometry", "--no-neighbors"]),
    ];
    // Each case on 2 ranks or on 3, in turn (the periodic box's runs take
    // every count from 1 to 4).
    for (case, (name, args)) in cases.iter().enumerate() {
        let one = dir.join(format!("{name}-one"));
        let o = cvd_job(&torus, &one, args);
        ok(&o, &format!("{name}: one process"));
        let strategy = if *name == "tet-cell" { "tet-cell on cpu" } else { "whole on cpu" };
        assert!(String::from_utf8_lossy(&o.stdout).contains(strategy), "{name}: whole cells by default");
        let ranks = 2 + case % 2;
        let out = dir.join(format!("{name}-{ranks}"));
        let o = mpirun_job(&torus, ranks, &out, args);
        ok(&o, &format!("{name}: {ranks} ranks"));
        let said = String::from_utf8_lossy(&o.stdout);
        // Whole cells with each rank reading its rows (cells,
        // neighbours, polyhedra, power cells, the optimisers); tet-cell
        // with the whole input on every rank, said.
        let by_rows = *name != "tet-cell";
        match by_rows {
            true => assert!(said.contains("each rank reading its rows"), "{name}: {said}"),
            false => assert!(
                said.contains("tet-cell on distributed") && said.contains("every rank reads the whole input"),
                "{name}: {said}"
            ),
        }
        let files: &[&str] = if by_rows { &["cells.csv", "neighbors.csv", "sites.xyz"] } else { &["cells.csv"] };
        same_files(&one, &out, files, &format!("{name}, {ranks} ranks"));
        let s = summary(&out);
        if *name == "transport" {
            same_files(&one, &out, &["weights.txt"], &format!("{name}, {ranks} ranks"));
            assert_eq!(s["transport"]["step_max_error"], summary(&one)["transport"]["step_max_error"]);
            assert_eq!(s["transport"]["converged"], true);
        }
        if *name == "geometry" {
            // Each rank's polyhedra: the same walls, and VTK reads the
            // pieces as one grid holding every cell once, as one
            // process wrote it.
            assert!(walls(&one.join("walls.ply")) == walls(&out.join("walls.ply")), "{ranks} ranks: walls.ply");
            assert_eq!(s["pieces"], summary(&one)["pieces"], "{ranks} ranks: pieces");
            // The pictures, each rank drawing its own cells' pieces: one
            // process's bytes. The pieces' files: one process's pieces,
            // each once, as VTK reads them.
            same_files(&one, &out, &["picture.png", "cells.png"], &format!("{name}, {ranks} ranks"));
            if vtk_here() {
                let (whole, parts) = (vtk_pieces(&one.join("pieces.vtu")), vtk_pieces(&out.join("pieces.pvtu")));
                assert!(whole.len() > 11_000 && whole.iter().any(|p| p.1 == -1), "{} pieces", whole.len());
                assert!(parts == whole, "{ranks} ranks: pieces.pvtu holds {} pieces of {}", parts.len(), whole.len());
            }
            if vtk_here() {
                let (whole, parts) = (vtk_cells(&one.join("cells.vtu")), vtk_cells(&out.join("cells.pvtu")));
                assert!(whole.len() > 11_000, "one process's cells.vtu: {} cells", whole.len());
                assert_eq!(parts.len(), whole.len(), "{ranks} ranks: cells in cells.pvtu");
                for (a, b) in whole.iter().zip(&parts) {
                    assert_eq!((a.0, a.1.to_bits(), a.3), (b.0, b.1.to_bits(), b.3), "{ranks} ranks: a cell");
                    assert!((a.2 - b.2).abs() <= 1e-12 * a.2.abs(), "{ranks} ranks: VTK's volume of {}", a.0);
                }
            }
        }
        if *name == "index" {
            let header = std::fs::read_to_string(out.join("cells.csv")).unwrap();
            assert!(header.lines().next().unwrap().contains(",n5,n6"), "{name}: the index columns");
            let indices = &s["particles"]["top_indices"];
            assert!(indices.as_array().is_some_and(|a| !a.is_empty()), "{name}: {s}");
            assert_eq!(indices, &summary(&one)["particles"]["top_indices"], "{name}: the most common indices");
            assert_eq!(s["particles"]["mean_coordination"], summary(&one)["particles"]["mean_coordination"]);
        }
        if *name == "power" {
            let volumes = |dir: &Path| -> Vec<f64> {
                let text = std::fs::read_to_string(dir.join("cells.csv")).unwrap();
                text.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect()
            };
            let (power, plain) = (volumes(&out), volumes(&dir.join("cells-one")));
            let empty = power.iter().filter(|&&v| v == 0.0).count();
            let moved = power.iter().zip(&plain).filter(|(a, b)| (*a - *b).abs() > 1e-3 * *b).count();
            // (The tight cluster's cells are emptied by their heavier
            // neighbours: about 3 000.)
            assert!(empty < power.len() / 3 && moved > power.len() / 2, "{empty} empty, {moved} changed");
        }
        if by_rows {
            let records = s["ranks"].as_array().unwrap();
            assert_eq!(records.len(), ranks, "{name}: {s}");
            let n = summary(&one)["sites"].as_u64().unwrap();
            let owned: u64 = records.iter().map(|r| r["owned"].as_u64().unwrap()).sum();
            assert_eq!(owned, n, "{name}: every site's cell built once");
            let rows: u64 = records.iter().map(|r| r["rows"].as_u64().unwrap()).sum();
            assert_eq!(rows, n, "{name}: every row read once");
        } else {
            assert_eq!(s["parts"]["ranks"], ranks, "{name}: {ranks} ranks");
            let built: u64 =
                s["parts"]["all"].as_array().unwrap().iter().map(|r| r["listed_sites"].as_u64().unwrap()).sum();
            assert!(built > 0, "{name}: {s}");
        }
    }
    assert_eq!(std::fs::read_dir(scratch).unwrap().count(), 0, "the ranks' rows left nothing in --scratch");
    // --output and --json: copies of the folder's cells.csv (one process's
    // bytes) and summary.json, each rank reading its rows.
    let (csv, json) = (dir.join("copy.csv"), dir.join("copy.json"));
    let copies = ["--output", csv.to_str().unwrap(), "--json", json.to_str().unwrap()];
    let out = dir.join("copies-2");
    let o = mpirun_job(&torus, 2, &out, &[&cases[0].1[..3], &copies[..]].concat());
    ok(&o, "2 ranks, --output and --json");
    assert!(String::from_utf8_lossy(&o.stdout).contains("each rank reading its rows"));
    assert!(read(&csv) == read(&dir.join("cells-one").join("cells.csv")), "--output: one process's cells.csv");
    assert!(read(&json) == read(&out.join("summary.json")), "--json: the run's summary.json");
    // A scratch folder that is not there: refused by name, before anything
    // is computed.
    let out = dir.join("no-scratch");
    let o = mpirun_job(&torus, 2, &out, &["--sites", "600", "--no-geometry", "--scratch", "/no/such/folder"]);
    let said = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{said}");
    assert!(said.contains("--scratch /no/such/folder: no such folder"), "{said}");
    // Few sites in many tets: one process takes tet-cell by default; the
    // ranks take whole cells and say so (one process's whole cells' bytes).
    let few = ["--sites", "600", "--no-geometry"];
    let one = dir.join("few-one");
    ok(&cvd_job(&torus, &one, &[&few[..], &["--strategy", "whole"]].concat()), "few sites: one process");
    let out = dir.join("few-2");
    let o = mpirun_job(&torus, 2, &out, &few);
    ok(&o, "few sites: 2 ranks");
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("in parts: whole cells, where one process takes tet-cell"), "{said}");
    same_files(&one, &out, &["cells.csv", "neighbors.csv"], "few sites, 2 ranks");
    // A density (every rank evaluating it at the mesh's vertices) with
    // Lloyd: one process takes tet-cell under a density; the ranks take
    // whole cells, say so, and give one process's whole cells' bytes.
    let dense = ["--sites", "4000", "--density", "1+8*x^2", "--iterations", "2", "--no-geometry"];
    let one = dir.join("density-one");
    ok(&cvd_job(&torus, &one, &[&dense[..], &["--strategy", "whole"]].concat()), "density: one process");
    let ranks = 3;
    let out = dir.join(format!("density-{ranks}"));
    let o = mpirun_job(&torus, ranks, &out, &dense);
    ok(&o, &format!("density: {ranks} ranks"));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("each rank reading its rows"), "density: {said}");
    assert!(said.contains("where one process takes tet-cell (under a density)"), "{said}");
    same_files(&one, &out, &["cells.csv", "neighbors.csv", "sites.xyz"], &format!("density, {ranks} ranks"));
    // On Vulkan (lavapipe here): each rank's cells built on the device in
    // its window of held cells, the polyhedra on the CPU; optimal
    // transport's diagrams too: one process's device run, byte for byte.
    let device = ["run", "--model", "torus", "--resolution", "12", "--backend", "vulkan", "--strategy", "whole"];
    let cases: [(&str, &[&str], &[&str]); 2] = [
        ("device", &["--sites", "6000", "--no-picture"], &["cells.csv", "neighbors.csv", "sites.xyz"]),
        (
            "device-transport",
            &["--sites", "3000", "--volumes", "lognormal:0,0.5", "--no-geometry"],
            &["cells.csv", "neighbors.csv", "sites.xyz", "weights.txt"],
        ),
    ];
    for (name, args, files) in cases {
        let one = dir.join(format!("{name}-one"));
        ok(&cvd_job(&device, &one, args), &format!("{name}: one process"));
        let out = dir.join(format!("{name}-2"));
        let o = mpirun_job(&device, 2, &out, args);
        ok(&o, &format!("{name}: 2 ranks"));
        let said = String::from_utf8_lossy(&o.stdout);
        assert!(said.contains("each rank reading its rows), whole cells on vulkan"), "{name}: {said}");
        same_files(&one, &out, files, &format!("{name}, 2 ranks"));
        if name == "device" {
            assert!(walls(&one.join("walls.ply")) == walls(&out.join("walls.ply")), "{name}: walls.ply");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_mesh_in_parts_holds_a_fraction_of_one_process_memory() {
    if !mpi_here() {
        return;
    }
    // 10^6 sites in a cube of 6 000 tets (every rank holds the mesh), with
    // their faces: each rank's peak against one process's (both on one
    // thread), measured by the processes themselves (VmHWM); the ranks
    // each in the parts they take by default (4, one after another).
    let dir = temp_dir("mesh-memory");
    struct Removed(PathBuf);
    impl Drop for Removed {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    let _removed = Removed(dir.clone());
    let job = ["run", "--model", "cube", "--resolution", "10", "--no-picture", "--no-geometry", "--strategy", "whole"];
    let args = ["--sites", "1000000", "--threads", "1"];
    let one = dir.join("one");
    ok(&cvd_job(&job, &one, &args), "one process");
    let peak = summary(&one)["peak_memory_bytes"].as_f64().unwrap();
    assert!(peak > 0.0, "the peak is measured here");
    // (By default 4 parts a rank, the rows' faces kept in a file until
    // written: 2 ranks peak at about 0.30, 4 at 0.20; with the rows in
    // memory, 0.55 and 0.33; with one part a rank too, 0.80 and 0.50.)
    for (ranks, most) in [(2, 0.42), (4, 0.28)] {
        let out = dir.join(format!("ranks{ranks}"));
        let o = mpirun_job(&job, ranks, &out, &args[..2]);
        ok(&o, &format!("{ranks} ranks"));
        same_files(&one, &out, &["cells.csv", "neighbors.csv"], &format!("{ranks} ranks"));
        let left: Vec<_> = std::fs::read_dir(&out).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
        assert!(
            !left.iter().any(|f| f.to_string_lossy().starts_with(".cvd-spill")),
            "{ranks} ranks: a spill file left in the output folder: {left:?}"
        );
        for r in summary(&out)["ranks"].as_array().unwrap() {
            assert_eq!(r["parts"], 4, "{ranks} ranks: the parts a rank takes by default");
            assert_eq!(r["widened"], 0, "{ranks} ranks: uniform sites take their first halo");
            let share = r["peak_memory_bytes"].as_f64().unwrap() / peak;
            eprintln!("{ranks} ranks x 4 parts: rank {} peak {:.3} of one process's", r["rank"], share);
            assert!(share <= most, "{ranks} ranks: rank {} peaked at {share:.3} of one process's", r["rank"]);
        }
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn a_mesh_too_large_for_one_process_runs_in_parts_that_fit() {
    if !mpi_here() {
        return;
    }
    // A budget the whole job exceeds and each rank's parts fit: one
    // process refuses it, the ranks read their rows of the file and run.
    let dir = temp_dir("mesh-budget");
    let n = 200_000;
    let mesh = cvd::mesher::models::builtin("cube", Some(10)).unwrap();
    let npy = dir.join("sites.npy");
    cvd_io::write_sites_npy(&npy, &cvd::geom::points::in_mesh(&mesh, n, 9)).unwrap();
    let whole = cvd::job::memory::JobSize { sites: n as u64, tets: mesh.tets.len() as u64, k_site: 48, faces: true };
    let budget = ((whole.bytes() / 2) >> 20).to_string();
    let job = ["run", "--model", "cube", "--resolution", "10", "--no-picture", "--no-geometry"];
    let args = ["--sites-file", npy.to_str().unwrap(), "--memory-budget", &budget];
    let o = cvd_job(&job, &dir.join("one"), &args);
    assert_eq!(o.status.code(), Some(2), "one process: {}", String::from_utf8_lossy(&o.stdout));
    assert!(String::from_utf8_lossy(&o.stderr).contains("memory budget"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = mpirun_job(&job, 4, &dir.join("four"), &[&args[..], &["--parts", "2"]].concat());
    ok(&o, "4 ranks x 2 parts under the budget");
    assert_eq!(cvd_io::read_cells_csv(&dir.join("four").join("cells.csv")).unwrap().len(), n);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn lloyd_over_mpi_moves_the_sites_of_one_process() {
    if !mpi_here() {
        return;
    }
    let dir = temp_dir("lloyd");
    let args = ["--strategy", "tet-cell", "--sites", "8000", "--iterations", "4", "--parts", "2"];
    let one = dir.join("one");
    ok(&cvd(&one, &args[..6]), "one process");
    let out = dir.join("three");
    ok(&mpirun(3, &out, &args), "3 ranks x 2 parts");
    same_files(&one, &out, &["sites.xyz", "cells.csv"], "3 ranks x 2 parts");
}

/// A periodic box's run, without pictures.
const BOX: &[&str] = &["run", "--periodic", "--no-picture"];

/// `summary.json` of a run.
fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&read(&out.join("summary.json"))).unwrap()
}

#[test]
fn mpirun_gives_a_periodic_box_in_parts_byte_for_byte() {
    if !mpi_here() {
        return;
    }
    let dir = temp_dir("periodic");
    // A crowd with a tight cluster in a triclinic cell, some given outside
    // it, as an .npy; a slab with walls as text; sites made by each rank.
    let cell = cvd::PeriodicBox::lammps([0.0; 3], [30.0, 25.0, 28.0], [4.0, -3.0, 2.0]).unwrap();
    let crowd = cvd::geom::points::uniform(18_000, 3);
    let blob = cvd::geom::points::clustered(2_000, 1, 0.01, 4);
    let mut sites: Vec<[f64; 3]> = crowd.iter().chain(&blob).map(|&s| cell.cartesian(s)).collect();
    for i in (0..sites.len()).step_by(89) {
        sites[i] = cell.shifted(sites[i], [2, 0, -1]);
    }
    let npy = dir.join("crowd.npy");
    cvd_io::write_sites_npy(&npy, &sites).unwrap();
    let slab: Vec<[f64; 3]> =
        cvd::geom::points::uniform(12_000, 5).iter().map(|p| [40.0 * p[0], 30.0 * p[1], 10.0 * p[2]]).collect();
    let xyz = dir.join("slab.xyz");
    cvd_io::write_sites_xyz(&xyz, &slab).unwrap();
    let (npy, xyz) = (npy.to_str().unwrap(), xyz.to_str().unwrap());
    let cases: [(&str, Vec<&str>, usize); 3] = [
        ("crowd", vec!["--box", "0,0,0,30,25,28", "--tilt", "4,-3,2", "--sites-file", npy], 20_000),
        ("slab", vec!["--box", "0,0,0,40,30,10", "--periodic-axes", "xy", "--sites-file", xyz], 12_000),
        ("made", vec!["--box", "0,0,0,20,30,25", "--sites", "15000", "--seed", "9"], 15_000),
    ];
    for (name, args, n) in &cases {
        let one = dir.join(format!("{name}-one"));
        ok(&cvd_job(BOX, &one, args), &format!("{name}: one process"));
        // The points of the whole job: the sites and their images.
        let whole = *n as u64 + summary(&one)["periodic"]["images"].as_u64().unwrap();
        for ranks in 1..=4 {
            let out = dir.join(format!("{name}-{ranks}"));
            let o = mpirun_job(BOX, ranks, &out, args);
            ok(&o, &format!("{name}: {ranks} ranks"));
            same_files(&one, &out, &["cells.csv", "neighbors.csv", "sites.xyz"], &format!("{name}, {ranks} ranks"));
            let s = summary(&out);
            let records = s["ranks"].as_array().unwrap();
            assert_eq!(records.len(), ranks, "{name}: a record per rank");
            let sum = |key: &str| records.iter().map(|r| r[key].as_u64().unwrap()).sum::<u64>();
            assert_eq!((sum("rows"), sum("owned")), (*n as u64, *n as u64), "{name}, {ranks} ranks: every row once");
            for r in records {
                // Each rank read its share of the rows, and held a part of
                // the job's points.
                assert!(r["rows"].as_u64().unwrap() <= (*n / ranks + 1) as u64, "{name}: {r}");
                if ranks > 1 {
                    assert!(r["held"].as_u64().unwrap() < whole, "{name}: a rank held the whole job: {r}");
                }
            }
            assert_eq!(s["volume_sum"].as_f64().map(|v| v > 0.0), Some(true));
            // Rank 0 alone speaks.
            let said = String::from_utf8_lossy(&o.stdout);
            assert_eq!(said.matches("wrote ").count(), 1, "{said}");
        }
    }
    // Exchanges in many rounds (as MPI's int counts make them at scale): the
    // same bytes.
    let (one, out) = (dir.join("made-one"), dir.join("made-rounds"));
    let o = mpirun_env(BOX, 3, &out, &cases[2].1, &[("CVD_MPI_ROUND_BYTES", "4096")]);
    ok(&o, "3 ranks, exchanges of 4096 bytes per pair and call");
    same_files(&one, &out, &["cells.csv", "neighbors.csv", "sites.xyz"], "in rounds");
    // --output and --json: copies of the folder's cells.csv (one process's
    // bytes) and summary.json.
    let out = dir.join("made-copies");
    let (csv, json) = (dir.join("copy.csv"), dir.join("copy.json"));
    let copies = ["--output", csv.to_str().unwrap(), "--json", json.to_str().unwrap()];
    ok(&mpirun_job(BOX, 2, &out, &[&cases[2].1[..], &copies[..]].concat()), "2 ranks, --output and --json");
    assert!(read(&csv) == read(&one.join("cells.csv")), "--output: one process's cells.csv");
    assert!(read(&json) == read(&out.join("summary.json")), "--json: the run's summary.json");
    // A bad line in one rank's part: it says so, and every rank ends (none
    // waits for it), within a bound.
    let bad = dir.join("bad.xyz");
    let mut text = String::new();
    for (i, p) in slab.iter().enumerate() {
        text += &if i == 9_000 { "1.0 2.0 x\n".to_string() } else { format!("{} {} {}\n", p[0], p[1], p[2]) };
    }
    std::fs::write(&bad, text).unwrap();
    let o = mpirun_job(BOX, 3, &dir.join("bad"), &["--box", "0,0,0,40,30,10", "--sites-file", bad.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&o.stderr);
    assert_ne!(o.status.code(), Some(124), "the ranks waited for the one that failed: {said}");
    assert!(!o.status.success() && said.contains("bad.xyz") && said.contains("byte"), "{said}");
    // On a device (lavapipe here): each part one windowed whole-cell job,
    // the files one process's device run's, byte for byte, and with
    // --voronoi-index the polyhedra from a run on the CPU, as one process;
    // optimal transport on the device (its whole cells' f32 masses round
    // near 1e-6 of a cell: a tolerance above that).
    let device = ["--backend", "vulkan", "--box", "0,0,0,20,30,25", "--seed", "9"];
    let transport = ["--sites", "2500", "--volumes", "lognormal:0,0.3", "--tolerance", "1e-5"];
    for (name, extra) in
        [("device-index", &["--sites", "8000", "--voronoi-index"][..]), ("device-transport", &transport[..])]
    {
        let args = [&device[..], extra].concat();
        let one = dir.join(format!("{name}-one"));
        ok(&cvd_job(BOX, &one, &[&args[..], &["--strategy", "whole"]].concat()), &format!("{name}: one process"));
        let out = dir.join(format!("{name}-2"));
        let o = mpirun_job(BOX, 2, &out, &args);
        ok(&o, &format!("{name}: 2 ranks"));
        let said = String::from_utf8_lossy(&o.stdout);
        assert!(said.contains("whole cells on vulkan"), "{name}: {said}");
        same_files(&one, &out, &["cells.csv", "neighbors.csv", "sites.xyz"], &format!("{name}, 2 ranks"));
        if name == "device-transport" {
            same_files(&one, &out, &["weights.txt"], "device transport, 2 ranks");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A LAMMPS dump of `frames` frames of `n` atoms each: ids a shuffled
/// sparse set, a radius column; frame 0 a periodic box, frame 1 walls
/// along z, frame 2 a triclinic cell (its bounds the tilted cell's
/// bounding box, as LAMMPS writes them), each atom moved a little between
/// frames.
fn dump(n: usize, frames: usize) -> String {
    use std::fmt::Write;
    let l = (n as f64).cbrt() * 1.1;
    let mut state = 11u64;
    let mut next = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut ids: Vec<u64> = (0..n as u64).map(|i| 7 * i + 3).collect();
    for i in (1..n).rev() {
        ids.swap(i, (next() * (i + 1) as f64) as usize);
    }
    let mut at: Vec<[f64; 3]> = (0..n).map(|_| [next() * l, next() * l, next() * l]).collect();
    let radii: Vec<f64> = (0..n).map(|_| 0.3 + 0.2 * next()).collect();
    let mut out = String::new();
    for f in 0..frames {
        let bounds = match f % 3 {
            0 => format!("ITEM: BOX BOUNDS pp pp pp\n0 {l}\n0 {l}\n0 {l}\n"),
            1 => format!("ITEM: BOX BOUNDS pp pp ff\n0 {l}\n0 {l}\n0 {l}\n"),
            _ => format!("ITEM: BOX BOUNDS xy xz yz pp pp pp\n0 {} 1\n-0.5 {l} 0.5\n0 {l} -0.5\n", l + 1.5),
        };
        write!(
            out,
            "ITEM: TIMESTEP\n{}\nITEM: NUMBER OF ATOMS\n{n}\n{bounds}ITEM: ATOMS id type x y z radius\n",
            100 * f
        )
        .unwrap();
        for i in 0..n {
            for c in &mut at[i] {
                *c = (*c + 0.05 * (next() - 0.5)).clamp(0.0, l);
            }
            let [x, y, z] = at[i];
            writeln!(out, "{} 1 {x} {y} {z} {}", ids[i], radii[i]).unwrap();
        }
    }
    out
}

#[test]
fn mpirun_gives_a_trajectorys_frames_byte_for_byte() {
    if !mpi_here() {
        return;
    }
    let dir = temp_dir("frames");
    let path = dir.join("dump.atoms");
    std::fs::write(&path, dump(4000, 3)).unwrap();
    let file = path.to_str().unwrap();
    // An extended XYZ without ids (the file's order), in a periodic cell.
    let xyz = dir.join("particles.extxyz");
    let mut text = String::new();
    for f in 0..2 {
        let sites = cvd::geom::points::uniform(3000, 20 + f);
        text += "3000\nLattice=\"14 0 0 0 15 0 0 0 16\" Properties=species:S:1:pos:R:3 pbc=\"T T T\"\n";
        for p in sites {
            text += &format!("Ar {} {} {}\n", 14.0 * p[0], 15.0 * p[1], 16.0 * p[2]);
        }
    }
    std::fs::write(&xyz, text).unwrap();
    // Fewer atoms than ranks: a rank reads no rows.
    let tiny = dir.join("tiny.lammpstrj");
    let box4 = "ITEM: BOX BOUNDS pp pp pp\n0 4\n0 4\n0 4\n";
    std::fs::write(
        &tiny,
        format!("ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n2\n{box4}ITEM: ATOMS id type x y z\n5 1 1 1 1\n2 1 3 3 3\n"),
    )
    .unwrap();
    let frames = |n: usize| (0..n).map(|f| format!("frames/cells.{f:06}.csv")).collect::<Vec<_>>();
    let cases: [(&str, Vec<&str>, usize); 4] = [
        ("dump", vec!["--particles", file], 3),
        ("index", vec!["--particles", file, "--frames", "1:3", "--voronoi-index"], 0),
        ("extxyz", vec!["--particles", xyz.to_str().unwrap()], 2),
        ("tiny", vec!["--particles", tiny.to_str().unwrap()], 1),
    ];
    for (name, args, n) in &cases {
        let files = match *name {
            "index" => vec!["frames/cells.000001.csv".to_string(), "frames/cells.000002.csv".to_string()],
            _ => frames(*n),
        };
        let files: Vec<&str> = files.iter().map(String::as_str).collect();
        let one = dir.join(format!("{name}-one"));
        ok(&cvd_job(&["run"], &one, args), &format!("{name}: one process"));
        for ranks in [2, 3] {
            let out = dir.join(format!("{name}-{ranks}"));
            let o = mpirun_job(&["run"], ranks, &out, args);
            ok(&o, &format!("{name}: {ranks} ranks"));
            same_files(&one, &out, &files, &format!("{name}, {ranks} ranks"));
            let (a, b) = (summary(&one), summary(&out));
            for f in 0..files.len() {
                for key in ["frame", "timestep", "particles", "periodic", "images", "empty_cells", "file"] {
                    assert_eq!(a["frames"][f][key], b["frames"][f][key], "{name}, {ranks} ranks: frame {f}'s {key}");
                }
            }
            let said = String::from_utf8_lossy(&o.stdout);
            assert!(said.contains("in parts over MPI") && said.matches("wrote ").count() == 1, "{said}");
        }
    }
    // An id twice, in the parts of two ranks: named by its lines, exit 2.
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let (first, again) = (9, 9 + 3000);
    let id = lines[first].split(' ').next().unwrap().to_string();
    let moved = lines[again].split_once(' ').unwrap().1.to_string();
    let mut bad: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    bad[again] = format!("{id} {moved}");
    let bad_path = dir.join("bad.lammpstrj");
    std::fs::write(&bad_path, bad.join("\n") + "\n").unwrap();
    let o = mpirun_job(&["run"], 3, &dir.join("bad"), &["--particles", bad_path.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&o.stderr);
    let expected =
        format!("bad.lammpstrj:{}: frame 0: atom id {id} again (it is on line {} too)", again + 1, first + 1);
    assert_ne!(o.status.code(), Some(124), "the ranks waited for the one that failed: {said}");
    assert!(!o.status.success() && said.contains(&expected), "{:?}: {said}", o.status.code());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mpirun_moves_the_sites_as_one_process_does() {
    if !mpi_here() {
        return;
    }
    // Lloyd and L-BFGS in parts: each rank moves its own rows, every sum is
    // exact, so the steps are one process's. Few sites for the ranks: at 3
    // and 4 ranks some own no block of the box (and send nothing).
    let dir = temp_dir("cvt");
    for optimizer in ["lloyd", "lbfgs"] {
        let args = ["--box", "0,0,0,14,16,12", "--sites", "3000", "--iterations", "3", "--optimizer", optimizer];
        let one = dir.join(format!("{optimizer}-one"));
        ok(&cvd_job(BOX, &one, &args), &format!("{optimizer}: one process"));
        let energies = |dir: &Path| summary(dir)["cvt"]["energy"].clone();
        assert_eq!(energies(&one).as_array().map(|e| e.len()), Some(3), "{optimizer}: one process's record");
        let mut idle = 0;
        for ranks in 2..=4 {
            let out = dir.join(format!("{optimizer}-{ranks}"));
            ok(&mpirun_job(BOX, ranks, &out, &args), &format!("{optimizer}: {ranks} ranks"));
            same_files(
                &one,
                &out,
                &["cells.csv", "neighbors.csv", "sites.xyz"],
                &format!("{optimizer}, {ranks} ranks"),
            );
            assert_eq!(energies(&out), energies(&one), "{optimizer}, {ranks} ranks: the energies");
            assert_eq!(summary(&out)["energy"], summary(&one)["energy"], "{optimizer}, {ranks} ranks");
            assert!(out.join("energy.png").is_file(), "{optimizer}, {ranks} ranks: energy.png");
            let s = summary(&out);
            idle += s["ranks"].as_array().unwrap().iter().filter(|r| r["blocks"].as_u64() == Some(0)).count();
        }
        assert!(idle > 0, "{optimizer}: every rank had blocks; the case of a rank without is not tested");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The walls of a `walls.ply`, as a sorted list of (site, neighbour, the
/// loop's points' bits): the file read whole, every byte accounted for.
fn walls(path: &Path) -> Vec<(i32, i32, Vec<[u64; 3]>)> {
    let bytes = read(path);
    let end = b"end_header\n";
    let body = bytes.windows(end.len()).position(|w| w == end).expect("a PLY header") + end.len();
    let header = String::from_utf8_lossy(&bytes[..body]).to_string();
    let count = |what: &str| -> usize {
        header.split(what).nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap()
    };
    let (points, faces) = (count("element vertex "), count("element face "));
    let f64_at = |at: usize| f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    let i32_at = |at: usize| i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let point = |k: usize| [0, 1, 2].map(|a| f64_at(body + 24 * k + 8 * a).to_bits());
    let mut at = body + 24 * points;
    let mut walls = Vec::with_capacity(faces);
    for _ in 0..faces {
        let n = bytes[at] as usize;
        let ring = (0..n).map(|v| point(i32_at(at + 1 + 4 * v) as usize)).collect();
        at += 1 + 4 * n;
        walls.push((i32_at(at), i32_at(at + 4), ring));
        at += 8;
    }
    assert_eq!(at, bytes.len(), "{}: bytes after the last face", path.display());
    walls.sort();
    walls
}

/// What `tests/scripts/SCRIPT` (Python with VTK) prints of `path`.
fn vtk_read(script: &str, path: &Path) -> serde_json::Value {
    let script = env!("CARGO_MANIFEST_DIR").to_string() + "/../tests/scripts/" + script;
    let o = Command::new("python3").arg(script).arg(path).output().unwrap();
    assert!(o.status.success(), "VTK on {}: {}", path.display(), String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// The cells of a `cells.vtu` or `cells.pvtu` as VTK reads them, by site:
/// (site, stored volume, VTK's measure of the polyhedron, faces).
fn vtk_cells(path: &Path) -> Vec<(i64, f64, f64, i64)> {
    let json = vtk_read("read_cells_vtu.py", path);
    let mut cells: Vec<(i64, f64, f64, i64)> = json["cells"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let f = |k: &str| c[k].as_f64().unwrap();
            (c["site"].as_i64().unwrap(), f("volume"), f("vtk_volume"), c["faces"].as_i64().unwrap())
        })
        .collect();
    cells.sort_by_key(|c| c.0);
    cells
}

/// The pieces of a `pieces.vtu` or `pieces.pvtu` as VTK reads them,
/// sorted: (site, tet, stored volume's bits, faces).
fn vtk_pieces(path: &Path) -> Vec<(i64, i64, u64, i64)> {
    let json = vtk_read("read_pieces_vtk.py", path);
    let mut pieces: Vec<(i64, i64, u64, i64)> = json["pieces"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let i = |k: usize| p[k].as_i64().unwrap();
            (i(0), i(1), p[2].as_f64().unwrap().to_bits(), i(3))
        })
        .collect();
    pieces.sort_unstable();
    pieces
}

/// Whether `python3` with VTK runs here (skipped with the reason; under
/// `CI=true` its absence fails).
fn vtk_here() -> bool {
    match Command::new("python3").args(["-c", "import vtk"]).output() {
        Ok(o) if o.status.success() => true,
        _ if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("CI=true: python3 with vtk is needed"),
        _ => {
            eprintln!("skipped: python3 with vtk is not here (pip install vtk)");
            false
        }
    }
}

#[test]
fn mpirun_gives_power_cells_in_parts_byte_for_byte() {
    if !mpi_here() {
        return;
    }
    // Polydisperse particles (radii, voro++'s radical cells) in a triclinic
    // cell, and weights in a slab with walls: each rank reads a part of
    // the values file and sends each value to its site's rank.
    let dir = temp_dir("power");
    let n = 6000;
    let unit = cvd::geom::points::uniform(n, 31);
    let radii: String = unit.iter().map(|p| format!("{}\n", 0.2 + 0.5 * p[0] * p[1])).collect();
    let weights: String = unit.iter().map(|p| format!("{}\n", p[2] - 0.5)).collect();
    let (r, w) = (dir.join("radii.txt"), dir.join("weights.txt"));
    std::fs::write(&r, format!("# radii\n{radii}")).unwrap();
    std::fs::write(&w, weights).unwrap();
    let (r, w) = (r.to_str().unwrap(), w.to_str().unwrap());
    let n = n.to_string();
    let cases: [(&str, Vec<&str>); 2] = [
        ("radii", vec!["--box", "0,0,0,18,17,19", "--tilt", "2,-1,3", "--sites", &n, "--radii", r]),
        ("weights", vec!["--box", "0,0,0,30,25,8", "--periodic-axes", "xy", "--sites", &n, "--weights", w]),
    ];
    for (name, args) in &cases {
        let one = dir.join(format!("{name}-one"));
        ok(&cvd_job(BOX, &one, args), &format!("{name}: one process"));
        for ranks in [2, 4] {
            let out = dir.join(format!("{name}-{ranks}"));
            ok(&mpirun_job(BOX, ranks, &out, args), &format!("{name}: {ranks} ranks"));
            same_files(&one, &out, &["cells.csv", "neighbors.csv", "sites.xyz"], &format!("{name}, {ranks} ranks"));
        }
    }
    // The Voronoi index of each radical cell, measured on the rank that
    // built it: the same cells.csv (its index columns too).
    let index = dir.join("index-one");
    let args = ["--box", "0,0,0,18,17,19", "--periodic-axes", "xy", "--sites", &n, "--radii", r, "--voronoi-index"];
    ok(&cvd_job(BOX, &index, &args), "--voronoi-index: one process");
    let header = String::from_utf8_lossy(&read(&index.join("cells.csv"))).lines().next().unwrap_or("").to_string();
    assert!(header.contains("coordination"), "{header}");
    for ranks in [2, 3] {
        let out = dir.join(format!("index-{ranks}"));
        let o = mpirun_job(BOX, ranks, &out, &args);
        ok(&o, &format!("--voronoi-index: {ranks} ranks"));
        same_files(&index, &out, &["cells.csv", "neighbors.csv"], &format!("--voronoi-index, {ranks} ranks"));
        // summary.json's most common indices: every rank's cells counted.
        let (one, parts) = (summary(&index)["particles"].clone(), summary(&out)["particles"].clone());
        assert!(one["top_indices"].as_array().is_some_and(|a| !a.is_empty()), "{one}");
        assert_eq!(parts, one, "{ranks} ranks: the most common indices");
        // walls.ply: the same walls, each rank's after the ranks' before.
        assert!(walls(&index.join("walls.ply")) == walls(&out.join("walls.ply")), "{ranks} ranks: walls.ply's walls");
        // VTK reads the pieces as one grid: every cell once, each as one
        // process wrote it (the same stored volume, VTK's measure of it).
        if vtk_here() {
            let (whole, parts) = (vtk_cells(&index.join("cells.vtu")), vtk_cells(&out.join("cells.pvtu")));
            // (Radical cells: a small particle beside large ones may have none.)
            assert!(whole.len() > 5900, "one process's cells.vtu: {} cells", whole.len());
            assert_eq!(parts.len(), whole.len(), "{ranks} ranks: cells in cells.pvtu");
            for (a, b) in whole.iter().zip(&parts) {
                assert_eq!((a.0, a.1.to_bits(), a.3), (b.0, b.1.to_bits(), b.3), "{ranks} ranks: a cell");
                assert!((a.2 - b.2).abs() <= 1e-12 * a.2.abs(), "{ranks} ranks: VTK's volume of site {}", a.0);
            }
        }
    }
    // Too few values, and a bad radius named by its particle's row.
    let short = dir.join("short.txt");
    std::fs::write(&short, &radii[..radii.len() / 2]).unwrap();
    let args = ["--box", "0,0,0,18,17,19", "--sites", &n, "--radii", short.to_str().unwrap()];
    let o = mpirun_job(BOX, 3, &dir.join("short"), &args);
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && said.contains("short.txt") && said.contains("radii for 6000 sites"), "{said}");
    let bad = dir.join("bad.txt");
    let mut lines: Vec<String> = radii.lines().map(str::to_string).collect();
    lines[5000] = "-0.5".into();
    std::fs::write(&bad, lines.join("\n")).unwrap();
    let args = ["--box", "0,0,0,18,17,19", "--sites", &n, "--radii", bad.to_str().unwrap()];
    let o = mpirun_job(BOX, 3, &dir.join("bad"), &args);
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && said.contains("particle 5000's radius is -0.5"), "{said}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mpirun_solves_optimal_transport_as_one_process() {
    if !mpi_here() {
        return;
    }
    // Each rank its rows of the weights; the Newton system's Laplacian and
    // its conjugate gradients across ranks (a row's neighbours on other
    // ranks fetched each iteration), every sum exact: the same weights,
    // steps and files. Capacities read by parts, volumes drawn by rows,
    // and the capacity-constrained CVT.
    let dir = temp_dir("transport");
    let capacities: String =
        cvd::geom::points::uniform(3000, 51).iter().map(|p| format!("{}\n", 1.0 + 3.0 * p[0])).collect();
    let c = dir.join("capacities.txt");
    std::fs::write(&c, capacities).unwrap();
    let c = c.to_str().unwrap();
    let cases: [(&str, Vec<&str>); 3] = [
        ("capacities", vec!["--box", "0,0,0,14,16,12", "--tilt", "1,2,-1", "--sites", "3000", "--capacities", c]),
        ("volumes", vec!["--box", "0,0,0,14,16,12", "--sites", "3000", "--volumes", "lognormal:0,0.3"]),
        ("ccvt", vec!["--box", "0,0,0,10,11,12", "--sites", "1500", "--transport", "--iterations", "1"]),
    ];
    for (name, args) in &cases {
        let one = dir.join(format!("{name}-one"));
        ok(&cvd_job(BOX, &one, args), &format!("{name}: one process"));
        let steps = |dir: &Path| summary(dir)["transport"]["step_max_error"].clone();
        assert!(steps(&one).as_array().is_some_and(|s| s.len() > 1), "{name}: one process's record");
        for ranks in [2, 3] {
            let out = dir.join(format!("{name}-{ranks}"));
            ok(&mpirun_job(BOX, ranks, &out, args), &format!("{name}: {ranks} ranks"));
            let files = ["cells.csv", "neighbors.csv", "sites.xyz", "weights.txt"];
            same_files(&one, &out, &files, &format!("{name}, {ranks} ranks"));
            assert_eq!(steps(&out), steps(&one), "{name}, {ranks} ranks: the Newton steps");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_job_too_large_for_one_process_runs_in_parts_that_fit() {
    if !mpi_here() {
        return;
    }
    // A budget the whole job exceeds and each of 4 ranks' parts fits: one
    // process refuses it, the ranks read their rows and run.
    let dir = temp_dir("budget");
    let n = 200_000;
    let sites: Vec<[f64; 3]> = cvd::geom::points::uniform(n, 7).iter().map(|p| p.map(|c| 60.0 * c)).collect();
    let npy = dir.join("sites.npy");
    cvd_io::write_sites_npy(&npy, &sites).unwrap();
    let whole = cvd::job::memory::JobSize { sites: 2 * n as u64, tets: 6, k_site: 48, faces: true }.bytes();
    let budget = ((whole / 2) >> 20).to_string();
    let args = ["--box", "0,0,0,60,60,60", "--sites-file", npy.to_str().unwrap(), "--memory-budget", &budget];
    let o = cvd_job(BOX, &dir.join("one"), &args);
    assert_eq!(o.status.code(), Some(2), "one process: {}", String::from_utf8_lossy(&o.stdout));
    assert!(String::from_utf8_lossy(&o.stderr).contains("memory budget"), "{}", String::from_utf8_lossy(&o.stderr));
    ok(&mpirun_job(BOX, 4, &dir.join("four"), &args), "4 ranks under the budget");
    assert_eq!(cvd_io::read_cells_csv(&dir.join("four").join("cells.csv")).unwrap().len(), n);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ranks_hold_a_fraction_of_one_process_memory() {
    if !mpi_here() {
        return;
    }
    // 10^6 sites: each rank's peak against one process's (both on one
    // thread), measured by the processes themselves (VmHWM).
    let dir = temp_dir("memory");
    // Its files (gigabytes of neighbours) go, whatever the outcome.
    struct Removed(PathBuf);
    impl Drop for Removed {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    let _removed = Removed(dir.clone());
    let args = ["--box", "0,0,0,100,100,100", "--sites", "1000000", "--threads", "1"];
    let one = dir.join("one");
    ok(&cvd_job(BOX, &one, &args), "one process");
    let peak = summary(&one)["peak_memory_bytes"].as_f64().unwrap();
    assert!(peak > 0.0, "the peak is measured here");
    for (ranks, most) in [(2, 0.6), (4, 0.35)] {
        let out = dir.join(format!("ranks{ranks}"));
        ok(&mpirun_job(BOX, ranks, &out, &args[..4]), &format!("{ranks} ranks"));
        assert!(read(&one.join("cells.csv")) == read(&out.join("cells.csv")), "{ranks} ranks: cells.csv differs");
        for r in summary(&out)["ranks"].as_array().unwrap() {
            let share = r["peak_memory_bytes"].as_f64().unwrap() / peak;
            eprintln!("{ranks} ranks: rank {} peak {:.3} of one process's", r["rank"], share);
            assert!(share <= most, "{ranks} ranks: rank {} peaked at {share:.3} of one process's", r["rank"]);
        }
        let _ = std::fs::remove_dir_all(&out);
    }
}
