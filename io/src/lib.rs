//! # cvd-io: what `cvd` reads and writes
//!
//! Readers ([`read`](mod@read)): tet meshes, closed surfaces, sites and per-line
//! values, each format chosen by its file's extension. Writers
//! ([`write`](mod@write)): the cells as CSV, VTK and PLY, pictures as PNG, the run as
//! JSON. The engine (`cvd`) knows no file format; this crate knows no
//! command line.

mod numbers;
pub mod read;
pub mod write;

pub use read::*;
pub use write::*;
