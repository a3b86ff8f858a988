//! A uniform grid over the sites (paper section 5.2), built by a counting
//! sort: [`count_site`] bins each site and counts the bins, a prefix sum
//! ([`crate::scan`]) turns counts into bin starts, and [`scatter_site`] moves
//! each site to its bin. The scatter's order inside a bin depends on thread
//! timing, so [`sort_cell`] then orders each bin by site index: walks over
//! the grid (the second pass clips in the order it meets sites) give the
//! same bits run after run. [`ring_span`] and [`ring_row`] list the cells
//! of a Chebyshev ring around a cell: the k-NN and the walks search the grid
//! ring by ring.

use crate::abi::{GridParams, QuantPoint};
use crate::buffers::{AtomicCounters, OutBuf};

/// `|a - b|`, written out: rust-gpu 0.11 lacks the intrinsics behind
/// `abs_diff` and `saturating_sub`.
#[inline]
#[allow(clippy::manual_abs_diff)]
pub fn diff(a: u32, b: u32) -> u32 {
    if a > b {
        a - b
    } else {
        b - a
    }
}

/// `max(a - b, 0)`.
#[inline]
#[allow(clippy::implicit_saturating_sub)]
pub fn sub_floor0(a: u32, b: u32) -> u32 {
    if a > b {
        a - b
    } else {
        0
    }
}

/// Rows or layers `lo..=hi` of Chebyshev ring `r` around cell coordinate
/// `c` along an axis of `dim` cells.
#[inline]
pub fn ring_span(c: u32, r: u32, dim: u32) -> (u32, u32) {
    (sub_floor0(c, r), (c + r).min(dim - 1))
}

/// The cells of Chebyshev ring `r` around cell `c` in row `(y, z)` of the
/// ring's span: `x` from `first` by `step` up to `last` (none when `first >
/// last`). A row on the ring's y-z shell lies wholly on the ring; inside
/// it, only the row's two ends do.
#[inline]
pub fn ring_row(g: &GridParams, c: [u32; 3], r: u32, y: u32, z: u32) -> (u32, u32, u32) {
    if diff(z, c[2]) == r || diff(y, c[1]) == r {
        let (x0, x1) = ring_span(c[0], r, g.dim_x);
        return (x0, x1, 1);
    }
    // Not on the shell: r >= 1.
    let low = c[0] >= r;
    let high = c[0] + r < g.dim_x;
    if low && high {
        (c[0] - r, c[0] + r, 2 * r)
    } else if low {
        (c[0] - r, c[0] - r, 1)
    } else if high {
        (c[0] + r, c[0] + r, 1)
    } else {
        (1, 0, 1)
    }
}

/// The cell holding quantized point `q` (points past the last cell go to it).
#[inline]
pub fn cell_coords(g: &GridParams, q: [u32; 3]) -> [u32; 3] {
    [
        (q[0] / g.cell_size).min(g.dim_x - 1),
        (q[1] / g.cell_size).min(g.dim_y - 1),
        (q[2] / g.cell_size).min(g.dim_z - 1),
    ]
}

/// The linear index of cell `c` (x fastest).
#[inline]
pub fn cell_index(g: &GridParams, c: [u32; 3]) -> usize {
    ((c[2] as usize * g.dim_y as usize) + c[1] as usize) * g.dim_x as usize + c[0] as usize
}

/// Thread `i`: records the cell of site `i` and counts it in `counts`.
#[inline]
pub fn count_site<C, A>(i: usize, g: &GridParams, sites: &[QuantPoint], site_cell: &mut C, counts: &mut A)
where
    C: OutBuf<u32> + ?Sized,
    A: AtomicCounters,
{
    if i >= g.n_sites as usize {
        return;
    }
    let s = sites[i];
    let cell = cell_index(g, cell_coords(g, [s[0], s[1], s[2]]));
    site_cell.write(i, cell as u32);
    counts.fetch_add(cell, 1);
}

/// Thread `i`: writes site `i` into the next free slot of its cell in
/// `sorted`. `cursor` must start zeroed; each slot is written exactly once.
#[inline]
pub fn scatter_site<A, S>(
    i: usize,
    g: &GridParams,
    sites: &[QuantPoint],
    site_cell: &[u32],
    cell_start: &[u32],
    cursor: &mut A,
    sorted: &mut S,
) where
    A: AtomicCounters,
    S: OutBuf<QuantPoint> + ?Sized,
{
    if i >= g.n_sites as usize {
        return;
    }
    let cell = site_cell[i] as usize;
    let slot = cell_start[cell] + cursor.fetch_add(cell, 1);
    sorted.write(slot as usize, sites[i]);
}

/// Thread `c`: sorts the sites of cell `c` by index (insertion sort: a cell
/// holds a few sites).
#[inline]
pub fn sort_cell<S>(c: usize, g: &GridParams, cell_start: &[u32], cell_count: &[u32], sorted: &mut S)
where
    S: OutBuf<QuantPoint> + ?Sized,
{
    if c >= g.n_cells as usize {
        return;
    }
    let start = cell_start[c] as usize;
    let n = cell_count[c] as usize;
    let mut i = 1;
    while i < n {
        let x = sorted.read(start + i);
        let mut j = i;
        while j > 0 {
            let y = sorted.read(start + j - 1);
            if y[3] <= x[3] {
                break;
            }
            sorted.write(start + j, y);
            j -= 1;
        }
        sorted.write(start + j, x);
        i += 1;
    }
}
