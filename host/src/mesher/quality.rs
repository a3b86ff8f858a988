//! Quality and conformity of a tet mesh: dihedral angles, inverted tets,
//! volume; faces shared by the right number of tets and a closed boundary.

use crate::TetMesh;
use std::collections::HashMap;
use std::fmt;

/// Element quality of a mesh, from its f32 vertices evaluated in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quality {
    /// Number of tets.
    pub tets: usize,
    /// Number of vertices used by some tet.
    pub vertices: usize,
    /// Smallest dihedral angle of any tet, in degrees (`NaN` without tets).
    pub min_dihedral: f64,
    /// Largest dihedral angle of any tet, in degrees (`NaN` without tets).
    pub max_dihedral: f64,
    /// Tets whose signed volume is zero or negative.
    pub inverted: usize,
    /// Sum of the tets' signed volumes.
    pub volume: f64,
}

/// The six dihedral angles of the tet `p`, in radians, in edge order
/// 01, 02, 03, 12, 13, 23.
pub fn dihedral_angles(p: [[f64; 3]; 4]) -> [f64; 6] {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross =
        |u: [f64; 3], v: [f64; 3]| [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    // Normal of the face opposite vertex k, pointing away from vertex k.
    let normal = |k: usize| {
        let [a, b, c] = match k {
            0 => [1, 2, 3],
            1 => [0, 2, 3],
            2 => [0, 1, 3],
            _ => [0, 1, 2],
        };
        let n = cross(sub(p[b], p[a]), sub(p[c], p[a]));
        if dot(n, sub(p[k], p[a])) > 0.0 {
            n.map(|x| -x)
        } else {
            n
        }
    };
    let n = [0, 1, 2, 3].map(normal);
    // The edge ij is shared by the faces opposite the other two vertices;
    // the interior angle there is pi minus the angle between their outward normals.
    let angle = |k: usize, l: usize| {
        let c = -dot(n[k], n[l]) / (dot(n[k], n[k]) * dot(n[l], n[l])).sqrt();
        c.clamp(-1.0, 1.0).acos()
    };
    [angle(2, 3), angle(1, 3), angle(1, 2), angle(0, 3), angle(0, 2), angle(0, 1)]
}

impl Quality {
    /// Measures `mesh`.
    pub fn of(mesh: &TetMesh) -> Self {
        let mut q = Self {
            tets: mesh.tets.len(),
            vertices: 0,
            min_dihedral: f64::NAN,
            max_dihedral: f64::NAN,
            inverted: 0,
            volume: 0.0,
        };
        let mut used = vec![false; mesh.vertices.len()];
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (t, tet) in mesh.tets.iter().enumerate() {
            for &v in tet {
                used[v as usize] = true;
            }
            let volume = mesh.tet_volume(t);
            q.volume += volume;
            if volume <= 0.0 {
                q.inverted += 1;
            }
            let p = tet.map(|v| mesh.vertices[v as usize].map(f64::from));
            for a in dihedral_angles(p) {
                lo = lo.min(a);
                hi = hi.max(a);
            }
        }
        q.vertices = used.iter().filter(|&&u| u).count();
        if !mesh.tets.is_empty() {
            q.min_dihedral = lo.to_degrees();
            q.max_dihedral = hi.to_degrees();
        }
        q
    }
}

impl fmt::Display for Quality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} tets, {} vertices, dihedral angles {:.2}..{:.2} degrees, {} inverted, volume {:.6}",
            self.tets, self.vertices, self.min_dihedral, self.max_dihedral, self.inverted, self.volume
        )
    }
}

/// How the tets of a mesh fit together, counted over triangles and edges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Conformity {
    /// Triangles shared by two tets.
    pub interior_faces: usize,
    /// Triangles of one tet only: the boundary.
    pub boundary_faces: usize,
    /// Triangles shared by more than two tets (never in a valid mesh).
    pub overshared_faces: usize,
    /// Interior triangles whose two tets lie on the same side of them
    /// (the tets overlap there).
    pub same_side_faces: usize,
    /// Edges of the boundary.
    pub boundary_edges: usize,
    /// Boundary edges in an odd number of boundary triangles: cracks, where
    /// neighbouring tets do not meet face to face (never in a valid mesh).
    pub cracked_edges: usize,
    /// Boundary edges in four or more boundary triangles: pieces of the
    /// mesh touching along an edge (the boundary is not a manifold there).
    pub pinched_edges: usize,
}

