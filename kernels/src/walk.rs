//! A piece clipped to its site's cell, whatever the neighbour lists hold.
//!
//! A piece is clipped by its site's neighbour list first, nearest first
//! (when the list is bound), so it is small by the time the list runs out;
//! then it walks the site grid ring by ring around its site, clipping by
//! every site met whose bisector can still reach it (the order does not
//! change the result). Once the sites not yet met are all beyond the
//! security radius (twice the piece's farthest vertex without weights, see
//! [`crate::cell::reach2`]), nothing can cut it any more: the piece is
//! exact. So no security radius is ever missed; only a polyhedron or a
//! flood queue too small leaves a piece unfinished. Most pieces never walk:
//! the list settles them, and a short list trades k-NN time for walks.

use crate::abi::{GridParams, QuantPoint, RefineParams, SplitPoint, OUT_OF_HALO, UNHELD};
use crate::cell::{clip_by_bisectors, tet_vertices, BisectorRun, Clipped, Slack};
use crate::grid::{ring_row, ring_span};
use crate::lists::{Lists, NO_LIST};
use crate::polyhedron::{between, bisector_offset, bisector_offset_at, point, weight_gap, Point, Polyhedron};
use spirv_std::glam::Vec3;

/// What clipping a piece to its cell searches: the sites' neighbour
/// lists, then the site grid — its cells, their sites, and where cell
/// (0, 0, 0) lies in the clipping frame.
#[derive(Clone, Copy)]
pub struct GridWalk<'a> {
    /// The k-NN's lists, `k_site` per site of `nbr_base..nbr_end`
    /// ([`Lists::of`] the job's parameters); none when empty.
    pub lists: Lists<'a>,
    /// Sites in all.
    pub n_sites: u32,
    /// The power weights' range (0: Voronoi cells; see
    /// [`crate::abi::ClipParams::weight_range`]).
    pub weight_range: f32,
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
    /// The held cells' first cell and extent ([`RefineParams::held_lo_x`]):
    /// `cell_start` and `cell_count` cover them only.
    pub held_lo: [u32; 3],
    /// See `held_lo`.
    pub held_dim: [u32; 3],
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
            lists: Lists::of(c, site_nbrs),
            n_sites: c.n_sites,
            weight_range: c.weight_range,
            grid: p.grid,
            lo: Vec3::new(p.grid_lo_x, p.grid_lo_y, p.grid_lo_z),
            cell_len: p.cell_len,
            margin: p.clip.walk_margin,
            cell_start,
            cell_count,
            sorted,
            held_lo: [p.held_lo_x, p.held_lo_y, p.held_lo_z],
            held_dim: [p.held_dim_x, p.held_dim_y, p.held_dim_z],
        }
    }

    /// The index of grid cell `c` in the held cells' arrays, or
    /// [`NO_CELL`] when its sites are not held (outside the held cells'
    /// box, or inside it and marked [`UNHELD`]).
    #[inline]
    pub fn held_cell(&self, c: [u32; 3]) -> usize {
        let (lo, dim) = (self.held_lo, self.held_dim);
        let mut a = 0;
        while a < 3 {
            if c[a] < lo[a] || c[a] - lo[a] >= dim[a] {
                return NO_CELL;
            }
            a += 1;
        }
        let cell = (((c[2] - lo[2]) as usize * dim[1] as usize) + (c[1] - lo[1]) as usize) * dim[0] as usize
            + (c[0] - lo[0]) as usize;
        if self.cell_count[cell] == 0 && self.cell_start[cell] == UNHELD {
            return NO_CELL;
        }
        cell
    }
}

/// A grid cell whose sites the job does not hold ([`GridWalk::held_cell`]).
pub const NO_CELL: usize = usize::MAX;

