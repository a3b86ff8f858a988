//! A clipping job in parts by space, on one machine or over MPI, with the
//! same results to the bit as the whole job in one process.
//!
//! The job's tets are in Morton order; part `p` of `P` is a run of them
//! (balanced by the pieces they are estimated to hold), so each part is a
//! compact piece of the domain.
//! A part computes with the sites of a box of grid cells around its tets
//! ([`halo`]), whose neighbour lists, flood starts and walks are
//! certified, not guessed: a tet whose flood needed a site outside the box
//! adds nothing and is done again in the next round, grouped with its
//! nearby tets, with a halo twice as wide, until none is left (at worst the
//! box is the whole grid). Every tet's pieces are clipped as in one process,
//! and the sums are fixed point: adding the parts' sums, in any order, gives
//! the same bits.
//!
//! Whole cells (the default strategy on the CPU) are split by sites
//! instead: part `p` builds the cells of a run of the job's sites (in
//! Morton order: a compact piece of the domain), with the whole job's
//! lists, walks and pieces ([`ClipJob::answering`]), so each site's sums
//! and face sums come from one part, as one process makes them. Every rank
//! holds the whole job there; each builds its share of the cells and of
//! their lists.
//!
//! [`Distributed`] is a [`Backend`]: it computes the parts of its rank on
//! the CPU and adds the sums of all ranks through a [`Reduce`] — an MPI
//! all-reduce (`cvd::backends::distributed::mpi`, the `mpi` feature), or nothing in
//! one process ([`OneProcess`]), where one rank may compute several parts one
//! after another (what P ranks compute, in one process, and in a
//! P-th of the memory for the lists and grids). So the diagram, Lloyd's
//! iterations and everything built on [`Backend::clip`] run distributed.

pub mod halo;
#[cfg(feature = "mpi")]
pub mod mpi;

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::exec::{CpuBackend, TaskSink};
use crate::geom::exact_sum::ExactSum;
use crate::geom::timing::{timed, Timings};
use crate::job::clip::{ClipJob, ClipOutput, JobShape, Pairing, Strategy};
use crate::job::held::HeldCells;
use crate::job::knn::{KnnJob, Neighbors};
use crate::job::BackendKind;
use cvd_kernels::abi::{counter, ACCUM_PER_SITE, OUT_OF_HALO};
use cvd_kernels::clip::NoPieces;
use halo::{cells_of, part_job, ListedCells, SitesByCell};
use std::sync::Mutex;

/// Adds numbers across the ranks of a distributed run.
pub trait Reduce: Send + Sync {
    /// This rank, `0..size`.
    fn rank(&self) -> usize;
    /// Ranks in all.
    fn size(&self) -> usize;
    /// Replaces `values` on every rank by their sums over all ranks (the
    /// same on every rank).
    fn sum(&self, values: &mut [i64]) -> Result<()>;
    /// Replaces `values` on every rank by their largest over all ranks.
    fn max(&self, values: &mut [f64]) -> Result<()>;
    /// Every rank's `mine`, by rank (the same on every rank).
    fn all_gather(&self, mine: &[u8]) -> Result<Vec<Vec<u8>>>;
    /// Sends each rank its parcel of `to` and returns what each rank sent
    /// this one.
    fn exchange(&self, to: Parcels) -> Result<Parcels>;
    /// What the ranks are, for reports (e.g. `MPI, 4 ranks`).
    fn describe(&self) -> String;
    /// Every rank's `value`, by rank (the same on every rank).
    fn gather_u64(&self, value: u64) -> Result<Vec<u64>> {
        let all = self.all_gather(&value.to_le_bytes())?;
        Ok(all
            .iter()
            .map(|b| u64::from_le_bytes(b.get(..8).and_then(|b| b.try_into().ok()).unwrap_or([0; 8])))
            .collect())
    }

    /// The exact sum of every rank's terms (`mine`: this rank's), the same
    /// bits on every rank whatever the split: one integer sum of words.
    fn exact_total(&self, mine: &ExactSum) -> Result<ExactSum> {
        let mut words = mine.words();
        self.sum(&mut words)?;
        ExactSum::from_words(&words).ok_or_else(|| Error::Internal("a sum's words did not come through".into()))
    }

    /// Ends every rank with exit status `code`, where the ranks are
    /// processes that would otherwise wait for this one in their next
    /// collective (MPI's); elsewhere nothing (the error returns as usual).
    fn abort(&self, _code: i32) {}
}

/// A buffer of bytes for (or from) each rank, laid end to end in one
/// allocation: what an exchange between ranks sends and receives.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Parcels {
    /// Every parcel's bytes, rank 0's first.
    pub bytes: Vec<u8>,
    /// Where each rank's parcel ends in `bytes`.
    pub ends: Vec<usize>,
}

impl Parcels {
    /// The parcels `parts`, one per rank, laid end to end.
    pub fn of(parts: Vec<Vec<u8>>) -> Self {
        let ends = parts.iter().scan(0, |at, p| Some(std::mem::replace(at, *at + p.len()) + p.len())).collect();
        Self { bytes: parts.concat(), ends }
    }

    /// Ranks.
    pub fn len(&self) -> usize {
        self.ends.len()
    }

    /// Whether there is no rank.
    pub fn is_empty(&self) -> bool {
        self.ends.is_empty()
    }

    /// Rank `r`'s parcel.
    pub fn get(&self, r: usize) -> &[u8] {
        let start = if r == 0 { 0 } else { self.ends[r - 1] };
        &self.bytes[start..self.ends[r]]
    }

    /// Each parcel's length.
    pub fn lengths(&self) -> Vec<u64> {
        (0..self.len()).map(|r| self.get(r).len() as u64).collect()
    }
}

/// One process: nothing to add.
#[derive(Clone, Copy, Debug, Default)]
pub struct OneProcess;

impl Reduce for OneProcess {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn sum(&self, _values: &mut [i64]) -> Result<()> {
        Ok(())
    }
    fn max(&self, _values: &mut [f64]) -> Result<()> {
        Ok(())
    }
    fn all_gather(&self, mine: &[u8]) -> Result<Vec<Vec<u8>>> {
        Ok(vec![mine.to_vec()])
    }
    fn exchange(&self, to: Parcels) -> Result<Parcels> {
        if to.len() != 1 {
            return Err(Error::Internal(format!("{} parcels exchanged in one process", to.len())));
        }
        Ok(to)
    }
    fn describe(&self) -> String {
        "one process".into()
    }
}

