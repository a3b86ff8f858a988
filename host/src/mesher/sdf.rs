//! Signed distance functions: a few primitives and constructive solid
//! geometry, as a small expression tree.
//!
//! A shape is the set where [`Sdf::eval`] is negative (zero on its
//! surface). The primitives return the exact Euclidean distance; union
//! (`min`), intersection (`max`), difference (`max(a, -b)`) and translation
//! keep the sign exact and the magnitude a lower bound of the distance,
//! which is all the mesher's root finding along lattice edges needs: a
//! continuous function whose sign says inside or outside.

use crate::geom::vec3::{dot, norm, sub};

/// What the mesher fills: a function negative inside the shape, zero on its
/// surface, positive outside — continuous, with the magnitude a lower bound
/// of the distance to the surface — and a box holding the shape.
pub trait Shape: Sync {
    /// The signed distance (or a lower bound of it) at `p`.
    fn eval(&self, p: [f64; 3]) -> f64;
    /// An axis-aligned box `(lower, upper)` holding the shape.
    fn bounds(&self) -> ([f64; 3], [f64; 3]);
}

impl Shape for Sdf {
    fn eval(&self, p: [f64; 3]) -> f64 {
        Sdf::eval(self, p)
    }
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        Sdf::bounds(self)
    }
}

/// A shape given by its signed distance (negative inside).
#[derive(Clone, Debug, PartialEq)]
pub enum Sdf {
    /// A ball.
    Sphere {
        /// Centre.
        centre: [f64; 3],
        /// Radius (> 0).
        radius: f64,
    },
    /// An axis-aligned box, its edges and corners rounded with radius
    /// `rounding` (0 for sharp ones).
    Cuboid {
        /// Centre.
        centre: [f64; 3],
        /// Half the side lengths (each > `rounding`).
        half: [f64; 3],
        /// Radius of the rounded edges and corners (>= 0).
        rounding: f64,
    },
    /// A finite solid cylinder along any axis.
    Cylinder {
        /// Centre (halfway along the axis).
        centre: [f64; 3],
        /// Unit axis direction.
        axis: [f64; 3],
        /// Radius (> 0).
        radius: f64,
        /// Half the length (> 0).
        half_length: f64,
    },
    /// A solid torus around an axis.
    Torus {
        /// Centre.
        centre: [f64; 3],
        /// Unit axis direction (normal to the plane of the ring).
        axis: [f64; 3],
        /// Distance from the centre to the tube's centre line.
        major: f64,
        /// Radius of the tube (< `major`).
        minor: f64,
    },
    /// Points in either shape.
    Union(Box<Sdf>, Box<Sdf>),
    /// Points in both shapes.
    Intersection(Box<Sdf>, Box<Sdf>),
    /// Points in the first shape and not in the second.
    Difference(Box<Sdf>, Box<Sdf>),
    /// A shape moved by `offset`.
    Translate {
        /// The displacement.
        offset: [f64; 3],
        /// The shape moved.
        shape: Box<Sdf>,
    },
}

fn normalized(a: [f64; 3]) -> [f64; 3] {
    let n = norm(a);
    a.map(|c| c / n)
}

/// The components of `d` along the unit `axis` and across it (distance
/// from the axis line).
fn axial_radial(d: [f64; 3], axis: [f64; 3]) -> (f64, f64) {
    let along = dot(d, axis);
    let across = (dot(d, d) - along * along).max(0.0).sqrt();
    (along, across)
}

impl Sdf {
    /// A ball of `radius` around `centre`.
    pub fn sphere(centre: [f64; 3], radius: f64) -> Self {
        Self::Sphere { centre, radius }
    }

    /// An axis-aligned box with sharp edges.
    pub fn cuboid(centre: [f64; 3], half: [f64; 3]) -> Self {
        Self::Cuboid { centre, half, rounding: 0.0 }
    }

    /// An axis-aligned box whose edges and corners are rounded with
    /// `rounding` (the box keeps its outer size `2 * half`).
    pub fn rounded_cuboid(centre: [f64; 3], half: [f64; 3], rounding: f64) -> Self {
        Self::Cuboid { centre, half, rounding }
    }

