//! Clipped Voronoi cells (paper sections 4 and 6): each tet is paired with
//! sites, and each pair's piece — the site's Voronoi cell inside the tet —
//! is built and integrated, then added to the site's sums.
//!
//! * tet-cell (Algorithm 4): start from the tet, clip by the bisectors of
//!   the site and its neighbours, nearest first, until the security radius.
//! * cell-tet (Algorithms 1 and 2): build each site's Voronoi cell once
//!   ([`voronoi_cell`]), store it, and clip a copy by the tet's 4 faces.
//!
//! A pair whose piece could not be finished (security radius not reached
//! within the neighbour list, capacity overflow, numerical breakdown) adds
//! nothing and is listed in `unfinished`, for a second pass (`refine`) with
//! a complete neighbourhood and more capacity. Flood pairing completes
//! short lists on the spot ([`clip_to_cell`]).
//!
//! Each piece added to a site's sums is also handed to a [`PieceSink`]:
//! nothing on the GPU, the host's piece export on the CPU.
//!
//! Everything is computed relative to the site (the bisector of `x_i` and
//! `x_j` is `n·x <= |n|²/2` with `n = x_j - x_i`), in f32. Power cells
//! shift each bisector by the weights, `n·x <= (|n|² + w_i - w_j)/2`, and
//! widen the security radius ([`reach2`](crate::cell::reach2)); the
//! bisector clips themselves are [`crate::cell`]'s.

use crate::abi::{counter, ClipParams, RefineParams, SplitPoint, ACCUM_PER_SITE, INCOMPLETE_TET, NO_SITE, OUT_OF_HALO};
use crate::buffers::{AtomicSums, OutBuf, PairList};
use crate::cell::{clip_by_bisectors, tet_vertices, Clipped};
use crate::lists::{Lists, NO_LIST};
use crate::polyhedron::{
    between, bisector_offset, made_by_site, normal, weight_gap, Cell, Clip, Moments, Piece, Point, Polyhedron,
    CELL_PLANES, CELL_VERTS, NO_ID, TET_FACE,
};
use crate::walk::{clip_to_cell, power_nearest, GridWalk};
// Also here, where the host names it.
pub use crate::cell::Slack;
use spirv_std::glam::{Vec3, Vec4};
#[cfg(target_arch = "spirv")]
use spirv_std::num_traits::Float;

/// `[f32; 4]` records per stored cell: a header (planes, vertices, status
/// as bits, and the squared radius of the ball around the site where a
/// [`cell_status::SECURITY_MISSED`] cell is exact), the planes, the
/// vertices (position in `xyz`, packed plane triple in the bits of `w`),
/// and the planes' makers (site indices as bits, four per record).
pub const CELL_RECORDS: usize = 1 + CELL_PLANES + CELL_VERTS + CELL_PLANES / 4;

/// Where a stored cell's plane makers start.
const CELL_IDS: usize = 1 + CELL_PLANES + CELL_VERTS;

/// Status of a stored cell (header `z`).
pub mod cell_status {
    /// The security radius was reached (or every site was used).
    pub const COMPLETE: u32 = 0;
    /// The neighbour budget ran out first. The cell is still exact within
    /// half the distance to the last neighbour: no site farther than `2R`
    /// from the site can own a point within `R` of it.
    pub const SECURITY_MISSED: u32 = 1;
    /// The polyhedron overflowed or broke down.
    pub const FAILED: u32 = 2;
}

#[inline]
pub(crate) fn xyz(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
}

/// Whether this dispatch answers for site `j` (`own_lo..own_hi`).
#[inline]
pub(crate) fn owns(p: &ClipParams, j: usize) -> bool {
    j >= p.own_lo as usize && j < p.own_hi as usize
}

/// Sites nearest the tet's centroid that a pair is first tested against.
pub const FILTER_SITES: usize = 8;

/// Whether site `j` can own any point of the tet (vertices `tv`, relative
/// to `x_j`): for each of the first sites `s` of the tet's list, the
/// half-space where `j` is nearer than `s` (in power distance, with
/// weights) must hold a tet vertex (a half-space meets a convex polytope
/// only if it holds one of its vertices). The test keeps a margin, so it
/// never drops a real piece.
#[inline]
fn may_meet(tv: &[Vec3; 4], j: usize, list: usize, p: &ClipParams, sites: &[SplitPoint], tet_sites: &[u32]) -> bool {
    let xj = sites[j];
    let k = p.k_tet as usize;
    let mut f = 0;
    while f < FILTER_SITES && f < k {
        let s = tet_sites[list + f];
        if s != NO_SITE && s as usize != j {
            let xs = Vec3::from(between(&sites[s as usize], &xj));
            // |v|² - w_j <= |v - xs|² - w_s  <=>  2 v·xs <= |xs|² + w_j - w_s
            let limit = 2.0 * bisector_offset(xs.length_squared(), weight_gap(&xj, &sites[s as usize]));
            let slack = 1e-5 * limit + 1e-12;
            let mut any = false;
            let mut v = 0;
            while v < 4 {
                if 2.0 * tv[v].dot(xs) <= limit + slack {
                    any = true;
                }
                v += 1;
            }
            if !any {
                return false;
            }
        }
        f += 1;
    }
    true
}