/// `size` ranks in one process, one per thread (a run in parts tested, or
/// run, without MPI): each collective waits for every rank.
pub struct InProcess {
    rank: usize,
    shared: std::sync::Arc<Shared>,
}

/// What the ranks of [`InProcess`] share: a slot per rank, and a barrier.
struct Shared {
    slots: Mutex<Vec<Parcels>>,
    barrier: std::sync::Barrier,
}

impl InProcess {
    /// The `size` ranks, to be moved each to its own thread.
    pub fn ranks(size: usize) -> Vec<Self> {
        let shared = std::sync::Arc::new(Shared {
            slots: Mutex::new(vec![Parcels::default(); size]),
            barrier: std::sync::Barrier::new(size),
        });
        (0..size).map(|rank| Self { rank, shared: shared.clone() }).collect()
    }

    /// Runs `run` on each of `size` ranks, each on its own thread; their
    /// results by rank. A panic on a rank is raised here.
    pub fn each<T: Send>(size: usize, run: impl Fn(&InProcess) -> T + Sync) -> Vec<T> {
        std::thread::scope(|scope| {
            let run = &run;
            let handles: Vec<_> = Self::ranks(size).into_iter().map(|comm| scope.spawn(move || run(&comm))).collect();
            handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
        })
    }

    /// Puts `mine` (a parcel per rank, or one for all) in this rank's
    /// slot and returns every rank's parcel for this one.
    fn swap(&self, mine: Parcels, each: bool) -> Vec<Vec<u8>> {
        let lock = || self.shared.slots.lock().unwrap_or_else(|e| e.into_inner());
        lock()[self.rank] = mine;
        self.shared.barrier.wait();
        let got = lock().iter().map(|s| s.get(if each { self.rank } else { 0 }).to_vec()).collect();
        self.shared.barrier.wait();
        got
    }
}

impl Reduce for InProcess {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.shared.barrier_size()
    }
    fn sum(&self, values: &mut [i64]) -> Result<()> {
        let all = self.swap(Parcels::of(vec![bytemuck::cast_slice(values).to_vec()]), false);
        values.fill(0);
        for b in all {
            for (v, w) in values.iter_mut().zip(b.as_chunks::<8>().0) {
                *v += i64::from_ne_bytes(*w);
            }
        }
        Ok(())
    }
    fn max(&self, values: &mut [f64]) -> Result<()> {
        let all = self.swap(Parcels::of(vec![bytemuck::cast_slice(values).to_vec()]), false);
        for b in all {
            for (v, w) in values.iter_mut().zip(b.as_chunks::<8>().0) {
                *v = v.max(f64::from_ne_bytes(*w));
            }
        }
        Ok(())
    }
    fn all_gather(&self, mine: &[u8]) -> Result<Vec<Vec<u8>>> {
        Ok(self.swap(Parcels::of(vec![mine.to_vec()]), false))
    }
    fn exchange(&self, to: Parcels) -> Result<Parcels> {
        if to.len() != self.size() {
            return Err(Error::Internal(format!("{} parcels exchanged among {} ranks", to.len(), self.size())));
        }
        Ok(Parcels::of(self.swap(to, true)))
    }
    fn describe(&self) -> String {
        format!("{} ranks in one process", self.size())
    }
}

impl Shared {
    fn barrier_size(&self) -> usize {
        self.slots.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
}

/// Grid cells around the cells a part's tets overlap whose sites get
/// neighbour lists (the sites whose cells meet its tets lie within about
/// one cell of them; a cell holds about five sites).
const LIST_HALO: u32 = 1;

/// Further cells held beyond the listed ones' box: the reach of the listed
/// sites' k-th neighbours (about 1.3 cells at `k_site` = 48) and walks.
const WALK_HALO: u32 = 2;

/// Most cells along an axis of a group of tets done again together.
const GROUP_CELLS: u32 = 8;

/// The environment variable by which an MPI launcher (Open MPI's or
/// MPICH's `mpirun`, Slurm's `srun` with PMI or PMIx) says it started this
/// process, if one did.
pub fn mpi_launcher() -> Option<&'static str> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"].into_iter().find(|v| std::env::var_os(v).is_some())
}

/// A communicator between the processes of a run.
pub type Comm = Box<dyn Reduce>;

/// Whether this build speaks MPI (its `mpi` feature).
pub const HAS_MPI: bool = cfg!(feature = "mpi");

/// This process's communicator when an MPI launcher started it
/// ([`mpi_launcher`]): MPI's in a build with the `mpi` feature; in a build
/// without it, none and a warning that every rank computes the whole job.
/// Without a launcher: none, and no warning.
pub fn launched_comm() -> Result<(Option<Comm>, Option<String>)> {
    let Some(var) = mpi_launcher() else { return Ok((None, None)) };
    #[cfg(feature = "mpi")]
    {
        let _ = var;
        Ok((mpi::Mpi::init()?.map(|m| Box::new(m) as Box<dyn Reduce>), None))
    }
    #[cfg(not(feature = "mpi"))]
    Ok((
        None,
        Some(format!(
            "started by an MPI launcher ({var}), but this cvd was built without the `mpi` feature: \
             every rank computes the whole job (build with --features mpi)"
        )),
    ))
}

