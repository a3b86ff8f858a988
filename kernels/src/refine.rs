//! The second pass: every piece or tet the first pass could not finish
//! (security radius not reached within `k_site` neighbours, a full
//! polyhedron or flood queue), redone with room to spare and a complete
//! neighbourhood, on the device or the CPU alike.
//!
//! Instead of a neighbour list, a piece walks the site grid ring by ring
//! around its site, clipping by every site met whose bisector can reach it
//! (the order does not change the result; nearest-first order only makes
//! the first pass stop early). Once the sites not yet met are all farther
//! than twice the piece's farthest vertex, nothing can cut it any more: the
//! piece is exact. So no security radius is ever missed here; only a
//! polyhedron or a flood queue that is still too small leaves an entry
//! unfinished, for the host.

use crate::abi::{GridParams, QuantPoint, RefineParams, INCOMPLETE_TET, NO_SITE};
use crate::buffers::{AtomicSums, PairList};
use crate::clip::{finish_pair, flood, tet_vertices, BisectorRun, Clipped, Paired, PieceSink};
use crate::grid::cell_index;
use crate::knn::sub_floor0;
use crate::polyhedron::{point, Cell, Polyhedron, CELL_PLANES, CELL_VERTS};
use spirv_std::glam::Vec3;

/// Most sites a tet's flood may visit in the second pass.
pub const REFINE_QUEUE: usize = 256;

/// The site grid as a walk sees it: cells, their sites, and where cell
/// (0, 0, 0) lies in the clipping frame.
#[derive(Clone, Copy)]
pub struct GridWalk<'a> {
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
    /// The walk over the grid `cell_start`, `cell_count`, `sorted` that
    /// `p` describes.
    #[inline]
    pub fn new(p: &RefineParams, cell_start: &'a [u32], cell_count: &'a [u32], sorted: &'a [QuantPoint]) -> Self {
        Self {
            grid: p.grid,
            lo: Vec3::new(p.grid_lo_x, p.grid_lo_y, p.grid_lo_z),
            cell_len: p.cell_len,
            margin: p.margin,
            cell_start,
            cell_count,
            sorted,
        }
    }
}