/// Where the bodies hand their finished pieces: every non-empty piece
/// added to a site's sums is also given here (a sink drops those of zero
/// volume, which add nothing), so that the host can export the diagram
/// computed by the very code that measured it. The GPU entry points pass
/// [`NoPieces`], which compiles to nothing.
pub trait PieceSink {
    /// Site `site`'s non-empty piece of tet `tet`, relative to the site,
    /// with the volume its moments gave the sums (0: the sums took it as no
    /// piece).
    fn piece<const P: usize, const V: usize>(&mut self, tet: u32, site: u32, poly: &Polyhedron<P, V>, volume: f32);
    /// Forgets the pieces of tet `tet` given so far: its flood failed and
    /// the tet is redone whole (by the second pass, through a sink too).
    fn discard_tet(&mut self, tet: u32);
    /// Forgets the pieces of site `site` given so far: its whole cell
    /// failed, and the host finishes the site another way.
    fn discard_site(&mut self, site: u32);
}

/// A sink that keeps nothing (the GPU's, and the CPU's when no pieces are
/// wanted).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoPieces;

impl PieceSink for NoPieces {
    #[inline]
    fn piece<const P: usize, const V: usize>(&mut self, _tet: u32, _site: u32, _poly: &Polyhedron<P, V>, _volume: f32) {
    }
    #[inline]
    fn discard_tet(&mut self, _tet: u32) {}
    #[inline]
    fn discard_site(&mut self, _site: u32) {}
}

/// `x * scale` rounded to the nearest integer (unbiased: the sums of many
/// pieces drift by the square root of their number, not by it).
#[inline]
fn fixed(x: f32, scale: f32) -> i64 {
    let y = x * scale;
    (if y < 0.0 { y - 0.5 } else { y + 0.5 }) as i64
}

/// Adds a piece's integrals to site `j`'s sums, in fixed point.
#[inline]
pub fn accumulate<A: AtomicSums>(j: usize, m: &Moments, scale: f32, sums: &mut A) {
    let mut total = [0i64; ACCUM_PER_SITE];
    add_fixed(&mut total, m, scale);
    accumulate_fixed(j, &total, sums);
}

/// Adds a piece's integrals to `total`, in fixed point, each rounded as
/// [`accumulate`] rounds it: a thread summing many pieces of one site (a
/// cell cut by its tets) sums them exactly, not in f32.
#[inline]
pub fn add_fixed(total: &mut [i64; ACCUM_PER_SITE], m: &Moments, scale: f32) {
    total[0] += fixed(m.volume, scale);
    total[1] += fixed(m.first.x, scale);
    total[2] += fixed(m.first.y, scale);
    total[3] += fixed(m.first.z, scale);
    total[4] += fixed(m.second, scale);
}

/// Adds `total` (fixed point, [`add_fixed`]) to site `j`'s sums.
#[inline]
pub fn accumulate_fixed<A: AtomicSums>(j: usize, total: &[i64; ACCUM_PER_SITE], sums: &mut A) {
    let base = j * ACCUM_PER_SITE;
    let mut k = 0;
    while k < ACCUM_PER_SITE {
        sums.add(base + k, total[k]);
        k += 1;
    }
}

/// Spill slots per site for faces made by sites outside its list (a grid
/// walk found them): `(maker + 1, area)` pairs, each claimed by one maker.
pub const FACE_SPILLS: usize = 8;

/// Sums per site of the faces' region after its `k_site` neighbour slots:
/// the area on the domain's boundary, the area of faces made by sites
/// neither in the list nor in a spill slot (the host finishes those
/// sites), the boundary's area vector `∫ n dA` (outward, x, y, z), then the
/// [`FACE_SPILLS`] spill pairs.
pub const FACE_SUMS_EXTRA: usize = 5 + 2 * FACE_SPILLS;

/// What [`add_faces`] reads: each site's neighbour list (`site_nbrs`, as
/// for the clips, read as [`Lists::of`] the job's parameters) and, per tet, which faces lie on the domain's boundary
/// (`tet_faces`: 4 bits per tet, 8 tets per word, bit `f` for the face
/// opposite vertex `f`).
#[derive(Clone, Copy)]
pub struct FaceInputs<'a> {
    /// The neighbour lists of sites `nbr_base..nbr_end`.
    pub site_nbrs: &'a [u32],
    /// The boundary bits of every tet.
    pub tet_faces: &'a [u32],
}

