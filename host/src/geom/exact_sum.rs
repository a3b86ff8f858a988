//! Sums of `f64` that do not depend on the order of their terms, nor on
//! how the terms are split between processes: [`ExactSum`] holds the sum
//! exactly and rounds it once, to the nearest `f64` (ties to even).
//!
//! Every finite `f64` is an integer multiple of `2^-1074` below `2^1024`,
//! so a sum of them is a (long) integer in those units. It is held in
//! 32-bit digits, each in an `i64` so that up to `2^30` terms can be added
//! before the carries are passed on. Two sums merge by adding their
//! digits, which is also how the ranks of a run in parts add theirs: the
//! words of [`ExactSum::words`], summed by any integer all-reduce, are the
//! words of the sum of all terms. A run in parts thus reports the same
//! energies, and takes the same optimiser steps, as one process, to the
//! bit.

/// Bits per digit.
const DIGIT: u32 = 32;
/// Digits: a term's bits lie from `2^-1074` (bit 0) to below `2^1024`
/// (bit 2097), and two more digits hold the carries of up to `2^64` terms.
const DIGITS: usize = 68;
/// Terms added before the carries must be passed on (each adds less than
/// `2^32` to a digit; an `i64` holds `2^63`).
const PENDING: u32 = 1 << 30;

/// An exact sum of `f64` terms: see the module's documentation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExactSum {
    /// Digit `k` holds the sum's bits `32k .. 32k + 32`, in units of
    /// `2^-1074`; after [`Self::carry`], every digit but the last lies in
    /// `0 .. 2^32` and the last holds the sign.
    digits: [i64; DIGITS],
    /// Terms added since the carries were last passed on.
    pending: u32,
    /// Terms that were NaN, `+inf` and `-inf`.
    special: [i64; 3],
}

impl Default for ExactSum {
    fn default() -> Self {
        Self { digits: [0; DIGITS], pending: 0, special: [0; 3] }
    }
}

impl ExactSum {
    /// The number of [`Self::words`].
    pub const WORDS: usize = DIGITS + 3;

    /// The empty sum (0).
    pub fn new() -> Self {
        Self::default()
    }

