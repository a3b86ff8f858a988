//! k nearest neighbours (paper section 5): brute force and grid ring search.
//!
//! Distances are squared Euclidean distances between quantized points,
//! computed exactly in 64-bit integers, and ties break by site index. So the
//! answer is one well-defined list, the same on every backend and for both
//! methods. Each query keeps its sorted candidate list directly in its slots
//! of the output buffers (`k` slots from `base`), so `k` has no fixed cap.

use crate::abi::{GridParams, KnnParams, QuantPoint, NO_SITE};
use crate::buffers::OutBuf;
use crate::grid::{
    cell_coords, cell_index, cell_lo, diff, in_cell_key, key_shift, ring_row, ring_span, sub_key, DENSE, KEY_BITS,
};

/// `max(a - b, 0)` in 64 bits.
#[inline]
#[allow(clippy::implicit_saturating_sub)]
fn sub_floor0_u64(a: u64, b: u64) -> u64 {
    if a > b {
        a - b
    } else {
        0
    }
}

/// Exact squared distance between quantized points.
#[inline]
pub fn dist2(a: [u32; 3], b: &QuantPoint) -> u64 {
    let dx = diff(a[0], b[0]) as u64;
    let dy = diff(a[1], b[1]) as u64;
    let dz = diff(a[2], b[2]) as u64;
    dx * dx + dy * dy + dz * dz
}

/// A query's sorted list of the best `k` candidates, kept in `nbr`/`d2` at
/// `base..base + k`, ordered by `(distance, index)`; the current k-th
/// entry is mirrored in locals so that most candidates are rejected
/// without touching memory.
struct Best {
    k: u32,
    base: usize,
    found: u32,
    worst_d: u64,
    worst_i: u32,
}

impl Best {
    #[inline]
    fn new(k: u32, base: usize) -> Self {
        Self { k, base, found: 0, worst_d: u64::MAX, worst_i: u32::MAX }
    }

    #[inline]
    fn offer<N, D>(&mut self, d: u64, idx: u32, nbr: &mut N, d2: &mut D)
    where
        N: OutBuf<u32> + ?Sized,
        D: OutBuf<u64> + ?Sized,
    {
        if self.found == self.k && (d > self.worst_d || (d == self.worst_d && idx > self.worst_i)) {
            return;
        }
        let base = self.base;
        let mut pos = self.found as usize;
        if self.found == self.k {
            pos -= 1;
        } else {
            self.found += 1;
        }
        // Shift larger entries up one slot, then insert.
        while pos > 0 {
            let pd = d2.read(base + pos - 1);
            let pi = nbr.read(base + pos - 1);
            if pd < d || (pd == d && pi < idx) {
                break;
            }
            d2.write(base + pos, pd);
            nbr.write(base + pos, pi);
            pos -= 1;
        }
        d2.write(base + pos, d);
        nbr.write(base + pos, idx);
        if self.found == self.k {
            let last = base + self.k as usize - 1;
            self.worst_d = d2.read(last);
            self.worst_i = nbr.read(last);
        }
    }
}

/// Fills the slots a query could not fill (only when `k` exceeds the sites).
#[inline]
fn pad<N, D>(found: u32, k: u32, base: usize, nbr: &mut N, d2: &mut D)
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let mut j = found as usize;
    while j < k as usize {
        nbr.write(base + j, NO_SITE);
        d2.write(base + j, u64::MAX);
        j += 1;
    }
}

/// Brute force: the `k` nearest of all sites to `q`, skipping site `exclude`.
#[inline]
pub fn brute_query<N, D>(
    sites: &[QuantPoint],
    n_sites: u32,
    q: [u32; 3],
    exclude: u32,
    k: u32,
    base: usize,
    nbr: &mut N,
    d2: &mut D,
) where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let mut best = Best::new(k, base);
    let mut j = 0usize;
    while j < n_sites as usize {
        let s = sites[j];
        if s[3] != exclude {
            best.offer(dist2(q, &s), s[3], nbr, d2);
        }
        j += 1;
    }
    pad(best.found, k, base, nbr, d2);
}

