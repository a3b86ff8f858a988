//! The Vulkan backend: the kernels' SPIR-V dispatched with ash.

mod context;
mod job;
mod memory;
mod pipelines;
mod plan;

pub use context::{list_devices, validation_errors, DeviceInfo, VulkanOptions};

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::geom::timing::timed;
use crate::geom::timing::Timings;
use crate::job::clip::{split_sums, ClipJob, ClipOutput, Pairing, Strategy};
use crate::job::kept::LocalKept;
use crate::job::knn::{KnnJob, KnnMethod, Neighbors};
use crate::job::lloyd::LloydOutput;
use crate::job::BackendKind;
use context::Context;
use cvd_kernels::abi::{
    counter, lloyd_stat, ClipParams, GridBuildParams, GridParams, KnnParams, RefineParams, SplitPoint, ACCUM_PER_SITE,
};
use cvd_kernels::clip::CELL_RECORDS;
use cvd_kernels::scan;
use job::{BufId, Job};
use pipelines::{Pipelines, KERNELS};
use plan::Plan;

/// Whether this build embeds the kernels' SPIR-V (the `vulkan` feature).
pub const HAS_KERNELS: bool = !crate::spirv::MODULES.is_empty();

/// Why a build without the kernels cannot run on Vulkan.
const NO_KERNELS: &str = "this build of cvd has no SPIR-V kernels: it was built without the `vulkan` \
                          feature (cargo build --features vulkan; cargo xtask run --backend vulkan; \
                          Python: CVD_KERNELS=1 python -m pip install ./python)";

/// Runs the kernels on a Vulkan device.
pub struct VulkanBackend {
    // Dropped before the context that owns the device.
    pipelines: Pipelines,
    ctx: Context,
}

impl VulkanBackend {
    /// Opens a device and loads the kernels' module.
    pub fn new(options: &VulkanOptions) -> Result<Self> {
        if !HAS_KERNELS {
            return Err(Error::VulkanUnavailable(NO_KERNELS.into()));
        }
        let ctx = Context::new(options)?;
        let pipelines = Pipelines::new(&ctx)?;
        Ok(Self { pipelines, ctx })
    }

    /// The device in use.
    pub fn device(&self) -> &DeviceInfo {
        self.ctx.info()
    }

    /// The most device-local memory the backend's buffers held at once
    /// since the last [`Self::reset_peak_memory`] (or since it opened), in
    /// bytes.
    pub fn peak_memory(&self) -> u64 {
        self.ctx.usage.peak()
    }

    /// The most device memory one job may hold, in bytes: larger clipping
    /// jobs run in parts (see [`VulkanOptions::memory_budget`]).
    pub fn memory_budget(&self) -> u64 {
        self.ctx.memory_budget.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Sets [`Self::memory_budget`] for the jobs that follow.
    pub fn set_memory_budget(&self, bytes: u64) {
        self.ctx.memory_budget.store(bytes, std::sync::atomic::Ordering::Relaxed);
    }

    /// Starts measuring [`Self::peak_memory`] afresh.
    pub fn reset_peak_memory(&self) {
        self.ctx.usage.reset_peak();
    }

    /// Creates every pipeline now (drivers may compile for seconds) and
    /// returns the time that took.
    pub fn warm_up(&self) -> Result<f64> {
        let (r, t) = timed(|| KERNELS.iter().try_for_each(|k| self.pipelines.get(k.name).map(|_| ())));
        r.map(|_| t)
    }
}

impl Backend for VulkanBackend {
    fn kind(&self) -> BackendKind {
        BackendKind::Vulkan
    }

    fn device(&self) -> String {
        self.ctx.info().name.clone()
    }

    fn kernel_compile_seconds(&self) -> f64 {
        self.pipelines.compile_seconds()
    }

    fn knn(&self, job: &KnnJob) -> Result<Neighbors> {
        let (nq, k) = (job.queries.len() as u64, job.params.k as u64);
        let mut j = Job::new(&self.ctx, &self.pipelines, 8)?;
        let (nbr, d2) = record_knn(&mut j, job)?;
        let nbr_back = j.download(nbr, nq * k * 4)?;
        let d2_back = j.download(d2, nq * k * 8)?;
        j.mark("download");
        let done = j.run()?;
        let len = (nq * k) as usize;
        Ok(Neighbors {
            k: k as usize,
            indices: done.read(nbr_back, len),
            dist2: done.read(d2_back, len),
            timings: done.timings,
        })
    }

