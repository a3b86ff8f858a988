//! The ranks of an MPI run (`mpirun -np P cvd run ...`), through the `mpi`
//! crate over the system's MPI library.

use super::Reduce;
use crate::error::{Error, Result};
use mpi::collective::SystemOperation;
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::sync::Mutex;

/// Most values one MPI call adds (its counts are `int`s).
const CALL: usize = 1 << 28;

/// MPI's world communicator, kept for the life of the process (MPI ends
/// when it is dropped).
pub struct Mpi {
    /// The universe and its world, behind a lock: MPI is asked for
    /// serialised threading, one call at a time from any thread.
    inner: Mutex<(Universe, SimpleCommunicator)>,
    rank: usize,
    size: usize,
    library: String,
}

// SAFETY: MPI runs with `Threading::Serialized` (checked in `init`), which
// allows calls from any thread as long as no two overlap; every call goes
// through the mutex.
unsafe impl Send for Mpi {}
unsafe impl Sync for Mpi {}

impl Mpi {
    /// Starts MPI, or `None` when it is started already in this process.
    pub fn init() -> Result<Option<Self>> {
        let Some((universe, threading)) = mpi::initialize_with_threading(mpi::Threading::Serialized) else {
            return Ok(None);
        };
        if threading < mpi::Threading::Serialized {
            return Err(Error::InvalidInput(format!(
                "the MPI library gives threading level {threading:?}; cvd needs Serialized"
            )));
        }
        let world = universe.world();
        let (rank, size) = (world.rank() as usize, world.size() as usize);
        let library = mpi::environment::library_version().unwrap_or_else(|_| "MPI".into());
        let library = library.lines().next().unwrap_or("MPI").trim().to_string();
        Ok(Some(Self { inner: Mutex::new((universe, world)), rank, size, library }))
    }

    /// The MPI library's own name and version.
    pub fn library(&self) -> &str {
        &self.library
    }

    /// Waits for every rank.
    pub fn barrier(&self) {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).1.barrier();
    }
}

impl Reduce for Mpi {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn sum(&self, values: &mut [i64]) -> Result<()> {
        let world = &self.inner.lock().unwrap_or_else(|e| e.into_inner()).1;
        let mut sum = vec![0i64; values.len().min(CALL)];
        for part in values.chunks_mut(CALL) {
            let sum = &mut sum[..part.len()];
            world.all_reduce_into(&part[..], sum, SystemOperation::sum());
            part.copy_from_slice(sum);
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!("MPI, {} ranks: {}", self.size, self.library)
    }
}
