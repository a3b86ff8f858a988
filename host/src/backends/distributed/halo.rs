//! A part of a job: some of its tets, and the sites of a box of grid cells
//! around them (the halo), as a job of its own that computes exactly what
//! the whole job computes for those tets, or says that it cannot.
//!
//! The part's sites keep the whole job's order (so ties break alike), its
//! quantized coordinates are the whole job's shifted by whole cells (so
//! every distance is the same integer), and its grid is the whole grid's
//! cells inside the box. Then:
//! * a site's neighbour list is the whole job's when the ball through its
//!   k-th neighbour lies inside the box ([`HeldCells::certifies`]); other
//!   sites get a list marked unknown (`cvd_kernels::lists`), and so does
//!   every site beyond the listed cells (their lists are not computed);
//! * a tet's nearest site, likewise, or [`OUT_OF_HALO`];
//! * a grid walk meets the same sites in the same order as long as it
//!   stays inside the box, and gives up when it must search a cell outside
//!   (`RefineParams::held_lo_x`).
//!
//! A flood that met an unknown list, an uncertified start or a cell
//! outside adds nothing and is listed `(tet, OUT_OF_HALO)`: the caller does
//! that tet again with a wider halo. Every other tet's pieces are clipped
//! by the same planes in the same order as in the whole job, so its sums
//! are the same bits.

use crate::error::{Error, Result};
use crate::exec::{build_grid, CpuGrid};
use crate::job::clip::ClipJob;
use crate::job::held::HeldCells;
use crate::job::knn::KnnJob;
use cvd_kernels::abi::{ClipParams, KnnParams, QuantPoint, RefineParams};
use cvd_kernels::grid::cell_coords;

/// The whole job's sites by grid cell, to find the sites of a box quickly:
/// the site grid the kernels build (each cell's sites in index order).
pub(crate) struct SitesByCell(CpuGrid);

impl SitesByCell {
    pub(crate) fn new(job: &ClipJob) -> Self {
        Self(build_grid(&job.site_knn))
    }

    /// Sites in grid cell `c` (its linear index).
    pub(crate) fn count(&self, c: usize) -> u32 {
        self.0.cell_count[c]
    }

    /// The sites of the held cells, in increasing order.
    fn of(&self, job: &ClipJob, held: &HeldCells) -> Vec<u32> {
        let g = &job.site_knn.params.grid;
        let grid = &self.0;
        let mut found = Vec::new();
        for z in held.lo[2]..held.lo[2] + held.dim[2] {
            for y in held.lo[1]..held.lo[1] + held.dim[1] {
                // A row of cells is one run of the sorted sites.
                let first = cvd_kernels::grid::cell_index(g, [held.lo[0], y, z]);
                let last = first + held.dim[0] as usize - 1;
                let (a, b) = (grid.cell_start[first], grid.cell_start[last] + grid.cell_count[last]);
                found.extend(grid.sorted[a as usize..b as usize].iter().map(|q| q[3]));
            }
        }
        found.sort_unstable();
        found
    }
}

/// The grid cells `lo..=hi` that the vertices of `tets` (the whole job's)
/// fall in.
pub(crate) fn cells_of(job: &ClipJob, tets: &[u32]) -> ([u32; 3], [u32; 3]) {
    let g = &job.site_knn.params.grid;
    let q = &job.site_knn.quantizer;
    let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
    for &t in tets {
        for v in job.tets[t as usize] {
            let x = q.quantize(job.verts[v as usize].to_f64(), 0);
            let c = cell_coords(g, [x[0], x[1], x[2]]);
            for a in 0..3 {
                lo[a] = lo[a].min(c[a]);
                hi[a] = hi[a].max(c[a]);
            }
        }
    }
    (lo, hi)
}

/// The held cells whose sites get neighbour lists: those within a halo of
/// the cells a part's tets overlap (not of their bounding box: a run of
/// tets in Morton order may bend around a corner).
pub(crate) struct ListedCells {
    held: HeldCells,
    /// Per held cell (x fastest).
    mask: Vec<bool>,
}

impl ListedCells {
    /// Every held cell.
    #[cfg(test)]
    pub(crate) fn all(held: HeldCells) -> Self {
        Self { held, mask: vec![true; held.dim.iter().product::<u32>() as usize] }
    }

