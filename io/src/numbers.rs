//! Numbers in the text files, fast: Rust's `{}` and `{:e}` of an `f64`
//! (the shortest decimal that reads back as the same number, in the same
//! notation), from zmij's shortest digits. Rust's own formatting of floats
//! was about a sixth of a run's time where the faces are written. The one
//! difference: where two shortest decimals lie exactly as near the number
//! (2^-25 = 2.98023223876953125e-8 has 17 digits either way), zmij takes
//! the even last digit (…312) and Rust the other (…313); both read back
//! as the number. Such ties are rare beside powers of two: 1 number in
//! about 14 000 of the tests' random ones.

use std::fmt;

/// `x` as `format!("{x}")` writes it: the shortest decimal, never in
/// exponent notation (`0.0000001`, `1000000000000000000000`, `-0`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Dec(pub f64);

/// `x` as `format!("{x:e}")` writes it: the shortest decimal in exponent
/// notation (`1e-7`, `1.5e3`, `0e0`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Exp(pub f64);

/// A finite number's shortest decimal digits (no leading or trailing
/// zeros; none for zero) and the place of the point: `0.DIGITS × 10^point`.
struct Shortest {
    negative: bool,
    digits: [u8; 32],
    len: usize,
    point: i32,
}

impl Shortest {
    /// From zmij's `text` of a number's magnitude (in either notation),
    /// and its sign.
    fn of(text: &[u8], negative: bool) -> Self {
        let (mantissa, exponent) = match text.iter().position(|&c| c == b'e') {
            Some(e) => (&text[..e], parse_exponent(&text[e + 1..])),
            None => (text, 0),
        };
        let mut out = Self { negative, digits: [0; 32], len: 0, point: 0 };
        let mut before_point = 0;
        let mut seen_point = false;
        for &c in mantissa {
            match c {
                b'.' => seen_point = true,
                b'0' if out.len == 0 => {
                    // A leading zero: the point moves left past it.
                    if seen_point {
                        out.point -= 1;
                    }
                }
                _ => {
                    if !seen_point {
                        before_point += 1;
                    }
                    out.digits[out.len] = c;
                    out.len += 1;
                }
            }
        }
        while out.len > 0 && out.digits[out.len - 1] == b'0' {
            out.len -= 1;
        }
        out.point += before_point + exponent;
        out
    }

    fn digits(&self) -> &str {
        std::str::from_utf8(&self.digits[..self.len]).unwrap_or("")
    }
}

fn parse_exponent(text: &[u8]) -> i32 {
    let (negative, digits) = match text.first() {
        Some(b'-') => (true, &text[1..]),
        Some(b'+') => (false, &text[1..]),
        _ => (false, text),
    };
    let value = digits.iter().fold(0i32, |v, &d| v * 10 + i32::from(d - b'0'));
    if negative {
        -value
    } else {
        value
    }
}

/// NaN and the infinities, as Rust writes them.
fn special(x: f64, f: &mut fmt::Formatter<'_>) -> Option<fmt::Result> {
    match () {
        _ if x.is_nan() => Some(f.write_str("NaN")),
        _ if x.is_infinite() => Some(f.write_str(if x < 0.0 { "-inf" } else { "inf" })),
        _ => None,
    }
}

fn zeros(f: &mut fmt::Formatter<'_>, mut n: usize) -> fmt::Result {
    const ZEROS: &str = "00000000000000000000000000000000";
    while n > 0 {
        let k = n.min(ZEROS.len());
        f.write_str(&ZEROS[..k])?;
        n -= k;
    }
    Ok(())
}

impl fmt::Display for Dec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(r) = special(self.0, f) {
            return r;
        }
        let mut buffer = zmij::Buffer::new();
        let text = buffer.format_finite(self.0.abs());
        if !text.contains('e') {
            // zmij's plain notation is Rust's, but for an integer's ".0".
            let text = text.strip_suffix(".0").unwrap_or(text);
            if self.0.is_sign_negative() {
                f.write_str("-")?;
            }
            return f.write_str(text);
        }
        let s = Shortest::of(text.as_bytes(), self.0.is_sign_negative());
        if s.negative {
            f.write_str("-")?;
        }
        let (digits, point) = (s.digits(), s.point);
        if digits.is_empty() {
            return f.write_str("0");
        }
        let len = digits.len() as i32;
        if point <= 0 {
            f.write_str("0.")?;
            zeros(f, (-point) as usize)?;
            f.write_str(digits)
        } else if point < len {
            f.write_str(&digits[..point as usize])?;
            f.write_str(".")?;
            f.write_str(&digits[point as usize..])
        } else {
            f.write_str(digits)?;
            zeros(f, (point - len) as usize)
        }
    }
}

