//! Closed triangle surfaces: the domains users bring as STL, OBJ, OFF or
//! PLY files (read by `io::read_surface`), checked and oriented before
//! anything is meshed from them.
//!
//! [`TriSurface::into_closed`] says exactly what keeps a surface from
//! enclosing a volume — holes (open edges around a gap wider than
//! [`MAX_CRACK`]; narrower cracks are accepted and counted), non-manifold
//! edges, a
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
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct SurfaceReport {
    /// Triangles left (after dropping those with a repeated vertex).
    pub triangles: usize,
    /// Triangles dropped because a vertex was repeated in them.
    pub dropped: usize,
    /// Triangles of zero area (kept: they enclose nothing).
    pub zero_area: usize,
    /// Boundary (open) edges accepted as cracks: each on one triangle, in
    /// gaps no wider than [`MAX_CRACK`] of the surface's size.
    pub open_edges: usize,
    /// How many cracks (connected runs of open edges) there are.
    pub cracks: usize,
    /// The widest crack: the diagonal of its vertices' bounding box.
    pub widest_crack: f64,
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

use crate::geom::vec3::{cross, dot, norm, sub, P};

/// The widest gap, relative to the surface's longest side, that
/// [`TriSurface::into_closed`] accepts as a crack (1 %): the mesher's
/// lattice, 40 cells along that side by default, does not see it, and the
/// sign of the distance across it comes from the winding number.
pub const MAX_CRACK: f64 = 0.01;

/// The gaps a surface's open edges leave, given each as its triangle runs
/// along it: rims are grouped when connected or nearer than `near` (the
/// two sides of a crack), and a group's width is the square root of the
/// area vector its edges span (half the sum of `a × b`). The two rims of a
/// narrow seam span opposite areas that nearly cancel (the seam's length
/// times its width remains); a hole's rim spans the hole. Widths sorted.
fn cracks(vertices: &[P], rims: &[(u32, u32)], near: f64, origin: P) -> Vec<f64> {
    let mut ids: HashMap<u32, usize> = HashMap::new();
    for &(a, b) in rims {
        for v in [a, b] {
            let n = ids.len();
            ids.entry(v).or_insert(n);
        }
    }
    let mut parent: Vec<usize> = (0..ids.len()).collect();
    fn root(parent: &mut [usize], mut v: usize) -> usize {
        while parent[v] != v {
            parent[v] = parent[parent[v]];
            v = parent[v];
        }
        v
    }
    let join = |parent: &mut Vec<usize>, a: usize, b: usize| {
        let (ra, rb) = (root(parent, a), root(parent, b));
        parent[ra.max(rb)] = ra.min(rb);
    };
    for &(a, b) in rims {
        join(&mut parent, ids[&a], ids[&b]);
    }
    // Rim vertices nearer than `near`, through a grid of that cell size.
    if near > 0.0 {
        let cell = |p: P| p.map(|c| (c / near).floor() as i64);
        let mut grid: HashMap<[i64; 3], Vec<(u32, usize)>> = HashMap::new();
        for (&v, &i) in &ids {
            grid.entry(cell(vertices[v as usize])).or_default().push((v, i));
        }
        for (&v, &i) in &ids {
            let p = vertices[v as usize];
            let c = cell(p);
            for d in 0..27 {
                let key = [c[0] + d % 3 - 1, c[1] + (d / 3) % 3 - 1, c[2] + d / 9 - 1];
                for &(w, j) in grid.get(&key).map_or(&[][..], Vec::as_slice) {
                    if norm(sub(vertices[w as usize], p)) <= near {
                        join(&mut parent, i, j);
                    }
                }
            }
        }
    }
    let mut area: HashMap<usize, P> = HashMap::new();
    for &(a, b) in rims {
        let r = root(&mut parent, ids[&a]);
        let e = area.entry(r).or_insert([0.0; 3]);
        let c = cross(sub(vertices[a as usize], origin), sub(vertices[b as usize], origin));
        *e = [0, 1, 2].map(|k| e[k] + 0.5 * c[k]);
    }
    let mut widths: Vec<f64> = area.values().map(|a| norm(*a).sqrt()).collect();
    widths.sort_by(f64::total_cmp);
    widths
}

/// The signed solid angle of triangle `a, b, c` seen from `p`: positive
/// when `p` is behind it (its corners counter-clockwise seen from the
/// front) — A. Van Oosterom and J. Strackee, IEEE TBME 1983.
pub(crate) fn solid_angle([a, b, c]: [P; 3], p: P) -> f64 {
    let [a, b, c] = [a, b, c].map(|v| sub(v, p));
    let (la, lb, lc) = (norm(a), norm(b), norm(c));
    let num = dot(a, cross(b, c));
    let den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb;
    2.0 * num.atan2(den)
}

impl TriSurface {
    /// The axis-aligned box `lo..hi`: 12 triangles facing outward.
    pub fn cuboid(lo: P, hi: P) -> Self {
        let vertices = (0..8).map(|i| [0, 1, 2].map(|a| if (i >> a) & 1 == 1 { hi[a] } else { lo[a] })).collect();
        // Each face as a quad of corner indices, counter-clockwise from outside.
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        TriSurface { vertices, triangles }
    }

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
    /// outward): the sum of the tets from the bounding box's centre over
    /// the triangles (exact for a closed surface wherever the apex is; for
    /// one with small cracks, the apex inside keeps the cracks' share
    /// small).
    pub fn signed_volume(&self) -> f64 {
        let o = self.centre();
        (0..self.triangles.len()).map(|t| self.tri_volume(t, o)).sum()
    }

    fn centre(&self) -> P {
        let (lo, hi) = self.bounding_box();
        [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]))
    }

    fn tri_volume(&self, t: usize, o: P) -> f64 {
        let [a, b, c] = self.corners(t).map(|v| sub(v, o));
        dot(a, cross(b, c)) / 6.0
    }

    /// The triangles whose boxes meet the box `lo..hi` (on the same
    /// vertices, in the same order).
    pub fn meeting(&self, lo: [f64; 3], hi: [f64; 3]) -> TriSurface {
        let meets =
            |t: &[u32; 3]| crate::geom::vec3::box_meets(t.iter().map(|&v| &self.vertices[v as usize]), (lo, hi));
        let triangles = self.triangles.iter().filter(|t| meets(t)).copied().collect();
        TriSurface { vertices: self.vertices.clone(), triangles }
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
        crate::geom::vec3::bounding_box(&self.vertices)
    }

    /// The generalised winding number of the surface at `p`: 1 inside a
    /// closed, outward surface, 0 outside (the solid angles of the
    /// triangles seen from `p`, over 4π; Van Oosterom and Strackee).
    pub fn winding_number(&self, p: P) -> f64 {
        self.winding(0..self.triangles.len(), p)
    }

    /// The winding number at `p` of the triangles `tris` alone.
    fn winding(&self, tris: impl Iterator<Item = usize>, p: P) -> f64 {
        let total: f64 = tris.map(|t| solid_angle(self.corners(t), p)).sum();
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
        open.sort_unstable();
        fans.sort_unstable();
        if !fans.is_empty() {
            let (a, b) = fans[0];
            let open =
                if open.is_empty() { String::new() } else { format!("; and {} boundary (open) edges", open.len()) };
            return Err(Error::InvalidInput(format!(
                "{name}: the surface is not closed, so it encloses no volume: {} non-manifold edges, each on more \
                 than two triangles (e.g. between vertices {a} and {b}, on {}){open}",
                fans.len(),
                edges[&(a, b)].len()
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
        let o = self.centre();
        for t in 0..n {
            let v = self.tri_volume(t, o);
            volume[shell[t] as usize] += if turned[t] { -v } else { v };
        }
        let mut outward: Vec<bool> = volume.iter().map(|&v| v >= 0.0).collect();
        if shells > 1 {
            // Up to 9 vertices spread through each shell (its triangles'
            // first corners, evenly in index order).
            let mut members: Vec<Vec<usize>> = vec![Vec::new(); shells as usize];
            for t in 0..n {
                members[shell[t] as usize].push(t);
            }
            for s in 0..shells as usize {
                let m = &members[s];
                let probes: Vec<P> = (0..9.min(m.len()))
                    .map(|k| self.vertices[self.triangles[m[k * m.len() / 9.min(m.len())]][0] as usize])
                    .collect();
                let mut depth = 0;
                for (o, others) in members.iter().enumerate() {
                    if o == s {
                        continue;
                    }
                    // The median winding number of shell o at the probes:
                    // 1 inside a closed shell, near 1 inside a cracked one;
                    // near 1/2 on a shell that this one closes across a seam
                    // (where a probe on the rim may see up to 7/8).
                    let mut w: Vec<f64> =
                        probes.iter().map(|&p| self.winding(others.iter().copied(), p).abs()).collect();
                    w.sort_by(f64::total_cmp);
                    if w[w.len() / 2] > 0.75 {
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
        // Open edges, as their (now outward) triangles run along them: small
        // cracks are let through, holes are not.
        let rims: Vec<(u32, u32)> = open
            .iter()
            .map(|&(a, b)| {
                let t = edges[&(a, b)][0] as usize;
                let tri = self.triangles[t];
                if (0..3).any(|j| tri[j] == a && tri[(j + 1) % 3] == b) {
                    (a, b)
                } else {
                    (b, a)
                }
            })
            .collect();
        let (lo, hi) = self.bounding_box();
        let size = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let gaps = cracks(&self.vertices, &rims, MAX_CRACK * size, self.centre());
        let widest = gaps.last().copied().unwrap_or(0.0);
        if widest > MAX_CRACK * size {
            let (a, b) = open[0];
            return Err(Error::InvalidInput(format!(
                "{name}: the surface is not closed, so it encloses no volume: {} boundary (open) edges, each on one \
                 triangle only (e.g. between vertices {a} and {b}), around {} gaps, the widest about {widest:.3e} \
                 across: a hole, more than the {} % of the surface's size ({size:.3e}) let through as a crack",
                open.len(),
                gaps.len(),
                100.0 * MAX_CRACK
            )));
        }
        report.open_edges = open.len();
        report.cracks = gaps.len();
        report.widest_crack = widest;
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

    #[test]
    fn a_closed_box_is_kept_and_measured() {
        let s = TriSurface::cuboid([0.0; 3], [1.0, 2.0, 3.0]);
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
        let mut s = TriSurface::cuboid([0.0; 3], [1.0; 3]);
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
        let mut s = TriSurface::cuboid([0.0; 3], [2.0; 3]);
        let b = TriSurface::cuboid([0.9, 1.2, 1.3], [3.1, 2.7, 3.3]);
        s.vertices.extend(&b.vertices);
        s.triangles.extend(b.triangles.iter().map(|t| t.map(|v| v + 8)));
        let e = s.into_closed("two.stl").unwrap_err().to_string();
        assert!(e.contains("two.stl: the surface crosses itself") && e.contains("shells 0 and 1"), "{e}");
    }

    #[test]
    fn a_nested_shell_is_a_hole() {
        let outer = TriSurface::cuboid([0.0; 3], [3.0; 3]);
        let inner = TriSurface::cuboid([1.0; 3], [2.0; 3]);
        let mut s = outer.clone();
        s.vertices.extend(&inner.vertices);
        s.triangles.extend(inner.triangles.iter().map(|t| t.map(|v| v + 8)));
        let (c, r) = s.into_closed("shells").unwrap();
        assert_eq!((r.shells, r.holes), (2, 1));
        assert!((c.signed_volume() - 26.0).abs() < 1e-12, "{}", c.signed_volume());
        // Two separate boxes: two shells, no hole.
        let mut s = outer;
        let apart = TriSurface::cuboid([5.0; 3], [6.0; 3]);
        s.vertices.extend(&apart.vertices);
        s.triangles.extend(apart.triangles.iter().map(|t| t.map(|v| v + 8)));
        let (c, r) = s.into_closed("boxes").unwrap();
        assert_eq!((r.shells, r.holes), (2, 0));
        assert!((c.signed_volume() - 28.0).abs() < 1e-12);
    }

    #[test]
    fn open_and_non_manifold_surfaces_are_named_errors() {
        let mut s = TriSurface::cuboid([0.0; 3], [1.0; 3]);
        s.triangles.pop();
        let e = s.into_closed("open.stl").unwrap_err().to_string();
        assert!(e.contains("open.stl") && e.contains("3 boundary (open) edges"), "{e}");
        let mut s = TriSurface::cuboid([0.0; 3], [1.0; 3]);
        // A fin on edge 0-1: a third triangle there (and its twin, closed).
        s.vertices.push([0.5, -1.0, 0.0]);
        s.triangles.push([0, 1, 8]);
        s.triangles.push([1, 0, 8]);
        let e = s.into_closed("fin.obj").unwrap_err().to_string();
        assert!(e.contains("fin.obj") && e.contains("non-manifold edges"), "{e}");
        let e = TriSurface::default().into_closed("empty.off").unwrap_err().to_string();
        assert!(e.contains("empty.off") && e.contains("no triangles"), "{e}");
    }

    /// The unit cube's surface with each face cut into `n × n` squares of
    /// two triangles, facing outward.
    pub(crate) fn fine_box(n: u32) -> TriSurface {
        let mut s = TriSurface::default();
        let mut index: HashMap<[u32; 3], u32> = HashMap::new();
        let mut vertex = |s: &mut TriSurface, g: [u32; 3]| {
            *index.entry(g).or_insert_with(|| {
                s.vertices.push(g.map(|c| c as f64 / n as f64));
                s.vertices.len() as u32 - 1
            })
        };
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in [0, n] {
                for i in 0..n {
                    for j in 0..n {
                        let at = |di: u32, dj: u32| {
                            let mut g = [0; 3];
                            g[axis] = side;
                            g[u] = i + di;
                            g[v] = j + dj;
                            g
                        };
                        let q = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)].map(|g| vertex(&mut s, g));
                        // Counter-clockwise seen from outside: u, v, axis is right-handed.
                        let (a, b, c, d) = if side == n { (q[0], q[1], q[2], q[3]) } else { (q[0], q[3], q[2], q[1]) };
                        s.triangles.push([a, b, c]);
                        s.triangles.push([a, c, d]);
                    }
                }
            }
        }
        s
    }

    #[test]
    fn small_cracks_are_let_through_and_holes_are_not() {
        let closed = fine_box(100);
        let (_, r) = closed.clone().into_closed("box").unwrap();
        assert!((r.volume - 1.0).abs() < 1e-10 && r.open_edges == 0, "{r:?}");
        // One triangle missing: a gap 0.007 across, under 1 % of the box.
        let mut s = closed.clone();
        s.triangles.remove(1000);
        let (_, r) = s.into_closed("crack").unwrap();
        assert_eq!((r.open_edges, r.cracks), (3, 1));
        assert!(r.widest_crack > 0.007 && r.widest_crack < 0.0071, "{r:?}");
        assert!((r.volume - 1.0).abs() < 1e-4, "{r:?}");
        // A seam: the top face's vertices moved 1e-7 off its sides', so
        // the two rims (each as wide as the box) face each other.
        let mut s = closed.clone();
        let top: Vec<usize> = (0..s.triangles.len())
            .filter(|&t| s.triangles[t].iter().all(|&v| s.vertices[v as usize][2] == 1.0))
            .collect();
        let mut moved: HashMap<u32, u32> = HashMap::new();
        for t in top {
            for k in 0..3 {
                let v = s.triangles[t][k];
                let p = s.vertices[v as usize];
                if p[0] == 0.0 || p[0] == 1.0 || p[1] == 0.0 || p[1] == 1.0 {
                    let copy = *moved.entry(v).or_insert_with(|| {
                        s.vertices.push([p[0], p[1], p[2] - 1e-7]);
                        s.vertices.len() as u32 - 1
                    });
                    s.triangles[t][k] = copy;
                }
            }
        }
        let (_, r) = s.into_closed("seam").unwrap();
        assert_eq!((r.open_edges, r.cracks, r.shells), (4 * 100 * 2, 1, 2), "{r:?}");
        assert!(r.widest_crack < 1e-3, "{r:?}");
        // A 4 x 4 block of squares missing: a hole 0.04 across, refused.
        let mut s = closed;
        let hole: Vec<usize> = (0..s.triangles.len())
            .filter(|&t| {
                s.triangles[t].iter().all(|&v| {
                    let p = s.vertices[v as usize];
                    p[0] == 0.0
                        && (0.5..=0.5 + 4.0 / 100.0 + 1e-9).contains(&p[1])
                        && (0.5..=0.5 + 4.0 / 100.0 + 1e-9).contains(&p[2])
                })
            })
            .collect();
        assert_eq!(hole.len(), 32);
        for &t in hole.iter().rev() {
            s.triangles.remove(t);
        }
        let e = s.into_closed("hole.stl").unwrap_err().to_string();
        assert!(e.contains("hole.stl") && e.contains("16 boundary (open) edges") && e.contains("a hole"), "{e}");
    }

    #[test]
    fn repeated_vertices_are_dropped_and_counted() {
        let mut s = TriSurface::cuboid([0.0; 3], [1.0; 3]);
        s.triangles.push([2, 2, 5]);
        let (_, r) = s.into_closed("box").unwrap();
        assert_eq!((r.dropped, r.triangles), (1, 12));
    }
}
