//! The part of a job's site grid a part of a distributed job holds
//! ([`HeldCells`]): a box of grid cells.

use cvd_kernels::abi::{GridParams, RefineParams};

/// The grid cells whose sites a part holds: a box of the whole job's grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
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

/// The grid cells a part holds: the cells of any of a few boxes (each
/// around a group of its own sites' cells), inside their bounding box.
/// The job's window is the bounding box ([`Self::bounds`]); the cells of
/// it in no box are not held ([`Self::unheld_bits`]: their grid cells are
/// marked, so a walk that must look at one gives up as outside).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HeldSet {
    /// The boxes' bounding box.
    pub bounds: HeldCells,
    /// The boxes (each of the same grid).
    pub boxes: Vec<HeldCells>,
}

/// The most a [`HeldSet::clearance`] counts (cells).
const CLEARANCE_CAP: u16 = u16::MAX;

impl HeldSet {
    /// The cells of `boxes` (at least one, all of one grid).
    pub fn of(boxes: Vec<HeldCells>) -> Self {
        let first = boxes[0];
        let lo = [0, 1, 2].map(|a| boxes.iter().map(|b| b.lo[a]).min().unwrap_or(0));
        let end = [0, 1, 2].map(|a| boxes.iter().map(|b| b.lo[a] + b.dim[a]).max().unwrap_or(0));
        let bounds = HeldCells { lo, dim: [0, 1, 2].map(|a| end[a] - lo[a]), ..first };
        // A box that holds the bounds holds them all.
        let boxes = match boxes.iter().find(|b| **b == bounds) {
            Some(b) => vec![*b],
            None => boxes,
        };
        Self { bounds, boxes }
    }

    /// Whether grid cell `c` (whole grid coordinates) is held.
    pub fn holds(&self, c: [u32; 3]) -> bool {
        self.boxes.iter().any(|b| b.holds(c))
    }

    /// Whether every cell of the whole grid is held.
    pub fn is_whole(&self) -> bool {
        self.boxes.iter().any(HeldCells::is_whole)
    }

    /// One bit per cell of the bounds (x fastest), set where the cell is in
    /// no box; `None` when every cell of the bounds is held.
    pub fn unheld_bits(&self) -> Option<Vec<u32>> {
        if self.boxes.len() == 1 {
            return None;
        }
        let d = self.bounds.dim.map(|x| x as usize);
        // How many boxes cover each cell, from +1 and -1 at each box's
        // corners summed along the three axes in turn: the boxes' corners
        // and the bounds' cells once each, however many boxes overlap.
        let e = d.map(|x| x + 1);
        let mut cover = vec![0i32; e[0] * e[1] * e[2]];
        for b in &self.boxes {
            let o = [0, 1, 2].map(|a| (b.lo[a] - self.bounds.lo[a]) as usize);
            for corner in 0u32..8 {
                let at = [0, 1, 2].map(|a| if corner >> a & 1 == 0 { o[a] } else { o[a] + b.dim[a] as usize });
                let sign = if corner.count_ones() % 2 == 0 { 1 } else { -1 };
                cover[(at[2] * e[1] + at[1]) * e[0] + at[0]] += sign;
            }
        }
        for (axis, stride) in [(0, 1), (1, e[0]), (2, e[0] * e[1])] {
            for c in 0..cover.len() {
                let along = c / stride % e[axis];
                if along > 0 {
                    cover[c] += cover[c - stride];
                }
            }
        }
        let mut bits = vec![0u32; (d[0] * d[1] * d[2]).div_ceil(32)];
        for z in 0..d[2] {
            for y in 0..d[1] {
                for x in 0..d[0] {
                    if cover[(z * e[1] + y) * e[0] + x] == 0 {
                        let c = (z * d[1] + y) * d[0] + x;
                        bits[c / 32] |= 1 << (c % 32);
                    }
                }
            }
        }
        let n = d[0] * d[1] * d[2];
        let any = (0..n).any(|c| bits[c / 32] >> (c % 32) & 1 == 1);
        any.then_some(bits)
    }

    /// The cells held, looked up in one step each rather than box by box
    /// (a part's sites sent to the parts that hold them: many boxes).
    pub fn mask(&self) -> HeldMask {
        HeldMask { bounds: self.bounds, unheld: self.unheld_bits() }
    }

