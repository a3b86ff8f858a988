//! The pieces of a clipped Voronoi diagram — each site's cell inside each
//! tet — as polyhedra with explicit faces, collected from the kernels'
//! bodies through their piece sink (see
//! [`ClippedVoronoi::compute_with_pieces`](crate::ClippedVoronoi::compute_with_pieces)).
//!
//! The kernels store a polyhedron as planes and, per vertex, the triple of
//! planes meeting there; a face's loop is found by chaining the vertices
//! on its plane through the edges they share (see
//! [`Polyhedron::vertex_planes`]).

use crate::cpu::TaskSink;
use crate::diagram::voronoi::{ClipJob, Frame};
use cvd_kernels::clip::PieceSink;
use cvd_kernels::polyhedron::{made_by_site, Polyhedron, NO_ID, TET_FACE};
use rayon::prelude::*;
use std::sync::Mutex;

/// Site `site`'s clipped cell inside tet `tet`: a convex polyhedron.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Piece {
    /// The site's index in the input (the lowest one, for duplicated sites).
    pub site: u32,
    /// The tet's index in the mesh.
    pub tet: u32,
    /// Vertex positions, every one on a face.
    pub vertices: Vec<[f64; 3]>,
    /// The faces' vertex loops, one after another, as indices into
    /// `vertices`; each loop runs counter-clockwise seen from outside.
    pub face_vertices: Vec<u32>,
    /// Where each face's loop ends in `face_vertices`.
    pub face_ends: Vec<u32>,
    /// What made each face: the neighbouring site (input index) whose
    /// bisector it lies on, [`ON_BOUNDARY`] for the domain's boundary, or
    /// [`IN_MESH`] for a face between two tets (the cell goes on there).
    pub face_makers: Vec<i64>,
}

/// A face of a piece on the domain's boundary (see [`Piece::face_makers`]).
pub const ON_BOUNDARY: i64 = -1;
/// A face of a piece on a face between two tets, inside the mesh.
pub const IN_MESH: i64 = -2;

impl Piece {
    /// The faces' vertex loops.
    pub fn faces(&self) -> impl Iterator<Item = &[u32]> + '_ {
        crate::diagram::polyhedra::loops(&self.face_vertices, &self.face_ends)
    }

    /// The volume, by the divergence theorem over the face loops.
    pub fn volume(&self) -> f64 {
        crate::diagram::polyhedra::enclosed_volume(&self.vertices, self.faces())
    }
}

/// A task's pieces as the kernels give them: job indices, vertices
/// relative to the site in the job's normalised frame.
#[derive(Default)]
pub(crate) struct PieceCollector(Vec<Piece>);

impl PieceSink for PieceCollector {
    fn piece<const P: usize, const V: usize>(&mut self, tet: u32, site: u32, poly: &Polyhedron<P, V>) {
        // As in the sums: a piece of no volume is no piece.
        if poly.moments().volume == 0.0 {
            return;
        }
        let mut piece = Piece { site, tet, ..Piece::default() };
        face_loops(poly, &mut piece);
        self.0.push(piece);
    }

    fn discard_tet(&mut self, tet: u32) {
        // A tet's pieces are given one after another by one task.
        while self.0.last().is_some_and(|p| p.tet == tet) {
            self.0.pop();
        }
    }
}

impl TaskSink for PieceCollector {
    fn hand_over(self, all: &Mutex<Vec<Self>>) {
        if !self.0.is_empty() {
            all.lock().unwrap_or_else(|e| e.into_inner()).push(self);
        }
    }
}

