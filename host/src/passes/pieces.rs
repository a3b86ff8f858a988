//! The pieces of a clipped Voronoi diagram — each site's cell inside each
//! tet — as polyhedra with explicit faces, collected from the kernels'
//! bodies through their piece sink (see
//! `ClippedVoronoi::compute_with_pieces`).
//!
//! The kernels store a polyhedron as planes and, per vertex, the triple of
//! planes meeting there; a face's loop is found by chaining the vertices
//! on its plane through the edges they share (see
//! [`Polyhedron::vertex_planes`]).

use crate::exec::TaskSink;
use crate::job::clip::{ClipJob, Frame};
use cvd_kernels::abi::WHOLE_CELL;
use cvd_kernels::clip::PieceSink;
use cvd_kernels::polyhedron::{made_by_site, Polyhedron, NO_ID, TET_FACE};
use rayon::prelude::*;
use std::sync::Mutex;

/// Site `site`'s clipped cell inside tet `tet`: a convex polyhedron. Under
/// the whole-cell strategy, a cell inside the domain is one piece of no
/// tet ([`Piece::WHOLE`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Piece {
    /// The site's index in the input (the lowest one, for duplicated sites).
    pub site: u32,
    /// The tet's index in the mesh, or [`Piece::WHOLE`].
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
        crate::passes::polyhedra::loops(&self.face_vertices, &self.face_ends)
    }

    /// The volume, by the divergence theorem over the face loops.
    pub fn volume(&self) -> f64 {
        crate::passes::polyhedra::enclosed_volume(&self.vertices, self.faces())
    }
}

/// Every piece of a diagram, packed: the kernels' own f32 vertices
/// (relative to the site, in the job's frame) and one byte per corner of a
/// face, a few hundred bytes a piece, with no allocation of its own, kept
/// in the parts the CPU's tasks collected them in. A [`Piece`] in world
/// coordinates is made on request ([`Pieces::get`]). Pieces are numbered
/// by site, then tet.
#[derive(Clone, Debug, Default)]
pub struct Pieces {
    parts: Vec<Part>,
    /// Each site's position (input order) and the frame's scale: a vertex
    /// `v` of a piece of site `i` is at `origins[i] + scale * v`.
    origins: Vec<[f64; 3]>,
    scale: f64,
    /// The pieces in (site, tet) order, as (part, piece in the part).
    order: Vec<(u32, u32)>,
    /// The site each site index stands for, where [`Pieces::relabel`]
    /// gave them other names (empty: itself).
    labels: Vec<u32>,
}

/// One task's pieces, packed.
#[derive(Clone, Debug, Default)]
struct Part {
    /// Per piece: site and tet (input indices, once [`to_world`] ran).
    sites: Vec<u32>,
    tets: Vec<u32>,
    /// Per piece: where its vertices and its faces end.
    vertex_ends: Vec<u32>,
    face_ends: Vec<u32>,
    /// Per vertex: relative to the piece's site, in the job's frame.
    vertices: Vec<[f32; 3]>,
    /// Per face: where its loop ends in `corners`, and its maker.
    loop_ends: Vec<u32>,
    makers: Vec<i32>,
    /// Per corner: the vertex, within its piece.
    corners: Vec<u8>,
}

impl Pieces {
    /// Each face's maker `m` (an input site, or [`ON_BOUNDARY`], [`IN_MESH`])
    /// replaced by `f(m)`, which must fit an `i32`: makers that are one
    /// face, made one maker (a periodic box's mirrors in one wall).
    pub fn map_makers(&mut self, f: impl Fn(i64) -> i64 + Sync) {
        self.parts.par_iter_mut().for_each(|part| {
            for m in &mut part.makers {
                *m = f(*m as i64) as i32;
            }
        });
    }

    /// Each site `i` named `label(i)` from now on (`site`, `get`, and the
    /// makers of the faces that are sites'): the pieces of a job over some
    /// of the sites, numbered as the whole input numbers them. The names
    /// must keep the sites apart.
    pub fn relabel(&mut self, label: impl Fn(u32) -> u32 + Sync) {
        let labels: Vec<u32> = (0..self.origins.len() as u32).map(&label).collect();
        self.map_makers(|m| if m >= 0 { i64::from(label(m as u32)) } else { m });
        self.labels = labels;
    }