    /// The held cells within `halo` cells (along each axis) of the cells
    /// the bounding boxes of `tets` overlap.
    pub(crate) fn around(job: &ClipJob, tets: &[u32], held: HeldCells, halo: u32) -> Self {
        let d = held.dim.map(|d| d as usize);
        let index = |c: [usize; 3]| (c[2] * d[1] + c[1]) * d[0] + c[0];
        let mut mask = vec![false; d[0] * d[1] * d[2]];
        for &t in tets {
            let (lo, hi) = cells_of(job, &[t]);
            let lo = [0, 1, 2].map(|a| lo[a].max(held.lo[a]) - held.lo[a]);
            let hi = [0, 1, 2].map(|a| (hi[a].max(held.lo[a]) - held.lo[a]).min(held.dim[a] - 1));
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        mask[index([x as usize, y as usize, z as usize])] = true;
                    }
                }
            }
        }
        // Widened by `halo` along each axis in turn: the cube of cells
        // around each.
        let h = halo as usize;
        for a in 0..3 {
            let before = mask.clone();
            for z in 0..d[2] {
                for y in 0..d[1] {
                    for x in 0..d[0] {
                        let c = [x, y, z];
                        if !before[index(c)] {
                            continue;
                        }
                        for v in c[a].saturating_sub(h)..=(c[a] + h).min(d[a] - 1) {
                            let mut e = c;
                            e[a] = v;
                            mask[index(e)] = true;
                        }
                    }
                }
            }
        }
        Self { held, mask }
    }

    /// Whether grid cell `c` (whole grid coordinates) is listed.
    fn holds(&self, c: [u32; 3]) -> bool {
        let (lo, dim) = (self.held.lo, self.held.dim);
        self.held.holds(c) && self.mask[(((c[2] - lo[2]) * dim[1] + (c[1] - lo[1])) * dim[0] + (c[0] - lo[0])) as usize]
    }
}

