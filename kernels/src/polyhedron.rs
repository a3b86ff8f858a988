//! A convex polyhedron of fixed capacity, clipped by planes and integrated
//! exactly (paper Algorithms 1-3).
//!
//! Representation (the dual triangles of Ray et al. 2018): the polyhedron is
//! the intersection of the half-spaces `n·x <= d` of its planes, and each
//! vertex is stored as the triple of planes that meet there, ordered
//! consistently around the vertex, with its position cached. Clipping
//! removes the vertices outside the new plane and closes the hole with one
//! new vertex per boundary edge; no adjacency is stored (a clip finds the
//! edges between removed and kept vertices from the removed ones' plane
//! pairs alone). All coordinates are relative to a local origin (the
//! site), so f32 keeps its precision; the moments are taken around each
//! piece itself, with its vertices moved onto their planes first.

use crate::abi::SplitPoint;
use spirv_std::glam::{Vec3, Vec4};

/// A vertex position: a 16-byte SIMD vector on the CPU (its products and
/// crosses are a few instructions there), a plain `Vec3` on the GPU; the
/// code is the same for both.
#[cfg(not(target_arch = "spirv"))]
pub type Point = spirv_std::glam::Vec3A;
/// A vertex position: a 16-byte SIMD vector on the CPU (its products and
/// crosses are a few instructions there), a plain `Vec3` on the GPU; the
/// code is the same for both.
#[cfg(target_arch = "spirv")]
pub type Point = Vec3;

/// The `xyz` of a buffer record, as a [`Point`] (one load on the CPU).
#[cfg(not(target_arch = "spirv"))]
#[inline]
pub fn point(v: [f32; 4]) -> Point {
    Point::from_vec4(Vec4::from_array(v))
}

/// The `xyz` of a buffer record, as a [`Point`] (one load on the CPU).
#[cfg(target_arch = "spirv")]
#[inline]
pub fn point(v: [f32; 4]) -> Point {
    Vec3::new(v[0], v[1], v[2])
}

/// `a - b`, accurate to f32 relative to the difference (see
/// [`SplitPoint`]): the vector from a site to a neighbour or to a tet
/// vertex.
#[inline]
pub fn between(a: &SplitPoint, b: &SplitPoint) -> Point {
    (point(a.hi) - point(b.hi)) + (point(a.lo) - point(b.lo))
}

/// `w_a - w_b`, the difference of two sites' power weights (their
/// `hi[3] + lo[3]`), accurate to f32 relative to the weights' range.
#[inline]
pub fn weight_gap(a: &SplitPoint, b: &SplitPoint) -> f32 {
    (a.hi[3] - b.hi[3]) + (a.lo[3] - b.lo[3])
}

/// The offset `h` of the power bisector `n·x <= h` of site `i` and a site
/// at `n` from it (`d2 = |n|²`, `gap = w_i - w_j`): where `|x|² - w_i <=
/// |x - n|² - w_j`. Without weights, `|n|² / 2`.
#[inline]
pub fn bisector_offset(d2: f32, gap: f32) -> f32 {
    0.5 * (d2 + gap)
}

/// `a + b` exactly, as the rounded sum and its error (Knuth's two-sum).
#[inline]
fn two_sum(a: f32, b: f32) -> (f32, f32) {
    let s = a + b;
    let v = s - a;
    (s, (a - (s - v)) + (b - v))
}

/// `a * b` exactly, as the rounded product and its error (one fused
/// multiply-add: a GLSL `Fma` on the device).
#[inline]
fn two_prod(a: f32, b: f32) -> (f32, f32) {
    let p = a * b;
    (p, spirv_std::num_traits::Float::mul_add(a, b, -p))
}

/// `|x - o|²` as `hi + lo`, to about f32's precision squared relative to
/// it: each axis's difference taken exactly in two parts, squared exactly.
#[inline]
fn distance2_split(x: &SplitPoint, o: &SplitPoint) -> (f32, f32) {
    let (mut s, mut e) = (0.0f32, 0.0f32);
    let mut k = 0;
    while k < 3 {
        let (d, de) = two_sum(x.hi[k], -o.hi[k]);
        let dl = de + (x.lo[k] - o.lo[k]);
        let (p, pe) = two_prod(d, d);
        let (t, te) = two_sum(s, p);
        s = t;
        e += te + pe + dl * (2.0 * d + dl);
        k += 1;
    }
    (s, e)
}

/// The offset `h` of site `i`'s power bisector with site `j`, `n·y <= h`
/// with `n` = [`between`]`(x_j, x_i)`, in the frame whose origin is `o`
/// (`y = x - o`): `h = (|x_j - o|² - |x_i - o|² + w_i - w_j) / 2`, summed
/// in two parts, so that `h` is exact to f32 relative to itself — to the
/// distance from `o` to the plane, not to the site's. A power cell far
/// from its site is built in a frame at its centre with these (see
/// `whole`): in the site's frame its planes' offsets are rounded relative
/// to their distance from the site, many times the cell's size. With `o`
/// at `x_i` this is [`bisector_offset`].
#[inline]
pub fn bisector_offset_at(xi: &SplitPoint, xj: &SplitPoint, o: &SplitPoint) -> f32 {
    let (a, ae) = distance2_split(xj, o);
    let (b, be) = distance2_split(xi, o);
    let (g, ge) = two_sum(xi.hi[3], -xj.hi[3]);
    let (t, te) = two_sum(a, -b);
    let (u, ue) = two_sum(t, g);
    0.5 * (u + (ue + te + (ae - be) + (ge + (xi.lo[3] - xj.lo[3]))))
}

/// The point `s + c` as a [`SplitPoint`] (`hi + lo`, exact to f32's
/// precision squared), with `s`'s value: the origin of a frame at `c`
/// from a site.
#[inline]
pub fn offset_point(s: &SplitPoint, c: Vec3) -> SplitPoint {
    let (x, xe) = two_sum(s.hi[0], c.x);
    let (y, ye) = two_sum(s.hi[1], c.y);
    let (z, ze) = two_sum(s.hi[2], c.z);
    SplitPoint { hi: [x, y, z, s.hi[3]], lo: [xe + s.lo[0], ye + s.lo[1], ze + s.lo[2], s.lo[3]] }
}

/// The normal (`xyz`) of a plane `(n, d)`, as a [`Point`].
#[cfg(not(target_arch = "spirv"))]
#[inline]
pub fn normal(plane: Vec4) -> Point {
    Point::from_vec4(plane)
}

/// The normal (`xyz`) of a plane `(n, d)`, as a [`Point`].
#[cfg(target_arch = "spirv")]
#[inline]
pub fn normal(plane: Vec4) -> Point {
    plane.truncate()
}

/// `plane` scaled exactly, by a power of two, so that its normal's largest
/// component lies in `[1, 2)`: the products of normals the clips and the
/// integrals form neither underflow nor overflow f32, however small the
/// cell (a bisector's normal is the vector between two sites, 1e-6 of the
/// frame in a tight cluster, and its cube would be 1e-18).
#[inline]
pub fn normalized(plane: Vec4) -> Vec4 {
    let m = plane.x.abs().max(plane.y.abs()).max(plane.z.abs());
    let e = (m.to_bits() >> 23) & 0xff;
    if e == 0 || e > 253 {
        // Zero, subnormal, infinite or NaN: left as it is.
        return plane;
    }
    plane * f32::from_bits((254 - e) << 23)
}

/// The planes of the tetrahedron `v` (any orientation), normalised, as
/// `(n, d)` with the inside `n·x <= d`: plane `i` is the face opposite
/// vertex `i`, facing away from it.
#[inline]
pub fn tet_planes(v: [Vec3; 4]) -> [Vec4; 4] {
    let v = [Point::from(v[0]), Point::from(v[1]), Point::from(v[2]), Point::from(v[3])];
    let mut planes = [Vec4::ZERO; 4];
    let mut i = 0;
    while i < 4 {
        let a = v[(i + 1) % 4];
        let b = v[(i + 2) % 4];
        let c = v[(i + 3) % 4];
        let mut n = (b - a).cross(c - a);
        if n.dot(v[i] - a) > 0.0 {
            n = -n;
        }
        planes[i] = normalized(Vec3::from(n).extend(n.dot(a)));
        i += 1;
    }
    planes
}