/// The `k` nearest to `q` of the candidate sites `cands` (indices into
/// `sites`, in any order), skipping site `exclude`, sorted as
/// [`grid_query`] sorts (distance, then index) at `base..base + k`, the
/// slots past the candidates padded as there. Returns how many were
/// found. Where every site nearer than some distance is a candidate (a
/// list kept from the last frame, see the host's trajectories), the list
/// up to that distance is the one [`grid_query`] gives, entry for entry.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn candidate_query<N, D>(
    sites: &[QuantPoint],
    cands: &[u32],
    q: [u32; 3],
    exclude: u32,
    k: u32,
    base: usize,
    nbr: &mut N,
    d2: &mut D,
) -> u32
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let mut best = Best::new(k, base);
    let mut j = 0usize;
    while j < cands.len() {
        let c = cands[j];
        if c != exclude && c != NO_SITE {
            best.offer(dist2(q, &sites[c as usize]), c, nbr, d2);
        }
        j += 1;
    }
    pad(best.found, k, base, nbr, d2);
    best.found
}

/// The distance from `q` to the nearest point outside the box of cells
/// within Chebyshev ring `r` of cell `c`, or `u64::MAX` when that box covers
/// the whole grid. Every site not yet visited is at least this far.
#[inline]
fn ring_gap(g: &GridParams, q: [u32; 3], c: [u32; 3], r: u32) -> u64 {
    let dims = [g.dim_x, g.dim_y, g.dim_z];
    let cs = g.cell_size as u64;
    let mut gap = u64::MAX;
    let mut a = 0;
    while a < 3 {
        if c[a] > r {
            let lo = q[a] as u64 - (c[a] - r) as u64 * cs;
            gap = gap.min(lo);
        }
        if c[a] + r < dims[a] - 1 {
            let hi = (c[a] + r + 1) as u64 * cs - q[a] as u64;
            gap = gap.min(hi);
        }
        a += 1;
    }
    gap
}

/// The squared distance from `q` to the box of grid cell `c` (0 inside).
#[inline]
fn cell_dist2(g: &GridParams, q: [u32; 3], c: [u32; 3]) -> u64 {
    let cs = g.cell_size as u64;
    let mut d2 = 0u64;
    let mut a = 0;
    while a < 3 {
        let lo = c[a] as u64 * cs;
        let hi = lo + cs;
        let x = q[a] as u64;
        let gap = if x < lo { lo - x } else { sub_floor0_u64(x, hi) };
        d2 += gap * gap;
        a += 1;
    }
    d2
}

/// What a grid query searches: the grid, its cells' sites, the query
/// point and the site it skips (its own, or `NO_SITE`).
struct Search<'a> {
    g: &'a GridParams,
    cell_start: &'a [u32],
    cell_count: &'a [u32],
    sorted: &'a [QuantPoint],
    q: [u32; 3],
    exclude: u32,
}

/// Offers every site of grid cell `c`, unless the list is full and the
/// whole cell is farther than its worst entry.
#[inline(always)]
fn visit_cell<N, D>(s: &Search, c: [u32; 3], best: &mut Best, nbr: &mut N, d2: &mut D)
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    if best.found == best.k && cell_dist2(s.g, s.q, c) > best.worst_d {
        return;
    }
    let cell = cell_index(s.g, c);
    let start = s.cell_start[cell] as usize;
    let end = start + s.cell_count[cell] as usize;
    if s.cell_count[cell] > DENSE {
        visit_dense(s, c, start, end, best, nbr, d2);
        return;
    }
    offer_range(s, start, end, best, nbr, d2);
}

