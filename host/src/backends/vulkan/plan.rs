//! How a clipping job fits the device: what stays resident, and into how
//! many parts the sites' k-NN and the tets are split so that the job's
//! device memory stays under the budget and no buffer bound to a kernel
//! exceeds the device's `maxStorageBufferRange`.
//!
//! The sites' neighbour lists stay resident when they fit. When they do
//! not (tet-cell only: cell-tet's stored cells are larger still), the sites
//! are taken in windows: each window's lists are computed and bound, and
//! each knn pair is clipped by the window that owns the
//! site of its pair. Floods in windows take the sites in slabs across the
//! longest axis, `own / 4` sites each (Morton order within a slab), and
//! each tet in the slab of its centroid: a window binds eight consecutive
//! slabs' lists and floods the tets of the middle four, so each tet is
//! flooded once and the sites it meets lie in the slabs bound. A piece
//! whose site's list is still outside is left to the second pass, which
//! needs no lists. (A knn pair needs its own site's list only, which the
//! window that owns the site binds.)

use super::context::Context;
use crate::error::{Error, Result};
use crate::job::clip::{ClipJob, Strategy};
use cvd_kernels::abi::{counter, ACCUM_PER_SITE, WORKGROUP_SIZE};
use cvd_kernels::clip::CELL_RECORDS;

/// Chunk sizes of a clipping job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Plan {
    /// Sites per dispatch of the sites' k-NN (all of them: one dispatch in
    /// grid order, with distances for every site).
    pub site_chunk: u64,
    /// Sites whose neighbour lists are bound at once: all of them, or a
    /// window (see the module's documentation).
    pub window: u64,
    /// Sites each window answers for (all of them with one window): four
    /// slabs, with two more on either side.
    pub own: u64,
    /// Tets per part: their k-NN, clipping and second pass.
    pub tet_chunk: u64,
    /// Number of tet parts.
    pub tet_parts: u64,
}

/// One window of sites: those it answers for, `own_lo..own_hi`, and those
/// whose lists it binds, `first..end`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Window {
    pub own_lo: u64,
    pub own_hi: u64,
    pub first: u64,
    pub end: u64,
}

const MIB: f64 = (1u64 << 20) as f64;

/// Bytes that stay on the device for the whole job, but for the sites'
/// neighbour lists.
fn resident_bytes(job: &ClipJob) -> Vec<(&'static str, u64)> {
    let p = &job.params;
    let (n, nt, nv) = (p.n_sites as u64, p.n_tets as u64, job.verts.len() as u64);
    let cells = job.site_knn.params.grid.n_cells as u64;
    let mut parts = vec![
        ("sites", 16 * n),
        ("quantized sites", 16 * n),
        ("mesh", 16 * nv + 16 * nt),
        ("tet centroids", 16 * nt),
        ("sums", 8 * (ACCUM_PER_SITE as u64 * n + nt) + 16 * counter::COUNT as u64),
        ("site grid", 20 * n + 12 * cells),
    ];
    if job.strategy == Strategy::CellTet {
        parts.push(("Voronoi cells", 16 * CELL_RECORDS as u64 * n));
    }
    if let Some(d) = job.domain.as_deref() {
        parts.push(("domain index", d.bytes() as u64 + 16 * n));
    }
    parts
}

/// Device bytes of one tet of a part: its k-NN list and distances, and
/// its entries in the two unfinished lists.
fn bytes_per_tet(job: &ClipJob) -> u64 {
    let kt = job.params.k_tet as u64;
    4 * kt + 8 * kt + 2 * 8 * kt
}

impl Plan {
    /// The plan of `job` on `ctx`'s device, or an error naming what does
    /// not fit.
    pub(crate) fn clip(ctx: &Context, job: &ClipJob) -> Result<Self> {
        let budget = ctx.memory_budget.load(std::sync::atomic::Ordering::Relaxed);
        Self::new(job, budget, ctx.limits.max_storage_buffer_range as u64, &ctx.info.name)
    }

