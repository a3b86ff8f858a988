//! `cvd`: the command line over the engine (`cvd`) and its files
//! (`cvd-io`). [`args`] says what it takes, [`inputs`] reads it, [`run`]
//! is the one path of `cvd run` (meshes and periodic boxes alike) and
//! [`outputs`] its table of files; [`backend`], [`progress`] and
//! [`commands`] (devices, knn, spirv) serve them.

mod args;
mod backend;
mod commands;
mod frames;
mod inputs;
mod mesh_parts;
mod optimise;
mod outputs;
mod parts;
mod pictures;
mod progress;
mod run;

use args::{Cli, Command};
use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    // Die quietly when the reader of our output goes away (`cvd ... | head`).
    #[cfg(unix)]
    // SAFETY: restoring the default action of a signal at start-up.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Large buffers straight from the system and back to it when freed:
    // glibc's default raises its mmap threshold after the first large free,
    // and the job's freed temporaries then stay resident under the buffers
    // that follow (about 90 MB of 575 MB at 1M sites).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: a malloc tuning call at start-up, before any other thread.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Devices { json } => commands::devices(*json).map(|()| 0),
        Command::Run(args) => run::run(args),
        Command::Knn(args) => commands::knn(args).map(|()| 0),
        Command::Spirv { out } => commands::spirv(out).map(|()| 0),
    };
    match result {
        Ok(status) => ExitCode::from(status),
        Err(e) => {
            eprintln!("cvd: {e}");
            // Like clap's own errors: 2 for what the user gave, 1 for the rest.
            ExitCode::from(if e.is_input_error() { 2 } else { 1 })
        }
    }
}