/// Fills `piece`'s vertices (in the polyhedron's own coordinates) and face
/// loops. Vertices at exactly the same position (a plane through a vertex
/// leaves two there, joined by an edge of length zero) become one, and a
/// face left with fewer than 3 corners is dropped.
fn face_loops<const P: usize, const V: usize>(poly: &Polyhedron<P, V>, piece: &mut Piece) {
    let n = (poly.n_verts as usize).min(V);
    // The first vertex at each position.
    let mut same = [0usize; V];
    for (i, s) in same.iter_mut().enumerate().take(n) {
        *s = (0..i).find(|&k| poly.verts[k] == poly.verts[i]).unwrap_or(i);
    }
    // Output index of each kept vertex, given on first use.
    let mut out = [u32::MAX; V];
    let mut on_face: Vec<(usize, u32, u32)> = Vec::with_capacity(16);
    let mut ring: Vec<u32> = Vec::with_capacity(16);
    for plane in 0..poly.n_planes.min(P as u32) {
        // The vertices on this plane, as (vertex, b, c) with (plane, b, c)
        // their triple rotated to start with the plane.
        on_face.clear();
        for i in 0..n {
            let [a, b, c] = poly.vertex_planes(i);
            let rotated = if a == plane {
                (b, c)
            } else if b == plane {
                (c, a)
            } else if c == plane {
                (a, b)
            } else {
                continue;
            };
            on_face.push((i, rotated.0, rotated.1));
        }
        if on_face.len() < 3 {
            continue;
        }
        // Counter-clockwise from outside: from (plane, b, c) to (plane, c, _).
        ring.clear();
        let mut at = 0;
        let closed = loop {
            let (i, _, c) = on_face[at];
            ring.push(same[i] as u32);
            match on_face.iter().position(|&(_, b, _)| b == c) {
                Some(0) => break true,
                Some(next) if ring.len() < on_face.len() => at = next,
                _ => break false,
            }
        };
        if !closed || ring.len() != on_face.len() {
            continue;
        }
        ring.dedup();
        while ring.len() > 1 && ring.first() == ring.last() {
            ring.pop();
        }
        if ring.len() < 3 {
            continue;
        }
        for &v in ring.iter() {
            let v = v as usize;
            if out[v] == u32::MAX {
                out[v] = piece.vertices.len() as u32;
                let p = poly.verts[v];
                piece.vertices.push([p.x as f64, p.y as f64, p.z as f64]);
            }
            piece.face_vertices.push(out[v]);
        }
        piece.face_ends.push(piece.face_vertices.len() as u32);
        // The job's id for now; `to_world` makes it the input's.
        piece.face_makers.push(poly.ids[plane as usize] as i64);
    }
}

/// The collected pieces in world coordinates, with input site and tet
/// indices, sorted by site and tet. `map` sends each input site to its
/// job site (`None` for a duplicate), as [`ClippedVoronoi::job`](crate::ClippedVoronoi::job) gives it.
pub(crate) fn to_world(
    collected: Vec<PieceCollector>,
    job: &ClipJob,
    map: &[Option<usize>],
    frame: &Frame,
    input: &[[f64; 3]],
) -> Vec<Piece> {
    // The input index that owns each job site: the lowest.
    let mut owner = vec![u32::MAX; job.sites.len()];
    for (i, m) in map.iter().enumerate().rev() {
        if let Some(u) = *m {
            owner[u] = i as u32;
        }
    }
    let mut pieces: Vec<Piece> = collected.into_iter().flat_map(|c| c.0).collect();
    let local = crate::TetMesh { vertices: Vec::new(), tets: job.tets.clone() };
    let bits = crate::diagram::faces::boundary_bits(&local);
    pieces.par_iter_mut().for_each(|p| {
        let t = p.tet as usize;
        for m in &mut p.face_makers {
            let id = *m as u32;
            *m = if made_by_site(id) {
                owner[id as usize] as i64
            } else if (TET_FACE..NO_ID).contains(&id)
                && (bits[t / 8] >> (4 * (t % 8) + (id - TET_FACE) as usize)) & 1 != 0
            {
                ON_BOUNDARY
            } else {
                IN_MESH
            };
        }
        let site = owner[p.site as usize];
        // Relative to the input site itself, whose position is exact.
        let x = input[site as usize];
        for v in &mut p.vertices {
            *v = [0, 1, 2].map(|a| x[a] + frame.scale * v[a]);
        }
        p.site = site;
        p.tet = job.tet_order[p.tet as usize];
    });
    pieces.par_sort_unstable_by_key(|p| (p.site, p.tet));
    pieces
}
