//! Closed triangle surfaces: the domains users bring as STL, OBJ, OFF or
//! PLY files ([`crate::io::read_surface`]), checked and oriented before
//! anything is meshed from them.
//!
//! [`TriSurface::into_closed`] says exactly what keeps a surface from
//! enclosing a volume — boundary (open) edges, non-manifold edges, a
//! non-orientable component, triangles crossing each other — naming the
//! file and an example edge or pair of triangles; it fixes what has one
//! meaning: triangles whose orientation disagrees with their neighbours'
//! are turned, a shell facing inward is turned outward, and a shell nested
//! inside another one is turned inward (a hole).
//! Triangles with a repeated vertex are dropped and counted; triangles of
//! zero area are counted.

pub mod bvh;
pub mod crossing;

use crate::error::{Error, Result};
use std::collections::HashMap;

/// A triangle surface: vertices and triangles as 3 vertex indices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriSurface {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles, as indices into `vertices`, counter-clockwise seen from
    /// outside once [`TriSurface::into_closed`] has oriented them.
    pub triangles: Vec<[u32; 3]>,
}

/// What [`TriSurface::into_closed`] found and fixed.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct SurfaceReport {
    /// Triangles left (after dropping those with a repeated vertex).
    pub triangles: usize,
    /// Triangles dropped because a vertex was repeated in them.
    pub dropped: usize,
    /// Triangles of zero area (kept: they enclose nothing).
    pub zero_area: usize,
    /// Connected shells.
    pub shells: usize,
    /// Shells nested inside an odd number of others: holes.
    pub holes: usize,
    /// Triangles turned to agree with their neighbours.
    pub reoriented: usize,
    /// Shells that faced inward (or a hole that faced outward), turned.
    pub flipped_shells: usize,
    /// The enclosed volume.
    pub volume: f64,
}

use crate::vec3::{cross, dot, norm, sub, P};

