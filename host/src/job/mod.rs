//! Jobs: what crosses from the host to a backend and back — k-NN jobs and
//! their neighbour lists ([`knn`]), the clipping job and its output
//! ([`clip`]), Lloyd's records ([`lloyd`]), the grid cells a part of a
//! distributed job holds ([`held`]), the lists a trajectory keeps between
//! frames ([`kept`]), a job's memory estimated before it is allocated
//! ([`memory`]), the sites as the kernels take them
//! ([`sites`]) and, with power weights, each site's bound of its
//! neighbours' weights (`weight_bounds`). Plain data and its validation:
//! no backend, no pass, no diagram.

pub mod clip;
pub mod held;
pub mod kept;
pub mod knn;
pub mod lloyd;
pub mod memory;
pub mod sites;
pub(crate) mod weight_bounds;

use std::fmt;

/// What runs a job's kernels (see `Backend::kind`): some defaults depend
/// on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BackendKind {
    /// CPU cores: the kernels' bodies called natively.
    Cpu,
    /// A Vulkan device: the kernels as SPIR-V.
    Vulkan,
}

impl BackendKind {
    /// `cpu` or `vulkan`.
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Vulkan => "vulkan",
        }
    }
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
