//! k nearest neighbours: the job description shared by the backends.

use crate::error::{Error, Result};
use crate::geom::quantize::Quantizer;
use crate::geom::timing::Timings;
use cvd_kernels::abi::{GridParams, KnnParams, QuantPoint, QUANT_MAX};

/// How the neighbours are searched.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum KnnMethod {
    /// Uniform grid with ring search (paper section 5.2).
    Grid,
    /// Every query against every site (paper section 5.1).
    Brute,
}

impl KnnMethod {
    /// Its name on the command line and in files: `grid`, `brute`.
    pub fn name(self) -> &'static str {
        match self {
            KnnMethod::Grid => "grid",
            KnnMethod::Brute => "brute",
        }
    }
}

/// Target number of sites per grid cell (paper section 5.2).
pub const SITES_PER_CELL: f64 = 5.0;

/// A validated, quantized k-NN job, ready for any backend.
#[derive(Clone, Debug)]
pub struct KnnJob {
    /// Sites, quantized and tagged with their index (shared with the
    /// jobs that search the same sites).
    pub sites: Points,
    /// Query points (the sites themselves, shared, for a site job).
    pub queries: Points,
    /// Kernel parameters (grid, counts, `k` clamped to what exists).
    pub params: KnnParams,
    /// Search method.
    pub method: KnnMethod,
    /// The frame the points were quantized in.
    pub quantizer: Quantizer,
    /// A part's grid cells inside its held box whose sites it does not
    /// hold, one bit per cell of its grid (set: not held); their first slot
    /// is marked [`cvd_kernels::abi::UNHELD`] when the grid is built, so a
    /// walk gives up there. `None`: every cell of the grid is held.
    pub unheld: Option<std::sync::Arc<[u32]>>,
}

/// Quantized points, shared by the jobs that read them (a site job's sites
/// are its queries and the tets' job's sites too).
pub type Points = std::sync::Arc<[QuantPoint]>;

/// The neighbours of every query: `k` per query, nearest first.
#[derive(Clone, Debug, Default)]
pub struct Neighbors {
    /// Neighbours per query (after clamping to the sites that exist).
    pub k: usize,
    /// Site indices, `k` per query.
    pub indices: Vec<u32>,
    /// Squared distances in quantized units, `k` per query.
    pub dist2: Vec<u64>,
    /// Time per phase.
    pub timings: Timings,
}

/// Neighbour lists packed as the clipping kernels read them
/// ([`cvd_kernels::lists`]): `k` entries of `bits` bits per query, each
/// list in whole words; an entry of all ones is `NO_SITE`.
#[derive(Clone, Debug, Default)]
pub struct PackedLists {
    /// The lists' words, [`cvd_kernels::lists::stride`] per query.
    pub words: Vec<u32>,
    /// Entries per list.
    pub k: u32,
    /// Bits per entry (32: plain `u32` entries).
    pub bits: u32,
    /// Time per phase.
    pub timings: Timings,
}

impl PackedLists {
    /// The lists as the kernels read them, as those of queries
    /// `base..base + (the number of lists)`.
    pub fn view(&self, base: u32) -> cvd_kernels::lists::Lists<'_> {
        let words = self.words.len().saturating_sub(cvd_kernels::lists::spare(self.bits));
        let n = words / cvd_kernels::lists::stride(self.k, self.bits).max(1);
        cvd_kernels::lists::Lists::new(&self.words, self.k, self.bits, base, base + n as u32)
    }
}

impl Neighbors {
    /// The neighbours of query `i`.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.indices[i * self.k..(i + 1) * self.k]
    }
}

impl KnnJob {
    /// The `k` nearest other sites of every site.
    pub fn sites(sites: &[[f64; 3]], k: usize, method: KnnMethod) -> Result<Self> {
        let quantizer = Quantizer::fit(&[("site", sites)])?;
        let q: Points = quantizer.quantize_all(sites).into();
        Self::build(q.clone(), q, true, k, method, quantizer)
    }