#[inline]
fn xyz(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
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

/// Clips `poly` (relative to site `i`) by the bisectors of every site that
/// can cut it, met by walking the grid ring by ring (see the module's
/// documentation). Never misses the security radius.
#[inline]
pub fn clip_by_grid<const P: usize, const V: usize>(
    poly: &mut Polyhedron<P, V>,
    i: usize,
    sites: &[[f32; 4]],
    w: GridWalk,
) -> Clipped {
    let xi = point(sites[i]);
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
    // A ring walk meets every site: no security radius to miss.
    run.out.security_missed = false;
    let mut r = 0u32;
    loop {
        let z0 = sub_floor0(c[2], r);
        let z1 = if c[2] + r < dims[2] { c[2] + r } else { dims[2] - 1 };
        let y0 = sub_floor0(c[1], r);
        let y1 = if c[1] + r < dims[1] { c[1] + r } else { dims[1] - 1 };
        let x0 = sub_floor0(c[0], r);
        let x1 = if c[0] + r < dims[0] { c[0] + r } else { dims[0] - 1 };
        let mut z = z0;
        while z <= z1 {
            let mut y = y0;
            while y <= y1 {
                let on_shell = z + r == c[2] || z == c[2] + r || y + r == c[1] || y == c[1] + r;
                let mut xc = x0;
                while xc <= x1 {
                    // Inside the shell's y-z extent only the two x ends are new.
                    if on_shell || xc + r == c[0] || xc == c[0] + r {
                        let cell = cell_index(&g, [xc, y, z]);
                        let start = w.cell_start[cell] as usize;
                        let end = start + w.cell_count[cell] as usize;
                        let mut k = start;
                        while k < end {
                            let s = w.sorted[k][3];
                            k += 1;
                            if s as usize == i {
                                continue;
                            }
                            let n = point(sites[s as usize]) - xi;
                            let d2 = n.length_squared();
                            // Beyond twice the farthest vertex, or clear of
                            // the bounding box: the bisector cannot cut.
                            if d2 > 4.0 * run.r2 || run.clears(n, d2) {
                                continue;
                            }
                            if run.clip(poly, n, d2, s) {
                                return run.out;
                            }
                        }
                    }
                    xc += 1;
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

/// Thread `e` of the second pass over the first pass's unfinished list
/// (`list[0]` entries `(tet, site)` from `list[1]`): a whole tet
/// (`site == NO_SITE`, a failed flood) is flooded again from the site
/// nearest its centroid (`tet_sites[(tet - tet_base) * k_tet]`); a pair's piece is
/// clipped on its own and checked against the tet's paired sites; a tet
/// already known to be incomplete is passed on. What fails again, and the
/// incomplete tets, go to `still`.
#[inline]
pub fn refine_entry<A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    e: usize,
    p: &RefineParams,
    w: GridWalk,
    sites: &[[f32; 4]],
    verts: &[[f32; 4]],
    tets: &[[u32; 4]],
    tet_sites: &[u32],
    list: &[u32],
    sums: &mut A,
    counters: &mut C,
    still: &mut L,
    sink: &mut S,
) {
    if e >= list[0] as usize || e >= p.capacity as usize {
        return;
    }
    let t = list[1 + 2 * e] as usize;
    let j = list[2 + 2 * e];
    // The tet's slots in `tet_sites`: its paired sites, nearest first.
    let (k, slot) = (p.clip.k_tet as usize, (t - p.clip.tet_base as usize) * p.clip.k_tet as usize);
    if j == NO_SITE {
        refine_tet::<REFINE_QUEUE, _, _, _, _>(
            t,
            tet_sites[slot],
            p,
            w,
            sites,
            verts,
            tets,
            sums,
            counters,
            still,
            sink,
        );
    } else if j == INCOMPLETE_TET {
        still.push(t as u32, INCOMPLETE_TET);
    } else {
        let paired = Paired::around(tet_sites, slot, k);
        refine_pair(t, j as usize, paired, p, w, sites, verts, tets, sums, still, sink);
    }
}

/// Tet `t` flooded again from site `start`, each piece clipped by a grid
/// walk in a [`Cell`], with room for `Q` sites; listed whole in `still`
/// if even that fails.
#[inline]
pub fn refine_tet<const Q: usize, A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    t: usize,
    start: u32,
    p: &RefineParams,
    w: GridWalk,
    sites: &[[f32; 4]],
    verts: &[[f32; 4]],
    tets: &[[u32; 4]],
    sums: &mut A,
    counters: &mut C,
    still: &mut L,
    sink: &mut S,
) {
    flood::<CELL_PLANES, CELL_VERTS, Q, _, _, _, _, _>(
        t,
        start,
        p.clip.fixed_scale,
        sites,
        verts,
        tets,
        move |j: usize, poly: &mut Cell| clip_by_grid(poly, j, sites, w),
        sums,
        counters,
        still,
        sink,
    );
}

/// Site `j`'s piece of tet `t`, clipped by a grid walk in a [`Cell`];
/// listed in `still` if even that fails (and its tet if it borders a site
/// not `paired` with the tet).
#[inline]
pub fn refine_pair<A: AtomicSums, L: PairList, S: PieceSink>(
    t: usize,
    j: usize,
    paired: Paired,
    p: &RefineParams,
    w: GridWalk,
    sites: &[[f32; 4]],
    verts: &[[f32; 4]],
    tets: &[[u32; 4]],
    sums: &mut A,
    still: &mut L,
    sink: &mut S,
) {
    let mut poly = Cell::empty();
    let tv = tet_vertices(t, verts, tets, xyz(sites[j]));
    poly.set_tetrahedron(tv);
    let c = clip_by_grid(&mut poly, j, sites, w);
    finish_pair(t, j, &poly, &tv, &c, paired, &p.clip, sites, verts, tets, sums, still, sink);
}