    /// The exact sum of `terms`.
    pub fn of<'a>(terms: impl IntoIterator<Item = &'a f64>) -> Self {
        let mut sum = Self::new();
        for &x in terms {
            sum.add(x);
        }
        sum
    }

    /// Adds `x`.
    pub fn add(&mut self, x: f64) {
        if !x.is_finite() {
            self.special[if x.is_nan() {
                0
            } else if x > 0.0 {
                1
            } else {
                2
            }] += 1;
            return;
        }
        let bits = x.to_bits();
        let exponent = ((bits >> 52) & 0x7ff) as u32;
        let fraction = bits & ((1 << 52) - 1);
        // x = m * 2^(p - 1074), m an integer below 2^53.
        let (m, p) = match exponent {
            0 => (fraction, 0),
            e => (fraction | 1 << 52, e - 1),
        };
        if m == 0 {
            return;
        }
        let (k, shift) = ((p / DIGIT) as usize, p % DIGIT);
        let wide = (m as u128) << shift;
        let parts = [wide as u32 as i64, (wide >> 32) as u32 as i64, (wide >> 64) as i64];
        let negative = bits >> 63 == 1;
        for (d, part) in self.digits[k..k + 3].iter_mut().zip(parts) {
            *d += if negative { -part } else { part };
        }
        self.pending += 1;
        if self.pending == PENDING {
            self.carry();
        }
    }

    /// Adds every term of `other`.
    pub fn merge(&mut self, other: &ExactSum) {
        let mut other = other.clone();
        other.carry();
        self.carry();
        for (d, o) in self.digits.iter_mut().zip(other.digits) {
            *d += o;
        }
        for (s, o) in self.special.iter_mut().zip(other.special) {
            *s += o;
        }
        self.pending = 1;
        self.carry();
    }

    /// Passes each digit's carry on to the next: every digit but the last
    /// in `0 .. 2^32`.
    fn carry(&mut self) {
        for k in 0..DIGITS - 1 {
            let c = self.digits[k] >> DIGIT;
            self.digits[k] -= c << DIGIT;
            self.digits[k + 1] += c;
        }
        self.pending = 0;
    }

    /// The sum as words to add across processes (an integer all-reduce of
    /// these words, from every process's sum, gives the words of the sum
    /// of all their terms; up to `2^31` processes).
    pub fn words(&self) -> Vec<i64> {
        let mut s = self.clone();
        s.carry();
        s.digits.iter().chain(&s.special).copied().collect()
    }

    /// The sum whose [`Self::words`] (or the sum of several sums' words)
    /// these are; `None` if they are not [`Self::WORDS`] words.
    pub fn from_words(words: &[i64]) -> Option<Self> {
        if words.len() != Self::WORDS {
            return None;
        }
        let mut s = Self::new();
        s.digits.copy_from_slice(&words[..DIGITS]);
        s.special.copy_from_slice(&words[DIGITS..]);
        s.pending = 1;
        s.carry();
        Some(s)
    }

    /// The sum, rounded once to the nearest `f64` (ties to even): NaN if
    /// a term was NaN or both infinities were added, an infinity if one
    /// was (or the sum overflows), `+0.0` for an exact zero.
    pub fn value(&self) -> f64 {
        let [nan, plus, minus] = self.special;
        if nan > 0 || (plus > 0 && minus > 0) {
            return f64::NAN;
        } else if plus > 0 {
            return f64::INFINITY;
        } else if minus > 0 {
            return f64::NEG_INFINITY;
        }
        let mut s = self.clone();
        s.carry();
        let negative = s.digits[DIGITS - 1] < 0;
        if negative {
            for d in &mut s.digits {
                *d = -*d;
            }
            s.carry();
        }
        let Some(top) = s.digits.iter().rposition(|&d| d != 0) else {
            return 0.0;
        };
        // The top four digits (at least 97 bits of the sum once past the
        // first two), those below only as a sticky bit: one rounding.
        let low = top.saturating_sub(3);
        let mut window = 0u128;
        for k in (low..=top).rev() {
            window = window << DIGIT | s.digits[k] as u128;
        }
        if s.digits[..low].iter().any(|&d| d != 0) {
            window |= 1;
        }
        // Exact below 2^53 units (a subnormal's bits), else rounded here
        // once and scaled exactly (the result is normal).
        let magnitude = window as f64 * pow2(low as i32 * DIGIT as i32 - 1074);
        if negative {
            -magnitude
        } else {
            magnitude
        }
    }
}

/// `2^e` for `-1074 <= e <= 1023`.
fn pow2(e: i32) -> f64 {
    if e >= -1022 {
        f64::from_bits(((e + 1023) as u64) << 52)
    } else {
        f64::from_bits(1 << (e + 1074))
    }
}

