//! Isosurface stuffing: F. Labelle and J. R. Shewchuk, *Isosurface
//! Stuffing: Fast Tetrahedral Meshes with Good Dihedral Angles*, SIGGRAPH
//! 2007, on a uniform body-centred cubic (BCC) lattice.
//!
//! 1. **Lattice.** Cube corners and cube centres cover the shape's bounding
//!    box with a margin. Its tets: for each face shared by two cubes, the
//!    two centres and each edge of the face (4 tets per face). *Black*
//!    edges join two corners or two centres (length `h`); *red* edges join
//!    a centre to a corner of its cube (length `h √3 / 2`). Each tet has
//!    two opposite black edges and four red ones.
//! 2. **Cut points.** The signed distance is evaluated at every lattice
//!    vertex; every edge whose ends have opposite strict signs gets a cut
//!    point, the zero of the distance along the edge (found in f64 by
//!    regula falsi, the bracket kept).
//! 3. **Warping.** A vertex closer to a cut point on one of its edges than
//!    `alpha` times that edge's length (`alpha_long` for black edges,
//!    `alpha_short` for red ones) moves onto its nearest such cut point and
//!    becomes a surface vertex (value 0); the cut points on its other edges
//!    go, since those edges no longer change sign. Vertices are warped in
//!    lattice order; a cut point already dropped warps nothing.
//! 4. **Stencils.** Each lattice tet is replaced by the part of it inside the
//!    surface, by the signs of its vertices (inside `-`, on `0`, outside
//!    `+`): no inside vertex, nothing (four surface vertices included: such
//!    a tet lies along the surface, nearly flat); no outside vertex, the
//!    tet; one inside vertex, one tet; two inside, one on the surface, one
//!    outside, a pyramid (2 tets); two inside and two outside, a prism (3
//!    tets); three inside and one outside, a prism (3 tets).
//!
//! **Quadrilaterals.** A tet face with two inside vertices and one outside
//! vertex leaves a quadrilateral, which the tets on both sides of the face
//! must split along the same diagonal; every rule below depends on the
//! face alone, so they do. If the two inside vertices share a red edge, the
//! diagonal joins the one whose edge to the outside vertex is red to the
//! cut point on the other (black) edge. If they share a black edge, the
//! paper's *parity rule* picks the endpoint: it alternates like a
//! checkerboard around the black edge, so that the two such faces of one
//! lattice tet pick opposite endpoints. With these rules the three
//! quadrilaterals of a prism never form a cycle, so a prism splits into
//! three tets without a new vertex. These are the paper's stencils; for
//! them and the default `alpha`s its computer-assisted proof bounds every
//! dihedral angle between 10.7 and 164.8 degrees, whatever the shape (the
//! tests check these bounds on random shapes, sharp creases included).
//!
//! Shared vertices and cut points are created once (cut points keyed by
//! their lattice edge), so the mesh is conforming. Output tets are
//! positively oriented: each takes the orientation it has with its cut
//! points at their edges' midpoints and its vertices unwarped, where every
//! stencil is a valid tetrahedralization; a tet the warp turned over would
//! show as inverted in [`Quality`](super::quality::Quality).

use super::sdf::Shape;
use crate::error::{Error, Result};
use crate::TetMesh;
use rayon::prelude::*;
use std::collections::HashMap;

/// Warping threshold on black edges, as a fraction of their length: the
/// paper's value for its 10.7..164.8 degree bounds.
pub const ALPHA_LONG: f64 = 0.24999;
/// Warping threshold on red edges, as a fraction of their length: the
/// paper's value for its 10.7..164.8 degree bounds.
pub const ALPHA_SHORT: f64 = 0.41189;

/// Empty lattice cells around the shape's bounding box on each side.
const MARGIN: usize = 2;
/// The largest lattice stuffed, in lattice vertices: it bounds the run's
/// memory (8 bytes per lattice vertex, besides the mesh).
pub const MAX_LATTICE_VERTICES: usize = 1 << 24;

