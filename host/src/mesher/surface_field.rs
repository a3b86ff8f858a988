//! The signed distance to a closed triangle surface, for stuffing the
//! volume it encloses.
//!
//! The distance is found through the surface's bounding-volume hierarchy
//! ([`TriangleTree`]). Its sign comes from the angle-weighted
//! pseudo-normal of the nearest feature (J. A. Bærentzen and H. Aanæs,
//! *Signed distance computation using the angle weighted pseudonormal*,
//! IEEE TVCG 2005): the face normal when the nearest point is inside a
//! triangle, the sum of the two faces' normals on an edge, the
//! angle-weighted normal at a vertex. For a closed, consistently oriented
//! surface this sign is exact, however sharp the surface's creases and
//! corners. [`TriSurface::into_closed`] also lets through small cracks
//! (open edges around gaps narrower than [`crate::geom::surface::MAX_CRACK`]);
//! where the nearest feature lies on a crack's rim, the sign is the
//! generalised winding number's instead (inside above 1/2), which a small
//! gap barely moves. Shells touching at a vertex keep the pseudo-normal
//! (the two cones' normals add; tested around a box and a slanted tet);
//! parts touching along an edge (non-manifold edges) and triangles
//! crossing each other are refused before they get here.

use super::sdf::Shape;
use crate::geom::surface::TriSurface;
use std::collections::HashMap;

use crate::geom::surface::bvh::TriangleTree;
use crate::geom::vec3::{add, cross, dot, scale, sub, unit, P};

/// The feature of a triangle a point is nearest to.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Feature {
    /// Corner `k`.
    Vertex(usize),
    /// The edge from corner `k` to corner `k + 1`.
    Edge(usize),
    /// The inside of the triangle.
    Face,
}

/// The point of triangle `a, b, c` nearest `p`, and its feature (C.
/// Ericson, *Real-Time Collision Detection*, 5.1.5).
#[inline(always)]
fn nearest_on_triangle(p: P, a: P, b: P, c: P) -> (P, Feature) {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, Feature::Vertex(0));
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (add(a, scale(ab, v)), Feature::Edge(0));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (add(a, scale(ac, w)), Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (add(b, scale(sub(c, b), w)), Feature::Edge(1));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (add(a, add(scale(ab, v), scale(ac, w))), Feature::Face)
}

/// The signed distance to a closed, outward-oriented triangle surface.
pub struct SurfaceDistance<'a> {
    /// The surface.
    surface: &'a TriSurface,
    tree: TriangleTree,
    face_normal: Vec<P>,
    /// Per triangle and edge `k` (corner k to k + 1): the edge's pseudo-normal.
    edge_normal: Vec<[P; 3]>,
    vertex_normal: Vec<P>,
    /// Per triangle: bit `k` when its edge `k` is open (a crack's rim),
    /// bit `3 + k` when its corner `k` lies on such an edge.
    on_crack: Vec<u8>,
}

impl<'a> SurfaceDistance<'a> {
    /// The field of `surface`, which must be closed and oriented outward
    /// ([`TriSurface::into_closed`]).
    pub fn new(surface: &'a TriSurface) -> Self {
        let (vertices, triangles) = (&surface.vertices, &surface.triangles);
        let corners = |t: usize| triangles[t].map(|v| vertices[v as usize]);
        let face_normal: Vec<P> = (0..triangles.len())
            .map(|t| {
                let [a, b, c] = corners(t);
                unit(cross(sub(b, a), sub(c, a)))
            })
            .collect();
        let mut vertex_normal = vec![[0.0; 3]; vertices.len()];
        // Per undirected edge: the sum of its triangles' normals, and how many.
        let mut edge_sum: HashMap<(u32, u32), (P, u32)> = HashMap::with_capacity(3 * triangles.len() / 2);
        for (t, tri) in triangles.iter().enumerate() {
            let p = corners(t);
            for k in 0..3 {
                // The angle at corner k, weighting the face's normal there.
                let (u, w) = (sub(p[(k + 1) % 3], p[k]), sub(p[(k + 2) % 3], p[k]));
                let angle = dot(cross(u, w), cross(u, w)).sqrt().atan2(dot(u, w));
                let n = &mut vertex_normal[tri[k] as usize];
                *n = add(*n, scale(face_normal[t], angle));
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let e = edge_sum.entry((a.min(b), a.max(b))).or_insert(([0.0; 3], 0));
                *e = (add(e.0, face_normal[t]), e.1 + 1);
            }
        }
        let edge_normal = triangles
            .iter()
            .map(|tri| {
                [0, 1, 2].map(|k| {
                    let (a, b) = (tri[k], tri[(k + 1) % 3]);
                    edge_sum[&(a.min(b), a.max(b))].0
                })
            })
            .collect();
        // Open edges: their one triangle's normal alone says nothing of the
        // other side of the crack.
        let mut rim = vec![false; vertices.len()];
        let open = |tri: &[u32; 3], k: usize| {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            edge_sum[&(a.min(b), a.max(b))].1 == 1
        };
        for tri in triangles {
            for k in 0..3 {
                if open(tri, k) {
                    rim[tri[k] as usize] = true;
                    rim[tri[(k + 1) % 3] as usize] = true;
                }
            }
        }
        let on_crack = triangles
            .iter()
            .map(|tri| {
                (0..3).fold(0u8, |bits, k| bits | (open(tri, k) as u8) << k | (rim[tri[k] as usize] as u8) << (3 + k))
            })
            .collect();
        Self { surface, tree: TriangleTree::new(surface), face_normal, edge_normal, vertex_normal, on_crack }
    }

