//! `cargo xtask`: builds, runs, tests and benchmarks the project by driving
//! cargo (the SPIR-V kernels are built by the host crate's build script).

use std::process::{Command, ExitCode};

const USAGE: &str = "\
usage: cargo xtask <command> [args...]

commands:
  run [ARGS]          the main job: a clipped Voronoi diagram (cvd run ARGS, release build)
  test [ARGS]         the whole test suite, optimised (cargo test ARGS)
  bench paper [ARGS]  the paper's evaluation: Table 1, Figs. 7, 8, 12, 13 and scale runs, CPU and
                      Vulkan; tables, JSON and charts in bench-results/paper (--sections LIST,
                      --quick, --cpu-only, --only MODEL, --repeat R, --scale-max N, --models-dir DIR, ...)
  bench cvd [ARGS]    Table 1 alone (bench paper --sections table1 ARGS)
  bench knn [ARGS]    the k-NN benchmark (ARGS: --sizes, --ks, --json PATH, ...)
  bench cvt [ARGS]    Lloyd and L-BFGS per model and backend (--iterations N, --only NAME, --json PATH, ...)
  build               build everything, optimised
  spirv --out DIR     write the kernels as SPIR-V (one module per entry point) and manifest.json into DIR
                      (docs/EMBEDDING.md); then: cargo run --release -p cvd-embed-example -- DIR
  lint                cargo fmt --check and cargo clippy -D warnings
";

/// Paths given after these options are made absolute: cargo runs benches
/// from the package's folder, not from where the user typed the command.
const PATH_OPTIONS: &[&str] =
    &["--json", "--models-dir", "--mesh", "--sites-file", "--output", "--out", "--plots", "--density-file"];

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

fn status(mut cmd: Command) -> Result<(), String> {
    let shown = format!("{cmd:?}");
    match cmd.status() {
        Ok(s) if s.success() => Ok(()),
        Ok(s) => Err(format!("{shown} failed ({s})")),
        Err(e) => Err(format!("cannot run {shown}: {e}")),
    }
}

fn run(args: &[String]) -> Result<(), String> {
    let Some((command, rest)) = args.split_first() else {
        return Err(USAGE.into());
    };
    match command.as_str() {
        "run" => status(cargo(&["run", "--release", "--package", "cvd", "--", "run"], rest)),
        "test" => status(cargo(&["test", "--release", "--workspace"], rest)),
        "build" => status(cargo(&["build", "--release", "--workspace"], rest)),
        "spirv" => {
            if !rest.iter().any(|a| a == "--out") {
                return Err(format!("spirv needs --out DIR\n\n{USAGE}"));
            }
            status(cargo(&["run", "--quiet", "--release", "--package", "cvd", "--", "spirv"], rest))
        }
        "bench" => match rest.split_first() {
            Some((which, extra)) if ["knn", "paper", "cvt"].contains(&which.as_str()) => {
                status(cargo(&["bench", "--package", "cvd", "--bench", which, "--"], extra))
            }
            Some((cvd, extra)) if cvd == "cvd" => {
                status(cargo(&["bench", "--package", "cvd", "--bench", "paper", "--", "--sections", "table1"], extra))
            }
            _ => Err(format!("unknown benchmark; expected: paper, cvd, knn or cvt\n\n{USAGE}")),
        },
        "lint" => {
            status(cargo(&["fmt", "--all", "--check"], &[]))?;
            status(cargo(&["clippy", "--release", "--workspace", "--all-targets", "--", "-D", "warnings"], &[]))
        }
        "help" | "--help" | "-h" => {
            print!("{USAGE}");
            Ok(())
        }
        other => Err(format!("unknown command '{other}'\n\n{USAGE}")),
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}
