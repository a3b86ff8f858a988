//! Deterministic point sets: for default inputs, benchmarks and tests.

/// SplitMix64: a small, fast, well-mixed generator; the same seed gives the
/// same points on every machine.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `0..n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.unit() * n as f64) as usize % n
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u = self.unit().max(1e-300);
        let v = self.unit();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// The generator `n` draws on (SplitMix64 counts: a jump is one step).
    pub fn skipped(seed: u64, n: u64) -> Self {
        Self(seed.wrapping_add(n.wrapping_mul(0x9E37_79B9_7F4A_7C15)))
    }
}

/// `n` points uniform in the unit cube.
pub fn uniform(n: usize, seed: u64) -> Vec<[f64; 3]> {
    uniform_rows(0..n as u64, seed)
}

/// The points `rows` of [`uniform`]`(n, seed)` for any `n` past them,
/// without making the others (a part of a run in parts makes its own).
pub fn uniform_rows(rows: std::ops::Range<u64>, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng::skipped(seed, 3 * rows.start);
    rows.map(|_| [rng.unit(), rng.unit(), rng.unit()]).collect()
}

/// `n` points in `blobs` tight Gaussian blobs (standard deviation `sigma`)
/// centred uniformly in the unit cube.
pub fn clustered(n: usize, blobs: usize, sigma: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng::new(seed);
    let centres: Vec<[f64; 3]> = (0..blobs.max(1)).map(|_| [rng.unit(), rng.unit(), rng.unit()]).collect();
    (0..n)
        .map(|_| {
            let c = centres[rng.below(centres.len())];
            [0, 1, 2].map(|a| c[a] + sigma * rng.normal())
        })
        .collect()
}

/// `n` points on an integer lattice of side `side` (many equal distances),
/// in random order, with repeats when `n` exceeds the lattice.
pub fn lattice(n: usize, side: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng::new(seed);
    let side = side.max(1);
    (0..n).map(|_| [0; 3].map(|_| rng.below(side) as f64)).collect()
}

/// `n` points uniform inside a tet mesh: a tet drawn with probability
/// proportional to its volume, then a uniform point in it.
pub fn in_mesh(mesh: &crate::TetMesh, n: usize, seed: u64) -> Vec<[f64; 3]> {
    in_mesh_rows(mesh, 0..n as u64, seed)
}

/// Rows `rows` of [`in_mesh`]'s points (for any `n` beyond them): a part
/// makes its own rows alone.
pub fn in_mesh_rows(mesh: &crate::TetMesh, rows: std::ops::Range<u64>, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng::skipped(seed, 4 * rows.start);
    let mut cumulative = Vec::with_capacity(mesh.tets.len());
    let mut total = 0.0;
    for t in 0..mesh.tets.len() {
        total += mesh.tet_volume(t).abs();
        cumulative.push(total);
    }
    if mesh.tets.is_empty() || total <= 0.0 {
        return Vec::new();
    }
    rows.map(|_| {
        let r = rng.unit() * total;
        let t = cumulative.partition_point(|&c| c <= r).min(mesh.tets.len() - 1);
        // Uniform barycentric coordinates: sorted uniforms' gaps.
        let mut u = [rng.unit(), rng.unit(), rng.unit()];
        u.sort_by(f64::total_cmp);
        let w = [u[0], u[1] - u[0], u[2] - u[1], 1.0 - u[2]];
        let v = mesh.tets[t].map(|i| mesh.vertices[i as usize]);
        [0, 1, 2].map(|a| (0..4).map(|k| w[k] * v[k][a]).sum::<f64>())
    })
    .collect()
}

/// Points' places along a Morton (Z-order) curve over their bounding
/// cube: 10 bits per axis, x lowest. Points in parts key alike when every
/// part takes the same bounds (all the points' box).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MortonKeys {
    lo: [f64; 3],
    extent: f64,
}

impl MortonKeys {
    /// Keys over the bounding box `lo..hi`.
    pub fn new(lo: [f64; 3], hi: [f64; 3]) -> Self {
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0f64, f64::max).max(f64::MIN_POSITIVE);
        Self { lo, extent }
    }

    /// Keys over the bounding box of `points`.
    pub fn over(points: impl Iterator<Item = [f64; 3]>) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        // Not `vec3::bounding_box`: the points are made as needed, not held.
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        Self::new(lo, hi)
    }

    /// The key of `p` (30 bits).
    pub fn key(&self, p: [f64; 3]) -> u32 {
        // Spreads the low 10 bits of v to every third bit.
        let spread = |v: u32| {
            let mut x = v & 0x3ff;
            x = (x | (x << 16)) & 0x0300_00ff;
            x = (x | (x << 8)) & 0x0300_f00f;
            x = (x | (x << 4)) & 0x030c_30c3;
            (x | (x << 2)) & 0x0924_9249
        };
        let q = |a: usize| (((p[a] - self.lo[a]) / self.extent) * 1023.0) as u32;
        spread(q(0)) | (spread(q(1)) << 1) | (spread(q(2)) << 2)
    }
}

/// The order of `points` along a Morton (Z-order) curve: neighbours in
/// space become neighbours in memory, which keeps caches (and GPU
/// workgroups) on nearby data. Ties keep the input order.
pub fn morton_order(points: &[[f64; 3]]) -> Vec<u32> {
    morton_order_by(points.len(), |i| points[i])
}

/// [`morton_order`] of the `n` points `point(0..n)`, computed as needed
/// (twice each) rather than held.
pub fn morton_order_by(n: usize, point: impl Fn(usize) -> [f64; 3]) -> Vec<u32> {
    let keys = MortonKeys::over((0..n).map(&point));
    let mut keyed: Vec<(u32, u32)> = (0..n).map(|i| (keys.key(point(i)), i as u32)).collect();
    keyed.sort_unstable();
    // Not collected in place: that would keep the pairs' allocation.
    keyed.iter().map(|&(_, i)| i).collect()
}