/// A part of `job`: its tets `tets` (in the job's order), and the sites
/// of the cells `held`, with neighbour lists for those of `listed` (the
/// rest marked unknown). Returns the part's job and each of its sites'
/// index in `job`.
pub(crate) fn part_job(
    job: &ClipJob,
    by_cell: &SitesByCell,
    tets: &[u32],
    held: HeldCells,
    listed: &ListedCells,
) -> Result<(ClipJob, Vec<u32>)> {
    if job.params.faces_base != 0 {
        return Err(Error::InvalidInput("a job in parts does not sum faces (yet): ask for cells only".into()));
    }
    let sites = by_cell.of(job, &held);
    let shift = held.shift();
    let global = &job.site_knn.params.grid;
    let quant: Vec<QuantPoint> = sites
        .iter()
        .enumerate()
        .map(|(l, &s)| {
            let q = job.site_knn.sites[s as usize];
            [q[0] - shift[0], q[1] - shift[1], q[2] - shift[2], l as u32]
        })
        .collect();
    let queries: Vec<QuantPoint> = sites
        .iter()
        .zip(&quant)
        .filter(|(&s, _)| {
            let q = job.site_knn.sites[s as usize];
            listed.holds(cell_coords(global, [q[0], q[1], q[2]]))
        })
        .map(|(_, &q)| q)
        .collect();
    let grid = held.grid_params(sites.len());
    let quant: crate::job::knn::Points = quant.into();
    let site_knn = KnnJob {
        sites: quant.clone(),
        params: KnnParams {
            grid,
            n_queries: queries.len() as u32,
            // The whole job's k, whatever this part holds.
            k: job.site_knn.params.k,
            exclude_self: 1,
            query_base: 0,
            in_order: 1,
            local_lists: 0,
            _pad: [0; 2],
        },
        queries: queries.into(),
        method: job.site_knn.method,
        quantizer: job.site_knn.quantizer,
        unheld: None,
    };
    let tet_knn = KnnJob {
        sites: quant,
        queries: Vec::new().into(),
        params: KnnParams { grid, n_queries: 0, ..job.tet_knn.params },
        method: job.tet_knn.method,
        quantizer: job.tet_knn.quantizer,
        unheld: None,
    };
    // The part's vertices, in the whole job's order.
    let mut verts: Vec<u32> = tets.iter().flat_map(|&t| job.tets[t as usize]).collect();
    verts.sort_unstable();
    verts.dedup();
    let local = |v: u32| verts.binary_search(&v).map_or(0, |i| i as u32);
    let part_tets: Vec<[u32; 4]> = tets.iter().map(|&t| job.tets[t as usize].map(local)).collect();
    let n = sites.len();
    let mut split: Vec<_> = sites.iter().map(|&s| job.sites[s as usize]).collect();
    if job.sites.len() > job.params.n_sites as usize {
        // Each site's local weight bound, after the sites.
        let base = job.params.n_sites as usize;
        split.extend(sites.iter().map(|&s| job.sites[base + s as usize]));
    }
    let params = ClipParams {
        n_sites: n as u32,
        n_tets: tets.len() as u32,
        tet_base: 0,
        nbr_base: 0,
        nbr_end: n as u32,
        own_lo: 0,
        own_hi: n as u32,
        capacity: 0,
        list_bits: 32,
        ..job.params
    };
    let refine = held.in_refine(RefineParams { clip: params, ..job.refine });
    let part = ClipJob {
        site_knn,
        tet_knn,
        sites: split,
        verts: verts.iter().map(|&v| job.verts[v as usize]).collect(),
        tets: part_tets,
        tet_order: tets.iter().map(|&t| job.tet_order[t as usize]).collect(),
        params,
        refine,
        strategy: job.strategy,
        domain: job.domain.clone(),
        pairing: job.pairing,
        tet_faces: vec![0],
        held: Some(held),
        keep: None,
        face_sites: n as u32,
        only: None,
    };
    Ok((part, sites))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ball_is_certified_inside_the_open_sides_only() {
        // Cells 2..6 of 10 along x, 0..4 of 4 along y and z: only x has
        // cells beyond, on both sides.
        let h = HeldCells { lo: [2, 0, 0], dim: [4, 4, 4], grid: [10, 4, 4], cell_size: 10 };
        assert!(!h.is_whole());
        assert_eq!(h.shift(), [20, 0, 0]);
        // x = 5 of 0..40: 5 from the low side, 35 from the high one.
        assert!(h.certifies([5, 0, 0], 24));
        assert!(!h.certifies([5, 0, 0], 25), "a site at the side's distance may be outside");
        assert!(h.certifies([35, 0, 0], 24));
        assert!(!h.certifies([35, 0, 0], 25));
        // y and z have nothing beyond: any ball there.
        assert!(h.certifies([20, 0, 39], 399));
        assert!(!h.certifies([20, 0, 0], u64::MAX));
        let whole = HeldCells { lo: [0; 3], dim: [10, 4, 4], grid: [10, 4, 4], cell_size: 10 };
        assert!(whole.is_whole() && whole.certifies([0, 0, 0], u64::MAX));
    }

    #[test]
    fn a_box_around_cells_stays_in_the_grid() {
        let h = HeldCells::around([1, 5, 0], [3, 9, 0], 2, [10, 10, 1], 7);
        assert_eq!((h.lo, h.dim), ([0, 3, 0], [6, 7, 1]));
        assert!(h.holds([5, 9, 0]) && !h.holds([6, 9, 0]) && !h.holds([0, 2, 0]));
    }
}

#[cfg(test)]
mod lists_tests {
    use super::*;
    use crate::exec::{build_grid, CpuBackend};
    use crate::{geom::points, ClippedVoronoi, TetMesh};

