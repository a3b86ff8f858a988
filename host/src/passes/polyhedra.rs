//! Each clipped cell as one polyhedron: its pieces (one per tet, see
//! [`Pieces`]) merged into the cell's own boundary.
//!
//! A cell's pieces meet on the faces between tets; those faces are inside
//! the cell and are dropped. What is left lies on bisectors (one face per
//! neighbouring site) and on the domain's boundary. The pieces' vertices
//! are welded (the same point computed in two tets differs by rounding),
//! the polygons of one face — one bisector, or one plane of the boundary —
//! are joined by cancelling the edges they share, and the points where a
//! cell's edge only crossed a tet's face (on exactly two faces, so on
//! their common line) are taken out. The result is closed and oriented
//! outwards (counter-clockwise loops seen from outside), with each point
//! once.
//!
//! A cell cut by a non-convex domain may be non-convex or in several
//! parts: each face may then have several loops, each given as a face of
//! its own with the same neighbour. A face whose outline would be a loop
//! with holes, or loops touching at a point, keeps its pieces' polygons
//! (each a face with the same neighbour), so that every face is a simple
//! polygon.

use crate::geom::vec3::{add, bounding_box, cross, dot, norm, sub};
use crate::passes::pieces::{Piece, Pieces, IN_MESH, ON_BOUNDARY};
use rayon::prelude::*;
use std::collections::HashMap;

/// Points of one cell closer than this, relative to the diagonal of the
/// cell's bounding box, are one point: the kernels compute a vertex in
/// f32 relative to the site, to about 1e-7 of the cell's size.
pub const WELD_TOLERANCE: f64 = 1e-6;

/// Points left apart by the weld but on one crack of the surface no wider
/// than this (relative to the diagonal of the cell's bounding box) are
/// made one.
const CRACK: f64 = 1e-5;

/// A point on two faces is taken out where it is this close to the line of
/// its neighbours, relative to the diagonal of the cell's bounding box.
const COLLINEAR: f64 = 1e-6;

/// Two boundary polygons of a cell are on one plane when their unit
/// normals differ by less than this (and their offsets by less than the
/// weld tolerance).
const COPLANAR: f64 = 1e-6;

/// One clipped cell as a closed polyhedron.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CellPolyhedron {
    /// The site (input index).
    pub site: u32,
    /// The points, each once.
    pub vertices: Vec<[f64; 3]>,
    /// The faces' loops, one after another, as indices into `vertices`;
    /// each runs counter-clockwise seen from outside the cell.
    pub face_vertices: Vec<u32>,
    /// Where each face's loop ends in `face_vertices`.
    pub face_ends: Vec<u32>,
    /// Across each face: the neighbouring site (input index),
    /// [`ON_BOUNDARY`] (-1) for the domain's boundary, or [`IN_MESH`] (-2)
    /// for a lid ([`Self::repaired_holes`]).
    pub face_neighbors: Vec<i64>,
    /// Lids: faces inside the domain closing a hole the pieces left, where
    /// a corner of the cell pokes through a tet's face into the next tet
    /// by a sliver the kernels' flood did not reach there (its volume is
    /// below the flood's check, 1e-4 of the tet's). The polyhedron is
    /// then the union of the pieces found, closed.
    pub repaired_holes: u32,
    /// Edges left without their reverse (0: the polyhedron is closed).
    pub open_edges: u32,
}

impl CellPolyhedron {
    /// The faces' vertex loops.
    pub fn faces(&self) -> impl Iterator<Item = &[u32]> + '_ {
        loops(&self.face_vertices, &self.face_ends)
    }

    /// The volume, by the divergence theorem over the faces.
    pub fn volume(&self) -> f64 {
        enclosed_volume(&self.vertices, self.faces())
    }

    /// The area of each face.
    pub fn face_areas(&self) -> Vec<f64> {
        self.faces().map(|f| norm(newell(&self.vertices, f)) / 2.0).collect()
    }
}

