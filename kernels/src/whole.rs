//! Whole cells: each site's Voronoi cell built once, and only the cells
//! the domain's boundary may cut go through the tets.
//!
//! Thread `i` builds site `i`'s cell in its own frame, from a box holding
//! the domain, by its neighbours' bisectors and, where the list does not
//! settle it, a walk of the site grid ([`clip_to_cell`]): the cell is then
//! exact up to the security radius. Its vertices lie within `r` of the
//! site; if the site lies inside the domain and every boundary triangle
//! within `r` of it (found through a hierarchy over them) lies beyond one
//! of the cell's face planes, the boundary does not meet the cell, and the
//! cell, holding an inside point (its site: a power cell away from its
//! site is taken as cut), lies inside the domain: it is integrated
//! whole — volume, moments, faces with
//! their neighbours — and handed to the sink as the piece of tet
//! [`WHOLE_CELL`]. The test is certified (distances to the triangles from
//! a hierarchy over them, with a margin for rounding); a cell it cannot
//! clear is clipped by every tet whose bounding box meets the cell's,
//! found in a voxel grid over the tets (each tet listed in every voxel its
//! box meets, and taken once: in the first voxel of the query that lists
//! it), and its pieces are summed as the other strategies sum theirs.
//!
//! A cell inside the domain has no tet plane in it: its volume is one sum
//! of terms of its own size, whatever the tets around it (a small cell
//! next to a big tet is as exact as any). A density that varies inside the
//! tets needs the pieces: with one, every cell goes through its tets
//! ([`DomainParams::whole`]).
//!
//! In a periodic box nothing cuts a cell: its neighbours across the box's
//! sides are the sites' images, and every cell is whole
//! ([`domain_whole::ALL`]).
//!
//! A cell that could not be built (a full polyhedron, a breakdown), or a
//! piece of a cut cell that failed, adds nothing: its faces are taken
//! back, its pieces discarded from the sink, and the site is listed as
//! `(WHOLE_CELL, i)` for the host, which finishes it from its tets.

use crate::abi::{counter, domain_whole, DomainParams, RefineParams, SplitPoint, ACCUM_PER_SITE, NO_SITE, WHOLE_CELL};
use crate::buffers::{AtomicSums, PairList};
use crate::cell::Slack;
use crate::cell::{tet_vertices, Clipped};
use crate::clip::{
    accumulate, accumulate_fixed, add_faces, add_fixed, count, face_sums, face_sums_of, owns, piece_moments, xyz,
    FaceInputs, PieceSink,
};
use crate::lists::NO_LIST;
use crate::polyhedron::{between, offset_point, tet_planes, Clip, Point, Polyhedron, TET_FACE};
use crate::walk::{clip_by_list, clip_in_frame, clip_to_cell, walk_to_cell, GridWalk};
use spirv_std::glam::{Vec3, Vec4};
#[cfg(target_arch = "spirv")]
use spirv_std::num_traits::Float;

/// In a node record's `w` (as bits): the node is a leaf, its first
/// triangle in the low bits.
pub const LEAF: u32 = 1 << 31;

/// The deepest hierarchy a thread searches (its stack); the host builds
/// none deeper.
pub const TREE_DEPTH: usize = 40;

/// The domain as [`whole_cell`] reads it.
#[derive(Clone, Copy)]
pub struct Domain<'a> {
    /// The voxel grid and the hierarchy's size.
    pub params: DomainParams,
    /// Where each voxel's tets start in `voxel_tets` (one more entry than
    /// voxels, x fastest).
    pub voxel_start: &'a [u32],
    /// The tets of each voxel.
    pub voxel_tets: &'a [u32],
    /// Each tet's first voxel (the one holding its bounding box's lower
    /// corner), as a linear index.
    pub tet_voxel: &'a [u32],
    /// The boundary's hierarchy, two records per node: `[lo, a]`, `[hi,
    /// b]` with the box padded outwards; a leaf has `a = LEAF | first
    /// triangle` and `b` triangles, an inner node children `a` and `b`
    /// (as bits). Node 0 is the root.
    pub nodes: &'a [[f32; 4]],
    /// The boundary triangles, as mesh vertex indices (`[3]` unused).
    pub tris: &'a [[u32; 4]],
}