/// Capacities: a Voronoi cell of a site (Algorithm 1) may have ~40 faces
/// and ~80 vertices; a piece of a cell inside a tet has far fewer. A clip
/// needs room for the new vertices before it drops the removed ones.
/// Planes no vertex uses are recycled before a plane overflow is declared.
/// Planes of a [`Cell`].
pub const CELL_PLANES: usize = 64;
/// Vertices of a [`Cell`].
pub const CELL_VERTS: usize = 128;
/// The id of planes no site made.
pub const NO_ID: u32 = u32::MAX;
/// The id of the face of a tet opposite its vertex `f` is `TET_FACE + f`
/// (the starting planes of [`Polyhedron::set_tetrahedron`]): a piece knows
/// which of its tet's faces bound it.
pub const TET_FACE: u32 = u32::MAX - 4;

/// Whether a plane's id names the site whose bisector it is (not a tet's
/// face, nor another plane no site made).
#[inline]
pub fn made_by_site(id: u32) -> bool {
    id < TET_FACE
}

/// A Voronoi cell.
pub type Cell = Polyhedron<CELL_PLANES, CELL_VERTS>;
/// A piece of a cell inside one tet: at most 32 planes and 64 vertices.
pub type Piece = Polyhedron<32, 64>;

/// The result of a clip (`u32`-sized: SPIR-V has no 8-bit integers here).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
#[repr(u32)]
pub enum Clip {
    /// The plane does not cut the polyhedron.
    Unchanged,
    /// The plane cut the polyhedron.
    Cut,
    /// Nothing is left.
    Empty,
    /// The polyhedron ran out of capacity (it is left unchanged).
    Overflow,
    /// The vertex structure was inconsistent (numerical breakdown).
    Broken,
}

/// Exact integrals over a polyhedron, relative to its local origin.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Moments {
    /// Volume.
    pub volume: f32,
    /// First moment `∫ x dV`.
    pub first: Vec3,
    /// Second moment `∫ |x|² dV`.
    pub second: f32,
}

impl Moments {
    /// These moments (about a frame's origin) about a point `c` behind
    /// it: the frame's origin lies at `c` from the new one.
    #[inline]
    pub fn moved_by(&self, c: Vec3) -> Self {
        Self {
            volume: self.volume,
            first: self.first + self.volume * c,
            second: self.second + 2.0 * c.dot(self.first) + self.volume * c.length_squared(),
        }
    }
}

/// [`Moments`] while they are summed, in [`Point`]s.
#[derive(Default)]
struct Sums {
    volume: f32,
    first: Point,
    second: f32,
}

/// A convex polyhedron of at most `P` planes (`P <= 64`: a clip keeps
/// planes as bits of a `u64`) and `V` vertices.
#[derive(Clone, Copy)]
pub struct Polyhedron<const P: usize, const V: usize> {
    /// Planes `(n, d)`: the inside is `n·x <= d`.
    pub planes: [Vec4; P],
    /// Who made each plane: the neighbour site of a bisector, a tet's face
    /// ([`TET_FACE`] + the opposite vertex), or [`NO_ID`].
    pub ids: [u32; P],
    /// Vertex positions.
    pub verts: [Point; V],
    /// Vertex plane triples, packed 8 bits each: `a | b << 8 | c << 16`.
    pub tris: [u32; V],
    /// Planes in use.
    pub n_planes: u32,
    /// Vertices in use.
    pub n_verts: u32,
    /// The largest squared distance of the starting shape's vertices from
    /// the local origin (0: none given): how far the first clips' vertices
    /// may have come from.
    pub start_radius2: f32,
}

#[inline]
fn pack(a: u32, b: u32, c: u32) -> u32 {
    a | (b << 8) | (c << 16)
}

#[inline]
fn unpack(t: u32) -> [u32; 3] {
    [t & 0xff, (t >> 8) & 0xff, (t >> 16) & 0xff]
}

/// Whether packed triple `t` has directed edge `x -> y` (cyclically):
/// its edges `a -> b`, `b -> c`, `c -> a` are compared packed, as `x | y << 8`.
#[inline]
fn has_edge(t: u32, x: u32, y: u32) -> bool {
    let e = x | (y << 8);
    (t & 0xffff) == e || ((t >> 8) & 0xffff) == e || (((t >> 16) & 0xff) | ((t & 0xff) << 8)) == e
}

impl<const P: usize, const V: usize> Polyhedron<P, V> {
    /// Refuses, at compile time, more planes than a clip's `u64` masks or
    /// the 8-bit plane numbers of a vertex triple hold.
    const PLANES_FIT: () = assert!(P <= 64, "a polyhedron has at most 64 planes");

    /// Makes this polyhedron a copy of `from`, copying only the planes
    /// and vertices in use.
    #[inline]
    pub fn copy_from(&mut self, from: &Self) {
        let mut q = 0;
        while q < (from.n_planes as usize).min(P) {
            self.planes[q] = from.planes[q];
            self.ids[q] = from.ids[q];
            q += 1;
        }
        let mut v = 0;
        while v < (from.n_verts as usize).min(V) {
            self.verts[v] = from.verts[v];
            self.tris[v] = from.tris[v];
            v += 1;
        }
        self.n_planes = from.n_planes;
        self.n_verts = from.n_verts;
        self.start_radius2 = from.start_radius2;
    }

    /// An empty polyhedron (no vertices).
    pub fn empty() -> Self {
        Self {
            planes: [Vec4::ZERO; P],
            ids: [NO_ID; P],
            verts: [Point::ZERO; V],
            tris: [0; V],
            n_planes: 0,
            n_verts: 0,
            start_radius2: 0.0,
        }
    }

    /// The planes meeting at vertex `v`, ordered so that `det(n_a, n_b,
    /// n_c) > 0`: seen from outside face `a`, the next vertex
    /// counter-clockwise around it is the one whose triple, rotated to start
    /// with `a`, is `(a, c, _)` (the two share the edge where `a` and `c` meet).
    #[inline]
    pub fn vertex_planes(&self, v: usize) -> [u32; 3] {
        unpack(self.tris[v])
    }