    /// The nearest point of the surface to `p`: squared distance,
    /// triangle and feature.
    fn nearest(&self, p: P) -> (f64, u32, Feature, P) {
        let nearest = self.tree.nearest(p, |t| {
            let [a, b, c] = self.surface.triangles[t as usize].map(|v| self.surface.vertices[v as usize]);
            let (q, f) = nearest_on_triangle(p, a, b, c);
            (dot(sub(p, q), sub(p, q)), (f, q))
        });
        let (d2, t, (f, q)) = nearest.unwrap_or((f64::INFINITY, 0, (Feature::Face, p)));
        (d2, t, f, q)
    }

    /// The signed distance at `p`: negative inside.
    pub fn distance(&self, p: P) -> f64 {
        let (d2, t, feature, q) = self.nearest(p);
        let t = t as usize;
        let (n, on_crack) = match feature {
            Feature::Face => (self.face_normal[t], false),
            Feature::Edge(k) => (self.edge_normal[t][k], self.on_crack[t] & (1 << k) != 0),
            Feature::Vertex(k) => {
                (self.vertex_normal[self.surface.triangles[t][k] as usize], self.on_crack[t] & (8 << k) != 0)
            }
        };
        let inside = if on_crack { self.tree.winding_number(self.surface, p) > 0.5 } else { dot(sub(p, q), n) < 0.0 };
        let d = d2.sqrt();
        if inside {
            -d
        } else {
            d
        }
    }
}