/// The voxel of `d`'s grid holding coordinate `x` on axis `a`, clamped to
/// the grid: the host lists the tets by it, the kernels query by it.
#[inline]
pub fn voxel_of(d: &DomainParams, x: f32, a: usize) -> u32 {
    let (lo, dim) = match a {
        0 => (d.lo_x, d.dim_x),
        1 => (d.lo_y, d.dim_y),
        _ => (d.lo_z, d.dim_z),
    };
    let v = (x - lo) / d.voxel_len;
    if v <= 0.0 {
        0
    } else if v >= (dim - 1) as f32 {
        dim - 1
    } else {
        v as u32
    }
}

impl Domain<'_> {
    /// The voxel holding coordinate `x` on axis `a`, clamped to the grid.
    #[inline]
    fn voxel(&self, x: f32, a: usize) -> u32 {
        voxel_of(&self.params, x, a)
    }

    /// The voxels `[lo, hi]` on each axis that the box `[a, b]` meets.
    #[inline]
    fn range(&self, a: Vec3, b: Vec3) -> ([u32; 3], [u32; 3]) {
        (
            [self.voxel(a.x, 0), self.voxel(a.y, 1), self.voxel(a.z, 2)],
            [self.voxel(b.x, 0), self.voxel(b.y, 1), self.voxel(b.z, 2)],
        )
    }

    /// The linear index of voxel `v`.
    #[inline]
    fn index(&self, v: [u32; 3]) -> usize {
        (v[2] as usize * self.params.dim_y as usize + v[1] as usize) * self.params.dim_x as usize + v[0] as usize
    }
}

/// The squared distance from the origin to the triangle `a, b, c`
/// (Ericson, *Real-Time Collision Detection*, 5.1.5: the closest point by
/// the origin's Voronoi region of the triangle).
#[inline]
pub fn triangle_distance2(a: Point, b: Point, c: Point) -> f32 {
    let ab = b - a;
    let ac = c - a;
    let ap = -a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a.length_squared();
    }
    let bp = -b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b.length_squared();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + ab * v).length_squared();
    }
    let cp = -c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c.length_squared();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + ac * w).length_squared();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * w).length_squared();
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (a + ab * v + ac * w).length_squared()
}

/// Whether a boundary triangle comes within `sqrt(r2)` of `site` and is
/// not separated from `cell` (relative to the site) by one of its faces'
/// planes with a margin of `gap` (or the search could not tell: a
/// hierarchy deeper than [`TREE_DEPTH`]). A triangle no face separates may
/// still miss the cell: such a cell is taken as cut, which costs time only.
#[inline]
pub fn boundary_near<const P: usize, const V: usize>(
    site: &SplitPoint,
    r2: f32,
    cell: &Polyhedron<P, V>,
    gap: f32,
    verts: &[SplitPoint],
    d: &Domain,
) -> bool {
    if d.params.n_nodes == 0 {
        return false;
    }
    let x = xyz(site.hi) + xyz(site.lo);
    let mut stack = [0u32; TREE_DEPTH];
    let mut top = 1;
    while top > 0 {
        top -= 1;
        let n = stack[top] as usize;
        let a = d.nodes[2 * n];
        let b = d.nodes[2 * n + 1];
        // The box's distance from the site (boxes are padded for rounding).
        let dx = (a[0] - x.x).max(x.x - b[0]).max(0.0);
        let dy = (a[1] - x.y).max(x.y - b[1]).max(0.0);
        let dz = (a[2] - x.z).max(x.z - b[2]).max(0.0);
        if dx * dx + dy * dy + dz * dz > r2 {
            continue;
        }
        let (first, second) = (a[3].to_bits(), b[3].to_bits());
        if first & LEAF != 0 {
            let start = (first & !LEAF) as usize;
            let mut t = start;
            while t < start + second as usize {
                let tri = d.tris[t];
                let p = between(&verts[tri[0] as usize], site);
                let q = between(&verts[tri[1] as usize], site);
                let s = between(&verts[tri[2] as usize], site);
                if triangle_distance2(p, q, s) <= r2 && !separated(cell, [p, q, s], gap) {
                    return true;
                }
                t += 1;
            }
        } else if top + 2 > TREE_DEPTH {
            return true;
        } else {
            stack[top] = first;
            stack[top + 1] = second;
            top += 2;
        }
    }
    false
}

