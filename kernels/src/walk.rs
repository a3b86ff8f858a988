//! A piece clipped to its site's cell, whatever the neighbour lists hold.
//!
//! A piece is clipped by its site's neighbour list first, nearest first
//! (when the list is bound), so it is small by the time the list runs out;
//! then it walks the site grid ring by ring around its site, clipping by
//! every site met whose bisector can still reach it (the order does not
//! change the result). Once the sites not yet met are all farther than
//! twice the piece's farthest vertex, nothing can cut it any more: the piece
//! is exact. So no security radius is ever missed; only a polyhedron or a
//! flood queue too small leaves a piece unfinished. Most pieces never walk:
//! the list settles them, and a short list trades k-NN time for walks.

use crate::abi::{GridParams, QuantPoint, RefineParams, SplitPoint};
use crate::clip::{clip_by_bisectors, list_in, BisectorRun, Clipped, NO_LIST};
use crate::grid::{cell_index, ring_row, ring_span};
use crate::polyhedron::{between, point, Polyhedron};
use spirv_std::glam::Vec3;

/// What clipping a piece to its cell searches: the sites' neighbour
/// lists, then the site grid — its cells, their sites, and where cell
/// (0, 0, 0) lies in the clipping frame.
#[derive(Clone, Copy)]
pub struct GridWalk<'a> {
    /// The k-NN's lists, `k_site` per site of `nbr_base..nbr_end`
    /// (as [`crate::clip::list_start`] reads them); none when empty.
    pub site_nbrs: &'a [u32],
    /// Entries per list.
    pub k_site: u32,
    /// First site whose list is bound.
    pub nbr_base: u32,
    /// End of the sites whose lists are bound.
    pub nbr_end: u32,
    /// Sites in all.
    pub n_sites: u32,
    /// Cell counts and sizes.
    pub grid: GridParams,
    /// Lower corner of cell (0, 0, 0).
    pub lo: Vec3,
    /// Side of a cell.
    pub cell_len: f32,
    /// How far a site may sit outside its cell.
    pub margin: f32,
    /// First slot of each cell in `sorted`.
    pub cell_start: &'a [u32],
    /// Sites per cell.
    pub cell_count: &'a [u32],
    /// Sites sorted by cell (index in `[3]`).
    pub sorted: &'a [QuantPoint],
}

impl<'a> GridWalk<'a> {
    /// The lists `site_nbrs` (empty: none) and the walk over the grid
    /// `cell_start`, `cell_count`, `sorted` that `p` describes.
    #[inline]
    pub fn new(
        p: &RefineParams,
        site_nbrs: &'a [u32],
        cell_start: &'a [u32],
        cell_count: &'a [u32],
        sorted: &'a [QuantPoint],
    ) -> Self {
        let c = &p.clip;
        Self {
            site_nbrs,
            k_site: c.k_site,
            nbr_base: c.nbr_base,
            nbr_end: if site_nbrs.is_empty() { c.nbr_base } else { c.nbr_end },
            n_sites: c.n_sites,
            grid: p.grid,
            lo: Vec3::new(p.grid_lo_x, p.grid_lo_y, p.grid_lo_z),
            cell_len: p.cell_len,
            margin: p.clip.walk_margin,
            cell_start,
            cell_count,
            sorted,
        }
    }
}

#[inline]
fn cell_of(x: f32, lo: f32, len: f32, dim: u32) -> u32 {
    let c = (x - lo) / len;
    if c <= 0.0 {
        0
    } else if c >= (dim - 1) as f32 {
        dim - 1
    } else {
        c as u32
    }
}

/// The squared distance from `x` to grid cell `c`'s box, less the margin
/// by which a site may sit outside it (0 when that reaches `x`).
#[inline]
fn cell_gap2(w: &GridWalk, x: [f32; 3], c: [u32; 3]) -> f32 {
    let lo = [w.lo.x, w.lo.y, w.lo.z];
    let mut d2 = 0.0;
    let mut a = 0;
    while a < 3 {
        let low = lo[a] + c[a] as f32 * w.cell_len - w.margin;
        let high = low + w.cell_len + 2.0 * w.margin;
        let gap = if x[a] < low {
            low - x[a]
        } else if x[a] > high {
            x[a] - high
        } else {
            0.0
        };
        d2 += gap * gap;
        a += 1;
    }
    d2
}