impl Extend<f64> for ExactSum {
    fn extend<I: IntoIterator<Item = f64>>(&mut self, terms: I) {
        for x in terms {
            self.add(x);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `m * 2^e` with `m` below `2^53` and `e` in `-60..=10`, so that a few
    /// of them sum exactly in an `i128` counted in units of `2^-60`.
    fn term() -> impl Strategy<Value = (i64, i32)> {
        (-(1i64 << 53) + 1..1i64 << 53, -60i32..=10)
    }

    fn as_f64((m, e): (i64, i32)) -> f64 {
        m as f64 * pow2(e)
    }

    proptest! {
        #[test]
        fn rounds_the_exact_sum_once(terms in prop::collection::vec(term(), 0..24)) {
            let exact: i128 = terms.iter().map(|&(m, e)| (m as i128) << (e + 60)).sum();
            // An i128 converts to the nearest f64 (ties to even); 2^-60 scales exactly.
            let expected = exact as f64 * pow2(-60);
            let got = ExactSum::of(&terms.iter().map(|&t| as_f64(t)).collect::<Vec<_>>()).value();
            prop_assert_eq!(got.to_bits(), (expected + 0.0).to_bits(), "exact {}", exact);
        }

        #[test]
        fn the_same_bits_in_any_order_and_split(
            terms in prop::collection::vec(any::<f64>().prop_filter("finite", |x| x.is_finite()), 1..64),
            cut in 0usize..64,
            seed in any::<u64>(),
        ) {
            let whole = ExactSum::of(&terms);
            let mut shuffled = terms.clone();
            let mut state = seed;
            for i in (1..shuffled.len()).rev() {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                shuffled.swap(i, (state >> 33) as usize % (i + 1));
            }
            let cut = cut.min(terms.len());
            let (a, b) = (ExactSum::of(&shuffled[..cut]), ExactSum::of(&shuffled[cut..]));
            let mut merged = a.clone();
            merged.merge(&b);
            prop_assert_eq!(merged.value().to_bits(), whole.value().to_bits());
            let words: Vec<i64> = a.words().iter().zip(b.words()).map(|(x, y)| x + y).collect();
            prop_assert_eq!(ExactSum::from_words(&words).unwrap().value().to_bits(), whole.value().to_bits());
        }
    }

    #[test]
    fn cancellation_leaves_what_a_float_sum_loses() {
        let terms = [1e300, 1.0, -1e300, 1e-300, 2.5e-320];
        assert_eq!(ExactSum::of(&terms).value(), 1.0);
        assert_eq!(ExactSum::of(&[1e16, 1.0, 1.0, 1.0, -1e16]).value(), 3.0);
        assert_eq!(ExactSum::of(&[0.1, 0.2, -0.3]).value(), pow2(-55), "the three f64s' own sum");
        assert_eq!(ExactSum::of(&[0.1, -0.1]).value().to_bits(), 0.0f64.to_bits(), "an exact zero is +0");
        assert_eq!(ExactSum::new().value().to_bits(), 0.0f64.to_bits());
    }

    #[test]
    fn subnormals_and_the_largest_are_exact() {
        let tiny = f64::from_bits(1);
        assert_eq!(ExactSum::of(&[tiny, tiny, tiny]).value(), f64::from_bits(3));
        assert_eq!(ExactSum::of(&[f64::MIN_POSITIVE, -tiny]).value(), f64::MIN_POSITIVE - tiny);
        assert_eq!(ExactSum::of(&[f64::MAX, -f64::MAX, f64::MAX]).value(), f64::MAX);
        assert_eq!(ExactSum::of(&[f64::MAX, f64::MAX]).value(), f64::INFINITY, "overflow rounds to inf");
        assert_eq!(ExactSum::of(&[-f64::MAX, -f64::MAX]).value(), f64::NEG_INFINITY);
        // Ties to even at the last bit: 1 + 2^-53 is 1, 1 + 3 * 2^-53 is 1 + 2^-51.
        let half = pow2(-53);
        assert_eq!(ExactSum::of(&[1.0, half]).value(), 1.0);
        assert_eq!(ExactSum::of(&[1.0, half, half, half]).value(), 1.0 + 4.0 * half);
        // Just above a tie rounds up, however far below the extra bit lies.
        assert_eq!(ExactSum::of(&[1.0, half, 1e-300]).value(), 1.0 + 2.0 * half);
    }

    #[test]
    fn infinities_and_nan() {
        assert!(ExactSum::of(&[1.0, f64::NAN]).value().is_nan());
        assert!(ExactSum::of(&[f64::INFINITY, f64::NEG_INFINITY]).value().is_nan());
        assert_eq!(ExactSum::of(&[f64::INFINITY, -1e308, -1e308]).value(), f64::INFINITY);
        assert_eq!(ExactSum::of(&[f64::NEG_INFINITY, 5.0]).value(), f64::NEG_INFINITY);
    }

    #[test]
    fn many_terms_carry() {
        // More terms than one digit holds between carries.
        let mut s = ExactSum::new();
        let x = f64::from_bits(0x3fef_ffff_ffff_ffff); // just below 1: every bit set
        let n = PENDING as u64 + 12345;
        for _ in 0..n {
            s.add(x);
        }
        let exact = (n as u128) * ((1u128 << 53) - 1); // in units of 2^-53
        assert_eq!(s.value(), exact as f64 * pow2(-53));
        let mut products = ExactSum::new();
        products.extend([1.0f64, 2.0, 3.0].iter().zip([4.0, -5.0, 6.0]).map(|(x, y)| x * y));
        assert_eq!(products.value(), 12.0);
    }
}
