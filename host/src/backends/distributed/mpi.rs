//! The ranks of an MPI run (`mpirun -np P cvd run ...`), through the `mpi`
//! crate over the system's MPI library.

use super::{Parcels, Reduce};
use crate::error::{Error, Result};
use mpi::collective::SystemOperation;
use mpi::datatype::{Partition, PartitionMut};
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::Count;
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

    fn max(&self, values: &mut [f64]) -> Result<()> {
        let world = &self.inner.lock().unwrap_or_else(|e| e.into_inner()).1;
        let mut max = vec![0f64; values.len().min(CALL)];
        for part in values.chunks_mut(CALL) {
            let max = &mut max[..part.len()];
            world.all_reduce_into(&part[..], max, SystemOperation::max());
            part.copy_from_slice(max);
        }
        Ok(())
    }

    fn all_gather(&self, mine: &[u8]) -> Result<Vec<Vec<u8>>> {
        let world = &self.inner.lock().unwrap_or_else(|e| e.into_inner()).1;
        let mut lengths = vec![0u64; self.size];
        world.all_gather_into(&(mine.len() as u64), &mut lengths[..]);
        let (counts, displs) = counts_of(&lengths, "gathered")?;
        // A byte more: never an empty buffer whose pointer may be `mine`'s.
        let mut all = vec![0u8; lengths.iter().sum::<u64>() as usize + 1];
        {
            let mut to = PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
            world.all_gather_varcount_into(sendable(mine), &mut to);
        }
        Ok(split(all, &lengths))
    }

    fn exchange(&self, to: Parcels) -> Result<Parcels> {
        if to.len() != self.size {
            return Err(Error::Internal(format!("{} parcels exchanged among {} ranks", to.len(), self.size)));
        }
        let world = &self.inner.lock().unwrap_or_else(|e| e.into_inner()).1;
        let sent = to.lengths();
        let mut got = vec![0u64; self.size];
        world.all_to_all_into(&sent[..], &mut got[..]);
        // MPI's counts and displacements are `int`s: at most `per_pair`
        // bytes between two ranks in one call, in as many rounds as the
        // largest parcel of any rank needs.
        let per_pair = round_bytes(self.size);
        let most = sent.iter().chain(&got).copied().max().unwrap_or(0);
        let mut rounds = 0u64;
        world.all_reduce_into(&most.div_ceil(per_pair), &mut rounds, SystemOperation::max());
        let starts = |lengths: &[u64]| -> Vec<u64> {
            lengths.iter().scan(0, |at, &l| Some(std::mem::replace(at, *at + l))).collect()
        };
        let (send_starts, recv_starts) = (starts(&sent), starts(&got));
        // A byte more: never two empty buffers, whose pointers could be the
        // same, which MPI takes for one buffer sent in place.
        let mut all = vec![0u8; got.iter().sum::<u64>() as usize + 1];
        let ends = got.iter().scan(0, |at, &l| Some(std::mem::replace(at, *at + l as usize) + l as usize)).collect();
        if rounds <= 1 {
            // One call, from the parcels and into the result: no copy.
            let (send_counts, send_displs) = counts_of(&sent, "sent")?;
            let (counts, displs) = counts_of(&got, "received")?;
            let from = Partition::new(sendable(&to.bytes), &send_counts[..], &send_displs[..]);
            let mut into = PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
            world.all_to_all_varcount_into(&from, &mut into);
            all.pop();
            return Ok(Parcels { bytes: all, ends });
        }
        for round in 0..rounds {
            let part = |len: u64| len.saturating_sub(round * per_pair).min(per_pair);
            let (out, back): (Vec<u64>, Vec<u64>) =
                (sent.iter().map(|&l| part(l)).collect(), got.iter().map(|&l| part(l)).collect());
            let mut send = Vec::with_capacity(out.iter().sum::<u64>() as usize);
            for (q, &n) in out.iter().enumerate().filter(|&(_, &n)| n > 0) {
                let from = (send_starts[q] + round * per_pair) as usize;
                send.extend_from_slice(&to.bytes[from..from + n as usize]);
            }
            let (send_counts, send_displs) = counts_of(&out, "sent")?;
            let (counts, displs) = counts_of(&back, "received")?;
            send.push(0);
            let mut recv = vec![0u8; back.iter().sum::<u64>() as usize + 1];
            {
                let from = Partition::new(&send[..], &send_counts[..], &send_displs[..]);
                let mut into = PartitionMut::new(&mut recv[..], &counts[..], &displs[..]);
                world.all_to_all_varcount_into(&from, &mut into);
            }
            let mut at = 0;
            for (q, &n) in back.iter().enumerate().filter(|&(_, &n)| n > 0) {
                let into = (recv_starts[q] + round * per_pair) as usize;
                all[into..into + n as usize].copy_from_slice(&recv[at..at + n as usize]);
                at += n as usize;
            }
        }
        all.pop();
        Ok(Parcels { bytes: all, ends })
    }

    fn describe(&self) -> String {
        format!("MPI, {} ranks: {}", self.size, self.library)
    }

    fn abort(&self, code: i32) {
        if self.size > 1 {
            // Not through the lock: another thread may hold it, waiting.
            // SAFETY: MPI_Abort on the world communicator, which ends
            // every process of the run; it does not return.
            unsafe {
                mpi::ffi::MPI_Abort(mpi::ffi::RSMPI_COMM_WORLD, code);
            }
        }
    }
}

