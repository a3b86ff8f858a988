//! The faces of the clipped cells: which sites' cells touch, over what
//! area, and how much of each cell lies on the domain's boundary — the
//! clipped Voronoi adjacency (the restricted Delaunay graph), from the
//! kernels' face sums ([`cvd_kernels::clip::add_faces`]).
//!
//! The kernels add each piece's bisector faces to the slot of the
//! neighbour that made them in the site's own neighbour list, and its
//! faces on the mesh's boundary to one slot per site; a face whose maker
//! is not in the list (a grid walk found it) goes to one of a few spill
//! slots that maker claims, and when those run out it is summed apart and
//! the host gives such a site its faces from the same kernel bodies on the
//! CPU ([`FaceCollector`]). Each
//! shared face is then measured from both sides; the adjacency holds their
//! mean, so `area(i, j) == area(j, i)` exactly.

use crate::cpu::TaskSink;
use crate::mesh::TetMesh;
use cvd_kernels::clip::PieceSink;
use cvd_kernels::polyhedron::{made_by_site, Polyhedron, NO_ID, TET_FACE};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Mutex;

/// The clipped Voronoi adjacency, per input site (CSR): the sites whose
/// cells share a face with its cell, the face's area and unit normal
/// (from the site towards the neighbour), and the cell's area on the
/// domain's boundary. A duplicated site's row is empty (its cell is the
/// first copy's).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Adjacency {
    /// Row `i` is `offsets[i]..offsets[i + 1]` of the arrays below.
    pub offsets: Vec<usize>,
    /// Neighbour sites (input indices), increasing within a row.
    pub neighbors: Vec<u32>,
    /// Area of each shared face, the same from either side.
    pub areas: Vec<f64>,
    /// Unit normal of each shared face, from the site towards the
    /// neighbour (the bisector's).
    pub normals: Vec<[f64; 3]>,
    /// Each cell's area on the domain's boundary.
    pub boundary: Vec<f64>,
    /// Each cell's boundary area vector `∫ n dA` over its part of the
    /// domain's boundary (`n` the outward unit normal): its length is at
    /// most the boundary area, equal where that part is flat.
    pub boundary_vector: Vec<[f64; 3]>,
}

impl Adjacency {
    /// The faces site `i` shares: `(neighbour, area, normal)`.
    pub fn of(&self, i: usize) -> impl Iterator<Item = (u32, f64, [f64; 3])> + '_ {
        let r = self.offsets[i]..self.offsets[i + 1];
        r.map(move |e| (self.neighbors[e], self.areas[e], self.normals[e]))
    }

    /// The surface area of cell `i`: its shared faces and its boundary.
    pub fn surface_area(&self, i: usize) -> f64 {
        self.areas[self.offsets[i]..self.offsets[i + 1]].iter().sum::<f64>() + self.boundary[i]
    }

    /// Number of sites (rows).
    pub fn len(&self) -> usize {
        self.boundary.len()
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.boundary.is_empty()
    }
}

/// Which faces of each tet lie on the mesh's boundary: 4 bits per tet
/// (bit `f` for the face opposite vertex `f`), 8 tets per word, as the
/// kernels read them.
pub(crate) fn boundary_bits(mesh: &TetMesh) -> Vec<u32> {
    let mut seen: HashMap<[u32; 3], u32> = HashMap::with_capacity(2 * mesh.tets.len());
    for t in &mesh.tets {
        for f in 0..4 {
            let mut key = [t[(f + 1) % 4], t[(f + 2) % 4], t[(f + 3) % 4]];
            key.sort_unstable();
            *seen.entry(key).or_insert(0) += 1;
        }
    }
    let mut bits = vec![0u32; mesh.tets.len().div_ceil(8).max(1)];
    for (i, t) in mesh.tets.iter().enumerate() {
        for f in 0..4 {
            let mut key = [t[(f + 1) % 4], t[(f + 2) % 4], t[(f + 3) % 4]];
            key.sort_unstable();
            if seen[&key] == 1 {
                bits[i / 8] |= 1 << (4 * (i % 8) + f);
            }
        }
    }
    bits
}

