//! The CPU runtime: the kernels' bodies called natively over rayon, one
//! call per thread index, in chunks of consecutive indices. The CPU
//! backend ([`CpuBackend`]; its `Backend` implementation in
//! `backends::cpu`) and every host pass run on it.

use crate::error::{Error, Result};
use crate::geom::timing::{timed, Timings};
use crate::job::clip::{cell_kind, ClipJob, ClipOutput, Pairing, Strategy};
use crate::job::held::HeldCells;
use crate::job::kept::{Keep, LocalKept};
use crate::job::knn::{KnnJob, KnnMethod, Neighbors, PackedLists};
use cvd_kernels::abi::{
    counter, ClipParams, KnnParams, QuantPoint, RefineParams, ACCUM_PER_SITE, NO_SITE, OUT_OF_HALO,
};
use cvd_kernels::buffers::{DeviceSums, OutBuf, PairList, Window};
use cvd_kernels::clip::{self, FaceInputs, NoPieces, PieceSink, CELL_RECORDS};
use cvd_kernels::polyhedron::{CELL_PLANES, CELL_VERTS};
use cvd_kernels::walk::GridWalk;
use cvd_kernels::{grid, knn, lists, refine, scan, whole};
use rayon::prelude::*;
use std::sync::atomic::{AtomicI64, AtomicU32, AtomicU64, AtomicU8, Ordering};
use std::sync::Mutex;

/// Thread indices per rayon task.
const CHUNK: usize = 256;

/// Runs kernel bodies on a rayon thread pool.
pub struct CpuBackend {
    pool: rayon::ThreadPool,
}

impl CpuBackend {
    /// A backend with `threads` worker threads (None: one per core).
    pub fn new(threads: Option<usize>) -> Result<Self> {
        if threads == Some(0) {
            return Err(Error::InvalidInput("--threads must be at least 1".into()));
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.unwrap_or(0))
            .build()
            .map_err(|e| Error::InvalidInput(format!("cannot start {threads:?} CPU threads: {e}")))?;
        Ok(Self { pool })
    }

