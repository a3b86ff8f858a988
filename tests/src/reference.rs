//! An exact reference for clipped Voronoi cells, written apart from the
//! kernels so that the two cannot share a bug: f64, face polygons clipped
//! one by one (Sutherland-Hodgman), each tet clipped by the bisectors of
//! ALL other sites (no k, no security radius), integrated by pyramids from
//! an interior point.

use cvd::TetMesh;

type P = [f64; 3];

fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn add(a: P, b: P) -> P {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: P, s: f64) -> P {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: P, b: P) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: P, b: P) -> P {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn norm(a: P) -> f64 {
    dot(a, a).sqrt()
}

/// A convex polyhedron as a list of face polygons.
#[derive(Clone, Debug)]
struct Poly {
    faces: Vec<Vec<P>>,
}

impl Poly {
    fn tet(v: [P; 4]) -> Self {
        let f = |a: usize, b: usize, c: usize| vec![v[a], v[b], v[c]];
        Self { faces: vec![f(1, 2, 3), f(0, 2, 3), f(0, 1, 3), f(0, 1, 2)] }
    }

    /// Keeps `n·x <= d`.
    fn clip(&mut self, n: P, d: f64) {
        // A plane that removes nothing is skipped, so a repeated plane does
        // not add a second copy of a face.
        // Points this close to the plane count as on it: features thinner
        // than f64 rounding would only make the cap's angular order
        // meaningless (and add volume through misordered faces). Relative
        // to the polyhedron, whose coordinates are relative to its site.
        let size = self.faces.iter().flatten().map(|&p| norm(p)).fold(0.0, f64::max);
        let tol = 1e-12 * norm(n) * size;
        let side = |p: P| {
            let s = dot(n, p) - d;
            if s.abs() <= tol {
                0.0
            } else {
                s
            }
        };
        if self.faces.iter().flatten().all(|&p| side(p) <= 0.0) {
            return;
        }
        let mut cap: Vec<P> = Vec::new();
        let mut faces = Vec::with_capacity(self.faces.len() + 1);
        for face in &self.faces {
            // A face lying in the plane is replaced by the cap.
            if face.iter().all(|&p| side(p) == 0.0) {
                cap.extend(face);
                continue;
            }
            let mut out = Vec::with_capacity(face.len() + 2);
            for i in 0..face.len() {
                let a = face[i];
                let b = face[(i + 1) % face.len()];
                let (sa, sb) = (side(a), side(b));
                if sa <= 0.0 {
                    out.push(a);
                }
                if (sa < 0.0 && sb > 0.0) || (sa > 0.0 && sb < 0.0) {
                    let p = add(a, scale(sub(b, a), sa / (sa - sb)));
                    out.push(p);
                    cap.push(p);
                } else if sa == 0.0 {
                    cap.push(a);
                }
            }
            if out.len() >= 3 {
                faces.push(out);
            }
        }
        if faces.len() >= 3 {
            // The cap: the points on the plane, ordered by angle.
            let c = scale(cap.iter().fold([0.0; 3], |s, &p| add(s, p)), 1.0 / cap.len().max(1) as f64);
            // A basis of the plane (from the unit normal: any axis not
            // nearly parallel to it).
            let unit = scale(n, 1.0 / norm(n));
            let u = if unit[0].abs() < 0.9 { cross(unit, [1.0, 0.0, 0.0]) } else { cross(unit, [0.0, 1.0, 0.0]) };
            let w = cross(unit, u);
            let mut pts: Vec<(f64, P)> = cap
                .iter()
                .map(|&p| {
                    let q = sub(p, c);
                    (dot(q, w).atan2(dot(q, u)), p)
                })
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut ring: Vec<P> = Vec::new();
            for (_, p) in pts {
                if ring.last().is_none_or(|&l| norm(sub(l, p)) > 1e-14) {
                    ring.push(p);
                }
            }
            if ring.len() >= 3 {
                faces.push(ring);
            }
        }
        self.faces = if faces.len() >= 4 { faces } else { Vec::new() };
    }

    /// Volume and centroid.
    fn integrate(&self) -> (f64, P) {
        let pts: Vec<P> = self.faces.iter().flatten().copied().collect();
        if pts.is_empty() {
            return (0.0, [0.0; 3]);
        }
        let c = scale(pts.iter().fold([0.0; 3], |s, &p| add(s, p)), 1.0 / pts.len() as f64);
        let (mut vol, mut moment) = (0.0, [0.0; 3]);
        for face in &self.faces {
            for i in 1..face.len() - 1 {
                let (a, b, d) = (face[0], face[i], face[i + 1]);
                let v = dot(sub(a, c), cross(sub(b, c), sub(d, c))).abs() / 6.0;
                vol += v;
                moment = add(moment, scale(add(add(a, b), add(d, c)), v / 4.0));
            }
        }
        let centroid = if vol > 0.0 { scale(moment, 1.0 / vol) } else { c };
        (vol, centroid)
    }
}

/// Volume and centroid of each site's cell clipped to the mesh; duplicate
/// sites: the lowest index owns the cell. Each cell is computed relative to
/// its site (so its precision is relative to the cell), its pieces clipped
/// by the other sites nearest first until the next is farther than twice
/// the piece's farthest point (then no bisector can reach it).
pub fn clipped_cells(mesh: &TetMesh, sites: &[[f64; 3]]) -> (Vec<f64>, Vec<[f64; 3]>) {
    clipped_power_cells(mesh, sites, &vec![0.0; sites.len()])
}

/// Volume and centroid of each site's power (Laguerre) cell clipped to the
/// mesh: the points `x` with `|x - x_i|² - w_i <= |x - x_j|² - w_j` for
/// every `j` (a cell may be empty, or miss its site; its centroid is then
/// the site). Equal sites: the larger weight owns the cell, the lowest
/// index among equal weights. The plane of `j`, relative to `x_i`, is `n·x
/// <= (|n|² + w_i - w_j) / 2` with `n = x_j - x_i`. A site `j` at distance
/// `d` cuts a point within `r` of `x_i` only if `|n|² - 2 r |n| < w_j -
/// w_i`, that is `d < r + sqrt(r² + w_j - w_i)`: the others are taken
/// nearest first until `d > r + sqrt(r² + Δ)`, `Δ = max w - w_i` (twice
/// the piece's reach for equal weights).
pub fn clipped_power_cells(mesh: &TetMesh, sites: &[[f64; 3]], weights: &[f64]) -> (Vec<f64>, Vec<[f64; 3]>) {
    assert_eq!(sites.len(), weights.len(), "one weight per site");
    let x: Vec<P> = sites.to_vec();
    let w = weights;
    let n = x.len();
    let w_max = w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut vol = vec![0.0; n];
    let mut moment = vec![[0.0; 3]; n];
    // Other sites nearest first.
    let order: Vec<Vec<(f64, usize)>> = (0..n)
        .map(|i| {
            let mut o: Vec<(f64, usize)> = (0..n).filter(|&j| j != i).map(|j| (norm(sub(x[j], x[i])), j)).collect();
            o.sort_by(|a, b| a.0.total_cmp(&b.0));
            o
        })
        .collect();
    let cell = |i: usize| {
        let (mut vol, mut moment) = (0.0, [0.0; 3]);
        if (0..n).any(|j| j != i && x[j] == x[i] && (w[j] > w[i] || (w[j] == w[i] && j < i))) {
            return (vol, moment);
        }
        let spread = w_max - w[i];
        for tet in &mesh.tets {
            let v = tet.map(|k| sub(mesh.vertices[k as usize], x[i]));
            let mut poly = Poly::tet(v);
            for &(dist, j) in &order[i] {
                if x[j] == x[i] {
                    continue;
                }
                let reach = poly.faces.iter().flatten().map(|&p| norm(p)).fold(0.0, f64::max);
                if dist > reach + (reach * reach + spread).sqrt() {
                    break;
                }
                let nrm = sub(x[j], x[i]);
                poly.clip(nrm, 0.5 * (dot(nrm, nrm) + w[i] - w[j]));
                if poly.faces.is_empty() {
                    break;
                }
            }
            let (pv, pc) = poly.integrate();
            vol += pv;
            moment = add(moment, scale(pc, pv));
        }
        (vol, moment)
    };
    // The cells on every core, each thread taking every `threads`-th site.
    let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
    let parts: Vec<Vec<(usize, (f64, P))>> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|t| {
                let cell = &cell;
                s.spawn(move || (t..n).step_by(threads).map(|i| (i, cell(i))).collect())
            })
            .collect();
        workers.into_iter().map(|w| w.join().expect("a reference thread panicked")).collect()
    });
    for (i, (v, m)) in parts.into_iter().flatten() {
        vol[i] = v;
        moment[i] = m;
    }
    let centroids =
        (0..n).map(|i| if vol[i] > 0.0 { add(x[i], scale(moment[i], 1.0 / vol[i])) } else { x[i] }).collect();
    (vol, centroids)
}