/// Adds the faces of site `j`'s piece of tet `t` (their `areas` by plane,
/// from [`piece_moments`] or [`Polyhedron::face_areas`]) to the site's face sums
/// (`sign` = 1), or takes them back (`-1`), when `p.faces_base` is not 0:
/// from `faces_base + (j - faces_first) * (k_site + FACE_SUMS_EXTRA)`
/// (nothing for a site before `faces_first`), the area shared with
/// each neighbour of the site's list (the bisector face that neighbour
/// made), then the area on the domain's boundary (the faces of the tet
/// flagged in `tet_faces`), the area of bisector faces made by sites
/// outside the list and in no spill slot, the boundary's area vector, and
/// the spill slots ([`FACE_SUMS_EXTRA`]). Internal faces of the mesh add
/// nothing: the pieces on either side belong to the same cell.
#[inline]
pub fn add_faces<const P: usize, const V: usize, A: AtomicSums>(
    j: usize,
    t: usize,
    poly: &Polyhedron<P, V>,
    areas: &[f32; P],
    p: &ClipParams,
    inputs: FaceInputs,
    sign: i64,
    sums: &mut A,
) {
    if p.faces_base == 0 || j < p.faces_first as usize {
        return;
    }
    let k = p.k_site as usize;
    let base = p.faces_base as usize + (j - p.faces_first as usize) * (k + FACE_SUMS_EXTRA);
    let lists = Lists::of(p, inputs.site_nbrs);
    let list = lists.slot(j);
    let boundary = inputs.tet_faces[t / 8] >> (4 * (t % 8));
    let mut q = 0;
    while q < (poly.n_planes as usize).min(P) {
        let area = areas[q];
        let id = poly.ids[q];
        if area != 0.0 {
            let a = sign * fixed(area, p.area_scale);
            if made_by_site(id) {
                let mut slot = k + 1;
                // Without the site's list (the host's pass has none), the
                // face goes to a spill slot or is summed apart.
                if list != NO_LIST {
                    let mut s = 0;
                    while s < k {
                        if lists.get(list, s) == id {
                            slot = s;
                            s = k;
                        }
                        s += 1;
                    }
                }
                if slot == k + 1 {
                    let mut spill = 0;
                    while spill < FACE_SPILLS {
                        let key = base + k + 5 + 2 * spill;
                        if sums.claim(key, id as i64 + 1) {
                            slot = k + 6 + 2 * spill;
                            spill = FACE_SPILLS;
                        }
                        spill += 1;
                    }
                }
                sums.add(base + slot, a);
            } else if (TET_FACE..NO_ID).contains(&id) && (boundary >> (id - TET_FACE)) & 1 != 0 {
                sums.add(base + k, a);
                // The face's outward unit normal (a tet's face faces out
                // of it, and a boundary face out of the domain).
                let n = normal(poly.planes[q]);
                let scale = sign as f32 * area / n.length();
                sums.add(base + k + 2, fixed(n.x * scale, p.area_scale));
                sums.add(base + k + 3, fixed(n.y * scale, p.area_scale));
                sums.add(base + k + 4, fixed(n.z * scale, p.area_scale));
            }
        }
        q += 1;
    }
}

/// The sites paired with a tet (knn pairing): `list[start..start + len]`,
/// nearest the tet's centroid first. `len == 0`: no list to check against
/// (the pair's site was found otherwise).
#[derive(Clone, Copy)]
pub struct Paired<'a> {
    /// The buffer holding the list.
    pub list: &'a [u32],
    /// Where the tet's list starts.
    pub start: usize,
    /// Its length, `k_tet`.
    pub len: usize,
}

impl<'a> Paired<'a> {
    /// No list: the pair is not checked.
    pub const NONE: Paired<'static> = Paired { list: &[], start: 0, len: 0 };

    /// The list of the tet whose paired sites hold slot `slot` of
    /// `tet_sites`, `k_tet` slots per tet.
    #[inline]
    pub fn around(tet_sites: &'a [u32], slot: usize, k_tet: usize) -> Self {
        Paired { list: tet_sites, start: slot - slot % k_tet, len: k_tet }
    }

    /// Whether site `s` is in the list.
    #[inline]
    fn holds(&self, s: u32) -> bool {
        let mut i = 0;
        while i < self.len {
            if self.list[self.start + i] == s {
                return true;
            }
            i += 1;
        }
        false
    }
}