    /// Whether nothing is left.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.n_verts == 0
    }

    /// Adds vertex `pos` where planes `a, b, c` meet, ordered so that
    /// `det(n_a, n_b, n_c) > 0` (the orientation every clip preserves).
    fn add_corner(&mut self, a: u32, b: u32, c: u32, pos: Point) {
        let na = normal(self.planes[a as usize]);
        let nb = normal(self.planes[b as usize]);
        let nc = normal(self.planes[c as usize]);
        let t = if na.cross(nb).dot(nc) > 0.0 { pack(a, b, c) } else { pack(a, c, b) };
        self.tris[self.n_verts as usize] = t;
        self.verts[self.n_verts as usize] = pos;
        self.n_verts += 1;
    }

    /// The tetrahedron `v` (any orientation), relative to the local origin.
    pub fn tetrahedron(v: [Vec3; 4]) -> Self {
        let mut p = Self::empty();
        p.set_tetrahedron(v);
        p
    }

    /// Makes this polyhedron the tetrahedron `v`, reusing its storage.
    pub fn set_tetrahedron(&mut self, v: [Vec3; 4]) {
        let planes = tet_planes(v);
        let v = [Point::from(v[0]), Point::from(v[1]), Point::from(v[2]), Point::from(v[3])];
        let p = self;
        p.n_verts = 0;
        let mut i = 0;
        while i < 4 {
            p.planes[i] = planes[i];
            p.ids[i] = TET_FACE + i as u32;
            i += 1;
        }
        p.n_planes = 4;
        p.start_radius2 =
            v[0].length_squared().max(v[1].length_squared()).max(v[2].length_squared()).max(v[3].length_squared());
        let mut i = 0u32;
        while i < 4 {
            // Vertex i lies on the three faces other than face i.
            p.add_corner((i + 1) % 4, (i + 2) % 4, (i + 3) % 4, v[i as usize]);
            i += 1;
        }
    }

    /// The axis-aligned box `[lo, hi]`, relative to the local origin.
    pub fn cuboid(lo: Vec3, hi: Vec3) -> Self {
        let mut p = Self::empty();
        p.set_cuboid(lo, hi);
        p
    }

    /// Makes this polyhedron the box `[lo, hi]`, reusing its storage.
    pub fn set_cuboid(&mut self, lo: Vec3, hi: Vec3) {
        let p = self;
        p.n_verts = 0;
        // Planes: 0 -x, 1 +x, 2 -y, 3 +y, 4 -z, 5 +z.
        p.planes[0] = Vec4::new(-1.0, 0.0, 0.0, -lo.x);
        p.planes[1] = Vec4::new(1.0, 0.0, 0.0, hi.x);
        p.planes[2] = Vec4::new(0.0, -1.0, 0.0, -lo.y);
        p.planes[3] = Vec4::new(0.0, 1.0, 0.0, hi.y);
        p.planes[4] = Vec4::new(0.0, 0.0, -1.0, -lo.z);
        p.planes[5] = Vec4::new(0.0, 0.0, 1.0, hi.z);
        let mut k = 0;
        while k < 6 {
            p.ids[k] = NO_ID;
            k += 1;
        }
        p.n_planes = 6;
        p.start_radius2 = lo.length_squared().max(hi.length_squared()) * 3.0;
        let mut corner = 0u32;
        while corner < 8 {
            let sx = corner & 1;
            let sy = (corner >> 1) & 1;
            let sz = (corner >> 2) & 1;
            let pos = Point::new(
                if sx == 1 { hi.x } else { lo.x },
                if sy == 1 { hi.y } else { lo.y },
                if sz == 1 { hi.z } else { lo.z },
            );
            p.add_corner(sx, 2 + sy, 4 + sz, pos);
            corner += 1;
        }
    }

    /// The planes some vertex uses — the faces — as bits (`P <= 64`).
    #[inline]
    pub fn face_mask(&self) -> u64 {
        let mut mask = 0u64;
        let mut i = 0;
        while i < (self.n_verts as usize).min(V) {
            let [a, b, c] = unpack(self.tris[i]);
            mask |= (1u64 << a) | (1u64 << b) | (1u64 << c);
            i += 1;
        }
        mask
    }

    /// Whether a side of the box this polyhedron started as
    /// ([`Self::set_cuboid`]: the planes of id [`NO_ID`]) is still a face,
    /// wherever a recycling of planes moved it.
    #[inline]
    pub fn has_box_face(&self) -> bool {
        let faces = self.face_mask();
        let mut p = 0;
        while p < (self.n_planes as usize).min(P) {
            if (faces >> p) & 1 != 0 && self.ids[p] == NO_ID {
                return true;
            }
            p += 1;
        }
        false
    }

    /// Whether a plane in use was made by site `id`.
    #[inline]
    pub fn has_plane_of(&self, id: u32) -> bool {
        let mut p = 0;
        while p < (self.n_planes as usize).min(P) {
            if self.ids[p] == id {
                return true;
            }
            p += 1;
        }
        false
    }

    /// The largest squared distance of a vertex from the local origin, and
    /// the centre and half-extent of the bounding box.
    pub fn bounds(&self) -> (f32, Point, Point) {
        let mut r = 0.0f32;
        let mut lo = Point::splat(f32::INFINITY);
        let mut hi = Point::splat(f32::NEG_INFINITY);
        let mut i = 0;
        while i < (self.n_verts as usize).min(V) {
            let v = self.verts[i];
            r = r.max(v.length_squared());
            lo = lo.min(v);
            hi = hi.max(v);
            i += 1;
        }
        (r, 0.5 * (lo + hi), 0.5 * (hi - lo))
    }

    /// Moves the polyhedron by `d`: from a frame at `d` to the frame it
    /// is in (its planes' offsets follow).
    #[inline]
    pub fn translate(&mut self, d: Vec3) {
        let d = Point::from(d);
        let mut q = 0;
        while q < (self.n_planes as usize).min(P) {
            let pl = self.planes[q];
            self.planes[q].w = pl.w + normal(pl).dot(d);
            q += 1;
        }
        let mut v = 0;
        while v < (self.n_verts as usize).min(V) {
            self.verts[v] += d;
            v += 1;
        }
    }

    /// Frees the planes no vertex uses, renumbering the rest.
    fn recycle_planes(&mut self) {
        let mut remap = [0xffu32; P];
        let mut i = 0;
        while i < self.n_verts as usize {
            let [a, b, c] = unpack(self.tris[i]);
            remap[a as usize] = 0;
            remap[b as usize] = 0;
            remap[c as usize] = 0;
            i += 1;
        }
        let mut used = 0u32;
        let mut p = 0;
        while p < self.n_planes as usize {
            if remap[p] == 0 {
                self.planes[used as usize] = self.planes[p];
                self.ids[used as usize] = self.ids[p];
                remap[p] = used;
                used += 1;
            }
            p += 1;
        }
        self.n_planes = used;
        let mut i = 0;
        while i < self.n_verts as usize {
            let [a, b, c] = unpack(self.tris[i]);
            self.tris[i] = pack(remap[a as usize], remap[b as usize], remap[c as usize]);
            i += 1;
        }
    }

    /// Keeps the part with `n·x <= d` (`plane = (n, d)`).
    pub fn clip(&mut self, plane: Vec4) -> Clip {
        self.clip_as(plane, NO_ID)
    }

    /// A plane that leaves the polyhedron unchanged but lies on one of its
    /// tet's faces (a bisector through a face of the mesh: sites on a
    /// lattice in a lattice's mesh) makes that face: it takes the plane's
    /// id, so that the face between the two cells is not taken for the
    /// inside of one.
    #[inline]
    fn claim_tet_face(&mut self, plane: Vec4, id: u32) {
        if !made_by_site(id) {
            return;
        }
        let n = normal(plane);
        let len = n.length();
        if len == 0.0 {
            return;
        }
        let mut q = 0;
        while q < (self.n_planes as usize).min(P) {
            let other = self.planes[q];
            let m = normal(other);
            let m_len = m.length();
            if (TET_FACE..NO_ID).contains(&self.ids[q]) && m_len > 0.0 {
                let (a, b) = (plane.w / len, other.w / m_len);
                let along = (n / len - m / m_len).length_squared();
                if along <= 1e-10 && (a - b).abs() <= 1e-5 * a.abs().max(b.abs()) {
                    self.ids[q] = id;
                }
            }
            q += 1;
        }
    }

    /// Like [`Self::clip`], recording `id` as the new plane's maker.
    pub fn clip_as(&mut self, plane: Vec4, id: u32) -> Clip {
        let () = Self::PLANES_FIT;
        let plane = normalized(plane);
        if self.n_planes as usize == P {
            self.recycle_planes();
            if self.n_planes as usize == P {
                return Clip::Overflow;
            }
        }
        let n_old = (self.n_verts as usize).min(V);
        let n = normal(plane);
        // One test per vertex, listing the removed ones without a branch;
        // and the range of `n·v`, to see where the plane only touches.
        let mut out = [0u32; V];
        let mut r = 0;
        let (mut low, mut high) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut i = 0;
        while i < n_old {
            out[r] = i as u32;
            let dn = self.verts[i].dot(n);
            r += (dn > plane.w) as usize;
            low = low.min(dn);
            high = high.max(dn);
            i += 1;
        }
        // What rounding leaves of a point on the plane.
        let rounding = 1e-6 * (low.abs().max(high.abs()) + plane.w.abs());
        if r == 0 {
            if high >= plane.w - rounding {
                self.claim_tet_face(plane, id);
            }
            return Clip::Unchanged;
        }
        // Nothing kept but points on the plane, to rounding: a flat piece
        // (a tet on the far side of a bisector lying on its face), empty.
        if r == n_old || low >= plane.w - rounding {
            self.n_verts = 0;
            return Clip::Empty;
        }
        let new_plane = self.n_planes;
        self.planes[new_plane as usize] = plane;
        self.ids[new_plane as usize] = id;
        // A plane through a point where more than three planes meet (a
        // corner of a lattice's cell on a face of its tet) finds there one
        // vertex per triple, all at that point to rounding; rounding may
        // remove some of them and keep others, and the removed vertices
        // then need not be connected: the plane crosses a face twice (two
        // crossing edges `x -> y` with the same `y`), two vertices would
        // hold the same edge, and later clips would drop part of the
        // piece. Then the vertices within rounding above the plane are
        // kept (they are on it, to rounding) and the cut is made again; a
        // face still crossed twice breaks the clip. The new vertices go
        // after the old ones, which stay as they are until the cut is
        // known to be whole.
        let mut attempt = 0;
        let n_new = loop {
            // The removed vertices' directed edges, by plane: bit `y` of
            // `from[x]` for each edge `x -> y` (plane numbers are below 64).
            let mut from = [0u64; P];
            let mut a = 0;
            while a < r {
                let [x, y, z] = unpack(self.tris[out[a] as usize]);
                from[x as usize] |= 1u64 << y;
                from[y as usize] |= 1u64 << z;
                from[z as usize] |= 1u64 << x;
                a += 1;
            }
            // Each edge x -> y of a removed vertex whose reverse y -> x is
            // not also a removed vertex's crosses the plane: it gets a new
            // vertex, which inherits the edge's direction, so orientation
            // is preserved. The new vertex slides from the removed one
            // along the edge (the line where planes x and y meet) to the
            // plane. Each face is entered once.
            let mut entered = 0u64;
            let mut twice = false;
            let mut n_new = n_old;
            let mut a = 0;
            while a < r {
                let t = out[a] as usize;
                let tri = unpack(self.tris[t]);
                let mut e = 0;
                while e < 3 {
                    let x = tri[e];
                    let y = tri[(e + 1) % 3];
                    if (from[y as usize] >> x) & 1 == 0 {
                        if n_new == V {
                            return Clip::Overflow;
                        }
                        twice |= (entered >> y) & 1 != 0;
                        entered |= 1u64 << y;
                        let v_out = self.verts[t];
                        let dir = normal(self.planes[x as usize]).cross(normal(self.planes[y as usize]));
                        let along = n.dot(dir);
                        self.verts[n_new] = if along * along > 1e-12 * n.length_squared() * dir.length_squared() {
                            v_out + dir * ((plane.w - n.dot(v_out)) / along)
                        } else {
                            // The edge is (nearly) parallel to the plane:
                            // both ends are about as far from it, and the
                            // line intersection is ill-conditioned.
                            // Interpolate between the edge's ends by their
                            // distances (a point of the edge, whatever the
                            // rounding). The other end is the kept vertex
                            // with edge y -> x.
                            let mut b = 0;
                            while b < n_old && !has_edge(self.tris[b], y, x) {
                                b += 1;
                            }
                            if b == n_old {
                                return Clip::Broken;
                            }
                            let v_in = self.verts[b];
                            let (d_out, d_in) = (n.dot(v_out) - plane.w, n.dot(v_in) - plane.w);
                            v_out + (v_in - v_out) * (d_out / (d_out - d_in))
                        };
                        self.tris[n_new] = pack(x, y, new_plane);
                        n_new += 1;
                    }
                    e += 1;
                }
                a += 1;
            }
            if !twice {
                break n_new;
            }
            if attempt == 1 {
                return Clip::Broken;
            }
            attempt = 1;
            let mut kept = 0;
            let mut a = 0;
            while a < r {
                out[kept] = out[a];
                kept += (self.verts[out[a] as usize].dot(n) > plane.w + rounding) as usize;
                a += 1;
            }
            r = kept;
            if r == 0 {
                self.claim_tet_face(plane, id);
                return Clip::Unchanged;
            }
        };
        // Fill the removed slots with the last kept or new vertices (highest
        // removed slot first, so every vertex moved is one to keep).
        let mut end = n_new;
        let mut a = r;
        while a > 0 {
            a -= 1;
            let slot = out[a] as usize;
            end -= 1;
            if slot != end {
                self.verts[slot] = self.verts[end];
                self.tris[slot] = self.tris[end];
            }
        }
        self.n_verts = end as u32;
        self.n_planes += 1;
        Clip::Cut
    }

    /// The frame the moments are taken in: the mean `o` of the vertices
    /// (inside the piece, which is convex), the squared half-diagonal `h²`
    /// of the bounding box, and whether the piece is much smaller than the
    /// shape it was cut from (`16 h² < R²`, `R` the start's radius). Cones
    /// from the site of a piece far from it (in a long cell, or a cell cut
    /// from a big tet) have volumes of order `L² h` that cancel to `h³` (`L`
    /// the distance, `h` the size), and their f32 sums lose `L/h` of their
    /// precision; cones from inside the piece add up without cancelling. A
    /// plane `(n, d)` is `(n, d - n·o)` there.
    #[inline]
    fn frame(&self) -> (Point, f32, bool) {
        let n = (self.n_verts as usize).min(V);
        let mut sum = Point::ZERO;
        let mut lo = Point::splat(f32::INFINITY);
        let mut hi = Point::splat(f32::NEG_INFINITY);
        let mut i = 0;
        while i < n {
            let v = self.verts[i];
            sum += v;
            lo = lo.min(v);
            hi = hi.max(v);
            i += 1;
        }
        let o = if n > 0 { sum / n as f32 } else { Point::ZERO };
        let h2 = (0.5 * (hi - lo)).length_squared();
        (o, h2, 16.0 * h2 < self.start_radius2)
    }

    /// Rebuilds this piece in `q`, relative to the frame's origin `o`: its
    /// bounding box grown to 1.5 times its extent, clipped by its faces'
    /// planes (each new plane's id is its number here). The vertices then
    /// come from corners as far from each other as the piece is large, not
    /// from a tet's far corners. Returns false (leaving `q` unusable) where
    /// the clips fail or a box plane survives.
    fn rebuild_into(&self, q: &mut Self, o: Point) -> bool {
        let (_, mid, half) = self.bounds();
        let h = half * 1.5 + Point::splat(1e-3 * half.max_element());
        q.set_cuboid(Vec3::from(mid - o - h), Vec3::from(mid - o + h));
        q.start_radius2 = 0.0;
        let faces = self.face_mask();
        let mut p = 0;
        while p < (self.n_planes as usize).min(P) {
            if (faces >> p) & 1 != 0 {
                let plane = self.planes[p];
                match q.clip_as(plane.truncate().extend(plane.w - normal(plane).dot(o)), p as u32) {
                    Clip::Cut | Clip::Unchanged => {}
                    _ => return false,
                }
            }
            p += 1;
        }
        // No side of the box may be a face.
        !q.has_box_face()
    }

    /// The area of each face, by plane number (the planes no vertex uses
    /// get 0), from the same vertex-local triangles as [`Self::moments`]:
    /// vertex `v` with edge `x -> y` owns the triangles `(c_x, f, v)` on face
    /// `x` and `(c_y, v, f)` on face `y`. As `c_x` is parallel to `n_x`, the
    /// first's area along `n̂_x` is `½ (f × v)·n̂_x`, and `f × v = w` of
    /// [`add_corner_edge`]: each edge adds `½ w·n_x` to face `x` and takes
    /// `½ w·n_y` from face `y`, scaled by `1/|n|` once per face — in the
    /// moments' own pass ([`Self::moments_and_areas`]).
    pub fn face_areas(&self) -> [f32; P] {
        let mut areas = [0.0f32; P];
        self.moments_with::<true>(&mut areas);
        areas
    }

    /// Volume, first and second moments about the local origin (the site),
    /// from vertex-local pieces only (no adjacency search), taken around
    /// the piece ([`Self::frame`]): each face is fanned from the foot `c_x`
    /// of the perpendicular from the frame's origin to its plane, and each
    /// fan triangle is split at the foot `f` of the perpendicular to its
    /// edge's line, so a vertex `v` with edge `x -> y` owns the triangles
    /// `(c_x, f, v)` on face `x` and `(c_y, v, f)` on face `y`; each
    /// triangle is coned to the frame's origin (signed tets). `|f| <= |v|`,
    /// so no far-away point enters the sums.
    pub fn moments(&self) -> Moments {
        let mut unused = [0.0f32; P];
        self.moments_with::<false>(&mut unused)
    }

    /// [`Self::moments`] and, in the same pass over the vertices, each
    /// face's area by plane number as [`Self::face_areas`] gives it.
    pub fn moments_and_areas(&self, areas: &mut [f32; P]) -> Moments {
        self.moments_with::<true>(areas)
    }

    /// The moments (and with `AREAS` the face areas), relative to the site,
    /// taken around the piece ([`Self::frame`]), each vertex moved onto its
    /// three planes first ([`Self::integrate`]). That needs each vertex's
    /// planes to be independent: where some are nearly dependent and the
    /// vertex is off them, its place along its edge is what the clip made
    /// it, and moving its neighbours would no longer match it (rare: 41 of
    /// 408 000 pieces on joint_31k with 35 000 sites). Such a piece, when
    /// much smaller than its tet, is rebuilt around itself
    /// ([`Self::rebuilt_moments`]); else it is taken as the clips made it.
    #[inline]
    fn moments_with<const AREAS: bool>(&self, areas: &mut [f32; P]) -> Moments {
        let (o, h2, small) = self.frame();
        let (mut m, ok) = self.integrate::<AREAS, true>(o, h2, areas);
        if !ok {
            *areas = [0.0f32; P];
            let mut rebuilt = false;
            if small {
                (m, rebuilt) = self.rebuilt_moments::<AREAS>(o, areas);
            }
            if !rebuilt {
                *areas = [0.0f32; P];
                (m, _) = self.integrate::<AREAS, false>(o, h2, areas);
            }
        }
        moved_back(m, o)
    }

    /// The moments (and with `AREAS` the face areas, into `areas`, zeroed
    /// first) of this piece rebuilt around `o` ([`Self::rebuild_into`]),
    /// relative to `o`; false where the rebuild failed.
    fn rebuilt_moments<const AREAS: bool>(&self, o: Point, areas: &mut [f32; P]) -> (Moments, bool) {
        let mut q = Self::empty();
        if !self.rebuild_into(&mut q, o) {
            return (Moments::default(), false);
        }
        let mut local = [0.0f32; P];
        let (m, _) = q.integrate::<AREAS, false>(Point::ZERO, 0.0, &mut local);
        if AREAS {
            // The rebuilt planes' ids are the planes' numbers here.
            *areas = [0.0f32; P];
            let mut k = 0;
            while k < (q.n_planes as usize).min(P) {
                if q.ids[k] != NO_ID {
                    areas[q.ids[k] as usize] = local[k];
                }
                k += 1;
            }
        }
        (m, true)
    }

    /// The moments (and with `AREAS` the face areas) relative to the
    /// frame's origin `o` (`h2`: the piece's squared size). With `REFINE`,
    /// each vertex whose planes are independent is first moved onto them
    /// ([`refined`], from the residuals the moments need anyway), and false
    /// is returned (with nothing summed usefully) where a vertex whose
    /// planes are nearly dependent (`det² <= 1e-4` for normals scaled as
    /// [`normalized`] scales them, so that `|det| <= 42`) is off them by
    /// more than rounding.
    #[inline]
    fn integrate<const AREAS: bool, const REFINE: bool>(
        &self,
        o: Point,
        h2: f32,
        areas: &mut [f32; P],
    ) -> (Moments, bool) {
        // Per plane: the foot c (from o) and 3|c|², and the offset there.
        let mut feet = [Vec4::ZERO; P];
        let mut offsets = [0.0f32; P];
        let mut p = 0;
        while p < (self.n_planes as usize).min(P) {
            let n = self.planes[p].truncate();
            offsets[p] = self.planes[p].w - n.dot(Vec3::from(o));
            let c = n * (offsets[p] / n.length_squared());
            feet[p] = c.extend(3.0 * c.length_squared());
            p += 1;
        }
        // Residuals below this are the rounding of `n·v` itself (normals'
        // lengths are at most 3.5, `|v| <= 2h` from o).
        let rounding2 = 1e-14 * h2;
        // Summed as 6 V, 24 ∫x and 60 ∫|x|²: the cones' constant factors
        // are applied once, at the end.
        let mut m = Sums::default();
        let mut i = 0;
        while i < (self.n_verts as usize).min(V) {
            let [a, b, c] = unpack(self.tris[i]);
            let (na, nb, nc) =
                (normal(self.planes[a as usize]), normal(self.planes[b as usize]), normal(self.planes[c as usize]));
            let (ab, bc, ca) = (na.cross(nb), nb.cross(nc), nc.cross(na));
            let mut v = self.verts[i] - o;
            let (mut va, mut vb, mut vc) = (v.dot(na), v.dot(nb), v.dot(nc));
            if REFINE {
                let (da, db, dc) = (offsets[a as usize], offsets[b as usize], offsets[c as usize]);
                let (ra, rb, rc) = (da - va, db - vb, dc - vc);
                let det = na.dot(bc);
                if det * det > 1e-4 {
                    v = refined(v, [ra, rb, rc], [ab, bc, ca], det);
                    (va, vb, vc) = (da, db, dc);
                } else if ra * ra > rounding2 || rb * rb > rounding2 || rc * rc > rounding2 {
                    return (Moments::default(), false);
                }
            }
            let vv = v.length_squared();
            let wab = add_corner_edge(&mut m, &feet, v, vv, (a, na, va), (b, nb, vb), ab);
            let wbc = add_corner_edge(&mut m, &feet, v, vv, (b, nb, vb), (c, nc, vc), bc);
            let wca = add_corner_edge(&mut m, &feet, v, vv, (c, nc, vc), (a, na, va), ca);
            if AREAS {
                // See `face_areas`: each edge x -> y adds ½ w·n_x to face x
                // and takes ½ w·n_y from face y.
                areas[a as usize] += 0.5 * (wab.dot(na) - wca.dot(na));
                areas[b as usize] += 0.5 * (wbc.dot(nb) - wab.dot(nb));
                areas[c as usize] += 0.5 * (wca.dot(nc) - wbc.dot(nc));
            }
            i += 1;
        }
        if AREAS {
            let mut p = 0;
            while p < (self.n_planes as usize).min(P) {
                let len = normal(self.planes[p]).length();
                areas[p] = if len > 0.0 { areas[p] / len } else { 0.0 };
                p += 1;
            }
        }
        (Moments { volume: m.volume / 6.0, first: Vec3::from(m.first) / 24.0, second: m.second / 60.0 }, true)
    }
}