/// The loops of a face list: `face_vertices` cut at `face_ends`.
pub fn loops<'a>(face_vertices: &'a [u32], face_ends: &'a [u32]) -> impl Iterator<Item = &'a [u32]> + 'a {
    let starts = std::iter::once(0).chain(face_ends.iter().copied());
    starts.zip(face_ends).map(|(a, &b)| &face_vertices[a as usize..b as usize])
}

/// The volume enclosed by closed, outward-oriented `faces` over
/// `vertices` (divergence theorem, relative to the first vertex for
/// precision far from the origin).
pub fn enclosed_volume<'a>(vertices: &[[f64; 3]], faces: impl Iterator<Item = &'a [u32]>) -> f64 {
    let Some(&o) = vertices.first() else { return 0.0 };
    let rel = |i: u32| sub(vertices[i as usize], o);
    let mut six = 0.0;
    for face in faces {
        let a = rel(face[0]);
        for w in face[1..].windows(2) {
            six += dot(a, cross(rel(w[0]), rel(w[1])));
        }
    }
    six / 6.0
}

/// Every cell with pieces, merged (see the module's text), in site order.
pub fn merge_pieces(pieces: &Pieces) -> Vec<CellPolyhedron> {
    pieces.by_site().into_par_iter().map(|r| merge_cell(pieces, r)).collect()
}

/// What a face of a cell lies on: a neighbour's bisector, or one plane of
/// the boundary (numbered per cell).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Wall {
    Site(u32),
    Boundary(u32),
    /// A lid on a hole ([`CellPolyhedron::repaired_holes`]).
    Lid,
}

/// The pieces `range` (all of one site) merged into one polyhedron.
fn merge_cell(pieces: &Pieces, range: std::ops::Range<usize>) -> CellPolyhedron {
    let whole = range.len() == 1 && pieces.tet(range.start) == Piece::WHOLE;
    if whole {
        if let Some(cell) = whole_cell(pieces, range.start) {
            return cell;
        }
    }
    let site = pieces.site(range.start);
    let mut points: Vec<[f64; 3]> = Vec::new();
    // The faces not between two tets, with their makers.
    let mut kept: Vec<(i64, Vec<u32>)> = Vec::new();
    for k in range {
        pieces.unpack_into(k, &mut points, |ring, maker| {
            if maker != IN_MESH {
                kept.push((maker, ring.collect()));
            }
        });
    }
    let (weld, tolerance) = weld(&points);

    // Every polygon, welded, by the wall it is on.
    let mut polygons: Vec<(Wall, Vec<u32>)> = Vec::with_capacity(kept.len());
    let mut planes: Vec<([f64; 3], f64)> = Vec::new();
    for (maker, ring) in kept {
        // Welded, a polygon may pass a point twice (a sliver collapsed):
        // its simple loops.
        for ring in simple_loops(ring.iter().map(|&v| weld[v as usize]).collect()) {
            let wall = if maker == ON_BOUNDARY {
                Wall::Boundary(boundary_plane(&points, &ring, tolerance, &mut planes))
            } else {
                Wall::Site(maker as u32)
            };
            polygons.push((wall, ring));
        }
    }
    group_walls(&mut polygons);
    let mut faces = join_walls(&points, &polygons);
    if !open_edges(&faces).is_empty() {
        // Rare: copies of a point the weld left apart; made one, then the
        // walls joined again.
        close_cracks(&mut points, &mut polygons, tolerance * (CRACK / WELD_TOLERANCE));
        group_walls(&mut polygons);
        faces = join_walls(&points, &polygons);
    }
    let (repaired, open) = close_holes(&mut faces);
    // A whole cell is convex: a point on only two of its faces lies on
    // their line, however far rounding (or a sliver joined into a face)
    // left it from the line of its neighbours.
    let straight = if whole { f64::INFINITY } else { tolerance * (COLLINEAR / WELD_TOLERANCE) };
    drop_edge_points(&points, &mut faces, straight);

    // Only the points the faces use, numbered in order of first use.
    let mut number = vec![u32::MAX; points.len()];
    let mut cell = CellPolyhedron { site, repaired_holes: repaired, open_edges: open, ..CellPolyhedron::default() };
    for (wall, ring) in &faces {
        for &v in ring {
            let v = v as usize;
            if number[v] == u32::MAX {
                number[v] = cell.vertices.len() as u32;
                cell.vertices.push(points[v]);
            }
            cell.face_vertices.push(number[v]);
        }
        cell.face_ends.push(cell.face_vertices.len() as u32);
        cell.face_neighbors.push(match wall {
            Wall::Site(j) => *j as i64,
            Wall::Boundary(_) => ON_BOUNDARY,
            Wall::Lid => IN_MESH,
        });
    }
    cell
}