/// How to stuff a shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// Lattice spacing `h`: the side of the lattice cubes.
    pub spacing: f64,
    /// Warping threshold on black edges (fraction of the edge length).
    pub alpha_long: f64,
    /// Warping threshold on red edges (fraction of the edge length).
    pub alpha_short: f64,
    /// Shift of the lattice from centred on the shape's box, in lattice
    /// spacings per axis (each in `[0, 1)`).
    pub shift: [f64; 3],
}

impl Params {
    /// Lattice spacing `spacing` and the paper's warping thresholds.
    pub fn new(spacing: f64) -> Self {
        Self { spacing, alpha_long: ALPHA_LONG, alpha_short: ALPHA_SHORT, shift: [0.0; 3] }
    }
}

/// Fills the shape `shape` (negative inside) with tets on a BCC lattice of
/// spacing `params.spacing` covering `shape.bounds()`.
///
/// Errors: a spacing that is not positive and finite, thresholds outside
/// `[0, 0.5)`, an empty or unbounded shape box, a lattice above
/// [`MAX_LATTICE_VERTICES`], a non-finite distance, or no tet at all (the
/// spacing is too coarse for the shape).
pub fn stuff<S: Shape + ?Sized>(shape: &S, params: &Params) -> Result<TetMesh> {
    let h = params.spacing;
    if !(h.is_finite() && h > 0.0) {
        return Err(Error::InvalidInput(format!("lattice spacing must be positive and finite, got {h}")));
    }
    for (name, alpha) in [("alpha_long", params.alpha_long), ("alpha_short", params.alpha_short)] {
        if !(0.0..0.5).contains(&alpha) {
            return Err(Error::InvalidInput(format!("{name} must be in [0, 0.5), got {alpha}")));
        }
    }
    let lattice = Lattice::around(shape.bounds(), h, params.shift)?;
    let mut value: Vec<f64> =
        (0..lattice.len() as u32).into_par_iter().map(|v| shape.eval(lattice.position(v))).collect();
    if let Some(v) = value.iter().position(|f| !f.is_finite()) {
        let p = lattice.position(v as u32);
        return Err(Error::InvalidInput(format!("the signed distance is not finite at {p:?}")));
    }
    let (cuts, candidates) = cut_points(shape, &lattice, &value, params);
    let warped = warp(candidates, &mut value);
    let mut out = Output::new(&lattice, &cuts, &warped);
    lattice.for_each_tet(|tet| {
        if tet.iter().any(|&v| value[v as usize] < 0.0) {
            fill(&lattice, tet, &value, &mut |t| out.push(t));
        }
    });
    if out.tets.is_empty() {
        return Err(Error::InvalidInput(format!(
            "stuffing produced no tets: lattice spacing {h} is too coarse for the shape"
        )));
    }
    let vertices = out.positions.clone();
    TetMesh::new(vertices, out.tets)
}

/// The BCC lattice: `n` cubes of side `h` per axis from `origin`. Vertex
/// ids: the corners `(n + 1)³` first, then the centres `n³`, each x-fastest.
struct Lattice {
    origin: [f64; 3],
    h: f64,
    n: [usize; 3],
}