/// Vertex `v`, moved onto its three planes (residuals `r = d - n·v`, `x`
/// the crosses `n_a × n_b, n_b × n_c, n_c × n_a` and `det = n_a·(n_b ×
/// n_c)`, not near 0): one step of iterative refinement, `v + N⁻¹ r` by
/// Cramer's rule. A vertex made by sliding along an edge from a far one (a
/// tet's corner, `L` away) carries an error `~ε L`, where its planes
/// (accurate relative to the cell) and the vertex itself (`|v| ~ h` from
/// the frame's origin inside the piece) give residuals accurate to `ε h`:
/// the step brings it to `~ε h`.
#[inline]
fn refined(v: Point, [ra, rb, rc]: [f32; 3], [ab, bc, ca]: [Point; 3], det: f32) -> Point {
    v + (bc * ra + ca * rb + ab * rc) / det
}

/// Moments relative to a frame at `o`, moved back to the site: `∫x = ∫x' +
/// o V` and `∫|x|² = ∫|x'|² + 2 o·∫x' + |o|² V`.
#[inline]
fn moved_back(m: Moments, o: Point) -> Moments {
    let o = Vec3::from(o);
    Moments {
        volume: m.volume,
        first: m.first + o * m.volume,
        second: m.second + 2.0 * o.dot(m.first) + o.length_squared() * m.volume,
    }
}