    /// The `k` nearest other sites of every site, quantized in a frame and
    /// on a grid that also cover `frame` (points the sites may move to).
    pub fn sites_in_frame(sites: &[[f64; 3]], frame: &[[f64; 3]], k: usize, method: KnnMethod) -> Result<Self> {
        let quantizer = Quantizer::fit(&[("site", sites), ("frame point", frame)])?;
        let q: Points = quantizer.quantize_all(sites).into();
        let mut job = Self::build(q.clone(), q, true, k, method, quantizer)?;
        job.params.grid = grid_over(job.sites.iter().chain(&quantizer.quantize_all(frame)), sites.len());
        Ok(job)
    }

    /// The same job over a grid sized for `n` sites in the frame of its
    /// sites and `frame` (a part of a job laid out by its caller searches
    /// the whole job's grid, so that its walks meet the sites in the same
    /// order).
    pub fn with_grid_for(mut self, frame: &[[f64; 3]], n: usize) -> Self {
        let frame = self.quantizer.quantize_all(frame);
        let sites = self.params.grid.n_sites;
        self.params.grid = GridParams { n_sites: sites, ..grid_over(self.sites.iter().chain(&frame), n) };
        self
    }

    /// The same job over the window of its grid that holds its sites,
    /// widened by `pad` cells on every side: the sites' quantized
    /// coordinates shifted by the window's corner (whole cells, so every
    /// distance is the same integer and every site in the same cell), the
    /// grid the window's cells. Returns the window too, or `None` when it
    /// is the whole grid (the job unchanged). A part of a job laid out by
    /// its caller (`with_grid_for`) holds only the sites near it: its
    /// grid's table is then its window's size, not the whole job's, and a
    /// walk that would leave the window gives up instead
    /// (`RefineParams::held_lo_x`).
    pub fn windowed(self, pad: u32) -> (Self, Option<crate::job::held::HeldCells>) {
        let g = self.params.grid;
        if self.sites.is_empty() {
            return (self, None);
        }
        let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
        for s in self.sites.iter() {
            let c = cvd_kernels::grid::cell_coords(&g, [s[0], s[1], s[2]]);
            for a in 0..3 {
                lo[a] = lo[a].min(c[a]);
                hi[a] = hi[a].max(c[a]);
            }
        }
        let window = crate::job::held::HeldCells::around(lo, hi, pad, [g.dim_x, g.dim_y, g.dim_z], g.cell_size);
        if window.is_whole() {
            return (self, None);
        }
        (self.moved_into(window), Some(window))
    }

    /// The same job over the cells `window` of its grid: its sites'
    /// quantized coordinates shifted by the window's corner (whole cells,
    /// so every distance is the same integer and every site in the same
    /// cell), the grid the window's cells.
    fn moved_into(mut self, window: crate::job::held::HeldCells) -> Self {
        let shift = window.shift();
        let moved = |p: &Points| -> Points {
            p.iter().map(|q| [q[0] - shift[0], q[1] - shift[1], q[2] - shift[2], q[3]]).collect::<Vec<_>>().into()
        };
        let shared = std::sync::Arc::ptr_eq(&self.sites, &self.queries);
        self.sites = moved(&self.sites);
        self.queries = if shared { self.sites.clone() } else { moved(&self.queries) };
        self.params.grid = window.grid_params(self.params.grid.n_sites as usize);
        self
    }

    /// The same job over the held cells `held` of its grid (a part that
    /// holds every site of those cells, and only those: each must lie in
    /// them), its sites' quantized coordinates shifted by their corner.
    pub fn windowed_to(self, held: crate::job::held::HeldCells) -> crate::error::Result<Self> {
        let g = self.params.grid;
        if held.grid != [g.dim_x, g.dim_y, g.dim_z] || held.cell_size != g.cell_size {
            return Err(crate::error::Error::Internal(format!("held cells {held:?} of another grid than {g:?}")));
        }
        if let Some(s) = self.sites.iter().find(|s| !held.holds(cvd_kernels::grid::cell_coords(&g, [s[0], s[1], s[2]])))
        {
            return Err(crate::error::Error::Internal(format!("site {} outside the held cells {held:?}", s[3])));
        }
        Ok(self.moved_into(held))
    }