    /// A cylinder of `radius` and `length` along `axis` (any non-zero
    /// vector), centred on `centre`.
    pub fn cylinder(centre: [f64; 3], axis: [f64; 3], radius: f64, length: f64) -> Self {
        Self::Cylinder { centre, axis: normalized(axis), radius, half_length: length / 2.0 }
    }

    /// A torus around `axis` (any non-zero vector) through `centre`.
    pub fn torus(centre: [f64; 3], axis: [f64; 3], major: f64, minor: f64) -> Self {
        Self::Torus { centre, axis: normalized(axis), major, minor }
    }

    /// Points in `self` or `other`.
    pub fn union(self, other: Sdf) -> Self {
        Self::Union(Box::new(self), Box::new(other))
    }

    /// Points in both `self` and `other`.
    pub fn intersection(self, other: Sdf) -> Self {
        Self::Intersection(Box::new(self), Box::new(other))
    }

    /// Points in `self` but not in `other`.
    pub fn difference(self, other: Sdf) -> Self {
        Self::Difference(Box::new(self), Box::new(other))
    }

    /// `self` moved by `offset`.
    pub fn translated(self, offset: [f64; 3]) -> Self {
        Self::Translate { offset, shape: Box::new(self) }
    }

    /// The signed distance at `p`: negative inside, zero on the surface.
    pub fn eval(&self, p: [f64; 3]) -> f64 {
        match self {
            Self::Sphere { centre, radius } => norm(sub(p, *centre)) - radius,
            Self::Cuboid { centre, half, rounding } => {
                // Distance to the box shrunk by the rounding, minus the rounding.
                let q = [0, 1, 2].map(|a| (p[a] - centre[a]).abs() - (half[a] - rounding));
                let outside = norm(q.map(|c| c.max(0.0)));
                let inside = q[0].max(q[1]).max(q[2]).min(0.0);
                outside + inside - rounding
            }
            Self::Cylinder { centre, axis, radius, half_length } => {
                let (along, across) = axial_radial(sub(p, *centre), *axis);
                let d = [across - radius, along.abs() - half_length];
                let outside = (d[0].max(0.0).powi(2) + d[1].max(0.0).powi(2)).sqrt();
                outside + d[0].max(d[1]).min(0.0)
            }
            Self::Torus { centre, axis, major, minor } => {
                let (along, across) = axial_radial(sub(p, *centre), *axis);
                (along * along + (across - major).powi(2)).sqrt() - minor
            }
            Self::Union(a, b) => a.eval(p).min(b.eval(p)),
            Self::Intersection(a, b) => a.eval(p).max(b.eval(p)),
            Self::Difference(a, b) => a.eval(p).max(-b.eval(p)),
            Self::Translate { offset, shape } => shape.eval(sub(p, *offset)),
        }
    }