/// Sorts rows held by the ranks of `comm` by `key`, as one sort of all of
/// them would: returns this rank's run of the sorted whole (rank 0 the
/// first, then rank 1's, and so on; rows of one key on one rank, in rank
/// order and then in each rank's order). The runs' lengths follow a
/// sample of the keys (each rank's at evenly spaced places), so they are
/// about equal; the rows travel once (a sample sort). A particle file's
/// rows read in parts are put in order of their ids so.
pub fn sort_across<T: bytemuck::Pod>(comm: &dyn Reduce, mut rows: Vec<T>, key: impl Fn(&T) -> u64) -> Result<Vec<T>> {
    rows.sort_by_key(&key);
    let ranks = comm.size();
    if ranks == 1 {
        return Ok(rows);
    }
    // The sample: keys at evenly spaced places, each with the rows it
    // stands for.
    const SAMPLES_PER_RANK: usize = 64;
    let n = rows.len();
    let s = n.min(SAMPLES_PER_RANK * ranks);
    let mut sample = Vec::with_capacity(16 * s);
    for k in 0..s {
        let (at, next) = (k * n / s, (k + 1) * n / s);
        sample.extend_from_slice(&key(&rows[at]).to_le_bytes());
        sample.extend_from_slice(&((next - at) as u64).to_le_bytes());
    }
    let mut weighed: Vec<(u64, u64)> = comm
        .all_gather(&sample)?
        .iter()
        .flat_map(|b| {
            let pairs = b.as_chunks::<8>().0.as_chunks::<2>().0;
            pairs.iter().map(|[k, w]| (u64::from_le_bytes(*k), u64::from_le_bytes(*w))).collect::<Vec<_>>()
        })
        .collect();
    weighed.sort_unstable();
    let total: u64 = weighed.iter().map(|w| w.1).sum();
    // Rank r takes the keys from the r-th splitter on, up to the next.
    let mut splitters = vec![0u64; ranks];
    let mut before = 0u64;
    let mut r = 1;
    for &(k, w) in &weighed {
        while r < ranks && (before as u128) * (ranks as u128) >= (total as u128) * (r as u128) {
            splitters[r] = k;
            r += 1;
        }
        before += w;
    }
    for s in &mut splitters[r..] {
        *s = u64::MAX;
    }
    let mut to = vec![Vec::new(); ranks];
    let mut from = 0;
    for (r, part) in to.iter_mut().enumerate() {
        let end = match splitters.get(r + 1) {
            Some(&next) => rows.partition_point(|x| key(x) < next).max(from),
            None => n,
        };
        *part = bytemuck::cast_slice(&rows[from..end]).to_vec();
        from = end;
    }
    drop(rows);
    let got = comm.exchange(Parcels::of(to))?;
    let size = size_of::<T>();
    let mut mine: Vec<T> =
        got.bytes.chunks_exact(size.max(1)).map(|b| bytemuck::pod_read_unaligned(&b[..size])).collect();
    // Each rank's run in order already: a stable sort keeps rank order.
    mine.sort_by_key(&key);
    Ok(mine)
}

/// Where each of `parts` runs of `job`'s tets begins (and the last ends),
/// balanced by an estimate of each tet's pieces: a tet of volume `V` where
/// the sites have density `ρ` (those of its centroid's grid cell) meets
/// about `(1 + (ρV)^(1/3))³` cells — one when it is small beside them,
/// `ρV` when it holds many. Clustered sites put most of the work in few
/// tets; by count, one part would get most of it.
fn balanced_bounds(job: &ClipJob, by_cell: &SitesByCell, parts: usize) -> Vec<usize> {
    let g = &job.site_knn.params.grid;
    let cell = g.cell_size as f64 / job.site_knn.quantizer.scale();
    let density = |t: usize| {
        let q = job.tet_query(t);
        let c = cvd_kernels::grid::cell_index(g, cvd_kernels::grid::cell_coords(g, [q[0], q[1], q[2]]));
        by_cell.count(c) as f64 / cell.powi(3)
    };
    let mut total = 0.0;
    let prefix: Vec<f64> = (0..job.tets.len())
        .map(|t| {
            let v = job.tets[t].map(|i| job.verts[i as usize].to_f64());
            let volume = crate::geom::mesh::signed_volume(v[0], v[1], v[2], v[3]).abs();
            total += (1.0 + (density(t) * volume).cbrt()).powi(3);
            total
        })
        .collect();
    let mut bounds = vec![0];
    for p in 1..parts {
        let share = total * p as f64 / parts as f64;
        let at = prefix.partition_point(|&w| w < share);
        bounds.push(at.max(*bounds.last().unwrap_or(&0)));
    }
    bounds.push(job.tets.len());
    bounds
}

/// What one round of a part did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Round {
    /// Tets computed in the round.
    pub tets: u64,
    /// Boxes of cells (one in the first round; groups of nearby tets
    /// after).
    pub groups: u64,
    /// Sites held, summed over the groups.
    pub held_sites: u64,
    /// Sites with a neighbour list computed, summed over the groups.
    pub listed_sites: u64,
    /// Of those, lists certified.
    pub certified_lists: u64,
    /// Tets left for the next round (their flood needed a site outside).
    pub out_of_halo: u64,
    /// The halo in cells beyond the tets' cells.
    pub halo_cells: u32,
    /// Seconds.
    pub seconds: f64,
}

/// What this rank's parts did, round by round.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct PartReport {
    /// This rank.
    pub rank: usize,
    /// Ranks.
    pub ranks: usize,
    /// The parts this rank computed.
    pub parts: Vec<usize>,
    /// Parts in all.
    pub of: usize,
    /// Tets of this rank's parts.
    pub tets: u64,
    /// Each round, summed over this rank's parts.
    pub rounds: Vec<Round>,
    /// Seconds in the all-reduce.
    pub reduce_seconds: f64,
    /// Every rank's totals (the same on every rank).
    pub all: Vec<RankTotals>,
}

/// One rank's totals for a job, gathered on every rank.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct RankTotals {
    /// Tets of its parts.
    pub tets: u64,
    /// Sites held in the first round (its parts' boxes; whole cells: every
    /// site).
    pub held_sites: u64,
    /// Sites with neighbour lists in the first round (whole cells: the
    /// cells it built).
    pub listed_sites: u64,
    /// Tets done again in later rounds.
    pub tets_again: u64,
    /// Rounds.
    pub rounds: u64,
    /// Microseconds computing its parts (before the all-reduce).
    pub micros: u64,
}

impl RankTotals {
    const FIELDS: usize = 6;

    fn of(report: &PartReport, seconds: f64) -> Self {
        let first = report.rounds.first().copied().unwrap_or_default();
        Self {
            tets: report.tets,
            held_sites: first.held_sites,
            listed_sites: first.listed_sites,
            tets_again: report.rounds.iter().skip(1).map(|r| r.tets).sum(),
            rounds: report.rounds.len() as u64,
            micros: (seconds * 1e6) as u64,
        }
    }

