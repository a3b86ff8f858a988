//! The periodic box: the unit cell of a space that repeats, its wrap of
//! points into it and its images.

use crate::error::{Error, Result};
use crate::geom::mesh::TetMesh;

/// The names of the three axes along the cell's vectors `a`, `b`, `c`
/// (x, y, z for an axis-aligned box).
const AXES: [&str; 3] = ["a (x)", "b (y)", "c (z)"];

/// The unit cell of a space that repeats: a parallelepiped, the points
/// `origin + s_a a + s_b b + s_c c` with `0 <= s < 1`, whose opposite
/// faces are glued along the periodic axes; along the others its two
/// faces are walls.
///
/// An axis-aligned box (`lo..hi`, [`Self::new`]) is the common case; a
/// triclinic cell is given by three lattice vectors ([`Self::triclinic`])
/// or by LAMMPS's bounds and tilts ([`Self::lammps`]). Points are moved
/// into it by whole lattice vectors, in lattice (fractional) coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeriodicBox {
    origin: [f64; 3],
    /// The cell's edge vectors `a`, `b`, `c`.
    vectors: [[f64; 3]; 3],
    /// Whether the space repeats along each vector (else: walls).
    periodic: [bool; 3],
    /// The reciprocal vectors: `reciprocal[a] · vectors[b] = δ_ab`, so a
    /// point's fractional coordinate along `a` is `reciprocal[a] · (p -
    /// origin)`.
    reciprocal: [[f64; 3]; 3],
    /// The corner opposite the origin (an axis-aligned box's `hi` as
    /// given).
    far: [f64; 3],
    /// Whether the vectors lie along x, y and z (the exact axis-aligned
    /// arithmetic applies).
    aligned: bool,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

impl PeriodicBox {
    /// The axis-aligned box `lo..hi` (finite, `lo < hi` along every axis),
    /// periodic along x, y and z.
    pub fn new(lo: [f64; 3], hi: [f64; 3]) -> Result<Self> {
        for a in 0..3 {
            if !(lo[a].is_finite() && hi[a].is_finite() && lo[a] < hi[a]) {
                return Err(Error::InvalidInput(format!(
                    "a periodic box needs finite corners with lo < hi along every axis; along {} it runs from {} to {}",
                    ["x", "y", "z"][a],
                    lo[a],
                    hi[a]
                )));
            }
        }
        let l = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let vectors = [[l[0], 0.0, 0.0], [0.0, l[1], 0.0], [0.0, 0.0, l[2]]];
        let reciprocal = [[1.0 / l[0], 0.0, 0.0], [0.0, 1.0 / l[1], 0.0], [0.0, 0.0, 1.0 / l[2]]];
        Ok(Self { origin: lo, vectors, periodic: [true; 3], reciprocal, far: hi, aligned: true })
    }

    /// The unit cube `0..1` along each axis.
    pub fn unit() -> Self {
        Self::new([0.0; 3], [1.0; 3]).expect("the unit cube is a box")
    }