/// One face of a piece: its site, its maker (a site, or [`TET_FACE`] +
/// f), its area, its tet and its outward unit normal, in the job's frame
/// and indices.
pub(crate) struct PieceFace {
    site: u32,
    maker: u32,
    area: f32,
    tet: u32,
    normal: [f32; 3],
}

/// Every face of every piece the kernels finish.
#[derive(Default)]
pub(crate) struct FaceCollector(pub(crate) Vec<PieceFace>);

impl PieceSink for FaceCollector {
    fn piece<const P: usize, const V: usize>(&mut self, tet: u32, site: u32, poly: &Polyhedron<P, V>) {
        let areas = poly.face_areas();
        for (q, &area) in areas.iter().enumerate().take(poly.n_planes as usize) {
            let maker = poly.ids[q];
            if area != 0.0 && maker != NO_ID {
                let n = poly.planes[q].truncate().normalize();
                self.0.push(PieceFace { site, maker, area, tet, normal: n.to_array() });
            }
        }
    }

    fn discard_tet(&mut self, tet: u32) {
        while self.0.last().is_some_and(|f| f.tet == tet) {
            self.0.pop();
        }
    }
}

impl TaskSink for FaceCollector {
    fn hand_over(self, all: &Mutex<Vec<Self>>) {
        if !self.0.is_empty() {
            all.lock().unwrap_or_else(|e| e.into_inner()).push(self);
        }
    }
}

/// One site's faces in the job's frame: `(neighbour, area)`, the boundary
/// area and the boundary's area vector.
pub(crate) type SiteFaces = (Vec<(u32, f64)>, f64, [f64; 3]);

/// Each unique site's faces from the kernels' sums (`sums`, `k + 2` per
/// site after `faces_base`, in units of `1 / area_scale`) and its list
/// `lists[u * k..]`; the sites with faces outside their list are returned
/// apart, to be completed.
pub(crate) fn from_sums(sums: &[i64], lists: &[u32], k: usize, area_scale: f64) -> (Vec<SiteFaces>, Vec<u32>) {
    let per = k + cvd_kernels::clip::FACE_SUMS_EXTRA;
    let n = sums.len() / per;
    let mut out = Vec::with_capacity(n);
    let mut incomplete = Vec::new();
    for u in 0..n {
        let s = &sums[u * per..(u + 1) * per];
        let mut faces: Vec<(u32, f64)> =
            (0..k).filter(|&q| s[q] != 0).map(|q| (lists[u * k + q], s[q] as f64 / area_scale)).collect();
        // Spilled: (maker + 1, area) pairs.
        for spill in 0..cvd_kernels::clip::FACE_SPILLS {
            let (key, area) = (s[k + 5 + 2 * spill], s[k + 6 + 2 * spill]);
            if key != 0 && area != 0 {
                faces.push(((key - 1) as u32, area as f64 / area_scale));
            }
        }
        out.push((faces, s[k] as f64 / area_scale, [2, 3, 4].map(|c| s[k + c] as f64 / area_scale)));
        if s[k + 1] != 0 {
            incomplete.push(u as u32);
        }
    }
    (out, incomplete)
}

/// The faces of the sites `which` from every piece's faces (`all`, from a
/// [`FaceCollector`]) and the tets' boundary bits, replacing theirs in
/// `faces`.
pub(crate) fn complete(faces: &mut [SiteFaces], which: &[u32], all: &[FaceCollector], bits: &[u32]) {
    let wanted: std::collections::HashSet<u32> = which.iter().copied().collect();
    type Redone = (HashMap<u32, f64>, f64, [f64; 3]);
    let mut redone: HashMap<u32, Redone> = which.iter().map(|&u| (u, Default::default())).collect();
    for f in all.iter().flat_map(|c| &c.0) {
        if !wanted.contains(&f.site) {
            continue;
        }
        let entry = redone.get_mut(&f.site).expect("a wanted site");
        if made_by_site(f.maker) {
            *entry.0.entry(f.maker).or_insert(0.0) += f.area as f64;
        } else if (TET_FACE..NO_ID).contains(&f.maker) {
            let t = f.tet as usize;
            if (bits[t / 8] >> (4 * (t % 8) + (f.maker - TET_FACE) as usize)) & 1 != 0 {
                entry.1 += f.area as f64;
                for (c, n) in entry.2.iter_mut().zip(f.normal) {
                    *c += (n * f.area) as f64;
                }
            }
        }
    }
    for (u, (nbrs, boundary, vector)) in redone {
        let mut list: Vec<(u32, f64)> = nbrs.into_iter().collect();
        list.sort_unstable_by_key(|e| e.0);
        faces[u as usize] = (list, boundary, vector);
    }
}

