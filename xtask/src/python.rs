//! The Python package's tests (`python/tests`): the extension built into a
//! virtual environment in the target folder (`maturin develop`), then
//! pytest, with the `cvd` command line beside it for the comparisons.
//! Where python3, venv, maturin or pytest cannot be had, the tests are
//! skipped with the reason — and fail under `CI=true`.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Builds the package and runs its tests.
pub fn test(root: &Path) -> Result<(), String> {
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    let skip = |why: String| -> Result<(), String> {
        if ci {
            Err(format!("CI=true but the Python package cannot be tested: {why}"))
        } else {
            eprintln!("SKIPPED the Python package's tests ({why})");
            Ok(())
        }
    };
    let target = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), PathBuf::from);
    let venv = target.join("python-venv");
    let python = venv.join("bin").join("python");
    if !python.is_file() {
        // numpy and the test tools installed system-wide stay visible.
        let made = Command::new("python3").args(["-m", "venv", "--system-site-packages"]).arg(&venv).status();
        if !made.is_ok_and(|s| s.success()) {
            return skip("python3 -m venv failed".into());
        }
    }
    let has = |module: &str| {
        Command::new(&python).args(["-c", &format!("import {module}")]).output().is_ok_and(|o| o.status.success())
    };
    let pip = |args: &[&str]| {
        Command::new(&python).args(["-m", "pip", "install", "--quiet"]).args(args).status().is_ok_and(|s| s.success())
    };
    let missing: Vec<&str> = ["pytest", "numpy"].into_iter().filter(|m| !has(m)).collect();
    if !missing.is_empty() && !pip(&missing) {
        return skip(format!("pip could not install {}", missing.join(", ")));
    }
    // maturin into the environment itself (its script runs the build),
    // even where the system has one.
    let maturin = venv.join("bin").join("maturin");
    if !maturin.is_file() && !pip(&["--ignore-installed", "maturin"]) {
        return skip("pip could not install maturin".into());
    }
    // The environment's scripts (maturin's own) first on the path.
    let mut path = std::ffi::OsString::from(venv.join("bin"));
    if let Some(rest) = std::env::var_os("PATH") {
        path.push(":");
        path.push(rest);
    }
    let run = |mut cmd: Command, what: &str| -> Result<(), String> {
        match cmd.status() {
            Ok(s) if s.success() => Ok(()),
            Ok(s) => Err(format!("{what} failed ({s})")),
            Err(e) => Err(format!("cannot run {what}: {e}")),
        }
    };
    let mut build = Command::new(&maturin);
    build
        .args(["develop", "--release", "--manifest-path"])
        .arg(root.join("python").join("Cargo.toml"))
        .env("VIRTUAL_ENV", &venv)
        .env("PATH", &path)
        .env("CARGO_TARGET_DIR", &target);
    run(build, "maturin develop")?;
    let mut pytest = Command::new(&python);
    pytest
        .args(["-m", "pytest", "-q"])
        .arg(root.join("python").join("tests"))
        .env("CVD_BIN", target.join("release").join("cvd"));
    run(pytest, "pytest python/tests")
}
