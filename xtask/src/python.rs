//! The Python package: its wheel (`cargo xtask wheel`) and its tests.
//!
//! The tests run the package as users get it: the wheel (with the SPIR-V
//! kernels, for the lavapipe comparisons) installed into a fresh virtual
//! environment whose PATH holds no Rust, then pytest there; and the front
//! door, `python -m pip install ./python` without the kernels into another
//! fresh environment, then a diagram from it. Where python3, venv, maturin
//! or pytest cannot be had, the tests are skipped with the reason — and
//! fail under `CI=true`.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Why the Python side could not run: skipped outside CI.
pub enum Problem {
    /// Python, venv or pip are missing here.
    Unavailable(String),
    /// Something ran and failed.
    Failed(String),
}

impl From<String> for Problem {
    fn from(s: String) -> Self {
        Problem::Failed(s)
    }
}

fn target(root: &Path) -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), PathBuf::from)
}

/// A virtual environment at `dir` (made again from nothing when `fresh`),
/// seeing the system's packages (numpy, the test tools); its python.
fn venv(dir: &Path, fresh: bool) -> Result<PathBuf, Problem> {
    let python = dir.join("bin").join("python");
    if fresh || !python.is_file() {
        let mut make = Command::new("python3");
        make.args(["-m", "venv", "--system-site-packages"]);
        if fresh {
            make.arg("--clear");
        }
        if !make.arg(dir).status().is_ok_and(|s| s.success()) {
            return Err(Problem::Unavailable(format!("python3 -m venv {} failed", dir.display())));
        }
    }
    Ok(python)
}

fn pip(python: &Path, args: &[&str]) -> bool {
    Command::new(python).args(["-m", "pip", "install", "--quiet"]).args(args).status().is_ok_and(|s| s.success())
}

fn has(python: &Path, module: &str) -> bool {
    Command::new(python).args(["-c", &format!("import {module}")]).output().is_ok_and(|o| o.status.success())
}

/// `PATH` with `first` in front and without the folders that hold cargo
/// or rustc (rustup's; the system's own folders stay, whatever they hold):
/// what a machine without Rust has. Also whether Rust is then out of reach.
fn path_without_rust(first: &Path) -> (OsString, bool) {
    let has_rust = |d: &Path| d.join("cargo").exists() || d.join("rustc").exists();
    let system = |d: &Path| [Path::new("/usr/bin"), Path::new("/bin")].contains(&d);
    let mut dirs = vec![first.to_path_buf()];
    if let Some(path) = std::env::var_os("PATH") {
        dirs.extend(std::env::split_paths(&path).filter(|d| system(d) || !has_rust(d)));
    }
    let hidden = !dirs.iter().any(|d| has_rust(d));
    (std::env::join_paths(dirs).unwrap_or_default(), hidden)
}

fn run(mut cmd: Command, what: &str) -> Result<(), Problem> {
    match cmd.status() {
        Ok(s) if s.success() => Ok(()),
        Ok(s) => Err(Problem::Failed(format!("{what} failed ({s})"))),
        Err(e) => Err(Problem::Failed(format!("cannot run {what}: {e}"))),
    }
}

/// Builds the package's abi3 wheel, with or without the SPIR-V kernels,
/// into `target/wheels/with-kernels/` or `target/wheels/cpu-only/` (the
/// folder says which; so does `cvd.KERNELS` once installed). Returns it.
pub fn wheel(root: &Path, kernels: bool) -> Result<PathBuf, Problem> {
    let target = target(root);
    // maturin lives in a build environment of its own.
    let python = venv(&target.join("python-venv"), false)?;
    let maturin = python.with_file_name("maturin");
    if !maturin.is_file() && !pip(&python, &["--ignore-installed", "maturin>=1.5,<2"]) {
        return Err(Problem::Unavailable("pip could not install maturin".into()));
    }
    let out = target.join("wheels").join(if kernels { "with-kernels" } else { "cpu-only" });
    if let Ok(old) = std::fs::read_dir(&out) {
        for f in old.flatten().filter(|f| f.path().extension().is_some_and(|e| e == "whl")) {
            let _ = std::fs::remove_file(f.path());
        }
    }
    let mut path = OsString::from(python.parent().unwrap_or(Path::new(".")));
    if let Some(rest) = std::env::var_os("PATH") {
        path.push(":");
        path.push(rest);
    }
    let mut build = Command::new(&maturin);
    build
        .args(["build", "--release", "--manifest-path"])
        .arg(root.join("python").join("Cargo.toml"))
        .arg("--out")
        .arg(&out)
        .args(if kernels { &["--features", "vulkan"][..] } else { &[] })
        .env("PATH", &path)
        .env("CARGO_TARGET_DIR", &target)
        // The workspace's features for every crate, as `cargo test
        // --workspace` resolves them: built alone, the package would resolve
        // the build tools' features differently (voro++'s bindings in the
        // tests ask more of proc-macro2 and syn), rebuild rust-gpu's code
        // generator with them and then the kernels, 15 to 25 minutes on two
        // cores. Through the workspace, the wheel reuses them and compiles
        // only the library, its readers and the bindings. (The package is
        // the same: only `cvd`'s `clap` feature, for the CLI, comes along
        // unused.) On the command line, not in the environment: the build
        // script's own cargo, which builds the kernels for SPIR-V, must not
        // see it.
        .args(["--config", "resolver.feature-unification=\"workspace\"", "-Z", "feature-unification"]);
    run(build, "maturin build")?;
    let built = std::fs::read_dir(&out)
        .map_err(|e| format!("reading {}: {e}", out.display()))?
        .flatten()
        .map(|f| f.path())
        .find(|p| p.extension().is_some_and(|e| e == "whl"))
        .ok_or_else(|| format!("maturin wrote no wheel into {}", out.display()))?;
    println!(
        "wheel ({}): {}",
        if kernels { "with the SPIR-V kernels" } else { "CPU only, no SPIR-V kernels" },
        built.display()
    );
    Ok(built)
}