/// How a ring walk ([`walk_rings`]) ended.
pub mod walk_end {
    /// Every site within the visitor's reach was met.
    pub const DONE: u32 = 0;
    /// The visitor ended the walk.
    pub const STOPPED: u32 = 1;
    /// A cell within reach is not held (a part of a distributed job): the
    /// walk cannot tell what it holds.
    pub const OUT_OF_HALO: u32 = 2;
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
    let (mut low, mut high) = ([0.0f32; 3], [0.0f32; 3]);
    let mut a = 0;
    while a < 3 {
        low[a] = lo[a] + c[a] as f32 * w.cell_len - w.margin;
        high[a] = low[a] + w.cell_len + 2.0 * w.margin;
        a += 1;
    }
    box_gap2(x, low, high)
}

/// The squared distance from `x` to the box `lo..hi` (0 inside it).
#[inline]
fn box_gap2(x: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let mut d2 = 0.0;
    let mut a = 0;
    while a < 3 {
        let gap = if x[a] < lo[a] {
            lo[a] - x[a]
        } else if x[a] > hi[a] {
            x[a] - hi[a]
        } else {
            0.0
        };
        d2 += gap * gap;
        a += 1;
    }
    d2
}

/// What a ring walk ([`walk_rings`]) does with the sites it meets (and
/// with a `T` it works on, such as a polyhedron), and how far it must go.
/// (The `T` is handed in, not held: a reference to a local in a struct
/// breaks some Vulkan drivers' compilers.)
pub trait RingVisitor<T> {
    /// The squared distance from the walk's centre beyond which no site
    /// matters any more (it may shrink as sites are met).
    fn reach2(&self) -> f32;
    /// Site `s` was met (the centre's own site too, if it has one); true
    /// ends the walk.
    fn visit(&mut self, on: &mut T, s: u32) -> bool;
    /// Whether a site in the box `lo..hi` (the walk's frame) could change
    /// `on` (true unless the visitor can tell: then a walk gives up at a
    /// cell it does not hold).
    #[inline]
    fn may_cut(&self, _on: &T, _lo: [f32; 3], _hi: [f32; 3]) -> bool {
        true
    }
}

/// The most boxes of unheld cells a walk sets aside ([`walk_rings`]):
/// past that, each new cell goes into the box it grows least.
const PENDING: usize = 4;

/// Whether a site in the box `lo..hi` (the polyhedron's frame) could cut
/// `poly`, whose site is at `site` (the same frame): whether some vertex
/// lies nearer the box than its own site (within a thousandth, for
/// rounding). A site cuts a cell only so: the cell is what lies nearer its
/// own site than the other, and the nearer part of a convex cell holds one
/// of its vertices.
#[inline]
pub fn box_may_cut<const P: usize, const V: usize>(
    poly: &Polyhedron<P, V>,
    site: Point,
    lo: [f32; 3],
    hi: [f32; 3],
) -> bool {
    let mut i = 0;
    while i < (poly.n_verts as usize).min(V) {
        let v = poly.verts[i];
        if box_gap2([v.x, v.y, v.z], lo, hi) <= (v - site).length_squared() * (1.0 + 1e-3) {
            return true;
        }
        i += 1;
    }
    false
}

/// The box of grid cells `c0..=c1` in the walk's frame, wider by twice the
/// margin by which a site may sit outside its cell.
#[inline]
fn cells_box(w: &GridWalk, c0: [u32; 3], c1: [u32; 3]) -> ([f32; 3], [f32; 3]) {
    let lo = [w.lo.x, w.lo.y, w.lo.z];
    let (mut a_lo, mut a_hi) = ([0.0f32; 3], [0.0f32; 3]);
    let mut a = 0;
    while a < 3 {
        a_lo[a] = lo[a] + c0[a] as f32 * w.cell_len - 2.0 * w.margin;
        a_hi[a] = lo[a] + (c1[a] + 1) as f32 * w.cell_len + 2.0 * w.margin;
        a += 1;
    }
    (a_lo, a_hi)
}

/// Unheld cells a walk met that its polyhedron could reach then, kept as
/// a few boxes of cells (lower and upper corners) to test against the
/// finished polyhedron ([`walk_rings`]).
struct Pending {
    lo: [[u32; 3]; PENDING],
    hi: [[u32; 3]; PENDING],
    n: usize,
}

