//! Lloyd's iteration: every site moves to the centroid of its clipped cell,
//! and its quantized copy (for the next k-NN) follows, so that a loop of
//! iterations needs nothing from the host.

use crate::abi::{lloyd_stat, LloydParams, QuantPoint, SplitPoint, ACCUM_PER_SITE, QUANT_MAX};
use crate::buffers::{AtomicSums, OutBuf};

/// The coordinate `hi + lo` quantized: `round((hi + lo - origin) * scale)`
/// within `[0, QUANT_MAX]`, to within one step (`scale` is a power of two,
/// so the scaled f32 values are exact, and the parts are added where they
/// are small).
#[inline]
fn quantize(hi: f32, lo: f32, origin: f32, scale: f32) -> u32 {
    // hi - origin = d + e exactly (two-sum).
    let d = hi - origin;
    let z = d - hi;
    let e = (hi - (d - z)) - (origin + z);
    let t = d * scale;
    if t <= 0.0 {
        return 0;
    }
    if t >= QUANT_MAX as f32 {
        return QUANT_MAX;
    }
    let whole = t as u32;
    let rest = (t - whole as f32) + (e + lo) * scale + 0.5;
    let q = whole as i64 + if rest < 0.0 { -1 } else { rest as i64 };
    if q <= 0 {
        0
    } else if q >= QUANT_MAX as i64 {
        QUANT_MAX
    } else {
        q as u32
    }
}

/// `hi + lo + step`, as a new `(hi, lo)` pair: `hi + step` exactly (two-sum),
/// its error added to `lo`, then the pair renormalised.
#[inline]
fn moved(hi: f32, lo: f32, step: f32) -> (f32, f32) {
    let s = hi + step;
    let z = s - hi;
    let e = (hi - (s - z)) + (step - z);
    let lo = lo + e;
    let h = s + lo;
    (h, lo - (h - s))
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
    S: OutBuf<SplitPoint> + ?Sized,
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
    let step = [s[1] as f32 / v, s[2] as f32 / v, s[3] as f32 / v];
    let mut a = 0;
    while a < 3 {
        (x.hi[a], x.lo[a]) = moved(x.hi[a], x.lo[a], step[a]);
        a += 1;
    }
    sites.write(i, x);
    quant.write(
        i,
        [
            quantize(x.hi[0], x.lo[0], p.quant_origin_x, p.quant_scale),
            quantize(x.hi[1], x.lo[1], p.quant_origin_y, p.quant_scale),
            quantize(x.hi[2], x.lo[2], p.quant_origin_z, p.quant_scale),
            i as u32,
        ],
    );
}
