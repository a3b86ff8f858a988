//! A uniform grid over the sites for the host's ball and nearest queries
//! (the host pass). The kernels' grid answers k-nearest queries; these
//! ask for every site within a radius, which a k cannot bound.

use cvd_kernels::abi::SplitPoint;
/// Sites binned into cubic cells.
pub struct SiteGrid<'a> {
    sites: &'a [SplitPoint],
    lo: [f64; 3],
    cell: f64,
    dims: [usize; 3],
    /// Cell `c` holds `ids[start[c]..start[c + 1]]`.
    start: Vec<u32>,
    ids: Vec<u32>,
}

/// About this many sites per cell.
const SITES_PER_CELL: f64 = 4.0;

impl<'a> SiteGrid<'a> {
    /// Bins `sites` (at least one).
    pub fn new(sites: &'a [SplitPoint]) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for s in sites {
            let s = s.to_f64();
            for a in 0..3 {
                lo[a] = lo[a].min(s[a]);
                hi[a] = hi[a].max(s[a]);
            }
        }
        let ext = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(1e-9));
        let volume: f64 = ext.iter().product();
        let mut cell = (volume * SITES_PER_CELL / sites.len() as f64).cbrt().max(1e-9);
        // Flat sets: keep the cell count near the site count.
        let dims_for = |cell: f64| ext.map(|e| (e / cell).floor() as usize + 1);
        while dims_for(cell).iter().product::<usize>() > 2 * sites.len() + 64 {
            cell *= 2.0;
        }
        let dims = dims_for(cell);
        let mut grid =
            Self { sites, lo, cell, dims, start: vec![0; dims.iter().product::<usize>() + 1], ids: Vec::new() };
        let cells: Vec<usize> = sites.iter().map(|s| grid.index(grid.coords(s.to_f64()))).collect();
        for &c in &cells {
            grid.start[c + 1] += 1;
        }
        for c in 1..grid.start.len() {
            grid.start[c] += grid.start[c - 1];
        }
        let mut next = grid.start.clone();
        grid.ids = vec![0; sites.len()];
        for (i, &c) in cells.iter().enumerate() {
            grid.ids[next[c] as usize] = i as u32;
            next[c] += 1;
        }
        grid
    }

    fn coords(&self, p: [f64; 3]) -> [usize; 3] {
        [0, 1, 2].map(|a| (((p[a] - self.lo[a]) / self.cell).floor().max(0.0) as usize).min(self.dims[a] - 1))
    }

    fn index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    /// Squared distance from `p` to site `i`.
    pub fn dist2(&self, i: u32, p: [f64; 3]) -> f64 {
        let s = self.sites[i as usize].to_f64();
        (0..3).map(|a| (s[a] - p[a]).powi(2)).sum()
    }

    /// Appends every site within `radius` of `p` to `out`.
    pub fn within(&self, p: [f64; 3], radius: f64, out: &mut Vec<u32>) {
        let r2 = radius * radius;
        self.each_near(p, radius, |i, d2| {
            if d2 <= r2 {
                out.push(i);
            }
        });
    }

    /// Each site of the grid cells the box `p ± radius` meets, with its
    /// squared distance to `p`.
    fn each_near(&self, p: [f64; 3], radius: f64, mut f: impl FnMut(u32, f64)) {
        let lo = self.coords(p.map(|c| c - radius));
        let hi = self.coords(p.map(|c| c + radius));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let row = self.index([0, y, z]);
                let (a, b) = (self.start[row + lo[0]] as usize, self.start[row + hi[0] + 1] as usize);
                for &i in &self.ids[a..b] {
                    f(i, self.dist2(i, p));
                }
            }
        }
    }

    /// The site nearest `p` (lowest index on ties) and its distance.
    pub fn nearest(&self, p: [f64; 3]) -> (u32, f64) {
        let mut radius = self.cell;
        loop {
            // The nearest within `radius`, if any: then the nearest of all.
            let r2 = radius * radius;
            let mut best: Option<(f64, u32)> = None;
            self.each_near(p, radius, |i, d2| {
                if d2 <= r2 && best.is_none_or(|b| (d2, i) < b) {
                    best = Some((d2, i));
                }
            });
            if let Some((d2, i)) = best {
                return (i, d2.sqrt());
            }
            radius *= 2.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ball_and_nearest_match_brute_force() {
        let mut rng = crate::geom::points::Rng::new(7);
        let sites: Vec<SplitPoint> =
            (0..2000).map(|_| SplitPoint::new([rng.unit(), rng.unit(), 0.3 * rng.unit()], 0.0)).collect();
        let grid = SiteGrid::new(&sites);
        for q in 0..50 {
            let p = [rng.unit() * 1.4 - 0.2, rng.unit(), rng.unit() - 0.5];
            let r = 0.02 * q as f64;
            let mut got = Vec::new();
            grid.within(p, r, &mut got);
            got.sort_unstable();
            let want: Vec<u32> = (0..sites.len() as u32).filter(|&i| grid.dist2(i, p) <= r * r).collect();
            assert_eq!(got, want);
            let (best, d) = grid.nearest(p);
            let brute = (0..sites.len() as u32).map(|i| grid.dist2(i, p)).fold(f64::INFINITY, f64::min);
            assert_eq!(d, grid.dist2(best, p).sqrt());
            assert_eq!(grid.dist2(best, p), brute);
        }
    }
}
