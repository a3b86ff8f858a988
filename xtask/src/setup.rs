//! What a command needs before it builds anything, checked in seconds: the
//! pinned toolchain's components, and the system's tools and libraries
//! (`xtask/install-deps`). What is missing is installed where that can be
//! done without asking (root, or sudo without a password, on apt);
//! otherwise the command stops with the one command to run.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// What a command needs from the system (`xtask/install-deps`'s groups).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Needs {
    /// Nothing beyond the toolchain: a build without the SPIR-V kernels.
    Toolchain,
    /// spirv-tools, to build the SPIR-V kernels.
    Build,
    /// Also the Vulkan loader, lavapipe and the validation layer, to run
    /// the kernels on lavapipe in the tests.
    Test,
}

impl Needs {
    fn group(self) -> Option<&'static str> {
        match self {
            Needs::Toolchain => None,
            Needs::Build => Some("build"),
            Needs::Test => Some("test"),
        }
    }
}

/// The workspace's root (where `rust-toolchain.toml` is): the nearest
/// folder holding it and `xtask/install-deps` from the current directory
/// up (cargo runs `cargo xtask` from inside the workspace). The path this
/// binary was compiled in is only the last resort: builds of several
/// clones that share a target directory share this binary too.
pub fn root() -> PathBuf {
    let is_root = |d: &Path| d.join("rust-toolchain.toml").is_file() && d.join("xtask").join("install-deps").is_file();
    let cwd = std::env::current_dir().unwrap_or_default();
    cwd.ancestors().find(|d| is_root(d)).map(Path::to_path_buf).unwrap_or_else(|| {
        Path::new(env!("CARGO_MANIFEST_DIR")).parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf)
    })
}

/// Whether MPI can be built against and run here (`mpicc` and `mpirun`
/// on the PATH): the tests then build the `mpi` feature.
pub fn has_mpi() -> bool {
    runs("mpicc") && runs("mpirun")
}

/// Whether `tool --version` runs and succeeds.
fn runs(tool: &str) -> bool {
    let status = Command::new(tool).arg("--version").stdout(Stdio::null()).stderr(Stdio::null()).status();
    status.is_ok_and(|s| s.success())
}

/// Whether spirv-tools (spirv-val and spirv-opt) are installed: what the
/// SPIR-V kernels' build needs.
pub fn has_spirv_tools() -> bool {
    runs("spirv-val") && runs("spirv-opt")
}

/// Checks (and where it can, installs) what `needs` asks for.
pub fn ensure(needs: Needs) -> Result<(), String> {
    ensure_components()?;
    let Some(group) = needs.group() else { return Ok(()) };
    if std::env::var_os("CVD_XTASK_NO_SETUP").is_some() {
        return Ok(());
    }
    let script = root().join("xtask").join("install-deps");
    let check = Command::new("bash")
        .arg(&script)
        .args(["--check", group])
        .stderr(Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", script.display()))?;
    if check.status.success() {
        return Ok(());
    }
    let missing = String::from_utf8_lossy(&check.stdout);
    let missing: Vec<&str> = missing.lines().filter(|l| !l.trim().is_empty()).collect();
    let shown = script.strip_prefix(std::env::current_dir().unwrap_or_default()).unwrap_or(&script).display();
    let Some(sudo) = can_install() else {
        return Err(format!(
            "missing: {}.\nInstall them with:\n\n    sudo {shown} {group}\n\n(or with your system's package \
             manager), then run this command again.",
            missing.join("; ")
        ));
    };
    eprintln!("xtask: installing {} (xtask/install-deps {group})", missing.join("; "));
    let mut install = Command::new(if sudo { "sudo" } else { "bash" });
    if sudo {
        install.args(["-n", "bash"]);
    }
    install.arg(&script).arg(group);
    match install.status() {
        Ok(s) if s.success() => Ok(()),
        Ok(s) => Err(format!("installing failed ({s}); to try by hand: sudo {shown} {group}")),
        Err(e) => Err(format!("cannot run {}: {e}", script.display())),
    }
}

/// Whether packages can be installed here without asking: `Some(false)` as
/// root, `Some(true)` through sudo without a password, `None` otherwise
/// (or without apt).
fn can_install() -> Option<bool> {
    let quiet = |cmd: &str, args: &[&str]| {
        Command::new(cmd)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if !quiet("sh", &["-c", "command -v apt-get"]) {
        return None;
    }
    let uid = Command::new("id").arg("-u").output().ok()?;
    if String::from_utf8_lossy(&uid.stdout).trim() == "0" {
        return Some(false);
    }
    quiet("sudo", &["-n", "true"]).then_some(true)
}

/// The components `rust-toolchain.toml` lists that the active toolchain
/// lacks are added (rustup installs them with the toolchain, but not into a
/// toolchain installed before they were listed).
fn ensure_components() -> Result<(), String> {
    let toml = std::fs::read_to_string(root().join("rust-toolchain.toml")).unwrap_or_default();
    let wanted = components(&toml);
    let Ok(out) = Command::new("rustup").args(["component", "list", "--installed"]).output() else {
        // No rustup: the toolchain is someone else's business.
        return Ok(());
    };
    if !out.status.success() {
        return Ok(());
    }
    let installed = String::from_utf8_lossy(&out.stdout);
    let missing: Vec<&str> = wanted
        .iter()
        .map(String::as_str)
        .filter(|c| !installed.lines().any(|l| l == *c || l.starts_with(&format!("{c}-"))))
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    eprintln!("xtask: adding the toolchain components {} (rust-toolchain.toml)", missing.join(", "));
    match Command::new("rustup").args(["component", "add"]).args(&missing).status() {
        Ok(s) if s.success() => Ok(()),
        _ => Err(format!("could not add the components; run: rustup component add {}", missing.join(" "))),
    }
}

/// The `components = [...]` of a `rust-toolchain.toml`.
fn components(toml: &str) -> Vec<String> {
    let Some(line) = toml.lines().find(|l| l.trim_start().starts_with("components")) else { return Vec::new() };
    let Some(list) = line.split_once('[').and_then(|(_, rest)| rest.split_once(']')).map(|(list, _)| list) else {
        return Vec::new();
    };
    list.split(',').map(|c| c.trim().trim_matches('"').to_string()).filter(|c| !c.is_empty()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_pinned_components() {
        let toml = std::fs::read_to_string(root().join("rust-toolchain.toml")).expect("rust-toolchain.toml");
        let c = components(&toml);
        for wanted in ["rust-src", "rustc-dev", "llvm-tools"] {
            assert!(c.iter().any(|x| x == wanted), "{wanted} in {c:?}");
        }
        assert!(components("[toolchain]\nchannel = \"stable\"\n").is_empty());
    }
}