    /// For each cell of the bounds (x fastest), how many cells away the
    /// nearest cell of the bounds in no box is (the largest offset along
    /// any axis; at most [`CLEARANCE_CAP`]); `None` when every cell of the
    /// bounds is held.
    pub fn clearance(&self) -> Option<Vec<u16>> {
        let bits = self.unheld_bits()?;
        let d = self.bounds.dim.map(|x| x as usize);
        let n = d[0] * d[1] * d[2];
        let mut far = vec![CLEARANCE_CAP; n];
        let mut front: Vec<usize> = (0..n).filter(|&c| bits[c / 32] >> (c % 32) & 1 == 1).collect();
        for &c in &front {
            far[c] = 0;
        }
        // Rings outward from the unheld cells, one cell (in any of the 26
        // directions) a step.
        let mut step = 0;
        while !front.is_empty() {
            step += 1;
            let mut next = Vec::new();
            for &c in &front {
                let at = [c % d[0], c / d[0] % d[1], c / (d[0] * d[1])];
                for dz in -1i64..=1 {
                    for dy in -1i64..=1 {
                        for dx in -1i64..=1 {
                            let p = [at[0] as i64 + dx, at[1] as i64 + dy, at[2] as i64 + dz];
                            if (0..3).any(|a| p[a] < 0 || p[a] >= d[a] as i64) {
                                continue;
                            }
                            let e = (p[2] as usize * d[1] + p[1] as usize) * d[0] + p[0] as usize;
                            if far[e] > step {
                                far[e] = step;
                                next.push(e);
                            }
                        }
                    }
                }
            }
            front = next;
        }
        Some(far)
    }

    /// Whether every site within `sqrt(d2)` of the point `q` (the part's
    /// quantized coordinates, in its bounds) is held: the bounds certify
    /// it ([`HeldCells::certifies`]), and no cell the ball may reach is in
    /// no box — from `q`'s cell, `floor(sqrt(d2) / cell_size) + 1` cells at
    /// most along any axis, fewer than its `clearance` ([`Self::clearance`],
    /// `None`: every cell of the bounds held).
    pub fn certifies(&self, q: [u32; 3], d2: u64, clearance: Option<&[u16]>) -> bool {
        if !self.bounds.certifies(q, d2) {
            return false;
        }
        let Some(far) = clearance else { return true };
        let b = &self.bounds;
        let c = [0, 1, 2].map(|a| (q[a] / b.cell_size).min(b.dim[a] - 1) as usize);
        let cell = (c[2] * b.dim[1] as usize + c[1]) * b.dim[0] as usize + c[0];
        let reach = ((d2 as f64).sqrt() / b.cell_size as f64).floor() as u64 + 1;
        reach < far[cell] as u64
    }
}

/// The cells of a [`HeldSet`] as its bounds and one bit per cell of them
/// ([`HeldSet::mask`]).
#[derive(Clone, Debug)]
pub struct HeldMask {
    bounds: HeldCells,
    unheld: Option<Vec<u32>>,
}

impl HeldMask {
    /// The bounds of the cells held.
    pub fn bounds(&self) -> &HeldCells {
        &self.bounds
    }