/// A whole cell (piece `k`, in no tet) as it is: nothing to merge, every
/// face on one neighbour's bisector, closed by construction. The points
/// numbered in order of first use, as merged cells' are. `None` where the
/// weld would make two of its points one, or a point lies on fewer than
/// three faces (a degenerate cell, as a lattice's, where more than three
/// bisectors meet at a point): that cell is merged as cut cells are.
fn whole_cell(pieces: &Pieces, k: usize) -> Option<CellPolyhedron> {
    let mut points = Vec::new();
    let mut cell = CellPolyhedron { site: pieces.site(k), ..CellPolyhedron::default() };
    pieces.unpack_into(k, &mut points, |ring, maker| {
        cell.face_vertices.extend(ring);
        cell.face_ends.push(cell.face_vertices.len() as u32);
        cell.face_neighbors.push(maker);
    });
    // Two faces with one maker are one face (a periodic box's wall, made
    // by several mirrors): joined as a cut cell's are.
    let mut makers = cell.face_neighbors.clone();
    makers.sort_unstable();
    if makers.windows(2).any(|w| w[0] == w[1]) {
        return None;
    }
    let (weld, _) = weld(&points);
    if weld.iter().enumerate().any(|(i, &w)| w as usize != i) {
        return None;
    }
    let mut number = vec![u32::MAX; points.len()];
    let mut uses = vec![0u8; points.len()];
    for v in &mut cell.face_vertices {
        let p = *v as usize;
        uses[p] = uses[p].saturating_add(1);
        if number[p] == u32::MAX {
            number[p] = cell.vertices.len() as u32;
            cell.vertices.push(points[p]);
        }
        *v = number[p];
    }
    if uses.iter().any(|&u| u != 0 && u < 3) {
        return None;
    }
    Some(cell)
}

/// The polygons grouped by wall, the walls in the order they first
/// appear (stable): the order of the pieces' faces, not of the numbers the
/// makers go by, so that a cell's faces come out in one order however its
/// job numbered the sites (one process, or a part of a box in parts).
fn group_walls(polygons: &mut [(Wall, Vec<u32>)]) {
    let mut seen: Vec<Wall> = Vec::new();
    let mut rank = |w: Wall| match seen.iter().position(|&s| s == w) {
        Some(k) => k,
        None => {
            seen.push(w);
            seen.len() - 1
        }
    };
    let ranks: Vec<usize> = polygons.iter().map(|(w, _)| rank(*w)).collect();
    let mut order: Vec<usize> = (0..polygons.len()).collect();
    order.sort_by_key(|&k| ranks[k]);
    let sorted: Vec<(Wall, Vec<u32>)> =
        order.iter().map(|&k| (polygons[k].0, std::mem::take(&mut polygons[k].1))).collect();
    for (p, s) in polygons.iter_mut().zip(sorted) {
        *p = s;
    }
}

