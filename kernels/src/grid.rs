//! A uniform grid over the sites (paper section 5.2), built by a counting
//! sort: [`count_site`] bins each site and counts the bins, a prefix sum
//! ([`crate::scan`]) turns counts into bin starts, and [`scatter_site`] moves
//! each site to its bin. The order of sites inside a bin depends on thread
//! timing; nothing downstream depends on it (k-NN ties break by index).

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
