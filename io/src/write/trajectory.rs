//! summary.json of a trajectory run (`cvd run --particles`): a record per
//! frame and the run's totals.

use crate::read::write_file;
use cvd::error::Result;
use std::path::Path;

/// One frame's record.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FrameRecord {
    pub frame: usize,
    pub timestep: Option<u64>,
    pub particles: usize,
    /// Periodic along a, b, c.
    pub periodic: [bool; 3],
    pub images: usize,
    /// Cells built from the last frame's neighbour lists, without a
    /// search for neighbours.
    pub reused_cells: u64,
    /// `|Σ V_i - V| / V`.
    pub e_vol: f64,
    pub empty_cells: u64,
    /// Unfinished cells the host finished (counted, never dropped).
    pub second_pass: u64,
    pub unresolved: u64,
    pub seconds: f64,
    pub file: String,
}

/// summary.json of a trajectory run.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TrajectorySummary {
    pub particles_file: String,
    pub frames: Vec<FrameRecord>,
    /// Seconds computing cells over all frames (reading and writing apart).
    pub diagram_seconds: f64,
    /// Seconds in all: reading, computing, writing.
    pub total_seconds: f64,
    pub frames_per_second: f64,
    /// Cells built from the last frame's neighbour lists over all frames
    /// (the frames' `reused_cells` summed).
    pub reused_cells: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub thresholds: Option<[f64; 4]>,
}

impl TrajectorySummary {
    /// Writes the summary as pretty-printed JSON.
    pub fn write_json(&self, path: &Path) -> Result<()> {
        write_file(path, |w| {
            serde_json::to_writer_pretty(&mut *w, self).map_err(std::io::Error::other)?;
            writeln!(w)
        })
    }
}