/// Each wall's polygons (grouped by wall) joined into its faces (see
/// [`join`]; a wall that cannot be keeps its polygons).
fn join_walls(points: &[[f64; 3]], polygons: &[(Wall, Vec<u32>)]) -> Vec<(Wall, Vec<u32>)> {
    let mut faces = Vec::new();
    let mut at = 0;
    while at < polygons.len() {
        let wall = polygons[at].0;
        let end = at + polygons[at..].iter().take_while(|(w, _)| *w == wall).count();
        let group: Vec<&[u32]> = polygons[at..end].iter().map(|(_, r)| r.as_slice()).collect();
        match join(points, &group) {
            Some(joined) => faces.extend(joined.into_iter().map(|r| (wall, r))),
            None => faces.extend(group.iter().map(|r| (wall, r.to_vec()))),
        }
        at = end;
    }
    faces
}

/// Each point's representative and the tolerance: see [`weld_within`],
/// with [`WELD_TOLERANCE`] of the points' bounding box.
fn weld(points: &[[f64; 3]]) -> (Vec<u32>, f64) {
    let (lo, hi) = bounding_box(points);
    let tolerance = WELD_TOLERANCE * norm(sub(hi, lo));
    (weld_within(points, tolerance), tolerance)
}

/// Each point's representative: the lowest index among those within
/// `tolerance` of each other, transitively.
fn weld_within(points: &[[f64; 3]], tolerance: f64) -> Vec<u32> {
    let n = points.len();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by(|&a, &b| points[a as usize][0].total_cmp(&points[b as usize][0]));
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut a: u32) -> u32 {
        while parent[a as usize] != a {
            parent[a as usize] = parent[parent[a as usize] as usize];
            a = parent[a as usize];
        }
        a
    }
    for (k, &a) in order.iter().enumerate() {
        let pa = points[a as usize];
        for &b in &order[k + 1..] {
            let pb = points[b as usize];
            if pb[0] - pa[0] > tolerance {
                break;
            }
            if norm(sub(pa, pb)) <= tolerance {
                let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                // The lower index represents, so the result does not depend
                // on the sort's order of equal x.
                parent[ra.max(rb) as usize] = ra.min(rb);
            }
        }
    }
    (0..n as u32).map(|a| root(&mut parent, a)).collect()
}

/// The number of the boundary plane `ring` lies on, among `planes`
/// (unit normal, offset) found so far in this cell; a new one if none.
fn boundary_plane(points: &[[f64; 3]], ring: &[u32], tolerance: f64, planes: &mut Vec<([f64; 3], f64)>) -> u32 {
    let v = newell(points, ring);
    let len = norm(v);
    if len > 0.0 {
        let n = v.map(|c| c / len);
        let d = dot(n, points[ring[0] as usize]);
        if let Some(k) = planes.iter().position(|&(m, e)| norm(sub(m, n)) < COPLANAR && (e - d).abs() <= tolerance) {
            return k as u32;
        }
        planes.push((n, d));
    } else {
        // No normal to compare: a plane of its own.
        planes.push(([0.0; 3], f64::NAN));
    }
    (planes.len() - 1) as u32
}

/// The outline of polygons on one plane: their edges, less those two of
/// them share (once each way), chained into loops. `None` where that is
/// not a set of simple polygons side by side: a point where the outline
/// passes twice, or a loop turning the other way (a hole).
fn join(points: &[[f64; 3]], group: &[&[u32]]) -> Option<Vec<Vec<u32>>> {
    if group.len() == 1 {
        return Some(vec![group[0].to_vec()]);
    }
    // The outline's edges, sorted by their first point: one per point, or
    // the outline passes it twice.
    let mut outline = unmatched(group.iter().copied());
    outline.sort_unstable();
    if outline.windows(2).any(|w| w[0].0 == w[1].0) {
        return None;
    }
    let next = |v: u32| outline.binary_search_by_key(&v, |e| e.0).ok();
    let mut reference = [0.0; 3];
    for ring in group {
        reference = add(reference, newell(points, ring));
    }
    let mut used = vec![false; outline.len()];
    let mut out = Vec::new();
    for start in 0..outline.len() {
        if used[start] {
            continue;
        }
        let mut ring = Vec::new();
        let mut e = start;
        loop {
            used[e] = true;
            ring.push(outline[e].0);
            e = next(outline[e].1)?;
            if e == start {
                break;
            }
            if used[e] {
                return None;
            }
        }
        if ring.len() >= 3 {
            if dot(newell(points, &ring), reference) <= 0.0 {
                return None;
            }
            out.push(ring);
        }
    }
    Some(out)
}