    /// Only the pieces of the sites `keep` says, by the names they have
    /// now (a part's cells finished in one round of several).
    pub(crate) fn retain_sites(&mut self, keep: impl Fn(u32) -> bool) {
        let order = std::mem::take(&mut self.order);
        let site = |&(part, p): &(u32, u32)| self.label(self.parts[part as usize].sites[p as usize]);
        self.order = order.into_iter().filter(|k| keep(site(k))).collect();
    }

    /// The name of site index `i` (see [`Pieces::relabel`]).
    fn label(&self, i: u32) -> u32 {
        self.labels.get(i as usize).copied().unwrap_or(i)
    }

    /// Where the site of piece `k` lies.
    pub fn origin(&self, k: usize) -> [f64; 3] {
        let (part, p) = self.order[k];
        self.origins[self.parts[part as usize].sites[p as usize] as usize]
    }

    /// Number of pieces.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// The site of piece `k`.
    pub fn site(&self, k: usize) -> u32 {
        let (part, p) = self.order[k];
        self.label(self.parts[part as usize].sites[p as usize])
    }

    /// The tet of piece `k` ([`Piece::WHOLE`] for a whole cell).
    pub(crate) fn tet(&self, k: usize) -> u32 {
        let (part, p) = self.order[k];
        self.parts[part as usize].tets[p as usize]
    }

    /// Piece `k`, in world coordinates.
    pub fn get(&self, k: usize) -> Piece {
        let (part, p) = self.order[k];
        let (part, p) = (&self.parts[part as usize], p as usize);
        let mut piece = Piece { site: self.label(part.sites[p]), tet: part.tets[p], ..Piece::default() };
        part.unpack(p, self.origins[part.sites[p] as usize], self.scale, &mut piece.vertices, |ring, maker| {
            piece.face_vertices.extend(ring);
            piece.face_ends.push(piece.face_vertices.len() as u32);
            piece.face_makers.push(maker);
        });
        piece
    }

    /// Every piece, in world coordinates, made one after another.
    pub fn iter(&self) -> impl Iterator<Item = Piece> + '_ {
        (0..self.len()).map(|k| self.get(k))
    }

    /// Every piece in world coordinates, all at once.
    pub fn to_vec(&self) -> Vec<Piece> {
        (0..self.len()).into_par_iter().map(|k| self.get(k)).collect()
    }

    /// The ranges of the numbering that hold one site's pieces each.
    pub(crate) fn by_site(&self) -> Vec<std::ops::Range<usize>> {
        let mut runs = Vec::new();
        let mut start = 0;
        for k in 1..=self.len() {
            if k == self.len() || self.site(k) != self.site(start) {
                runs.push(start..k);
                start = k;
            }
        }
        runs
    }

    /// Piece `k`'s vertices in world coordinates, appended to `out`, and
    /// its faces given to `face` as (loop, maker), the loop numbering
    /// `out`.
    pub(crate) fn unpack_into(
        &self,
        k: usize,
        out: &mut Vec<[f64; 3]>,
        face: impl FnMut(&mut dyn Iterator<Item = u32>, i64),
    ) {
        let (part, p) = self.order[k];
        let (part, p) = (&self.parts[part as usize], p as usize);
        part.unpack(p, self.origins[part.sites[p] as usize], self.scale, out, face);
    }
}

impl Part {
    /// Where piece `p`'s vertices and faces start.
    fn starts(&self, p: usize) -> (usize, usize) {
        if p == 0 {
            (0, 0)
        } else {
            (self.vertex_ends[p - 1] as usize, self.face_ends[p - 1] as usize)
        }
    }

    /// Piece `p`'s vertices at `x + scale * v`, appended to `out`, and its
    /// faces given to `face` as (loop, maker), the loop numbering `out`.
    fn unpack(
        &self,
        p: usize,
        x: [f64; 3],
        scale: f64,
        out: &mut Vec<[f64; 3]>,
        mut face: impl FnMut(&mut dyn Iterator<Item = u32>, i64),
    ) {
        let (v0, f0) = self.starts(p);
        let base = out.len() as u32;
        out.extend(
            self.vertices[v0..self.vertex_ends[p] as usize]
                .iter()
                .map(|v| [0, 1, 2].map(|a| x[a] + scale * v[a] as f64)),
        );
        for f in f0..self.face_ends[p] as usize {
            let c0 = if f == 0 { 0 } else { self.loop_ends[f - 1] as usize };
            let mut ring = self.corners[c0..self.loop_ends[f] as usize].iter().map(|&c| base + c as u32);
            face(&mut ring, self.makers[f] as i64);
        }
    }

