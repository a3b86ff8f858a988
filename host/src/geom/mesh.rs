//! Tetrahedral meshes: validation, measures and simple built-in shapes.

use crate::error::{Error, Result};

/// A tetrahedral mesh: vertices and tets as 4 vertex indices. Tets may have
/// either orientation (signed volumes are used where orientation matters).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TetMesh {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Tets, as indices into `vertices`.
    pub tets: Vec<[u32; 4]>,
}

/// Signed volume of the tet `a, b, c, d` (positive when `d` is on the side
/// of `(b - a) x (c - a)`), in f64.
pub fn signed_volume(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]) -> f64 {
    let s = |p: [f64; 3], q: [f64; 3]| [0, 1, 2].map(|i| p[i] - q[i]);
    let (u, v, w) = (s(b, a), s(c, a), s(d, a));
    let cross = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    (cross[0] * w[0] + cross[1] * w[1] + cross[2] * w[2]) / 6.0
}

impl TetMesh {
    /// A mesh from vertices and tets, rejecting (by index) out-of-range
    /// vertex references, non-finite coordinates and zero-volume tets.
    pub fn new(vertices: Vec<[f64; 3]>, tets: Vec<[u32; 4]>) -> Result<Self> {
        if let Some(i) = vertices.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(Error::InvalidInput(format!("vertex {i} has a non-finite coordinate: {:?}", vertices[i])));
        }
        let n = vertices.len();
        for (t, tet) in tets.iter().enumerate() {
            if let Some(&bad) = tet.iter().find(|&&v| v as usize >= n) {
                return Err(Error::InvalidInput(format!(
                    "tet {t} refers to vertex {bad}, but the mesh has {n} vertices (indices 0..{n})"
                )));
            }
        }
        let mesh = Self { vertices, tets };
        if let Some(t) = (0..mesh.tets.len()).find(|&t| mesh.tet_volume(t) == 0.0) {
            return Err(Error::InvalidInput(format!("tet {t} {:?} has zero volume", mesh.tets[t])));
        }
        if let Some(t) = (0..mesh.tets.len()).find(|&t| !mesh.tet_volume(t).is_finite()) {
            return Err(Error::InvalidInput(format!(
                "tet {t} {:?} is too large: its volume overflows f64",
                mesh.tets[t]
            )));
        }
        Ok(mesh)
    }

    /// Signed volume of tet `t`.
    pub fn tet_volume(&self, t: usize) -> f64 {
        let [a, b, c, d] = self.tets[t].map(|v| self.vertices[v as usize]);
        signed_volume(a, b, c, d)
    }

    /// Makes every tet positively oriented (swapping two vertices of the
    /// inverted ones) and returns how many were inverted. The algorithms
    /// accept either orientation; this is for writers and readers of the
    /// mesh that expect the usual one.
    pub fn orient_positively(&mut self) -> usize {
        let mut flipped = 0;
        for t in 0..self.tets.len() {
            if self.tet_volume(t) < 0.0 {
                self.tets[t].swap(2, 3);
                flipped += 1;
            }
        }
        flipped
    }

    /// Total volume (sum of the tets' absolute volumes).
    pub fn volume(&self) -> f64 {
        (0..self.tets.len()).map(|t| self.tet_volume(t).abs()).sum()
    }

    /// The mesh's boundary: the tet faces no other tet shares, facing out
    /// of their tet, on the mesh's vertices (unused ones included).
    pub fn boundary(&self) -> crate::geom::surface::TriSurface {
        self.boundary_of(&self.unshared_faces())
    }

    /// [`Self::boundary`] from the mesh's [`Self::unshared_faces`].
    pub fn boundary_of(&self, unshared: &[(u32, u8)]) -> crate::geom::surface::TriSurface {
        let mut triangles: Vec<[u32; 3]> = unshared
            .iter()
            .map(|&(t, f)| {
                let [a, b, c, d] = self.tets[t as usize];
                // Counter-clockwise seen from outside a positive tet.
                let mut face = [[b, c, d], [a, d, c], [a, b, d], [a, c, b]][f as usize];
                if self.tet_volume(t as usize) < 0.0 {
                    face.swap(1, 2);
                }
                face
            })
            .collect();
        triangles.sort_unstable();
        crate::geom::surface::TriSurface { vertices: self.vertices.clone(), triangles }
    }

    /// The tet faces no other tet shares, as (tet, f), face `f` the one
    /// opposite vertex `f`, in tet order. A face is shared when another tet
    /// of its lowest vertex holds its other two: the tets of each vertex
    /// are listed once (4 bytes per tet corner), not every face (a map of
    /// faces took 180 bytes per tet at a million tets, a sorted list 64).
    pub fn unshared_faces(&self) -> Vec<(u32, u8)> {
        use rayon::prelude::*;
        let n = self.tets.iter().flatten().map(|&v| v as usize + 1).max().unwrap_or(0);
        let mut start = vec![0u32; n + 1];
        for &v in self.tets.iter().flatten() {
            start[v as usize + 1] += 1;
        }
        for v in 0..n {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut of = vec![0u32; 4 * self.tets.len()];
        for (t, tet) in self.tets.iter().enumerate() {
            for &v in tet {
                of[fill[v as usize] as usize] = t as u32;
                fill[v as usize] += 1;
            }
        }
        drop(fill);
        (0..self.tets.len())
            .into_par_iter()
            .flat_map_iter(|t| {
                let tet = self.tets[t];
                let (start, of) = (&start, &of);
                (0..4).filter_map(move |f| {
                    let face = [tet[(f + 1) % 4], tet[(f + 2) % 4], tet[(f + 3) % 4]];
                    let a = face[0].min(face[1]).min(face[2]) as usize;
                    let shared = of[start[a] as usize..start[a + 1] as usize]
                        .iter()
                        .any(|&u| u as usize != t && face.iter().all(|v| self.tets[u as usize].contains(v)));
                    (!shared).then_some((t as u32, f as u8))
                })
            })
            .collect()
    }

    /// Centroid of tet `t`.
    pub fn centroid(&self, t: usize) -> [f64; 3] {
        centroid_of(&self.vertices, self.tets[t])
    }

    /// Centroid of every tet.
    pub fn centroids(&self) -> Vec<[f64; 3]> {
        (0..self.tets.len()).map(|t| self.centroid(t)).collect()
    }

    /// Lower and upper corners of the vertices' bounding box.
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        crate::geom::vec3::bounding_box(&self.vertices)
    }

    /// The unit cube cut into `n³` sub-cubes, each split into 6 tets.
    pub fn cube(n: usize) -> Self {
        Self::voxels(n, |_, _, _| true)
    }

    /// The sub-cubes `(i, j, k)` of an `n³` grid over the unit cube for
    /// which `filled` holds, each split into 6 tets (Freudenthal: the tets
    /// of neighbouring cubes share their faces).
    pub fn voxels(n: usize, filled: impl Fn(usize, usize, usize) -> bool) -> Self {
        let n = n.max(1);
        Self::lattice([n; 3], [0.0; 3], [1.0; 3], filled)
    }

    /// The box `lo..hi` cut into `dims` cells along its axes (at least one
    /// each), each split into 6 tets as [`Self::voxels`] does; its corners
    /// are `lo` and `hi` exactly.
    pub fn grid(lo: [f64; 3], hi: [f64; 3], dims: [usize; 3]) -> Self {
        Self::lattice(dims.map(|d| d.max(1)), lo, hi, |_, _, _| true)
    }

    fn lattice(dims: [usize; 3], lo: [f64; 3], hi: [f64; 3], filled: impl Fn(usize, usize, usize) -> bool) -> Self {
        let side = dims.map(|d| d + 1);
        let id = |i: usize, j: usize, k: usize| ((k * side[1] + j) * side[0] + i) as u32;
        let coord = |a: usize, i: usize| {
            if i == dims[a] {
                hi[a]
            } else {
                lo[a] + (hi[a] - lo[a]) * i as f64 / dims[a] as f64
            }
        };
        let vertices = (0..side[0] * side[1] * side[2])
            .map(|v| {
                let (i, j, k) = (v % side[0], (v / side[0]) % side[1], v / (side[0] * side[1]));
                [coord(0, i), coord(1, j), coord(2, k)]
            })
            .collect();
        const PATHS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
        let mut tets = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    if !filled(i, j, k) {
                        continue;
                    }
                    for path in PATHS {
                        let mut at = [i, j, k];
                        let mut tet = [id(i, j, k); 4];
                        for (step, &axis) in path.iter().enumerate() {
                            at[axis] += 1;
                            tet[step + 1] = id(at[0], at[1], at[2]);
                        }
                        tets.push(tet);
                    }
                }
            }
        }
        // Unused vertices are harmless: nothing refers to them.
        tets.shrink_to_fit();
        Self { vertices, tets }
    }
}