/// Offers the sites `sorted[start..end]`.
#[inline(always)]
fn offer_range<N, D>(s: &Search, start: usize, end: usize, best: &mut Best, nbr: &mut N, d2: &mut D)
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let mut j = start;
    while j < end {
        let site = s.sorted[j];
        if site[3] != s.exclude {
            best.offer(dist2(s.q, &site), site[3], nbr, d2);
        }
        j += 1;
    }
}

/// A dense cell's node holding this many sites or fewer is read whole.
const LEAF: u32 = 64;

/// Room for the nodes waiting in a dense cell's descent: at most 7 a level
/// below the root's 8.
const NODES: usize = 7 * KEY_BITS as usize + 8;

/// The squared distance from `q` to the box of sub-cells `from..from +
/// side` (per axis) of the cell at `lo`, sub-cells `1 << shift` wide
/// ([`crate::grid::key_shift`]).
#[inline]
fn node_dist2(q: [u32; 3], lo: [u32; 3], shift: u32, from: [u32; 3], side: u32) -> u64 {
    let mut d2 = 0u64;
    let mut a = 0;
    while a < 3 {
        let low = lo[a] as u64 + ((from[a] as u64) << shift);
        let high = lo[a] as u64 + (((from[a] + side) as u64) << shift);
        let x = q[a] as u64;
        let gap = if x < low { low - x } else { sub_floor0_u64(x, high) };
        d2 += gap * gap;
        a += 1;
    }
    d2
}

/// The first place in `sorted[from..to]` (a dense cell at `lo`, in key
/// order; `shift` from [`crate::grid::key_shift`]) whose key is at least
/// `key`.
#[inline]
fn first_at_least(s: &Search, (shift, lo): (u32, [u32; 3]), mut from: usize, mut to: usize, key: u32) -> usize {
    while from < to {
        let mid = from + (to - from) / 2;
        if in_cell_key(shift, lo, &s.sorted[mid]) < key {
            from = mid + 1;
        } else {
            to = mid;
        }
    }
    from
}

/// The first sub-cell of child `o` of a node whose first sub-cell is
/// `from` (children `half` sub-cells wide): bit `o & 1` of x, `o >> 1 & 1`
/// of y, `o >> 2` of z, as the key orders them.
#[inline]
fn child_first(from: [u32; 3], o: u32, half: u32) -> [u32; 3] {
    [from[0] + (o & 1) * half, from[1] + ((o >> 1) & 1) * half, from[2] + (o >> 2) * half]
}

/// Offers the sites of dense cell `c` (`sorted[start..end]`, in key
/// order): down the implicit octree of its sub-cells, nearest child
/// first, skipping a node farther than the list's worst entry once the
/// list is full. Offers the sites a full scan would that could enter the
/// list: the same list. (Kept out of line, and cold, on the CPU: the plain cells
/// loop stays small.)
#[cfg_attr(not(target_arch = "spirv"), inline(never), cold)]
fn visit_dense<N, D>(s: &Search, c: [u32; 3], start: usize, end: usize, best: &mut Best, nbr: &mut N, d2: &mut D)
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let (lo, shift) = (cell_lo(s.g, c), key_shift(s.g));
    // A node: its sites' range, its level and its first sub-cell (8 bits
    // an axis, the level above them).
    let mut stack = [[0u32; 3]; NODES];
    stack[0] = [start as u32, end as u32, 0];
    let mut top = 1usize;
    while top > 0 {
        top -= 1;
        let [a, b, packed] = stack[top];
        let level = packed >> 24;
        let from = [packed & 0xff, (packed >> 8) & 0xff, (packed >> 16) & 0xff];
        let side = 1u32 << (KEY_BITS - level);
        if best.found == best.k && node_dist2(s.q, lo, shift, from, side) > best.worst_d {
            continue;
        }
        if b - a <= LEAF || level == KEY_BITS {
            offer_range(s, a as usize, b as usize, best, nbr, d2);
            continue;
        }
        // The children's ranges, in key order (see `child_first`).
        let half = side / 2;
        let mut bounds = [0u32; 9];
        bounds[0] = a;
        bounds[8] = b;
        let mut o = 1;
        while o < 8 {
            let first = child_first(from, o, half);
            let at = first_at_least(s, (shift, lo), bounds[o as usize - 1] as usize, b as usize, sub_key(first));
            bounds[o as usize] = at as u32;
            o += 1;
        }
        // The non-empty children within reach, farthest first on the
        // stack (so the nearest is taken next).
        let mut order = [(0u64, 0u32); 8];
        let mut n = 0usize;
        let mut o = 0;
        while o < 8 {
            if bounds[o as usize] < bounds[o as usize + 1] {
                let first = child_first(from, o, half);
                let d = node_dist2(s.q, lo, shift, first, half);
                if best.found < best.k || d <= best.worst_d {
                    let mut j = n;
                    while j > 0 && order[j - 1].0 < d {
                        order[j] = order[j - 1];
                        j -= 1;
                    }
                    order[j] = (d, o);
                    n += 1;
                }
            }
            o += 1;
        }
        let mut j = 0;
        while j < n {
            let o = order[j].1;
            let first = child_first(from, o, half);
            let packed = ((level + 1) << 24) | (first[2] << 16) | (first[1] << 8) | first[0];
            stack[top] = [bounds[o as usize], bounds[o as usize + 1], packed];
            top += 1;
            j += 1;
        }
    }
}

