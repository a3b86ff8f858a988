//! A bounding-volume hierarchy over a surface's triangles: boxes split at
//! the median of their centroids' longest axis, four triangles per leaf.
//! It answers the two questions asked of a surface: the nearest triangle to
//! a point (the signed distance the mesher stuffs) and the triangles whose
//! boxes overlap a box (the check that a surface does not cross itself).

use super::TriSurface;
use crate::geom::vec3::{add, bounding_box, cross, dot, norm, scale, sub, P};

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
    /// The sum of the triangles' area vectors (area times unit normal):
    /// the dipole that stands for them seen from afar.
    area_normal: P,
    /// Their area-weighted centroid.
    center: P,
    /// The distance from `center` to the box's farthest corner.
    radius: f64,
    /// The triangles' total area.
    area: f64,
}

const NO_DIPOLE: Node = Node {
    lo: [0.0; 3],
    hi: [0.0; 3],
    start: 0,
    count: 0,
    area_normal: [0.0; 3],
    center: [0.0; 3],
    radius: 0.0,
    area: 0.0,
};

/// A node seen from farther than this many times its radius counts as its
/// dipole in the winding number (first order; the error of a node's part is
/// about `1 / BETA²` of it).
const BETA: f64 = 3.0;

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
        let mut nodes = vec![Node { lo: [0.0; 3], hi: [0.0; 3], start: 0, count: n as u32, ..NO_DIPOLE }];
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
            nodes.push(Node { lo, hi, start: start as u32, count: mid as u32, ..NO_DIPOLE });
            nodes.push(Node { lo, hi, start: (start + mid) as u32, count: (count - mid) as u32, ..NO_DIPOLE });
            nodes[i].start = first as u32;
            nodes[i].count = 0;
            stack.push(first);
            stack.push(first + 1);
        }
        // Dipoles bottom up: children come after their parent.
        for i in (0..nodes.len()).rev() {
            let node = nodes[i];
            let (mut area_normal, mut moment, mut area) = ([0.0; 3], [0.0; 3], 0.0);
            let mut add_part = |n: P, c: P, a: f64| {
                area_normal = add(area_normal, n);
                moment = add(moment, scale(c, a));
                area += a;
            };
            if node.count > 0 {
                for &t in &order[node.start as usize..(node.start + node.count) as usize] {
                    let [a, b, c] = surface.corners(t as usize);
                    let n = scale(cross(sub(b, a), sub(c, a)), 0.5);
                    add_part(n, centroid[t as usize], norm(n));
                }
            } else {
                for child in [node.start as usize, node.start as usize + 1] {
                    let c = &nodes[child];
                    add_part(c.area_normal, c.center, c.area);
                }
            }
            let center = if area > 0.0 { scale(moment, 1.0 / area) } else { scale(add(node.lo, node.hi), 0.5) };
            let radius = (0..8)
                .map(|k| {
                    let corner = [0, 1, 2].map(|a| if (k >> a) & 1 == 1 { node.hi[a] } else { node.lo[a] });
                    norm(sub(corner, center))
                })
                .fold(0.0, f64::max);
            nodes[i] = Node { area_normal, center, radius, area, ..node };
        }
        Self { order, nodes }
    }

    /// The hierarchy as the kernels read it (`cvd_kernels::whole::Domain`):
    /// two records per node, `[lo, a]` and `[hi, b]`, the box padded
    /// outwards by `pad` (plus f32 rounding); a leaf has `a = LEAF | first`
    /// and `b` triangles, an inner node its children `a` and `b`; and the
    /// triangles in the leaves' order.
    pub fn kernel_records(&self, surface: &TriSurface, pad: f64) -> (Vec<[f32; 4]>, Vec<[u32; 4]>) {
        use cvd_kernels::whole::LEAF as KERNEL_LEAF;
        let down = |x: f64| {
            let y = (x - pad) as f32;
            if y as f64 > x - pad {
                y.next_down()
            } else {
                y
            }
        };
        let up = |x: f64| {
            let y = (x + pad) as f32;
            if (y as f64) < x + pad {
                y.next_up()
            } else {
                y
            }
        };
        let mut records = Vec::with_capacity(2 * self.nodes.len());
        for node in &self.nodes {
            let (a, b) =
                if node.count > 0 { (KERNEL_LEAF | node.start, node.count) } else { (node.start, node.start + 1) };
            records.push([down(node.lo[0]), down(node.lo[1]), down(node.lo[2]), f32::from_bits(a)]);
            records.push([up(node.hi[0]), up(node.hi[1]), up(node.hi[2]), f32::from_bits(b)]);
        }
        let tris = self.order.iter().map(|&t| {
            let [a, b, c] = surface.triangles[t as usize];
            [a, b, c, 0]
        });
        (records, tris.collect())
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

    /// The generalised winding number of `surface` (whose tree this is) at
    /// `p`: 1 inside a closed outward surface, 0 outside, near 1/2 on it —
    /// and still near 0 or 1 away from small cracks and where shells
    /// overlap (2) or touch. Exact solid angles for the triangles near `p`,
    /// a node's dipole for those far from it (G. Barill, N. Dickson, R.
    /// Schmidt, D. Levin, A. Jacobson, *Fast winding numbers for soups and
    /// clouds*, SIGGRAPH 2018).
    pub fn winding_number(&self, surface: &TriSurface, p: P) -> f64 {
        let mut total = 0.0;
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i];
            let d = sub(node.center, p);
            let d2 = dot(d, d);
            if d2 > (BETA * node.radius).powi(2) {
                total += dot(node.area_normal, d) / (d2 * d2.sqrt());
            } else if node.count > 0 {
                total +=
                    self.leaf(node).iter().map(|&t| super::solid_angle(surface.corners(t as usize), p)).sum::<f64>();
            } else {
                stack.extend([node.start as usize, node.start as usize + 1]);
            }
        }
        total / (4.0 * std::f64::consts::PI)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points::Rng;

    /// The hierarchical winding number agrees with the exact one (the sum
    /// over every triangle) to a few hundredths, inside, outside and near a
    /// torus's surface, and gives the same side everywhere off it.
    #[test]
    fn the_fast_winding_number_matches_the_exact_one() {
        let mesh = crate::mesher::models::builtin("torus", Some(12)).unwrap();
        let surface = mesh.boundary();
        let tree = TriangleTree::new(&surface);
        let (lo, hi) = surface.bounding_box();
        let mut rng = Rng::new(3);
        let mut worst: f64 = 0.0;
        for _ in 0..3000 {
            let p = [0, 1, 2].map(|a| lo[a] - 0.2 + (hi[a] - lo[a] + 0.4) * rng.unit());
            let (fast, exact) = (tree.winding_number(&surface, p), surface.winding_number(p));
            worst = worst.max((fast - exact).abs());
            assert!((exact - 0.5).abs() < 0.1 || (fast > 0.5) == (exact > 0.5), "at {p:?}: {fast} vs {exact}");
        }
        assert!(worst < 0.05, "worst difference {worst}");
    }
}