/// The centroid of `tet` on `vertices`.
pub fn centroid_of(vertices: &[[f64; 3]], tet: [u32; 4]) -> [f64; 3] {
    let mut c = [0.0f64; 3];
    for v in tet {
        for (a, ca) in c.iter_mut().enumerate() {
            *ca += vertices[v as usize][a] / 4.0;
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_boundary_is_the_faces_met_once_facing_out() {
        let mut mesh = TetMesh::cube(3);
        // An inverted tet faces out all the same.
        mesh.tets[5].swap(2, 3);
        let b = mesh.boundary();
        // 6 sides of 3 x 3 squares, 2 triangles each.
        assert_eq!(b.triangles.len(), 6 * 9 * 2);
        assert!((b.area() - 6.0).abs() < 1e-12);
        assert!((b.signed_volume() - 1.0).abs() < 1e-12, "outwards: {}", b.signed_volume());
        // Every triangle on a side of the cube, once.
        let mut seen = std::collections::HashSet::new();
        for t in &b.triangles {
            let mut key = *t;
            key.sort_unstable();
            assert!(seen.insert(key), "{t:?} twice");
            let on_side = (0..3).any(|a| {
                let c = t.map(|v| mesh.vertices[v as usize][a]);
                c.iter().all(|&x| x == 0.0) || c.iter().all(|&x| x == 1.0)
            });
            assert!(on_side, "{t:?} inside");
        }
    }

    #[test]
    fn inverted_tets_are_reoriented_and_counted() {
        let mut mesh = TetMesh::cube(2);
        let volume = mesh.volume();
        for t in (0..mesh.tets.len()).step_by(3) {
            mesh.tets[t].swap(0, 1);
        }
        let inverted = (0..mesh.tets.len()).filter(|&t| mesh.tet_volume(t) < 0.0).count();
        assert!(inverted > 0);
        assert_eq!(mesh.orient_positively(), inverted);
        assert!((0..mesh.tets.len()).all(|t| mesh.tet_volume(t) > 0.0));
        assert!((mesh.volume() - volume).abs() < 1e-12);
        assert_eq!(mesh.orient_positively(), 0);
    }
}