impl Pending {
    /// Sets cell `c` aside. When the boxes are full, those no site in
    /// which could cut `on` any more (it only shrinks) go first.
    #[inline]
    fn add<T, R: RingVisitor<T>>(&mut self, w: &GridWalk, visitor: &R, on: &T, c: [u32; 3]) {
        if self.n == PENDING {
            let (mut b, mut kept) = (0, 0);
            while b < PENDING {
                let (lo, hi) = cells_box(w, self.lo[b], self.hi[b]);
                if visitor.may_cut(on, lo, hi) {
                    self.lo[kept] = self.lo[b];
                    self.hi[kept] = self.hi[b];
                    kept += 1;
                }
                b += 1;
            }
            self.n = kept;
        }
        if self.n < PENDING {
            self.lo[self.n] = c;
            self.hi[self.n] = c;
            self.n += 1;
            return;
        }
        // Into the box whose volume (in cells) grows least.
        let (mut best, mut growth) = (0, u64::MAX);
        let mut b = 0;
        while b < PENDING {
            let (mut before, mut after) = (1u64, 1u64);
            let mut a = 0;
            while a < 3 {
                let (l, h) = (self.lo[b][a], self.hi[b][a]);
                before *= (h - l + 1) as u64;
                after *= (h.max(c[a]) - l.min(c[a]) + 1) as u64;
                a += 1;
            }
            if after - before < growth {
                (best, growth) = (b, after - before);
            }
            b += 1;
        }
        let mut a = 0;
        while a < 3 {
            self.lo[best][a] = self.lo[best][a].min(c[a]);
            self.hi[best][a] = self.hi[best][a].max(c[a]);
            a += 1;
        }
    }

    /// How a walk that ended so (`end`) ends with these cells set aside:
    /// given up if a site in one could still cut the visitor's `on`.
    #[inline]
    fn settle<T, R: RingVisitor<T>>(&self, w: &GridWalk, visitor: &R, on: &T, end: u32) -> u32 {
        let mut b = 0;
        while b < self.n {
            let (lo, hi) = cells_box(w, self.lo[b], self.hi[b]);
            if visitor.may_cut(on, lo, hi) {
                return walk_end::OUT_OF_HALO;
            }
            b += 1;
        }
        end
    }
}

/// Walks the site grid ring by ring around `x` (clipping frame), handing
/// [`RingVisitor::visit`] every site of each cell within the visitor's
/// reach, until the sites not met yet all lie beyond it, the rings cover
/// the grid, or the visitor ends the walk. Returns how it ended
/// ([`walk_end`]). A cell within reach that is not held is passed over
/// where no site in it could change what the visitor works on
/// ([`RingVisitor::may_cut`]: then, or when the walk ends — it only
/// shrinks); otherwise the walk gives up ([`walk_end::OUT_OF_HALO`]). A
/// walk over held cells only is the same walk whatever else is held, and
/// the same as over every cell wherever the sites it passed over could
/// not cut.
#[inline]
pub fn walk_rings<T, R: RingVisitor<T>>(w: &GridWalk, x: Point, visitor: &mut R, on: &mut T) -> u32 {
    let g = w.grid;
    let dims = [g.dim_x, g.dim_y, g.dim_z];
    let c = [
        cell_of(x.x, w.lo.x, w.cell_len, g.dim_x),
        cell_of(x.y, w.lo.y, w.cell_len, g.dim_y),
        cell_of(x.z, w.lo.z, w.cell_len, g.dim_z),
    ];
    let x = [x.x, x.y, x.z];
    let lo = [w.lo.x, w.lo.y, w.lo.z];
    let mut r = 0u32;
    let mut pending = Pending { lo: [[0; 3]; PENDING], hi: [[0; 3]; PENDING], n: 0 };
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
                    if cell_gap2(w, x, cell) <= visitor.reach2() {
                        let at = cell;
                        let cell = w.held_cell(at);
                        if cell != NO_CELL {
                            let start = w.cell_start[cell] as usize;
                            let end = start + w.cell_count[cell] as usize;
                            let mut k = start;
                            while k < end {
                                if visitor.visit(on, w.sorted[k][3]) {
                                    return pending.settle(w, visitor, on, walk_end::STOPPED);
                                }
                                k += 1;
                            }
                        } else {
                            let (blo, bhi) = cells_box(w, at, at);
                            if visitor.may_cut(on, blo, bhi) {
                                pending.add(w, visitor, on, at);
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
            return pending.settle(w, visitor, on, walk_end::DONE);
        }
        let gap = gap - w.margin;
        if gap > 0.0 && gap * gap > visitor.reach2() * (1.0 + 1e-5) {
            return pending.settle(w, visitor, on, walk_end::DONE);
        }
        r += 1;
    }
}

/// A polyhedron in a frame away from site `i` ([`clip_in_frame`]),
/// clipped by the bisectors of the sites a ring walk meets.
struct FrameClip<'a> {
    run: BisectorRun,
    i: u32,
    sites: &'a [SplitPoint],
    /// The frame's origin.
    frame: SplitPoint,
    /// Sites farther from site `i` than this (squared) cannot cut.
    reach2: f32,
    /// Power weights: a walk rules out no cell it does not hold.
    weighted: bool,
}