/// The directed edges of `rings` less those met once each way, each as
/// many times as it outnumbers its reverse.
fn unmatched<'a>(rings: impl Iterator<Item = &'a [u32]>) -> Vec<(u32, u32)> {
    // Each edge under its lower point first, +1 along, -1 against.
    let mut edges: Vec<(u64, i32)> = Vec::new();
    for ring in rings {
        for k in 0..ring.len() {
            let (a, b) = (ring[k], ring[(k + 1) % ring.len()]);
            let key = ((a.min(b) as u64) << 32) | a.max(b) as u64;
            edges.push((key, if a < b { 1 } else { -1 }));
        }
    }
    edges.sort_unstable_by_key(|e| e.0);
    let mut out = Vec::new();
    let mut k = 0;
    while k < edges.len() {
        let key = edges[k].0;
        let mut net = 0;
        while k < edges.len() && edges[k].0 == key {
            net += edges[k].1;
            k += 1;
        }
        let (lo, hi) = ((key >> 32) as u32, key as u32);
        for _ in 0..net.abs() {
            out.push(if net > 0 { (lo, hi) } else { (hi, lo) });
        }
    }
    out
}

/// Closes the cracks: points on edges without their reverse (where the
/// weld left two copies of a point apart by a little more than its
/// tolerance) closer than `width` to each other are made one, at their
/// mean.
fn close_cracks(points: &mut [[f64; 3]], faces: &mut Vec<(Wall, Vec<u32>)>, width: f64) {
    let open = open_edges(faces);
    if open.is_empty() {
        return;
    }
    let mut ends: Vec<u32> = open.iter().flat_map(|&(a, b)| [a, b]).collect();
    ends.sort_unstable();
    ends.dedup();
    let at: Vec<[f64; 3]> = ends.iter().map(|&v| points[v as usize]).collect();
    let reps = weld_within(&at, width);
    let mut onto: HashMap<u32, u32> = HashMap::new();
    let mut groups: HashMap<u32, Vec<u32>> = HashMap::new();
    for (k, &r) in reps.iter().enumerate() {
        if r as usize != k {
            groups.entry(r).or_insert_with(|| vec![r]).push(k as u32);
        }
    }
    for (r, members) in groups {
        let mut mean = [0.0; 3];
        for &k in &members {
            mean = add(mean, at[k as usize]);
        }
        let target = ends[r as usize];
        points[target as usize] = mean.map(|c| c / members.len() as f64);
        for k in members {
            onto.insert(ends[k as usize], target);
        }
    }
    if onto.is_empty() {
        return;
    }
    let moved = std::mem::take(faces);
    for (wall, ring) in moved {
        let ring: Vec<u32> = ring.iter().map(|v| onto.get(v).copied().unwrap_or(*v)).collect();
        faces.extend(simple_loops(ring).into_iter().map(|r| (wall, r)));
    }
}

/// `ring` cut where it passes a point again into loops that do not, those
/// of fewer than 3 points dropped (spikes and points repeated in a row).
fn simple_loops(ring: Vec<u32>) -> Vec<Vec<u32>> {
    let mut out = Vec::new();
    let mut stack: Vec<u32> = Vec::with_capacity(ring.len());
    for v in ring {
        if let Some(k) = stack.iter().position(|&w| w == v) {
            let cut: Vec<u32> = stack.drain(k + 1..).collect();
            if cut.len() >= 2 {
                let mut l = vec![v];
                l.extend(cut);
                out.push(l);
            }
        } else {
            stack.push(v);
        }
    }
    if stack.len() >= 3 {
        out.push(stack);
    }
    out
}

