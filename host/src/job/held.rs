//! The part of a job's site grid a part of a distributed job holds
//! ([`HeldCells`]): a box of grid cells.

use cvd_kernels::abi::{GridParams, RefineParams};

/// The grid cells whose sites a part holds: a box of the whole job's grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeldCells {
    /// The box's first cell, in the whole grid's cell coordinates.
    pub lo: [u32; 3],
    /// Cells of the box per axis.
    pub dim: [u32; 3],
    /// Cells of the whole grid per axis.
    pub grid: [u32; 3],
    /// Side of a cell in quantized units.
    pub cell_size: u32,
}

impl HeldCells {
    /// The cells `lo..=hi` widened by `halo` cells on every side, inside a
    /// grid of `grid` cells of `cell_size` units.
    pub fn around(lo: [u32; 3], hi: [u32; 3], halo: u32, grid: [u32; 3], cell_size: u32) -> Self {
        let first = [0, 1, 2].map(|a| lo[a].saturating_sub(halo));
        let end = [0, 1, 2].map(|a| hi[a].saturating_add(halo).saturating_add(1).min(grid[a]));
        Self { lo: first, dim: [0, 1, 2].map(|a| end[a] - first[a]), grid, cell_size }
    }

    /// Every cell of `grid`.
    pub fn whole(grid: &GridParams) -> Self {
        let dim = [grid.dim_x, grid.dim_y, grid.dim_z];
        Self { lo: [0; 3], dim, grid: dim, cell_size: grid.cell_size }
    }

    /// The held cells `refine` describes (`RefineParams::held_lo_x`: those
    /// a part's or a window's walks read).
    pub fn of(refine: &RefineParams) -> Self {
        let g = &refine.grid;
        Self {
            lo: [refine.held_lo_x, refine.held_lo_y, refine.held_lo_z],
            dim: [refine.held_dim_x, refine.held_dim_y, refine.held_dim_z],
            grid: [g.dim_x, g.dim_y, g.dim_z],
            cell_size: g.cell_size,
        }
    }