    fn to_words(self) -> [i64; Self::FIELDS] {
        [self.tets, self.held_sites, self.listed_sites, self.tets_again, self.rounds, self.micros].map(|v| v as i64)
    }

    fn from_words(w: &[i64]) -> Self {
        let v = |i: usize| w[i].max(0) as u64;
        Self { tets: v(0), held_sites: v(1), listed_sites: v(2), tets_again: v(3), rounds: v(4), micros: v(5) }
    }
}

/// A backend that computes the parts of its rank of a job on the CPU and
/// adds the sums of every rank (see the module's documentation): tet-cell
/// with flood pairing (parts by tets, without face sums), or whole cells
/// (parts by sites, faces included: `Distributed::clip_whole`).
pub struct Distributed {
    cpu: CpuBackend,
    comm: Box<dyn Reduce>,
    /// Parts per rank.
    per_rank: usize,
    /// Cells around a part's tets with lists, and held beyond them, in the
    /// first round.
    halo: [u32; 2],
    report: Mutex<PartReport>,
}

impl Distributed {
    /// The parts `rank * per_rank..(rank + 1) * per_rank` of `size *
    /// per_rank` for `comm`'s rank, on `cpu`.
    pub fn new(cpu: CpuBackend, comm: Box<dyn Reduce>, per_rank: usize) -> Result<Self> {
        if per_rank == 0 {
            return Err(Error::InvalidInput("parts per rank must be at least 1".into()));
        }
        Ok(Self { cpu, comm, per_rank, halo: [LIST_HALO, WALK_HALO], report: Mutex::new(PartReport::default()) })
    }

    /// The first round's halo: `listed` cells around a part's tets whose
    /// sites get neighbour lists, and `beyond` more cells whose sites are
    /// held (default 1 and 2). Narrower halos hold fewer sites and leave
    /// more tets for the next rounds; the results are the same.
    pub fn with_halo(mut self, listed: u32, beyond: u32) -> Self {
        self.halo = [listed.max(1), beyond];
        self
    }

    /// What the last job's parts did on this rank.
    pub fn report(&self) -> PartReport {
        self.report.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// This rank.
    pub fn rank(&self) -> usize {
        self.comm.rank()
    }

    /// The ranks' reducer.
    pub fn comm(&self) -> &dyn Reduce {
        self.comm.as_ref()
    }

    /// The report of this rank's parts, before they run.
    fn new_report(&self) -> PartReport {
        let (rank, ranks, per) = (self.comm.rank(), self.comm.size(), self.per_rank);
        PartReport {
            rank,
            ranks,
            parts: (rank * per..(rank + 1) * per).collect(),
            of: ranks * per,
            ..Default::default()
        }
    }

    /// This rank's parts of `job`, their sums added into `sums` (the whole
    /// job's layout), counters into `counters`; returns the second pass's
    /// finished and unresolved entries.
    fn clip_parts(
        &self,
        job: &ClipJob,
        sums: &mut [i64],
        counters: &mut [i64],
        timings: &mut Timings,
    ) -> Result<[u64; 2]> {
        let (by_cell, t) = timed(|| SitesByCell::new(job));
        timings.add("halo", t);
        let mut report = self.new_report();
        let (of, parts) = (report.of, report.parts.clone());
        let mut redone = [0u64; 2];
        let bounds = balanced_bounds(job, &by_cell, of);
        for &p in &parts {
            let range = bounds[p]..bounds[p + 1];
            report.tets += range.len() as u64;
            let tets: Vec<u32> = range.map(|t| t as u32).collect();
            let r = self.clip_part(job, &by_cell, tets, sums, counters, timings)?;
            for (i, round) in r.rounds.iter().enumerate() {
                if report.rounds.len() <= i {
                    report.rounds.push(Round { halo_cells: round.halo_cells, ..Round::default() });
                }
                let to = &mut report.rounds[i];
                to.tets += round.tets;
                to.groups += round.groups;
                to.held_sites += round.held_sites;
                to.listed_sites += round.listed_sites;
                to.certified_lists += round.certified_lists;
                to.out_of_halo += round.out_of_halo;
                to.seconds += round.seconds;
            }
            redone[0] += r.redone[0];
            redone[1] += r.redone[1];
        }
        *self.report.lock().unwrap_or_else(|e| e.into_inner()) = report;
        Ok(redone)
    }

    /// The tets `tets` of `job`, round after round (see the module's
    /// documentation); then, holding every site, the tets the kernels
    /// could not finish for want of room (the host pass's).
    fn clip_part(
        &self,
        job: &ClipJob,
        by_cell: &SitesByCell,
        mut todo: Vec<u32>,
        sums: &mut [i64],
        counters: &mut [i64],
        timings: &mut Timings,
    ) -> Result<PartOutcome> {
        let g = &job.site_knn.params.grid;
        let grid = [g.dim_x, g.dim_y, g.dim_z];
        let mut outcome = PartOutcome::default();
        let mut host = Vec::new();
        let mut scale = 1;
        while !todo.is_empty() || !host.is_empty() {
            let start = std::time::Instant::now();
            let (list_halo, mut halo) = (self.halo[0] * scale, (self.halo[0] + self.halo[1]) * scale);
            let groups = if todo.is_empty() {
                // Every site held, the tets for the host pass together.
                halo = grid.into_iter().max().unwrap_or(0);
                vec![std::mem::take(&mut host)]
            } else if outcome.rounds.is_empty() {
                // The first round in one box; then nearby tets together.
                vec![std::mem::take(&mut todo)]
            } else {
                groups(job, &std::mem::take(&mut todo))
            };
            let mut round = Round { groups: groups.len() as u64, halo_cells: halo, ..Round::default() };
            for group in groups {
                round.tets += group.len() as u64;
                let (lo, hi) = cells_of(job, &group);
                let held = HeldCells::around(lo, hi, halo, grid, g.cell_size);
                let (part, t) = timed(|| {
                    let listed = ListedCells::around(job, &group, held, list_halo);
                    part_job(job, by_cell, &group, held, &listed)
                });
                let (part, sites) = part?;
                timings.add("halo", t);
                round.held_sites += sites.len() as u64;
                round.listed_sites += part.site_knn.queries.len() as u64;
                let mut out = self.cpu.clip(&part)?;
                round.certified_lists += out.certified;
                if held.is_whole() {
                    // Every site is held, but not every site's list: a tet
                    // that needed one not computed goes round again with
                    // more listed; the host pass finishes the rest, as in
                    // one process.
                    let (halo_left, rest) = out.unfinished.iter().partition(|e| e[1] == OUT_OF_HALO);
                    let halo_left: Vec<[u32; 2]> = halo_left;
                    out.unfinished = rest;
                    round.out_of_halo += halo_left.len() as u64;
                    host.extend(halo_left.iter().map(|e| group[e[0] as usize]));
                    let none = Mutex::new(Vec::<NoPieces>::new());
                    let (r, t) = timed(|| crate::passes::second_pass::run(&part, &mut out, &none));
                    let r = r?;
                    timings.add("host pass", t);
                    outcome.redone[0] += r.finished;
                    outcome.redone[1] += r.unresolved;
                } else {
                    // A tet left unfinished added nothing: all of it again,
                    // with a wider halo, or with every site for the host
                    // pass.
                    for &[t, why] in &out.unfinished {
                        if why == OUT_OF_HALO {
                            round.out_of_halo += 1;
                            todo.push(group[t as usize]);
                        } else {
                            host.push(group[t as usize]);
                        }
                    }
                }
                outcome.redone[0] += out.refined;
                for (l, &s) in sites.iter().enumerate() {
                    let (from, to) = (l * ACCUM_PER_SITE, s as usize * ACCUM_PER_SITE);
                    for a in 0..ACCUM_PER_SITE {
                        sums[to + a] += out.sums[from + a];
                    }
                }
                for (c, v) in counters.iter_mut().zip(&out.counters) {
                    *c += v;
                }
                for (phase, s) in &out.timings.phases {
                    timings.add(phase, *s);
                }
            }
            todo.sort_unstable();
            todo.dedup();
            host.sort_unstable();
            host.dedup();
            round.seconds = start.elapsed().as_secs_f64();
            outcome.rounds.push(round);
            scale *= 2;
        }
        Ok(outcome)
    }
}

impl Distributed {
    /// Whole cells: this rank's parts are runs of the job's answered sites
    /// (in Morton order, so each is a compact piece of the domain), each
    /// built by the whole job answering them alone ([`ClipJob::answering`]):
    /// the same lists, walks and pieces as in one process, so every site's
    /// sums and face sums come from one rank, to the bit, and the
    /// all-reduce adds zeros to them. The cells the kernels could not
    /// finish are gathered from every rank and finished by each rank's host
    /// pass, as one process finishes them. Every rank holds the whole job;
    /// each builds its share of the cells, lists and pieces.
    fn clip_whole(&self, job: &ClipJob) -> Result<ClipOutput> {
        self.clip_whole_into(job, &Mutex::new(Vec::<NoPieces>::new()))
    }