/// Whether a plane separates `cell` from the triangle `tri` by more than
/// `gap`: one of the cell's faces, with the three points beyond it, or the
/// triangle's own, with every vertex of the cell on one side of it (a
/// cell beside a flat stretch of the boundary, inside the ball of its
/// farthest vertex but short of the boundary where it faces it).
#[inline]
fn separated<const P: usize, const V: usize>(cell: &Polyhedron<P, V>, tri: [Point; 3], gap: f32) -> bool {
    let faces = cell.face_mask();
    let mut q = 0;
    while q < (cell.n_planes as usize).min(P) {
        if (faces >> q) & 1 != 0 {
            let pl = cell.planes[q];
            let n = Point::new(pl.x, pl.y, pl.z);
            let h = pl.w + gap;
            if n.dot(tri[0]) > h && n.dot(tri[1]) > h && n.dot(tri[2]) > h {
                return true;
            }
        }
        q += 1;
    }
    let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
    let len = n.length();
    let longest = (tri[1] - tri[0]).length().max((tri[2] - tri[1]).length()).max((tri[0] - tri[2]).length());
    // (A NaN fails every test below: not separated.)
    if len <= 0.0 {
        return false;
    }
    let n = n / len;
    let d = n.dot(tri[0]);
    // The normal's direction is off by about the points' rounding over the
    // triangle's smallest height, which the distance to the cell's far
    // vertices magnifies (at most twice the farthest point's reach).
    let reach = tri[0].length().max(tri[1].length()).max(tri[2].length());
    let slack = gap + 1e-6 * reach * reach * longest / len;
    let (mut below, mut above) = (true, true);
    let mut v = 0;
    while v < (cell.n_verts as usize).min(V) {
        let s = n.dot(cell.verts[v]) - d;
        below &= s < -slack;
        above &= s > slack;
        v += 1;
    }
    below || above
}

/// Whether `cell` (relative to its site) holds the site strictly inside:
/// always for a Voronoi cell; a power cell may lie away from its site, and
/// is then taken as cut (the site inside the domain says nothing of it).
#[inline]
fn holds_its_site<const P: usize, const V: usize>(cell: &Polyhedron<P, V>) -> bool {
    let faces = cell.face_mask();
    let mut q = 0;
    while q < (cell.n_planes as usize).min(P) {
        // Inside plane (n, h) where n·x <= h: the origin when 0 < h.
        if (faces >> q) & 1 != 0 && cell.planes[q].w <= 0.0 {
            return false;
        }
        q += 1;
    }
    true
}

/// Whether `site` lies in one of the tets of its voxel (on a face counts:
/// the boundary's distance decides there).
#[inline]
pub fn site_in_mesh(site: &SplitPoint, verts: &[SplitPoint], tets: &[[u32; 4]], d: &Domain) -> bool {
    let x = xyz(site.hi) + xyz(site.lo);
    let v = d.index([d.voxel(x.x, 0), d.voxel(x.y, 1), d.voxel(x.z, 2)]);
    let mut e = d.voxel_start[v] as usize;
    while e < d.voxel_start[v + 1] as usize {
        let tv = tet_vertices(d.voxel_tets[e] as usize, verts, tets, site);
        let planes = tet_planes(tv);
        // The site is the origin: inside plane (n, h) when 0 <= h.
        let mut inside = true;
        let mut f = 0;
        while f < 4 {
            if planes[f].w < -1e-6 * (tv[f].length() + tv[(f + 1) % 4].length()) {
                inside = false;
            }
            f += 1;
        }
        if inside {
            return true;
        }
        e += 1;
    }
    false
}

/// [`site_in_mesh`] not asked yet ([`in_mesh_once`]).
const MAYBE: u32 = 2;