    fn lloyd(&self, job: &ClipJob, iterations: usize, progress: &mut dyn FnMut(usize, i64)) -> Result<LloydOutput> {
        lloyd_on_device(self, job, iterations, progress)
    }

    fn clip(&self, job: &ClipJob) -> Result<ClipOutput> {
        if job.only.is_some() {
            // A part's cells built again: on the CPU backend (a device's
            // part builds every answered cell again).
            return Err(Error::Internal("some answered cells only are built on the CPU backend".into()));
        }
        if job.held.is_some() || (job.is_windowed() && job.strategy != Strategy::Whole) {
            // Tets in parts: their lists' certificates and the tets' first
            // sites marked out of the halo are the CPU backend's. Whole
            // cells in a held window (a mesh's sites in parts) run here:
            // the walks stay in the held cells, and the lists' distances
            // come back for the part's certificate (`ClipJob::keep`).
            return Err(Error::InvalidInput("tets in parts run on the CPU backend".into()));
        }
        let plan = Plan::clip(&self.ctx, job)?;
        let p = &job.params;
        let (sk, tk) = (&job.site_knn, &job.tet_knn_job());
        let (n, nt) = (p.n_sites as u64, p.n_tets as u64);
        let (ks, kt) = (sk.params.k as u64, p.k_tet as u64);
        let site_parts = n.div_ceil(plan.site_chunk);
        let mut j = Job::new(&self.ctx, &self.pipelines, 16 + site_parts as u32 + 4 * plan.tet_parts as u32)?;
        // Every site's neighbour list, or a window's. Floods in windows
        // take the sites and the tets in slabs (see `plan`; knn pairs need
        // no other list than their own site's, and keep the job's order,
        // and its ties); the results go back to the job's order.
        let windows = plan.windows(n);
        let slabs = (windows.len() > 1 && job.pairing == Pairing::Flood).then(|| Slabs::new(job, plan.own / 4));
        let (sites, quant, tets, centroids) = match &slabs {
            None => (j.upload(&job.sites)?, j.upload(&sk.sites)?, j.upload(&job.tets)?, j.upload(&tk.queries)?),
            Some(s) => {
                // The sites in the slabs' order, then their weight bounds
                // (if any) in the same order.
                let n = n as usize;
                let bounds = if job.sites.len() > n { s.sites.as_slice() } else { &[] };
                let sites: Vec<SplitPoint> = s
                    .sites
                    .iter()
                    .map(|&old| job.sites[old as usize])
                    .chain(bounds.iter().map(|&old| job.sites[n + old as usize]))
                    .collect();
                let quant: Vec<[u32; 4]> = (0..s.sites.len())
                    .map(|new| {
                        let q = sk.sites[s.sites[new] as usize];
                        [q[0], q[1], q[2], new as u32]
                    })
                    .collect();
                let tets: Vec<[u32; 4]> = s.tets.iter().map(|&old| job.tets[old as usize]).collect();
                let centroids: Vec<[u32; 4]> = s.tets.iter().map(|&old| tk.queries[old as usize]).collect();
                (j.upload(&sites)?, j.upload(&quant)?, j.upload(&tets)?, j.upload(&centroids)?)
            }
        };
        let verts = j.upload(&job.verts)?;
        if slabs.is_some() && job.face_sums_len() > 0 {
            return Err(Error::InvalidInput(format!(
                "summing the cells' faces needs every site's neighbour list on the device at once, but this job \
                 is split into {} windows of lists on '{}'; use the CPU backend or a larger --memory-budget",
                windows.len(),
                self.ctx.info().name
            )));
        }
        let tet_faces = j.upload(&job.tet_faces)?;
        // The sites' sums, then one volume sum per tet (knn pairing's
        // certificate), then the faces' sums.
        let n_sums = n * ACCUM_PER_SITE as u64 + nt + job.face_sums_len() as u64;
        let sums = j.zeroed(n_sums * 8)?;
        let counters = j.zeroed(counter::COUNT as u64 * 8)?;
        let site_nbrs = j.buffer((plan.window * ks).max(1) * 4)?;
        j.mark("upload");

        // One grid of the sites answers both k-NN searches.
        let g = GridBuffers::new(&mut j, sk.params.grid)?;
        g.record(&mut j, quant)?;
        if let Some(unheld) = &sk.unheld {
            // A part's cells it does not hold, marked in the first slots
            // (the counting sort's, as the host's lays them out).
            let mut start = crate::exec::cell_starts(sk);
            crate::exec::mark_unheld(&mut start.0, &start.1, unheld);
            let marked = j.upload(&start.0)?;
            j.barrier();
            j.copy_to(marked, g.start, 0, 4 * start.0.len() as u64);
            j.barrier();
        }
        j.mark("grid");
        // The lists of sites `first..end`, into `site_nbrs` from its start:
        // all at once in grid order, or in parts of sites in index order,
        // each part's lists copied to their place.
        let part_lists = if ks > 0 && plan.site_chunk < n {
            Some((j.buffer(plan.site_chunk * ks * 4)?, j.buffer(plan.site_chunk * ks * 8)?))
        } else {
            None
        };
        // The lists' squared distances, when `distances` is given, copied
        // there (from list `first`'s on).
        let site_lists = |j: &mut Job, first: u64, end: u64, distances: Option<job::Readback>| -> Result<()> {
            match part_lists {
                None if ks > 0 => {
                    let d2 = j.buffer(n * ks * 8)?;
                    j.dispatch("knn_grid", &[quant, g.start, g.count, g.sorted, site_nbrs, d2], &sk.params, n)?;
                    if let Some(to) = distances {
                        j.barrier();
                        j.download_into(d2, to, (end - first) * ks * 8);
                    }
                }
                Some((part_nbrs, part_d2)) => {
                    for at in (first..end).step_by(plan.site_chunk as usize) {
                        let count = plan.site_chunk.min(end - at);
                        // A job answering some of its sites lists them from
                        // its first (`KnnJob::answering`).
                        let base = sk.params.query_base + at as u32;
                        let kp = KnnParams { n_queries: count as u32, query_base: base, in_order: 1, ..sk.params };
                        j.dispatch("knn_grid", &[quant, g.start, g.count, g.sorted, part_nbrs, part_d2], &kp, count)?;
                        j.barrier();
                        j.copy_to(part_nbrs, site_nbrs, (at - first) * ks * 4, count * ks * 4);
                        if let Some(to) = distances {
                            j.download_into_at(part_d2, to, (at - first) * ks * 8, count * ks * 8);
                        }
                        j.barrier();
                    }
                }
                None => {}
            }
            j.mark("site knn");
            Ok(())
        };
        if job.strategy == Strategy::Whole {
            let domain = job
                .domain
                .as_deref()
                .ok_or_else(|| Error::Internal("a whole-cell job without its domain index".into()))?;
            // Whole cells keep every list (the plan has one window): one
            // thread per site, then the sums back; the lists' distances
            // too where the job keeps them.
            let nq = sk.params.n_queries as u64;
            let keep = kept_reach(job)?;
            let distances = match keep {
                Some(_) if ks > 0 => Some(j.readback(nq * ks * 8)?),
                _ => None,
            };
            site_lists(&mut j, 0, nq, distances)?;
            // No buffer is empty: an unread record where there is none.
            let d = [
                j.upload(std::slice::from_ref(&domain.params))?,
                j.upload(&domain.voxel_start)?,
                j.upload(&or_one(&domain.voxel_tets))?,
                j.upload(&or_one(&domain.tet_voxel))?,
                j.upload(&or_one(&domain.nodes))?,
                j.upload(&or_one(&domain.tris))?,
            ];
            let list_len = 1 + 2 * n;
            let unfinished = j.zeroed(list_len * 4)?;
            let rp = RefineParams { clip: ClipParams { capacity: n as u32, ..*p }, ..job.refine };
            let args = [
                sites, verts, tets, site_nbrs, g.start, g.count, g.sorted, sums, counters, unfinished, tet_faces, d[0],
                d[1], d[2], d[3], d[4], d[5],
            ];
            j.dispatch("clip_whole", &args, &rp, n)?;
            j.mark("clip");
            let sums_back = j.download(sums, n_sums * 8)?;
            let lists_back = if job.face_sums_len() > 0 { Some(j.download(site_nbrs, nq * ks * 4)?) } else { None };
            let counters_back = j.download(counters, counter::COUNT as u64 * 8)?;
            let list_back = j.download(unfinished, list_len * 4)?;
            j.mark("download");
            let done = j.run()?;
            let all: Vec<i64> = done.read(sums_back, n_sums as usize);
            let (sums, tet_volumes, faces) = split_sums(all, n as usize * ACCUM_PER_SITE, nt as usize);
            let kept = keep.map(|kk| {
                let d2: Vec<u64> = distances.map_or_else(Vec::new, |d| done.read(d, (nq * ks) as usize));
                reach_of_lists(&d2, nq as usize, ks as usize, kk)
            });
            return Ok(ClipOutput {
                sums,
                tet_volumes,
                faces,
                site_lists: read_lists(&done, lists_back, nq, ks),
                counters: done.read(counters_back, counter::COUNT),
                refined: 0,
                unresolved: 0,
                certified: 0,
                kept,
                chunks: 1,
                unfinished: crate::job::clip::pair_list(&done.read::<u32>(list_back, list_len as usize)),
                timings: done.timings.clone(),
                kinds: Vec::new(),
            });
        }
        let cells = if job.strategy == Strategy::CellTet {
            // Cell-tet keeps every list (the plan has one window).
            site_lists(&mut j, 0, n, None)?;
            let cells = j.buffer(n * CELL_RECORDS as u64 * 16)?;
            j.dispatch("voronoi_cells", &[sites, site_nbrs, cells, counters], p, n)?;
            j.mark("cells");
            Some(cells)
        } else {
            None
        };

        // For each window, the tets, part by part: k-NN pairing, clipping,
        // second pass.
        let c = plan.tet_chunk;
        let tet_sites = j.buffer(c * kt * 4)?;
        let tet_d2 = j.buffer(c * kt * 8)?;
        let list_len = 1 + 2 * c * kt;
        let unfinished = j.buffer(list_len * 4)?;
        let still = j.buffer(list_len * 4)?;
        let ignored = j.buffer(counter::COUNT as u64 * 8)?;
        let first_back = j.readback(4)?;
        let still_back = j.readback(list_len * 4)?;
        let (mut refined, mut left, mut timings) = (0, Vec::new(), Timings::default());
        // Entries the second pass finished, and those left, of a part.
        let mut collect = |first: u32, list: &[u32]| {
            let still = crate::job::clip::pair_list(list);
            refined += first as u64 - still.len() as u64;
            left.extend(still);
        };
        // Floods walk the site grid and take the walk's parameters.
        let (kernel, cell_input, flood) = match (job.strategy, job.pairing, cells) {
            (Strategy::TetCell, Pairing::Flood, _) => ("clip_flood", site_nbrs, true),
            (Strategy::TetCell, Pairing::Knn, _) => ("clip_tet_cell", site_nbrs, false),
            (Strategy::CellTet, _, cells) => ("clip_cell_tet", cells.unwrap_or(site_nbrs), false),
            (Strategy::Whole, _, _) => unreachable!("whole cells returned above"),
        };
        // Whether the last part's lists are still to be read.
        let mut pending = false;
        for (w, window) in windows.iter().enumerate() {
            if cells.is_none() {
                site_lists(&mut j, window.first, window.end, None)?;
            }
            // Floods in slabs: the window's tets; otherwise every tet, for
            // the pairs of the sites the window owns.
            let tets_of = slabs.as_ref().map_or(0..nt, |s| s.tet_ranges[w].clone());
            for t0 in tets_of.clone().step_by(c as usize) {
                let count = c.min(tets_of.end - t0);
                let cp = ClipParams {
                    tet_base: t0 as u32,
                    n_tets: (t0 + count) as u32,
                    nbr_base: window.first as u32,
                    nbr_end: window.end as u32,
                    own_lo: window.own_lo as u32,
                    own_hi: window.own_hi as u32,
                    ..*p
                };
                let kp = KnnParams { n_queries: count as u32, query_base: t0 as u32, ..tk.params };
                j.fill_zero(unfinished);
                j.fill_zero(still);
                j.dispatch("knn_grid", &[centroids, g.start, g.count, g.sorted, tet_sites, tet_d2], &kp, count)?;
                j.mark("tet knn");
                // One thread per pair (flood: per tet, k_tet = 1).
                let pairs = count * kt;
                let rp = RefineParams { clip: ClipParams { capacity: pairs as u32, ..cp }, ..job.refine };
                if flood {
                    let args = [
                        sites, verts, tets, tet_sites, site_nbrs, g.start, g.count, g.sorted, sums, counters,
                        unfinished, tet_faces,
                    ];
                    j.dispatch(kernel, &args, &rp, pairs)?;
                } else if cells.is_some() {
                    let args =
                        [sites, verts, tets, tet_sites, cell_input, sums, counters, unfinished, site_nbrs, tet_faces];
                    j.dispatch(kernel, &args, &cp, pairs)?;
                } else {
                    let args = [sites, verts, tets, tet_sites, cell_input, sums, counters, unfinished, tet_faces];
                    j.dispatch(kernel, &args, &cp, pairs)?;
                }
                j.mark("clip");
                // The second pass, over as many threads as the list can hold
                // entries: those past its count return at once.
                let args = [
                    sites, verts, tets, tet_sites, unfinished, site_nbrs, g.start, g.count, g.sorted, sums, ignored,
                    still, tet_faces,
                ];
                j.dispatch("refine", &args, &rp, pairs)?;
                j.mark("second pass");
                j.download_into(unfinished, first_back, 4);
                j.download_into(still, still_back, list_len * 4);
                // Parts before the last are read before the next reuses the
                // lists; the last with the sums, in the job's one submission
                // when it has a single part.
                pending = true;
                if t0 + count < tets_of.end || w + 1 < windows.len() {
                    j.mark("download");
                    timings.phases.extend(j.submit()?.phases);
                    collect(j.read::<u32>(first_back, 1)[0], &j.read(still_back, list_len as usize));
                    pending = false;
                }
            }
        }
        let sums_back = j.download(sums, n_sums * 8)?;
        // With faces and every list resident, the lists the slots refer to.
        let whole_lists = job.face_sums_len() > 0 && windows.len() == 1;
        let lists_back = if whole_lists { Some(j.download(site_nbrs, n * ks * 4)?) } else { None };
        let counters_back = j.download(counters, counter::COUNT as u64 * 8)?;
        j.mark("download");
        let done = j.run()?;
        if pending {
            collect(done.read::<u32>(first_back, 1)[0], &done.read(still_back, list_len as usize));
        }
        timings.phases.extend(done.timings.phases.iter().cloned());
        let all: Vec<i64> = done.read(sums_back, n_sums as usize);
        let (mut sums, mut tet_volumes, faces) = split_sums(all, n as usize * ACCUM_PER_SITE, nt as usize);
        if let Some(s) = slabs {
            s.restore(&mut sums, &mut tet_volumes, &mut left);
        }
        left.sort_unstable();
        Ok(ClipOutput {
            sums,
            tet_volumes,
            faces,
            site_lists: read_lists(&done, lists_back, n, ks),
            counters: done.read(counters_back, counter::COUNT),
            refined,
            unresolved: 0,
            certified: 0,
            kept: None,
            chunks: plan.tet_parts * windows.len() as u64,
            unfinished: left,
            timings,
            kinds: Vec::new(),
        })
    }
}

/// The entries a whole-cell job keeps of each list, if it keeps their
/// distances only ([`crate::job::kept::Keep`] without entries: a part's
/// certificate) — the device's lists are the job's `k_site` long, so no
/// more than those. Lists kept whole, or from candidates (a trajectory's
/// next frame), are the CPU backend's: none kept here.
fn kept_reach(job: &ClipJob) -> Result<Option<u32>> {
    let Some(keep) = job.keep.as_ref().filter(|k| !k.entries && k.candidates.is_none()) else { return Ok(None) };
    let k = job.site_knn.params.k;
    let kk = keep.k.max(k).max(1);
    if k > 0 && kk > k {
        return Err(Error::Internal(format!("{kk} entries kept of lists of {k} on the device")));
    }
    Ok(Some(kk))
}

/// What a job keeps of its `n` lists of `k` entries ([`LocalKept`]
/// without entries) from their squared distances `d2`, `k` a list (none
/// when `k` is 0: a job of one site), `kk` entries kept: as the CPU
/// backend's lists keep them.
fn reach_of_lists(d2: &[u64], n: usize, k: usize, kk: u32) -> LocalKept {
    let last = |u: usize| if k == 0 { u64::MAX } else { d2[u * k + kk as usize - 1] };
    LocalKept {
        k: kk,
        lists: Vec::new(),
        last2: (0..n).map(last).collect(),
        kth2: (0..n).map(|u| if k == 0 { 0 } else { d2[u * k + k - 1] }).collect(),
        reused: vec![false; n],
    }
}

/// The site lists read back with the sums (`None`: not kept).
fn read_lists(done: &job::Finished, back: Option<job::Readback>, n: u64, ks: u64) -> crate::job::knn::PackedLists {
    back.map_or_else(Default::default, |b| crate::job::knn::PackedLists {
        words: done.read(b, (n * ks) as usize),
        k: ks as u32,
        bits: 32,
        timings: Default::default(),
    })
}

/// `data`, or one zeroed record where it is empty (a binding needs a
/// buffer; the kernels do not read it then).
fn or_one<T: bytemuck::Pod>(data: &[T]) -> std::borrow::Cow<'_, [T]> {
    if data.is_empty() {
        std::borrow::Cow::Owned(vec![T::zeroed()])
    } else {
        std::borrow::Cow::Borrowed(data)
    }
}