impl Conformity {
    /// Counts the faces and boundary edges of `mesh`. Tets are taken with
    /// their orientation as given (positive volume expected).
    pub fn of(mesh: &TetMesh) -> Self {
        // Each tet's faces, oriented outward for a positive tet.
        const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
        // Sorted triangle -> (tets, orientation of the first, two tets seen on one side).
        let mut faces: HashMap<[u32; 3], (u32, bool, bool)> = HashMap::with_capacity(mesh.tets.len() * 3);
        for tet in &mesh.tets {
            for face in FACES {
                let tri = face.map(|i| tet[i]);
                let (key, even) = sorted_with_parity(tri);
                faces
                    .entry(key)
                    .and_modify(|e| {
                        e.0 += 1;
                        // Two tets on opposite sides see the face with opposite orientations.
                        if e.1 == even {
                            e.2 = true;
                        }
                    })
                    .or_insert((1, even, false));
            }
        }
        let mut c = Self::default();
        let mut edges: HashMap<[u32; 2], u32> = HashMap::new();
        for (key, &(count, _, same_side)) in &faces {
            match count {
                1 => {
                    c.boundary_faces += 1;
                    for (a, b) in [(key[0], key[1]), (key[1], key[2]), (key[0], key[2])] {
                        *edges.entry([a, b]).or_insert(0) += 1;
                    }
                }
                2 => {
                    c.interior_faces += 1;
                    c.same_side_faces += same_side as usize;
                }
                _ => c.overshared_faces += 1,
            }
        }
        c.boundary_edges = edges.len();
        c.cracked_edges = edges.values().filter(|&&n| n % 2 == 1).count();
        c.pinched_edges = edges.values().filter(|&&n| n % 2 == 0 && n > 2).count();
        c
    }

    /// Tets meet face to face: every triangle in one or two tets, two from
    /// opposite sides, and the boundary closed (no crack).
    pub fn is_conforming(&self) -> bool {
        self.overshared_faces == 0 && self.same_side_faces == 0 && self.cracked_edges == 0
    }

    /// Conforming, and the boundary a 2-manifold along its edges: each
    /// boundary edge joins exactly two boundary triangles.
    pub fn is_manifold(&self) -> bool {
        self.is_conforming() && self.pinched_edges == 0
    }
}

/// The triangle's vertices sorted, and whether sorting was an even permutation.
fn sorted_with_parity(mut t: [u32; 3]) -> ([u32; 3], bool) {
    let mut even = true;
    for (i, j) in [(0, 1), (1, 2), (0, 1)] {
        if t[i] > t[j] {
            t.swap(i, j);
            even = !even;
        }
    }
    (t, even)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `TetMesh::cube(n)` with every tet positively oriented.
    fn cube(n: usize) -> TetMesh {
        let mut mesh = TetMesh::cube(n);
        for t in 0..mesh.tets.len() {
            if mesh.tet_volume(t) < 0.0 {
                mesh.tets[t].swap(2, 3);
            }
        }
        mesh
    }

    #[test]
    fn regular_tet_angles() {
        let p = [[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]];
        for a in dihedral_angles(p) {
            assert!((a.to_degrees() - (1.0f64 / 3.0).acos().to_degrees()).abs() < 1e-9);
        }
        // The corner tet of a cube: three right angles at the corner's edges.
        let c = dihedral_angles([[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        for a in &c[..3] {
            assert!((a.to_degrees() - 90.0).abs() < 1e-9);
        }
    }

    #[test]
    fn cube_mesh_is_conforming() {
        let mesh = cube(3);
        let q = Quality::of(&mesh);
        assert_eq!(q.tets, 162);
        assert_eq!(q.inverted, 0);
        assert!((q.volume - 1.0).abs() < 1e-12);
        assert!((q.min_dihedral - 45.0).abs() < 1e-4 && (q.max_dihedral - 90.0).abs() < 1e-4, "{q}");
        let c = Conformity::of(&mesh);
        assert!(c.is_manifold(), "{c:?}");
        // 6 sides x 9 squares x 2 triangles.
        assert_eq!(c.boundary_faces, 108);
        assert_eq!(c.interior_faces, (162 * 4 - 108) / 2);
    }

    #[test]
    fn defects_are_counted() {
        let mut mesh = cube(1);
        // A copy of tet 0: its faces are shared with a tet on the same side.
        mesh.tets.push(mesh.tets[0]);
        let c = Conformity::of(&mesh);
        assert!(c.same_side_faces > 0 && !c.is_conforming());
        // Flip a tet: negative volume.
        let mut flipped = cube(1);
        flipped.tets[0].swap(0, 1);
        assert_eq!(Quality::of(&flipped).inverted, 1);
        // Drop a tet: the boundary stays closed, around the hole too.
        let mut holed = cube(2);
        holed.tets.remove(0);
        assert!(Conformity::of(&holed).is_manifold());
        // Two cubes touching along an edge: a pinch.
        let mut pinched = TetMesh::voxels(2, |i, j, k| k == 0 && i == j);
        for t in 0..pinched.tets.len() {
            if pinched.tet_volume(t) < 0.0 {
                pinched.tets[t].swap(2, 3);
            }
        }
        let c = Conformity::of(&pinched);
        assert!(c.is_conforming() && !c.is_manifold() && c.pinched_edges == 1, "{c:?}");
    }
}