    /// Number of worker threads.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// Runs a clipping job like [`Backend::clip`], handing every piece
    /// the kernels finish to the tasks' sinks, which end up in `sinks`.
    pub(crate) fn clip_into<S: TaskSink>(&self, job: &ClipJob, sinks: &Mutex<Vec<S>>) -> Result<ClipOutput> {
        if job.only.is_some() && job.strategy != Strategy::Whole {
            return Err(Error::Internal(format!(
                "some answered cells only are built under whole cells, not {:?}",
                job.strategy
            )));
        }
        // The site grid, once: both k-NN jobs search it (the tets' job has
        // the sites' grid), and so do the walks of the pieces their lists
        // do not settle and the second pass.
        let (g, grid_time) = self.pool.install(|| timed(|| build_grid(&job.site_knn)));
        // The sites' lists packed in as few bits as their indices need; the
        // kernels run with parameters that say so.
        let bits = lists::width(job.params.n_sites);
        // Whole cells pair no tets: no tet lists.
        let whole = job.strategy == Strategy::Whole;
        let mut kept = None;
        let (site_nn, tet_nn, certified) = match &job.held {
            None if whole => {
                let lists = match &job.keep {
                    Some(keep) => {
                        let (lists, local) = self.kept_lists(&job.site_knn, keep, bits, &g, job.only.as_deref());
                        kept = Some(local);
                        lists
                    }
                    None => self.packed_lists_on(&job.site_knn, bits, Some(&g))?,
                };
                (lists, PackedLists::default(), 0)
            }
            None => (
                self.packed_lists_on(&job.site_knn, bits, Some(&g))?,
                self.packed_lists_on(&job.tet_knn_job(), 32, Some(&g))?,
                0,
            ),
            Some(held) => {
                let (sites, certified) = self.held_lists(&job.site_knn, job.params.n_sites as usize, bits, &g, held);
                let (tets, _) = self.held_lists(&job.tet_knn_job(), job.tets.len(), 32, &g, held);
                (sites, tets, certified)
            }
        };
        let refine = RefineParams { clip: ClipParams { list_bits: site_nn.bits, ..job.refine.clip }, ..job.refine };
        self.pool.install(|| {
            let p = &refine.clip;
            let mut timings = Timings::default();
            let mut kinds = Vec::new();
            timings.push("knn", grid_time + site_nn.timings.total() + tet_nn.timings.total());
            let tet_nn = Neighbors { k: tet_nn.k as usize, indices: tet_nn.words, ..Default::default() };
            // The sites' sums, then one volume sum per tet (knn pairing's
            // certificate).
            let n_sums = p.n_sites as usize * ACCUM_PER_SITE + p.n_tets as usize + job.face_sums_len();
            let faces = FaceInputs { site_nbrs: &site_nn.words, tet_faces: &job.tet_faces };
            let sums: Vec<AtomicI64> = (0..n_sums).map(|_| AtomicI64::new(0)).collect();
            let totals: Vec<AtomicI64> = (0..counter::COUNT).map(|_| AtomicI64::new(0)).collect();
            let unfinished = Mutex::new(Vec::new());
            let n_pairs = p.n_tets as usize * p.k_tet as usize;
            let (sites, verts, tets) = (&job.sites, &job.verts, &job.tets);
            match job.strategy {
                Strategy::TetCell if job.pairing == Pairing::Flood => {
                    let (_, t) = timed(|| {
                        let w = GridWalk::new(&refine, &site_nn.words, &g.cell_start, &g.cell_count, &g.sorted);
                        par_indices(
                            p.n_tets as usize,
                            CHUNK / 16,
                            &sums,
                            &totals,
                            &unfinished,
                            sinks,
                            |t, s, c, u, k| {
                                clip::flood_tet(t, &refine, w, sites, verts, tets, &tet_nn.indices, faces, s, c, u, k)
                            },
                        )
                    });
                    timings.push("clip", t);
                }
                Strategy::Whole => {
                    let domain = job
                        .domain
                        .as_deref()
                        .ok_or_else(|| Error::Internal("a whole-cell job without its domain index".into()))?;
                    // Every site, or those the job builds only; where the
                    // lists are kept (a part's), each one's kind as the
                    // counters say it.
                    let only = job.only.as_deref();
                    let built = only.map_or(p.n_sites as usize, <[u32]>::len);
                    let kinds_of = if job.keep.is_some() { p.n_sites } else { 0 };
                    let cell_kinds: Vec<AtomicU8> = (0..kinds_of).map(|_| AtomicU8::new(0)).collect();
                    let (_, t) = timed(|| {
                        let w = GridWalk::new(&refine, &site_nn.words, &g.cell_start, &g.cell_count, &g.sorted);
                        let d = domain.view();
                        par_indices(built, CHUNK / 16, &sums, &totals, &unfinished, sinks, |b, s, c, u, k| {
                            let i = only.map_or(b, |o| o[b] as usize);
                            let before = (c.0[counter::WHOLE], c.0[counter::CUT]);
                            whole::whole_cell::<CELL_PLANES, CELL_VERTS, _, _, _, _>(
                                i, &refine, w, sites, verts, tets, d, faces, s, c, u, k,
                            );
                            let kind = match (c.0[counter::WHOLE] > before.0, c.0[counter::CUT] > before.1) {
                                (true, _) => cell_kind::WHOLE,
                                (_, true) => cell_kind::CUT,
                                _ => cell_kind::NONE,
                            };
                            if let Some(slot) = cell_kinds.get(i) {
                                slot.store(kind, Ordering::Relaxed);
                            }
                        })
                    });
                    kinds = cell_kinds.into_iter().map(AtomicU8::into_inner).collect();
                    timings.push("clip", t);
                }
                Strategy::TetCell => {
                    let (_, t) = timed(|| {
                        par_indices(n_pairs, CHUNK / 4, &sums, &totals, &unfinished, sinks, |pair, s, c, u, k| {
                            let (nbrs, tf) = (&site_nn.words, &job.tet_faces);
                            clip::tet_cell_pair(pair, p, sites, verts, tets, &tet_nn.indices, nbrs, tf, s, c, u, k)
                        })
                    });
                    timings.push("clip", t);
                }
                Strategy::CellTet => {
                    let (cells, t) = timed(|| {
                        let mut cells = vec![[0f32; 4]; p.n_sites as usize * CELL_RECORDS];
                        cells.par_chunks_mut(CELL_RECORDS).enumerate().for_each(|(i, data)| {
                            let mut local = [0i64; counter::COUNT];
                            let mut out = Window { start: i * CELL_RECORDS, data };
                            clip::voronoi_cell(i, p, sites, &site_nn.words, &mut out, &mut DeviceSums(&mut local));
                            for (t, &v) in totals.iter().zip(&local) {
                                t.fetch_add(v, Ordering::Relaxed);
                            }
                        });
                        cells
                    });
                    timings.push("cells", t);
                    let (_, t) = timed(|| {
                        par_indices(n_pairs, CHUNK / 4, &sums, &totals, &unfinished, sinks, |pair, s, c, u, k| {
                            let (nbrs, tf) = (&site_nn.words, &job.tet_faces);
                            clip::cell_tet_pair(
                                pair,
                                p,
                                sites,
                                verts,
                                tets,
                                &tet_nn.indices,
                                &cells,
                                nbrs,
                                tf,
                                s,
                                c,
                                u,
                                k,
                            )
                        })
                    });
                    timings.push("clip", t);
                }
            }
            let mut first = unfinished.into_inner().unwrap_or_else(|e| e.into_inner());
            first.sort_unstable();
            let mut still = Vec::new();
            if !first.is_empty() {
                let (_, t) = timed(|| {
                    let mut list = vec![first.len() as u32];
                    list.extend(first.iter().flatten());
                    let rp =
                        RefineParams { clip: ClipParams { capacity: first.len() as u32, ..refine.clip }, ..refine };
                    let w = GridWalk::new(&rp, &site_nn.words, &g.cell_start, &g.cell_count, &g.sorted);
                    let ignored: Vec<AtomicI64> = (0..counter::COUNT).map(|_| AtomicI64::new(0)).collect();
                    let again = Mutex::new(Vec::new());
                    par_indices(first.len(), 1, &sums, &ignored, &again, sinks, |e, s, c, u, k| {
                        refine::refine_entry(e, &rp, w, sites, verts, tets, &tet_nn.indices, &list, faces, s, c, u, k)
                    });
                    still = again.into_inner().unwrap_or_else(|e| e.into_inner());
                    still.sort_unstable();
                });
                timings.push("second pass", t);
            }
            let all: Vec<i64> = sums.into_iter().map(AtomicI64::into_inner).collect();
            let (sums, tet_volumes, faces) =
                crate::job::clip::split_sums(all, p.n_sites as usize * ACCUM_PER_SITE, p.n_tets as usize);
            let site_lists = if faces.is_empty() { PackedLists::default() } else { site_nn };
            Ok(ClipOutput {
                sums,
                tet_volumes,
                faces,
                site_lists,
                counters: totals.into_iter().map(AtomicI64::into_inner).collect(),
                refined: (first.len() - still.len()) as u64,
                unresolved: 0,
                certified,
                kept,
                chunks: 1,
                unfinished: still,
                timings,
                kinds,
            })
        })
    }
}

