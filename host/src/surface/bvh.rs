//! A bounding-volume hierarchy over a surface's triangles: boxes split at
//! the median of their centroids' longest axis, four triangles per leaf.
//! It answers the two questions asked of a surface: the nearest triangle to
//! a point (the signed distance the mesher stuffs) and the triangles whose
//! boxes overlap a box (the check that a surface does not cross itself).

use super::TriSurface;
use crate::vec3::{add, bounding_box, scale, P};

/// A node: a box and either two children or a range of the ordered
/// triangles.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: P,
    hi: P,
    /// Leaf: first triangle (in `order`); inner: first child.
    start: u32,
    /// Leaf: triangle count; inner: 0.
    count: u32,
}

/// The hierarchy of one surface's triangles.
pub struct TriangleTree {
    /// Triangles in hierarchy order.
    order: Vec<u32>,
    nodes: Vec<Node>,
}

const LEAF: usize = 4;

fn box_dist2(node: &Node, p: P) -> f64 {
    (0..3).map(|a| (node.lo[a] - p[a]).max(0.0).max(p[a] - node.hi[a]).powi(2)).sum()
}

impl TriangleTree {
    /// The hierarchy of `surface`'s triangles.
    pub fn new(surface: &TriSurface) -> Self {
        let (tris, verts) = (&surface.triangles, &surface.vertices);
        let n = tris.len();
        let centroid: Vec<P> =
            (0..n).map(|t| scale(surface.corners(t).into_iter().fold([0.0; 3], add), 1.0 / 3.0)).collect();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut nodes = vec![Node { lo: [0.0; 3], hi: [0.0; 3], start: 0, count: n as u32 }];
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let (start, count) = (nodes[i].start as usize, nodes[i].count as usize);
            let range = start..start + count;
            let corners =
                order[range.clone()].iter().flat_map(|&t| tris[t as usize].iter().map(|&v| &verts[v as usize]));
            let (lo, hi) = bounding_box(corners);
            let (clo, chi) = bounding_box(order[range.clone()].iter().map(|&t| &centroid[t as usize]));
            nodes[i].lo = lo;
            nodes[i].hi = hi;
            if count <= LEAF {
                continue;
            }
            let axis = (0..3).max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b]))).unwrap_or(0);
            let mid = count / 2;
            order[range].select_nth_unstable_by(mid, |&x, &y| {
                centroid[x as usize][axis].total_cmp(&centroid[y as usize][axis])
            });
            let first = nodes.len();
            nodes.push(Node { lo, hi, start: start as u32, count: mid as u32 });
            nodes.push(Node { lo, hi, start: (start + mid) as u32, count: (count - mid) as u32 });
            nodes[i].start = first as u32;
            nodes[i].count = 0;
            stack.push(first);
            stack.push(first + 1);
        }
        Self { order, nodes }
    }

    fn leaf(&self, node: &Node) -> &[u32] {
        &self.order[node.start as usize..(node.start + node.count) as usize]
    }

    /// The least of `dist2(t)` over the triangles `t`, where `dist2` is a
    /// triangle's squared distance to `p` (with what else it finds, `R`):
    /// nodes are visited nearest first and skipped when farther than the
    /// best so far. `None` for a surface without triangles.
    pub fn nearest<R>(&self, p: P, mut dist2: impl FnMut(u32) -> (f64, R)) -> Option<(f64, u32, R)> {
        let (mut best_d2, mut best) = (f64::INFINITY, None);
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i];
            if box_dist2(node, p) >= best_d2 {
                continue;
            }
            if node.count > 0 {
                for &t in self.leaf(node) {
                    let (d2, r) = dist2(t);
                    if d2 < best_d2 {
                        best_d2 = d2;
                        best = Some((t, r));
                    }
                }
            } else {
                // The nearer child last, so that it is searched first.
                let (l, r) = (node.start as usize, node.start as usize + 1);
                if box_dist2(&self.nodes[l], p) < box_dist2(&self.nodes[r], p) {
                    stack.push(r);
                    stack.push(l);
                } else {
                    stack.push(l);
                    stack.push(r);
                }
            }
        }
        best.map(|(t, r)| (best_d2, t, r))
    }

    /// Calls `visit` with every triangle whose leaf's box overlaps the box
    /// `lo..hi` (a superset of the triangles whose own boxes do).
    pub fn overlapping(&self, lo: P, hi: P, mut visit: impl FnMut(u32)) {
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i];
            if (0..3).any(|a| node.lo[a] > hi[a] || node.hi[a] < lo[a]) {
                continue;
            }
            if node.count > 0 {
                self.leaf(node).iter().for_each(|&t| visit(t));
            } else {
                stack.extend([node.start as usize, node.start as usize + 1]);
            }
        }
    }
}