/// The Python package's tests (see the module's comment).
pub fn test(root: &Path) -> Result<(), String> {
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    match test_steps(root) {
        Ok(()) => Ok(()),
        Err(Problem::Failed(why)) => Err(why),
        Err(Problem::Unavailable(why)) if ci => Err(format!("CI=true but the Python package cannot be tested: {why}")),
        Err(Problem::Unavailable(why)) => {
            eprintln!("SKIPPED the Python package's tests ({why})");
            Ok(())
        }
    }
}

fn test_steps(root: &Path) -> Result<(), Problem> {
    let target = target(root);
    let wheel = wheel(root, true)?;
    // The wheel in a fresh environment with no Rust on its PATH.
    let env = target.join("python-wheel-venv");
    let python = venv(&env, true)?;
    let missing: Vec<&str> = ["pytest", "numpy"].into_iter().filter(|m| !has(&python, m)).collect();
    if !missing.is_empty() && !pip(&python, &missing) {
        return Err(Problem::Unavailable(format!("pip could not install {}", missing.join(", "))));
    }
    let whl = wheel.to_string_lossy().into_owned();
    if !pip(&python, &["--no-deps", "--force-reinstall", &whl]) {
        return Err(Problem::Failed(format!("pip install {whl} failed")));
    }
    let (path, no_rust) = path_without_rust(&env.join("bin"));
    let mut pytest = Command::new(&python);
    pytest
        .args(["-m", "pytest", "-q"])
        .arg(root.join("python").join("tests"))
        .current_dir(&target)
        .env("PATH", path)
        .env("CVD_TEST_INSTALLED", "1")
        .env("CVD_TEST_NO_RUST", if no_rust { "1" } else { "0" })
        .env("CVD_BIN", target.join("release").join("cvd"))
        .env("CVD_TEST_CACHE", &target);
    run(pytest, "pytest python/tests (the wheel, installed)")?;
    front_door(root, &target)
}

/// `python -m pip install ./python` as the README says, without the
/// kernels (CVD_KERNELS=0), into a fresh environment; then a diagram.
fn front_door(root: &Path, target: &Path) -> Result<(), Problem> {
    let python = venv(&target.join("python-pip-venv"), true)?;
    let start = Instant::now();
    let mut install = Command::new(&python);
    install
        .args(["-m", "pip", "install", "--quiet"])
        .arg(root.join("python"))
        .env("CVD_KERNELS", "0")
        .env("CARGO_TARGET_DIR", target);
    run(install, "python -m pip install ./python (CVD_KERNELS=0)")?;
    println!("python -m pip install ./python (CVD_KERNELS=0): {:.1} s", start.elapsed().as_secs_f64());
    let check = r#"
import cvd
assert not cvd.KERNELS, "CVD_KERNELS=0 built the kernels"
mesh = cvd.builtin("joint")
cells = cvd.clipped_voronoi(mesh, cvd.sample(mesh, 2000, seed=3), backend="cpu")
assert abs(cells.volume.sum() - mesh.volume) < 1e-6 * mesh.volume, cells.volume.sum()
try:
    cvd.clipped_voronoi(mesh, cvd.sample(mesh, 10), backend="vulkan")
    raise AssertionError("Vulkan ran without kernels")
except RuntimeError as e:
    assert "CVD_KERNELS=1" in str(e), str(e)
print("the package from pip install ./python: 2000 cells, volumes adding up to the mesh's")
"#;
    let mut run_check = Command::new(&python);
    run_check
        .args(["-c", check])
        .current_dir(target)
        .env("PATH", path_without_rust(python.parent().unwrap_or(target)).0);
    run(run_check, "the package installed by pip")
}