/// The first ring's 26 offsets, faces first, then edges, then corners, as
/// `x + 3 y + 9 z` with digits 0, 1, 2 for -1, 0, +1: 5 bits each, 12 to a
/// word. A table, so a query walks 26 offsets, not 3 passes over 27.
const FIRST_RING: [u64; 3] = first_ring();

const fn first_ring() -> [u64; 3] {
    let mut words = [0u64; 3];
    let mut n = 0;
    let mut axes = 1;
    while axes <= 3 {
        let mut o = 0u64;
        while o < 27 {
            let off = (o % 3 != 1) as u32 + ((o / 3) % 3 != 1) as u32 + (o / 9 != 1) as u32;
            if off == axes {
                words[n / 12] |= o << (5 * (n % 12));
                n += 1;
            }
            o += 1;
        }
        axes += 1;
    }
    words
}

/// Visits the 26 cells around cell `c`, faces first, then edges, then
/// corners: nearer candidates come first, so the list's worst entry
/// tightens early and later candidates are mostly rejected or land near the
/// list's end (short shifts).
#[inline]
fn visit_first_ring<N, D>(s: &Search, c: [u32; 3], best: &mut Best, nbr: &mut N, d2: &mut D)
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let mut i = 0u32;
    while i < 26 {
        let word = if i < 12 {
            FIRST_RING[0]
        } else if i < 24 {
            FIRST_RING[1]
        } else {
            FIRST_RING[2]
        };
        let o = ((word >> (5 * (i % 12))) & 31) as u32;
        // Digits 0, 1, 2: the neighbour is at `c + digit - 1`.
        let x = c[0] + o % 3;
        let y = c[1] + (o / 3) % 3;
        let z = c[2] + o / 9;
        if x >= 1 && y >= 1 && z >= 1 && x <= s.g.dim_x && y <= s.g.dim_y && z <= s.g.dim_z {
            visit_cell(s, [x - 1, y - 1, z - 1], best, nbr, d2);
        }
        i += 1;
    }
}

/// Visits the cells of Chebyshev ring `r` around cell `c`.
#[inline]
fn visit_ring<N, D>(s: &Search, c: [u32; 3], r: u32, best: &mut Best, nbr: &mut N, d2: &mut D)
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let (z0, z1) = ring_span(c[2], r, s.g.dim_z);
    let (y0, y1) = ring_span(c[1], r, s.g.dim_y);
    let mut z = z0;
    while z <= z1 {
        let mut y = y0;
        while y <= y1 {
            let (first, last, step) = ring_row(s.g, c, r, y, z);
            let mut x = first;
            while x <= last {
                visit_cell(s, [x, y, z], best, nbr, d2);
                x += step;
            }
            y += 1;
        }
        z += 1;
    }
}

