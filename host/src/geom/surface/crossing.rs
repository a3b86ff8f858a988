//! Does a surface cross itself? Two triangles that share no vertex and
//! intersect — one's edge passes through the other's inside — make the
//! inside of the surface ambiguous: two overlapping shells (a union left
//! unjoined), or a shell folded through itself. The sign of the distance
//! the mesher uses (the pseudo-normal of the nearest feature) is exact only
//! for a surface that does not cross itself, so such a surface is refused
//! by name rather than meshed wrongly. Triangles that merely touch (at a
//! vertex, along an edge, or lying in one plane) do not cross.

use super::bvh::TriangleTree;
use super::TriSurface;
use crate::geom::vec3::{cross, dot, sub, P};
use rayon::prelude::*;

/// The sign of the volume of `a, b, c, d`, zero within rounding of its
/// edges' lengths (so that touching and coplanar contacts are not
/// crossings).
fn orient(a: P, b: P, c: P, d: P) -> i8 {
    let (u, v, w) = (sub(b, a), sub(c, a), sub(d, a));
    let det = dot(u, cross(v, w));
    let size2 = dot(u, u) * dot(v, v) * dot(w, w);
    if det * det <= 1e-24 * size2 {
        0
    } else if det > 0.0 {
        1
    } else {
        -1
    }
}

/// Whether the segment `p, q` passes through the inside of triangle
/// `a, b, c`: its ends strictly on either side, and the line strictly
/// inside the three edges.
fn segment_crosses(p: P, q: P, [a, b, c]: [P; 3]) -> bool {
    let (sp, sq) = (orient(a, b, c, p), orient(a, b, c, q));
    if sp == 0 || sq == 0 || sp == sq {
        return false;
    }
    let s = [orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)];
    s[0] != 0 && s[0] == s[1] && s[1] == s[2]
}

fn triangles_cross(x: [P; 3], y: [P; 3]) -> bool {
    // Most candidates lie wholly on one side of the other's plane.
    let one_side = |t: [P; 3], [a, b, c]: [P; 3]| {
        let s = t.map(|p| orient(a, b, c, p));
        s[0] != 0 && s[0] == s[1] && s[1] == s[2]
    };
    if one_side(x, y) || one_side(y, x) {
        return false;
    }
    (0..3).any(|k| segment_crosses(x[k], x[(k + 1) % 3], y) || segment_crosses(y[k], y[(k + 1) % 3], x))
}

/// The pairs of triangles that cross: how many, and the first (by index).
pub fn crossings(surface: &TriSurface, tree: &TriangleTree) -> (usize, Option<(u32, u32)>) {
    let boxes: Vec<(P, P)> =
        (0..surface.triangles.len()).map(|t| crate::geom::vec3::bounding_box(&surface.corners(t))).collect();
    let found: Vec<(usize, Option<(u32, u32)>)> = (0..surface.triangles.len())
        .into_par_iter()
        .map(|t| {
            let (lo, hi) = boxes[t];
            let tri = surface.triangles[t];
            let mut count = 0;
            let mut first: Option<u32> = None;
            tree.overlapping(lo, hi, |u| {
                let (ulo, uhi) = boxes[u as usize];
                if u as usize <= t
                    || (0..3).any(|a| ulo[a] > hi[a] || uhi[a] < lo[a])
                    || surface.triangles[u as usize].iter().any(|v| tri.contains(v))
                {
                    return;
                }
                if triangles_cross(surface.corners(t), surface.corners(u as usize)) {
                    count += 1;
                    first = Some(first.map_or(u, |f| f.min(u)));
                }
            });
            (count, first.map(|u| (t as u32, u)))
        })
        .collect();
    let count = found.iter().map(|f| f.0).sum();
    (count, found.iter().find_map(|f| f.1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::surface::TriSurface;

    fn union(a: TriSurface, b: &TriSurface) -> TriSurface {
        let mut s = a;
        let n = s.vertices.len() as u32;
        s.vertices.extend(&b.vertices);
        s.triangles.extend(b.triangles.iter().map(|t| t.map(|v| v + n)));
        s
    }

    #[test]
    fn overlapping_boxes_cross_and_nested_or_touching_ones_do_not() {
        let count = |s: &TriSurface| crossings(s, &TriangleTree::new(s));
        let a = TriSurface::cuboid([0.0; 3], [2.0; 3]);
        assert_eq!(count(&a), (0, None));
        // Overlapping: crossing pairs found.
        let (n, first) = count(&union(a.clone(), &TriSurface::cuboid([0.9, 1.2, 1.3], [3.1, 2.7, 3.3])));
        assert!(n > 0 && first.is_some_and(|(t, u)| t < 12 && u >= 12), "{n} {first:?}");
        // Nested, apart, or touching face to face: none.
        assert_eq!(count(&union(a.clone(), &TriSurface::cuboid([0.5; 3], [1.5; 3]))).0, 0);
        assert_eq!(count(&union(a.clone(), &TriSurface::cuboid([3.0; 3], [4.0; 3]))).0, 0);
        assert_eq!(count(&union(a, &TriSurface::cuboid([2.0, 0.0, 0.0], [4.0, 2.0, 2.0]))).0, 0);
    }
}