/// The order of a flood's sites and tets in windows of neighbour lists
/// (see `plan`): slabs of `slab` sites across the longest axis of the
/// sites' bounding box, the job's (Morton) order within each; each tet in
/// the slab of its centroid. A window binds eight slabs' lists and clips
/// the tets of the middle four, so each tet is clipped once, and the sites
/// its flood meets lie in the slabs bound.
struct Slabs {
    /// `sites[new] = old`.
    sites: Vec<u32>,
    /// `tets[new] = old`.
    tets: Vec<u32>,
    /// The tets (new order) each window clips.
    tet_ranges: Vec<std::ops::Range<u64>>,
}

impl Slabs {
    fn new(job: &ClipJob, slab: u64) -> Self {
        let slab = slab.max(1) as usize;
        let sites = &job.sites[..job.params.n_sites as usize];
        let extent = |a: usize| {
            let (lo, hi) =
                sites.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), p| (l.min(p.hi[a]), h.max(p.hi[a])));
            hi - lo
        };
        let axis = (0..3).max_by(|&a, &b| extent(a).total_cmp(&extent(b))).unwrap_or(0);
        let mut along: Vec<u32> = (0..sites.len() as u32).collect();
        along.sort_by(|&a, &b| sites[a as usize].hi[axis].total_cmp(&sites[b as usize].hi[axis]).then(a.cmp(&b)));
        let mut slab_of = vec![0usize; sites.len()];
        for (rank, &i) in along.iter().enumerate() {
            slab_of[i as usize] = rank / slab;
        }
        // Where each slab ends along the axis.
        let ends: Vec<f32> = along.chunks(slab).map(|c| sites[c[c.len() - 1] as usize].hi[axis]).collect();
        let mut site_order: Vec<u32> = (0..sites.len() as u32).collect();
        site_order.sort_by_key(|&i| slab_of[i as usize]);
        let tet_slab: Vec<usize> = job
            .tets
            .iter()
            .map(|t| {
                let c = t.iter().map(|&v| job.verts[v as usize].hi[axis]).sum::<f32>() / 4.0;
                ends.partition_point(|&e| e < c).min(ends.len() - 1)
            })
            .collect();
        let mut tets: Vec<u32> = (0..job.tets.len() as u32).collect();
        tets.sort_by_key(|&t| tet_slab[t as usize]);
        // Window w owns slabs 4w..4w + 4 (the plan's `own` is four slabs).
        let mut tet_ranges = Vec::new();
        let mut start = 0u64;
        for w in 0..ends.len().div_ceil(4) {
            let end = tets.partition_point(|&t| tet_slab[t as usize] < 4 * (w + 1)) as u64;
            tet_ranges.push(start..end);
            start = end;
        }
        Self { sites: site_order, tets, tet_ranges }
    }

    /// Puts the sums and the unfinished entries back in the job's order.
    fn restore(&self, sums: &mut Vec<i64>, tet_volumes: &mut [i64], left: &mut [[u32; 2]]) {
        let mut back = vec![0; sums.len()];
        for (new, &old) in self.sites.iter().enumerate() {
            let (from, to) = (new * ACCUM_PER_SITE, old as usize * ACCUM_PER_SITE);
            back[to..to + ACCUM_PER_SITE].copy_from_slice(&sums[from..from + ACCUM_PER_SITE]);
        }
        *sums = back;
        let volumes = tet_volumes.to_vec();
        for (new, &old) in self.tets.iter().enumerate() {
            tet_volumes[old as usize] = volumes[new];
        }
        for entry in left {
            entry[0] = self.tets[entry[0] as usize];
            if (entry[1] as usize) < self.sites.len() {
                entry[1] = self.sites[entry[1] as usize];
            }
        }
    }
}