/// [`site_in_mesh`], asked once per site: `known` holds the answer (0 or
/// 1) once asked, [`MAYBE`] before.
#[inline]
fn in_mesh_once(site: &SplitPoint, verts: &[SplitPoint], tets: &[[u32; 4]], d: &Domain, known: &mut u32) -> bool {
    if *known == MAYBE {
        *known = site_in_mesh(site, verts, tets, d) as u32;
    }
    *known == 1
}

/// Whether the domain's boundary may cut the cell within `poly` (relative
/// to `si`: its site, or the origin of the frame a cell far from its site
/// is built in): asked of the finished cell (false: it is integrated
/// whole), and of a polyhedron holding it before the walk (true: the walk
/// need only reach what the tets hold). A side of the domain's box as a
/// face, a cell away from `si`, a boundary triangle near and not
/// separated, or `si` outside the tets: true. Rounding: the vertices
/// are within 1e-6 of the cell's size of where they belong, the triangles
/// and the site within `margin`.
#[inline]
fn may_be_cut<const P: usize, const V: usize>(
    si: &SplitPoint,
    poly: &Polyhedron<P, V>,
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    d: &Domain,
    in_mesh: &mut u32,
) -> bool {
    if d.params.whole != domain_whole::INSIDE || poly.has_box_face() || !holds_its_site(poly) {
        return true;
    }
    let (r2, _, _) = poly.bounds();
    let reach = r2.sqrt() * (1.0 + 1e-5) + d.params.margin;
    boundary_near(si, reach * reach, poly, reach - r2.sqrt(), verts, d) || !in_mesh_once(si, verts, tets, d, in_mesh)
}

/// The squared distance from the site (the frame's origin) beyond which
/// no point of the domain within `poly`'s bounding box lies: the farthest
/// corner, over the tets the voxels of that box list, of the tet's box
/// clipped to it, with a margin for rounding. Every piece of the cell
/// within `poly` lies inside it. A voxel whose own box (clipped) cannot
/// reach farther than the farthest found is skipped whole.
#[inline]
fn domain_reach2<const P: usize, const V: usize>(
    si: &SplitPoint,
    poly: &Polyhedron<P, V>,
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    d: &Domain,
) -> f32 {
    let (_, centre, half) = poly.bounds();
    let xi = xyz(si.hi) + xyz(si.lo);
    let m = d.params.margin;
    let pad = Vec3::from(half) * 1e-5 + Vec3::splat(m);
    let blo = Vec3::from(centre - half) - pad;
    let bhi = Vec3::from(centre + half) + pad;
    let (qlo, qhi) = d.range(xi + blo, xi + bhi);
    let corner = Vec3::new(d.params.lo_x, d.params.lo_y, d.params.lo_z) - xi;
    let len = d.params.voxel_len;
    let mut best = 0.0f32;
    let mut z = qlo[2];
    while z <= qhi[2] {
        let mut y = qlo[1];
        while y <= qhi[1] {
            let mut x = qlo[0];
            while x <= qhi[0] {
                let v = d.index([x, y, z]);
                let (start, end) = (d.voxel_start[v] as usize, d.voxel_start[v + 1] as usize);
                // The voxel's box, padded for the rounding of its index.
                let vlo = corner + Vec3::new(x as f32, y as f32, z as f32) * len - Vec3::splat(m);
                let vhi = vlo + Vec3::splat(len + 2.0 * m);
                if start < end && farthest2(vlo.max(blo), vhi.min(bhi)) > best {
                    let mut e = start;
                    while e < end {
                        let tv = tet_vertices(d.voxel_tets[e] as usize, verts, tets, si);
                        let tlo = tv[0].min(tv[1]).min(tv[2].min(tv[3])) - Vec3::splat(m);
                        let thi = tv[0].max(tv[1]).max(tv[2].max(tv[3])) + Vec3::splat(m);
                        best = best.max(farthest2(tlo.max(blo), thi.min(bhi)));
                        e += 1;
                    }
                }
                x += 1;
            }
            y += 1;
        }
        z += 1;
    }
    let r = best.sqrt() * (1.0 + 1e-5) + m;
    r * r
}