impl fmt::Display for Exp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(r) = special(self.0, f) {
            return r;
        }
        let mut buffer = zmij::Buffer::new();
        let text = buffer.format_finite(self.0.abs()).as_bytes();
        // At most a sign, 17 digits, a point, "e-" and 3 digits.
        let mut out = [0u8; 32];
        let mut n = 0;
        let mut put = |bytes: &[u8]| {
            out[n..n + bytes.len()].copy_from_slice(bytes);
            n += bytes.len();
        };
        if self.0.is_sign_negative() {
            put(b"-");
        }
        let exponent = match text.iter().position(|&c| c == b'e') {
            // zmij's exponent notation is Rust's, but for a '+'.
            Some(e) => {
                put(&text[..=e]);
                put(text[e + 1..].strip_prefix(b"+").unwrap_or(&text[e + 1..]));
                None
            }
            None => {
                let dot = text.iter().position(|&c| c == b'.').unwrap_or(text.len());
                let (int, frac) = (&text[..dot], text.get(dot + 1..).unwrap_or(&[]));
                if int != b"0" {
                    // d.ddd from the integer part's digits and the fraction's.
                    put(&int[..1]);
                    let rest = [&int[1..], frac].concat();
                    let end = rest.iter().rposition(|&c| c != b'0').map_or(0, |k| k + 1);
                    if end > 0 {
                        put(b".");
                        put(&rest[..end]);
                    }
                    Some(int.len() as i32 - 1)
                } else {
                    let zeros = frac.iter().take_while(|&&c| c == b'0').count();
                    let digits = &frac[zeros..];
                    let end = digits.iter().rposition(|&c| c != b'0').map_or(0, |k| k + 1);
                    match end {
                        0 => put(b"0"),
                        _ => {
                            put(&digits[..1]);
                            if end > 1 {
                                put(b".");
                                put(&digits[1..end]);
                            }
                        }
                    }
                    Some(if end == 0 { 0 } else { -(zeros as i32) - 1 })
                }
            }
        };
        if let Some(e) = exponent {
            put(b"e");
            if e < 0 {
                put(b"-");
            }
            let e = e.unsigned_abs();
            let digits = [(e / 100) as u8, (e / 10 % 10) as u8, (e % 10) as u8].map(|d| b'0' + d);
            let skip = if e >= 100 {
                0
            } else if e >= 10 {
                1
            } else {
                2
            };
            put(&digits[skip..]);
        }
        f.write_str(std::str::from_utf8(&out[..n]).map_err(|_| fmt::Error)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether `ours` is Rust's `theirs`: the same characters, or a tie's
    /// other last digit (the same length and notation, one apart in the
    /// last digit); and reads back as `x`. Returns whether it was a tie.
    fn as_rust(ours: &str, theirs: &str, x: f64) -> bool {
        let what = format!("{x:e} ({:#x}): {ours} against Rust's {theirs}", x.to_bits());
        if !x.is_nan() {
            assert_eq!(ours.parse::<f64>().unwrap().to_bits(), x.to_bits(), "{what}: reads back");
        }
        if ours == theirs {
            return false;
        }
        let (a, b) = (ours.as_bytes(), theirs.as_bytes());
        let last = ours.find('e').unwrap_or(a.len()) - 1;
        assert!(a.len() == b.len() && a[..last] == b[..last] && a[last + 1..] == b[last + 1..], "{what}");
        assert_eq!(a[last].abs_diff(b[last]), 1, "{what}: a tie's last digit");
        true
    }

    fn same(x: f64) -> usize {
        usize::from(as_rust(&Dec(x).to_string(), &format!("{x}"), x))
            + usize::from(as_rust(&Exp(x).to_string(), &format!("{x:e}"), x))
    }

    /// Every kind of `f64` is written as Rust writes it: edge cases, every
    /// bit pattern at random, and the numbers the files hold (coordinates,
    /// volumes, areas, unit normals); ties (see the module) are rare.
    #[test]
    fn numbers_are_written_as_rust_writes_them() {
        let edges = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.1,
            0.5,
            10.0,
            1e-7,
            1e-5,
            123456.0,
            1e15,
            1e16,
            1e21,
            1e22,
            1e23,
            1e300,
            -1e-300,
            5e-324,
            f64::MIN_POSITIVE,
            f64::MAX,
            f64::MIN,
            f64::EPSILON,
            f64::NAN,
            -f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            2.9802322387695312e-8,
            5.444310685350916e14,
            43210.0,
            0.3,
            2.0 / 3.0,
        ];
        let mut ties = 0;
        for x in edges {
            ties += same(x);
        }
        assert_eq!(same(2.9802322387695312e-8), 2, "2^-25: a tie, both notations");
        assert_eq!(Exp(2.9802322387695312e-8).to_string(), "2.9802322387695312e-8");
        // A xorshift generator: the same numbers on every run.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let rounds = 400_000;
        for _ in 0..rounds {
            let bits = next();
            ties += same(f64::from_bits(bits));
            // Uniform in [0, 1), and a unit normal's components.
            let u = (bits >> 11) as f64 / (1u64 << 53) as f64;
            ties += same(u) + same(2.0 * u - 1.0);
            ties += same(u * 1e-9);
            // Powers of two (where the ties are: exact binary fractions)
            // and of ten.
            same((u * 40.0 - 20.0).exp2().round());
            same(((bits % 200) as f64 - 100.0).exp2());
            same(10f64.powi((bits % 640) as i32 - 320));
        }
        // (Measured: 228 ties in 3.2 million, 1 in 14 000.)
        assert!(ties < rounds * 8 / 2000, "{ties} ties in {} numbers that are not powers of two", rounds * 8);
    }
}
