//! The part of a job's site grid a part of a distributed job holds
//! ([`Held`]): a box of grid cells.

use cvd_kernels::abi::GridParams;

/// The grid cells whose sites a part holds: a box of the whole job's grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Held {
    /// The box's first cell, in the whole grid's cell coordinates.
    pub lo: [u32; 3],
    /// Cells of the box per axis.
    pub dim: [u32; 3],
    /// Cells of the whole grid per axis.
    pub grid: [u32; 3],
    /// Side of a cell in quantized units.
    pub cell_size: u32,
}

impl Held {
    /// The cells `lo..=hi` widened by `halo` cells on every side, inside a
    /// grid of `grid` cells of `cell_size` units.
    pub fn around(lo: [u32; 3], hi: [u32; 3], halo: u32, grid: [u32; 3], cell_size: u32) -> Self {
        let first = [0, 1, 2].map(|a| lo[a].saturating_sub(halo));
        let end = [0, 1, 2].map(|a| hi[a].saturating_add(halo).saturating_add(1).min(grid[a]));
        Self { lo: first, dim: [0, 1, 2].map(|a| end[a] - first[a]), grid, cell_size }
    }

    /// Whether the box is the whole grid (every site is held).
    pub fn is_whole(&self) -> bool {
        self.lo == [0; 3] && self.dim == self.grid
    }

    /// What the part subtracts from the whole job's quantized coordinates.
    pub fn shift(&self) -> [u32; 3] {
        self.lo.map(|c| c * self.cell_size)
    }

    /// Whether grid cell `c` (whole grid coordinates) is held.
    pub fn holds(&self, c: [u32; 3]) -> bool {
        (0..3).all(|a| c[a] >= self.lo[a] && c[a] - self.lo[a] < self.dim[a])
    }

    /// Whether every site within `sqrt(d2)` of the point `q` (the part's
    /// quantized coordinates) is held: the ball lies strictly inside every
    /// side of the box that has cells beyond it. `d2 = u64::MAX` (fewer
    /// neighbours than asked for) is certified only by the whole grid.
    pub fn certifies(&self, q: [u32; 3], d2: u64) -> bool {
        let cs = self.cell_size as u64;
        (0..3).all(|a| {
            let low = self.lo[a] == 0 || {
                let d = q[a] as u64;
                d * d > d2
            };
            let high = self.lo[a] + self.dim[a] >= self.grid[a] || {
                let d = (self.dim[a] as u64 * cs).saturating_sub(q[a] as u64);
                d * d > d2
            };
            low && high
        })
    }

    /// The part's grid over `n_sites` held sites.
    pub(crate) fn grid_params(&self, n_sites: usize) -> GridParams {
        GridParams {
            dim_x: self.dim[0],
            dim_y: self.dim[1],
            dim_z: self.dim[2],
            cell_size: self.cell_size,
            n_sites: n_sites as u32,
            n_cells: self.dim.iter().product(),
            _pad: [0; 2],
        }
    }
}
