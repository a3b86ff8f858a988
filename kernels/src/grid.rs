//! A uniform grid over the sites (paper section 5.2), built by a counting
//! sort: [`count_site`] bins each site and counts the bins, a prefix sum
//! ([`crate::scan`]) turns counts into bin starts, and [`scatter_site`] moves
//! each site to its bin. The scatter's order inside a bin depends on thread
//! timing, so [`sort_cell`] then orders each bin by site index: walks over
//! the grid (the second pass clips in the order it meets sites) give the
//! same bits run after run.

use crate::abi::{GridParams, QuantPoint};
use crate::buffers::{AtomicCounters, OutBuf};

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