    /// The triclinic cell at `origin` with edge vectors `vectors` (`a`,
    /// `b`, `c`: finite, a right-handed frame, `(a × b) · c > 0`),
    /// periodic along all three. Vectors along x, y and z make the
    /// axis-aligned box `origin..origin + a + b + c`.
    pub fn triclinic(origin: [f64; 3], vectors: [[f64; 3]; 3]) -> Result<Self> {
        if !origin.iter().chain(vectors.iter().flatten()).all(|x| x.is_finite()) {
            return Err(Error::InvalidInput(format!(
                "a periodic cell needs a finite origin and lattice vectors; got origin {origin:?}, vectors {vectors:?}"
            )));
        }
        let [a, b, c] = vectors;
        let volume = dot(cross(a, b), c);
        let norms: f64 = vectors.iter().map(|v| dot(*v, *v).sqrt()).product();
        if volume.partial_cmp(&(1e-12 * norms)) != Some(std::cmp::Ordering::Greater) {
            return Err(Error::InvalidInput(format!(
                "the lattice vectors a = {a:?}, b = {b:?}, c = {c:?} must span a right-handed cell \
                 ((a x b) . c > 0); their triple product is {volume:e}{}",
                if volume < 0.0 { " (swap two vectors)" } else { "" }
            )));
        }
        let off = |v: usize| (0..3).filter(|&k| k != v).all(|k| vectors[v][k] == 0.0);
        if (0..3).all(off) {
            let hi = [0, 1, 2].map(|k| origin[k] + vectors[k][k]);
            let mut aligned = Self::new(origin, hi)?;
            // The exact sides, not hi - lo rounded.
            aligned.vectors = vectors;
            aligned.reciprocal = [0, 1, 2].map(|k| {
                let mut r = [0.0; 3];
                r[k] = 1.0 / vectors[k][k];
                r
            });
            return Ok(aligned);
        }
        let reciprocal = [cross(b, c), cross(c, a), cross(a, b)].map(|r| r.map(|x| x / volume));
        let far = [0, 1, 2].map(|k| origin[k] + a[k] + b[k] + c[k]);
        Ok(Self { origin, vectors, periodic: [true; 3], reciprocal, far, aligned: false })
    }

    /// LAMMPS's cell: `lo..hi` along x, y and z with the tilts `[xy, xz,
    /// yz]` (lengths), that is `a = (hi_x - lo_x, 0, 0)`, `b = (xy, hi_y -
    /// lo_y, 0)`, `c = (xz, yz, hi_z - lo_z)` from `lo`. (A dump's `ITEM:
    /// BOX BOUNDS` hold the bounds of the tilted cell's bounding box,
    /// which the dump's reader turns into these.)
    pub fn lammps(lo: [f64; 3], hi: [f64; 3], tilt: [f64; 3]) -> Result<Self> {
        Self::new(lo, hi)?;
        let l = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let [xy, xz, yz] = tilt;
        Self::triclinic(lo, [[l[0], 0.0, 0.0], [xy, l[1], 0.0], [xz, yz, l[2]]])
    }

    /// The same cell, periodic along the axes flagged (`a`, `b`, `c`), with
    /// walls along the others.
    pub fn with_periodic(mut self, periodic: [bool; 3]) -> Self {
        self.periodic = periodic;
        self
    }

    /// Whether the space repeats along each of the cell's vectors.
    pub fn periodic(&self) -> [bool; 3] {
        self.periodic
    }

    /// Whether the cell has walls (an axis that does not repeat).
    pub fn has_walls(&self) -> bool {
        self.periodic.contains(&false)
    }

    /// Whether the cell is an axis-aligned box.
    pub fn is_aligned(&self) -> bool {
        self.aligned
    }

    /// The cell's corner `origin` (an axis-aligned box's lower corner).
    pub fn lo(&self) -> [f64; 3] {
        self.origin
    }

    /// The corner opposite the origin, `origin + a + b + c` (an
    /// axis-aligned box's upper corner).
    pub fn hi(&self) -> [f64; 3] {
        self.far
    }

    /// The edge vectors `a`, `b`, `c`.
    pub fn vectors(&self) -> [[f64; 3]; 3] {
        self.vectors
    }

    /// The edge vectors' lengths (an axis-aligned box's sides).
    pub fn lengths(&self) -> [f64; 3] {
        if self.aligned {
            return [0, 1, 2].map(|k| self.vectors[k][k]);
        }
        self.vectors.map(|v| dot(v, v).sqrt())
    }

    /// The cell's volume.
    pub fn volume(&self) -> f64 {
        if self.aligned {
            return self.lengths().iter().product();
        }
        let [a, b, c] = self.vectors;
        dot(cross(a, b), c)
    }

    /// The distance between the cell's two faces across each axis (its
    /// sides, for an axis-aligned box).
    pub fn heights(&self) -> [f64; 3] {
        if self.aligned {
            return self.lengths();
        }
        self.reciprocal.map(|r| 1.0 / dot(r, r).sqrt())
    }