    /// The same job answering only its sites `range`, in index order (a
    /// periodic box's whole cells in parts: the sites of a part).
    pub fn answering(mut self, range: std::ops::Range<usize>) -> Self {
        if self.params.exclude_self != 0 && (range.start > 0 || range.end < self.queries.len()) {
            self.params.query_base = range.start as u32;
            self.params.n_queries = range.len() as u32;
            self.params.in_order = 1;
        }
        self
    }

    /// The `k` nearest sites of every query point, with the sites, frame
    /// and grid of a site job (the queries must lie in its frame).
    pub fn points_like(site_job: &KnnJob, queries: &[[f64; 3]], k: usize) -> Result<Self> {
        let q = site_job.quantizer;
        let mut job =
            Self::build(site_job.sites.clone(), q.quantize_all(queries).into(), false, k, site_job.method, q)?;
        job.params.grid = site_job.params.grid;
        Ok(job)
    }

    /// The `k` nearest sites of every query point.
    pub fn points(sites: &[[f64; 3]], queries: &[[f64; 3]], k: usize, method: KnnMethod) -> Result<Self> {
        let quantizer = Quantizer::fit(&[("site", sites), ("query point", queries)])?;
        let (sites, queries) = (quantizer.quantize_all(sites), quantizer.quantize_all(queries));
        Self::build(sites.into(), queries.into(), false, k, method, quantizer)
    }

    fn build(
        sites: Points,
        queries: Points,
        exclude_self: bool,
        k: usize,
        method: KnnMethod,
        quantizer: Quantizer,
    ) -> Result<Self> {
        if k == 0 {
            return Err(Error::InvalidInput("k must be at least 1".into()));
        }
        // Indices are u32 and NO_SITE is reserved; outputs must be addressable.
        if sites.len() >= u32::MAX as usize || queries.len() >= u32::MAX as usize {
            return Err(Error::InvalidInput(format!(
                "too many points: {} sites, {} queries",
                sites.len(),
                queries.len()
            )));
        }
        let available = if exclude_self { sites.len().saturating_sub(1) } else { sites.len() };
        let k = k.min(available);
        if queries.len().checked_mul(k).is_none_or(|n| n > u32::MAX as usize) {
            return Err(Error::InvalidInput(format!(
                "{} queries x k = {k} neighbours do not fit one buffer",
                queries.len()
            )));
        }
        let params = KnnParams {
            grid: grid_for(&sites),
            n_queries: queries.len() as u32,
            k: k as u32,
            exclude_self: exclude_self as u32,
            query_base: 0,
            in_order: 0,
            local_lists: 0,
            _pad: [0; 2],
        };
        Ok(Self { sites, queries, params, method, quantizer, unheld: None })
    }
}

/// The quantizer and grid of a job laid out over the frame points
/// `frame` (whose bounding box holds every site) for `n` sites: those
/// [`KnnJob::sites_in_frame`] and [`KnnJob::with_grid_for`] give it,
/// known without its sites (a part of a job learns them so).
pub(crate) fn frame_grid(frame: &[[f64; 3]], n: usize) -> Result<(Quantizer, GridParams)> {
    let quantizer = Quantizer::fit(&[("frame point", frame)])?;
    let q = quantizer.quantize_all(frame);
    Ok((quantizer, grid_over(q.iter(), n)))
}

/// A grid with about [`SITES_PER_CELL`] sites per cell over the sites'
/// quantized bounding box (from the frame origin).
pub fn grid_for(sites: &[QuantPoint]) -> GridParams {
    grid_over(sites.iter(), sites.len())
}