/// A buffer shared by many threads, each index read and written by one
/// thread only, at positions the algorithm computes: the counting sort's
/// scatter (slots from atomic counters), site queries in grid order (a
/// query owns the `k` slots of its site). The CPU twin of a storage buffer
/// indexed by data.
struct SharedSlots<'a, T> {
    ptr: *mut T,
    len: usize,
    _borrow: std::marker::PhantomData<&'a mut [T]>,
}

// SAFETY: threads access disjoint indices (see the type's contract).
unsafe impl<T: Send> Send for SharedSlots<'_, T> {}
unsafe impl<T: Send> Sync for SharedSlots<'_, T> {}

impl<'a, T> SharedSlots<'a, T> {
    fn new(data: &'a mut [T]) -> Self {
        Self { ptr: data.as_mut_ptr(), len: data.len(), _borrow: std::marker::PhantomData }
    }
    fn share(&self) -> Self {
        Self { ptr: self.ptr, len: self.len, _borrow: std::marker::PhantomData }
    }
}

impl<T: Copy> OutBuf<T> for SharedSlots<'_, T> {
    #[inline]
    fn read(&self, i: usize) -> T {
        if i >= self.len {
            out_of_bounds(i, self.len);
        }
        // SAFETY: in bounds; only this thread touches slot `i`.
        unsafe { self.ptr.add(i).read() }
    }
    #[inline]
    fn write(&mut self, i: usize, value: T) {
        if i >= self.len {
            out_of_bounds(i, self.len);
        }
        // SAFETY: in bounds; only this thread touches slot `i`.
        unsafe { self.ptr.add(i).write(value) }
    }
}

/// The panic of a slot out of bounds, kept out of the k-NN's inner loop
/// (formatting its message there cost a register spill per shift).
#[cold]
#[inline(never)]
fn out_of_bounds(i: usize, len: usize) -> ! {
    panic!("slot {i} out of {len}")
}

/// A task's list of unfinished pairs, merged after the task.
#[derive(Default)]
pub(crate) struct LocalPairs(pub(crate) Vec<[u32; 2]>);

impl PairList for LocalPairs {
    fn push(&mut self, tet: u32, site: u32) {
        self.0.push([tet, site]);
    }
}

/// A k-NN thread on its task's scratch (`KnnParams::local_lists`):
/// answers query `i` in the two buffers and returns the query's slot.
type QueryThread<'a> = dyn Fn(usize, &mut [u32], &mut [u64]) -> usize + Sync + 'a;

/// Where a finished list goes: its query's slot, the list, its squared
/// distances.
type ListStore<'a> = dyn Fn(usize, &[u32], &[u64]) + Sync + 'a;

/// A rayon task's piece sink: each task fills its own, and hands it over
/// when done.
pub(crate) trait TaskSink: PieceSink + Default + Send {
    /// Adds this task's pieces to `all` (nothing to do for [`NoPieces`]).
    fn hand_over(self, all: &Mutex<Vec<Self>>);
}

impl TaskSink for NoPieces {
    fn hand_over(self, _all: &Mutex<Vec<Self>>) {}
}