    /// Forgets the last piece.
    fn pop(&mut self) {
        self.sites.pop();
        self.tets.pop();
        self.vertex_ends.pop();
        self.face_ends.pop();
        let (v, f) =
            (self.vertex_ends.last().map_or(0, |&e| e as usize), self.face_ends.last().map_or(0, |&e| e as usize));
        self.vertices.truncate(v);
        self.loop_ends.truncate(f);
        self.makers.truncate(f);
        self.corners.truncate(self.loop_ends.last().map_or(0, |&e| e as usize));
    }
}

/// A task's pieces as the kernels give them: job indices, vertices
/// relative to the site in the job's normalised frame.
#[derive(Default)]
pub(crate) struct PieceCollector(Part);

impl Piece {
    /// The `tet` of a whole cell: the site's cell lies inside the domain
    /// and was integrated whole, in no tet.
    pub const WHOLE: u32 = WHOLE_CELL;
}

impl PieceSink for PieceCollector {
    fn piece<const P: usize, const V: usize>(&mut self, tet: u32, site: u32, poly: &Polyhedron<P, V>, volume: f32) {
        // As in the sums: a piece of no volume is no piece.
        if volume == 0.0 {
            return;
        }
        face_loops(poly, &mut self.0);
        let all = &mut self.0;
        if all.loop_ends.len() as u32 == all.face_ends.last().copied().unwrap_or(0) {
            // No face closed: no piece.
            all.vertices.truncate(all.vertex_ends.last().map_or(0, |&e| e as usize));
            return;
        }
        all.sites.push(site);
        all.tets.push(tet);
        all.vertex_ends.push(all.vertices.len() as u32);
        all.face_ends.push(all.loop_ends.len() as u32);
    }

    fn discard_tet(&mut self, tet: u32) {
        // A tet's pieces are given one after another by one task.
        while self.0.tets.last() == Some(&tet) {
            self.0.pop();
        }
    }

    fn discard_site(&mut self, site: u32) {
        // A whole cell's pieces too.
        while self.0.sites.last() == Some(&site) {
            self.0.pop();
        }
    }
}

impl TaskSink for PieceCollector {
    fn hand_over(self, all: &Mutex<Vec<Self>>) {
        if !self.0.sites.is_empty() {
            all.lock().unwrap_or_else(|e| e.into_inner()).push(self);
        }
    }
}

/// Appends `poly`'s vertices (in the polyhedron's own coordinates) and face
/// loops to `out` (the piece's entry is the caller's). Vertices at exactly
/// the same position (a plane through a vertex leaves two there, joined by
/// an edge of length zero) become one, and a face left with fewer than 3
/// corners is dropped.
fn face_loops<const P: usize, const V: usize>(poly: &Polyhedron<P, V>, out: &mut Part) {
    // A vertex's number within its piece is a byte.
    const { assert!(V < 255) };
    let n = (poly.n_verts as usize).min(V);
    let mut place = [[0.0f32; 3]; V];
    for (i, p) in place.iter_mut().enumerate().take(n) {
        *p = vertex_on_its_planes(poly, i);
    }
    // The first vertex at each position.
    let mut same = [0usize; V];
    for (i, s) in same.iter_mut().enumerate().take(n) {
        *s = (0..i).find(|&k| place[k] == place[i]).unwrap_or(i);
    }
    // Output index of each kept vertex, given on first use.
    let mut number = [u8::MAX; V];
    let mut kept = 0u8;
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
            if number[v] == u8::MAX {
                number[v] = kept;
                kept += 1;
                out.vertices.push(place[v]);
            }
            out.corners.push(number[v]);
        }
        out.loop_ends.push(out.corners.len() as u32);
        // The job's id for now; `to_world` makes it the input's.
        out.makers.push(poly.ids[plane as usize] as i32);
    }
}

