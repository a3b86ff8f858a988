//! The host pass: finishes, with the kernels' own bodies, what even the
//! kernels' second pass left unfinished (a tet met by more cells than its
//! flood queue holds, a piece with more faces than a `Cell` holds), so
//! that no volume is lost; and, for knn pairing, completes the tets whose
//! pieces border a site not paired with them.
//!
//! * A whole tet is flooded again (`refine::refine_tet`, the grid walk of
//!   the second pass) with a longer queue, from the site nearest its
//!   centroid.
//! * A tet whose flood still fails is paired with every site that may own
//!   part of it (a radius bound, filtered), and each pair is done as below.
//! * A `(tet, site)` pair is clipped on its own (`refine::refine_pair`).
//! * A site whose whole cell could not be built (`WHOLE_CELL`) gets its
//!   piece of every tet, each pair as above.
//! * Knn pairing: a tet with a piece bordering a site not paired with it
//!   (or, as a safety net, whose pieces do not add up to it) gets the
//!   pieces of the sites that may own part of it but were not among its k
//!   nearest.

use crate::error::Result;
use crate::exec::{build_grid, par_indices, CpuBackend, LocalPairs, TaskSink};
use crate::geom::site_grid::SiteGrid;
use crate::job::clip::{ClipJob, ClipOutput};
use crate::job::knn::KnnJob;
use cvd_kernels::abi::{counter, KnnParams, INCOMPLETE_TET, NO_SITE, OUT_OF_HALO, WHOLE_CELL};
use cvd_kernels::clip::{FaceInputs, Paired};
use cvd_kernels::refine;
use cvd_kernels::walk::{power_nearest, GridWalk};
use std::cell::OnceCell;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::Mutex;

/// Most sites a tet's flood may visit in the second pass.
const QUEUE: usize = 1024;

/// What the second pass did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SecondPassCounts {
    /// Unfinished entries (whole tets or pairs) finished here.
    pub finished: u64,
    /// Pieces that could not be finished even here (more faces than a
    /// `Cell` holds): their volume is missing, and counted.
    pub unresolved: u64,
    /// Knn pairing: tets a site owning part of them was not paired with (a
    /// piece bordered it, or the pieces did not add up to the tet), whose
    /// missing pieces were added here.
    pub missed_tets: u64,
}