impl Lattice {
    /// The lattice covering `bounds` with `MARGIN` cells to spare on each
    /// side, centred on the box.
    fn around((lo, hi): ([f64; 3], [f64; 3]), h: f64, shift: [f64; 3]) -> Result<Self> {
        if !(0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && lo[a] <= hi[a]) {
            return Err(Error::InvalidInput(format!("the shape's bounding box {lo:?}..{hi:?} is empty or unbounded")));
        }
        let cells = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / h).ceil() + 2.0 * MARGIN as f64);
        let vertices = cells.iter().map(|c| c + 1.0).product::<f64>() + cells.iter().product::<f64>();
        if vertices > MAX_LATTICE_VERTICES as f64 {
            return Err(Error::InvalidInput(format!(
                "lattice spacing {h} needs {vertices:.0} lattice vertices for the shape's box \
                 {lo:?}..{hi:?}, more than {MAX_LATTICE_VERTICES}"
            )));
        }
        let n = cells.map(|c| c as usize);
        let origin = [0, 1, 2].map(|a| (lo[a] + hi[a]) / 2.0 - n[a] as f64 * h / 2.0 + shift[a] * h);
        Ok(Self { origin, h, n })
    }

    fn corners(&self) -> usize {
        (self.n[0] + 1) * (self.n[1] + 1) * (self.n[2] + 1)
    }

    fn len(&self) -> usize {
        self.corners() + self.n[0] * self.n[1] * self.n[2]
    }

    fn corner(&self, [i, j, k]: [usize; 3]) -> u32 {
        (i + (self.n[0] + 1) * (j + (self.n[1] + 1) * k)) as u32
    }

    fn centre(&self, [i, j, k]: [usize; 3]) -> u32 {
        (self.corners() + i + self.n[0] * (j + self.n[1] * k)) as u32
    }

    fn is_centre(&self, v: u32) -> bool {
        v as usize >= self.corners()
    }

    /// Twice the vertex's coordinates in cube units: all even for a
    /// corner, all odd for a centre.
    fn doubled(&self, v: u32) -> [i64; 3] {
        let v = v as usize;
        if v < self.corners() {
            let (sx, sy) = (self.n[0] + 1, self.n[1] + 1);
            [v % sx, (v / sx) % sy, v / (sx * sy)].map(|c| 2 * c as i64)
        } else {
            let v = v - self.corners();
            let (sx, sy) = (self.n[0], self.n[1]);
            [v % sx, (v / sx) % sy, v / (sx * sy)].map(|c| 2 * c as i64 + 1)
        }
    }

    fn position(&self, v: u32) -> [f64; 3] {
        let d = self.doubled(v);
        [0, 1, 2].map(|a| self.origin[a] + d[a] as f64 * self.h / 2.0)
    }

    /// Calls `f(u, v, black)` for every lattice edge.
    fn for_each_edge(&self, mut f: impl FnMut(u32, u32, bool)) {
        let n = self.n;
        for k in 0..=n[2] {
            for j in 0..=n[1] {
                for i in 0..=n[0] {
                    let c = [i, j, k];
                    for a in 0..3 {
                        if c[a] < n[a] {
                            let mut d = c;
                            d[a] += 1;
                            f(self.corner(c), self.corner(d), true);
                        }
                    }
                }
            }
        }
        for k in 0..n[2] {
            for j in 0..n[1] {
                for i in 0..n[0] {
                    let c = [i, j, k];
                    let centre = self.centre(c);
                    for a in 0..3 {
                        if c[a] + 1 < n[a] {
                            let mut d = c;
                            d[a] += 1;
                            f(centre, self.centre(d), true);
                        }
                    }
                    for corner in 0..8 {
                        let d = [0, 1, 2].map(|a| c[a] + (corner >> a & 1));
                        f(centre, self.corner(d), false);
                    }
                }
            }
        }
    }

    /// Calls `f` for every lattice tet: for each face shared by two cubes,
    /// the two centres and each edge of the face.
    fn for_each_tet(&self, mut f: impl FnMut([u32; 4])) {
        let n = self.n;
        for a in 0..3 {
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            for k in 0..n[2] {
                for j in 0..n[1] {
                    for i in 0..n[0] {
                        let cube = [i, j, k];
                        if cube[a] + 1 >= n[a] {
                            continue;
                        }
                        let mut next = cube;
                        next[a] += 1;
                        let (c1, c2) = (self.centre(cube), self.centre(next));
                        // The shared face's corners, in order around it.
                        let at = |db: usize, dc: usize| {
                            let mut p = next;
                            p[b] += db;
                            p[c] += dc;
                            self.corner(p)
                        };
                        let ring = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)];
                        for m in 0..4 {
                            f([c1, c2, ring[m], ring[(m + 1) % 4]]);
                        }
                    }
                }
            }
        }
    }
}

/// Cut points by lattice edge (smaller id first), and the warping
/// candidates: `(vertex, distance, other end, cut point)` for each cut
/// point closer to a vertex than its threshold.
type Cuts = HashMap<(u32, u32), [f64; 3]>;
type Candidate = (u32, f64, u32, [f64; 3]);