    /// `p`'s fractional coordinates: `p = origin + s_a a + s_b b + s_c c`.
    pub fn fractional(&self, p: [f64; 3]) -> [f64; 3] {
        let d = [0, 1, 2].map(|k| p[k] - self.origin[k]);
        if self.aligned {
            return [0, 1, 2].map(|k| d[k] / self.vectors[k][k]);
        }
        self.reciprocal.map(|r| dot(r, d))
    }

    /// The point at fractional coordinates `s`.
    pub fn cartesian(&self, s: [f64; 3]) -> [f64; 3] {
        let v = &self.vectors;
        [0, 1, 2].map(|k| self.origin[k] + s[0] * v[0][k] + s[1] * v[1][k] + s[2] * v[2][k])
    }

    /// `p` moved by whole lattice vectors into the cell (`0 <= s < 1`)
    /// along its periodic axes; unchanged, bit for bit, if it is in
    /// already.
    pub fn wrap(&self, p: [f64; 3]) -> [f64; 3] {
        if self.aligned {
            let (lo, l) = (self.origin, self.lengths());
            let hi = self.hi();
            return [0, 1, 2].map(|a| {
                if !self.periodic[a] || (p[a] >= lo[a] && p[a] < hi[a]) {
                    return p[a];
                }
                let x = lo[a] + (p[a] - lo[a]).rem_euclid(l[a]);
                // Rounding may land a point just below lo on hi itself.
                if x >= hi[a] {
                    lo[a]
                } else {
                    x
                }
            });
        }
        let mut q = p;
        // Whole turns, then a turn more or less where rounding left the
        // point a hair outside.
        for _ in 0..3 {
            let s = self.fractional(q);
            let turns =
                [0, 1, 2].map(|a| if self.periodic[a] && !(0.0..1.0).contains(&s[a]) { s[a].floor() } else { 0.0 });
            if turns == [0.0; 3] {
                return q;
            }
            q = self.moved(q, turns.map(|t| -t));
        }
        q
    }

    /// `p` moved by `t` (real) lattice vectors.
    fn moved(&self, p: [f64; 3], t: [f64; 3]) -> [f64; 3] {
        let v = &self.vectors;
        [0, 1, 2].map(|k| p[k] + t[0] * v[0][k] + t[1] * v[1][k] + t[2] * v[2][k])
    }

    /// `p` moved by `shift` lattice vectors.
    pub fn shifted(&self, p: [f64; 3], shift: [i32; 3]) -> [f64; 3] {
        if self.aligned {
            let l = self.lengths();
            return [0, 1, 2].map(|a| p[a] + shift[a] as f64 * l[a]);
        }
        self.moved(p, shift.map(f64::from))
    }

    /// `p` reflected in the wall across axis `axis` on the origin's side
    /// (`upper` false) or the far side.
    pub fn mirrored(&self, p: [f64; 3], axis: usize, upper: bool) -> [f64; 3] {
        if self.aligned {
            let mut q = p;
            let wall = if upper { self.hi()[axis] } else { self.origin[axis] };
            q[axis] = 2.0 * wall - p[axis];
            return q;
        }
        // p - 2 s r / |r|²: s / |r| is p's signed distance from the wall.
        let s = self.fractional(p)[axis] - if upper { 1.0 } else { 0.0 };
        let r = self.reciprocal[axis];
        let f = 2.0 * s / dot(r, r);
        [0, 1, 2].map(|k| p[k] - f * r[k])
    }

    /// How far `p` lies outside the walls (0 inside them, or with no
    /// walls), and the axis of the wall it is farthest outside of.
    pub fn outside_walls(&self, p: [f64; 3]) -> (f64, usize) {
        let (s, h) = (self.fractional(p), self.heights());
        (0..3)
            .filter(|&a| !self.periodic[a])
            .map(|a| ((-s[a]).max(s[a] - 1.0).max(0.0) * h[a], a))
            .fold((0.0, 0), |m, x| if x.0 > m.0 { x } else { m })
    }