impl<const P: usize, const V: usize> RingVisitor<Polyhedron<P, V>> for FrameClip<'_> {
    #[inline]
    fn reach2(&self) -> f32 {
        self.reach2
    }

    #[inline]
    fn visit(&mut self, poly: &mut Polyhedron<P, V>, s: u32) -> bool {
        if s == self.i {
            return false;
        }
        let si = self.sites[self.i as usize];
        let xs = self.sites[s as usize];
        let n = between(&xs, &si);
        if n.length_squared() > self.reach2 {
            return false;
        }
        let h = bisector_offset_at(&si, &xs, &self.frame);
        if self.run.clears(n, h) {
            return false;
        }
        self.run.clip(poly, n, h, s)
    }

    #[inline]
    fn may_cut(&self, poly: &Polyhedron<P, V>, lo: [f32; 3], hi: [f32; 3]) -> bool {
        // Power cells: a heavy site far off may cut (no region is ruled out).
        if self.weighted {
            return true;
        }
        let f = point(self.frame.hi);
        let site = point(self.sites[self.i as usize].hi) - f;
        box_may_cut(poly, site, [lo[0] - f.x, lo[1] - f.y, lo[2] - f.z], [hi[0] - f.x, hi[1] - f.y, hi[2] - f.z])
    }
}

/// Clips `poly`, in the frame whose origin is `frame` (near the cell, away
/// from site `i`), by the bisectors of every site within `sqrt(reach2)`
/// of site `i` (the security radius of `poly`'s farthest point from the
/// site), their offsets exact relative to their distance from the frame
/// ([`bisector_offset_at`]). The cell comes out as precise relative to
/// its own size as a cell around its site.
#[inline]
pub fn clip_in_frame<const P: usize, const V: usize>(
    poly: &mut Polyhedron<P, V>,
    i: usize,
    sites: &[SplitPoint],
    w: GridWalk,
    frame: &SplitPoint,
    reach2: f32,
) -> Clipped {
    let mut run = BisectorRun::new(poly, Slack::default());
    run.out.walks = 1;
    run.out.security_missed = false;
    let weighted = w.weight_range > 0.0;
    let mut clip = FrameClip { run, i: i as u32, sites, frame: *frame, reach2, weighted };
    if walk_rings(&w, point(sites[i].hi), &mut clip, poly) == walk_end::OUT_OF_HALO {
        clip.run.out.security_missed = true;
        clip.run.out.out_of_halo = true;
    }
    clip.run.out
}

/// A piece clipped by the sites a ring walk meets.
struct CellClip<'a> {
    run: BisectorRun,
    i: u32,
    sites: &'a [SplitPoint],
    /// Sites nearer than this (squared) are in the list, clipped already.
    inner: f32,
    /// Sites farther than this (squared) cannot cut what is wanted of the
    /// piece ([`walk_to_cell`]).
    cap2: f32,
    /// Power weights: a walk rules out no cell it does not hold.
    weighted: bool,
}