    /// A part's certified lists are the whole job's; the others are marked
    /// unknown, and so are its tets' uncertified nearest sites.
    #[test]
    fn certified_lists_are_the_whole_jobs() {
        let mesh = TetMesh::cube(12);
        let mut sites = points::in_mesh(&mesh, 9000, 5);
        // Sparse corner: long lists there.
        sites.retain(|p| p[0] > 0.3 || p[1] > 0.3 || p[0] + p[1] > 0.5 || ((p[2] * 1e4) as u64).is_multiple_of(5));
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).job().unwrap();
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let whole = cpu.lists(&job.site_knn).unwrap();
        let by_cell = SitesByCell::new(&job);
        let g = &job.site_knn.params.grid;
        let grid = [g.dim_x, g.dim_y, g.dim_z];
        let (mut certified, mut unknown) = (0, 0);
        for part in 0..4 {
            let n = job.tets.len();
            let tets: Vec<u32> = (n * part / 4..n * (part + 1) / 4).map(|t| t as u32).collect();
            let (lo, hi) = cells_of(&job, &tets);
            let held = HeldCells::around(lo, hi, 2, grid, g.cell_size);
            assert!(!held.is_whole());
            let (p, held_sites) = part_job(&job, &by_cell, &tets, held, &ListedCells::all(held)).unwrap();
            let k = p.site_knn.params.k as usize;
            let built = build_grid(&p.site_knn);
            let (lists, n) = cpu.held_lists(&p.site_knn, held_sites.len(), 32, &built, &held);
            let view = lists.view(0);
            let mut marked = 0;
            for (l, &s) in held_sites.iter().enumerate() {
                if view.unknown(l, l as u32) {
                    marked += 1;
                    continue;
                }
                let mine: Vec<u32> = (0..k).map(|e| held_sites[view.get(l, e) as usize]).collect();
                assert_eq!(mine, whole.of(s as usize), "part {part}: site {s}'s certified list");
            }
            assert_eq!(n as usize + marked, held_sites.len());
            certified += n;
            unknown += marked;
            // The tets' nearest sites, where certified.
            let (starts, _) = cpu.held_lists(&p.tet_knn_job(), tets.len(), 32, &built, &held);
            let all = cpu.lists(&job.tet_knn_job()).unwrap();
            for (l, &t) in tets.iter().enumerate() {
                let s = starts.words[l];
                if s != cvd_kernels::abi::OUT_OF_HALO {
                    assert_eq!(held_sites[s as usize], all.of(t as usize)[0], "part {part}: tet {t}'s nearest site");
                }
            }
        }
        assert!(certified > 0 && unknown > 0, "{certified} certified, {unknown} unknown");
    }
}

#[cfg(test)]
mod walk_tests {
    use super::*;
    use crate::exec::build_grid;
    use crate::{geom::points, ClippedVoronoi, TetMesh};
    use cvd_kernels::walk::{walk_end, walk_rings, GridWalk, RingVisitor};

    /// Every site met within a fixed reach.
    struct Meet {
        reach2: f32,
        met: Vec<u32>,
    }

    impl RingVisitor<()> for Meet {
        fn reach2(&self) -> f32 {
            self.reach2
        }
        fn visit(&mut self, _: &mut (), s: u32) -> bool {
            self.met.push(s);
            false
        }
    }

    /// A part's walk meets the whole job's sites in the whole job's order,
    /// or gives up when its reach leaves the held cells.
    #[test]
    fn a_part_walks_as_the_whole_job_or_gives_up() {
        let mesh = TetMesh::cube(10);
        let sites = points::in_mesh(&mesh, 8000, 3);
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).job().unwrap();
        let g = &job.site_knn.params.grid;
        let grid = [g.dim_x, g.dim_y, g.dim_z];
        let held = HeldCells::around([3; 3], [6, 7, 5], 1, grid, g.cell_size);
        assert!(!held.is_whole());
        let (part, held_sites) = part_job(&job, &SitesByCell::new(&job), &[], held, &ListedCells::all(held)).unwrap();
        let (all, mine) = (build_grid(&job.site_knn), build_grid(&part.site_knn));
        let whole = GridWalk::new(&job.refine, &[], &all.cell_start, &all.cell_count, &all.sorted);
        let walk = GridWalk::new(&part.refine, &[], &mine.cell_start, &mine.cell_count, &mine.sorted);
        let (mut same, mut gave_up) = (0, 0);
        for (l, &s) in held_sites.iter().enumerate().step_by(7) {
            let x = cvd_kernels::polyhedron::point(part.sites[l].hi);
            for reach in [0.02f32, 0.05, 0.1] {
                let mut a = Meet { reach2: reach * reach, met: Vec::new() };
                let mut b = Meet { reach2: reach * reach, met: Vec::new() };
                assert_eq!(walk_rings(&whole, x, &mut a, &mut ()), walk_end::DONE);
                if walk_rings(&walk, x, &mut b, &mut ()) == walk_end::OUT_OF_HALO {
                    gave_up += 1;
                } else {
                    let met: Vec<u32> = b.met.iter().map(|&m| held_sites[m as usize]).collect();
                    assert_eq!(met, a.met, "site {s}, reach {reach}");
                    same += 1;
                }
            }
        }
        assert!(same > 100 && gave_up > 100, "{same} walks as the whole job's, {gave_up} gave up");
    }
}