/// Vertex `i` of `poly` where its three planes meet, solved in f64 and
/// rounded once, if they are three sites' bisectors: a clip leaves a
/// vertex where it cut an edge, after the roundings of every clip before
/// (the kernels' integrals move each vertex onto its planes too). A vertex
/// on a plane of a tet or of the starting box stays as given (a tet's
/// planes are rounded from its corners, and the clips place a vertex on a
/// tet's edge between its corners), and so does one whose planes are
/// nearly dependent (where the solve would be worse) or whose solve lands
/// away from it.
fn vertex_on_its_planes<const P: usize, const V: usize>(poly: &Polyhedron<P, V>, i: usize) -> [f32; 3] {
    use crate::geom::vec3::{cross, dot, norm};
    let v = poly.verts[i];
    let given = [v.x, v.y, v.z];
    let on = poly.vertex_planes(i);
    if !on.iter().all(|&q| made_by_site(poly.ids[q as usize])) {
        return given;
    }
    let planes = on.map(|q| poly.planes[q as usize]);
    let n = planes.map(|p| [p.x as f64, p.y as f64, p.z as f64]);
    let w = planes.map(|p| p.w as f64);
    let (bc, ca, ab) = (cross(n[1], n[2]), cross(n[2], n[0]), cross(n[0], n[1]));
    let det = dot(n[0], bc);
    let norms: f64 = n.iter().map(|&m| norm(m)).product();
    if !det.is_finite() || det.abs() <= 1e-3 * norms {
        return given;
    }
    let x = [0, 1, 2].map(|a| (w[0] * bc[a] + w[1] * ca[a] + w[2] * ab[a]) / det);
    let size = given.iter().map(|c| c.abs() as f64).fold(0.0, f64::max);
    let moved = (0..3).map(|a| (x[a] - given[a] as f64).abs()).fold(0.0, f64::max);
    if moved <= 1e-5 * size.max(1e-30) {
        x.map(|c| c as f32)
    } else {
        given
    }
}

/// The collected pieces with input site and tet indices and the sites'
/// positions, numbered by site and tet. `map` sends each input site to its
/// job site (`None` for a duplicate), as `ClippedVoronoi::job` gives it.
pub(crate) fn to_world(
    collected: Vec<PieceCollector>,
    job: &ClipJob,
    map: &crate::job::sites::SiteMap,
    frame: &Frame,
    input: &[[f64; 3]],
    only: Option<std::ops::Range<usize>>,
) -> Pieces {
    // The input index that owns each job site: the lowest.
    let mut owner = vec![u32::MAX; job.sites.len()];
    for (i, m) in map.iter().enumerate().rev() {
        if let Some(u) = m {
            owner[u] = i as u32;
        }
    }
    // The job's boundary bits where it holds them (with faces, or whole
    // cells: a part's tets are not its mesh, nor their boundary its
    // boundary), else found here.
    let whole = job.strategy == crate::job::clip::Strategy::Whole;
    let held_bits = job.tet_faces.len() == job.tets.len().div_ceil(8).max(1);
    let found;
    let bits = if held_bits && (whole || job.params.faces_base != 0) {
        &job.tet_faces
    } else {
        let local = crate::geom::mesh::TetMesh { vertices: Vec::new(), tets: job.tets.clone() };
        found = crate::passes::faces::boundary_bits(&local);
        &found
    };
    let mut parts: Vec<Part> = collected.into_iter().map(|c| c.0).collect();
    parts.par_iter_mut().for_each(|part| {
        // Each face's maker: the input site, or where the face lies.
        for p in 0..part.sites.len() {
            let (_, f0) = part.starts(p);
            let t = part.tets[p] as usize;
            for m in &mut part.makers[f0..part.face_ends[p] as usize] {
                let id = *m as u32;
                *m = if made_by_site(id) {
                    owner[id as usize] as i32
                } else if (TET_FACE..NO_ID).contains(&id)
                    && (bits[t / 8] >> (4 * (t % 8) + (id - TET_FACE) as usize)) & 1 != 0
                {
                    ON_BOUNDARY as i32
                } else {
                    IN_MESH as i32
                };
            }
        }
        for s in &mut part.sites {
            *s = owner[*s as usize];
        }
        for t in &mut part.tets {
            if *t != WHOLE_CELL {
                *t = job.tet_order[*t as usize];
            }
        }
    });
    // The pieces of the sites at places `only` of the job (a share of its
    // cells: `backends::distributed`), or all.
    let place: Vec<u32> = map.iter().map(|m| m.map_or(u32::MAX, |u| u as u32)).collect();
    let kept = |site: u32| only.as_ref().is_none_or(|r| r.contains(&(place[site as usize] as usize)));
    let mut order: Vec<(u32, u32)> = parts
        .iter()
        .enumerate()
        .flat_map(|(k, part)| (0..part.sites.len() as u32).map(move |p| (k as u32, p)))
        .filter(|&(k, p)| kept(parts[k as usize].sites[p as usize]))
        .collect();
    order.par_sort_unstable_by_key(|&(k, p)| (parts[k as usize].sites[p as usize], parts[k as usize].tets[p as usize]));
    Pieces { parts, origins: input.to_vec(), scale: frame.scale, order, labels: Vec::new() }
}