/// Records a k-NN job (uploads, grid build, search); returns the neighbour
/// and distance buffers, `k` per query.
fn record_knn(j: &mut Job, job: &KnnJob) -> Result<(BufId, BufId)> {
    let p = &job.params;
    let (nq, k) = (job.queries.len() as u64, p.k as u64);
    let sites = j.upload(&job.sites)?;
    let queries = if p.exclude_self != 0 { sites } else { j.upload(&job.queries)? };
    let nbr = j.buffer(nq * k * 4)?;
    let d2 = j.buffer(nq * k * 8)?;
    if nq * k == 0 {
        return Ok((nbr, d2));
    }
    j.mark("upload");
    match job.method {
        KnnMethod::Grid => {
            let g = GridBuffers::new(j, p.grid)?;
            g.record(j, sites)?;
            j.mark("grid");
            j.dispatch("knn_grid", &[queries, g.start, g.count, g.sorted, nbr, d2], p, nq)?;
        }
        KnnMethod::Brute => j.dispatch("knn_brute", &[queries, sites, nbr, d2], p, nq)?,
    }
    j.mark("knn");
    Ok((nbr, d2))
}

/// The buffers of a site grid (`knn_grid`'s input) and its build's
/// parameters.
struct GridBuffers {
    params: GridBuildParams,
    site_cell: BufId,
    count: BufId,
    cursor: BufId,
    start: BufId,
    block_sums: BufId,
    sorted: BufId,
}