/// Grid ring search: visits the cells ring by ring around the query's cell
/// and stops once the k-th candidate is strictly nearer than anything
/// outside the rings visited so far (so ties are resolved too).
#[inline]
pub fn grid_query<N, D>(
    g: &GridParams,
    cell_start: &[u32],
    cell_count: &[u32],
    sorted: &[QuantPoint],
    q: [u32; 3],
    exclude: u32,
    k: u32,
    base: usize,
    nbr: &mut N,
    d2: &mut D,
) where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    let available = if exclude < g.n_sites { g.n_sites - 1 } else { g.n_sites };
    let c = cell_coords(g, q);
    let search = Search { g, cell_start, cell_count, sorted, q, exclude };
    let mut best = Best::new(k, base);
    let mut r = 0u32;
    loop {
        if r == 1 {
            visit_first_ring(&search, c, &mut best, nbr, d2);
        } else {
            visit_ring(&search, c, r, &mut best, nbr, d2);
        }
        let gap = ring_gap(g, q, c, r);
        if gap == u64::MAX || best.found == available {
            break;
        }
        if best.found == k && best.worst_d < gap * gap {
            break;
        }
        r += 1;
    }
    pad(best.found, k, base, nbr, d2);
}

/// Thread `i` of a grid k-NN job. A site job (`exclude_self`) takes its
/// queries in grid order — thread `i` answers `sorted[i]`, writing the
/// slots of that site's own index — so neighbouring threads search the same
/// cells; a point job, or a site job in parts (`in_order`), answers query
/// `query_base + i` at slot `i`. Returns the slot (`usize::MAX` past the
/// queries); with [`KnnParams::local_lists`] the list is in the first `k`
/// slots of the buffers, for the caller to store at that slot.
#[inline]
pub fn grid_thread<N, D>(
    i: usize,
    p: &KnnParams,
    queries: &[QuantPoint],
    cell_start: &[u32],
    cell_count: &[u32],
    sorted: &[QuantPoint],
    nbr: &mut N,
    d2: &mut D,
) -> usize
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    if i >= p.n_queries as usize {
        return usize::MAX;
    }
    let (q, exclude, slot) = if p.exclude_self != 0 && p.in_order == 0 {
        let q = sorted[i];
        (q, q[3], q[3] as usize)
    } else {
        let q = queries[p.query_base as usize + i];
        (q, if p.exclude_self != 0 { q[3] } else { NO_SITE }, i)
    };
    let base = if p.local_lists != 0 { 0 } else { slot * p.k as usize };
    grid_query(&p.grid, cell_start, cell_count, sorted, [q[0], q[1], q[2]], exclude, p.k, base, nbr, d2);
    slot
}

/// Thread `i` of a brute-force k-NN job: the neighbours of query `i`, at
/// slot `i` (returned, as by [`grid_thread`]).
#[inline]
pub fn brute_thread<N, D>(
    i: usize,
    p: &KnnParams,
    queries: &[QuantPoint],
    sites: &[QuantPoint],
    nbr: &mut N,
    d2: &mut D,
) -> usize
where
    N: OutBuf<u32> + ?Sized,
    D: OutBuf<u64> + ?Sized,
{
    if i >= p.n_queries as usize {
        return usize::MAX;
    }
    let q = queries[p.query_base as usize + i];
    let exclude = if p.exclude_self != 0 { q[3] } else { NO_SITE };
    let base = if p.local_lists != 0 { 0 } else { i * p.k as usize };
    brute_query(sites, p.grid.n_sites, [q[0], q[1], q[2]], exclude, p.k, base, nbr, d2);
    i
}
