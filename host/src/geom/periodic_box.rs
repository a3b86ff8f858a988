//! The periodic box: the unit cell of a space that repeats, its wrap of
//! points into it and its images.

use crate::error::{Error, Result};
use crate::geom::mesh::TetMesh;

/// An axis-aligned box whose opposite faces are glued: the unit cell of a
/// space that repeats along x, y and z.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeriodicBox {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl PeriodicBox {
    /// The box `lo..hi` (finite, `lo < hi` along every axis).
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
        Ok(Self { lo, hi })
    }

    /// The unit cube `0..1` along each axis.
    pub fn unit() -> Self {
        Self { lo: [0.0; 3], hi: [1.0; 3] }
    }

    /// The lower corner.
    pub fn lo(&self) -> [f64; 3] {
        self.lo
    }

    /// The upper corner.
    pub fn hi(&self) -> [f64; 3] {
        self.hi
    }

    /// The box's side along each axis.
    pub fn lengths(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| self.hi[a] - self.lo[a])
    }

    /// The box's volume.
    pub fn volume(&self) -> f64 {
        self.lengths().iter().product()
    }

    /// `p` moved by whole box lengths into the box (`lo <= x < hi`).
    pub fn wrap(&self, p: [f64; 3]) -> [f64; 3] {
        let l = self.lengths();
        [0, 1, 2].map(|a| {
            if p[a] >= self.lo[a] && p[a] < self.hi[a] {
                return p[a];
            }
            let x = self.lo[a] + (p[a] - self.lo[a]).rem_euclid(l[a]);
            // Rounding may land a point just below lo on hi itself.
            if x >= self.hi[a] {
                self.lo[a]
            } else {
                x
            }
        })
    }

    /// `p` moved by `shift` box lengths.
    pub fn shifted(&self, p: [f64; 3], shift: [i32; 3]) -> [f64; 3] {
        let l = self.lengths();
        [0, 1, 2].map(|a| p[a] + shift[a] as f64 * l[a])
    }

    /// The distance from `p` to the box (0 inside).
    pub(crate) fn distance(&self, p: [f64; 3]) -> f64 {
        (0..3).map(|a| (self.lo[a] - p[a]).max(p[a] - self.hi[a]).max(0.0).powi(2)).sum::<f64>().sqrt()
    }

    /// The box cut into about `tets` tets: cells as near cubes as its sides
    /// allow, 6 tets each.
    pub fn mesh(&self, tets: usize) -> TetMesh {
        let cube = (self.volume() * 6.0 / tets.max(6) as f64).cbrt();
        let dims = self.lengths().map(|l| ((l / cube).round() as usize).clamp(1, 1 << 10));
        TetMesh::grid(self.lo, self.hi, dims)
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
}
