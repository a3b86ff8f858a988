//! What particle simulations ask of each cell, from its polyhedron: its
//! surface area, its faces counted above thresholds (OVITO's
//! coordination), the Voronoi index — how many of those faces have 3, 4,
//! 5, ... edges — and the largest face order.
//!
//! The thresholds are OVITO's (its Voronoi analysis): an edge counts if
//! it is at least the edge threshold long; a face counts if its area is
//! above the face threshold (the larger of the absolute one and the
//! relative one times the cell's whole surface; no test when both are 0)
//! and it keeps at least 3 counted edges; every counted face, walls'
//! included, adds one to the coordination and to the index at its order.
//! The edge threshold may also be given relative to the cell's size
//! (`V^(1/3)`), the larger one applies. Points of a polyhedron closer than
//! [`WELD_TOLERANCE`](crate::passes::polyhedra::WELD_TOLERANCE) of its
//! diagonal are one point already (the kernels' f32 rounding): a lattice's
//! vertices where more than three cells meet need no threshold.

use crate::geom::vec3::{cross, norm, sub};
use crate::passes::polyhedra::CellPolyhedron;
use rayon::prelude::*;

/// Power weights `r²` from radii (voro++'s radical tessellation: the
/// cell of particle `i` is where `|x - x_i|² - r_i²` is least).
pub fn radii_weights(radii: &[f64]) -> crate::error::Result<Vec<f64>> {
    if let Some(i) = radii.iter().position(|r| !(r.is_finite() && *r >= 0.0)) {
        return Err(crate::error::Error::InvalidInput(format!(
            "particle {i}'s radius is {}; radii must be numbers >= 0",
            radii[i]
        )));
    }
    Ok(radii.iter().map(|r| r * r).collect())
}

/// The orders the Voronoi index counts: faces with 3, 4, ... edges, the
/// last column counting faces with `2 + INDEX_ORDERS` edges or more.
pub const INDEX_ORDERS: usize = 8;

/// Which edges and faces the Voronoi index counts (all 0: every one).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IndexThresholds {
    /// Edges shorter than this length are not counted.
    pub edge: f64,
    /// Edges shorter than this times the cell's `V^(1/3)` are not counted.
    pub relative_edge: f64,
    /// Faces of this area or less are not counted.
    pub face: f64,
    /// Faces of this fraction of the cell's surface or less are not
    /// counted.
    pub relative_face: f64,
}

impl IndexThresholds {
    /// Refuses negative or non-finite thresholds.
    pub fn check(&self) -> crate::error::Result<()> {
        for (name, v) in [
            ("edge", self.edge),
            ("relative edge", self.relative_edge),
            ("face", self.face),
            ("relative face", self.relative_face),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::error::Error::InvalidInput(format!(
                    "the {name} threshold must be a number >= 0, not {v}"
                )));
            }
        }
        Ok(())
    }
}

/// The per-particle quantities of a diagram's cells, per input site (an
/// empty cell: zeros).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleCells {
    /// The cell's surface area, every face's (walls' included).
    pub area: Vec<f64>,
    /// Its faces the thresholds count (OVITO's coordination).
    pub coordination: Vec<u32>,
    /// Its counted faces by order: column `k` for `k + 3` edges, the last
    /// for that many or more.
    pub index: Vec<[u32; INDEX_ORDERS]>,
    /// The most edges of a counted face (0: none).
    pub max_face_order: Vec<u32>,
}

impl ParticleCells {
    /// The quantities of the cells in `rows`.
    pub fn rows(&self, rows: std::ops::Range<usize>) -> Self {
        Self {
            area: self.area[rows.clone()].to_vec(),
            coordination: self.coordination[rows.clone()].to_vec(),
            index: self.index[rows.clone()].to_vec(),
            max_face_order: self.max_face_order[rows].to_vec(),
        }
    }

    /// The quantities of `n` sites' cells from their `polyhedra` (at most
    /// one per site, each naming its site).
    pub fn of(n: usize, polyhedra: &[CellPolyhedron], thresholds: &IndexThresholds) -> Self {
        let per: Vec<(usize, f64, u32, [u32; INDEX_ORDERS], u32)> = polyhedra
            .par_iter()
            .filter(|p| (p.site as usize) < n)
            .map(|p| {
                let (area, coordination, index, max) = cell_quantities(p, thresholds);
                (p.site as usize, area, coordination, index, max)
            })
            .collect();
        let mut out = Self {
            area: vec![0.0; n],
            coordination: vec![0; n],
            index: vec![[0; INDEX_ORDERS]; n],
            max_face_order: vec![0; n],
        };
        for (i, area, coordination, index, max) in per {
            out.area[i] = area;
            out.coordination[i] = coordination;
            out.index[i] = index;
            out.max_face_order[i] = max;
        }
        out
    }
}

