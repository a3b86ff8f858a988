//! How a clipping job fits the device: what stays resident, and into how
//! many parts the sites' k-NN and the tets are split so that the job's
//! device memory stays under the budget and no buffer bound to a kernel
//! exceeds the device's `maxStorageBufferRange`.

use super::context::Context;
use crate::error::{Error, Result};
use crate::voronoi::{ClipJob, Strategy};
use cvd_kernels::abi::{counter, ACCUM_PER_SITE, WORKGROUP_SIZE};
use cvd_kernels::clip::CELL_RECORDS;

/// Chunk sizes of a clipping job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Plan {
    /// Sites per dispatch of the sites' k-NN (all of them: one dispatch in
    /// grid order, with distances for every site).
    pub site_chunk: u64,
    /// Tets per part: their k-NN, clipping and second pass.
    pub tet_chunk: u64,
    /// Number of tet parts.
    pub tet_parts: u64,
}

const MIB: f64 = (1u64 << 20) as f64;

/// Bytes that stay on the device for the whole job.
fn resident_bytes(job: &ClipJob) -> Vec<(&'static str, u64)> {
    let p = &job.params;
    let (n, nt, nv) = (p.n_sites as u64, p.n_tets as u64, job.verts.len() as u64);
    let ks = job.site_knn.params.k as u64;
    let cells = job.site_knn.params.grid.n_cells as u64;
    let mut parts = vec![
        ("sites", 16 * n),
        ("quantized sites", 16 * n),
        ("mesh", 16 * nv + 16 * nt),
        ("tet centroids", 16 * nt),
        ("sums", 8 * (ACCUM_PER_SITE as u64 * n + nt) + 16 * counter::COUNT as u64),
        ("site grid", 20 * n + 12 * cells),
        ("neighbour lists", 4 * n * ks),
    ];
    if job.strategy == Strategy::CellTet {
        parts.push(("Voronoi cells", 16 * CELL_RECORDS as u64 * n));
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
        let resident = resident_bytes(job);
        let total: u64 = resident.iter().map(|r| r.1).sum();
        let too_big = |what: String| {
            Err(Error::InvalidInput(format!(
                "{what} on '{device}' (budget {:.0} MiB: --memory-budget, default 80 % of the device's memory; \
                 largest binding {:.0} MiB: maxStorageBufferRange); use fewer sites, a smaller k_site, or the CPU backend",
                budget as f64 / MIB,
                max_binding as f64 / MIB
            )))
        };
        if let Some((name, bytes)) = resident.iter().find(|r| r.1 > max_binding) {
            return too_big(format!("the {name} need {:.0} MiB in one buffer", *bytes as f64 / MIB));
        }
        // What parts need, at their smallest, on top of the resident data.
        let group = WORKGROUP_SIZE as u64;
        let (ks, kt) = (job.site_knn.params.k as u64, job.params.k_tet as u64);
        let (n, nt) = (job.params.n_sites as u64, job.params.n_tets as u64);
        let least = group * (12 * ks + bytes_per_tet(job));
        if total + least > budget {
            return too_big(format!("the job keeps {:.0} MiB resident", total as f64 / MIB));
        }
        let free = budget - total;
        // Half of what is free for the k-NN's distances (and a part's
        // lists) at most, the rest (and whatever they leave) for the tets.
        let fit = |bytes_each: u64, room: u64, count: u64| -> u64 {
            let most = (room / bytes_each.max(1)).min(max_binding / bytes_each.max(1));
            if most >= count {
                count.max(1)
            } else {
                (most / group * group).max(group)
            }
        };
        // Whole: distances for every site; in parts: lists and distances.
        let site_chunk =
            if 8 * ks * n <= free / 2 && 8 * ks * n <= max_binding { n } else { fit(12 * ks, free / 2, n) };
        let per_site = if site_chunk == n { 8 * ks } else { 12 * ks };
        let left = free.saturating_sub(site_chunk * per_site);
        let tet_chunk = fit(bytes_per_tet(job).max(8 * kt), left, nt);
        Ok(Self { site_chunk, tet_chunk, tet_parts: nt.div_ceil(tet_chunk) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{points, ClippedVoronoi, TetMesh};

    fn job(n: usize) -> ClipJob {
        let mesh = TetMesh::cube(6);
        let sites = points::in_mesh(&mesh, n, 3);
        ClippedVoronoi::new(&mesh, &sites).job().unwrap().0
    }

    #[test]
    fn a_roomy_device_runs_the_job_whole() {
        let j = job(2000);
        let plan = Plan::new(&j, 1 << 30, 1 << 30, "test").unwrap();
        assert_eq!(plan, Plan { site_chunk: 2000, tet_chunk: j.params.n_tets as u64, tet_parts: 1 });
    }

    #[test]
    fn a_small_budget_splits_sites_and_tets_into_workgroup_multiples() {
        let j = job(2000);
        let resident: u64 = resident_bytes(&j).iter().map(|r| r.1).sum();
        let plan = Plan::new(&j, resident + 100 * 1024, 1 << 30, "test").unwrap();
        assert!(plan.site_chunk < 2000 && plan.site_chunk.is_multiple_of(64), "{plan:?}");
        assert!(plan.tet_parts > 1 && plan.tet_chunk.is_multiple_of(64), "{plan:?}");
        assert_eq!(plan.tet_parts, (j.params.n_tets as u64).div_ceil(plan.tet_chunk));
    }

    #[test]
    fn what_cannot_fit_is_an_error_naming_the_sizes() {
        let j = job(2000);
        let e = Plan::new(&j, 1 << 19, 1 << 30, "test").unwrap_err().to_string();
        assert!(e.contains("resident") && e.contains("budget"), "{e}");
        let e = Plan::new(&j, 1 << 30, 100_000, "test").unwrap_err().to_string();
        assert!(e.contains("neighbour lists") && e.contains("maxStorageBufferRange"), "{e}");
    }
}