/// The squared distance from the origin to the farthest corner of the box
/// `[lo, hi]` (0 for an empty box).
#[inline]
fn farthest2(lo: Vec3, hi: Vec3) -> f32 {
    if lo.x > hi.x || lo.y > hi.y || lo.z > hi.z {
        return 0.0;
    }
    let far = (lo * lo).max(hi * hi);
    far.x + far.y + far.z
}

/// Twice the distance from site `i` to the last site of its list (0: no
/// list).
#[inline]
fn listed_reach(i: usize, sites: &[SplitPoint], w: &GridWalk) -> f32 {
    let k = w.lists.k();
    let slot = w.lists.slot(i);
    if k == 0 || slot == NO_LIST {
        return 0.0;
    }
    let last = w.lists.get(slot, k - 1);
    if last == NO_SITE {
        return 0.0;
    }
    2.0 * between(&sites[last as usize], &sites[i]).length()
}

/// Thread `i` of the whole-cell strategy: site `i`'s cell, integrated
/// whole if its ball lies inside the domain, else clipped by the tets it
/// may meet (see the module's documentation). `P`, `V`: the cell's
/// capacity.
#[inline]
pub fn whole_cell<const P: usize, const V: usize, A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    i: usize,
    p: &RefineParams,
    w: GridWalk,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    d: Domain,
    faces: FaceInputs,
    sums: &mut A,
    counters: &mut C,
    unfinished: &mut L,
    sink: &mut S,
) {
    let c = &p.clip;
    if i >= c.n_sites as usize || !owns(c, i) {
        return;
    }
    let si = sites[i];
    let xi = xyz(si.hi) + xyz(si.lo);
    let lo = Vec3::new(c.box_lo_x, c.box_lo_y, c.box_lo_z) - xi;
    let hi = Vec3::new(c.box_hi_x, c.box_hi_y, c.box_hi_z) - xi;
    // First from a box of the cell's own size (twice the distance to the
    // last listed neighbour): its vertices then come from corners near the
    // cell, not from the domain's far corners. If a side of that box is
    // still a face, the cell reaches beyond it: again from the domain's box.
    let reach = listed_reach(i, sites, &w);
    let mut poly = if reach > 0.0 {
        Polyhedron::<P, V>::cuboid(lo.max(Vec3::splat(-reach)), hi.min(Vec3::splat(reach)))
    } else {
        Polyhedron::<P, V>::cuboid(lo, hi)
    };
    // Where the list leaves the cell unsettled and the domain's boundary
    // may cut it, only the part of the cell the domain's tets can hold is
    // wanted: the walk goes out to twice that part's reach, not to twice
    // the whole cell's (which, for a site near the boundary, reaches out
    // of the domain to its box). Such a cell is then cut by its tets.
    let mut in_mesh = MAYBE;
    let mut bounded = false;
    let mut built = clip_by_list(&mut poly, i, sites, &w);
    if built.security_missed
        && d.params.whole != domain_whole::ALL
        && may_be_cut(&si, &poly, verts, tets, &d, &mut in_mesh)
    {
        if reach > 0.0 && poly.has_box_face() {
            poly.set_cuboid(lo, hi);
            built = clip_by_list(&mut poly, i, sites, &w);
        }
        if built.security_missed {
            let cap2 =
                Slack::of(c.weight_range, sites, i, c.n_sites).reach2(domain_reach2(&si, &poly, verts, tets, &d));
            built = walk_to_cell(&mut poly, i, sites, w, built, cap2);
            bounded = true;
        }
    }
    built = walk_to_cell(&mut poly, i, sites, w, built, f32::INFINITY);
    // A power cell may lie away from its site, out of the box of the cell's
    // own size: empty there says nothing, so again from the domain's box.
    if !bounded && reach > 0.0 && built.finished() && (poly.has_box_face() || poly.is_empty()) {
        poly.set_cuboid(lo, hi);
        built = clip_to_cell(&mut poly, i, sites, w);
    }
    if !built.finished() {
        unfinished.push(WHOLE_CELL, i as u32);
        count(counters, 0, 0, &built);
        return;
    }
    let with_faces = face_sums_of(c) != face_sums::NONE;
    let mut whole = poly.is_empty()
        || d.params.whole == domain_whole::ALL
        || (!bounded && !may_be_cut(&si, &poly, verts, tets, &d, &mut in_mesh));
    // A power cell away from its site (outside the cell's bounding box) is
    // built again in a frame at its centre: in the site's frame its
    // vertices are rounded relative to their distance from the site, up to
    // many times the cell's own size (weights that differ by more than the
    // sites' spacing squared, as transport's between cells of very
    // different sizes). A Voronoi cell holds its site: never rebuilt.
    let (_, centre, half) = poly.bounds();
    let mut frame = si;
    let mut shift = Vec3::ZERO;
    let away = centre.abs() - half;
    if !poly.is_empty() && away.x.max(away.y).max(away.z) > 0.0 {
        shift = Vec3::from(centre);
        frame = offset_point(&si, shift);
        // A box around the cell, larger than its rounding could make it (a
        // side of it as a face would say the first build was wrong), and
        // every site that can cut a point of the box: those within the
        // security radius of its farthest corner from the site (not only
        // those a bounded walk took: the box reaches a little beyond what
        // that walk certified).
        let span = Vec3::from(half) * 1.01 + Vec3::splat(1e-4 * centre.length());
        let corner = shift.abs() + span;
        let reach2 = Slack::of(c.weight_range, sites, i, c.n_sites).reach2(corner.length_squared() * (1.0 + 1e-5));
        let had_box_face = poly.has_box_face();
        poly.set_cuboid((lo - shift).max(-span), (hi - shift).min(span));
        let again = clip_in_frame(&mut poly, i, sites, w, &frame, reach2);
        built.clips += again.clips;
        built.walks += again.walks;
        if !again.finished() || (!had_box_face && poly.has_box_face()) {
            unfinished.push(WHOLE_CELL, i as u32);
            count(counters, 0, 0, &again);
            return;
        }
        // Empty now (it was a sliver of rounding): nothing to cut. Else the
        // cell holds its frame's origin: the domain's test, made there, can
        // find it whole (away from its site, it was taken as cut).
        let mut in_mesh = MAYBE;
        whole = whole || poly.is_empty() || (!bounded && !may_be_cut(&frame, &poly, verts, tets, &d, &mut in_mesh));
    }
    if whole {
        if !poly.is_empty() {
            let mut areas = [0.0f32; P];
            let m = if with_faces { poly.moments_and_areas(&mut areas) } else { poly.moments() };
            let m = m.moved_by(shift);
            accumulate(i, &m, c.fixed_scale, sums);
            // No tet face in a whole cell: tet 0's boundary bits are not read.
            add_faces(i, 0, &poly, &areas, c, faces, 1, sums);
            poly.translate(shift);
            sink.piece(WHOLE_CELL, i as u32, &poly, m.volume);
        }
        counters.add(counter::WHOLE, 1);
        count(counters, 1, !poly.is_empty() as i64, &built);
        return;
    }
    counters.add(counter::CUT, 1);
    let (_, centre, half) = poly.bounds();
    let mut out = Clipped { clips: built.clips, walks: built.walks, ..Clipped::default() };
    let cell = Frame { origin: &frame, shift, poly: &poly, centre, half };
    let (pieces, nonempty, failed) = cut_cell(i, &cell, c, verts, tets, &d, faces, 1, sums, sink);
    out.clips += pieces;
    if failed != NONE_FAILED {
        // Take back the faces of the pieces added before the failure.
        if with_faces {
            cut_cell_until(i, &cell, c, verts, tets, &d, faces, sums);
        }
        sink.discard_site(i as u32);
        unfinished.push(WHOLE_CELL, i as u32);
        out.overflow = true;
        count(counters, 0, 0, &out);
        return;
    }
    count(counters, pieces, nonempty, &out);
}