/// Finishes `out.unfinished`, adding the pieces to `out.sums` and handing
/// them to the tasks' sinks, which end up in `sinks`.
pub(crate) fn run<S: TaskSink>(job: &ClipJob, out: &mut ClipOutput, sinks: &Mutex<Vec<S>>) -> Result<SecondPassCounts> {
    let knn = job.pairing == crate::job::clip::Pairing::Knn;
    if out.unfinished.is_empty() && !knn {
        return Ok(SecondPassCounts::default());
    }
    // Whole cells in a part whose walks left its window: the part is done
    // again with a wider one, and a cell finished here from every tet
    // would only cost time. Left unfinished, and counted.
    let left_window = out.counters.get(counter::HALO).is_some_and(|&h| h > 0);
    if job.strategy == crate::job::clip::Strategy::Whole && job.is_windowed() && left_window {
        return Ok(SecondPassCounts { unresolved: out.unfinished.len() as u64, ..Default::default() });
    }
    // The kernels' grid walk, over the kernels' grid; the host grid answers
    // nearest-site and radius queries.
    let g = build_grid(&job.site_knn);
    let walk = GridWalk::new(&job.refine, &[], &g.cell_start, &g.cell_count, &g.sorted);
    let grid = SiteGrid::new(&job.sites[..job.params.n_sites as usize]);
    // The sites' sums, then the tets' volumes, as the kernels lay them out.
    let n_site_sums = out.sums.len();
    let sums: Vec<AtomicI64> =
        out.sums.iter().chain(&out.tet_volumes).chain(&out.faces).map(|&s| AtomicI64::new(s)).collect();
    // No neighbour lists here: the faces these pieces have are summed as
    // outside their site's list, and the host completes those sites.
    let faces = FaceInputs { site_nbrs: &[], tet_faces: &job.tet_faces };
    let mut tets = Vec::new();
    let mut pairs = Vec::new();
    let mut incomplete = Vec::new();
    let mut whole_sites = Vec::new();
    for &e in &out.unfinished {
        if e[0] == WHOLE_CELL {
            whole_sites.push(e[1]);
            continue;
        }
        match e[1] {
            NO_SITE => tets.push(e),
            // A part of a distributed job does such a tet again with a
            // wider halo: finished here, its clips would differ from the
            // whole job's.
            OUT_OF_HALO => {
                return Err(crate::error::Error::Internal(format!("tet {} out of its part's halo", e[0])));
            }
            INCOMPLETE_TET => incomplete.push(e[0]),
            _ => pairs.push(e),
        }
    }
    let mut redone = SecondPassCounts::default();

    // Whole tets: flood again, with a longer queue.
    let failed = Mutex::new(Vec::new());
    let ignored: Vec<AtomicI64> = (0..counter::COUNT).map(|_| AtomicI64::new(0)).collect();
    par_indices(tets.len(), 16, &sums, &ignored, &failed, sinks, |e, sums, counters, failed, sink| {
        let t = tets[e][0] as usize;
        let (sites, verts, tets) = (&job.sites, &job.verts, &job.tets);
        let (nearest, _) = grid.nearest(centroid(job, t));
        let start = power_nearest(t, nearest, sites, verts, tets, &walk);
        refine::refine_tet::<QUEUE, _, _, _, _>(
            t,
            start,
            &job.refine,
            walk,
            sites,
            verts,
            tets,
            faces,
            sums,
            counters,
            failed,
            sink,
        );
    });
    let failed = failed.into_inner().unwrap_or_else(|e| e.into_inner());
    redone.finished += (tets.len() - failed.len()) as u64;

    // Tets still unfinished, and the pairs: each pair on its own. An entry
    // is finished when all of its pairs are. A knn pair is checked against
    // its tet's paired sites (the same k-NN, redone for its tet); the
    // pairs of a failed tet are all the sites that may own part of it.
    let cpu = OnceCell::new();
    let paired = if knn { tet_lists(job, &cpu, pairs.iter().map(|e| e[0]))? } else { Vec::new() };
    let entries: Vec<[u32; 2]> =
        pairs.iter().chain(&failed).copied().chain(whole_sites.iter().map(|&j| [WHOLE_CELL, j])).collect();
    let mut work: Vec<Work> = pairs.iter().enumerate().map(|(e, &p)| (p, e, knn.then_some(e))).collect();
    work.extend(candidate_pairs(job, &grid, &walk, &failed).into_iter().map(|(p, e)| (p, pairs.len() + e, None)));
    // A whole cell that could not be built: its site's piece of every tet
    // (rare enough — a cell with more faces than a `Cell` holds — that no
    // bound on where its cell lies is kept).
    let first_whole = pairs.len() + failed.len();
    for (e, &j) in whole_sites.iter().enumerate() {
        work.extend((0..job.tets.len() as u32).map(|t| ([t, j], first_whole + e, None)));
    }
    let ok: Vec<AtomicBool> = entries.iter().map(|_| AtomicBool::new(true)).collect();
    let unresolved = AtomicU64::new(0);
    let found_incomplete = Mutex::new(Vec::new());
    let pair_work = |work: &[Work], ok: &[AtomicBool]| {
        par_indices(work.len(), 16, &sums, &ignored, &Mutex::new(Vec::new()), sinks, |w, sums, _, _, sink| {
            let ([t, j], entry, list) = work[w];
            let k = job.params.k_tet as usize;
            let paired = list.map_or(Paired::NONE, |e| Paired { list: &paired, start: e * k, len: k });
            let mut again = LocalPairs::default();
            let (sites, verts, tets) = (&job.sites, &job.verts, &job.tets);
            refine::refine_pair(
                t as usize,
                j as usize,
                paired,
                &job.refine,
                walk,
                sites,
                verts,
                tets,
                faces,
                sums,
                &mut again,
                sink,
            );
            for [t, j] in again.0 {
                if j == INCOMPLETE_TET {
                    found_incomplete.lock().unwrap_or_else(|e| e.into_inner()).push(t);
                } else {
                    unresolved.fetch_add(1, Ordering::Relaxed);
                    ok[entry].store(false, Ordering::Relaxed);
                }
            }
        });
    };
    pair_work(&work, &ok);
    redone.finished += ok.iter().filter(|o| o.load(Ordering::Relaxed)).count() as u64;

    if knn {
        // The certificate: a tet is missing pieces when one of its pieces
        // borders a site not paired with it (found by the kernels and just
        // above), or — a safety net for rounding — when its pieces do not
        // add up to it.
        incomplete.append(&mut found_incomplete.lock().unwrap_or_else(|e| e.into_inner()));
        let inv = 1.0 / job.params.fixed_scale as f64;
        incomplete.extend((0..job.tets.len() as u32).filter(|&t| {
            let v = job.tets[t as usize].map(|i| job.verts[i as usize].to_f64());
            let vol = crate::geom::mesh::signed_volume(v[0], v[1], v[2], v[3]).abs();
            let found = sums[n_site_sums + t as usize].load(Ordering::Relaxed) as f64 * inv;
            (found - vol).abs() > VOLUME_TOLERANCE * vol
        }));
        incomplete.sort_unstable();
        incomplete.dedup();
        let missed: Vec<[u32; 2]> = incomplete.iter().map(|&t| [t, NO_SITE]).collect();
        redone.missed_tets = missed.len() as u64;
        if !missed.is_empty() {
            // Their paired sites' pieces are exact and already counted: add
            // the pieces of the sites that may own part of the tet but were
            // not paired with it.
            let lists = tet_lists(job, &cpu, incomplete.iter().copied())?;
            let k = job.params.k_tet as usize;
            let fill: Vec<Work> = candidate_pairs(job, &grid, &walk, &missed)
                .into_iter()
                .filter(|&([_, j], e)| !lists[e * k..(e + 1) * k].contains(&j))
                .map(|(p, e)| (p, e, None))
                .collect();
            let ok: Vec<AtomicBool> = missed.iter().map(|_| AtomicBool::new(true)).collect();
            pair_work(&fill, &ok);
        }
    }
    redone.unresolved = unresolved.into_inner();
    let all: Vec<i64> = sums.into_iter().map(AtomicI64::into_inner).collect();
    (out.sums, out.tet_volumes, out.faces) = crate::job::clip::split_sums(all, n_site_sums, out.tet_volumes.len());
    Ok(redone)
}