impl GridBuffers {
    fn new(j: &mut Job, grid: GridParams) -> Result<Self> {
        let (n_sites, n_cells) = (grid.n_sites as u64, grid.n_cells as u64);
        let n_blocks = scan::block_count(n_cells as usize) as u64;
        Ok(Self {
            params: GridBuildParams { grid, n_blocks: n_blocks as u32, _pad: [0; 3] },
            site_cell: j.buffer(n_sites.max(1) * 4)?,
            count: j.buffer(n_cells * 4)?,
            cursor: j.buffer(n_cells * 4)?,
            start: j.buffer(n_cells * 4)?,
            block_sums: j.buffer(n_blocks.max(1) * 4)?,
            sorted: j.buffer(n_sites.max(1) * 16)?,
        })
    }

    /// Records the counting sort of `sites` into the grid.
    fn record(&self, j: &mut Job, sites: BufId) -> Result<()> {
        let bp = &self.params;
        let (n, n_blocks) = (bp.grid.n_sites as u64, bp.n_blocks as u64);
        j.fill_zero(self.count);
        j.fill_zero(self.cursor);
        j.barrier();
        j.dispatch("grid_count", &[sites, self.site_cell, self.count], bp, n)?;
        j.barrier();
        j.dispatch("scan_blocks", &[self.count, self.start, self.block_sums], bp, n_blocks)?;
        j.barrier();
        j.dispatch("scan_totals", &[self.block_sums], bp, 1)?;
        j.barrier();
        j.dispatch("scan_offsets", &[self.block_sums, self.start], bp, n_blocks)?;
        j.barrier();
        j.dispatch("grid_scatter", &[sites, self.site_cell, self.start, self.cursor, self.sorted], bp, n)?;
        j.barrier();
        j.dispatch("grid_sort", &[self.start, self.count, self.sorted], bp, bp.grid.n_cells as u64)?;
        Ok(())
    }
}