    /// `refine` with these held cells (its grid the whole one).
    pub fn in_refine(&self, refine: RefineParams) -> RefineParams {
        RefineParams {
            held_lo_x: self.lo[0],
            held_lo_y: self.lo[1],
            held_lo_z: self.lo[2],
            held_dim_x: self.dim[0],
            held_dim_y: self.dim[1],
            held_dim_z: self.dim[2],
            ..refine
        }
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

    /// Whether any cell from `lo` to `hi` (inclusive, whole grid
    /// coordinates) is held.
    pub fn meets(&self, lo: [u32; 3], hi: [u32; 3]) -> bool {
        (0..3).all(|a| hi[a] >= self.lo[a] && lo[a] < self.lo[a] + self.dim[a])
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

#[cfg(test)]
mod tests {
    use super::*;

    const GRID: [u32; 3] = [10, 10, 10];

    #[test]
    fn around_widens_by_the_halo_and_clamps_to_the_grid() {
        let h = HeldCells::around([2, 3, 4], [3, 3, 5], 1, GRID, 7);
        assert_eq!(h, HeldCells { lo: [1, 2, 3], dim: [4, 3, 4], grid: GRID, cell_size: 7 });
        assert_eq!(h.shift(), [7, 14, 21]);
        // At the grid's sides: cut there, on both ends.
        let h = HeldCells::around([0, 1, 8], [1, 9, 9], 2, GRID, 7);
        assert_eq!((h.lo, h.dim), ([0, 0, 6], [4, 10, 4]));
        // Any halo, however large, is the whole grid at most.
        let h = HeldCells::around([4, 4, 4], [5, 5, 5], u32::MAX, GRID, 7);
        assert_eq!((h.lo, h.dim), ([0; 3], GRID));
        assert!(h.is_whole());
        assert_eq!(h.shift(), [0; 3]);
    }

    #[test]
    fn is_whole_only_for_the_whole_grid() {
        assert!(HeldCells::around([0; 3], [9; 3], 0, GRID, 1).is_whole());
        assert!(!HeldCells::around([0; 3], [9, 9, 8], 0, GRID, 1).is_whole());
        assert!(!HeldCells::around([1, 0, 0], [9; 3], 0, GRID, 1).is_whole());
    }

    #[test]
    fn holds_exactly_the_cells_of_the_box() {
        let h = HeldCells::around([2, 3, 4], [3, 3, 5], 1, GRID, 7); // cells 1..5, 2..5, 3..7
        assert!(h.holds([1, 2, 3]) && h.holds([4, 4, 6]) && h.holds([2, 3, 5]));
        for outside in [[0, 3, 4], [5, 3, 4], [2, 1, 4], [2, 5, 4], [2, 3, 2], [2, 3, 7], [u32::MAX, 3, 4]] {
            assert!(!h.holds(outside), "{outside:?}");
        }
        let count = (0..10).flat_map(|x| (0..10).flat_map(move |y| (0..10).map(move |z| [x, y, z])));
        assert_eq!(count.filter(|&c| h.holds(c)).count(), 4 * 3 * 4);
    }

    #[test]
    fn meets_a_box_when_it_holds_one_of_its_cells() {
        let h = HeldCells::around([2, 3, 4], [3, 3, 5], 1, GRID, 7);
        let cells = |lo: [u32; 3], hi: [u32; 3]| {
            (lo[0]..=hi[0])
                .flat_map(move |x| (lo[1]..=hi[1]).flat_map(move |y| (lo[2]..=hi[2]).map(move |z| [x, y, z])))
        };
        for lo in cells([0; 3], [6; 3]).step_by(5) {
            for hi in cells(lo, [9; 3]).step_by(7) {
                assert_eq!(h.meets(lo, hi), cells(lo, hi).any(|c| h.holds(c)), "{lo:?}..={hi:?}");
            }
        }
    }

    #[test]
    fn certifies_a_ball_strictly_inside_the_box() {
        // Cells 2..5 on every axis, 100 units each: the part's quantized
        // box is 0..300, with cells beyond it on every side.
        let h = HeldCells::around([2; 3], [4; 3], 0, GRID, 100);
        let q = [150, 150, 150];
        assert!(h.certifies(q, 149 * 149), "inside");
        assert!(!h.certifies(q, 150 * 150), "touching a side");
        assert!(!h.certifies(q, 151 * 151), "beyond a side");
        assert!(!h.certifies(q, u64::MAX), "fewer neighbours than asked");
        // Near one side only.
        assert!(h.certifies([10, 150, 150], 99));
        assert!(!h.certifies([10, 150, 150], 100));
        assert!(h.certifies([150, 150, 290], 99));
        assert!(!h.certifies([150, 150, 290], 100));
        assert!(!h.certifies([0, 150, 150], 0), "on the low side");
        // Past the high side (a query outside the held cells).
        assert!(!h.certifies([150, 150, 400], 0));
    }

    #[test]
    fn a_side_at_the_grids_edge_needs_no_margin() {
        // Cells 0..3 along x (the grid's low end), 7..10 along y (its high
        // end), 4..6 along z.
        let h = HeldCells::around([0, 7, 4], [2, 9, 5], 0, GRID, 100);
        assert!(h.certifies([0, 150, 100], 99 * 99), "nothing below x = 0 or above y = 300");
        assert!(h.certifies([1, 299, 100], 99 * 99));
        assert!(!h.certifies([1, 299, 100], 100 * 100), "z still has cells beyond it");
        assert!(!h.certifies([150, 150, 100], 150 * 150), "x has cells above");
        // The whole grid certifies everything, even an unbounded ball.
        let whole = HeldCells::around([0; 3], [9; 3], 0, GRID, 100);
        assert!(whole.certifies([0, 0, 0], u64::MAX));
        assert!(whole.certifies([999, 999, 999], u64::MAX));
    }

    #[test]
    fn held_cells_go_into_refine_parameters_and_back() {
        let h = HeldCells::around([2, 3, 4], [3, 3, 5], 1, GRID, 7);
        let grid = GridParams { dim_x: 10, dim_y: 10, dim_z: 10, cell_size: 7, ..Default::default() };
        let refine = h.in_refine(RefineParams { grid, ..Default::default() });
        assert_eq!(HeldCells::of(&refine), h);
        let whole = HeldCells::whole(&grid);
        assert!(whole.is_whole() && HeldCells::of(&whole.in_refine(refine)).is_whole());
        assert_eq!(whole.shift(), [0; 3]);
    }

    #[test]
    fn grid_params_describe_the_box() {
        let h = HeldCells::around([2, 3, 4], [3, 3, 5], 1, GRID, 7);
        let g = h.grid_params(123);
        assert_eq!((g.dim_x, g.dim_y, g.dim_z, g.cell_size, g.n_sites, g.n_cells), (4, 3, 4, 7, 123, 48));
    }
}