/// Whether a face of `poly` — site `j`'s piece of the tet with vertices
/// `tv`, both relative to the site — was made by a site not in `paired`.
/// The pieces of the paired sites are exact; if they leave part of the tet
/// uncovered, that part borders one of them across a face made by a site
/// that is not paired: this finds every tet knn pairing got wrong, however
/// small the missing part. The list is the `len` sites nearest the
/// centroid: a site clearly nearer than the last is in it, one clearly
/// farther is not, and only the few in between are looked up.
#[inline]
fn borders_unpaired<const P: usize, const V: usize>(
    poly: &Polyhedron<P, V>,
    j: usize,
    tv: &[Vec3; 4],
    sites: &[SplitPoint],
    paired: Paired,
) -> bool {
    if paired.len == 0 {
        return false;
    }
    let last = paired.list[paired.start + paired.len - 1];
    if last == NO_SITE {
        // Fewer sites than slots: every site is paired.
        return false;
    }
    // The centroid, relative to the site.
    let c = (tv[0] + tv[1] + tv[2] + tv[3]) * 0.25;
    let xj = sites[j];
    let reach = (Vec3::from(between(&sites[last as usize], &xj)) - c).length();
    let band = 1e-4 * reach + 1e-6;
    let faces = poly.face_mask();
    let mut q = 0;
    while q < poly.n_planes as usize {
        let id = poly.ids[q];
        if (faces >> q) & 1 != 0 && made_by_site(id) {
            let d = (Vec3::from(between(&sites[id as usize], &xj)) - c).length();
            if d > reach + band || (d >= reach - band && !paired.holds(id)) {
                return true;
            }
        }
        q += 1;
    }
    false
}

/// Ends a pair (tet `t`, site `j`, tet vertices `tv` relative to the site)
/// whose clipping went as `c` says: a finished non-empty piece is added to
/// its site's sums and its tet's volume and handed to `sink`; an
/// unfinished one is listed in `unfinished`, and so is the tet, as
/// `(t, INCOMPLETE_TET)`, when the piece borders a site not `paired` with
/// it. Returns whether a piece was added.
#[inline]
pub fn finish_pair<const P: usize, const V: usize, A: AtomicSums, L: PairList, S: PieceSink>(
    t: usize,
    j: usize,
    poly: &Polyhedron<P, V>,
    tv: &[Vec3; 4],
    c: &Clipped,
    paired: Paired,
    p: &ClipParams,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    faces: FaceInputs,
    sums: &mut A,
    unfinished: &mut L,
    sink: &mut S,
) -> bool {
    if !c.finished() {
        unfinished.push(t as u32, j as u32);
        return false;
    }
    if poly.is_empty() {
        return false;
    }
    let mut areas = [0.0f32; P];
    let (m, volume) = piece_moments(poly, t, verts, tets, tv, face_sums_of(p), &mut areas);
    accumulate(j, &m, p.fixed_scale, sums);
    add_faces(j, t, poly, &areas, p, faces, 1, sums);
    add_tet_volume(t, p.n_sites, volume, p.fixed_scale, sums);
    sink.piece(t as u32, j as u32, poly, m.volume);
    if borders_unpaired(poly, j, tv, sites, paired) {
        unfinished.push(t as u32, INCOMPLETE_TET);
    }
    true
}

/// Adds a piece's plain volume to its tet's sum, kept after the sites'
/// sums (at `n_sites * ACCUM_PER_SITE + t`): the safety net behind knn
/// pairing's certificate by faces. The pieces of the sites paired with a
/// tet are exact; if they do not add up to the tet, a site that owns part
/// of it was not paired, and the host adds the missing pieces.
#[inline]
pub fn add_tet_volume<A: AtomicSums>(t: usize, n_sites: u32, volume: f32, scale: f32, sums: &mut A) {
    sums.add(n_sites as usize * ACCUM_PER_SITE + t, fixed(volume, scale));
}

/// What [`piece_moments`] gives of a piece's faces: nothing, their areas,
/// or their masses under the density ([`ClipParams::face_masses`]).
pub mod face_sums {
    /// No faces.
    pub const NONE: u32 = 0;
    /// Each face's area.
    pub const AREAS: u32 = 1;
    /// Each face's area times the piece's mean density.
    pub const MASSES: u32 = 2;
}

/// What the clipping kernels sum of each piece's faces under `p`
/// ([`face_sums`]).
#[inline]
pub fn face_sums_of(p: &ClipParams) -> u32 {
    if p.faces_base == 0 {
        face_sums::NONE
    } else if p.face_masses != 0 {
        face_sums::MASSES
    } else {
        face_sums::AREAS
    }
}