    /// Whether grid cell `c` (whole grid coordinates) is held: as
    /// [`HeldSet::holds`].
    pub fn holds(&self, c: [u32; 3]) -> bool {
        let b = &self.bounds;
        if !b.holds(c) {
            return false;
        }
        let Some(bits) = &self.unheld else { return true };
        let o = [0, 1, 2].map(|a| (c[a] - b.lo[a]) as usize);
        let at = (o[2] * b.dim[1] as usize + o[1]) * b.dim[0] as usize + o[0];
        bits[at / 32] >> (at % 32) & 1 == 0
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
    fn a_set_holds_the_cells_of_its_boxes_and_marks_the_rest_of_their_bounds() {
        // Two boxes at opposite corners of a 10-cell grid.
        let a = HeldCells::around([1, 1, 1], [2, 2, 2], 0, GRID, 100);
        let b = HeldCells::around([6, 6, 6], [7, 7, 7], 0, GRID, 100);
        let set = HeldSet::of(vec![a, b]);
        assert_eq!((set.bounds.lo, set.bounds.dim), ([1; 3], [7; 3]));
        assert!(set.holds([1, 1, 1]) && set.holds([7, 7, 7]) && !set.holds([4, 4, 4]) && !set.holds([1, 1, 7]));
        assert!(!set.is_whole());
        let bits = set.unheld_bits().unwrap();
        let unheld = |c: usize| bits[c / 32] >> (c % 32) & 1 == 1;
        for z in 0..7 {
            for y in 0..7 {
                for x in 0..7 {
                    let c = (z * 7 + y) * 7 + x;
                    assert_eq!(unheld(c), !set.holds([x as u32 + 1, y as u32 + 1, z as u32 + 1]), "{x} {y} {z}");
                }
            }
        }
        let mask = set.mask();
        for c in 0..1000u32 {
            let c = [c % 10, c / 10 % 10, c / 100];
            assert_eq!(mask.holds(c), set.holds(c), "{c:?}: the mask holds what the boxes hold");
        }
        // Clearance: the largest offset to the nearest unheld cell.
        let far = set.clearance().unwrap();
        assert_eq!(far[0], 2, "corner (1,1,1): (3,1,1) is two cells away");
        assert_eq!(far[(7 + 1) * 7 + 1], 1, "(2,2,2) touches (3,3,3)");
        assert_eq!(far[(3 * 7 + 3) * 7 + 3], 0, "(4,4,4) is not held");
        // A ball certified by the bounds, not by the cells held around it.
        let q = [50, 50, 50];
        assert!(set.certifies(q, 40 * 40, Some(&far)), "within the first cell: one cell away at most");
        assert!(!set.certifies(q, 100 * 100, Some(&far)), "reaching (3,1,1)'s neighbourhood");
        assert!(set.bounds.certifies(q, 40 * 40));
        // One box that holds the bounds: nothing marked.
        let big = HeldCells::around([1; 3], [7; 3], 0, GRID, 100);
        let set = HeldSet::of(vec![a, big, b]);
        assert_eq!((set.boxes.clone(), set.unheld_bits(), set.clearance()), (vec![big], None, None));
        let mask = set.mask();
        assert!(mask.holds([1; 3]) && mask.holds([7; 3]) && mask.holds([4; 3]) && !mask.holds([0, 4, 4]));
        assert!(set.certifies(q, 40 * 40, None));
    }

    #[test]
    fn overlapping_boxes_hold_their_union() {
        // Boxes that overlap, nest, touch and stand apart, in a 10-cell grid:
        // the unheld bits, the mask and the boxes agree on every cell.
        let boxes = vec![
            HeldCells::around([1, 1, 1], [3, 3, 3], 1, GRID, 100),
            HeldCells::around([2, 2, 2], [2, 2, 2], 0, GRID, 100),
            HeldCells::around([3, 1, 2], [6, 2, 2], 0, GRID, 100),
            HeldCells::around([7, 0, 0], [7, 0, 9], 0, GRID, 100),
            HeldCells::around([5, 5, 5], [8, 8, 8], 0, GRID, 100),
        ];
        let set = HeldSet::of(boxes);
        let (lo, d) = (set.bounds.lo, set.bounds.dim);
        let bits = set.unheld_bits().unwrap();
        let mask = set.mask();
        let mut held = 0;
        for c in 0..1000u32 {
            let c = [c % 10, c / 10 % 10, c / 100];
            let by_boxes = set.boxes.iter().any(|b| b.holds(c));
            assert_eq!(mask.holds(c), by_boxes, "{c:?}");
            if set.bounds.holds(c) {
                let at = (((c[2] - lo[2]) * d[1] + c[1] - lo[1]) * d[0] + c[0] - lo[0]) as usize;
                assert_eq!(bits[at / 32] >> (at % 32) & 1 == 1, !by_boxes, "{c:?}");
            }
            held += by_boxes as u32;
        }
        assert!(held > 64 && held < 1000, "{held} cells held");
    }

    #[test]
    fn a_walk_gives_up_at_a_cell_marked_unheld() {
        use crate::job::knn::{KnnJob, KnnMethod};
        use cvd_kernels::walk::{GridWalk, NO_CELL};
        // Sites in a 4 x 1 x 1 row of cells; the third marked unheld (it
        // holds none).
        let sites: Vec<[f64; 3]> = [0.1, 0.3, 0.9].iter().map(|&x| [x, 0.5, 0.5]).collect();
        let mut job = KnnJob::sites(&sites, 1, KnnMethod::Grid).unwrap();
        job.params.grid = GridParams { dim_x: 4, dim_y: 1, dim_z: 1, n_cells: 4, ..job.params.grid };
        job.params.grid.cell_size = (job.quantizer.scale() * 0.25).ceil() as u32;
        let plain = crate::exec::build_grid(&job);
        job.unheld = Some(vec![1 << 2].into());
        let g = crate::exec::build_grid(&job);
        assert_eq!(g.cell_count, plain.cell_count);
        assert_eq!(g.cell_count[2], 0);
        assert_eq!(g.cell_start[2], cvd_kernels::abi::UNHELD);
        assert_eq!((&g.cell_start[..2], g.cell_start[3]), (&plain.cell_start[..2], plain.cell_start[3]));
        let refine =
            HeldCells::whole(&job.params.grid).in_refine(RefineParams { grid: job.params.grid, ..Default::default() });
        let walk = GridWalk::new(&refine, &[], &g.cell_start, &g.cell_count, &g.sorted);
        assert_eq!(walk.held_cell([2, 0, 0]), NO_CELL);
        assert_eq!(walk.held_cell([1, 0, 0]), 1);
        assert_eq!(walk.held_cell([3, 0, 0]), 3);
        let walk = GridWalk::new(&refine, &[], &plain.cell_start, &plain.cell_count, &plain.sorted);
        assert_eq!(walk.held_cell([2, 0, 0]), 2, "unmarked: an empty cell");
    }

    /// A walk passes over a cell it does not hold when no site there could
    /// change what it works on (told when the cell is met, or when the walk
    /// ends: what it works on only shrinks), and gives up otherwise.
    #[test]
    fn a_walk_passes_over_an_unheld_cell_no_site_in_could_cut() {
        use crate::job::knn::{KnnJob, KnnMethod};
        use cvd_kernels::walk::{walk_end, walk_rings, GridWalk, RingVisitor};
        // Sites in a 4 x 1 x 1 row of cells; the third marked unheld (it
        // holds none).
        let sites: Vec<[f64; 3]> = [0.1, 0.15, 0.3, 0.9].iter().map(|&x| [x, 0.5, 0.5]).collect();
        let mut job = KnnJob::sites(&sites, 1, KnnMethod::Grid).unwrap();
        job.params.grid = GridParams { dim_x: 4, dim_y: 1, dim_z: 1, n_cells: 4, ..job.params.grid };
        job.params.grid.cell_size = (job.quantizer.scale() * 0.25).ceil() as u32;
        job.unheld = Some(vec![1 << 2].into());
        let g = crate::exec::build_grid(&job);
        let cell_len = job.params.grid.cell_size as f32;
        let refine = HeldCells::whole(&job.params.grid).in_refine(RefineParams {
            grid: job.params.grid,
            cell_len,
            ..Default::default()
        });
        let walk = GridWalk::new(&refine, &[], &g.cell_start, &g.cell_count, &g.sorted);
        // Meets every site within reach; a site in a box could cut while
        // fewer than `cut_until` sites were met.
        struct Visitor {
            met: Vec<u32>,
            cut_until: usize,
        }
        impl RingVisitor<()> for Visitor {
            fn reach2(&self) -> f32 {
                f32::INFINITY
            }
            fn visit(&mut self, _: &mut (), s: u32) -> bool {
                self.met.push(s);
                false
            }
            fn may_cut(&self, _: &(), _: [f32; 3], _: [f32; 3]) -> bool {
                self.met.len() < self.cut_until
            }
        }
        let x = cvd_kernels::polyhedron::Point::new(0.5 * cell_len, 0.0, 0.0);
        let mut ends = Vec::new();
        for cut_until in [0, 4, usize::MAX] {
            let mut v = Visitor { met: Vec::new(), cut_until };
            ends.push(walk_rings(&walk, x, &mut v, &mut ()));
            v.met.sort_unstable();
            assert_eq!(v.met, [0, 1, 2, 3], "every held site met (cut until {cut_until})");
        }
        // Could not cut when met; could then, not at the end; could always.
        assert_eq!(ends, [walk_end::DONE, walk_end::DONE, walk_end::OUT_OF_HALO]);
    }

    /// Whether a site in a box could cut a cell: only where the box comes
    /// nearer one of its vertices than its own site.
    #[test]
    fn a_box_may_cut_a_cell_only_within_a_vertex_ball() {
        use cvd_kernels::glam::Vec3;
        use cvd_kernels::polyhedron::Cell;
        use cvd_kernels::walk::box_may_cut;
        // A unit cube around its site: vertex balls of radius sqrt(3) / 2
        // about its corners.
        let cell = Cell::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5));
        let site = cvd_kernels::polyhedron::Point::ZERO;
        let r = 3f32.sqrt() / 2.0;
        // Beyond a face's centre (the nearest corner at sqrt(0.5 + d²)).
        let near = |d: f32| box_may_cut(&cell, site, [0.5 + d, -0.01, -0.01], [2.0, 0.01, 0.01]);
        assert!(near(0.49));
        assert!(!near(0.55));
        // Beyond a corner, along the diagonal.
        let corner = |d: f32| box_may_cut(&cell, site, [0.5 + d; 3], [3.0; 3]);
        assert!(corner(0.99 * r / 3f32.sqrt()));
        assert!(!corner(1.01 * r / 3f32.sqrt()));
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