/// A grid with about [`SITES_PER_CELL`] of `n_sites` sites per cell over the
/// quantized bounding box of `points` (from the frame origin).
fn grid_over<'a>(points: impl Iterator<Item = &'a QuantPoint>, n_sites: usize) -> GridParams {
    let n = n_sites.max(1) as f64;
    let mut ext = [1u64; 3];
    for s in points {
        for a in 0..3 {
            ext[a] = ext[a].max(s[a] as u64 + 1);
        }
    }
    let volume = ext.iter().map(|&e| e as f64).product::<f64>();
    let mut cell = (volume * SITES_PER_CELL / n).cbrt().ceil().clamp(1.0, QUANT_MAX as f64) as u64;
    let dims = |cell: u64| ext.map(|e| e.div_ceil(cell));
    // Flat or thin point sets make the volume estimate overshoot the cell
    // count: widen the cells until the grid is no bigger than the site count.
    while dims(cell).iter().product::<u64>() > 2 * n as u64 + 64 {
        cell *= 2;
    }
    let d = dims(cell);
    GridParams {
        dim_x: d[0] as u32,
        dim_y: d[1] as u32,
        dim_z: d[2] as u32,
        cell_size: cell as u32,
        n_sites: n_sites as u32,
        n_cells: (d[0] * d[1] * d[2]) as u32,
        _pad: [0; 2],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points;

    fn invalid<T: std::fmt::Debug>(r: Result<T>) -> String {
        match r {
            Err(Error::InvalidInput(m)) => m,
            other => panic!("expected an input error, got {other:?}"),
        }
    }

    #[test]
    fn k_zero_is_refused() {
        let sites = points::uniform(10, 1);
        for m in [KnnMethod::Grid, KnnMethod::Brute] {
            assert!(invalid(KnnJob::sites(&sites, 0, m)).contains("at least 1"));
            assert!(invalid(KnnJob::points(&sites, &sites, 0, m)).contains("at least 1"));
            assert!(invalid(KnnJob::sites_in_frame(&sites, &sites, 0, m)).contains("at least 1"));
        }
        let job = KnnJob::sites(&sites, 3, KnnMethod::Grid).unwrap();
        assert!(invalid(KnnJob::points_like(&job, &sites, 0)).contains("at least 1"));
    }

    #[test]
    fn non_finite_points_are_named() {
        let mut sites = points::uniform(10, 1);
        sites[4][1] = f64::NAN;
        assert!(invalid(KnnJob::sites(&sites, 3, KnnMethod::Grid)).contains("site 4"));
        let good = points::uniform(10, 1);
        let queries = [[0.0, f64::INFINITY, 0.0]];
        assert!(invalid(KnnJob::points(&good, &queries, 3, KnnMethod::Grid)).contains("query point 0"));
        assert!(invalid(KnnJob::sites_in_frame(&good, &queries, 3, KnnMethod::Grid)).contains("frame point 0"));
    }

    #[test]
    fn k_is_clamped_to_the_sites_there_are() {
        let sites = points::uniform(5, 2);
        let job = KnnJob::sites(&sites, 10, KnnMethod::Grid).unwrap();
        assert_eq!((job.params.k, job.params.exclude_self, job.params.n_queries), (4, 1, 5), "a site is not its own");
        let job = KnnJob::points(&sites, &sites[..3], 10, KnnMethod::Brute).unwrap();
        assert_eq!((job.params.k, job.params.exclude_self, job.params.n_queries), (5, 0, 3));
        assert_eq!(KnnJob::sites(&sites, 4, KnnMethod::Grid).unwrap().params.k, 4);
        // One site has no other: k = 0, and the run answers nothing.
        let one = KnnJob::sites(&sites[..1], 3, KnnMethod::Grid).unwrap();
        assert_eq!(one.params.k, 0);
        let cpu = crate::exec::CpuBackend::new(Some(1)).unwrap();
        let nn = one.run(&cpu).unwrap();
        assert_eq!(nn.k, 0);
        assert!(nn.indices.is_empty() && nn.dist2.is_empty());
    }

    #[test]
    fn lists_that_do_not_fit_one_buffer_are_refused() {
        // 70 000 x 69 999 entries > u32::MAX.
        let sites = points::uniform(70_000, 3);
        let m = invalid(KnnJob::sites(&sites, 100_000, KnnMethod::Brute));
        assert!(m.contains("do not fit one buffer"), "{m}");
    }

    /// Each point's grid cell, as the kernels find it.
    fn cell_of(g: &GridParams, p: &QuantPoint) -> [u32; 3] {
        [0, 1, 2].map(|a| p[a] / g.cell_size)
    }

    fn covers(g: &GridParams, pts: &[QuantPoint]) -> bool {
        let dims = [g.dim_x, g.dim_y, g.dim_z];
        pts.iter().all(|p| (0..3).all(|a| cell_of(g, p)[a] < dims[a]))
    }

    #[test]
    fn the_grid_has_about_five_sites_a_cell_and_covers_them() {
        for (n, seed) in [(1, 1), (7, 2), (500, 3), (5000, 4), (40_000, 5)] {
            let job = KnnJob::sites(&points::uniform(n, seed), 8, KnnMethod::Grid).unwrap();
            let g = job.params.grid;
            assert_eq!(g.n_cells, g.dim_x * g.dim_y * g.dim_z);
            assert_eq!(g.n_sites as usize, n);
            assert!(covers(&g, &job.sites), "{n} sites: {g:?}");
            let per_cell = n as f64 / g.n_cells as f64;
            if n >= 500 {
                assert!(
                    (SITES_PER_CELL * 0.7..=SITES_PER_CELL * 2.0).contains(&per_cell),
                    "{n} sites: {per_cell} a cell"
                );
            } else {
                assert!(g.n_cells <= 2, "{n} sites: {g:?}");
            }
        }
    }

    #[test]
    fn flat_and_thin_point_sets_widen_the_cells() {
        let n = 3000;
        let u = points::uniform(n, 6);
        let plane: Vec<[f64; 3]> = u.iter().map(|p| [p[0], p[1], 0.25]).collect();
        let line: Vec<[f64; 3]> = u.iter().map(|p| [p[0], 0.5, 0.5]).collect();
        for (what, pts) in [("plane", plane), ("line", line)] {
            let job = KnnJob::sites(&pts, 8, KnnMethod::Grid).unwrap();
            let g = job.params.grid;
            assert!(g.n_cells as usize <= 2 * n + 64, "{what}: {g:?}");
            assert!(g.n_cells as usize >= n / 40, "{what}: too coarse, {g:?}");
            assert!(covers(&g, &job.sites), "{what}: {g:?}");
            assert_eq!(g.dim_z, 1, "{what}: flat along z");
        }
    }

    #[test]
    fn a_site_job_in_a_frame_covers_the_frame_too() {
        let sites = points::uniform(400, 7);
        let frame = [[-1.0, -1.0, -1.0], [2.0, 2.0, 2.0]];
        let job = KnnJob::sites_in_frame(&sites, &frame, 8, KnnMethod::Grid).unwrap();
        assert_eq!(job.quantizer.origin(), [-1.0; 3]);
        let g = job.params.grid;
        let corner = job.quantizer.quantize_all(&frame);
        assert!(covers(&g, &corner) && covers(&g, &job.sites), "{g:?}");
        assert_eq!(g.n_sites, 400);
        // Cells sized for the sites over the whole frame: 27 times the
        // sites' cube, so about 80 cells over the sites' cube.
        let plain = KnnJob::sites(&sites, 8, KnnMethod::Grid).unwrap();
        assert!(
            g.cell_size as f64 / job.quantizer.scale() > plain.params.grid.cell_size as f64 / plain.quantizer.scale()
        );
        // Point jobs like it share its sites, frame and grid.
        let queries = points::uniform(9, 8);
        let like = KnnJob::points_like(&job, &queries, 500).unwrap();
        assert!(std::sync::Arc::ptr_eq(&like.sites, &job.sites));
        assert_eq!((like.params.grid, like.quantizer, like.method), (g, job.quantizer, job.method));
        assert_eq!((like.params.k, like.params.exclude_self, like.params.n_queries), (400, 0, 9));
        assert_eq!(&like.queries[..], &job.quantizer.quantize_all(&queries)[..]);
    }

    #[test]
    fn neighbours_of_a_query_are_its_slice() {
        let nn = Neighbors { k: 2, indices: vec![5, 6, 7, 8, 9, 10], ..Default::default() };
        assert_eq!((nn.of(0), nn.of(2)), (&[5, 6][..], &[9, 10][..]));
        assert_eq!((KnnMethod::Grid.name(), KnnMethod::Brute.name()), ("grid", "brute"));
    }
}
