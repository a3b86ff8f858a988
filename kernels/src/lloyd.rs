//! Lloyd's iteration: every site moves to the centroid of its clipped cell,
//! and its quantized copy (for the next k-NN) follows, so that a loop of
//! iterations needs nothing from the host.

use crate::abi::{lloyd_stat, LloydParams, QuantPoint, ACCUM_PER_SITE, QUANT_MAX};
use crate::buffers::{AtomicSums, OutBuf};

/// `x` quantized: `round((x - origin) * scale)` within `[0, QUANT_MAX]`.
#[inline]
fn quantize(x: f32, origin: f32, scale: f32) -> u32 {
    let q = (x - origin) * scale + 0.5;
    if q <= 0.0 {
        0
    } else if q >= QUANT_MAX as f32 {
        QUANT_MAX
    } else {
        q as u32
    }
}

/// Thread `i`: moves site `i` to its cell's centroid (first moment over
/// volume, relative to the site) unless the cell is empty — then it stays
/// and is counted. Adds the cell's energy to the iteration's statistics;
/// thread 0 also records the first and second passes' unfinished counts
/// (`unfinished[0]`, `still[0]`).
#[inline]
pub fn move_site<S, Q, A>(
    i: usize,
    p: &LloydParams,
    sums: &[i64],
    unfinished: &[u32],
    still: &[u32],
    sites: &mut S,
    quant: &mut Q,
    stats: &mut A,
) where
    S: OutBuf<[f32; 4]> + ?Sized,
    Q: OutBuf<QuantPoint> + ?Sized,
    A: AtomicSums,
{
    let base = p.iteration as usize * lloyd_stat::COUNT;
    if i == 0 {
        stats.add(base + lloyd_stat::UNFINISHED, unfinished[0] as i64);
        stats.add(base + lloyd_stat::STILL, still[0] as i64);
    }
    if i >= p.n_sites as usize {
        return;
    }
    let b = i * ACCUM_PER_SITE;
    // No sub-slices: SPIR-V has no pointers to slices of a buffer.
    let s = [sums[b], sums[b + 1], sums[b + 2], sums[b + 3], sums[b + 4]];
    stats.add(base + lloyd_stat::ENERGY, s[4]);
    if s[0] <= 0 {
        stats.add(base + lloyd_stat::EMPTY, 1);
        return;
    }
    // The fixed-point scale cancels in first / volume.
    let v = s[0] as f32;
    let mut x = sites.read(i);
    x[0] += s[1] as f32 / v;
    x[1] += s[2] as f32 / v;
    x[2] += s[3] as f32 / v;
    sites.write(i, x);
    quant.write(
        i,
        [
            quantize(x[0], p.quant_origin_x, p.quant_scale),
            quantize(x[1], p.quant_origin_y, p.quant_scale),
            quantize(x[2], p.quant_origin_z, p.quant_scale),
            i as u32,
        ],
    );
}