fn cut_points<S: Shape + ?Sized>(
    shape: &S,
    lattice: &Lattice,
    value: &[f64],
    params: &Params,
) -> (Cuts, Vec<Candidate>) {
    let mut crossing = Vec::new();
    lattice.for_each_edge(|u, v, black| {
        let (fu, fv) = (value[u as usize], value[v as usize]);
        if (fu < 0.0 && fv > 0.0) || (fu > 0.0 && fv < 0.0) {
            crossing.push((u, v, black));
        }
    });
    let found: Vec<(u32, u32, bool, f64, [f64; 3])> = crossing
        .into_par_iter()
        .map(|(u, v, black)| {
            let (pu, pv) = (lattice.position(u), lattice.position(v));
            let at = |t: f64| [0, 1, 2].map(|a| pu[a] + t * (pv[a] - pu[a]));
            let t = root(|t| shape.eval(at(t)), value[u as usize], value[v as usize]);
            (u, v, black, t, at(t))
        })
        .collect();
    let mut cuts = HashMap::with_capacity(found.len());
    let mut candidates = Vec::new();
    for (u, v, black, t, p) in found {
        let (length, alpha) =
            if black { (lattice.h, params.alpha_long) } else { (lattice.h * 3f64.sqrt() / 2.0, params.alpha_short) };
        if t < alpha {
            candidates.push((u, t * length, v, p));
        }
        if 1.0 - t < alpha {
            candidates.push((v, (1.0 - t) * length, u, p));
        }
        cuts.insert((u.min(v), u.max(v)), p);
    }
    (cuts, candidates)
}

/// The zero of `f` on `[0, 1]`, given `f(0) = f0` and `f(1) = f1` of
/// opposite signs: regula falsi with the Illinois correction, which keeps
/// the zero bracketed and converges superlinearly.
fn root(f: impl Fn(f64) -> f64, f0: f64, f1: f64) -> f64 {
    // A distance this small is a zero to f64 precision at the edge's scale.
    let tolerance = 1e-14 * (f0.abs() + f1.abs());
    let (mut a, mut fa, mut b, mut fb) = (0.0, f0, 1.0, f1);
    let mut last_side = 0;
    for _ in 0..100 {
        let secant = (a * fb - b * fa) / (fb - fa);
        let t = if secant > a && secant < b { secant } else { 0.5 * (a + b) };
        let ft = f(t);
        if ft.abs() <= tolerance {
            return t;
        }
        if (ft < 0.0) == (fa < 0.0) {
            (a, fa) = (t, ft);
            if last_side == -1 {
                fb *= 0.5;
            }
            last_side = -1;
        } else {
            (b, fb) = (t, ft);
            if last_side == 1 {
                fa *= 0.5;
            }
            last_side = 1;
        }
        if b - a < 1e-14 {
            break;
        }
    }
    0.5 * (a + b)
}

/// Warps the violated vertices in lattice order onto their nearest live
/// violating cut point; returns the warped vertices' new positions.
fn warp(mut candidates: Vec<Candidate>, value: &mut [f64]) -> HashMap<u32, [f64; 3]> {
    candidates.sort_by(|x, y| x.0.cmp(&y.0).then(x.1.total_cmp(&y.1)));
    let mut warped = HashMap::new();
    for &(v, _, other, p) in &candidates {
        // A cut point lives while neither end has been warped; candidates of
        // a vertex come nearest first, so the first live one wins.
        if warped.contains_key(&v) || warped.contains_key(&other) {
            continue;
        }
        warped.insert(v, p);
        value[v as usize] = 0.0;
    }
    warped
}

/// A vertex of the output: a lattice vertex (maybe warped) or the cut
/// point on the edge from an inside to an outside lattice vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Node {
    Lattice(u32),
    Cut(u32, u32),
}

/// Which diagonal splits a prism's side quadrilateral `(p_i, p_{i+1},
/// q_{i+1}, q_i)`: `P` joins `p_i` to `q_{i+1}`, `Q` joins `q_i` to `p_{i+1}`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Diagonal {
    P,
    Q,
}

impl Diagonal {
    fn other(self) -> Self {
        match self {
            Self::P => Self::Q,
            Self::Q => Self::P,
        }
    }
}