    /// Where part `p` of a whole-cell job's answered sites begins (and
    /// part `p - 1` ends).
    fn share_start(&self, job: &ClipJob, p: usize) -> usize {
        let (lo, hi) = (job.params.own_lo as usize, job.params.own_hi as usize);
        lo + (hi - lo) * p / (self.comm.size() * self.per_rank)
    }

    /// The sites (places in a whole-cell job's order) whose cells this
    /// rank builds.
    pub(crate) fn share(&self, job: &ClipJob) -> std::ops::Range<usize> {
        let first = self.comm.rank() * self.per_rank;
        self.share_start(job, first)..self.share_start(job, first + self.per_rank)
    }

    /// [`Self::clip_whole`], with the pieces of this rank's cells in
    /// `sinks`.
    pub(crate) fn clip_whole_into<S: TaskSink>(&self, job: &ClipJob, sinks: &Mutex<Vec<S>>) -> Result<ClipOutput> {
        let of = self.comm.size() * self.per_rank;
        let share = |p: usize| self.share_start(job, p);
        let (n, f) = (job.params.n_sites as usize * ACCUM_PER_SITE, job.face_sums_len());
        // The first part's sums and face sums take the others' (each the
        // whole job's size): no buffer more.
        let (mut sums, mut faces) = (Vec::new(), Vec::new());
        let mut small = vec![0i64; counter::COUNT + 2];
        let mut timings = Timings::default();
        let mut unfinished: Vec<[u32; 2]> = Vec::new();
        // With faces, each part's lists (the host reads them to place the
        // face sums): laid end to end in part order, the whole job's.
        let mut lists: Option<(Vec<u32>, u32, u32)> = (f > 0).then(|| (Vec::new(), 0, 0));
        let mut report = self.new_report();
        let parts = report.parts.clone();
        let mut round = Round { groups: parts.len() as u64, ..Round::default() };
        let clock = std::time::Instant::now();
        for &p in &parts {
            let range = share(p)..share(p + 1);
            if range.is_empty() {
                continue;
            }
            round.held_sites = job.sites.len() as u64;
            round.listed_sites += range.len() as u64;
            let mut out = self.cpu.clip_into(&job.answering(range.clone())?, sinks)?;
            for (to, from) in [(&mut sums, &mut out.sums), (&mut faces, &mut out.faces)] {
                match to.is_empty() {
                    true => *to = std::mem::take(from),
                    false => to.iter_mut().zip(from.iter()).for_each(|(a, b)| *a += b),
                }
            }
            let (counters, redone) = small.split_at_mut(counter::COUNT);
            counters.iter_mut().zip(&out.counters).for_each(|(a, b)| *a += b);
            redone[0] += out.refined as i64;
            redone[1] += out.unresolved as i64;
            unfinished.extend_from_slice(&out.unfinished);
            let l = &out.site_lists;
            let whole = l.words.len() >= cvd_kernels::lists::stride(l.k, l.bits) * range.len() && l.k > 0;
            lists = match lists.take() {
                Some((mut words, k, bits)) if whole && (words.is_empty() || (k, bits) == (l.k, l.bits)) => {
                    words.extend_from_slice(&l.words[..cvd_kernels::lists::stride(l.k, l.bits) * range.len()]);
                    Some((words, l.k, l.bits))
                }
                _ => None,
            };
            for (phase, s) in &out.timings.phases {
                timings.add(phase, *s);
            }
        }
        let seconds = clock.elapsed().as_secs_f64();
        round.seconds = seconds;
        report.rounds = vec![round];
        let mine = RankTotals::of(&report, seconds).to_words();
        // Every rank's lists, or none if a rank has none to give (the
        // host then lists the sites again).
        let shape = lists.as_ref().map_or([0u32; 2], |l| [l.1, l.2]);
        let (gathered, t) = timed(|| -> Result<_> {
            // A rank without parts adds zeros.
            sums.resize(n, 0);
            faces.resize(f, 0);
            self.comm.sum(&mut sums)?;
            self.comm.sum(&mut faces)?;
            self.comm.sum(&mut small)?;
            let totals = self.comm.all_gather(bytemuck::cast_slice(&mine))?;
            let entries = self.comm.all_gather(bytemuck::cast_slice(&unfinished))?;
            let shapes = match f > 0 {
                true => self.comm.all_gather(bytemuck::cast_slice(&shape))?,
                false => Vec::new(),
            };
            let agreed = !shapes.is_empty() && shapes.iter().all(|b| records::<u32>(b).eq(shape) && shape[0] > 0);
            let words = match (agreed, lists.take()) {
                (true, Some(l)) => Some(self.comm.all_gather(bytemuck::cast_slice(&l.0))?),
                _ => None,
            };
            Ok((totals, entries, words))
        });
        let (totals, entries, words) = gathered?;
        let site_lists = match words {
            Some(words) => {
                // Each rank's bytes dropped as soon as read.
                let total = words.iter().map(|b| b.len() / 4).sum::<usize>() + cvd_kernels::lists::spare(shape[1]);
                let mut all = Vec::with_capacity(total);
                for b in words {
                    all.extend(b.as_chunks::<4>().0.iter().map(|w| u32::from_ne_bytes(*w)));
                }
                all.resize(total, 0);
                let words = all;
                crate::job::knn::PackedLists { words, k: shape[0], bits: shape[1], timings: Timings::default() }
            }
            None => Default::default(),
        };
        timings.push("reduce", t);
        report.reduce_seconds = t;
        report.all = totals.iter().map(|b| RankTotals::from_words(&records::<i64>(b).collect::<Vec<_>>())).collect();
        let mut unfinished: Vec<[u32; 2]> = entries.iter().flat_map(|b| records::<[u32; 2]>(b)).collect();
        unfinished.sort_unstable();
        *self.report.lock().unwrap_or_else(|e| e.into_inner()) = report;
        let redone = small.split_off(counter::COUNT);
        Ok(ClipOutput {
            sums,
            tet_volumes: vec![0; job.tets.len()],
            faces,
            site_lists,
            counters: small,
            unfinished,
            refined: redone[0] as u64,
            unresolved: redone[1] as u64,
            chunks: of as u64,
            timings,
            ..Default::default()
        })
    }
}

/// The records of type `T` laid end to end in `bytes` (what a rank sent),
/// one after another.
pub(crate) fn records<T: bytemuck::Pod>(bytes: &[u8]) -> impl Iterator<Item = T> + '_ {
    bytes.chunks_exact(size_of::<T>()).map(bytemuck::pod_read_unaligned)
}

