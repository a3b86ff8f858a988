//! What a run shows while it works: a spinner, a bar fed by a writer's
//! `(done, total)`, and a bar over the optimiser's iterations. Each draws
//! only on a terminal.

use indicatif::{ProgressBar, ProgressStyle};
use std::time::Duration;

/// Runs `f` under a spinner saying `what`.
pub fn with_spinner<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let spinner = ProgressBar::new_spinner().with_message(what.to_string());
    spinner.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}").unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    spinner.enable_steady_tick(Duration::from_millis(100));
    let out = f();
    spinner.finish_and_clear();
    out
}

/// Runs `f` with a bar saying `what`, fed through `f`'s progress callback
/// with `(done, total)`.
pub fn with_bar<T>(what: &str, f: impl FnOnce(&mut dyn FnMut(u64, u64)) -> T) -> T {
    let bar = ProgressBar::new(1).with_message(what.to_string());
    bar.set_style(
        ProgressStyle::with_template("{msg:<24} [{bar:40}] {percent:>3}% {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let out = f(&mut |done, total| {
        bar.set_length(total.max(1));
        bar.set_position(done);
    });
    bar.finish_and_clear();
    out
}

/// Runs `f` with a bar over `iterations` iterations of `what` (an
/// optimiser), fed through `f`'s callback with the iterations done and the
/// energy the last one started from.
pub fn with_iterations<T>(what: &str, iterations: usize, f: impl FnOnce(&mut dyn FnMut(usize, f64)) -> T) -> T {
    let bar = ProgressBar::new(iterations as u64).with_style(
        ProgressStyle::with_template("{msg} {bar:30} {pos}/{len} iterations, {elapsed} ({per_sec})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(what.to_string());
    let out = f(&mut |done, energy| {
        bar.set_position(done as u64);
        bar.set_message(format!("{what}, energy {energy:.6e}"));
    });
    bar.finish_and_clear();
    out
}

/// Runs `f` with a bar over `frames` frames of a trajectory (a spinner
/// with a count when the number is not known), fed through `f`'s callback
/// with the frames done and the last one's particles.
pub fn with_frames<T>(frames: Option<usize>, f: impl FnOnce(&mut dyn FnMut(usize, usize)) -> T) -> T {
    let bar = match frames {
        Some(n) => ProgressBar::new(n as u64).with_style(
            ProgressStyle::with_template("frames {bar:30} {pos}/{len}, {elapsed} ({per_sec}) {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        ),
        None => ProgressBar::new_spinner().with_style(
            ProgressStyle::with_template("{spinner} frames {pos}, {elapsed} ({per_sec}) {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        ),
    };
    let out = f(&mut |done, particles| {
        bar.set_position(done as u64);
        bar.set_message(format!("{particles} particles"));
    });
    bar.finish_and_clear();
    out
}

/// Sends this process's standard output to nowhere: the ranks of a
/// distributed run other than 0 compute without speaking.
pub(crate) fn quiet_stdout() {
    #[cfg(unix)]
    if let Ok(null) = std::fs::OpenOptions::new().write(true).open("/dev/null") {
        use std::os::fd::AsRawFd;
        // SAFETY: redirecting fd 1 to a file opened here; both stay valid.
        unsafe {
            libc::dup2(null.as_raw_fd(), 1);
        }
    }
}