impl Shape for SurfaceDistance<'_> {
    fn eval(&self, p: P) -> f64 {
        self.distance(p)
    }

    fn bounds(&self) -> (P, P) {
        self.surface.bounding_box()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points::Rng;
    use crate::geom::surface::TriSurface;

    #[test]
    fn the_distance_to_a_box_is_exact_inside_and_out() {
        let s = TriSurface::cuboid([0.0; 3], [1.0, 2.0, 3.0]);
        let f = SurfaceDistance::new(&s);
        let exact = super::super::sdf::Sdf::cuboid([0.5, 1.0, 1.5], [0.5, 1.0, 1.5]);
        let mut rng = Rng::new(5);
        for _ in 0..2000 {
            let p = [0; 3].map(|_| 4.0 * rng.unit() - 1.0);
            let (a, b) = (f.distance(p), exact.eval(p));
            assert!((a - b).abs() < 1e-12, "at {p:?}: {a} vs {b}");
        }
        // On the corners, edges and faces themselves: zero.
        assert_eq!(f.distance([1.0, 2.0, 3.0]), 0.0);
        assert_eq!(f.distance([0.5, 0.0, 0.0]), 0.0);
    }

    /// A crack in the surface (a missing triangle) changes no sign: the
    /// distance's sign at the lattice's points and the mesh are those of
    /// the closed surface.
    #[test]
    fn a_crack_changes_no_sign() {
        let closed = crate::geom::surface::tests::fine_box(100);
        let mut cracked = closed.clone();
        // Triangles on the face x = 0 and on the edge x = 0, y = 0.
        let on =
            |s: &TriSurface, t: usize, f: &dyn Fn(P) -> bool| s.triangles[t].iter().any(|&v| f(s.vertices[v as usize]));
        let face = (0..cracked.triangles.len()).find(|&t| on(&cracked, t, &|p| p[0] == 0.0 && p[1] == 0.5)).unwrap();
        cracked.triangles.remove(face);
        let edge = (0..cracked.triangles.len())
            .find(|&t| on(&cracked, t, &|p| p[0] == 0.0 && p[1] == 0.0 && p[2] == 0.5))
            .unwrap();
        cracked.triangles.remove(edge);
        let (cracked, r) = cracked.into_closed("cracked").unwrap();
        assert_eq!(r.cracks, 2);
        let (f, g) = (SurfaceDistance::new(&closed), SurfaceDistance::new(&cracked));
        let mut rng = Rng::new(8);
        for _ in 0..20000 {
            // Near the cracks above all.
            let p = [0; 3].map(|_| 0.1 * rng.unit() - 0.05);
            let p = [p[0], p[1] + if rng.unit() < 0.5 { 0.5 } else { 0.0 }, p[2] + 0.5];
            let (a, b) = (f.distance(p), g.distance(p));
            assert!(a.signum() == b.signum() || a.abs() < 1e-12, "at {p:?}: {a} vs {b}");
        }
        let (m, n) =
            (super::super::mesh_surface(&closed, 10).unwrap(), super::super::mesh_surface(&cracked, 10).unwrap());
        assert_eq!(m.tets.len(), n.tets.len());
        assert!((m.volume() - n.volume()).abs() < 1e-12);
    }

    /// A box and a slanted tetrahedron touching at one corner (one vertex,
    /// two cones around it): the sign is right all around it.
    #[test]
    fn a_box_and_a_tet_touching_at_a_corner() {
        let mut s = TriSurface::cuboid([0.0; 3], [1.0; 3]);
        // The tet's apex is the box's corner 7, (1, 1, 1); its base far off.
        let base = [[2.0, 1.6, 1.1], [2.1, 0.7, 1.3], [1.9, 1.2, 0.2]];
        s.vertices.extend(base);
        // Faces outward: the base seen from +x, then the three sides.
        s.triangles.extend([[8, 9, 10], [7, 9, 8], [7, 10, 9], [7, 8, 10]]);
        let (s, r) = s.into_closed("touching").unwrap();
        assert_eq!((r.shells, r.holes, r.open_edges), (2, 0, 0), "{r:?}");
        let f = SurfaceDistance::new(&s);
        let tet = [[1.0; 3], base[0], base[1], base[2]];
        let in_tet = |p: P| {
            let v = |a: P, b: P, c: P, d: P| dot(sub(b, a), cross(sub(c, a), sub(d, a)));
            let whole = v(tet[0], tet[1], tet[2], tet[3]);
            (0..4).all(|k| {
                let mut t = tet;
                t[k] = p;
                v(t[0], t[1], t[2], t[3]) / whole > 0.0
            })
        };
        let inside = |p: P| (0..3).all(|a| p[a] > 0.0 && p[a] < 1.0) || in_tet(p);
        let mut rng = Rng::new(9);
        for _ in 0..20000 {
            let p = [0; 3].map(|_| 1.0 + 0.2 * (rng.unit() - 0.5));
            let d = f.distance(p);
            assert!((d < 0.0) == inside(p) || d.abs() < 1e-12, "at {p:?}: {d}");
        }
    }

    #[test]
    fn a_nested_hole_is_outside() {
        let outer = TriSurface::cuboid([0.0; 3], [3.0; 3]);
        let inner = TriSurface::cuboid([1.0; 3], [2.0; 3]);
        let mut s = outer;
        s.vertices.extend(&inner.vertices);
        s.triangles.extend(inner.triangles.iter().map(|t| t.map(|v| v + 8)));
        let (s, _) = s.into_closed("shells").unwrap();
        let f = SurfaceDistance::new(&s);
        assert!((f.distance([1.5; 3]) - 0.5).abs() < 1e-12, "{}", f.distance([1.5; 3]));
        assert!((f.distance([0.5, 1.5, 1.5]) + 0.5).abs() < 1e-12);
        assert!((f.distance([4.0, 1.5, 1.5]) - 1.0).abs() < 1e-12);
    }
}