/// A cell as [`cut_cell`] cuts it: the polyhedron, in the frame whose
/// origin is `origin` (`shift` from the site: 0, or the centre of a cell
/// far from its site), and its bounding box `centre ± half` there.
struct Frame<'a, const P: usize, const V: usize> {
    origin: &'a SplitPoint,
    shift: Vec3,
    poly: &'a Polyhedron<P, V>,
    centre: Point,
    half: Point,
}

/// No piece failed ([`cut_cell`]).
const NONE_FAILED: u32 = u32::MAX;

/// Site `i`'s cell (`cell`, in its frame) clipped by every tet of the
/// domain whose box meets the cell's; each non-empty piece's moments are
/// added to the site's sums (about the site), its faces with `sign`, and
/// the piece handed to `sink` (relative to the site). Returns the pairs
/// tried, the non-empty pieces, and the tet whose piece failed (then no
/// moments were added, but the faces of the pieces before it were), or
/// [`NONE_FAILED`].
#[inline]
fn cut_cell<const P: usize, const V: usize, A: AtomicSums, S: PieceSink>(
    i: usize,
    cell: &Frame<P, V>,
    c: &crate::abi::ClipParams,
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    d: &Domain,
    faces: FaceInputs,
    sign: i64,
    sums: &mut A,
    sink: &mut S,
) -> (i64, i64, u32) {
    let (poly, origin) = (cell.poly, cell.origin);
    let xo = xyz(origin.hi) + xyz(origin.lo);
    // The cell's box, padded for rounding, in the frame.
    let pad = Vec3::from(cell.half) * 1e-5 + Vec3::splat(d.params.margin);
    let blo = Vec3::from(cell.centre - cell.half) - pad;
    let bhi = Vec3::from(cell.centre + cell.half) + pad;
    let (qlo, qhi) = d.range(xo + blo, xo + bhi);
    // Summed in fixed point, each piece rounded alone: a cell cut into
    // thousands of pieces (a few sites in a large domain) sums them
    // exactly, as the other strategies' atomics do.
    let mut total = [0i64; ACCUM_PER_SITE];
    let (mut pairs, mut nonempty) = (0i64, 0i64);
    let mut piece = Polyhedron::<P, V>::empty();
    // A cell that still has a side of the domain's box (its site near the
    // domain's hull, or outside) may be far larger than its pieces: each
    // piece is then its tet clipped by the cell's faces, whose vertices
    // come from the tet's corners, not from the box's.
    let from_tet = poly.has_box_face();
    let with_faces = face_sums_of(c) != face_sums::NONE;
    let mut z = qlo[2];
    while z <= qhi[2] {
        let mut y = qlo[1];
        while y <= qhi[1] {
            let mut x = qlo[0];
            while x <= qhi[0] {
                let v = d.index([x, y, z]);
                let mut e = d.voxel_start[v] as usize;
                while e < d.voxel_start[v + 1] as usize {
                    let t = d.voxel_tets[e] as usize;
                    e += 1;
                    // Taken once: in the first voxel of the query listing it.
                    let f = d.tet_voxel[t];
                    let (dx, dy) = (d.params.dim_x, d.params.dim_y);
                    let first = [(f % dx).max(qlo[0]), ((f / dx) % dy).max(qlo[1]), (f / (dx * dy)).max(qlo[2])];
                    if first[0] != x || first[1] != y || first[2] != z {
                        continue;
                    }
                    let tv = tet_vertices(t, verts, tets, origin);
                    let tlo = tv[0].min(tv[1]).min(tv[2].min(tv[3]));
                    let thi = tv[0].max(tv[1]).max(tv[2].max(tv[3]));
                    if tlo.x > bhi.x
                        || tlo.y > bhi.y
                        || tlo.z > bhi.z
                        || thi.x < blo.x
                        || thi.y < blo.y
                        || thi.z < blo.z
                    {
                        continue;
                    }
                    pairs += 1;
                    let ok = if from_tet {
                        tet_by_cell(poly, tv, &mut piece)
                    } else {
                        clipped_by_tet(poly, tet_planes(tv), &mut piece)
                    };
                    if !ok {
                        return (pairs, nonempty, t as u32);
                    }
                    if piece.is_empty() {
                        continue;
                    }
                    let mut areas = [0.0f32; P];
                    let (m, _) = piece_moments(&piece, t, verts, tets, &tv, face_sums_of(c), &mut areas);
                    let m = m.moved_by(cell.shift);
                    if m.volume != 0.0 {
                        nonempty += 1;
                    }
                    add_fixed(&mut total, &m, c.fixed_scale);
                    if with_faces {
                        add_faces(i, t, &piece, &areas, c, faces, sign, sums);
                    }
                    if sign > 0 {
                        piece.translate(cell.shift);
                        sink.piece(t as u32, i as u32, &piece, m.volume);
                    }
                }
                x += 1;
            }
            y += 1;
        }
        z += 1;
    }
    if sign > 0 {
        accumulate_fixed(i, &total, sums);
    }
    (pairs, nonempty, NONE_FAILED)
}