/// The two cones of vertex `v` at its edge `x -> y` (each plane with its
/// normal `n` and `v·n`; `u = n_x × n_y`), added as 6 V, 24 ∫x and 60 ∫|x|². Every point of
/// a cone's base triangle lies on the base's plane and `f` is the foot on
/// the edge line, so the cross terms of the second moment reduce: `c·v =
/// c·f = |c|²` and `f·v = |f|²`; with `u = n_x × n_y`, `f = v - s u`,
/// `|f|² = |v|² - s (v·u)` and `f × v = s (v × u) = s (n_x (v·n_y) - n_y
/// (v·n_x))`: returns that `w = f × v`.
#[inline]
fn add_corner_edge<const P: usize>(
    m: &mut Sums,
    feet: &[Vec4; P],
    v: Point,
    vv: f32,
    (x, nx, vx): (u32, Point, f32),
    (y, ny, vy): (u32, Point, f32),
    u: Point,
) -> Point {
    let cx = feet[x as usize];
    let cy = feet[y as usize];
    let (cx3, cy3) = (normal(cx), normal(cy));
    let uu = u.length_squared();
    let vu = v.dot(u);
    let s = if uu > 0.0 { vu / uu } else { 0.0 };
    let f = v - u * s;
    let w = (nx * vy - ny * vx) * s;
    // 6x the signed volumes of (0, c_x, f, v) and (0, c_y, v, f).
    let vol_x = cx3.dot(w);
    let vol_y = -cy3.dot(w);
    let vol = vol_x + vol_y;
    let ff = vv - s * vu;
    m.volume += vol;
    m.first += (f + v) * vol + cx3 * vol_x + cy3 * vol_y;
    m.second += vol_x * cx.w + vol_y * cy.w + vol * (2.0 * ff + vv);
    w
}

