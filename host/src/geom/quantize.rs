//! Maps points to the integer frame the kernels compare distances in.
//!
//! The frame is the bounding box of all points, scaled uniformly by a power
//! of two so that its longest side spans at least half of `[0, QUANT_MAX]`
//! (2^29 to 2^30 steps). Squared distances between
//! quantized points are exact in 64-bit integers, which makes every
//! neighbour order identical on every backend. Points closer than one step
//! (at most 2e-9 of the box) compare as equally distant; ties break by index.

use crate::error::{Error, Result};
use cvd_kernels::abi::{QuantPoint, QUANT_MAX};

/// A uniform scaling of a bounding box onto the quantized frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quantizer {
    origin: [f64; 3],
    scale: f64,
}

impl Quantizer {
    /// The frame covering every point of all the given sets. Rejects
    /// non-finite coordinates, naming the set and the point.
    pub fn fit(sets: &[(&str, &[[f64; 3]])]) -> Result<Self> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (name, points) in sets {
            for (i, p) in points.iter().enumerate() {
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(Error::InvalidInput(format!("{name} {i} has a non-finite coordinate: {p:?}")));
                }
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
        }
        if lo[0] > hi[0] {
            return Ok(Self { origin: [0.0; 3], scale: 1.0 });
        }
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        // A power-of-two scale keeps points on a dyadic lattice exactly on
        // the integer lattice, so their distance ties stay ties.
        let scale = if extent > 0.0 { (QUANT_MAX as f64 / extent).log2().floor().exp2() } else { 1.0 };
        Ok(Self { origin: lo, scale })
    }

    /// The point quantized to 0.
    pub fn origin(&self) -> [f64; 3] {
        self.origin
    }

    /// Quantized units per unit of the points' coordinates.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The quantized point for `p`, tagged with `index`.
    pub fn quantize(&self, p: [f64; 3], index: u32) -> QuantPoint {
        let q = |a: usize| ((p[a] - self.origin[a]) * self.scale).round().clamp(0.0, QUANT_MAX as f64) as u32;
        [q(0), q(1), q(2), index]
    }

    /// Quantizes a whole set, tagging each point with its position.
    pub fn quantize_all(&self, points: &[[f64; 3]]) -> Vec<QuantPoint> {
        points.iter().enumerate().map(|(i, &p)| self.quantize(p, i as u32)).collect()
    }

    /// A quantized squared distance in the points' own units.
    pub fn world_dist2(&self, d2: u64) -> f64 {
        d2 as f64 / (self.scale * self.scale)
    }
}