/// Iterations per submission of a Lloyd loop (progress is reported
/// between submissions).
const LLOYD_BATCH: usize = 8;

/// Records and runs a Lloyd loop entirely on the device.
fn lloyd_on_device(
    b: &VulkanBackend,
    job: &ClipJob,
    iterations: usize,
    progress: &mut dyn FnMut(usize, i64),
) -> Result<LloydOutput> {
    let plan = Plan::clip(&b.ctx, job)?;
    if plan.tet_parts > 1 || plan.site_chunk < job.params.n_sites as u64 {
        return Err(Error::InvalidInput(format!(
            "the Lloyd loop on the device keeps the whole job resident, which does not fit the memory budget of '{}' \
             (a single diagram would run in {} parts); use the CPU backend or a larger --memory-budget",
            b.ctx.info().name,
            plan.tet_parts
        )));
    }
    let p = &job.params;
    let (sk, tk) = (&job.site_knn, &job.tet_knn_job());
    let (n, nt, k) = (p.n_sites as u64, p.n_tets as u64, sk.params.k as u64);
    let mut j = Job::new(&b.ctx, &b.pipelines, LLOYD_BATCH as u32 * 12 + 8)?;
    let sites = j.upload(&job.sites)?;
    let verts = j.upload(&job.verts)?;
    let tets = j.upload(&job.tets)?;
    let quant = j.upload(&sk.sites)?;
    let centroids = j.upload(&tk.queries)?;
    let g = GridBuffers::new(&mut j, sk.params.grid)?;
    let nbr = j.buffer((n * k).max(1) * 4)?;
    let d2 = j.buffer((n * k).max(1) * 8)?;
    let tet_sites = j.buffer(nt * 4)?;
    let tet_d2 = j.buffer(nt * 8)?;
    let sums = j.buffer(n * ACCUM_PER_SITE as u64 * 8)?;
    let counters = j.buffer(counter::COUNT as u64 * 8)?;
    let list_len = 1 + 2 * nt;
    let unfinished = j.buffer(list_len * 4)?;
    let still = j.buffer(list_len * 4)?;
    let ignored = j.buffer(counter::COUNT as u64 * 8)?;
    let stats = j.zeroed((iterations * lloyd_stat::COUNT).max(1) as u64 * 8)?;
    // No faces are summed in the loop (faces_base is 0): the binding is
    // there, never read.
    let tet_faces = j.upload(&[0u32])?;
    j.mark("upload");
    let rp = RefineParams { clip: ClipParams { capacity: nt as u32, faces_base: 0, ..job.refine.clip }, ..job.refine };
    let mut seconds = Vec::with_capacity(iterations);
    for it in 0..iterations {
        for buf in [sums, counters, unfinished, still] {
            j.fill_zero(buf);
        }
        g.record(&mut j, quant)?;
        j.barrier();
        if k > 0 {
            j.dispatch("knn_grid", &[quant, g.start, g.count, g.sorted, nbr, d2], &sk.params, n)?;
        }
        j.dispatch("knn_grid", &[centroids, g.start, g.count, g.sorted, tet_sites, tet_d2], &tk.params, nt)?;
        j.barrier();
        let args =
            [sites, verts, tets, tet_sites, nbr, g.start, g.count, g.sorted, sums, counters, unfinished, tet_faces];
        j.dispatch("clip_flood", &args, &rp, nt)?;
        j.barrier();
        let args = [
            sites, verts, tets, tet_sites, unfinished, nbr, g.start, g.count, g.sorted, sums, ignored, still, tet_faces,
        ];
        j.dispatch("refine", &args, &rp, nt)?;
        j.barrier();
        let lp = crate::job::lloyd::lloyd_params(job, it);
        j.dispatch("move_sites", &[sums, unfinished, still, sites, quant, stats], &lp, n.max(1))?;
        j.mark("iteration");
        if (it + 1) % LLOYD_BATCH == 0 && it + 1 < iterations {
            let energy = j.download_at(stats, (it * lloyd_stat::COUNT + lloyd_stat::ENERGY) as u64 * 8, 8)?;
            seconds.extend(j.submit()?.phases.iter().filter(|(ph, _)| ph == "iteration").map(|(_, s)| *s));
            progress(it + 1, j.read::<i64>(energy, 1)[0]);
        }
    }
    let sites_back = j.download(sites, n * std::mem::size_of::<SplitPoint>() as u64)?;
    let stats_back = j.download(stats, (iterations * lloyd_stat::COUNT) as u64 * 8)?;
    j.mark("download");
    let done = j.run()?;
    seconds.extend(done.timings.phases.iter().filter(|(ph, _)| ph == "iteration").map(|(_, s)| *s));
    let stats = done.read(stats_back, iterations * lloyd_stat::COUNT);
    progress(iterations, stats.len().checked_sub(lloyd_stat::COUNT).map_or(0, |last| stats[last + lloyd_stat::ENERGY]));
    Ok(LloydOutput { sites: done.read(sites_back, n as usize), stats, seconds })
}
