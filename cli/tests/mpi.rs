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
    Command::new(env!("CARGO_BIN_EXE_cvd")).args(JOB).args(args).arg("--out").arg(out).output().unwrap()
}

/// `ranks` ranks of one thread each (Open MPI: more ranks than cores, and
/// as root in containers, when asked).
fn mpirun(ranks: usize, out: &Path, args: &[&str]) -> Output {
    Command::new("mpirun")
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1")
        .args(["-np", &ranks.to_string(), env!("CARGO_BIN_EXE_cvd")])
        .args(JOB)
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
    for file in ["sites.xyz", "cells.csv"] {
        assert_eq!(read(&one.join(file)), read(&out.join(file)), "{file}");
    }
}