impl TriSurface {
    /// A surface from vertices and triangles, rejecting (by index)
    /// out-of-range vertex references and non-finite coordinates.
    pub fn new(vertices: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>) -> Result<Self> {
        if let Some(i) = vertices.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(Error::InvalidInput(format!("vertex {i} has a non-finite coordinate: {:?}", vertices[i])));
        }
        let n = vertices.len();
        if let Some((t, &bad)) =
            triangles.iter().enumerate().find_map(|(t, tri)| tri.iter().find(|&&v| v as usize >= n).map(|v| (t, v)))
        {
            return Err(Error::InvalidInput(format!(
                "triangle {t} refers to vertex {bad}, but the surface has {n} vertices (indices 0..{n})"
            )));
        }
        Ok(Self { vertices, triangles })
    }

    pub(crate) fn corners(&self, t: usize) -> [P; 3] {
        self.triangles[t].map(|v| self.vertices[v as usize])
    }

    /// The signed volume enclosed (positive when the triangles face
    /// outward): the sum of the tets from the origin over the triangles.
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len()).map(|t| self.tri_volume(t)).sum()
    }

    fn tri_volume(&self, t: usize) -> f64 {
        let [a, b, c] = self.corners(t);
        dot(a, cross(b, c)) / 6.0
    }

    /// The total area.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * norm(cross(sub(b, a), sub(c, a)))
            })
            .sum()
    }

    /// Lower and upper corners of the vertices' bounding box.
    pub fn bounding_box(&self) -> (P, P) {
        crate::vec3::bounding_box(&self.vertices)
    }

    /// The generalised winding number of the surface at `p`: 1 inside a
    /// closed, outward surface, 0 outside (the solid angles of the
    /// triangles seen from `p`, over 4π; Van Oosterom and Strackee).
    pub fn winding_number(&self, p: P) -> f64 {
        self.winding(0..self.triangles.len(), p)
    }

    /// The winding number at `p` of the triangles `tris` alone.
    fn winding(&self, tris: impl Iterator<Item = usize>, p: P) -> f64 {
        let mut total = 0.0;
        for t in tris {
            let [a, b, c] = self.corners(t).map(|v| sub(v, p));
            let (la, lb, lc) = (norm(a), norm(b), norm(c));
            let num = dot(a, cross(b, c));
            let den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb;
            total += 2.0 * num.atan2(den);
        }
        total / (4.0 * std::f64::consts::PI)
    }

    /// Checks that the surface encloses a volume and orients it (see the
    /// module's documentation); `name` (the file) heads every error.
    pub fn into_closed(mut self, name: &str) -> Result<(TriSurface, SurfaceReport)> {
        let mut report = SurfaceReport::default();
        let before = self.triangles.len();
        self.triangles.retain(|t| t[0] != t[1] && t[1] != t[2] && t[2] != t[0]);
        report.dropped = before - self.triangles.len();
        if self.triangles.is_empty() {
            return Err(Error::InvalidInput(format!("{name}: the surface has no triangles")));
        }
        report.zero_area = (0..self.triangles.len())
            .filter(|&t| {
                let [a, b, c] = self.corners(t);
                cross(sub(b, a), sub(c, a)) == [0.0; 3]
            })
            .count();

        // Each undirected edge with the triangles using it.
        let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::with_capacity(3 * self.triangles.len() / 2);
        for (t, tri) in self.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                edges.entry((a.min(b), a.max(b))).or_default().push(t as u32);
            }
        }
        let mut open: Vec<(u32, u32)> = edges.iter().filter(|(_, ts)| ts.len() == 1).map(|(&e, _)| e).collect();
        let mut fans: Vec<(u32, u32)> = edges.iter().filter(|(_, ts)| ts.len() > 2).map(|(&e, _)| e).collect();
        if !open.is_empty() || !fans.is_empty() {
            open.sort_unstable();
            fans.sort_unstable();
            let mut what = Vec::new();
            if let Some(&(a, b)) = open.first() {
                what.push(format!(
                    "{} boundary (open) edges, each on one triangle only (e.g. between vertices {a} and {b})",
                    open.len()
                ));
            }
            if let Some(&(a, b)) = fans.first() {
                what.push(format!(
                    "{} non-manifold edges, each on more than two triangles (e.g. between vertices {a} and {b}, on {})",
                    fans.len(),
                    edges[&(a, b)].len()
                ));
            }
            return Err(Error::InvalidInput(format!(
                "{name}: the surface is not closed, so it encloses no volume: {}",
                what.join("; ")
            )));
        }

        // Shells: orient each by its first triangle, walking across edges
        // (two triangles sharing an edge must run along it in opposite
        // directions).
        let n = self.triangles.len();
        let mut shell = vec![u32::MAX; n];
        let mut turned = vec![false; n];
        let mut shells = 0u32;
        for seed in 0..n {
            if shell[seed] != u32::MAX {
                continue;
            }
            shell[seed] = shells;
            let mut stack = vec![seed];
            while let Some(t) = stack.pop() {
                let tri = self.oriented(t, turned[t]);
                for k in 0..3 {
                    let (a, b) = (tri[k], tri[(k + 1) % 3]);
                    for &u in &edges[&(a.min(b), a.max(b))] {
                        let u = u as usize;
                        if u == t {
                            continue;
                        }
                        // u must run b -> a.
                        let runs_ab = |tri: [u32; 3]| (0..3).any(|j| tri[j] == a && tri[(j + 1) % 3] == b);
                        if shell[u] == u32::MAX {
                            shell[u] = shells;
                            turned[u] = runs_ab(self.triangles[u]);
                            stack.push(u);
                        } else if runs_ab(self.oriented(u, turned[u])) {
                            return Err(Error::InvalidInput(format!(
                                "{name}: the surface cannot be oriented (a Möbius-like shell): triangles {t} and {u} \
                                 cannot both face outward across the edge between vertices {a} and {b}"
                            )));
                        }
                    }
                }
            }
            shells += 1;
        }
        report.shells = shells as usize;

        // A surface crossing itself has no one inside (see `crossing`).
        if let (count, Some((t, u))) = crossing::crossings(&self, &bvh::TriangleTree::new(&self)) {
            let (st, su) = (shell[t as usize], shell[u as usize]);
            let whose = if st == su {
                format!("both of shell {st}, which folds through itself")
            } else {
                format!("of shells {st} and {su}, which overlap: join them into one surface (their union)")
            };
            return Err(Error::InvalidInput(format!(
                "{name}: the surface crosses itself, so its inside is ambiguous: {count} pairs of triangles \
                 intersect (e.g. triangles {t} and {u}, {whose})"
            )));
        }

        // Each shell outward, then nested shells inward: a shell inside an
        // odd number of others is a hole.
        let mut volume = vec![0.0; shells as usize];
        for t in 0..n {
            let v = self.tri_volume(t);
            volume[shell[t] as usize] += if turned[t] { -v } else { v };
        }
        let mut outward: Vec<bool> = volume.iter().map(|&v| v >= 0.0).collect();
        if shells > 1 {
            let first: Vec<usize> = (0..shells).map(|s| shell.iter().position(|&x| x == s).unwrap_or(0)).collect();
            for s in 0..shells as usize {
                // A vertex of shell s, against every other shell alone.
                let p = self.vertices[self.triangles[first[s]][0] as usize];
                let mut depth = 0;
                for o in 0..shells as usize {
                    if o == s {
                        continue;
                    }
                    if self.winding((0..n).filter(|&t| shell[t] as usize == o), p).abs() > 0.5 {
                        depth += 1;
                    }
                }
                if depth % 2 == 1 {
                    report.holes += 1;
                    outward[s] = !outward[s];
                }
            }
        }
        // A triangle turns when its walked orientation is not its shell's
        // outward one; a shell most of whose triangles turn was given
        // inside out (flipped whole), the others disagreed with their
        // neighbours (reoriented).
        let mut turns = vec![0usize; shells as usize];
        let mut sizes = vec![0usize; shells as usize];
        for t in 0..n {
            let s = shell[t] as usize;
            sizes[s] += 1;
            if turned[t] == outward[s] {
                let [a, b, c] = self.triangles[t];
                self.triangles[t] = [a, c, b];
                turns[s] += 1;
            }
        }
        for s in 0..shells as usize {
            if 2 * turns[s] > sizes[s] {
                report.flipped_shells += 1;
                report.reoriented += sizes[s] - turns[s];
            } else {
                report.reoriented += turns[s];
            }
        }
        report.triangles = n;
        report.volume = self.signed_volume();
        if report.volume <= 0.0 {
            return Err(Error::InvalidInput(format!(
                "{name}: the surface encloses no volume (its shells' volumes sum to {:e})",
                report.volume
            )));
        }
        Ok((self, report))
    }

    fn oriented(&self, t: usize, turned: bool) -> [u32; 3] {
        let [a, b, c] = self.triangles[t];
        if turned {
            [a, c, b]
        } else {
            [a, b, c]
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The axis-aligned box `lo..hi`, 12 triangles facing outward.
    pub(crate) fn box_surface(lo: P, hi: P) -> TriSurface {
        let vertices = (0..8).map(|i| [0, 1, 2].map(|a| if (i >> a) & 1 == 1 { hi[a] } else { lo[a] })).collect();
        // Each face as a quad of corner indices, counter-clockwise from outside.
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        TriSurface { vertices, triangles }
    }

    #[test]
    fn a_closed_box_is_kept_and_measured() {
        let s = box_surface([0.0; 3], [1.0, 2.0, 3.0]);
        assert!((s.signed_volume() - 6.0).abs() < 1e-12);
        assert!((s.area() - 22.0).abs() < 1e-12);
        assert!((s.winding_number([0.5, 1.0, 1.5]) - 1.0).abs() < 1e-9);
        assert!(s.winding_number([2.0, 1.0, 1.5]).abs() < 1e-9);
        let (c, r) = s.clone().into_closed("box").unwrap();
        assert_eq!(c, s);
        assert_eq!((r.shells, r.holes, r.reoriented, r.flipped_shells, r.dropped), (1, 0, 0, 0, 0));
        assert!((r.volume - 6.0).abs() < 1e-12);
    }

    #[test]
    fn inconsistent_and_inward_triangles_are_turned() {
        let mut s = box_surface([0.0; 3], [1.0; 3]);
        s.triangles[3].swap(1, 2);
        s.triangles[7].swap(0, 1);
        let (c, r) = s.clone().into_closed("box").unwrap();
        assert_eq!(r.reoriented, 2);
        assert!((c.signed_volume() - 1.0).abs() < 1e-12);
        // All turned: inward, flipped whole.
        for t in &mut s.triangles {
            t.swap(1, 2);
        }
        let (c, r) = s.into_closed("box").unwrap();
        assert_eq!(r.flipped_shells, 1);
        assert!((c.signed_volume() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn overlapping_shells_are_refused_by_name() {
        let mut s = box_surface([0.0; 3], [2.0; 3]);
        let b = box_surface([0.9, 1.2, 1.3], [3.1, 2.7, 3.3]);
        s.vertices.extend(&b.vertices);
        s.triangles.extend(b.triangles.iter().map(|t| t.map(|v| v + 8)));
        let e = s.into_closed("two.stl").unwrap_err().to_string();
        assert!(e.contains("two.stl: the surface crosses itself") && e.contains("shells 0 and 1"), "{e}");
    }

    #[test]
    fn a_nested_shell_is_a_hole() {
        let outer = box_surface([0.0; 3], [3.0; 3]);
        let inner = box_surface([1.0; 3], [2.0; 3]);
        let mut s = outer.clone();
        s.vertices.extend(&inner.vertices);
        s.triangles.extend(inner.triangles.iter().map(|t| t.map(|v| v + 8)));
        let (c, r) = s.into_closed("shells").unwrap();
        assert_eq!((r.shells, r.holes), (2, 1));
        assert!((c.signed_volume() - 26.0).abs() < 1e-12, "{}", c.signed_volume());
        // Two separate boxes: two shells, no hole.
        let mut s = outer;
        let apart = box_surface([5.0; 3], [6.0; 3]);
        s.vertices.extend(&apart.vertices);
        s.triangles.extend(apart.triangles.iter().map(|t| t.map(|v| v + 8)));
        let (c, r) = s.into_closed("boxes").unwrap();
        assert_eq!((r.shells, r.holes), (2, 0));
        assert!((c.signed_volume() - 28.0).abs() < 1e-12);
    }

    #[test]
    fn open_and_non_manifold_surfaces_are_named_errors() {
        let mut s = box_surface([0.0; 3], [1.0; 3]);
        s.triangles.pop();
        let e = s.into_closed("open.stl").unwrap_err().to_string();
        assert!(e.contains("open.stl") && e.contains("3 boundary (open) edges"), "{e}");
        let mut s = box_surface([0.0; 3], [1.0; 3]);
        // A fin on edge 0-1: a third triangle there (and its twin, closed).
        s.vertices.push([0.5, -1.0, 0.0]);
        s.triangles.push([0, 1, 8]);
        s.triangles.push([1, 0, 8]);
        let e = s.into_closed("fin.obj").unwrap_err().to_string();
        assert!(e.contains("fin.obj") && e.contains("non-manifold edges"), "{e}");
        let e = TriSurface::default().into_closed("empty.off").unwrap_err().to_string();
        assert!(e.contains("empty.off") && e.contains("no triangles"), "{e}");
    }

    #[test]
    fn repeated_vertices_are_dropped_and_counted() {
        let mut s = box_surface([0.0; 3], [1.0; 3]);
        s.triangles.push([2, 2, 5]);
        let (_, r) = s.into_closed("box").unwrap();
        assert_eq!((r.dropped, r.triangles), (1, 12));
    }
}