/// In the face `(a, b, o)`, `a` and `b` inside and `o` outside, whether
/// the quadrilateral `a, b, cut(b, o), cut(a, o)` is split by the diagonal
/// from `a` (to `cut(b, o)`) rather than from `b` (to `cut(a, o)`).
fn diagonal_from_first(lattice: &Lattice, a: u32, b: u32, o: u32) -> bool {
    if lattice.is_centre(a) != lattice.is_centre(b) {
        // Red edge ab: the face's black edge is ao or bo; the diagonal joins
        // the other inside vertex to the cut point on the black edge.
        return lattice.is_centre(a) != lattice.is_centre(o);
    }
    // Black edge ab along axis k: the parity rule. Count the axes on which
    // `a` lies above the cut point on bo: along k, when b is below a; across
    // k, when o is below a. The counts from a and from b differ by one plus
    // an even number, so exactly one endpoint has the wanted parity (odd for
    // corners, even for centres), and moving o across a neighbouring face
    // flips the choice.
    let (xa, xb, xo) = (lattice.doubled(a), lattice.doubled(b), lattice.doubled(o));
    let mut count = 0;
    for axis in 0..3 {
        let below = if xa[axis] != xb[axis] { xb[axis] < xa[axis] } else { xo[axis] < xa[axis] };
        count += below as u32;
    }
    (count % 2 == 1) != lattice.is_centre(a)
}

/// Emits the stencil tets of the lattice tet `tet` with vertex values
/// `value`: nothing without an inside vertex.
fn fill(lattice: &Lattice, tet: [u32; 4], value: &[f64], emit: &mut impl FnMut([Node; 4])) {
    // The vertices inside, on the surface and outside, in tet order.
    let mut groups = [([0u32; 4], 0usize); 3];
    for v in tet {
        let f = value[v as usize];
        let g = if f < 0.0 {
            0
        } else if f > 0.0 {
            2
        } else {
            1
        };
        groups[g].0[groups[g].1] = v;
        groups[g].1 += 1;
    }
    let [inside, zero, outside] = groups.each_ref().map(|(v, n)| &v[..*n]);
    let cut = |a: u32, o: u32| Node::Cut(a, o);
    use Node::Lattice as L;
    match (inside, zero, outside) {
        ([], _, _) => {}
        (_, _, []) => emit(tet.map(L)),
        (&[a], _, _) => emit(tet.map(|v| if v == a || value[v as usize] == 0.0 { L(v) } else { cut(a, v) })),
        (&[a, b], &[z], &[o]) => {
            // A pyramid from z over the quadrilateral a, b, cut(b, o), cut(a, o).
            if diagonal_from_first(lattice, a, b, o) {
                emit([L(z), L(a), L(b), cut(b, o)]);
                emit([L(z), L(a), cut(b, o), cut(a, o)]);
            } else {
                emit([L(z), L(a), L(b), cut(a, o)]);
                emit([L(z), L(b), cut(b, o), cut(a, o)]);
            }
        }
        (&[a, b], [], &[o1, o2]) => {
            // A prism between the triangles at a and at b. Its quadrilaterals
            // in the faces abo1 (0) and abo2 (2) always get the same kind of
            // diagonal (the face rules pick opposite endpoints of ab), so the
            // cut surface (1) takes the other kind, the only one without a cycle.
            let p = [L(a), cut(a, o1), cut(a, o2)];
            let q = [L(b), cut(b, o1), cut(b, o2)];
            let d0 = if diagonal_from_first(lattice, a, b, o1) { Diagonal::P } else { Diagonal::Q };
            let d2 = if diagonal_from_first(lattice, a, b, o2) { Diagonal::Q } else { Diagonal::P };
            prism(p, q, [d0, d0.other(), d2], emit);
        }
        (&[a, b, c], [], &[o]) => {
            // A prism between the inside face abc and the cut triangle.
            let p = [a, b, c];
            let q = p.map(|v| cut(v, o));
            let d = [0, 1, 2].map(|i| {
                if diagonal_from_first(lattice, p[i], p[(i + 1) % 3], o) {
                    Diagonal::P
                } else {
                    Diagonal::Q
                }
            });
            prism(p.map(L), q, d, emit);
        }
        _ => unreachable!("four vertices split into inside, surface and outside: every case is above"),
    }
}