/// The adjacency per input site from each unique site's faces (job
/// indices, job frame): shared faces averaged over their two sides,
/// lengths scaled to the world (`scale`), normals along the sites'
/// difference in the world (`sites`, input order; `map`: input to unique).
pub(crate) fn assemble(mut faces: Vec<SiteFaces>, map: &[Option<usize>], sites: &[[f64; 3]], scale: f64) -> Adjacency {
    // The input index of each unique site (duplicates map to nothing).
    let mut owner = vec![u32::MAX; faces.len()];
    for (i, m) in map.iter().enumerate() {
        if let Some(u) = *m {
            owner[u] = i as u32;
        }
    }
    faces.par_iter_mut().for_each(|(row, _, _)| row.sort_unstable_by_key(|e| e.0));
    let faces = &faces;
    let side = |v: u32, u: u32| {
        let row = &faces[v as usize].0;
        row.binary_search_by_key(&u, |e| e.0).ok().map(|at| row[at].1)
    };
    // Faces seen from one side only (the other side's rounded to nothing):
    // half the area, on both rows.
    let mut one_sided: Vec<(u32, u32, f64)> = (0..faces.len())
        .into_par_iter()
        .flat_map_iter(|u| {
            faces[u].0.iter().filter(move |&&(v, _)| side(v, u as u32).is_none()).map(move |&(v, a)| (v, u as u32, a))
        })
        .collect();
    one_sided.sort_unstable_by_key(|e| (e.0, e.1));
    let l2 = scale * scale;
    // Each input site's row; duplicates map to nothing and keep an empty row.
    type Row = (Vec<(u32, f64, [f64; 3])>, f64, [f64; 3]);
    let per_site: Vec<Row> = map
        .par_iter()
        .enumerate()
        .map(|(i, m)| {
            let Some(u) = *m else { return (Vec::new(), 0.0, [0.0; 3]) };
            let p = sites[i];
            let normal = |v: u32, area: f64| {
                let j = owner[v as usize];
                let q = sites[j as usize];
                let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                (j, area * l2, d.map(|c| c / len))
            };
            let seen = faces[u].0.iter().map(|&(v, a)| normal(v, 0.5 * (a + side(v, u as u32).unwrap_or(0.0))));
            let lo = one_sided.partition_point(|e| e.0 < u as u32);
            let extra = one_sided[lo..].iter().take_while(|e| e.0 == u as u32).map(|&(_, v, a)| normal(v, 0.5 * a));
            let mut row: Vec<(u32, f64, [f64; 3])> = seen.chain(extra).collect();
            row.sort_unstable_by_key(|e| e.0);
            (row, faces[u].1 * l2, faces[u].2.map(|c| c * l2))
        })
        .collect();
    let total = per_site.iter().map(|r| r.0.len()).sum();
    let mut adj = Adjacency {
        offsets: Vec::with_capacity(map.len() + 1),
        neighbors: Vec::with_capacity(total),
        areas: Vec::with_capacity(total),
        normals: Vec::with_capacity(total),
        boundary: Vec::with_capacity(map.len()),
        boundary_vector: Vec::with_capacity(map.len()),
    };
    adj.offsets.push(0);
    for (row, boundary, vector) in per_site {
        for (j, a, n) in row {
            adj.neighbors.push(j);
            adj.areas.push(a);
            adj.normals.push(n);
        }
        adj.boundary.push(boundary);
        adj.boundary_vector.push(vector);
        adj.offsets.push(adj.neighbors.len());
    }
    adj
}
