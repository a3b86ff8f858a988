//! Exclusive prefix sum in three short kernels: each thread scans one block
//! of [`SCAN_BLOCK`] values, one thread scans the block totals, each thread
//! adds its block's offset. Sizes here are small (a grid has about n/5
//! cells), so this simple form is far from the bottleneck.

use crate::buffers::OutBuf;

/// Values per block (and per thread) of the prefix sum.
pub const SCAN_BLOCK: usize = 256;

/// Number of blocks for `n` values.
#[inline]
pub fn block_count(n: usize) -> usize {
    n.div_ceil(SCAN_BLOCK)
}

/// Thread `b`: exclusive scan of block `b` of `values` into `out`; the block's
/// total goes to `block_sums[b]`.
#[inline]
pub fn scan_block<O, B>(b: usize, n: usize, values: &[u32], out: &mut O, block_sums: &mut B)
where
    O: OutBuf<u32> + ?Sized,
    B: OutBuf<u32> + ?Sized,
{
    let lo = b * SCAN_BLOCK;
    if lo >= n {
        return;
    }
    let hi = if lo + SCAN_BLOCK < n { lo + SCAN_BLOCK } else { n };
    let mut acc = 0u32;
    let mut i = lo;
    while i < hi {
        out.write(i, acc);
        acc += values[i];
        i += 1;
    }
    block_sums.write(b, acc);
}

/// One thread: exclusive scan of the `n_blocks` block totals, in place.
#[inline]
pub fn scan_block_sums<B>(n_blocks: usize, block_sums: &mut B)
where
    B: OutBuf<u32> + ?Sized,
{
    let mut acc = 0u32;
    let mut b = 0;
    while b < n_blocks {
        let v = block_sums.read(b);
        block_sums.write(b, acc);
        acc += v;
        b += 1;
    }
}

/// Thread `b`: adds the scanned total of the blocks before `b` to block `b`.
#[inline]
pub fn add_block_offset<O>(b: usize, n: usize, out: &mut O, block_offsets: &[u32])
where
    O: OutBuf<u32> + ?Sized,
{
    let lo = b * SCAN_BLOCK;
    if lo >= n || b == 0 {
        return;
    }
    let hi = if lo + SCAN_BLOCK < n { lo + SCAN_BLOCK } else { n };
    let offset = block_offsets[b];
    let mut i = lo;
    while i < hi {
        out.write(i, out.read(i) + offset);
        i += 1;
    }
}
