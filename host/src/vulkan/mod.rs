//! The Vulkan backend: the kernels' SPIR-V dispatched with ash.

mod context;
mod job;
mod memory;
mod pipelines;

pub use context::{list_devices, validation_errors, DeviceInfo, VulkanOptions};
pub use pipelines::KERNELS_SPV;

use crate::backend::Backend;
use crate::error::Result;
use crate::knn::{KnnJob, KnnMethod, Neighbors};
use crate::timing::timed;
use crate::voronoi::{ClipJob, ClipOutput, Pairing, Strategy};
use context::Context;
use cvd_kernels::abi::{counter, GridBuildParams, ACCUM_PER_SITE};
use cvd_kernels::clip::CELL_RECORDS;
use cvd_kernels::scan;
use job::{BufId, Job};
use pipelines::{Pipelines, KERNELS};

/// Runs the kernels on a Vulkan device.
pub struct VulkanBackend {
    // Dropped before the context that owns the device.
    pipelines: Pipelines,
    ctx: Context,
}

impl VulkanBackend {
    /// Opens a device and loads the kernels' module.
    pub fn new(options: &VulkanOptions) -> Result<Self> {
        let ctx = Context::new(options)?;
        let pipelines = Pipelines::new(&ctx)?;
        Ok(Self { pipelines, ctx })
    }

    /// The device in use.
    pub fn device(&self) -> &DeviceInfo {
        self.ctx.info()
    }

    /// Creates every pipeline now (drivers may compile for seconds) and
    /// returns the time that took.
    pub fn warm_up(&self) -> Result<f64> {
        let (r, t) = timed(|| KERNELS.iter().try_for_each(|k| self.pipelines.get(k.name).map(|_| ())));
        r.map(|_| t)
    }
}

impl Backend for VulkanBackend {
    fn kind(&self) -> &'static str {
        "vulkan"
    }

    fn device(&self) -> String {
        self.ctx.info().name.clone()
    }

    fn knn(&self, job: &KnnJob) -> Result<Neighbors> {
        let (nq, k) = (job.queries.len() as u64, job.params.k as u64);
        let mut j = Job::new(&self.ctx, &self.pipelines, 8)?;
        let (nbr, d2) = record_knn(&mut j, job, "knn")?;
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

    fn clip(&self, job: &ClipJob) -> Result<ClipOutput> {
        let p = &job.params;
        let (n, n_pairs) = (p.n_sites as u64, p.n_tets as u64 * p.k_tet as u64);
        let mut j = Job::new(&self.ctx, &self.pipelines, 24)?;
        let sites = j.upload(&job.sites)?;
        let verts = j.upload(&job.verts)?;
        let tets = j.upload(&job.tets)?;
        let sums = j.zeroed(n * ACCUM_PER_SITE as u64 * 8)?;
        let counters = j.zeroed(counter::COUNT as u64 * 8)?;
        // Count, then up to one (tet, site) entry per pair.
        let list_len = 1 + 2 * n_pairs;
        let unfinished = j.zeroed(list_len * 4)?;
        let (site_nbrs, _) = record_knn(&mut j, &job.site_knn, "site knn")?;
        let (tet_sites, _) = record_knn(&mut j, &job.tet_knn, "tet knn")?;
        match job.strategy {
            Strategy::TetCell if job.pairing == Pairing::Flood => {
                let args = [sites, verts, tets, tet_sites, site_nbrs, sums, counters, unfinished];
                j.dispatch("clip_flood", &args, p, p.n_tets as u64)?;
            }
            Strategy::TetCell => {
                j.dispatch(
                    "clip_tet_cell",
                    &[sites, verts, tets, tet_sites, site_nbrs, sums, counters, unfinished],
                    p,
                    n_pairs,
                )?;
            }
            Strategy::CellTet => {
                let cells = j.buffer(n * CELL_RECORDS as u64 * 16)?;
                j.dispatch("voronoi_cells", &[sites, site_nbrs, cells, counters], p, n)?;
                j.mark("cells");
                j.dispatch(
                    "clip_cell_tet",
                    &[sites, verts, tets, tet_sites, cells, sums, counters, unfinished],
                    p,
                    n_pairs,
                )?;
            }
        }
        j.mark("clip");
        let sums_back = j.download(sums, n * ACCUM_PER_SITE as u64 * 8)?;
        let counters_back = j.download(counters, counter::COUNT as u64 * 8)?;
        let unfinished_back = j.download(unfinished, list_len * 4)?;
        j.mark("download");
        let done = j.run()?;
        Ok(ClipOutput {
            sums: done.read(sums_back, n as usize * ACCUM_PER_SITE),
            counters: done.read(counters_back, counter::COUNT),
            unfinished: crate::voronoi::pair_list(&done.read(unfinished_back, list_len as usize)),
            timings: done.timings,
        })
    }
}

/// Records a k-NN job (uploads, grid build, search) ending with the phase
/// mark `phase`; returns the neighbour and distance buffers.
fn record_knn(j: &mut Job, job: &KnnJob, phase: &str) -> Result<(BufId, BufId)> {
    let p = &job.params;
    let (n, nq, k) = (job.sites.len() as u64, job.queries.len() as u64, p.k as u64);
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
            let n_cells = p.grid.n_cells as u64;
            let n_blocks = scan::block_count(n_cells as usize) as u64;
            let bp = GridBuildParams { grid: p.grid, n_blocks: n_blocks as u32, _pad: [0; 3] };
            let site_cell = j.buffer(n * 4)?;
            let count = j.zeroed(n_cells * 4)?;
            let cursor = j.zeroed(n_cells * 4)?;
            let start = j.buffer(n_cells * 4)?;
            let sums = j.buffer(n_blocks * 4)?;
            let sorted = j.buffer(n * 16)?;
            j.barrier();
            j.dispatch("grid_count", &[sites, site_cell, count], &bp, n)?;
            j.barrier();
            j.dispatch("scan_blocks", &[count, start, sums], &bp, n_blocks)?;
            j.barrier();
            j.dispatch("scan_totals", &[sums], &bp, 1)?;
            j.barrier();
            j.dispatch("scan_offsets", &[sums, start], &bp, n_blocks)?;
            j.barrier();
            j.dispatch("grid_scatter", &[sites, site_cell, start, cursor, sorted], &bp, n)?;
            j.mark("grid");
            j.dispatch("knn_grid", &[queries, start, count, sorted, nbr, d2], p, nq)?;
        }
        KnnMethod::Brute => {
            j.dispatch("knn_brute", &[queries, sites, nbr, d2], p, nq)?;
        }
    }
    j.mark(phase);
    Ok((nbr, d2))
}
