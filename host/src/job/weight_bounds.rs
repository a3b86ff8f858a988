//! Local bounds of the power weights, which keep the power cells' security
//! radius near the Voronoi cells' where the weights drift across the
//! domain (see [`cvd_kernels::clip::Slack`]).
//!
//! A site `j` cuts a polyhedron within `r` of site `i` only if `|x_j -
//! x_i| < reach(r, w_j - w_i)`, `reach(r, s) = r + sqrt(r² + s)`. With
//! `W_0` the largest weight of all, such a `j` lies within `ρ_0 = reach(r,
//! W_0 - w_i)`; so its weight is at most `W_1`, the largest within `ρ_0`
//! of `x_i`; so it lies within `ρ_1 = reach(r, W_1 - w_i)`, and weighs at
//! most `W_2`, the largest within `ρ_1`; and so on. Each `W_k` holds for
//! every polyhedron with `r <= R` when the radii are taken at `R`: the
//! record `[W_k, R²]` the kernels read. The largest weights within a
//! radius are read off a coarse grid of cell maxima (its cells meeting the
//! ball's box: an upper bound, which is all the argument needs).

use cvd_kernels::abi::SplitPoint;
use rayon::prelude::*;

/// Halvings of the bound (the `k` above).
const ROUNDS: usize = 3;

/// The radii the local bounds hold within, in mean site spacings (a
/// cell's farthest vertex is about one away; pieces start larger).
const CAPS: [f64; 3] = [1.0, 1.5, 2.5];

/// The most grid cells a site's bound reads (beyond, the largest weight
/// of all is its bound): 9 reads a site, so the bounds never cost more
/// than a few thousand reads per site, whatever the weights' spread.
const MOST_CELLS: usize = 1 << 12;

/// The side of the grid's cells, in mean site spacings.
const CELL_SPACINGS: f64 = 2.0;

/// The local bound record of each site of `sites` (the clipping frame,
/// weights in `hi[3] + lo[3]`, all in `0..=range`), for a domain of volume
/// `volume`: `hi = [W_0, R_0², W_1, R_1²]`, `lo = [W_2, R_2², 0, 0]` (see
/// the module's documentation), rounded so that they stay bounds in f32.
pub(crate) fn local_bounds(sites: &[SplitPoint], range: f64, volume: f64) -> Vec<SplitPoint> {
    let points: Vec<[f64; 3]> = sites.iter().map(SplitPoint::to_f64).collect();
    let (lo, hi) = crate::geom::vec3::bounding_box(points.iter());
    let mut grid = WeightGrid::new(lo, hi, sites.len(), volume);
    for s in sites {
        grid.add(s);
    }
    grid.bounds(sites, range)
}

/// The coarse grid of the largest weight in each cell that the bounds read
/// (see the module's documentation), over the box of all the sites. A job
/// in parts adds its own sites' and takes the largest of every part's in
/// each cell ([`Self::cells_mut`]): the grid of all sites, so each part
/// bounds its sites as the whole job does.
#[derive(Clone, Debug)]
pub(crate) struct WeightGrid {
    lo: [f64; 3],
    side: f64,
    dims: [usize; 3],
    spacing: f64,
    cells: Vec<f64>,
}

