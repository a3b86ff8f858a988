//! `cargo xtask bench paper`: the paper's evaluation side by side (Table 1,
//! Figs. 7, 8, 12, 13) and scale runs, on the CPU and the Vulkan device;
//! Markdown, JSON and PNG charts into `--out` (default `bench-results/paper`).
//!
//! Options: `--sections table1,fig7,fig8,fig12,fig13,scale` `--out DIR`
//! `--models-dir DIR` `--threads N` `--device D` `--cpu-only` `--only MODEL` `--repeat R`
//! `--iterations N` (Fig. 13) `--scale-max N` (largest scale run, default
//! 1 000 000; 10 000 000 on a GPU) `--quick` (every section, reduced sizes).

use cvd_bench::{Config, Section};
use std::path::PathBuf;
use std::process::ExitCode;

fn config() -> Result<Config, String> {
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("bench-results").join("paper");
    let mut c = Config::full(out);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        let number = |v: String| v.parse::<usize>().map_err(|_| format!("{a}: expected a number, got '{v}'"));
        match a.as_str() {
            "--sections" => {
                c.sections = value()?
                    .split(',')
                    .map(|s| s.parse::<Section>())
                    .collect::<Result<_, _>>()
                    .map_err(|e| e.to_string())?
            }
            "--out" => c.out = value()?.into(),
            "--models-dir" => c.models_dir = value()?.into(),
            "--threads" => c.threads = Some(number(value()?)?),
            "--device" => c.device = Some(value()?),
            "--cpu-only" => c.vulkan = false,
            "--only" => c.only = Some(value()?),
            "--repeat" => c.repeat = number(value()?)?,
            "--iterations" => c.iterations = number(value()?)?,
            "--scale-max" => c.scale_max = number(value()?)?,
            "--quick" => {
                let q = Config::quick(c.out.clone());
                (c.repeat, c.quick, c.iterations, c.scale_max) = (q.repeat, q.quick, q.iterations, q.scale_max);
            }
            "--bench" => {}
            other => return Err(format!("unknown option {other}")),
        }
    }
    Ok(c)
}

fn main() -> ExitCode {
    match config().and_then(|c| cvd_bench::run(&c).map_err(|e| e.to_string())) {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("bench paper: {e}");
            ExitCode::FAILURE
        }
    }
}