/// A pair to clip on its own: `(tet, site)`, the entry it finishes, and
/// where its tet's paired sites are in the lists (knn pairs only).
type Work = ([u32; 2], usize, Option<usize>);

/// A safety net behind the faces' check: a tet whose pieces miss more than
/// this fraction of its volume is incomplete. The pieces' own rounding
/// stays well below it.
const VOLUME_TOLERANCE: f64 = 1e-4;

/// The sites paired with each of `tets`, `k_tet` per tet: the job's tet
/// k-NN, redone for these tets' (quantized) centroids on the CPU backend
/// in `cpu`, started on first use (most passes have no tet to redo).
fn tet_lists(job: &ClipJob, cpu: &OnceCell<CpuBackend>, tets: impl Iterator<Item = u32>) -> Result<Vec<u32>> {
    let all = &job.tet_knn;
    let queries: Vec<_> = tets.map(|t| job.tet_query(t as usize)).collect();
    if queries.is_empty() {
        return Ok(Vec::new());
    }
    let cpu = match cpu.get() {
        Some(cpu) => cpu,
        None => {
            let started = CpuBackend::new(None)?;
            cpu.get_or_init(|| started)
        }
    };
    let params = KnnParams { n_queries: queries.len() as u32, ..all.params };
    let knn = KnnJob {
        sites: all.sites.clone(),
        queries: queries.into(),
        params,
        method: all.method,
        quantizer: all.quantizer,
        unheld: all.unheld.clone(),
    };
    Ok(cpu.lists(&knn)?.indices)
}

fn centroid(job: &ClipJob, t: usize) -> [f64; 3] {
    let v = job.tets[t].map(|i| job.verts[i as usize].to_f64());
    [0, 1, 2].map(|a| v.iter().map(|p| p[a]).sum::<f64>() / 4.0)
}