/// Takes back the faces [`cut_cell`] added before a piece failed: the same
/// pieces again (the clips are deterministic), with their faces
/// subtracted, up to the same failure.
#[inline]
fn cut_cell_until<const P: usize, const V: usize, A: AtomicSums>(
    i: usize,
    cell: &Frame<P, V>,
    c: &crate::abi::ClipParams,
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    d: &Domain,
    faces: FaceInputs,
    sums: &mut A,
) {
    let mut none = crate::clip::NoPieces;
    cut_cell(i, cell, c, verts, tets, d, faces, -1, sums, &mut none);
}

/// The tet `tv` (relative to the site) clipped by the planes of `cell`'s
/// faces, into `piece`, and whether the clips finished.
#[inline]
fn tet_by_cell<const P: usize, const V: usize>(
    cell: &Polyhedron<P, V>,
    tv: [Vec3; 4],
    piece: &mut Polyhedron<P, V>,
) -> bool {
    piece.set_tetrahedron(tv);
    let faces = cell.face_mask();
    let mut q = 0;
    while q < (cell.n_planes as usize).min(P) && !piece.is_empty() {
        if (faces >> q) & 1 != 0 {
            match piece.clip_as(cell.planes[q], cell.ids[q]) {
                Clip::Overflow | Clip::Broken => return false,
                _ => {}
            }
        }
        q += 1;
    }
    true
}