/// Splits the prism with triangles `p` and `q` (`p_i q_i` its side edges)
/// into three tets, given the diagonals of its side quadrilaterals, which
/// must not all be of one kind (a cycle). A vertex on two diagonals (the
/// hub) makes a tet with the opposite triangle and two with the opposite
/// quadrilateral.
fn prism(p: [Node; 3], q: [Node; 3], d: [Diagonal; 3], emit: &mut impl FnMut([Node; 4])) {
    let i =
        (0..3).find(|&i| d[i] != d[(i + 2) % 3]).expect("the stencils never give a prism three diagonals of one kind");
    let (j, k) = ((i + 1) % 3, (i + 2) % 3);
    let hub = match d[i] {
        Diagonal::P => {
            emit([p[i], q[0], q[1], q[2]]);
            p[i]
        }
        Diagonal::Q => {
            emit([q[i], p[0], p[1], p[2]]);
            q[i]
        }
    };
    match d[j] {
        Diagonal::P => {
            emit([hub, p[j], p[k], q[k]]);
            emit([hub, p[j], q[k], q[j]]);
        }
        Diagonal::Q => {
            emit([hub, p[j], p[k], q[j]]);
            emit([hub, p[k], q[k], q[j]]);
        }
    }
}

/// The output mesh being built: one vertex per lattice vertex or cut
/// point used, tets oriented positively.
struct Output<'a> {
    lattice: &'a Lattice,
    cuts: &'a Cuts,
    warped: &'a HashMap<u32, [f64; 3]>,
    index: HashMap<Node, u32>,
    positions: Vec<[f64; 3]>,
    tets: Vec<[u32; 4]>,
}

impl<'a> Output<'a> {
    fn new(lattice: &'a Lattice, cuts: &'a Cuts, warped: &'a HashMap<u32, [f64; 3]>) -> Self {
        Self { lattice, cuts, warped, index: HashMap::new(), positions: Vec::new(), tets: Vec::new() }
    }

    /// Cut nodes keyed by their edge, whichever end was named first.
    fn key(node: Node) -> Node {
        match node {
            Node::Cut(u, v) => Node::Cut(u.min(v), u.max(v)),
            n => n,
        }
    }

    fn position(&self, node: Node) -> [f64; 3] {
        match Self::key(node) {
            Node::Lattice(v) => self.warped.get(&v).copied().unwrap_or_else(|| self.lattice.position(v)),
            // Every edge from an inside to an outside vertex changed sign
            // before warping (warping only zeroes values), so it has a cut point.
            key @ Node::Cut(u, v) => {
                *self.cuts.get(&(u, v)).unwrap_or_else(|| unreachable!("no cut point for {key:?}"))
            }
        }
    }

    fn vertex(&mut self, node: Node) -> u32 {
        let key = Self::key(node);
        if let Some(&i) = self.index.get(&key) {
            return i;
        }
        let i = self.positions.len() as u32;
        let p = self.position(key);
        self.positions.push(p);
        self.index.insert(key, i);
        i
    }

    fn push(&mut self, tet: [Node; 4]) {
        let volume = reference_volume(self.lattice, tet);
        debug_assert!(volume != 0.0, "stencil tet {tet:?} is flat in the reference lattice");
        let mut ids = tet.map(|n| self.vertex(n));
        if volume < 0.0 {
            ids.swap(2, 3);
        }
        self.tets.push(ids);
    }
}

/// Where the node sits with every cut point at its edge's midpoint and no
/// vertex warped, in half-cube units (exact in f64).
fn reference(lattice: &Lattice, node: Node) -> [f64; 3] {
    match node {
        Node::Lattice(v) => lattice.doubled(v).map(|c| c as f64),
        Node::Cut(u, v) => {
            let (a, b) = (lattice.doubled(u), lattice.doubled(v));
            [0, 1, 2].map(|i| (a[i] + b[i]) as f64 / 2.0)
        }
    }
}