impl WeightGrid {
    /// An empty grid over `lo..hi` (the clipping frame) for `sites`
    /// distinct sites in a domain of volume `volume`: at most about 2^21
    /// cells.
    pub(crate) fn new(lo: [f64; 3], hi: [f64; 3], sites: usize, volume: f64) -> Self {
        let spacing = (volume.max(1e-30) / sites.max(1) as f64).cbrt();
        let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max).max(1e-30);
        let side = (CELL_SPACINGS * spacing).max(longest / 128.0);
        let dims = [0, 1, 2].map(|a| (((hi[a] - lo[a]) / side).floor() as usize + 1).min(129));
        Self { lo, side, dims, spacing, cells: vec![f64::NEG_INFINITY; dims[0] * dims[1] * dims[2]] }
    }

    fn cell_of(&self, x: f64, a: usize) -> usize {
        (((x - self.lo[a]) / self.side).floor().max(0.0) as usize).min(self.dims[a] - 1)
    }

    /// Adds a site (its weight in `hi[3] + lo[3]`).
    pub(crate) fn add(&mut self, site: &SplitPoint) {
        let p = site.to_f64();
        let c = (self.cell_of(p[2], 2) * self.dims[1] + self.cell_of(p[1], 1)) * self.dims[0] + self.cell_of(p[0], 0);
        self.cells[c] = self.cells[c].max(site.value());
    }

    /// Each cell's largest weight, to be taken the largest of over parts.
    pub(crate) fn cells_mut(&mut self) -> &mut [f64] {
        &mut self.cells
    }

    /// The largest weight of the cells meeting the box of the ball of
    /// `radius` around `p` (infinite when the box meets too many cells).
    fn box_max(&self, p: &[f64; 3], radius: f64) -> f64 {
        let dims = self.dims;
        let (a, b) =
            ([0, 1, 2].map(|k| self.cell_of(p[k] - radius, k)), [0, 1, 2].map(|k| self.cell_of(p[k] + radius, k)));
        // A ball over much of the grid (weights spread far wider than the
        // spacing) bounds nothing below the largest weight: no walk.
        if (0..3).map(|k| b[k] - a[k] + 1).product::<usize>() > MOST_CELLS {
            return f64::INFINITY;
        }
        let mut m = f64::NEG_INFINITY;
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                let row = (z * dims[1] + y) * dims[0];
                m = self.cells[row + a[0]..=row + b[0]].iter().copied().fold(m, f64::max);
            }
        }
        m
    }

    /// The local bound record of each of `sites` (every one inside the
    /// grid's box), weights in `0..=range` (see [`local_bounds`]).
    pub(crate) fn bounds(&self, sites: &[SplitPoint], range: f64) -> Vec<SplitPoint> {
        let spacing = self.spacing;
        // Rounded up, so that each bound stays one in f32.
        let up = |w: f64| {
            let b = w as f32;
            if (b as f64) < w {
                f32::from_bits(b.to_bits() + 1)
            } else {
                b
            }
        };
        sites
            .par_iter()
            .map(|s| {
                let (p, w) = (s.to_f64(), s.value());
                let bounds = CAPS.map(|c| {
                    let cap = c * spacing;
                    let reach = |slack: f64| (cap + (cap * cap + slack.max(0.0)).sqrt()) * (1.0 + 1e-4);
                    let mut bound = range;
                    for _ in 0..ROUNDS {
                        bound = bound.min(self.box_max(&p, reach(bound - w)));
                    }
                    (up(bound), (cap * cap * (1.0 - 1e-6)) as f32)
                });
                SplitPoint {
                    hi: [bounds[0].0, bounds[0].1, bounds[1].0, bounds[1].1],
                    lo: [bounds[2].0, bounds[2].1, 0.0, 0.0],
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sites(n: usize, spread: f64) -> Vec<SplitPoint> {
        let p = crate::geom::points::uniform(n, 7);
        let w = crate::geom::points::uniform(n, 8);
        p.iter().zip(&w).map(|(p, w)| SplitPoint::site(p.map(|c| 10.0 * c), spread * w[0])).collect()
    }

    #[test]
    fn each_bound_holds_the_weights_within_its_reach() {
        // Weights spread over a few spacings²: local bounds, each at least
        // the largest weight of the sites it lets reach its first radius.
        let s = sites(3000, 2.0);
        let range = s.iter().map(SplitPoint::value).fold(0.0, f64::max);
        let bounds = local_bounds(&s, range, 1000.0);
        let spacing = (1000.0f64 / 3000.0).cbrt();
        let mut below_range = 0;
        for (i, b) in bounds.iter().enumerate() {
            let (p, w) = (s[i].to_f64(), s[i].value());
            let r2 = b.hi[1] as f64;
            // The bound is its own: no site within reach(R, W - w_i) is heavier.
            let reach = r2.sqrt() + (r2 + (b.hi[0] as f64 - w).max(0.0)).sqrt();
            let near = s
                .iter()
                .filter(|q| (0..3).map(|a| (q.to_f64()[a] - p[a]).powi(2)).sum::<f64>().sqrt() <= reach)
                .map(SplitPoint::value)
                .fold(f64::NEG_INFINITY, f64::max);
            assert!(b.hi[0] as f64 >= near, "site {i}: bound {} below a weight {near} within its reach", b.hi[0]);
            assert!(b.hi[0] as f64 <= range * (1.0 + 1e-6) && r2 <= (spacing * spacing) * 1.0001);
            below_range += (b.hi[0] as f64 + 1e-3 < range) as usize;
        }
        assert!(below_range > 0, "no bound below the largest weight: nothing local");
    }

    #[test]
    fn weights_spread_far_wider_than_the_spacing_are_bounded_by_the_largest() {
        // A ball over much of the grid reads no cell (it would read them
        // all, for every site): its bound is the largest weight.
        let s = sites(3000, 1e6);
        let range = s.iter().map(SplitPoint::value).fold(0.0, f64::max);
        let bounds = local_bounds(&s, range, 1000.0);
        for b in &bounds {
            assert!(b.hi[0] as f64 >= range && b.lo[0] as f64 >= range, "{b:?} below {range}");
        }
    }
}