impl<const P: usize, const V: usize> RingVisitor<Polyhedron<P, V>> for CellClip<'_> {
    #[inline]
    fn reach2(&self) -> f32 {
        self.run.reach2.min(self.cap2)
    }

    #[inline]
    fn visit(&mut self, poly: &mut Polyhedron<P, V>, s: u32) -> bool {
        if s == self.i {
            return false;
        }
        let si = self.sites[self.i as usize];
        let xs = self.sites[s as usize];
        let n = between(&xs, &si);
        let d2 = n.length_squared();
        let h = bisector_offset(d2, weight_gap(&si, &xs));
        // In the list, beyond the security radius, or clear of the
        // bounding box: the bisector cannot cut. A face already (from the
        // list): its vertices lie on it, where rounding must not cut again.
        if d2 < self.inner || d2 > self.run.reach2.min(self.cap2) || self.run.clears(n, h) || poly.has_plane_of(s) {
            return false;
        }
        self.run.clip(poly, n, h, s)
    }

    #[inline]
    fn may_cut(&self, poly: &Polyhedron<P, V>, lo: [f32; 3], hi: [f32; 3]) -> bool {
        if self.weighted {
            return true;
        }
        // The piece is relative to its site; sites beyond the cap cannot
        // cut what is wanted of it.
        let x = point(self.sites[self.i as usize].hi);
        let (lo, hi) = ([lo[0] - x.x, lo[1] - x.y, lo[2] - x.z], [hi[0] - x.x, hi[1] - x.y, hi[2] - x.z]);
        box_gap2([0.0; 3], lo, hi) <= self.cap2 && box_may_cut(poly, Point::ZERO, lo, hi)
    }
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
    let listed = clip_by_list(poly, i, sites, &w);
    walk_to_cell(poly, i, sites, w, listed, f32::INFINITY)
}

/// Clips `poly` (relative to site `i`) by the bisectors of site `i`'s
/// neighbour list, nearest first ([`clip_by_bisectors`]).
#[inline]
pub fn clip_by_list<const P: usize, const V: usize>(
    poly: &mut Polyhedron<P, V>,
    i: usize,
    sites: &[SplitPoint],
    w: &GridWalk,
) -> Clipped {
    clip_by_bisectors(poly, i, w.n_sites, w.weight_range, sites, &w.lists, w.lists.slot(i))
}

/// Finishes what [`clip_by_list`] left (`listed`): when the list did not
/// reach the security radius, clips `poly` by the sites met walking the
/// grid ring by ring, out to the security radius or to `sqrt(cap2)`,
/// whichever is nearer. With a finite cap the piece is exact only where
/// no site beyond the cap can cut it: within `sqrt(cap2) / 2` of the site
/// for Voronoi cells (what a cell the domain cuts needs of itself: the
/// part its tets can hold).
#[inline]
pub fn walk_to_cell<const P: usize, const V: usize>(
    poly: &mut Polyhedron<P, V>,
    i: usize,
    sites: &[SplitPoint],
    w: GridWalk,
    listed: Clipped,
    cap2: f32,
) -> Clipped {
    if !listed.security_missed || listed.overflow || listed.broken || listed.out_of_halo {
        return listed;
    }
    let k = w.lists.k();
    let slot = w.lists.slot(i);
    let si = sites[i];
    // Sites clearly nearer than the list's last lie in the list (its
    // distances are exact on the quantized sites, which sit within
    // `margin` of these): clipped already.
    let inner = if slot == NO_LIST || k == 0 {
        0.0
    } else {
        let last = w.lists.get(slot, k - 1) as usize;
        let d = between(&sites[last], &si).length() - 4.0 * w.margin;
        if d > 0.0 {
            d * d
        } else {
            0.0
        }
    };
    let mut run = BisectorRun::new(poly, Slack::of(w.weight_range, sites, i, w.n_sites));
    run.out.clips = listed.clips;
    run.out.walks = 1;
    // A ring walk meets every site: no security radius to miss.
    run.out.security_missed = false;
    let weighted = w.weight_range > 0.0;
    let mut clip = CellClip { run, i: i as u32, sites, inner, cap2, weighted };
    if walk_rings(&w, point(si.hi), &mut clip, poly) == walk_end::OUT_OF_HALO {
        clip.run.out.security_missed = true;
        clip.run.out.out_of_halo = true;
    }
    clip.run.out
}

