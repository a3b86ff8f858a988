//! `cargo xtask`: builds, runs, tests and benchmarks the project by driving
//! cargo (the SPIR-V kernels are built by the host crate's build script).
//! Each command first checks what it needs (see `setup`), and passes the
//! exit status of what it runs through unchanged.

mod layers;
mod python;
mod setup;

use setup::Needs;
use std::process::{Command, ExitCode, ExitStatus};

const USAGE: &str = "\
usage: cargo xtask <command> [args...]

commands:
  run [ARGS]          the main job: a clipped Voronoi diagram (cvd run ARGS, release build); the
                      SPIR-V kernels are built only when a GPU (or --backend vulkan) will run them
  test [ARGS]         the whole test suite, optimised, on the CPU and lavapipe, and on MPI ranks
                      where MPI is installed (cargo test ARGS; without ARGS also the Python
                      package's, python/tests)
  test-python         the Python package alone: its wheel installed into a fresh virtual environment
                      without Rust, pytest there; then `pip install ./python` without the kernels
  wheel [--kernels|--no-kernels]  the Python package as an abi3 wheel, into target/wheels/with-kernels
                      or target/wheels/cpu-only (default: with the kernels where spirv-tools are installed)
  bench paper [ARGS]  the paper's evaluation: Table 1, Figs. 7, 8, 12, 13 and scale runs, CPU and
                      Vulkan; tables, JSON and charts in bench-results/paper (--sections LIST,
                      --quick, --cpu-only, --only MODEL, --repeat R, --scale-max N, --models-dir DIR, ...)
  bench cvd [ARGS]    Table 1 alone (bench paper --sections table1 ARGS)
  bench knn [ARGS]    the k-NN benchmark (ARGS: --sizes, --ks, --json PATH, ...)
  bench cvt [ARGS]    Lloyd and L-BFGS per model and backend (--iterations N, --only NAME, --json PATH, ...)
  bench transport [ARGS]  optimal transport: Newton steps, and the solve in diagram times (--model NAME,
                      --sites N, --backend cpu|vulkan, --repeat R, --json PATH)
  bench periodic [ARGS]  periodic boxes against the same box plain and voro++'s periodic container
                      (--sites N,M, --repeat R, --threads T, --json PATH)
  build               build everything, optimised
  spirv --out DIR     write the kernels as SPIR-V (one module per entry point) and manifest.json into DIR
                      (docs/EMBEDDING.md); then: cargo run --release -p cvd-embed-example -- DIR
  lint                the module layering (layers), cargo fmt --check and cargo clippy -D warnings
  layers              the top-level modules of each crate must not import each other in a circle
                      (each imports only modules below it); reads the sources only, builds nothing

Each command first checks what it needs from the system and installs what is missing where it
can (xtask/install-deps; CVD_XTASK_NO_SETUP=1 skips this), and exits with the status of what it ran.
";

/// Paths given after these options are made absolute: cargo runs benches
/// from the package's folder, not from where the user typed the command.
const PATH_OPTIONS: &[&str] = &[
    "--json",
    "--models-dir",
    "--mesh",
    "--surface",
    "--sites-file",
    "--output",
    "--out",
    "--plots",
    "--density-file",
];

fn absolute_paths(args: &[String]) -> Vec<String> {
    let cwd = std::env::current_dir().unwrap_or_default();
    let mut out = Vec::with_capacity(args.len());
    for (i, a) in args.iter().enumerate() {
        let after_path_option = i > 0 && PATH_OPTIONS.contains(&args[i - 1].as_str());
        if after_path_option && std::path::Path::new(a).is_relative() {
            out.push(cwd.join(a).to_string_lossy().into_owned());
        } else {
            out.push(a.clone());
        }
    }
    out
}

fn cargo(args: &[&str], extra: &[String]) -> Command {
    let extra = absolute_paths(extra);
    let mut cmd = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cmd.args(args).args(&extra);
    cmd
}

/// How a command ended: its exit status, or why it could not start.
enum Failure {
    /// The command ran and failed: its status is passed on unchanged.
    Status(ExitStatus),
    /// Something the xtask itself found wrong (exit 1).
    Message(String),
}

impl From<String> for Failure {
    fn from(message: String) -> Self {
        Failure::Message(message)
    }
}

fn status(mut cmd: Command) -> Result<(), Failure> {
    match cmd.status() {
        Ok(s) if s.success() => Ok(()),
        Ok(s) => Err(Failure::Status(s)),
        Err(e) => Err(Failure::Message(format!("cannot run {cmd:?}: {e}"))),
    }
}

/// The value of `--name VALUE` or `--name=VALUE` in `args`.
fn option<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter().enumerate().find_map(|(i, a)| {
        if a == name {
            args.get(i + 1).map(String::as_str)
        } else {
            a.strip_prefix(name).and_then(|rest| rest.strip_prefix('='))
        }
    })
}