/// The integrals of a piece of tet `t` (vertices `tv`, relative to the
/// piece's site) under the mesh's density — the `w` of each vertex record,
/// linear inside the tet; 1 everywhere without a density — and its plain
/// volume; with `faces` ([`face_sums`]) its faces' areas or masses, into
/// `areas`.
#[inline]
pub fn piece_moments<const P: usize, const V: usize>(
    poly: &Polyhedron<P, V>,
    t: usize,
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    tv: &[Vec3; 4],
    faces: u32,
    areas: &mut [f32; P],
) -> (Moments, f32) {
    let with_areas = faces != face_sums::NONE;
    let tet = tets[t];
    let r = [
        verts[tet[0] as usize].hi[3],
        verts[tet[1] as usize].hi[3],
        verts[tet[2] as usize].hi[3],
        verts[tet[3] as usize].hi[3],
    ];
    if r[0] == r[1] && r[1] == r[2] && r[2] == r[3] {
        let m = if with_areas { poly.moments_and_areas(areas) } else { poly.moments() };
        if faces == face_sums::MASSES {
            scale_all(areas, r[0]);
        }
        let scaled = Moments { volume: m.volume * r[0], first: m.first * r[0], second: m.second * r[0] };
        return (scaled, m.volume);
    }
    // The gradient g with (tv[k] - tv[0])·g = r[k] - r[0], and the density
    // at the site.
    let (e1, e2, e3) = (tv[1] - tv[0], tv[2] - tv[0], tv[3] - tv[0]);
    let det = e1.dot(e2.cross(e3));
    let g = (e2.cross(e3) * (r[1] - r[0]) + e3.cross(e1) * (r[2] - r[0]) + e1.cross(e2) * (r[3] - r[0])) / det;
    if with_areas {
        *areas = poly.face_areas();
    }
    let (m, volume) = poly.moments_linear(r[0] - g.dot(tv[0]), g);
    if faces == face_sums::MASSES && volume > 0.0 {
        scale_all(areas, m.volume / volume);
    }
    (m, volume)
}

/// Every entry of `a` times `k`.
#[inline]
fn scale_all<const P: usize>(a: &mut [f32; P], k: f32) {
    let mut q = 0;
    while q < P {
        a[q] *= k;
        q += 1;
    }
}

#[inline]
pub(crate) fn count<C: AtomicSums>(counters: &mut C, pieces: i64, nonempty: i64, c: &Clipped) {
    counters.add(counter::PAIRS, pieces);
    counters.add(counter::NONEMPTY, nonempty);
    counters.add(counter::CLIPS, c.clips);
    counters.add(counter::WALKS, c.walks);
    if c.security_missed {
        counters.add(counter::SECURITY_MISSED, 1);
    }
    if c.overflow {
        counters.add(counter::OVERFLOWS, 1);
    }
    if c.broken {
        counters.add(counter::BROKEN, 1);
    }
    if c.out_of_halo {
        counters.add(counter::HALO, 1);
    }
}

/// The tet and site of thread `pair` (knn pairing), with the tet's
/// vertices relative to the site in `tv`; the site is `NO_SITE` when there
/// is nothing to do (out of range, an empty slot, or dropped — and counted
/// — by the half-space test).
#[inline]
fn open_pair<C: AtomicSums>(
    i: usize,
    p: &ClipParams,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    tet_sites: &[u32],
    tv: &mut [Vec3; 4],
    counters: &mut C,
) -> (usize, usize) {
    let none = (0, NO_SITE as usize);
    let k = p.k_tet as usize;
    let pair = p.tet_base as usize * k + i;
    if pair >= p.n_tets as usize * k {
        return none;
    }
    let t = pair / k;
    let j = tet_sites[i];
    if j == NO_SITE || !owns(p, j as usize) {
        return none;
    }
    let j = j as usize;
    *tv = tet_vertices(t, verts, tets, &sites[j]);
    if !may_meet(tv, j, i - i % k, p, sites, tet_sites) {
        counters.add(counter::PAIRS, 1);
        counters.add(counter::FILTERED, 1);
        return none;
    }
    (t, j)
}

/// Thread `i` of the tet-cell strategy (Algorithm 4): pair `tet_base *
/// k_tet + i`, of tet `pair / k_tet` and its paired site `pair % k_tet`.
#[inline]
pub fn tet_cell_pair<A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    i: usize,
    p: &ClipParams,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    tet_sites: &[u32],
    site_nbrs: &[u32],
    tet_faces: &[u32],
    sums: &mut A,
    counters: &mut C,
    unfinished: &mut L,
    sink: &mut S,
) {
    let mut tv = [Vec3::ZERO; 4];
    let (t, j) = open_pair(i, p, sites, verts, tets, tet_sites, &mut tv, counters);
    if j == NO_SITE as usize {
        return;
    }
    let mut poly = Piece::tetrahedron(tv);
    let lists = Lists::of(p, site_nbrs);
    let c = clip_by_bisectors(&mut poly, j, p.n_sites, p.weight_range, sites, &lists, lists.slot(j));
    let paired = Paired::around(tet_sites, i, p.k_tet as usize);
    let faces = FaceInputs { site_nbrs, tet_faces };
    let nonempty = finish_pair(t, j, &poly, &tv, &c, paired, p, sites, verts, tets, faces, sums, unfinished, sink);
    count(counters, 1, nonempty as i64, &c);
}