/// The pairs of each tet `(t, NO_SITE)` with every site that may own part
/// of it: with `c` the centroid, `r` its distance to the farthest vertex,
/// `s1` the site nearest `c` (in power distance, with weights) at `d1`,
/// any site `s` owning a point `x` of the tet has `|x - x_s|² <= (r +
/// d1)² + w_s - w_1`, so it lies within `r + sqrt((r + d1)² + range -
/// w_1)` of `c` (`d1 + 2r` without weights); and it must beat `s1`
/// somewhere, so the half-space where it does must hold a tet vertex.
fn candidate_pairs(job: &ClipJob, grid: &SiteGrid, walk: &GridWalk, tets: &[[u32; 2]]) -> Vec<([u32; 2], usize)> {
    use rayon::prelude::*;
    let weight = |s: u32| job.sites[s as usize].value();
    let range = job.params.weight_range as f64;
    let per_tet: Vec<Vec<([u32; 2], usize)>> = tets
        .par_iter()
        .enumerate()
        .map(|(e, &[t, _])| {
            let c = centroid(job, t as usize);
            let v = job.tets[t as usize].map(|i| job.verts[i as usize].to_f64());
            let dist = |a: [f64; 3], b: [f64; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt();
            let r = v.iter().map(|&p| dist(p, c)).fold(0.0, f64::max);
            let (nearest, _) = grid.nearest(c);
            let s1 = power_nearest(t as usize, nearest, &job.sites, &job.verts, &job.tets, walk);
            let d1 = grid.dist2(s1, c).sqrt();
            let reach = r + ((r + d1).powi(2) + (range - weight(s1)).max(0.0)).sqrt();
            let mut found = Vec::new();
            grid.within(c, reach * (1.0 + 1e-6) + 1e-9, &mut found);
            found
                .into_iter()
                .filter(|&s| {
                    v.iter().any(|&q| {
                        let (a, b) = (grid.dist2(s, q), grid.dist2(s1, q));
                        let slack = 1e-5 * (a + b + weight(s).abs() + weight(s1).abs()) + 1e-12;
                        a - weight(s) <= b - weight(s1) + slack
                    })
                })
                .map(|s| ([t, s], e))
                .collect()
        })
        .collect();
    per_tet.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{geom::points, ClippedVoronoi, TetMesh};
    use cvd_kernels::abi::ACCUM_PER_SITE;
    use cvd_kernels::clip::NoPieces;

    /// The host pass alone, given every tet as unfinished — half of them
    /// whole (flooded), half as all their pairs (each clipped on its own) —
    /// rebuilds the diagram the kernels compute.
    #[test]
    fn host_pass_alone_rebuilds_the_diagram() {
        let mesh = TetMesh::voxels(4, |i, j, _| i < 2 || j < 2);
        let sites = points::in_mesh(&mesh, 120, 3);
        let cv = ClippedVoronoi::new(&mesh, &sites);
        let cells = cv.compute().unwrap();
        let (job, map, frame) = cv.job().unwrap();
        let (n, n_tets) = (job.params.n_sites as usize, job.tets.len());
        let mut unfinished: Vec<[u32; 2]> = (0..n_tets as u32 / 2).map(|t| [t, NO_SITE]).collect();
        for t in n_tets as u32 / 2..n_tets as u32 {
            unfinished.extend((0..n as u32).map(|j| [t, j]));
        }
        let mut out = ClipOutput {
            sums: vec![0; n * ACCUM_PER_SITE],
            tet_volumes: vec![0; n_tets],
            unfinished,
            ..Default::default()
        };
        let redone = run(&job, &mut out, &Mutex::new(Vec::<NoPieces>::new())).unwrap();
        assert_eq!(redone.unresolved, 0);
        assert_eq!(redone.finished as usize, n_tets / 2 + (n_tets - n_tets / 2) * n);
        let scale = frame.scale.powi(3) / job.params.fixed_scale as f64;
        for (i, m) in map.iter().enumerate() {
            let u = m.unwrap();
            let v = out.sums[u * ACCUM_PER_SITE] as f64 * scale;
            let want = cells.volume[i];
            assert!((v - want).abs() <= 1e-5 * want.max(cells.mesh_volume / n as f64), "site {i}: {v} vs {want}");
        }
    }
}