/// What a part's rounds did.
#[derive(Default)]
struct PartOutcome {
    rounds: Vec<Round>,
    /// Entries finished by the second passes, and left unresolved.
    redone: [u64; 2],
}

/// `tets` (in the job's order) in runs whose cells span at most
/// [`GROUP_CELLS`] along each axis.
fn groups(job: &ClipJob, tets: &[u32]) -> Vec<Vec<u32>> {
    let mut out: Vec<Vec<u32>> = Vec::new();
    let (mut lo, mut hi) = ([0u32; 3], [0u32; 3]);
    for &t in tets {
        let (a, b) = cells_of(job, &[t]);
        let (l, h) = ([0, 1, 2].map(|i| a[i].min(lo[i])), [0, 1, 2].map(|i| b[i].max(hi[i])));
        match out.last_mut() {
            Some(group) if (0..3).all(|i| h[i] - l[i] < GROUP_CELLS) => {
                group.push(t);
                (lo, hi) = (l, h);
            }
            _ => {
                out.push(vec![t]);
                (lo, hi) = (a, b);
            }
        }
    }
    out
}

impl Backend for Distributed {
    fn kind(&self) -> BackendKind {
        BackendKind::Cpu
    }

    fn device(&self) -> String {
        format!(
            "{} threads, rank {} of {} ({})",
            self.cpu.threads(),
            self.comm.rank(),
            self.comm.size(),
            self.comm.describe()
        )
    }

    /// As one process on the CPU: whole cells (each rank building a share
    /// of them), or tet-cell's floods where tets outnumber sites.
    fn default_strategy(&self, shape: JobShape) -> Strategy {
        Strategy::auto(BackendKind::Cpu, shape)
    }

    fn name(&self) -> String {
        format!("distributed {} parts ({})", self.comm.size() * self.per_rank, self.device())
    }

    fn knn(&self, job: &KnnJob) -> Result<Neighbors> {
        self.cpu.knn(job)
    }

