//! Small f64 vector helpers for the host's geometry (shapes, surfaces,
//! meshes): points as `[f64; 3]`.

/// A point or vector.
pub type P = [f64; 3];

/// `a - b`.
#[inline]
pub fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a + b`.
#[inline]
pub fn add(a: P, b: P) -> P {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a * s`.
#[inline]
pub fn scale(a: P, s: f64) -> P {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a · b`.
#[inline]
pub fn dot(a: P, b: P) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`.
#[inline]
pub fn cross(a: P, b: P) -> P {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `|a|`.
#[inline]
pub fn norm(a: P) -> f64 {
    dot(a, a).sqrt()
}

/// `a / |a|` (`a` itself when it is zero).
#[inline]
pub fn unit(a: P) -> P {
    let n = norm(a);
    if n > 0.0 {
        scale(a, 1.0 / n)
    } else {
        a
    }
}

/// Lower and upper corners of the points' bounding box (infinite and
/// reversed for no points).
pub fn bounding_box<'a>(points: impl IntoIterator<Item = &'a P>) -> (P, P) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// Whether the bounding box of `points` meets the box `lo..=hi`.
pub fn box_meets<'a>(points: impl IntoIterator<Item = &'a P>, (lo, hi): (P, P)) -> bool {
    let (min, max) = bounding_box(points);
    (0..3).all(|a| min[a] <= hi[a] && max[a] >= lo[a])
}