/// Thread `i` of Algorithm 1: the Voronoi cell of site `i` inside the
/// bounding box, stored at records `i * CELL_RECORDS..` of `cells`.
#[inline]
pub fn voronoi_cell<O: OutBuf<[f32; 4]> + ?Sized, C: AtomicSums>(
    i: usize,
    p: &ClipParams,
    sites: &[SplitPoint],
    site_nbrs: &[u32],
    cells: &mut O,
    counters: &mut C,
) {
    if i >= p.n_sites as usize || !owns(p, i) {
        return;
    }
    let xi = xyz(sites[i].hi) + xyz(sites[i].lo);
    let lo = Vec3::new(p.box_lo_x, p.box_lo_y, p.box_lo_z) - xi;
    let hi = Vec3::new(p.box_hi_x, p.box_hi_y, p.box_hi_z) - xi;
    let mut poly = Cell::cuboid(lo, hi);
    let k = p.k_site as usize;
    let lists = Lists::of(p, site_nbrs);
    let slot = lists.slot(i);
    let c = clip_by_bisectors(&mut poly, i, p.n_sites, p.weight_range, sites, &lists, slot);
    let status = if c.overflow || c.broken {
        cell_status::FAILED
    } else if c.security_missed {
        cell_status::SECURITY_MISSED
    } else {
        cell_status::COMPLETE
    };
    // Where a cell that missed its security radius is exact: within `R`
    // of its site, where `R + sqrt(R² + slack)` is the distance `D` to its
    // k-th neighbour (`cell::reach2`): `R = (D² - slack) / 2D`, half the
    // distance without weights (with a margin for rounding).
    let mut exact_r2 = 0.0;
    if status == cell_status::SECURITY_MISSED && k > 0 && slot != NO_LIST {
        let last = lists.get(slot, k - 1);
        if last != NO_SITE {
            let d2 = between(&sites[last as usize], &sites[i]).length_squared();
            let slack = Slack::of(p.weight_range, sites, i, p.n_sites);
            // The ball of exactness a bound gives.
            let ball = |slack: f32| {
                if slack <= 0.0 {
                    0.2499 * d2
                } else if d2 > slack {
                    let r = (d2 - slack) / (2.0 * d2.sqrt());
                    0.9996 * r * r
                } else {
                    0.0
                }
            };
            // The largest ball certified: the global bound's, or a local
            // bound's when its ball lies within that bound's cap.
            exact_r2 = ball(slack.global);
            let mut c = 3;
            while c > 0 {
                c -= 1;
                let r2 = ball(slack.local[c]);
                if r2 <= slack.caps[c] && r2 > exact_r2 {
                    exact_r2 = r2;
                }
            }
        }
    }
    let base = i * CELL_RECORDS;
    let header = [f32::from_bits(poly.n_planes), f32::from_bits(poly.n_verts), f32::from_bits(status), exact_r2];
    cells.write(base, header);
    let mut q = 0;
    while q < poly.n_planes as usize {
        let pl = poly.planes[q];
        cells.write(base + 1 + q, [pl.x, pl.y, pl.z, pl.w]);
        q += 1;
    }
    let mut v = 0;
    while v < poly.n_verts as usize {
        let x = poly.verts[v];
        cells.write(base + 1 + CELL_PLANES + v, [x.x, x.y, x.z, f32::from_bits(poly.tris[v])]);
        v += 1;
    }
    let mut q = 0;
    while q < poly.n_planes as usize {
        let ids = [poly.ids[q], poly.ids[q + 1], poly.ids[q + 2], poly.ids[q + 3]];
        let record = [f32::from_bits(ids[0]), f32::from_bits(ids[1]), f32::from_bits(ids[2]), f32::from_bits(ids[3])];
        cells.write(base + CELL_IDS + q / 4, record);
        q += 4;
    }
    count(counters, 0, 0, &c);
}