    /// A lower bound of the distance from `p` to the cell (0 inside): the
    /// distance itself for an axis-aligned box, else the largest distance
    /// outside the slabs between opposite faces.
    pub(crate) fn distance(&self, p: [f64; 3]) -> f64 {
        if self.aligned {
            let (lo, hi) = (self.origin, self.hi());
            return (0..3).map(|a| (lo[a] - p[a]).max(p[a] - hi[a]).max(0.0).powi(2)).sum::<f64>().sqrt();
        }
        let (s, h) = (self.fractional(p), self.heights());
        (0..3).map(|a| (-s[a]).max(s[a] - 1.0).max(0.0) * h[a]).fold(0.0, f64::max)
    }

    /// The cell cut into about `tets` tets: cells as near cubes as its
    /// sides allow, 6 tets each (a triclinic cell: the grid of its
    /// fractional coordinates, mapped).
    pub fn mesh(&self, tets: usize) -> TetMesh {
        let cube = (self.volume() * 6.0 / tets.max(6) as f64).cbrt();
        let dims = self.lengths().map(|l| ((l / cube).round() as usize).clamp(1, 1 << 10));
        if self.aligned {
            return TetMesh::grid(self.origin, self.hi(), dims);
        }
        let mut mesh = TetMesh::grid([0.0; 3], [1.0; 3], dims);
        for v in &mut mesh.vertices {
            *v = self.cartesian(*v);
        }
        mesh
    }

    /// The axis's name in messages.
    pub fn axis_name(axis: usize) -> &'static str {
        AXES[axis]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points;

    #[test]
    fn a_box_needs_finite_ordered_corners() {
        for (lo, hi, axis) in [
            ([0.0; 3], [1.0, 1.0, 0.0], "along z"),
            ([0.0, 2.0, 0.0], [1.0, 1.0, 1.0], "along y"),
            ([f64::NAN, 0.0, 0.0], [1.0; 3], "along x"),
            ([0.0; 3], [1.0, f64::INFINITY, 1.0], "along y"),
            ([f64::NEG_INFINITY, 0.0, 0.0], [1.0; 3], "along x"),
        ] {
            match PeriodicBox::new(lo, hi) {
                Err(Error::InvalidInput(m)) => assert!(m.contains(axis), "{lo:?}..{hi:?}: {m}"),
                other => panic!("{lo:?}..{hi:?}: {other:?}"),
            }
        }
        let b = PeriodicBox::new([-1.0, 0.0, 2.0], [1.0, 0.5, 5.0]).unwrap();
        assert_eq!(
            (b.lo(), b.hi(), b.lengths(), b.volume()),
            ([-1.0, 0.0, 2.0], [1.0, 0.5, 5.0], [2.0, 0.5, 3.0], 3.0)
        );
        assert_eq!(PeriodicBox::unit(), PeriodicBox::new([0.0; 3], [1.0; 3]).unwrap());
    }

    #[test]
    fn wrap_lands_in_the_half_open_box_and_is_idempotent() {
        let b = PeriodicBox::new([-1.0, 0.25, 2.0], [0.7, 0.5, 5.0]).unwrap();
        let l = b.lengths();
        for p in points::uniform(2000, 31) {
            let p = p.map(|c| 40.0 * c - 20.0);
            let w = b.wrap(p);
            for a in 0..3 {
                assert!(b.lo()[a] <= w[a] && w[a] < b.hi()[a], "{p:?} -> {w:?}");
                // Moved by a whole number of lengths.
                let turns = (p[a] - w[a]) / l[a];
                assert!((turns - turns.round()).abs() < 1e-9, "{p:?} -> {w:?}");
            }
            assert_eq!(b.wrap(w), w, "wrapping again moved {w:?}");
        }
        // Inside: unchanged, bit for bit; the upper side is the lower one.
        assert_eq!(b.wrap([0.1234567, 0.3, 4.999]), [0.1234567, 0.3, 4.999]);
        assert_eq!(b.wrap([0.7, 0.5, 5.0]), [-1.0, 0.25, 2.0]);
        assert_eq!(b.wrap([-1.0, 0.25, 2.0]), [-1.0, 0.25, 2.0]);
    }