/// The most bytes one exchange sends between two ranks in one MPI call:
/// what an `int` count allows among `ranks`, or less where the environment
/// says (`CVD_MPI_ROUND_BYTES`, which the tests set to exchange in many
/// rounds).
fn round_bytes(ranks: usize) -> u64 {
    let most = (Count::MAX as u64 / ranks.max(1) as u64).max(1);
    let asked = std::env::var("CVD_MPI_ROUND_BYTES").ok().and_then(|v| v.parse::<u64>().ok());
    asked.map_or(most, |a| a.clamp(1, most))
}

/// MPI's counts and displacements (`int`s) of buffers of `lengths` bytes,
/// or an error naming what does not fit them.
fn counts_of(lengths: &[u64], what: &str) -> Result<(Vec<Count>, Vec<Count>)> {
    let total: u64 = lengths.iter().sum();
    if total > Count::MAX as u64 {
        return Err(Error::TooLarge {
            what: format!("the bytes {what} in one exchange between MPI ranks"),
            needed: total,
            limit: Count::MAX as u64,
            of: "MPI's count (an int) per call".into(),
        });
    }
    let counts: Vec<Count> = lengths.iter().map(|&l| l as Count).collect();
    let displs: Vec<Count> = counts.iter().scan(0, |at, &c| Some(std::mem::replace(at, *at + c))).collect();
    Ok((counts, displs))
}

/// `all` cut into buffers of `lengths` bytes.
fn split(all: Vec<u8>, lengths: &[u64]) -> Vec<Vec<u8>> {
    let mut at = 0;
    lengths
        .iter()
        .map(|&l| {
            let part = all[at..at + l as usize].to_vec();
            at += l as usize;
            part
        })
        .collect()
}

/// `bytes` as a send buffer MPI cannot take for `MPI_IN_PLACE`: Open
/// MPI's `MPI_IN_PLACE` is the address 1, which is also where an empty
/// `Vec<u8>` points. A rank sending nothing through it would run the
/// in-place algorithm while the others do not, and the ranks would wait
/// for one another forever. Nothing is read from it: it is empty too (a
/// send count of one byte, where the others receive none from this rank,
/// would shift what they receive).
fn sendable(bytes: &[u8]) -> &[u8] {
    static NOTHING: [u8; 1] = [0];
    if bytes.is_empty() {
        &NOTHING[..0]
    } else {
        bytes
    }
}