/// The search for the site of smallest power distance to a point.
struct PowerNearest<'a> {
    sites: &'a [SplitPoint],
    /// The point, relative to `origin`'s site.
    c: Point,
    origin: u32,
    best: u32,
    /// `|c - x_best|² - (w_best - w_origin)`.
    power: f32,
    /// Squared radius around `c` beyond which no site beats `best`.
    reach2: f32,
    weight_range: f32,
    n_sites: u32,
}

impl PowerNearest<'_> {
    /// Takes site `s` if its power distance to the point is smaller.
    #[inline]
    fn offer(&mut self, s: u32) {
        let o = &self.sites[self.origin as usize];
        let x = &self.sites[s as usize];
        let d2 = (self.c - between(x, o)).length_squared();
        let q = d2 - weight_gap(x, o);
        if q < self.power {
            self.best = s;
            self.power = q;
            // A site beats s at c only if |c - x_j|² < |c - x_s|² + w_j -
            // w_s: it would cut c, at |c - x_s|, from s's cell.
            let slack = Slack::of(self.weight_range, self.sites, s as usize, self.n_sites);
            self.reach2 = (d2 + slack.at(d2)) * (1.0 + 1e-5);
        }
    }
}

impl RingVisitor<()> for PowerNearest<'_> {
    #[inline]
    fn reach2(&self) -> f32 {
        self.reach2
    }

    #[inline]
    fn visit(&mut self, _: &mut (), s: u32) -> bool {
        self.offer(s);
        false
    }
}

/// The site of smallest power distance `|c - x_j|² - w_j` to tet `t`'s
/// centroid `c`, where a flood of power cells starts (it owns `c`, so its
/// piece is not empty): from `start` (the site nearest `c`), down the
/// neighbour lists while a listed site is nearer, then certified by a ring
/// walk around `c` to `|c - x_best|² + weight_range - w_best`, beyond
/// which no site can be nearer. Without weights, `start` itself.
/// [`OUT_OF_HALO`] when the search needs a list or a cell not held.
#[inline]
pub fn power_nearest(
    t: usize,
    start: u32,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    w: &GridWalk,
) -> u32 {
    if w.weight_range == 0.0 || start == crate::abi::NO_SITE || start == OUT_OF_HALO {
        return start;
    }
    let tv = tet_vertices(t, verts, tets, &sites[start as usize]);
    let c = Point::from((tv[0] + tv[1] + tv[2] + tv[3]) * 0.25);
    let mut search = PowerNearest {
        sites,
        c,
        origin: start,
        best: start,
        power: f32::INFINITY,
        reach2: 0.0,
        weight_range: w.weight_range,
        n_sites: w.n_sites,
    };
    search.offer(start);
    let k = w.lists.k();
    let mut from = NO_LIST as u32;
    let mut steps = 0;
    while search.best != from && steps < 16 {
        from = search.best;
        let slot = w.lists.slot(from as usize);
        if slot != NO_LIST && w.lists.unknown(slot, from) {
            return OUT_OF_HALO;
        }
        if slot != NO_LIST {
            let mut s = 0;
            while s < k {
                let j = w.lists.get(slot, s);
                if j != crate::abi::NO_SITE {
                    search.offer(j);
                }
                s += 1;
            }
        }
        steps += 1;
    }
    if walk_rings(w, point(sites[start as usize].hi) + c, &mut search, &mut ()) == walk_end::OUT_OF_HALO {
        return OUT_OF_HALO;
    }
    search.best
}