    fn new(job: &ClipJob, budget: u64, max_binding: u64, device: &str) -> Result<Self> {
        let too_big = |what: String| {
            Err(Error::InvalidInput(format!(
                "{what} on '{device}' (budget {:.0} MiB: --memory-budget, default 80 % of the device's memory; \
                 largest binding {:.0} MiB: maxStorageBufferRange); use fewer sites, a smaller k_site, or the CPU backend",
                budget as f64 / MIB,
                max_binding as f64 / MIB
            )))
        };
        let resident = resident_bytes(job);
        if let Some((name, bytes)) = resident.iter().find(|r| r.1 > max_binding) {
            return too_big(format!("the {name} need {:.0} MiB in one buffer", *bytes as f64 / MIB));
        }
        let group = WORKGROUP_SIZE as u64;
        let (ks, kt) = (job.site_knn.params.k as u64, job.params.k_tet as u64);
        let (n, nt) = (job.params.n_sites as u64, job.params.n_tets as u64);
        // What the lists and parts need, at their smallest, on top of the
        // resident data.
        let least = group * (12 * ks + bytes_per_tet(job));
        let lists = 4 * n * ks;
        let mut kept: u64 = resident.iter().map(|r| r.1).sum();
        let whole = lists <= max_binding && kept + lists + least <= budget;
        // Cell-tet and whole cells keep every list.
        let every_list = matches!(job.strategy, Strategy::CellTet | Strategy::Whole);
        if whole || every_list {
            if lists > max_binding {
                return too_big(format!("the neighbour lists need {:.0} MiB in one buffer", lists as f64 / MIB));
            }
            kept += lists;
        }
        let windows = !whole && !every_list;
        if kept + least + windows as u64 * 4 * group * ks > budget {
            return too_big(format!("the job keeps {:.0} MiB resident", kept as f64 / MIB));
        }
        let mut free = budget - kept;
        // Whole, or workgroup multiples that fit `room` and one binding.
        let fit = |bytes_each: u64, room: u64, count: u64| -> u64 {
            let most = (room / bytes_each.max(1)).min(max_binding / bytes_each.max(1));
            if most >= count {
                count.max(1)
            } else {
                (most / group * group).max(group)
            }
        };
        let (window, own) = if windows {
            // A third of what is free for a window's lists: eight slabs,
            // the middle four its own.
            let slab = (fit(4 * ks, free / 3, n) / 8).max(1);
            free -= 4 * ks * 8 * slab;
            (8 * slab, 4 * slab)
        } else {
            (n, n)
        };
        // Whole: distances for every site; in parts: lists and distances.
        let site_chunk = if !windows && 8 * ks * n <= free / 2 && 8 * ks * n <= max_binding {
            n
        } else {
            fit(12 * ks, free / 2, window)
        };
        let per_site = if site_chunk == n { 8 * ks } else { 12 * ks };
        let left = free.saturating_sub(site_chunk * per_site);
        let tet_chunk = fit(bytes_per_tet(job).max(8 * kt), left, nt);
        Ok(Self { site_chunk, window, own, tet_chunk, tet_parts: nt.div_ceil(tet_chunk) })
    }