/// Closes the holes in a cell's surface with lids: the edges without their
/// reverse, chained into loops, each loop reversed a face of its own, on
/// no wall ([`IN_MESH`]). Returns the lids and the edges left open.
fn close_holes(faces: &mut Vec<(Wall, Vec<u32>)>) -> (u32, u32) {
    let open = open_edges(faces);
    if open.is_empty() {
        return (0, 0);
    }
    // Reversed, each open edge b -> a; chained from the lowest point.
    let mut next: HashMap<u32, Vec<u32>> = HashMap::new();
    for &(a, b) in &open {
        next.entry(b).or_default().push(a);
    }
    let mut lids = 0;
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    for s in starts {
        while let Some(mut v) = next.get_mut(&s).and_then(|n| n.pop()) {
            let mut ring = vec![s];
            while v != s && ring.len() <= open.len() {
                ring.push(v);
                match next.get_mut(&v).and_then(|n| n.pop()) {
                    Some(w) => v = w,
                    None => break,
                }
            }
            if v == s && ring.len() >= 3 {
                faces.push((Wall::Lid, ring));
                lids += 1;
            }
        }
    }
    (lids, open_edges(faces).len() as u32)
}

/// The directed edges of `faces` without their reverse (as many times as
/// they outnumber it).
fn open_edges(faces: &[(Wall, Vec<u32>)]) -> Vec<(u32, u32)> {
    unmatched(faces.iter().map(|(_, ring)| ring.as_slice()))
}

/// Takes out the points on exactly two faces of different walls that lie
/// on the line of their neighbours in both (within `tolerance`; any, when
/// infinite): there they only split an edge, where it crossed a face
/// between tets.
fn drop_edge_points(points: &[[f64; 3]], faces: &mut [(Wall, Vec<u32>)], tolerance: f64) {
    // Per point: faces, first and last wall, and whether it ever is a
    // corner.
    let mut seen: Vec<(u32, Wall, Wall, bool)> = vec![(0, Wall::Lid, Wall::Lid, false); points.len()];
    for (wall, ring) in faces.iter() {
        for k in 0..ring.len() {
            let v = ring[k];
            let (before, after) = (ring[(k + ring.len() - 1) % ring.len()], ring[(k + 1) % ring.len()]);
            let (p, a, b) = (points[v as usize], points[before as usize], points[after as usize]);
            let ab = sub(b, a);
            let off_line = norm(cross(sub(p, a), ab)) > tolerance * norm(ab);
            let e = &mut seen[v as usize];
            if e.0 == 0 {
                e.1 = *wall;
            }
            e.0 += 1;
            e.2 = *wall;
            e.3 |= off_line;
        }
    }
    for (_, ring) in faces.iter_mut() {
        if ring.len() <= 3 {
            continue;
        }
        let keep: Vec<u32> = ring
            .iter()
            .copied()
            .filter(|v| {
                let (count, first, last, corner) = seen[*v as usize];
                corner || count != 2 || first == last
            })
            .collect();
        if keep.len() >= 3 {
            *ring = keep;
        }
    }
}

/// Twice the vector area of a loop (Newell's normal).
fn newell(points: &[[f64; 3]], ring: &[u32]) -> [f64; 3] {
    let o = points[ring[0] as usize];
    let mut v = [0.0; 3];
    for k in 1..ring.len().saturating_sub(1) {
        let (a, b) = (sub(points[ring[k] as usize], o), sub(points[ring[k + 1] as usize], o));
        v = add(v, cross(a, b));
    }
    v
}