/// Calls `body` for every index in `0..n` over rayon, in chunks whose
/// counters, unfinished pairs and pieces are kept privately and merged once.
pub(crate) fn par_indices<S, F>(
    n: usize,
    chunk: usize,
    sums: &[AtomicI64],
    totals: &[AtomicI64],
    unfinished: &Mutex<Vec<[u32; 2]>>,
    sinks: &Mutex<Vec<S>>,
    body: F,
) where
    S: TaskSink,
    F: Fn(usize, &mut &[AtomicI64], &mut DeviceSums<'_>, &mut LocalPairs, &mut S) + Sync,
{
    (0..n).into_par_iter().chunks(chunk).for_each(|indices| {
        let mut local = [0i64; counter::COUNT];
        let mut pairs = LocalPairs::default();
        let mut sink = S::default();
        let mut s = sums;
        let mut counters = DeviceSums(&mut local);
        for i in indices {
            body(i, &mut s, &mut counters, &mut pairs, &mut sink);
        }
        for (t, &v) in totals.iter().zip(&local) {
            t.fetch_add(v, Ordering::Relaxed);
        }
        if !pairs.0.is_empty() {
            unfinished.lock().unwrap_or_else(|e| e.into_inner()).extend(pairs.0);
        }
        sink.hand_over(sinks);
    });
}

fn atomic_zeros(n: usize) -> Vec<AtomicU32> {
    (0..n).map(|_| AtomicU32::new(0)).collect()
}

fn into_plain(v: Vec<AtomicU32>) -> Vec<u32> {
    v.into_iter().map(AtomicU32::into_inner).collect()
}

/// The site grid built by the grid kernels' bodies.
pub(crate) struct CpuGrid {
    pub cell_start: Vec<u32>,
    pub cell_count: Vec<u32>,
    pub sorted: Vec<QuantPoint>,
}

pub(crate) fn build_grid(job: &KnnJob) -> CpuGrid {
    let g = &job.params.grid;
    let n = g.n_sites as usize;
    let n_cells = g.n_cells as usize;
    let sites = &job.sites;
    let (site_cell, cell_count, mut cell_start) = counted(job);

    let mut sorted = vec![[0u32; 4]; n];
    let cursor = atomic_zeros(n_cells);
    let slots = SharedSlots::new(&mut sorted);
    (0..n).into_par_iter().chunks(CHUNK).for_each(|chunk| {
        let mut out = slots.share();
        let mut counters: &[AtomicU32] = &cursor;
        for i in chunk {
            grid::scatter_site(i, g, sites, &site_cell, &cell_start, &mut counters, &mut out);
        }
    });
    debug_assert!(cursor.iter().zip(&cell_count).all(|(c, &n)| c.load(Ordering::Relaxed) == n));
    // Each cell's slots belong to one task.
    let slots = SharedSlots::new(&mut sorted);
    (0..n_cells).into_par_iter().chunks(CHUNK).for_each(|chunk| {
        let mut out = slots.share();
        for c in chunk {
            grid::sort_cell(c, g, &cell_start, &cell_count, &mut out);
        }
    });
    // A part's cells whose sites it does not hold (it holds none there).
    if let Some(unheld) = &job.unheld {
        mark_unheld(&mut cell_start, &cell_count, unheld);
    }
    CpuGrid { cell_start, cell_count, sorted }
}

/// The first slot and the count of each cell of `job`'s grid, as
/// [`build_grid`] finds them (a device's grid the same).
pub(crate) fn cell_starts(job: &KnnJob) -> (Vec<u32>, Vec<u32>) {
    let (_, count, start) = counted(job);
    (start, count)
}

/// The counting sort's first steps over `job`'s grid: each site's cell,
/// each cell's count and its first slot.
fn counted(job: &KnnJob) -> (Vec<u32>, Vec<u32>, Vec<u32>) {
    let g = &job.params.grid;
    let n = g.n_sites as usize;
    let n_cells = g.n_cells as usize;
    let sites = &job.sites;
    let mut site_cell = vec![0u32; n];
    let counts = atomic_zeros(n_cells);
    site_cell.par_chunks_mut(CHUNK).enumerate().for_each(|(c, data)| {
        let start = c * CHUNK;
        let mut out = Window { start, data };
        let mut counters: &[AtomicU32] = &counts;
        for i in start..start + out.data.len() {
            grid::count_site(i, g, sites, &mut out, &mut counters);
        }
    });
    let cell_count = into_plain(counts);

    let n_blocks = scan::block_count(n_cells);
    let mut cell_start = vec![0u32; n_cells];
    let mut block_sums = vec![0u32; n_blocks];
    cell_start.par_chunks_mut(scan::SCAN_BLOCK).zip(block_sums.par_chunks_mut(1)).enumerate().for_each(
        |(b, (data, sum))| {
            let mut out = Window { start: b * scan::SCAN_BLOCK, data };
            let mut sums = Window { start: b, data: sum };
            scan::scan_block(b, n_cells, &cell_count, &mut out, &mut sums);
        },
    );
    scan::scan_block_sums(n_blocks, block_sums.as_mut_slice());
    cell_start.par_chunks_mut(scan::SCAN_BLOCK).enumerate().for_each(|(b, data)| {
        let mut out = Window { start: b * scan::SCAN_BLOCK, data };
        scan::add_block_offset(b, n_cells, &mut out, &block_sums);
    });
    (site_cell, cell_count, cell_start)
}

/// Marks the first slot of each empty cell whose bit `unheld` sets
/// [`cvd_kernels::abi::UNHELD`] (a cell holding a site is held).
pub(crate) fn mark_unheld(cell_start: &mut [u32], cell_count: &[u32], unheld: &[u32]) {
    cell_start.par_iter_mut().zip(cell_count).enumerate().for_each(|(c, (start, &count))| {
        if count == 0 && unheld.get(c / 32).is_some_and(|w| w >> (c % 32) & 1 == 1) {
            *start = cvd_kernels::abi::UNHELD;
        }
    });
}

impl CpuBackend {
    /// The neighbour lists of a k-NN job, packed in `bits`-bit entries as
    /// the clipping kernels read them ([`cvd_kernels::lists`]; 32: plain),
    /// without their distances: each query sorts its candidates in its
    /// task's scratch and stores the list at its slot, so the lists are
    /// all the memory the job takes.
    pub(crate) fn packed_lists(&self, job: &KnnJob, bits: u32) -> Result<PackedLists> {
        self.packed_lists_on(job, bits, None)
    }

    /// [`Self::packed_lists`], searching `grid` (the job's grid, built
    /// already) if given.
    fn packed_lists_on(&self, job: &KnnJob, bits: u32, grid: Option<&CpuGrid>) -> Result<PackedLists> {
        let (k, n) = (job.params.k, job.params.n_queries as usize);
        let mut words = vec![0u32; n * lists::stride(k, bits) + lists::spare(bits)];
        let out = SharedSlots::new(&mut words);
        let timings = self.each_list(job, grid, &|slot, nbr, _| lists::pack(nbr, k, bits, slot, &mut out.share()));
        Ok(PackedLists { words, k, bits, timings })
    }

    /// The lists of a whole-cell job that keeps them ([`ClipJob::keep`]),
    /// searching `grid`: each listed site's `keep.k` nearest, from its
    /// candidates where they certify its first `k` (the job's), else from
    /// the grid; the first `k` packed in `bits`-bit entries for the
    /// kernels, all `keep.k` kept.
    ///
    /// With `only` (query places, increasing), those queries' lists alone:
    /// the others' words stay zero, their distances `u64::MAX`.
    fn kept_lists(
        &self,
        job: &KnnJob,
        keep: &Keep,
        bits: u32,
        grid: &CpuGrid,
        only: Option<&[u32]>,
    ) -> (PackedLists, LocalKept) {
        let p = job.params;
        let (k, n) = (p.k, p.n_queries as usize);
        // At least one entry kept (a job of one site has none to list).
        let kk = keep.k.max(k).max(1);
        let available = p.grid.n_sites.saturating_sub(1);
        let mut words = vec![0u32; n * lists::stride(k, bits) + lists::spare(bits)];
        let stride = if keep.entries { kk as usize } else { 0 };
        let mut local = LocalKept {
            k: kk,
            lists: vec![NO_SITE; n * stride],
            last2: vec![u64::MAX; n],
            kth2: vec![u64::MAX; n],
            reused: vec![false; n],
        };
        let out = SharedSlots::new(&mut words);
        let (cs, cc, sorted) = (&grid.cell_start, &grid.cell_count, &grid.sorted);
        let (_, t) = timed(|| {
            self.pool.install(|| {
                // The entries into the kept lists, or into a row of scratch.
                let lists: Vec<&mut [u32]> = match keep.entries {
                    true => local.lists.chunks_mut(kk as usize).collect(),
                    false => (0..n).map(|_| <&mut [u32]>::default()).collect(),
                };
                let rows = lists.into_par_iter().zip(&mut local.last2).zip(&mut local.kth2);
                rows.zip(&mut local.reused).enumerate().for_each_init(
                    || (vec![0u64; kk as usize], vec![NO_SITE; kk as usize]),
                    |(d2, scratch), (u, (((kept, last2), kth2), reused))| {
                        let list: &mut [u32] = if kept.is_empty() {
                            scratch.fill(NO_SITE);
                            &mut scratch[..]
                        } else {
                            kept
                        };
                        let place = p.query_base as usize + u;
                        if only.is_some_and(|o| o.binary_search(&(place as u32)).is_err()) {
                            return;
                        }
                        let q = job.queries[place];
                        let at = [q[0], q[1], q[2]];
                        *reused = keep.candidates.as_ref().is_some_and(|c| {
                            let below2 = c.below2.get(u).copied().unwrap_or(0);
                            if below2 == 0 {
                                return false;
                            }
                            let found = knn::candidate_query(&job.sites, c.of(u), at, q[3], kk, 0, list, &mut d2[..]);
                            k > 0 && found >= k.min(available) && d2[k as usize - 1] < below2
                        });
                        if !*reused {
                            knn::grid_query(&p.grid, cs, cc, sorted, at, q[3], kk, 0, list, &mut d2[..]);
                        }
                        *last2 = d2[kk as usize - 1];
                        *kth2 = if k > 0 { d2[k as usize - 1] } else { 0 };
                        lists::pack(&list[..k as usize], k, bits, u, &mut out.share());
                    },
                );
            })
        });
        let mut timings = Timings::default();
        timings.push("knn", t);
        (PackedLists { words, k, bits, timings }, local)
    }

    /// The lists of a part of a job ([`ClipJob::held`]) at its queries'
    /// slots, `n` of them: a site job's (its queries tagged with their
    /// site, the unlisted sites marked unknown), or a point job's with
    /// `k` = 1 (the tets' nearest sites, in plain entries). A list the held
    /// cells do not certify ([`HeldCells::certifies`]) is marked unknown; a
    /// nearest site, [`OUT_OF_HALO`]. Returns the lists and how many were
    /// certified.
    pub(crate) fn held_lists(
        &self,
        job: &KnnJob,
        n: usize,
        bits: u32,
        grid: &CpuGrid,
        held: &HeldCells,
    ) -> (PackedLists, u64) {
        let k = job.params.k;
        let sites = job.params.exclude_self != 0;
        let mut words = vec![0u32; n * lists::stride(k, bits) + lists::spare(bits)];
        let out = SharedSlots::new(&mut words);
        if sites {
            // Unknown until certified: each list begins with its own site.
            self.pool.install(|| {
                (0..n).into_par_iter().chunks(CHUNK).for_each(|chunk| {
                    let mut marker = vec![NO_SITE; k as usize];
                    for j in chunk {
                        if let Some(first) = marker.first_mut() {
                            *first = j as u32;
                        }
                        lists::pack(&marker, k, bits, j, &mut out.share());
                    }
                })
            });
        }
        let certified = AtomicU64::new(0);
        let timings = self.each_list(job, Some(grid), &|slot, nbr, d2| {
            let q = job.queries[slot];
            let ok = k > 0 && held.certifies([q[0], q[1], q[2]], d2[k as usize - 1]);
            if sites {
                if ok {
                    lists::pack(nbr, k, bits, q[3] as usize, &mut out.share());
                }
            } else {
                lists::pack(&[if ok { nbr[0] } else { OUT_OF_HALO }], 1, bits, slot, &mut out.share());
            }
            certified.fetch_add(ok as u64, Ordering::Relaxed);
        });
        (PackedLists { words, k, bits, timings }, certified.into_inner())
    }

    /// Runs every query of a k-NN job on its task's scratch
    /// (`KnnParams::local_lists`), searching `grid` if given (else the
    /// job's grid, built here), and hands each finished list, with its
    /// squared distances, to `store` with the query's slot.
    fn each_list(&self, job: &KnnJob, grid: Option<&CpuGrid>, store: &ListStore) -> Timings {
        let p = KnnParams { local_lists: 1, ..job.params };
        let (k, n) = (p.k as usize, p.n_queries as usize);
        let mut timings = Timings::default();
        if k == 0 || n == 0 {
            return timings;
        }
        self.pool.install(|| {
            let each = |thread: &QueryThread| {
                (0..n).into_par_iter().chunks(CHUNK).for_each(|chunk| {
                    let (mut nbr, mut d2) = (vec![0u32; k], vec![0u64; k]);
                    for i in chunk {
                        let slot = thread(i, &mut nbr, &mut d2);
                        store(slot, &nbr, &d2);
                    }
                })
            };
            match job.method {
                KnnMethod::Grid => {
                    let built;
                    let g = match grid {
                        Some(g) => g,
                        None => {
                            let t;
                            (built, t) = timed(|| build_grid(job));
                            timings.push("grid", t);
                            &built
                        }
                    };
                    let (cs, cc, sorted) = (&g.cell_start, &g.cell_count, &g.sorted);
                    let (_, t) =
                        timed(|| each(&|i, nbr, d2| knn::grid_thread(i, &p, &job.queries, cs, cc, sorted, nbr, d2)));
                    timings.push("knn", t);
                }
                KnnMethod::Brute => {
                    let (_, t) =
                        timed(|| each(&|i, nbr, d2| knn::brute_thread(i, &p, &job.queries, &job.sites, nbr, d2)));
                    timings.push("knn", t);
                }
            }
        });
        timings
    }

    /// The plain neighbour lists of a k-NN job, without their distances
    /// (left empty).
    pub(crate) fn lists(&self, job: &KnnJob) -> Result<Neighbors> {
        let l = self.packed_lists(job, 32)?;
        Ok(Neighbors { k: l.k as usize, indices: l.words, dist2: Vec::new(), timings: l.timings })
    }

    /// The neighbours of a k-NN job, with their distances (`Backend::knn`).
    pub fn neighbors(&self, job: &KnnJob) -> Result<Neighbors> {
        let k = job.params.k as usize;
        let mut indices = vec![0u32; job.queries.len() * k];
        let mut dist2 = vec![0u64; job.queries.len() * k];
        let (nbr_out, d2_out) = (SharedSlots::new(&mut indices), SharedSlots::new(&mut dist2));
        let timings = self.each_list(job, None, &|slot, nbr, d2| {
            let (mut nbr_out, mut d2_out) = (nbr_out.share(), d2_out.share());
            for s in 0..k {
                nbr_out.write(slot * k + s, nbr[s]);
                d2_out.write(slot * k + s, d2[s]);
            }
        });
        Ok(Neighbors { k, indices, dist2, timings })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points;

    fn cpu() -> CpuBackend {
        CpuBackend::new(Some(2)).unwrap()
    }

    #[test]
    fn zero_threads_are_refused() {
        match CpuBackend::new(Some(0)) {
            Err(Error::InvalidInput(m)) => assert!(m.contains("at least 1"), "{m}"),
            Err(e) => panic!("not an input error: {e}"),
            Ok(_) => panic!("zero threads accepted"),
        }
        assert_eq!(CpuBackend::new(Some(3)).unwrap().threads(), 3);
        assert!(CpuBackend::new(None).unwrap().threads() >= 1);
    }

    /// The `k` nearest of `sites` to each query by f64 distances, ties by
    /// index, skipping the query's own index for a site job.
    fn brute_f64(sites: &[[f64; 3]], queries: &[[f64; 3]], k: usize, exclude_self: bool) -> Vec<u32> {
        let mut out = Vec::new();
        for (qi, q) in queries.iter().enumerate() {
            let mut all: Vec<(f64, u32)> = (0..sites.len())
                .filter(|&j| !(exclude_self && j == qi))
                .map(|j| ((0..3).map(|a| (sites[j][a] - q[a]).powi(2)).sum(), j as u32))
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            out.extend(all[..k].iter().map(|e| e.1));
        }
        out
    }

    /// The exact squared distance of quantized points.
    fn d2(a: QuantPoint, b: QuantPoint) -> u64 {
        (0..3).map(|i| (a[i] as i64 - b[i] as i64).pow(2) as u64).sum()
    }

    fn check_distances(job: &KnnJob, nn: &Neighbors) {
        for (qi, q) in job.queries.iter().enumerate() {
            for (s, &j) in nn.of(qi).iter().enumerate() {
                assert_eq!(nn.dist2[qi * nn.k + s], d2(*q, job.sites[j as usize]), "query {qi}, entry {s}");
            }
        }
    }

    #[test]
    fn neighbours_are_the_nearest_in_f64() {
        let cpu = cpu();
        let sites = points::uniform(300, 21);
        // Queries spread wider than the sites: some lie outside their grid.
        let queries: Vec<[f64; 3]> = points::uniform(200, 22).iter().map(|p| p.map(|c| 1.6 * c - 0.3)).collect();
        for k in [1, 8] {
            for method in [KnnMethod::Grid, KnnMethod::Brute] {
                let job = KnnJob::sites(&sites, k, method).unwrap();
                let nn = cpu.neighbors(&job).unwrap();
                assert_eq!(nn.k, k);
                assert_eq!(nn.indices, brute_f64(&sites, &sites, k, true), "sites, k = {k}, {method:?}");
                check_distances(&job, &nn);
                let job = KnnJob::points(&sites, &queries, k, method).unwrap();
                let nn = cpu.neighbors(&job).unwrap();
                assert_eq!(nn.indices, brute_f64(&sites, &queries, k, false), "points, k = {k}, {method:?}");
                check_distances(&job, &nn);
            }
        }
    }

    #[test]
    fn grid_and_brute_agree_on_ties_by_index() {
        let cpu = cpu();
        // A 4³ lattice: equal distances everywhere, and duplicates.
        let sites = points::lattice(300, 4, 23);
        for k in [1, 8, 40] {
            let grid = cpu.neighbors(&KnnJob::sites(&sites, k, KnnMethod::Grid).unwrap()).unwrap();
            let brute = cpu.neighbors(&KnnJob::sites(&sites, k, KnnMethod::Brute).unwrap()).unwrap();
            assert_eq!(grid.indices, brute.indices, "k = {k}");
            assert_eq!(grid.dist2, brute.dist2, "k = {k}");
            // The lattice is exact in f64 and in the quantized frame.
            assert_eq!(grid.indices, brute_f64(&sites, &sites, k, true), "k = {k}");
            for i in 0..sites.len() {
                let row = &grid.dist2[i * k..(i + 1) * k];
                let ids = grid.of(i);
                for s in 1..k {
                    assert!((row[s - 1], ids[s - 1]) < (row[s], ids[s]), "site {i}: not by distance, then index");
                }
            }
        }
    }

    #[test]
    fn plain_and_packed_lists_are_the_neighbours() {
        let cpu = cpu();
        let sites = points::clustered(500, 3, 0.05, 24);
        let job = KnnJob::sites(&sites, 12, KnnMethod::Grid).unwrap();
        let nn = cpu.neighbors(&job).unwrap();
        let plain = cpu.lists(&job).unwrap();
        assert_eq!((plain.k, &plain.indices), (12, &nn.indices));
        assert!(plain.dist2.is_empty());
        let bits = lists::width(500);
        assert_eq!(bits, 9);
        let packed = cpu.packed_lists(&job, bits).unwrap();
        assert_eq!(packed.words.len(), 500 * lists::stride(12, bits) + 1);
        let view = packed.view(0);
        for i in 0..500 {
            let got: Vec<u32> = (0..12).map(|s| view.get(view.slot(i), s)).collect();
            assert_eq!(got, nn.of(i), "site {i}");
        }
    }

    #[test]
    fn the_grid_sorts_every_site_into_its_cell() {
        let sites = points::clustered(2000, 5, 0.03, 25);
        let job = KnnJob::sites(&sites, 4, KnnMethod::Grid).unwrap();
        let g = cpu().pool.install(|| build_grid(&job));
        let p = job.params.grid;
        assert_eq!((g.cell_start.len(), g.cell_count.len()), (p.n_cells as usize, p.n_cells as usize));
        assert_eq!(g.cell_count.iter().sum::<u32>(), 2000);
        let mut start = 0;
        for c in 0..p.n_cells as usize {
            assert_eq!(g.cell_start[c], start, "cell {c}: not the prefix sum");
            start += g.cell_count[c];
        }
        let cell = |q: &QuantPoint| {
            let [x, y, z] = [0, 1, 2].map(|a| q[a] / p.cell_size);
            ((z * p.dim_y + y) * p.dim_x + x) as usize
        };
        for c in 0..p.n_cells as usize {
            let (s, n) = (g.cell_start[c] as usize, g.cell_count[c] as usize);
            for q in &g.sorted[s..s + n] {
                assert_eq!(cell(q), c);
                assert_eq!(*q, job.sites[q[3] as usize], "a site changed on the way");
            }
        }
        let mut seen: Vec<u32> = g.sorted.iter().map(|q| q[3]).collect();
        seen.sort_unstable();
        assert!(seen.iter().copied().eq(0..2000), "every site once");
    }

    #[test]
    fn par_indices_visits_each_index_once_and_merges_what_it_counts() {
        let n = 1000;
        let sums: Vec<AtomicI64> = (0..n).map(|_| AtomicI64::new(0)).collect();
        let totals: Vec<AtomicI64> = (0..counter::COUNT).map(|_| AtomicI64::new(0)).collect();
        let unfinished = Mutex::new(Vec::new());
        let sinks = Mutex::new(Vec::<NoPieces>::new());
        cpu().pool.install(|| {
            par_indices(n, 7, &sums, &totals, &unfinished, &sinks, |i, s, c, u, _| {
                use cvd_kernels::buffers::AtomicSums;
                s.add(i, 1);
                c.add(counter::PAIRS, i as i64);
                if i % 100 == 3 {
                    u.0.push([i as u32, 7]);
                }
            })
        });
        assert!(sums.iter().all(|s| s.load(Ordering::Relaxed) == 1), "an index run twice or never");
        assert_eq!(totals[counter::PAIRS].load(Ordering::Relaxed), (n * (n - 1) / 2) as i64);
        let mut u = unfinished.into_inner().unwrap();
        u.sort_unstable();
        assert_eq!(u, (0..10).map(|k| [100 * k + 3, 7]).collect::<Vec<_>>());
    }

    #[test]
    fn held_lists_keep_only_what_the_box_certifies() {
        let cpu = cpu();
        let sites = points::uniform(600, 26);
        let job = KnnJob::sites(&sites, 6, KnnMethod::Grid).unwrap();
        let p = job.params.grid;
        let g = cpu.pool.install(|| build_grid(&job));
        // The lower corner's cells: its lists near the box's high sides are
        // not certified.
        let held = HeldCells::around([0; 3], [1; 3], 0, [p.dim_x, p.dim_y, p.dim_z], p.cell_size);
        assert!(!held.is_whole());
        let nn = cpu.neighbors(&job).unwrap();
        let (lists, certified) = cpu.held_lists(&job, 600, 32, &g, &held);
        let view = lists.view(0);
        let mut expected = 0;
        for i in 0..600 {
            let q = job.queries[i];
            let list: Vec<u32> = (0..6).map(|s| view.get(i, s)).collect();
            if held.certifies([q[0], q[1], q[2]], nn.dist2[6 * i + 5]) {
                expected += 1;
                assert_eq!(list, nn.of(i), "site {i}: certified, so its list");
            } else {
                assert!(view.unknown(i, i as u32), "site {i}: not certified, so unknown");
                assert_eq!(list[1..], [NO_SITE; 5]);
            }
        }
        assert_eq!(certified, expected);
        assert!(0 < certified && certified < 600, "{certified}: both cases");
        // The nearest site of points: itself, or out of the halo.
        let queries = points::uniform(300, 27);
        let points_job = KnnJob::points_like(&job, &queries, 1).unwrap();
        let nearest = cpu.neighbors(&points_job).unwrap();
        let (lists, certified) = cpu.held_lists(&points_job, 300, 32, &g, &held);
        let mut expected = 0;
        for (i, q) in points_job.queries.iter().enumerate() {
            let ok = held.certifies([q[0], q[1], q[2]], nearest.dist2[i]);
            expected += ok as u64;
            assert_eq!(lists.words[i], if ok { nearest.indices[i] } else { OUT_OF_HALO }, "query {i}");
        }
        assert_eq!(certified, expected);
        // The whole grid certifies every list.
        let whole = HeldCells::around([0; 3], [u32::MAX; 3], 0, [p.dim_x, p.dim_y, p.dim_z], p.cell_size);
        let (lists, certified) = cpu.held_lists(&job, 600, 32, &g, &whole);
        assert_eq!((certified, &lists.words[..600 * 6]), (600, &nn.indices[..]));
    }
}