    /// The windows of `n` sites: one, of all of them, when the lists fit.
    pub(crate) fn windows(&self, n: u64) -> Vec<Window> {
        let margin = (self.window - self.own) / 2;
        (0..n.max(1))
            .step_by(self.own.max(1) as usize)
            .map(|own_lo| {
                let own_hi = (own_lo + self.own).min(n);
                Window { own_lo, own_hi, first: own_lo.saturating_sub(margin), end: (own_hi + margin).min(n) }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::clip::DEFAULT_K_SITE;
    use crate::{geom::points, ClippedVoronoi, TetMesh};

    fn job(n: usize) -> ClipJob {
        let mesh = TetMesh::cube(6);
        let sites = points::in_mesh(&mesh, n, 3);
        // Vulkan's default list length.
        ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::TetCell).k_site(DEFAULT_K_SITE).job().unwrap().0
    }

    fn cell_tet_job(n: usize) -> ClipJob {
        let mesh = TetMesh::cube(6);
        let sites = points::in_mesh(&mesh, n, 3);
        ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::CellTet).job().unwrap().0
    }

    #[test]
    fn a_roomy_device_runs_the_job_whole() {
        let j = job(2000);
        let plan = Plan::new(&j, 1 << 30, 1 << 30, "test").unwrap();
        let nt = j.params.n_tets as u64;
        assert_eq!(plan, Plan { site_chunk: 2000, window: 2000, own: 2000, tet_chunk: nt, tet_parts: 1 });
        let all = Window { own_lo: 0, own_hi: 2000, first: 0, end: 2000 };
        assert_eq!(plan.windows(2000), vec![all]);
    }

    #[test]
    fn a_small_budget_splits_sites_and_tets_into_workgroup_multiples() {
        let j = job(2000);
        let lists = 4 * 2000 * j.site_knn.params.k as u64;
        let resident: u64 = resident_bytes(&j).iter().map(|r| r.1).sum::<u64>() + lists;
        let plan = Plan::new(&j, resident + 100 * 1024, 1 << 30, "test").unwrap();
        assert_eq!((plan.window, plan.own), (2000, 2000), "{plan:?}");
        assert!(plan.site_chunk < 2000 && plan.site_chunk.is_multiple_of(64), "{plan:?}");
        assert!(plan.tet_parts > 1 && plan.tet_chunk.is_multiple_of(64), "{plan:?}");
        assert_eq!(plan.tet_parts, (j.params.n_tets as u64).div_ceil(plan.tet_chunk));
    }

    #[test]
    fn what_cannot_fit_is_an_error_naming_the_sizes() {
        let j = job(2000);
        let e = Plan::new(&j, 1 << 17, 1 << 30, "test").unwrap_err().to_string();
        assert!(e.contains("resident") && e.contains("budget"), "{e}");
        // Cell-tet binds every cell (and every list) at once.
        let e = Plan::new(&cell_tet_job(2000), 1 << 30, 1_000_000, "test").unwrap_err().to_string();
        assert!(e.contains("Voronoi cells") && e.contains("maxStorageBufferRange"), "{e}");
        // Whole cells bind every list and the domain's index at once.
        let mesh = TetMesh::cube(6);
        let sites = points::in_mesh(&mesh, 2000, 3);
        let whole =
            ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).k_site(DEFAULT_K_SITE).job().unwrap().0;
        assert!(resident_bytes(&whole).iter().any(|r| r.0 == "domain index"));
        let e = Plan::new(&whole, 1 << 30, 100_000, "test").unwrap_err().to_string();
        assert!(e.contains("neighbour lists") && e.contains("maxStorageBufferRange"), "{e}");
    }

    /// Lists larger than a binding (tet-cell): windows that fit one, whose
    /// owned ranges cover every site once, each inside its window.
    #[test]
    fn lists_too_large_for_a_binding_go_in_windows() {
        let j = job(2000);
        let max_binding = 100_000;
        let plan = Plan::new(&j, 1 << 30, max_binding, "test").unwrap();
        assert!(plan.window < 2000 && 2 * plan.own == plan.window && plan.own.is_multiple_of(4), "{plan:?}");
        assert!(4 * plan.window * j.site_knn.params.k as u64 <= max_binding, "{plan:?}");
        let windows = plan.windows(2000);
        let mut next = 0;
        for w in &windows {
            assert_eq!(w.own_lo, next, "{windows:?}");
            assert!(w.first <= w.own_lo && w.own_lo < w.own_hi && w.own_hi <= w.end, "{w:?}");
            assert!(w.end - w.first <= plan.window, "{w:?}");
            next = w.own_hi;
        }
        assert_eq!(next, 2000);
        assert!(windows.len() > 1 && windows[1].first < windows[0].own_hi, "no margin: {windows:?}");
    }
}