    /// The whole job's sums and counters, the same on every rank. Tet-cell
    /// leaves nothing unfinished (the parts' host passes ran); whole cells
    /// leave every rank's unfinished cells to each rank's host pass, as one
    /// process leaves them.
    fn clip(&self, job: &ClipJob) -> Result<ClipOutput> {
        if job.strategy == Strategy::Whole {
            return self.clip_whole(job);
        }
        if job.strategy != Strategy::TetCell || job.pairing != Pairing::Flood {
            return Err(Error::InvalidInput(
                "a distributed run builds whole cells, or tet-cell's pieces with flood pairing".into(),
            ));
        }
        if job.face_sums_len() > 0 {
            return Err(Error::InvalidInput(
                "faces in parts (neighbours, optimal transport) come with whole cells: --strategy whole".into(),
            ));
        }
        // One all-reduce: the sums, the counters, the passes' entries, and
        // each rank's totals in its own slots.
        let n = job.params.n_sites as usize * ACCUM_PER_SITE;
        let ranks = self.comm.size();
        let mut all = vec![0i64; n + counter::COUNT + 2 + ranks * RankTotals::FIELDS];
        let mut timings = Timings::default();
        let (sums, rest) = all.split_at_mut(n);
        let (counters, rest) = rest.split_at_mut(counter::COUNT);
        let (redone, totals) = rest.split_at_mut(2);
        let (r, seconds) = timed(|| self.clip_parts(job, sums, counters, &mut timings));
        let r = r?;
        redone[0] = r[0] as i64;
        redone[1] = r[1] as i64;
        let mut report = self.report.lock().unwrap_or_else(|e| e.into_inner());
        let mine = RankTotals::of(&report, seconds).to_words();
        totals[self.comm.rank() * RankTotals::FIELDS..][..RankTotals::FIELDS].copy_from_slice(&mine);
        let (reduced, t) = timed(|| self.comm.sum(&mut all));
        reduced?;
        timings.push("reduce", t);
        report.reduce_seconds = t;
        let totals = all.split_off(n + counter::COUNT + 2);
        report.all = totals.chunks(RankTotals::FIELDS).map(RankTotals::from_words).collect();
        drop(report);
        let redone = all.split_off(n + counter::COUNT);
        let counters = all.split_off(n);
        Ok(ClipOutput {
            sums: all,
            tet_volumes: vec![0; job.tets.len()],
            counters,
            refined: redone[0] as u64,
            unresolved: redone[1] as u64,
            chunks: (self.comm.size() * self.per_rank) as u64,
            timings,
            ..Default::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cvt::SiteDiagram;
    use crate::{geom::points, ClippedVoronoi, TetMesh};

    #[test]
    fn rows_sorted_across_ranks_are_the_sort_of_all_of_them() {
        // Keys with many duplicates and extremes; each row tagged with its
        // rank and place so that the sort's stability shows.
        let mut state = 7u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            state >> 33
        };
        for ranks in 1..=4 {
            for n in [0, 1, 5, 300, 2000] {
                let held: Vec<Vec<[u64; 2]>> = (0..ranks)
                    .map(|r| {
                        (0..n * (r + 1) / ranks - n * r / ranks)
                            .map(|i| {
                                let k = match next() % 10 {
                                    0 => u64::MAX,
                                    1 => 0,
                                    _ => next() % 500,
                                };
                                [k, (r * 1_000_000 + i) as u64]
                            })
                            .collect()
                    })
                    .collect();
                let mut all: Vec<[u64; 2]> = held.concat();
                all.sort_by_key(|x| x[0]);
                let runs: Vec<Vec<[u64; 2]>> = std::thread::scope(|scope| {
                    let handles: Vec<_> = InProcess::ranks(ranks)
                        .into_iter()
                        .zip(held.clone())
                        .map(|(comm, rows)| scope.spawn(move || sort_across(&comm, rows, |x| x[0]).unwrap()))
                        .collect();
                    handles.into_iter().map(|h| h.join().unwrap()).collect()
                });
                assert_eq!(runs.concat(), all, "{ranks} ranks, {n} rows");
                // A key on one rank only; the runs about equal.
                for w in runs.windows(2) {
                    if let (Some(a), Some(b)) = (w[0].last(), w[1].first()) {
                        assert!(a[0] < b[0], "{ranks} ranks: {a:?} then {b:?}");
                    }
                }
                if n >= 2000 && ranks > 1 {
                    let most = runs.iter().map(Vec::len).max().unwrap();
                    assert!(most < 2 * n / ranks, "{ranks} ranks: {:?}", runs.iter().map(Vec::len).collect::<Vec<_>>());
                }
            }
        }
    }

    fn in_parts(parts: usize) -> Distributed {
        Distributed::new(CpuBackend::new(Some(2)).unwrap(), Box::new(OneProcess), parts).unwrap()
    }

    fn same_bits(a: &crate::Cells, b: &crate::Cells, what: &str) {
        assert_eq!(a.volume.len(), b.volume.len());
        for i in 0..a.volume.len() {
            assert_eq!(a.volume[i].to_bits(), b.volume[i].to_bits(), "{what}: volume of site {i}");
            assert_eq!(a.energy[i].to_bits(), b.energy[i].to_bits(), "{what}: energy of site {i}");
            for c in 0..3 {
                assert_eq!(a.centroid[i][c].to_bits(), b.centroid[i][c].to_bits(), "{what}: centroid of site {i}");
            }
        }
    }

    #[test]
    fn parts_give_the_bits_of_one_job() {
        // Uniform sites, and clustered ones (big cells beside small ones:
        // long walks, lists not certified), in an L-shaped domain; the
        // default halo, and one so narrow that many tets need a second or
        // third round.
        let mesh = TetMesh::voxels(16, |i, j, _| i < 8 || j < 8);
        let uniform = points::in_mesh(&mesh, 20_000, 7);
        let mut clustered = points::in_mesh(&mesh, 2000, 8);
        clustered.extend(points::clustered(8000, 4, 0.04, 9).into_iter().map(|p| p.map(|x| 0.1 + 0.4 * x)));
        let cpu = CpuBackend::new(Some(2)).unwrap();
        // Short lists: most pieces walk the grid, and walks reach past
        // narrow halos.
        for (name, sites, k_site) in
            [("uniform", &uniform, None), ("clustered", &clustered, None), ("walks", &uniform, Some(3))]
        {
            // Parts run tet-cell: one job of tet-cell is their reference.
            let tet_cell = ClippedVoronoi::new(&mesh, sites).strategy(Strategy::TetCell);
            let whole = tet_cell.k_site(k_site).backend(&cpu).compute().unwrap();
            let (mut retried, mut every_site) = (0, 0);
            for parts in 1..=4 {
                for halo in [[LIST_HALO, WALK_HALO], [1, 0]] {
                    let d = in_parts(parts).with_halo(halo[0], halo[1]);
                    let cells = tet_cell.k_site(k_site).backend(&d).compute().unwrap();
                    same_bits(&whole, &cells, &format!("{name}, {parts} parts, halo {halo:?}"));
                    let r = d.report();
                    assert_eq!((r.of, r.parts.len()), (parts, parts));
                    assert_eq!(r.rounds[0].tets, mesh.tets.len() as u64);
                    assert_eq!(r.rounds.last().unwrap().out_of_halo, 0);
                    retried += r.rounds.iter().skip(1).map(|r| r.tets).sum::<u64>();
                    // Rounds holding every site: the host pass's tets (and
                    // those that needed a list not computed even then).
                    every_site += r.rounds.iter().skip(1).filter(|x| x.held_sites == sites.len() as u64).count();
                    if parts > 1 {
                        assert!(r.rounds[0].held_sites > sites.len() as u64, "{name}: parts overlap by their halos");
                        assert!(
                            r.rounds[0].held_sites < parts as u64 * sites.len() as u64,
                            "{name}: halos are partial"
                        );
                    }
                }
            }
            assert!(retried > 0, "{name}: the narrow halo sends tets to later rounds");
            if name == "clustered" {
                assert!(every_site > 0, "{name}: floods too long for the kernels, done with every site held");
            }
        }
    }

    #[test]
    fn power_cells_and_lloyd_in_parts_give_the_bits_of_one_job() {
        let mesh = TetMesh::cube(10);
        let sites = points::in_mesh(&mesh, 6000, 11);
        let weights: Vec<f64> = (0..sites.len()).map(|i| 1e-4 * ((i * 7919) % 13) as f64).collect();
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let tet_cell = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::TetCell);
        let whole = tet_cell.weights(&weights).backend(&cpu).compute().unwrap();
        let d = in_parts(3).with_halo(1, 1);
        let cells = tet_cell.weights(&weights).backend(&d).compute().unwrap();
        same_bits(&whole, &cells, "power cells in 3 parts");
        let one = tet_cell.backend(&cpu).lloyd(5, &mut |_, _| {}).unwrap();
        let parts = tet_cell.backend(&d).lloyd(5, &mut |_, _| {}).unwrap();
        for (a, b) in one.sites.iter().zip(&parts.sites) {
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "Lloyd in 3 parts moves the sites alike");
        }
        for (a, b) in one.iterations.iter().zip(&parts.iterations) {
            assert_eq!(a.energy.to_bits(), b.energy.to_bits());
        }
    }