impl<const P: usize, const V: usize> Polyhedron<P, V> {
    /// Integrals under the linear density `ρ(x) = rho0 + g·x` (relative to
    /// the local origin): mass `∫ρ`, first moment `∫ρ x`, second moment
    /// `∫ρ |x|²`, returned as [`Moments`], and the plain volume. Same cones
    /// as [`Self::moments`], each integrated in full: over a tet `(0, a, b,
    /// c)` of volume `v`, with `s = a + b + c` and sums over `p ∈ {a, b,
    /// c}`, `∫x xᵀ = v/20 (Σ p pᵀ + s sᵀ)` and `∫x |x|² = v/120 (s |s|² +
    /// s Σ|p|² + 2 Σ p (p·s) + 2 Σ p |p|²)` (moments of a simplex).
    pub fn moments_linear(&self, rho0: f32, g: Vec3) -> (Moments, f32) {
        // As `moments_with`, with the density moved to each frame: around
        // o, ρ = (rho0 + g·o) + g·x'.
        let (o, h2, small) = self.frame();
        let rho_o = rho0 + g.dot(Vec3::from(o));
        let (mut m, mut volume, ok) = self.integrate_linear::<true>(o, h2, rho_o, g);
        if !ok {
            let mut rebuilt = false;
            if small {
                let mut q = Self::empty();
                if self.rebuild_into(&mut q, o) {
                    (m, volume, _) = q.integrate_linear::<false>(Point::ZERO, 0.0, rho_o, g);
                    rebuilt = true;
                }
            }
            if !rebuilt {
                (m, volume, _) = self.integrate_linear::<false>(o, h2, rho_o, g);
            }
        }
        (moved_back(m, o), volume)
    }

    /// [`Self::moments_linear`] relative to the frame's origin `o` (the
    /// density `rho0 + g·x'` there), as [`Self::integrate`] takes them, and
    /// the plain volume.
    #[inline]
    fn integrate_linear<const REFINE: bool>(&self, o: Point, h2: f32, rho0: f32, g: Vec3) -> (Moments, f32, bool) {
        let mut feet = [Vec3::ZERO; P];
        let mut offsets = [0.0f32; P];
        let mut p = 0;
        while p < (self.n_planes as usize).min(P) {
            let n = self.planes[p].truncate();
            offsets[p] = self.planes[p].w - n.dot(Vec3::from(o));
            feet[p] = n * (offsets[p] / n.length_squared());
            p += 1;
        }
        let rounding2 = 1e-14 * h2;
        let mut acc = Linear::default();
        let mut i = 0;
        while i < (self.n_verts as usize).min(V) {
            let t = unpack(self.tris[i]);
            let (na, nb, nc) = (
                normal(self.planes[t[0] as usize]),
                normal(self.planes[t[1] as usize]),
                normal(self.planes[t[2] as usize]),
            );
            let mut v = self.verts[i] - o;
            if REFINE {
                // As `integrate` does.
                let r = [
                    offsets[t[0] as usize] - v.dot(na),
                    offsets[t[1] as usize] - v.dot(nb),
                    offsets[t[2] as usize] - v.dot(nc),
                ];
                let (ab, bc, ca) = (na.cross(nb), nb.cross(nc), nc.cross(na));
                let det = na.dot(bc);
                if det * det > 1e-4 {
                    v = refined(v, r, [ab, bc, ca], det);
                } else if r[0] * r[0] > rounding2 || r[1] * r[1] > rounding2 || r[2] * r[2] > rounding2 {
                    return (Moments::default(), 0.0, false);
                }
            }
            let v = Vec3::from(v);
            let mut e = 0;
            while e < 3 {
                let (x, y) = (t[e], t[(e + 1) % 3]);
                let u = self.planes[x as usize].truncate().cross(self.planes[y as usize].truncate());
                let uu = u.length_squared();
                let f = if uu > 0.0 { v - u * (v.dot(u) / uu) } else { v };
                acc.add_cone(feet[x as usize], f, v, g);
                acc.add_cone(feet[y as usize], v, f, g);
                e += 1;
            }
            i += 1;
        }
        let m = Moments {
            volume: rho0 * acc.volume + g.dot(acc.first),
            first: acc.first * rho0 + acc.second_g,
            second: rho0 * acc.second + acc.third_g,
        };
        (m, acc.volume, true)
    }
}

/// Running sums of [`Polyhedron::moments_linear`]: `∫1`, `∫x`, `∫|x|²`,
/// `∫x (x·g)` and `∫(x·g) |x|²`.
#[derive(Default)]
struct Linear {
    volume: f32,
    first: Vec3,
    second: f32,
    second_g: Vec3,
    third_g: f32,
}

impl Linear {
    /// Adds the signed tet `(0, a, b, c)`.
    #[inline]
    fn add_cone(&mut self, a: Vec3, b: Vec3, c: Vec3, g: Vec3) {
        let v = a.dot(b.cross(c)) / 6.0;
        let s = a + b + c;
        let (aa, bb, cc, ss) = (a.length_squared(), b.length_squared(), c.length_squared(), s.length_squared());
        let (ag, bg, cg, sg) = (a.dot(g), b.dot(g), c.dot(g), s.dot(g));
        let sum_pp = aa + bb + cc;
        self.volume += v;
        self.first += s * (v / 4.0);
        self.second += v / 20.0 * (sum_pp + ss);
        self.second_g += (a * ag + b * bg + c * cg + s * sg) * (v / 20.0);
        let p_ps_g = ag * a.dot(s) + bg * b.dot(s) + cg * c.dot(s);
        let pp_pg = aa * ag + bb * bg + cc * cg;
        self.third_g += v / 120.0 * (ss * sg + sum_pp * sg + 2.0 * p_ps_g + 2.0 * pp_pg);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol * b.abs().max(1.0)
    }