/// A polygon's area.
fn polygon_area(points: &[[f64; 3]], ring: &[u32]) -> f64 {
    let p0 = points[ring[0] as usize];
    let mut sum = [0.0; 3];
    for w in ring[1..].windows(2) {
        let c = cross(sub(points[w[0] as usize], p0), sub(points[w[1] as usize], p0));
        for k in 0..3 {
            sum[k] += c[k];
        }
    }
    0.5 * norm(sum)
}

/// One cell's surface area, coordination, index and largest face order.
pub(crate) fn cell_quantities(p: &CellPolyhedron, t: &IndexThresholds) -> (f64, u32, [u32; INDEX_ORDERS], u32) {
    let areas: Vec<f64> = p.faces().map(|ring| polygon_area(&p.vertices, ring)).collect();
    let surface: f64 = areas.iter().sum();
    let edge = t.edge.max(t.relative_edge * p.volume().max(0.0).cbrt());
    let face = if t.relative_face > 0.0 { t.face.max(t.relative_face * surface) } else { t.face };
    let (mut coordination, mut index, mut max) = (0, [0u32; INDEX_ORDERS], 0);
    for (ring, &area) in p.faces().zip(&areas) {
        if face > 0.0 && area <= face {
            continue;
        }
        let order = (0..ring.len())
            .filter(|&k| {
                let (a, b) = (p.vertices[ring[k] as usize], p.vertices[ring[(k + 1) % ring.len()] as usize]);
                norm(sub(b, a)) >= edge
            })
            .count();
        if order < 3 {
            continue;
        }
        coordination += 1;
        index[(order - 3).min(INDEX_ORDERS - 1)] += 1;
        max = max.max(order as u32);
    }
    (surface, coordination, index, max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box `0..l` as a polyhedron, outward loops.
    fn cuboid(l: [f64; 3]) -> CellPolyhedron {
        let vertices: Vec<[f64; 3]> =
            (0..8).map(|k| [0, 1, 2].map(|a| if (k >> a) & 1 == 1 { l[a] } else { 0.0 })).collect();
        let faces: [[u32; 4]; 6] = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let mut p = CellPolyhedron { vertices, ..Default::default() };
        for (k, f) in faces.iter().enumerate() {
            p.face_vertices.extend(f);
            p.face_ends.push(p.face_vertices.len() as u32);
            p.face_neighbors.push(k as i64);
        }
        p
    }

    #[test]
    fn a_box_has_six_squares_and_thresholds_drop_faces_and_edges() {
        let p = cuboid([1.0, 2.0, 0.01]);
        assert!((p.volume() - 0.02).abs() < 1e-15);
        let q = ParticleCells::of(2, std::slice::from_ref(&p), &IndexThresholds::default());
        assert_eq!(q.coordination, [6, 0]);
        assert_eq!(q.index[0], [0, 6, 0, 0, 0, 0, 0, 0]);
        assert_eq!(q.max_face_order, [4, 0]);
        assert!((q.area[0] - 2.0 * (2.0 + 0.01 + 0.02)).abs() < 1e-12);
        // Edges of 0.01 not counted: the four thin faces keep 2 edges and
        // go; the two large ones keep their 4.
        let t = IndexThresholds { edge: 0.05, ..Default::default() };
        let q = ParticleCells::of(1, std::slice::from_ref(&p), &t);
        assert_eq!((q.coordination[0], q.index[0][1]), (2, 2));
        // The faces of 0.02 or less go (0.01 x 1, 0.01 x 2: the 0.01 x 1
        // faces); relative: 1 % of the surface, 0.0406.
        let t = IndexThresholds { face: 0.015, ..Default::default() };
        assert_eq!(ParticleCells::of(1, std::slice::from_ref(&p), &t).coordination, [4]);
        let t = IndexThresholds { relative_face: 0.01, ..Default::default() };
        assert_eq!(ParticleCells::of(1, std::slice::from_ref(&p), &t).coordination, [2]);
        // Relative to the cell's size: 0.02^(1/3) = 0.27; 0.05 of it is 0.014.
        let t = IndexThresholds { relative_edge: 0.05, ..Default::default() };
        assert_eq!(ParticleCells::of(1, std::slice::from_ref(&p), &t).coordination, [2]);
        assert!(IndexThresholds { face: -1.0, ..Default::default() }.check().is_err());
        assert!(IndexThresholds { relative_edge: f64::NAN, ..Default::default() }.check().is_err());
    }
}