/// Whether `cvd run ARGS` will run on Vulkan, so that its build needs the
/// SPIR-V kernels: when asked for (`--backend vulkan`, `--device`), or,
/// with the default `--backend auto`, when a real GPU is there (a device
/// that runs Vulkan on the CPU is not used by auto). The devices are listed
/// by a build without the kernels, which takes minutes less to make.
fn run_needs_kernels(args: &[String]) -> Result<bool, Failure> {
    match option(args, "--backend") {
        Some("cpu") => return Ok(false),
        Some("vulkan") => return Ok(true),
        _ if option(args, "--device").is_some() => return Ok(true),
        Some("auto") | None => {}
        // Let cvd say what is wrong with the value.
        Some(_) => return Ok(false),
    }
    eprintln!("xtask: listing the Vulkan devices: the SPIR-V kernels are built only if a GPU will run them");
    let out = cargo(&["run", "--release", "--package", "cvd-cli", "--no-default-features", "--"], &[])
        .args(["devices", "--json"])
        .stderr(std::process::Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot run cargo: {e}"))?;
    if !out.status.success() {
        return Err(Failure::Status(out.status));
    }
    let listing = String::from_utf8_lossy(&out.stdout);
    Ok(listing.contains("\"gpu\": true") || listing.contains("\"gpu\":true"))
}

fn run(args: &[String]) -> Result<(), Failure> {
    let Some((command, rest)) = args.split_first() else {
        return Err(USAGE.to_string().into());
    };
    match command.as_str() {
        "run" => {
            setup::ensure(Needs::Toolchain)?;
            let kernels = run_needs_kernels(rest)?;
            if kernels {
                setup::ensure(Needs::Build)?;
            }
            let features: &[&str] = if kernels { &[] } else { &["--no-default-features"] };
            let mut cmd = cargo(&["run", "--release", "--package", "cvd-cli"], &[]);
            cmd.args(features).args(["--", "run"]).args(absolute_paths(rest));
            status(cmd)
        }
        "test" => {
            setup::ensure(Needs::Test)?;
            // With MPI here (install-deps installs it), the MPI runs too.
            let mpi: &[&str] = if setup::has_mpi() { &["--features", "cvd/mpi"] } else { &[] };
            status(cargo(&[&["test", "--release", "--workspace"], mpi].concat(), rest))?;
            // The whole suite: the Python package's too.
            if rest.is_empty() {
                python::test(&setup::root())?;
            }
            Ok(())
        }
        "test-python" => {
            setup::ensure(Needs::Test)?;
            status(cargo(&["build", "--release", "--package", "cvd-cli"], &[]))?;
            Ok(python::test(&setup::root())?)
        }
        "wheel" => {
            let kernels = match rest.first().map(String::as_str) {
                Some("--kernels") => true,
                Some("--no-kernels") => false,
                None => setup::has_spirv_tools(),
                Some(other) => return Err(format!("wheel takes --kernels or --no-kernels, not '{other}'").into()),
            };
            setup::ensure(if kernels { Needs::Build } else { Needs::Toolchain })?;
            match python::wheel(&setup::root(), kernels) {
                Ok(_) => Ok(()),
                Err(python::Problem::Failed(why) | python::Problem::Unavailable(why)) => Err(why.into()),
            }
        }
        "build" => {
            setup::ensure(Needs::Build)?;
            status(cargo(&["build", "--release", "--workspace"], rest))
        }
        "spirv" => {
            if !rest.iter().any(|a| a == "--out") {
                return Err(format!("spirv needs --out DIR\n\n{USAGE}").into());
            }
            setup::ensure(Needs::Build)?;
            status(cargo(&["run", "--quiet", "--release", "--package", "cvd-cli", "--", "spirv"], rest))
        }
        "bench" => {
            setup::ensure(if rest.iter().any(|a| a == "--cpu-only") { Needs::Build } else { Needs::Test })?;
            bench(rest)
        }
        "lint" => {
            // First: it needs nothing and takes a moment.
            layers::check(&setup::root())?;
            setup::ensure(Needs::Build)?;
            status(cargo(&["fmt", "--all", "--check"], &[]))?;
            status(cargo(&["clippy", "--release", "--workspace", "--all-targets", "--", "-D", "warnings"], &[]))
        }
        "layers" => Ok(layers::check(&setup::root())?),
        "help" | "--help" | "-h" => {
            print!("{USAGE}");
            Ok(())
        }
        other => Err(format!("unknown command '{other}'\n\n{USAGE}").into()),
    }
}

fn bench(rest: &[String]) -> Result<(), Failure> {
    match rest.split_first() {
        Some((which, extra)) if ["knn", "paper", "cvt", "transport", "periodic"].contains(&which.as_str()) => {
            status(cargo(&["bench", "--package", "cvd-bench", "--bench", which, "--"], extra))
        }
        Some((cvd, extra)) if cvd == "cvd" => {
            status(cargo(&["bench", "--package", "cvd-bench", "--bench", "paper", "--", "--sections", "table1"], extra))
        }
        _ => Err(format!("unknown benchmark; expected: paper, cvd, knn, cvt, transport or periodic\n\n{USAGE}").into()),
    }
}

/// The exit code that passes `status` on: its own code, or 128 + the
/// signal that ended it (as shells report it).
fn exit_code(status: ExitStatus) -> u8 {
    #[cfg(unix)]
    if let Some(signal) = std::os::unix::process::ExitStatusExt::signal(&status) {
        return (128 + signal).clamp(0, 255) as u8;
    }
    status.code().map_or(1, |c| c.clamp(0, 255) as u8)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Status(s)) => ExitCode::from(exit_code(s)),
        Err(Failure::Message(e)) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}
