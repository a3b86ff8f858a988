//! Per-phase times of a job.

use std::fmt;

/// Named phases with their duration in seconds, in execution order.
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Timings {
    /// `(phase, seconds)` pairs.
    pub phases: Vec<(String, f64)>,
}

impl Timings {
    /// Appends a phase.
    pub fn push(&mut self, phase: impl Into<String>, seconds: f64) {
        self.phases.push((phase.into(), seconds));
    }

    /// Adds `seconds` to a phase, appended if new (a phase run many times
    /// is reported once).
    pub fn add(&mut self, phase: &str, seconds: f64) {
        match self.phases.iter_mut().find(|(p, _)| p == phase) {
            Some((_, s)) => *s += seconds,
            None => self.push(phase, seconds),
        }
    }

    /// The time of one phase (0 if absent).
    pub fn get(&self, phase: &str) -> f64 {
        // A fold from +0 (an empty `sum` of floats is -0).
        self.phases.iter().filter(|(p, _)| p == phase).fold(0.0, |t, (_, s)| t + s)
    }

    /// The neighbour searches: the site grid and every k-NN phase.
    pub fn knn(&self) -> f64 {
        self.phases.iter().filter(|(p, _)| p == "grid" || p.contains("knn")).fold(0.0, |t, (_, s)| t + s)
    }

    /// Clipping: cells (cell-tet), pieces, and the second and host passes.
    pub fn clip(&self) -> f64 {
        let clipping = |p: &str| matches!(p, "cells" | "clip" | "second pass" | "host pass");
        self.phases.iter().filter(|(p, _)| clipping(p)).fold(0.0, |t, (_, s)| t + s)
    }

    /// Sum of all phases.
    pub fn total(&self) -> f64 {
        self.phases.iter().map(|(_, s)| s).sum()
    }
}

impl fmt::Display for Timings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (phase, s)) in self.phases.iter().enumerate() {
            if i > 0 {
                write!(f, ", ")?;
            }
            write!(f, "{phase} {:.3} ms", s * 1e3)?;
        }
        Ok(())
    }
}

/// Runs `f` and returns its result and wall time in seconds.
pub fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = std::time::Instant::now();
    let out = f();
    (out, t.elapsed().as_secs_f64())
}