/// Thread `i` of the cell-tet strategy (Algorithm 2): pair `tet_base *
/// k_tet + i`, site `j`'s stored cell clipped by the 4 faces of its tet.
#[inline]
pub fn cell_tet_pair<A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    i: usize,
    p: &ClipParams,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    tet_sites: &[u32],
    cells: &[[f32; 4]],
    site_nbrs: &[u32],
    tet_faces: &[u32],
    sums: &mut A,
    counters: &mut C,
    unfinished: &mut L,
    sink: &mut S,
) {
    let mut tv = [Vec3::ZERO; 4];
    let (t, j) = open_pair(i, p, sites, verts, tets, tet_sites, &mut tv, counters);
    if j == NO_SITE as usize {
        return;
    }
    let base = j * CELL_RECORDS;
    let header = cells[base];
    // A cell that missed its security radius is exact within a ball
    // around its site: a tet inside that ball gets its piece from it.
    let status = header[2].to_bits();
    let usable =
        status == cell_status::COMPLETE || (status == cell_status::SECURITY_MISSED && inside_ball(&tv, header[3]));
    if !usable {
        // Counted when the cell was built; its pieces are left to the
        // second pass.
        counters.add(counter::PAIRS, 1);
        unfinished.push(t as u32, j as u32);
        return;
    }
    let mut poly = Cell::empty();
    poly.n_planes = header[0].to_bits();
    poly.n_verts = header[1].to_bits();
    let mut q = 0;
    while q < poly.n_planes as usize {
        let r = cells[base + 1 + q];
        poly.planes[q] = Vec4::new(r[0], r[1], r[2], r[3]);
        q += 1;
    }
    let mut v = 0;
    while v < poly.n_verts as usize {
        let r = cells[base + 1 + CELL_PLANES + v];
        poly.verts[v] = Point::new(r[0], r[1], r[2]);
        poly.tris[v] = r[3].to_bits();
        v += 1;
    }
    let mut q = 0;
    while q < poly.n_planes as usize {
        let r = cells[base + CELL_IDS + q / 4];
        poly.ids[q] = r[0].to_bits();
        poly.ids[q + 1] = r[1].to_bits();
        poly.ids[q + 2] = r[2].to_bits();
        poly.ids[q + 3] = r[3].to_bits();
        q += 4;
    }
    let faces = Piece::tetrahedron(tv);
    let mut c = Clipped::default();
    let mut f = 0;
    while f < 4 && !poly.is_empty() {
        match poly.clip_as(faces.planes[f], TET_FACE + f as u32) {
            Clip::Cut | Clip::Empty => c.clips += 1,
            Clip::Unchanged => {}
            Clip::Overflow => c.overflow = true,
            Clip::Broken => c.broken = true,
        }
        if c.overflow || c.broken {
            break;
        }
        f += 1;
    }
    let paired = Paired::around(tet_sites, i, p.k_tet as usize);
    let faces = FaceInputs { site_nbrs, tet_faces };
    let nonempty = finish_pair(t, j, &poly, &tv, &c, paired, p, sites, verts, tets, faces, sums, unfinished, sink);
    count(counters, 1, nonempty as i64, &c);
}

/// Whether every vertex of `tv` is nearer the origin than `sqrt(r2)`.
#[inline]
fn inside_ball(tv: &[Vec3; 4], r2: f32) -> bool {
    let mut v = 0;
    while v < 4 {
        if tv[v].length_squared() >= r2 {
            return false;
        }
        v += 1;
    }
    true
}

/// Most sites one tet's flood can visit in the kernel; more sends the tet
/// to the second pass.
pub const FLOOD_CAP: usize = 32;

/// Thread `i` of flood pairing (tet-cell): tet `t = tet_base + i`,
/// [`flood`] from the site nearest its centroid (`tet_sites[i]`, a 1-NN
/// list; with weights, the site of smallest power distance, found from it
/// by [`power_nearest`]), each piece clipped to its site's cell by [`clip_to_cell`]: its
/// `k_site` nearest neighbours, then a grid walk if they do not settle it.
#[inline]
pub fn flood_tet<A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    i: usize,
    p: &RefineParams,
    w: GridWalk,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    tet_sites: &[u32],
    faces: FaceInputs,
    sums: &mut A,
    counters: &mut C,
    unfinished: &mut L,
    sink: &mut S,
) {
    // Floods in windows of lists own their tets (`tet_base..n_tets`), not
    // sites: `own_lo..own_hi` does not apply.
    let t = p.clip.tet_base as usize + i;
    if t >= p.clip.n_tets as usize {
        return;
    }
    let start = power_nearest(t, tet_sites[i], sites, verts, tets, &w);
    flood::<32, 64, FLOOD_CAP, _, _, _, _, _>(
        t,
        start,
        &p.clip,
        sites,
        verts,
        tets,
        faces,
        move |j: usize, poly: &mut Piece| clip_to_cell(poly, j, sites, w),
        sums,
        counters,
        unfinished,
        sink,
    );
}