    #[test]
    fn cube_moments() {
        let p = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        let m = p.moments();
        assert!(close(m.volume, 8.0, 1e-6), "{m:?}");
        assert!(m.first.length() < 1e-5, "{m:?}");
        assert!(close(m.second, 8.0, 1e-6), "{m:?}");
    }

    #[test]
    fn tet_moments_either_orientation() {
        let v =
            [Vec3::new(0.1, 0.2, 0.3), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 0.0, 1.0)];
        let vol = ((v[1] - v[0]).cross(v[2] - v[0]).dot(v[3] - v[0]) / 6.0).abs();
        let centroid = (v[0] + v[1] + v[2] + v[3]) / 4.0;
        for order in [[0, 1, 2, 3], [1, 0, 2, 3]] {
            let m = Cell::tetrahedron(order.map(|i| v[i])).moments();
            assert!(close(m.volume, vol, 1e-5), "{m:?} vs {vol}");
            assert!((m.first / m.volume - centroid).length() < 1e-5, "{m:?}");
        }
    }

    #[test]
    fn linear_density_moments_of_a_cube() {
        // ρ = 1 + 10x on [0, 1]³: mass 6, ∫ρx = 23/6, ∫ρ y = 3,
        // ∫ρ|x|² = 1 + 10 (1/4 + 2/6) = 41/6.
        let p = Cell::cuboid(Vec3::ZERO, Vec3::ONE);
        let (m, v) = p.moments_linear(1.0, Vec3::new(10.0, 0.0, 0.0));
        assert!(close(v, 1.0, 1e-6), "{v}");
        assert!(close(m.volume, 6.0, 1e-6), "{m:?}");
        assert!(close(m.first.x, 23.0 / 6.0, 1e-6) && close(m.first.y, 3.0, 1e-6), "{m:?}");
        assert!(close(m.second, 41.0 / 6.0, 1e-6), "{m:?}");
        // A constant density scales the plain moments; a clipped shape too.
        let mut q = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        q.clip(Vec4::new(1.0, 2.0, 0.5, 0.3));
        let (plain, (lin, v)) = (q.moments(), q.moments_linear(2.5, Vec3::ZERO));
        assert!(close(lin.volume, 2.5 * plain.volume, 1e-5) && close(v, plain.volume, 1e-5));
        assert!((lin.first - plain.first * 2.5).length() < 1e-5 && close(lin.second, 2.5 * plain.second, 1e-5));
    }

    /// A cell of size 1 cut out of a tet 1 000 times larger: its vertices
    /// slid from corners 1 000 away, off by about `ε · 1000`; refined onto
    /// their planes before the moments, the cell is exact to f32.
    #[test]
    fn a_small_cell_in_a_big_tet_is_refined() {
        let m = slanted_box_in_a_big_tet(Vec3::ZERO).moments();
        assert!(close(m.volume, 1.0, 1e-6), "{m:?}");
        assert!(m.first.length() < 1e-6 && close(m.second, 0.25, 1e-6), "{m:?}");
    }

    /// A slanted unit box (three pairs of planes, `|(x - c)·n| <= 0.5` along
    /// a frame) centred at `c`, cut out of a tet 1 000 times larger around
    /// the origin.
    fn slanted_box_in_a_big_tet(c: Vec3) -> Cell {
        let big = [
            Vec3::new(-1000.0, -1000.0, -1000.0),
            Vec3::new(3000.0, -900.0, -1100.0),
            Vec3::new(-800.0, 2900.0, -950.0),
            Vec3::new(-1050.0, -1020.0, 3100.0),
        ];
        let mut p = Cell::tetrahedron(big);
        let (a, b) = (Vec3::new(0.8, 0.6, 0.0), Vec3::new(-0.36, 0.48, 0.8));
        for n in [a, b, a.cross(b)] {
            assert_eq!(p.clip(n.extend(n.dot(c) + 0.5)), Clip::Cut);
            assert_eq!(p.clip((-n).extend(-n.dot(c) + 0.5)), Clip::Cut);
        }
        p
    }

    /// A piece 300 times its size away from its origin (a piece far along
    /// a long cell): its cones from the origin would cancel to `1/300³` of
    /// themselves; integrated around itself, it keeps f32's precision —
    /// volume, centroid and second moment about the origin.
    #[test]
    fn a_piece_far_from_its_origin_keeps_its_precision() {
        let c = Vec3::new(170.0, -190.0, 160.0);
        let p = slanted_box_in_a_big_tet(c);
        let m = p.moments();
        assert!(close(m.volume, 1.0, 1e-6), "{m:?}");
        assert!((m.first / m.volume - c).length() < 1e-6 * c.length(), "{m:?}");
        assert!(close(m.second, c.length_squared() + 0.25, 1e-6), "{m:?}");
        // Under a linear density ρ = 2 + g·x, centred on the box: mass
        // ρ(c) (the box's volume is 1).
        let g = Vec3::new(0.01, 0.02, -0.03);
        let (lin, v) = p.moments_linear(2.0, g);
        assert!(close(v, 1.0, 1e-6) && close(lin.volume, 2.0 + g.dot(c), 1e-6), "{lin:?}");
    }

    /// Where three planes of a vertex are nearly dependent, refinement
    /// cannot move it (its place along its edge is what the clips made it):
    /// such a piece, much smaller than the tet its vertices slid from, is
    /// rebuilt around itself from a box of its own size. Two planes 1e-3
    /// apart in angle cut a corner off the box: the result does not depend
    /// on the shape it was cut from (the big tet, or a box just around it),
    /// and its face areas are those of the same piece.
    #[test]
    fn a_small_piece_with_nearly_dependent_planes_is_rebuilt() {
        let cuts = [Vec4::new(1.0, 1.0, 1.0, 0.9), Vec4::new(1.0, 1.001, 0.999, 0.9)];
        let mut far = slanted_box_in_a_big_tet(Vec3::ZERO);
        let mut near = Cell::tetrahedron([
            Vec3::new(-1.0, -1.0, -1.0),
            Vec3::new(3.0, -0.9, -1.1),
            Vec3::new(-0.8, 2.9, -0.95),
            Vec3::new(-1.05, -1.02, 3.1),
        ]);
        let (a, b) = (Vec3::new(0.8, 0.6, 0.0), Vec3::new(-0.36, 0.48, 0.8));
        for n in [a, b, a.cross(b)] {
            near.clip(n.extend(0.5));
            near.clip((-n).extend(0.5));
        }
        for plane in cuts {
            assert_eq!(far.clip(plane), Clip::Cut);
            assert_eq!(near.clip(plane), Clip::Cut);
        }
        let (o, h2, _) = far.frame();
        let refinable = far.integrate::<false, true>(o, h2, &mut [0.0; CELL_PLANES]).1;
        assert!(!refinable, "the cuts meet nearly dependent");
        let (mut af, mut an) = ([0.0f32; CELL_PLANES], [0.0f32; CELL_PLANES]);
        let (mf, mn) = (far.moments_and_areas(&mut af), near.moments_and_areas(&mut an));
        assert!(close(mf.volume, mn.volume, 1e-6), "{mf:?} vs {mn:?}");
        assert!((mf.first - mn.first).length() < 1e-6, "{mf:?} vs {mn:?}");
        assert!(close(mf.second, mn.second, 1e-6), "{mf:?} vs {mn:?}");
        // Both list the same planes after the tets' four: the box's six,
        // then the two cuts, whose common edge moves far along them with
        // any rounding (their areas' split is ill-conditioned, their sum
        // is not).
        let n = far.n_planes as usize;
        assert_eq!((n, near.n_planes), (12, 12));
        assert!((4..10).all(|k| close(af[k], an[k], 1e-6)), "{af:?} vs {an:?}");
        assert!(close(af[10] + af[11], an[10] + an[11], 1e-6), "{af:?} vs {an:?}");
    }

    /// Face areas: a unit cube's six are 1; a cell clipped many times is
    /// closed (its faces' area vectors sum to zero) and its volume is a
    /// third of the sum of its faces' areas times their distances from the
    /// origin (the divergence theorem), as the moments say.
    #[test]
    fn face_areas_close_and_agree_with_the_volume() {
        let cube = Cell::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5));
        let a = cube.face_areas();
        assert!((0..6).all(|f| close(a[f], 1.0, 1e-6)), "{:?}", &a[..6]);
        let mut p = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        let mut seed = 12345u32;
        let mut unit = || {
            seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            (seed >> 8) as f32 / (1u32 << 24) as f32
        };
        for _ in 0..30 {
            let n = Vec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize();
            p.clip(n.extend(0.3 + 0.6 * unit()));
        }
        // The origin outside, as for most pieces of a cell.
        assert_eq!(p.clip(Vec4::new(1.0, 0.2, 0.0, -0.1)), Clip::Cut);
        let a = p.face_areas();
        let (mut flux, mut cone) = (Vec3::ZERO, 0.0f32);
        for (plane, area) in p.planes.iter().zip(a).take(p.n_planes as usize) {
            let len = plane.truncate().length();
            flux += plane.truncate() / len * area;
            cone += area * plane.w / len / 3.0;
        }
        let m = p.moments();
        assert!(flux.length() < 1e-5, "{flux:?}");
        assert!(close(cone, m.volume, 1e-5), "{cone} vs {}", m.volume);
        // The same in the moments' own pass.
        let mut b = [0.0f32; CELL_PLANES];
        assert_eq!(p.moments_and_areas(&mut b), m);
        assert!(a.iter().zip(&b).all(|(x, y)| close(*x, *y, 1e-6)), "{a:?} vs {b:?}");
    }

    #[test]
    fn clipping_a_cube() {
        let mut p = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        assert_eq!(p.clip(Vec4::new(1.0, 0.0, 0.0, 0.3)), Clip::Cut);
        assert!(close(p.moments().volume, 5.2, 1e-5));
        assert_eq!(p.clip(Vec4::new(1.0, 0.0, 0.0, 2.0)), Clip::Unchanged);
        // An oblique plane through the centre halves the symmetric part.
        let mut q = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        assert_eq!(q.clip(Vec4::new(1.0, 1.0, 1.0, 0.0)), Clip::Cut);
        let m = q.moments();
        assert!(close(m.volume, 4.0, 1e-5), "{m:?}");
        assert!(close(m.second, 4.0, 1e-5), "{m:?}");
        // Corner cut: removes the tet x+y+z >= 2.5 near (1,1,1): volume 0.5^3/6.
        let mut c = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        assert_eq!(c.clip(Vec4::new(1.0, 1.0, 1.0, 2.5)), Clip::Cut);
        assert!(close(c.moments().volume, 8.0 - 0.125 / 6.0, 1e-5));
        assert_eq!(c.clip(Vec4::new(-1.0, 0.0, 0.0, -3.0)), Clip::Empty);
        assert!(c.is_empty());
    }

    #[test]
    fn many_clips_make_a_sphere_like_cell() {
        // Clip by tangent planes of the unit sphere: the volume decreases
        // toward the ball's and never below it.
        let mut p = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        let mut last = 8.0;
        let golden = 2.399_963_2f32;
        for i in 0..40 {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / 40.0;
            let r = (1.0 - z * z).sqrt();
            let n = Vec3::new(r * (golden * i as f32).cos(), r * (golden * i as f32).sin(), z);
            let c = p.clip(n.extend(1.0));
            assert!(c == Clip::Cut || c == Clip::Unchanged, "{c:?} at {i}");
            let v = p.moments().volume;
            assert!(v <= last + 1e-5 && v >= 4.18879, "{v} at {i}");
            last = v;
        }
    }

    /// Sites on a BCC lattice, one on an edge of its tet (the periodic
    /// box's repro): the octahedron its 8 nearest sites cut out has a
    /// corner on two of the tet's faces, where four planes meet, and the
    /// next bisector passes through it too. Rounding put one of the
    /// vertices there above that bisector and the others on it; removing
    /// that one alone crossed a face twice, and the square face cut next
    /// dropped a tenth of the piece. The piece (the site's cell in the tet,
    /// 8.2186777e-4 in f64) comes out whole.
    #[test]
    fn a_plane_through_a_corner_on_a_tet_face_cuts_once() {
        let mut p = Piece::tetrahedron([
            Vec3::new(-0.06666666, -0.06666667, -0.06666666),
            Vec3::new(-0.06666666, 0.26666665, -0.06666666),
            Vec3::new(0.26666668, 0.26666665, -0.06666666),
            Vec3::new(0.26666668, 0.26666665, 0.26666668),
        ]);
        // The bisectors, nearest first, as the kernels clip them (n, h).
        let cuts = [
            ([-0.12499999, 0.125, -0.12499999], 0.023437498, Clip::Cut),
            ([-0.125, 0.125, 0.12499999], 0.0234375, Clip::Cut),
            ([-0.12499999, -0.125, 0.125], 0.0234375, Clip::Unchanged),
            ([-0.125, -0.125, -0.12499999], 0.0234375, Clip::Cut),
            ([0.125, -0.125, -0.125], 0.0234375, Clip::Unchanged),
            ([0.125, 0.125, -0.125], 0.0234375, Clip::Cut),
            ([0.125, 0.125, 0.125], 0.0234375, Clip::Cut),
            ([0.125, -0.125, 0.125], 0.0234375, Clip::Unchanged),
            ([-6.351435e-10, 0.25, 4.4949218e-9], 0.03125, Clip::Cut),
        ];
        for (n, h, want) in cuts {
            assert_eq!(p.clip(Vec3::from(n).extend(h)), want, "{n:?}");
        }
        // Every directed edge once, and its reverse once.
        for v in 0..p.n_verts as usize {
            let t = p.vertex_planes(v);
            for e in 0..3 {
                let (x, y) = (t[e], t[(e + 1) % 3]);
                let held = |a, b| (0..p.n_verts as usize).filter(|&w| has_edge(p.tris[w], a, b)).count();
                assert_eq!((held(x, y), held(y, x)), (1, 1), "edge {x} -> {y}");
            }
        }
        let m = p.moments();
        assert!(close(m.volume, 8.218_678e-4, 1e-5), "{m:?}");
    }

    #[test]
    fn clip_order_does_not_change_the_result() {
        // Random planes through a cube, applied in two orders: the same
        // convex polyhedron must come out (volume, centroid, vertex count),
        // whichever vertices each clip removes along the way — many at once
        // included, which exercises the crossing-edge masks.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        for case in 0..200 {
            let planes: [Vec4; 12] = core::array::from_fn(|_| {
                let n = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
                n.extend(0.3 + 0.6 * next())
            });
            let run = |order: &mut dyn Iterator<Item = &Vec4>| {
                let mut p = Cell::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
                for &pl in order {
                    let c = p.clip(pl);
                    assert!(c == Clip::Cut || c == Clip::Unchanged, "case {case}: {c:?}");
                }
                p
            };
            let (a, b) = (run(&mut planes.iter()), run(&mut planes.iter().rev()));
            let (ma, mb) = (a.moments(), b.moments());
            assert!(close(ma.volume, mb.volume, 1e-5), "case {case}: {ma:?} vs {mb:?}");
            assert!((ma.first - mb.first).length() < 1e-5, "case {case}: {ma:?} vs {mb:?}");
            assert_eq!(a.n_verts, b.n_verts, "case {case}");
        }
    }
}