/// Clips `poly` (relative to site `i`) to site `i`'s cell: by the bisectors
/// of its list, then of the sites met by walking the grid ring by ring
/// (see the module's documentation). Never misses the security radius.
#[inline]
pub fn clip_to_cell<const P: usize, const V: usize>(
    poly: &mut Polyhedron<P, V>,
    i: usize,
    sites: &[SplitPoint],
    w: GridWalk,
) -> Clipped {
    let k = w.k_site as usize;
    let base = list_in(i, w.nbr_base, w.nbr_end, w.k_site);
    let listed = clip_by_bisectors(poly, i, w.n_sites, sites, w.site_nbrs, base, k);
    if !listed.security_missed || listed.overflow || listed.broken {
        return listed;
    }
    let si = sites[i];
    let xi = point(si.hi);
    // Sites clearly nearer than the list's last lie in the list (its
    // distances are exact on the quantized sites, which sit within
    // `margin` of these): clipped already.
    let inner = if base == NO_LIST || k == 0 {
        0.0
    } else {
        let last = w.site_nbrs[base + k - 1] as usize;
        let d = between(&sites[last], &si).length() - 4.0 * w.margin;
        if d > 0.0 {
            d * d
        } else {
            0.0
        }
    };
    let g = w.grid;
    let dims = [g.dim_x, g.dim_y, g.dim_z];
    let c = [
        cell_of(xi.x, w.lo.x, w.cell_len, g.dim_x),
        cell_of(xi.y, w.lo.y, w.cell_len, g.dim_y),
        cell_of(xi.z, w.lo.z, w.cell_len, g.dim_z),
    ];
    let x = [xi.x, xi.y, xi.z];
    let lo = [w.lo.x, w.lo.y, w.lo.z];
    let mut run = BisectorRun::new(poly);
    run.out.clips = listed.clips;
    run.out.walks = 1;
    // A ring walk meets every site: no security radius to miss.
    run.out.security_missed = false;
    let mut r = 0u32;
    loop {
        let (z0, z1) = ring_span(c[2], r, dims[2]);
        let (y0, y1) = ring_span(c[1], r, dims[1]);
        let mut z = z0;
        while z <= z1 {
            let mut y = y0;
            while y <= y1 {
                let (first, last, step) = ring_row(&g, c, r, y, z);
                let mut xc = first;
                while xc <= last {
                    let cell = [xc, y, z];
                    if cell_gap2(&w, x, cell) <= 4.0 * run.r2 {
                        let cell = cell_index(&g, cell);
                        let start = w.cell_start[cell] as usize;
                        let end = start + w.cell_count[cell] as usize;
                        let mut k = start;
                        while k < end {
                            let s = w.sorted[k][3];
                            k += 1;
                            if s as usize == i {
                                continue;
                            }
                            let n = between(&sites[s as usize], &si);
                            let d2 = n.length_squared();
                            // In the list, beyond twice the farthest vertex,
                            // or clear of the bounding box: the bisector
                            // cannot cut. A face already (from the list):
                            // its vertices lie on it, where rounding must
                            // not cut again.
                            if d2 < inner || d2 > 4.0 * run.r2 || run.clears(n, d2) || poly.has_plane_of(s) {
                                continue;
                            }
                            if run.clip(poly, n, d2, s) {
                                return run.out;
                            }
                        }
                    }
                    xc += step;
                }
                y += 1;
            }
            z += 1;
        }
        // Every site not met yet lies outside the box of rings 0..=r.
        let mut gap = f32::INFINITY;
        let mut a = 0;
        while a < 3 {
            if c[a] > r {
                gap = gap.min(x[a] - (lo[a] + (c[a] - r) as f32 * w.cell_len));
            }
            if c[a] + r + 1 < dims[a] {
                gap = gap.min(lo[a] + (c[a] + r + 1) as f32 * w.cell_len - x[a]);
            }
            a += 1;
        }
        if gap == f32::INFINITY {
            // The rings cover the grid: every site was met.
            return run.out;
        }
        let gap = gap - w.margin;
        if gap > 0.0 && gap * gap > 4.0 * run.r2 * (1.0 + 1e-5) {
            return run.out;
        }
        r += 1;
    }
}