    #[test]
    fn wrap_never_rounds_onto_the_upper_side() {
        // Just below lo: lo + (l - tiny) rounds to hi, which is lo again.
        let b = PeriodicBox::unit();
        let below = -f64::EPSILON / 1024.0;
        assert_eq!(b.wrap([below, 0.5, 0.5]), [0.0, 0.5, 0.5]);
        let b = PeriodicBox::new([1.0; 3], [3.0; 3]).unwrap();
        let w = b.wrap([1.0 - 1e-17, 3.0 + 1e-15, -1e300]);
        assert!((0..3).all(|a| (1.0..3.0).contains(&w[a])), "{w:?}");
    }

    #[test]
    fn shifted_moves_by_whole_lengths() {
        let b = PeriodicBox::new([-1.0, 0.0, 2.0], [1.0, 0.5, 5.0]).unwrap();
        assert_eq!(b.shifted([0.25, 0.125, 3.0], [1, -2, 3]), [2.25, -0.875, 12.0]);
        assert_eq!(b.shifted([0.25, 0.125, 3.0], [0; 3]), [0.25, 0.125, 3.0]);
        for p in points::uniform(100, 32) {
            let p = b.wrap(p);
            for s in [[1, 0, 0], [-3, 2, 1], [5, -5, -1]] {
                let back = b.wrap(b.shifted(p, s));
                assert!((0..3).all(|a| (back[a] - p[a]).abs() < 1e-12), "{p:?} by {s:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn distance_is_zero_inside_and_euclidean_outside() {
        let b = PeriodicBox::unit();
        assert_eq!(b.distance([0.5, 0.0, 1.0]), 0.0);
        assert_eq!(b.distance([-3.0, 0.5, 0.5]), 3.0);
        assert_eq!(b.distance([4.0, 5.0, 0.5]), 5.0);
    }

    #[test]
    fn the_mesh_fills_the_box_with_about_the_tets_asked() {
        let b = PeriodicBox::new([-1.0, 0.0, 2.0], [1.0, 1.0, 3.0]).unwrap();
        for tets in [0, 6, 100, 3000] {
            let m = b.mesh(tets);
            assert_eq!(m.bounding_box(), (b.lo(), b.hi()), "{tets}");
            assert!((m.volume() - b.volume()).abs() < 1e-12, "{tets}: volume {}", m.volume());
            assert!(m.tets.len().is_multiple_of(6) && m.tets.len() >= 6);
            assert!(m.tets.len() as f64 <= 2.0 * tets.max(6) as f64 + 6.0, "{tets}: {} tets", m.tets.len());
            assert!(m.tets.len() as f64 >= tets as f64 / 3.0, "{tets}: {} tets", m.tets.len());
        }
        assert_eq!(PeriodicBox::unit().mesh(6000).tets.len(), 6000, "10³ cubes");
    }

    #[test]
    fn a_triclinic_cell_wraps_in_its_own_coordinates() {
        let b = PeriodicBox::lammps([1.0, -2.0, 0.5], [3.0, 1.0, 2.0], [0.7, -0.4, 1.1]).unwrap();
        assert!(!b.is_aligned());
        assert_eq!(b.vectors(), [[2.0, 0.0, 0.0], [0.7, 3.0, 0.0], [-0.4, 1.1, 1.5]]);
        assert!((b.volume() - 9.0).abs() < 1e-12);
        for p in points::uniform(2000, 35) {
            let p = p.map(|c| 30.0 * c - 15.0);
            let w = b.wrap(p);
            let s = b.fractional(w);
            assert!(s.iter().all(|x| (0.0..1.0).contains(x)), "{p:?} -> {w:?} at {s:?}");
            // Moved by whole lattice vectors.
            let d = b.fractional([0, 1, 2].map(|k| p[k] - w[k] + b.lo()[k]));
            assert!(d.iter().all(|t| (t - t.round()).abs() < 1e-9), "{p:?} -> {w:?}: {d:?} turns");
            assert_eq!(b.wrap(w), w, "wrapping again moved {w:?}");
            let back = b.cartesian(b.fractional(p));
            assert!((0..3).all(|k| (back[k] - p[k]).abs() < 1e-12), "{p:?} -> {back:?}");
        }
        // The heights: the distances between opposite faces.
        let h = b.heights();
        assert!((h[2] - 1.5).abs() < 1e-12, "{h:?}");
        let v = b.vectors();
        for a in 0..3 {
            let (u, w) = (v[(a + 1) % 3], v[(a + 2) % 3]);
            let n = cross(u, w);
            assert!((h[a] - b.volume() / dot(n, n).sqrt()).abs() < 1e-12);
        }
    }

    #[test]
    fn walls_stop_the_wrap_and_mirror_points_across_themselves() {
        let b = PeriodicBox::lammps([0.0; 3], [2.0, 1.0, 1.0], [0.5, 0.25, 0.125])
            .unwrap()
            .with_periodic([true, false, true]);
        assert!(b.has_walls() && b.periodic() == [true, false, true]);
        let p = [5.0, 0.5, 7.3];
        let s = b.fractional(b.wrap(p));
        assert!((0.0..1.0).contains(&s[0]) && (0.0..1.0).contains(&s[2]));
        assert!((s[1] - b.fractional(p)[1]).abs() < 1e-12, "along the wall axis: unchanged");
        for p in points::uniform(200, 36) {
            let p = b.cartesian(p);
            for upper in [false, true] {
                let m = b.mirrored(p, 1, upper);
                // The wall is the bisector: its points are as far from both.
                let (s, t) = (b.fractional(p), b.fractional(m));
                let wall = if upper { 1.0 } else { 0.0 };
                assert!((s[1] + t[1] - 2.0 * wall).abs() < 1e-12, "{s:?} and {t:?}");
                let q = b.cartesian([0.3, wall, 0.8]);
                let d = |x: [f64; 3]| (0..3).map(|k| (x[k] - q[k]).powi(2)).sum::<f64>();
                assert!((d(p) - d(m)).abs() < 1e-12, "{p:?}, {m:?}");
                assert!((b.outside_walls(m).0 - (s[1] - wall).abs() * b.heights()[1]).abs() < 1e-12);
            }
            assert_eq!(b.outside_walls(p).0, 0.0);
        }
    }

    #[test]
    fn lattice_vectors_must_span_a_right_handed_cell() {
        let e = PeriodicBox::triclinic([0.0; 3], [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]).unwrap_err();
        assert!(e.to_string().contains("swap two vectors"), "{e}");
        let e = PeriodicBox::triclinic([0.0; 3], [[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).unwrap_err();
        assert!(e.to_string().contains("right-handed"), "{e}");
        let e = PeriodicBox::triclinic([f64::NAN, 0.0, 0.0], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        assert!(e.unwrap_err().to_string().contains("finite"));
        // Vectors along the axes: the axis-aligned box.
        let b = PeriodicBox::triclinic([1.0, 2.0, 3.0], [[2.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 4.0]]).unwrap();
        assert!(b.is_aligned());
        assert_eq!((b.lo(), b.hi(), b.volume()), ([1.0, 2.0, 3.0], [3.0, 2.5, 7.0], 4.0));
        // LAMMPS's bounds: lo < hi.
        assert!(PeriodicBox::lammps([0.0; 3], [1.0, 0.0, 1.0], [0.0; 3]).is_err());
    }

    #[test]
    fn a_triclinic_mesh_fills_the_cell() {
        let b = PeriodicBox::lammps([0.0; 3], [2.0, 1.0, 1.0], [0.5, -0.25, 0.125]).unwrap();
        for tets in [6, 600] {
            let m = b.mesh(tets);
            assert!((m.volume() - b.volume()).abs() < 1e-12, "{tets}: {}", m.volume());
            for v in &m.vertices {
                let s = b.fractional(*v);
                assert!(s.iter().all(|x| (-1e-12..=1.0 + 1e-12).contains(x)), "{v:?}");
            }
        }
    }
}
