//! A uniform grid over the sites (paper section 5.2), built by a counting
//! sort: [`count_site`] bins each site and counts the bins, a prefix sum
//! ([`crate::scan`]) turns counts into bin starts, and [`scatter_site`] moves
//! each site to its bin. The scatter's order inside a bin depends on thread
//! timing, so [`sort_cell`] then orders each bin by site index: walks over
//! the grid (the second pass clips in the order it meets sites) give the
//! same bits run after run. A dense bin (more than [`DENSE`] sites: a
//! tight cluster in a crowd) is ordered along a Morton curve of its own
//! ([`in_cell_key`], ties by index) instead: its sites then form an
//! implicit octree that the k-NN descends rather than reading them all.
//! [`ring_span`] and [`ring_row`] list the cells of a Chebyshev ring around
//! a cell: the k-NN and the walks search the grid ring by ring.

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

/// A cell with more sites than this is ordered along its own Morton curve
/// (see [`in_cell_key`]); one with fewer, by site index.
pub const DENSE: u32 = 64;

/// Bits per axis of a site's place inside its cell ([`in_cell_key`]): the
/// cell cut into `2^KEY_BITS` sub-cells a side.
pub const KEY_BITS: u32 = 8;

/// The shift that takes a coordinate inside a cell (`0..cell_size`) to its
/// sub-cell: the least with `(cell_size - 1) >> shift < 2^KEY_BITS` (the
/// sub-cells a power of two wide, the last ones past the cell maybe empty;
/// 32-bit arithmetic only, as the grid kernels need no 64-bit integers).
#[inline]
pub fn key_shift(g: &GridParams) -> u32 {
    let mut shift = 0;
    while (sub_floor0(g.cell_size, 1) >> shift) >= (1 << KEY_BITS) {
        shift += 1;
    }
    shift
}

/// The sub-cell coordinate (`0..2^KEY_BITS`) of quantized coordinate `x`
/// in a cell starting at `lo` (`shift` from [`key_shift`]; a point past
/// the cell, in the grid's last cell, in the last sub-cell).
#[inline]
pub fn sub_coord(x: u32, lo: u32, shift: u32) -> u32 {
    (sub_floor0(x, lo) >> shift).min((1 << KEY_BITS) - 1)
}

/// The low [`KEY_BITS`] bits of `v`, spread three apart.
#[inline]
pub fn spread(v: u32) -> u32 {
    let mut x = v & ((1 << KEY_BITS) - 1);
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    x = (x | (x << 2)) & 0x0924_9249;
    x
}

/// The Morton key of sub-cell `s` (x in the lowest bit of each triple).
#[inline]
pub fn sub_key(s: [u32; 3]) -> u32 {
    spread(s[0]) | (spread(s[1]) << 1) | (spread(s[2]) << 2)
}

/// The key of quantized point `q` inside the cell whose lowest corner is
/// `lo`: the Morton key of its sub-cell (`shift` from [`key_shift`]).
#[inline]
pub fn in_cell_key(shift: u32, lo: [u32; 3], q: &QuantPoint) -> u32 {
    sub_key([sub_coord(q[0], lo[0], shift), sub_coord(q[1], lo[1], shift), sub_coord(q[2], lo[2], shift)])
}

/// The lowest corner of cell `c`, in quantized units.
#[inline]
pub fn cell_lo(g: &GridParams, c: [u32; 3]) -> [u32; 3] {
    [c[0] * g.cell_size, c[1] * g.cell_size, c[2] * g.cell_size]
}

/// The coordinates of the cell of linear index `i`.
#[inline]
pub fn cell_of_index(g: &GridParams, i: usize) -> [u32; 3] {
    let i = i as u32;
    [i % g.dim_x, (i / g.dim_x) % g.dim_y, i / (g.dim_x * g.dim_y)]
}

/// Thread `c`: sorts the sites of cell `c`: by index (insertion sort: a
/// cell holds a few sites), or, in a cell of more than [`DENSE`], by
/// [`in_cell_key`] and then index (heapsort: in place, `n log n`).
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
    if n > DENSE as usize {
        let lo = cell_lo(g, cell_of_index(g, c));
        heapsort_by_key((key_shift(g), lo), start, n, sorted);
        return;
    }
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

/// Whether `a` comes before `b` in a dense cell whose lowest corner is
/// `lo` (`shift` from [`key_shift`]).
#[inline]
fn before((shift, lo): (u32, [u32; 3]), a: &QuantPoint, b: &QuantPoint) -> bool {
    let (ka, kb) = (in_cell_key(shift, lo, a), in_cell_key(shift, lo, b));
    ka < kb || (ka == kb && a[3] < b[3])
}

/// Sorts `sorted[start..start + n]` by ([`in_cell_key`], index).
#[inline]
fn heapsort_by_key<S>(lo: (u32, [u32; 3]), start: usize, n: usize, sorted: &mut S)
where
    S: OutBuf<QuantPoint> + ?Sized,
{
    // A max-heap: each parent after both its children.
    let mut i = n / 2;
    while i > 0 {
        i -= 1;
        sift_down(lo, start, i, n, sorted);
    }
    let mut end = n;
    while end > 1 {
        end -= 1;
        let (top, last) = (sorted.read(start), sorted.read(start + end));
        sorted.write(start, last);
        sorted.write(start + end, top);
        sift_down(lo, start, 0, end, sorted);
    }
}

/// Moves the heap entry at `i` down to its place in `start..start + n`.
#[inline]
fn sift_down<S>(lo: (u32, [u32; 3]), start: usize, mut i: usize, n: usize, sorted: &mut S)
where
    S: OutBuf<QuantPoint> + ?Sized,
{
    let x = sorted.read(start + i);
    loop {
        let mut child = 2 * i + 1;
        if child >= n {
            break;
        }
        let mut c = sorted.read(start + child);
        if child + 1 < n {
            let right = sorted.read(start + child + 1);
            if before(lo, &c, &right) {
                child += 1;
                c = right;
            }
        }
        if !before(lo, &x, &c) {
            break;
        }
        sorted.write(start + i, c);
        i = child;
    }
    sorted.write(start + i, x);
}