    /// Whole cells in parts (each rank a run of the sites): every site's
    /// sums and faces are one process's to the bit, in a non-convex domain
    /// with a tight cluster in a crowd (cells cut by the boundary, long
    /// walks), with power weights, and through Lloyd's iterations; the
    /// ranks run as threads, each with its parts.
    #[test]
    fn whole_cells_in_parts_give_the_bits_of_one_job() {
        let mesh = TetMesh::voxels(12, |i, j, _| i < 6 || j < 6);
        let mut sites = points::in_mesh(&mesh, 6000, 21);
        sites.extend(points::clustered(3000, 3, 0.02, 22).into_iter().map(|p| p.map(|x| 0.05 + 0.4 * x)));
        sites.push(sites[17]);
        let weights: Vec<f64> = (0..sites.len()).map(|i| 2e-5 * ((i * 7919) % 13) as f64).collect();
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true);
        let one = whole.backend(&cpu).compute().unwrap();
        let power = whole.weights(&weights).backend(&cpu).compute().unwrap();
        let lloyd = whole.faces(false).backend(&cpu).lloyd(3, &mut |_, _| {}).unwrap();
        let (with, _) = whole.compute_with_polyhedra(&cpu).unwrap();
        let one_polyhedra = &with.polyhedra.unwrap();
        assert!(one_polyhedra.len() > sites.len() / 2);
        assert!(one.counters.cut_cells > 0 && one.counters.whole_cells > 0);
        for (ranks, per_rank) in [(1, 1), (2, 1), (3, 2), (4, 1)] {
            let what = format!("{ranks} ranks x {per_rank} parts");
            let runs: Vec<_> = std::thread::scope(|scope| {
                let handles: Vec<_> = InProcess::ranks(ranks)
                    .into_iter()
                    .map(|comm| {
                        let (mesh, sites, weights) = (&mesh, &sites, &weights);
                        scope.spawn(move || {
                            let d =
                                Distributed::new(CpuBackend::new(Some(1)).unwrap(), Box::new(comm), per_rank).unwrap();
                            let cv = ClippedVoronoi::new(mesh, sites).faces(true).backend(&d);
                            let cells = cv.compute().unwrap();
                            let report = d.report();
                            let power = cv.weights(weights).compute().unwrap();
                            let lloyd = cv.faces(false).lloyd(3, &mut |_, _| {}).unwrap();
                            let (with, _) = cv.compute_with_geometry_in_parts(&d).unwrap();
                            same_bits(&cells, &with, "the cells with their polyhedra");
                            (cells, report, power, lloyd, with.polyhedra.unwrap())
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            let built: u64 = runs[0].1.all.iter().map(|t| t.listed_sites).sum();
            assert_eq!(built, sites.len() as u64 - 1, "{what}: every unique site's cell built once");
            let mut polyhedra: Vec<_> = runs.iter().flat_map(|r| r.4.iter().cloned()).collect();
            polyhedra.sort_by_key(|p| p.site);
            assert!(polyhedra == *one_polyhedra, "{what}: the ranks' polyhedra are one process's, each once");
            for (cells, report, p, l, _) in &runs {
                assert_eq!(cells.strategy, Strategy::Whole, "{what}: whole cells by default");
                assert_eq!(report.of, ranks * per_rank);
                same_bits(&one, cells, &what);
                assert_eq!(one.adjacency, cells.adjacency, "{what}: the faces");
                assert_eq!(one.total_volume.to_bits(), cells.total_volume.to_bits());
                assert_eq!(
                    (one.counters.whole_cells, one.counters.cut_cells),
                    (cells.counters.whole_cells, cells.counters.cut_cells)
                );
                same_bits(&power, p, &format!("{what}, power cells"));
                assert_eq!(power.adjacency, p.adjacency, "{what}: the power cells' faces");
                for (a, b) in lloyd.sites.iter().zip(&l.sites) {
                    assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{what}: Lloyd moves the sites alike");
                }
            }
        }
    }
}