    /// An axis-aligned box `(lower, upper)` holding the shape. It may be
    /// larger than the shape (intersections and differences keep their
    /// operands' boxes); it is empty (`lower > upper` on some axis) when
    /// an intersection's operands' boxes do not meet.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let around = |c: [f64; 3], r: [f64; 3]| ([0, 1, 2].map(|a| c[a] - r[a]), [0, 1, 2].map(|a| c[a] + r[a]));
        // Half extent along coordinate axis a of a disc or segment set
        // around `axis`: `along` units along it, `across` units across it.
        let extent = |axis: [f64; 3], along: f64, across: f64| {
            [0, 1, 2].map(|a| along * axis[a].abs() + across * (1.0 - axis[a] * axis[a]).max(0.0).sqrt())
        };
        match self {
            Self::Sphere { centre, radius } => around(*centre, [*radius; 3]),
            Self::Cuboid { centre, half, .. } => around(*centre, *half),
            Self::Cylinder { centre, axis, radius, half_length } => {
                around(*centre, extent(*axis, *half_length, *radius))
            }
            Self::Torus { centre, axis, major, minor } => around(*centre, extent(*axis, *minor, major + minor)),
            Self::Union(a, b) => {
                let ((la, ua), (lb, ub)) = (a.bounds(), b.bounds());
                ([0, 1, 2].map(|i| la[i].min(lb[i])), [0, 1, 2].map(|i| ua[i].max(ub[i])))
            }
            Self::Intersection(a, b) => {
                let ((la, ua), (lb, ub)) = (a.bounds(), b.bounds());
                ([0, 1, 2].map(|i| la[i].max(lb[i])), [0, 1, 2].map(|i| ua[i].min(ub[i])))
            }
            Self::Difference(a, _) => a.bounds(),
            Self::Translate { offset, shape } => {
                let (l, u) = shape.bounds();
                ([0, 1, 2].map(|i| l[i] + offset[i]), [0, 1, 2].map(|i| u[i] + offset[i]))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn primitives_are_exact_distances() {
        let s = Sdf::sphere([1.0, 0.0, 0.0], 2.0);
        assert!(close(s.eval([1.0, 0.0, 0.0]), -2.0));
        assert!(close(s.eval([1.0, 5.0, 0.0]), 3.0));

        let b = Sdf::cuboid([0.0; 3], [1.0, 2.0, 3.0]);
        assert!(close(b.eval([0.0; 3]), -1.0));
        assert!(close(b.eval([2.0, 0.0, 0.0]), 1.0));
        assert!(close(b.eval([2.0, 3.0, 0.0]), 2f64.sqrt()));

        let r = Sdf::rounded_cuboid([0.0; 3], [1.0; 3], 0.5);
        assert!(close(r.eval([2.0, 0.0, 0.0]), 1.0));
        // Outside a rounded corner: distance to the corner sphere of radius 0.5 at (0.5, 0.5, 0.5).
        assert!(close(r.eval([2.0, 2.0, 2.0]), 3f64.sqrt() * 1.5 - 0.5));

        let c = Sdf::cylinder([0.0; 3], [0.0, 0.0, 2.0], 1.0, 4.0);
        assert!(close(c.eval([0.0; 3]), -1.0));
        assert!(close(c.eval([3.0, 0.0, 0.0]), 2.0));
        assert!(close(c.eval([0.0, 0.0, 5.0]), 3.0));
        assert!(close(c.eval([4.0, 0.0, 6.0]), 5.0));
        // The same cylinder along x.
        let cx = Sdf::cylinder([0.0; 3], [1.0, 0.0, 0.0], 1.0, 4.0);
        assert!(close(cx.eval([5.0, 0.0, 0.0]), 3.0));

        let t = Sdf::torus([0.0; 3], [0.0, 0.0, 1.0], 3.0, 1.0);
        assert!(close(t.eval([3.0, 0.0, 0.0]), -1.0));
        assert!(close(t.eval([0.0, 0.0, 0.0]), 2.0));
        assert!(close(t.eval([0.0, 3.0, 2.0]), 1.0));
    }

    #[test]
    fn csg_signs_and_bounds() {
        let a = Sdf::cuboid([0.0; 3], [1.0; 3]);
        let hole = Sdf::cylinder([0.0; 3], [0.0, 0.0, 1.0], 0.5, 4.0);
        let part = a.clone().difference(hole.clone());
        assert!(part.eval([0.0; 3]) > 0.0);
        assert!(part.eval([0.75, 0.0, 0.0]) < 0.0);
        assert_eq!(part.bounds(), a.bounds());
        let both = a.clone().union(Sdf::sphere([3.0, 0.0, 0.0], 1.0));
        assert!(both.eval([3.0, 0.0, 0.0]) < 0.0);
        assert_eq!(both.bounds(), ([-1.0, -1.0, -1.0], [4.0, 1.0, 1.0]));
        let moved = a.clone().translated([1.0, 2.0, 3.0]);
        assert!(close(moved.eval([1.0, 2.0, 3.0]), -1.0));
        assert_eq!(moved.bounds(), ([0.0, 1.0, 2.0], [2.0, 3.0, 4.0]));
        let lens = a.intersection(hole);
        assert_eq!(lens.bounds(), ([-0.5, -0.5, -1.0], [0.5, 0.5, 1.0]));
        // A tilted cylinder's box: the end discs stick out across the axis.
        let tilted = Sdf::cylinder([0.0; 3], [1.0, 1.0, 0.0], 1.0, 2.0 * 2f64.sqrt());
        let (lo, hi) = tilted.bounds();
        assert!(close(hi[0], 1.0 + 0.5f64.sqrt()) && close(lo[2], -1.0));
        let t = Sdf::torus([0.0; 3], [0.0, 0.0, 1.0], 3.0, 1.0);
        assert_eq!(t.bounds(), ([-4.0, -4.0, -1.0], [4.0, 4.0, 1.0]));
    }
}