/// Six times the signed volume of the tet at the nodes' reference
/// positions: exact, since the coordinates are small multiples of 1/2.
fn reference_volume(lattice: &Lattice, tet: [Node; 4]) -> f64 {
    let [a, b, c, d] = tet.map(|n| reference(lattice, n));
    let s = |p: [f64; 3], q: [f64; 3]| [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    let (u, v, w) = (s(b, a), s(c, a), s(d, a));
    u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points::Rng;
    use crate::mesher::quality::{Conformity, Quality};
    use crate::mesher::sdf::Sdf;

    /// The paper's bounds on the dihedral angles for the default `alpha`s.
    const PAPER_MIN: f64 = 10.7;
    const PAPER_MAX: f64 = 164.8;

    fn small_lattice() -> Lattice {
        Lattice { origin: [0.0; 3], h: 1.0, n: [3, 3, 3] }
    }

    fn lattice_tets(lattice: &Lattice) -> Vec<[u32; 4]> {
        let mut tets = Vec::new();
        lattice.for_each_tet(|t| tets.push(t));
        tets
    }

    #[test]
    fn lattice_tets_tile_the_inner_cubes() {
        let lattice = small_lattice();
        let tets = lattice_tets(&lattice);
        // 3 axes x 2 x 3 x 3 shared faces, 4 tets each.
        assert_eq!(tets.len(), 3 * 18 * 4);
        for tet in &tets {
            let black = |a: u32, b: u32| lattice.is_centre(a) == lattice.is_centre(b);
            let blacks = (0..4).flat_map(|i| (i + 1..4).map(move |j| (i, j))).filter(|&(i, j)| black(tet[i], tet[j]));
            // Two opposite black edges.
            let blacks: Vec<_> = blacks.collect();
            assert_eq!(blacks.len(), 2);
            let (e, f) = (blacks[0], blacks[1]);
            assert!(e.0 != f.0 && e.0 != f.1 && e.1 != f.0 && e.1 != f.1);
            // Volume h³/12: 6 x volume = 1/2 in cube units, 4 in half-cube units.
            assert_eq!(reference_volume(&lattice, tet.map(Node::Lattice)).abs(), 4.0);
        }
    }

    #[test]
    fn quadrilateral_diagonals_agree_and_alternate() {
        let lattice = small_lattice();
        for tet in lattice_tets(&lattice) {
            for i in 0..4 {
                for j in 0..4 {
                    let others: Vec<u32> = (0..4).filter(|&k| k != i && k != j).map(|k| tet[k]).collect();
                    if i == j {
                        continue;
                    }
                    let (a, b) = (tet[i], tet[j]);
                    for &o in &others {
                        // The same face seen with a and b swapped picks the same diagonal.
                        assert_ne!(diagonal_from_first(&lattice, a, b, o), diagonal_from_first(&lattice, b, a, o));
                    }
                    // The two faces through ab pick opposite endpoints of ab, so a
                    // prism's two lattice-face quadrilaterals never share a vertex.
                    assert_ne!(
                        diagonal_from_first(&lattice, a, b, others[0]),
                        diagonal_from_first(&lattice, a, b, others[1])
                    );
                }
            }
        }
    }

    /// Every sign pattern of every lattice tet: the stencil tets are not
    /// flat, and the parts inside and outside (the stencil of the opposite
    /// signs) add up to the lattice tet.
    #[test]
    fn stencils_split_every_sign_pattern() {
        let lattice = small_lattice();
        let mut value = vec![1.0; lattice.len()];
        let mut patterns = 0;
        for tet in lattice_tets(&lattice) {
            let whole = reference_volume(&lattice, tet.map(Node::Lattice)).abs();
            for code in 0..81 {
                let sign = [0, 1, 2, 3].map(|i| (code / 3usize.pow(i)) % 3);
                let part = |value: &[f64]| {
                    let mut total = 0.0;
                    if tet.iter().any(|&v| value[v as usize] < 0.0) {
                        fill(&lattice, tet, value, &mut |t| {
                            let v = reference_volume(&lattice, t);
                            assert!(v != 0.0, "flat stencil tet {t:?}");
                            total += v.abs();
                        });
                    }
                    total
                };
                for (v, s) in tet.iter().zip(sign) {
                    value[*v as usize] = s as f64 - 1.0;
                }
                let inside = part(&value);
                for v in tet {
                    value[v as usize] = -value[v as usize];
                }
                let outside = part(&value);
                if sign.iter().all(|&s| s == 1) {
                    assert_eq!(inside + outside, 0.0);
                } else {
                    assert_eq!(inside + outside, whole, "signs {sign:?} of {tet:?}");
                }
                patterns += 1;
            }
        }
        assert_eq!(patterns, 216 * 81);
    }

    #[test]
    fn root_is_bracketed_and_accurate() {
        let t = root(|t| t * t - 0.3, -0.3, 0.7);
        assert!((t - 0.3f64.sqrt()).abs() < 1e-12);
        let t = root(|t| (t - 0.999).signum() * (t - 0.999).abs().sqrt(), -(0.999f64.sqrt()), 0.001f64.sqrt());
        assert!((t - 0.999).abs() < 1e-9);
    }

    fn random_shape(rng: &mut Rng) -> Sdf {
        let mut p = || [rng.unit(), rng.unit(), rng.unit()];
        let (c, r) = (p(), p());
        let axis = p().map(|x| x - 0.5);
        match (r[0] * 5.0) as usize {
            0 => Sdf::sphere(c, 0.2 + 0.3 * r[1]),
            1 => Sdf::torus(c, axis, 0.3 + 0.1 * r[1], 0.1 + 0.1 * r[2]),
            2 => Sdf::cylinder(c, axis, 0.1 + 0.2 * r[1], 0.2 + 0.6 * r[2]),
            3 => Sdf::rounded_cuboid(c, [0.2 + 0.2 * r[1], 0.1 + 0.3 * r[2], 0.3], 0.05 * r[1]),
            _ => Sdf::cuboid(c, [0.3, 0.2 + 0.2 * r[1], 0.1 + 0.3 * r[2]])
                .difference(Sdf::cylinder(c, axis, 0.05 + 0.1 * r[2], 2.0))
                .union(Sdf::sphere([c[0] + 0.3, c[1], c[2]], 0.15)),
        }
    }

    /// The paper's angle bounds hold whatever the shape, sharp creases
    /// included; the tets fit (pieces may touch along an edge where a
    /// feature is thinner than the lattice, so manifoldness is not checked).
    #[test]
    fn random_shapes_keep_the_angle_bounds() {
        let mut rng = Rng::new(7);
        for _ in 0..40 {
            let shape = random_shape(&mut rng);
            let h = 0.04 + 0.06 * rng.unit();
            let mesh = stuff(&shape, &Params::new(h)).unwrap();
            let q = Quality::of(&mesh);
            assert!(q.inverted == 0 && q.min_dihedral >= PAPER_MIN && q.max_dihedral <= PAPER_MAX, "{q} for {shape:?}");
            let c = Conformity::of(&mesh);
            assert!(c.is_conforming(), "{c:?} for {shape:?}");
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let ball = Sdf::sphere([0.0; 3], 1.0);
        for h in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(stuff(&ball, &Params::new(h)).is_err());
        }
        assert!(stuff(&ball, &Params { alpha_long: 0.5, ..Params::new(0.1) }).is_err());
        assert!(stuff(&ball, &Params { alpha_short: -0.1, ..Params::new(0.1) }).is_err());
        assert!(stuff(&ball, &Params::new(1e-4)).is_err(), "lattice too large");
        let apart = ball.clone().intersection(Sdf::sphere([5.0, 0.0, 0.0], 1.0));
        assert!(stuff(&apart, &Params::new(0.1)).is_err(), "empty box");
        let infinite = Sdf::sphere([0.0; 3], f64::INFINITY);
        assert!(stuff(&infinite, &Params::new(0.1)).is_err());
        // A thin ring between the lattice vertices: no tet.
        assert!(stuff(&Sdf::torus([0.0; 3], [0.0, 0.0, 1.0], 0.3, 0.01), &Params::new(1.0)).is_err());
    }
}