/// `poly` clipped by the tet whose planes are `planes`, into `piece`, and
/// whether the clips finished. A plane that keeps every vertex is skipped;
/// one that keeps none empties the piece before any copy.
#[inline]
fn clipped_by_tet<const P: usize, const V: usize>(
    poly: &Polyhedron<P, V>,
    planes: [Vec4; 4],
    piece: &mut Polyhedron<P, V>,
) -> bool {
    // Bit f: plane f cuts (a bool array is no SPIR-V memset).
    let mut cuts = 0u32;
    let mut f = 0;
    while f < 4 {
        let pl = planes[f];
        let n = Point::new(pl.x, pl.y, pl.z);
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut v = 0;
        while v < poly.n_verts as usize {
            let s = n.dot(poly.verts[v]);
            lo = lo.min(s);
            hi = hi.max(s);
            v += 1;
        }
        // As `Polyhedron::clip_as` rounds: a tet face on a face of the cell
        // (sites on a lattice in a lattice's mesh) neither cuts it nor
        // leaves a sliver.
        let rounding = 1e-6 * (lo.abs().max(hi.abs()) + pl.w.abs());
        let (lo, hi) = (lo - pl.w, hi - pl.w);
        if lo >= -rounding {
            piece.n_verts = 0;
            return true;
        }
        let hi = if hi <= rounding { 0.0 } else { hi };
        if hi > 0.0 {
            cuts |= 1 << f;
        }
        f += 1;
    }
    piece.copy_from(poly);
    let mut f = 0;
    while f < 4 {
        if (cuts >> f) & 1 != 0 {
            match piece.clip_as(planes[f], TET_FACE + f as u32) {
                Clip::Overflow | Clip::Broken => return false,
                Clip::Empty => return true,
                Clip::Cut | Clip::Unchanged => {}
            }
        }
        f += 1;
    }
    true
}