/// Flood pairing of tet `t` from site `start`: build its piece, and visit
/// every site whose bisector is a face of a piece built so far. The pieces
/// of the cells that meet a convex tet tile it and are connected through
/// such faces, so this finds exactly the sites that own part of the tet —
/// no k, no empty pairs. `piece(j, poly)` clips `poly`, the tet relative to
/// site `j`, into `j`'s piece. Certificate: the pieces' volumes must add up
/// to the tet's. A tet whose flood fails (a piece unfinished, more than `Q`
/// sites, the certificate off) adds nothing, has the pieces it gave `sink`
/// discarded, and is listed whole, as `(tet, NO_SITE)`.
#[inline]
pub fn flood<const P: usize, const V: usize, const Q: usize, F, A, C, L, S>(
    t: usize,
    start: u32,
    p: &ClipParams,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    faces: FaceInputs,
    mut piece: F,
    sums: &mut A,
    counters: &mut C,
    unfinished: &mut L,
    sink: &mut S,
) where
    F: FnMut(usize, &mut Polyhedron<P, V>) -> Clipped,
    A: AtomicSums,
    C: AtomicSums,
    L: PairList,
    S: PieceSink,
{
    let mut queue = [0u32; Q];
    let mut found = [Moments::default(); Q];
    queue[0] = start;
    let mut len = 1;
    let mut head = 0;
    let mut ok = start != NO_SITE && start != OUT_OF_HALO;
    let mut c = Clipped { out_of_halo: start == OUT_OF_HALO, ..Clipped::default() };
    let mut total = 0.0f32;
    let mut tet_volume = 0.0f32;
    // One polyhedron for all the pieces: no storage cleared per piece.
    let mut poly = Polyhedron::<P, V>::empty();
    while ok && head < len {
        let j = queue[head] as usize;
        let tv = tet_vertices(t, verts, tets, &sites[j]);
        if head == 0 {
            tet_volume = ((tv[1] - tv[0]).cross(tv[2] - tv[0]).dot(tv[3] - tv[0]) / 6.0).abs();
        }
        poly.set_tetrahedron(tv);
        let ci = piece(j, &mut poly);
        c.clips += ci.clips;
        c.walks += ci.walks;
        c.security_missed |= ci.security_missed;
        c.overflow |= ci.overflow;
        c.broken |= ci.broken;
        c.out_of_halo |= ci.out_of_halo;
        if !ci.finished() {
            ok = false;
        } else if !poly.is_empty() {
            let mut areas = [0.0f32; P];
            let (m, volume) = piece_moments(&poly, t, verts, tets, &tv, face_sums_of(p), &mut areas);
            found[head] = m;
            total += volume;
            // Given now, while the piece exists; taken back if the flood fails.
            sink.piece(t as u32, j as u32, &poly, m.volume);
            add_faces(j, t, &poly, &areas, p, faces, 1, sums);
            // Planes a clip made but a later one cut away are no faces.
            let faces = poly.face_mask();
            let mut q = 0;
            while q < poly.n_planes as usize {
                let id = poly.ids[q];
                if (faces >> q) & 1 != 0 && made_by_site(id) {
                    let mut seen = false;
                    let mut s = 0;
                    while s < len {
                        seen |= queue[s] == id;
                        s += 1;
                    }
                    if !seen {
                        if len == Q {
                            ok = false;
                        } else {
                            queue[len] = id;
                            len += 1;
                        }
                    }
                }
                q += 1;
            }
        }
        head += 1;
    }
    // The pieces tile the tet: anything else means a piece was missed.
    if ok && (total - tet_volume).abs() > 1e-4 * tet_volume {
        ok = false;
    }
    let mut nonempty = 0;
    if ok {
        let mut i = 0;
        while i < len {
            if found[i].volume != 0.0 {
                accumulate(queue[i] as usize, &found[i], p.fixed_scale, sums);
                nonempty += 1;
            }
            i += 1;
        }
    } else {
        sink.discard_tet(t as u32);
        unfinished.push(t as u32, if c.out_of_halo { OUT_OF_HALO } else { NO_SITE });
        // Take back the faces given so far: the same pieces again (the clip
        // is deterministic), subtracted.
        if p.faces_base != 0 {
            let mut h = 0;
            while h < head {
                if found[h].volume != 0.0 {
                    let j = queue[h] as usize;
                    let tv = tet_vertices(t, verts, tets, &sites[j]);
                    poly.set_tetrahedron(tv);
                    piece(j, &mut poly);
                    let mut areas = [0.0f32; P];
                    piece_moments(&poly, t, verts, tets, &tv, face_sums_of(p), &mut areas);
                    add_faces(j, t, &poly, &areas, p, faces, -1, sums);
                }
                h += 1;
            }
        }
    }
    count(counters, head as i64, nonempty, &c);
}
