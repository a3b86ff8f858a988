//! `cells.png`: a shaded 3D view of the clipped cells whose sites lie
//! below a horizontal plane (the mesh's middle by default), seen from above
//! at a slant, so that the cells' own faces show where the upper half was
//! lifted off — each cell in its colour (the section's), lit by a light
//! from the viewer's upper left. Drawn by a small software rasteriser:
//! orthographic projection, a depth buffer, each face fanned into
//! triangles and shaded by its normal.

use super::picture::colour;
use super::Progress;
use cvd::error::Result;
use cvd::passes::pieces::Pieces;
use std::path::Path;

type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn unit(a: V3) -> V3 {
    let l = dot(a, a).sqrt();
    if l > 0.0 {
        a.map(|c| c / l)
    } else {
        a
    }
}

/// The camera: looking along `forward`, `right` and `up` spanning the
/// image.
struct Camera {
    forward: V3,
    right: V3,
    up: V3,
}

impl Camera {
    fn new() -> Self {
        let forward = unit([-0.45, 0.75, -0.8]);
        let right = unit(cross(forward, [0.0, 0.0, 1.0]));
        let up = cross(right, forward);
        Self { forward, right, up }
    }

    /// Screen x, screen y (up), depth (larger is farther).
    fn project(&self, p: V3) -> V3 {
        [dot(p, self.right), dot(p, self.up), dot(p, self.forward)]
    }
}

/// Draws the cells of `pieces` whose sites (`sites`, input order) lie at
/// `z <= cut` into a PNG `size` pixels wide, reporting progress in pieces.
pub fn write_cells_view_png(
    path: &Path,
    pieces: &Pieces,
    sites: &[[f64; 3]],
    cut: f64,
    size: usize,
    progress: Progress<'_>,
) -> Result<()> {
    let camera = Camera::new();
    let shown = |k: &usize| sites.get(pieces.site(*k) as usize).is_some_and(|s| s[2] <= cut);
    // The image's extent: every shown vertex, projected.
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in (0..pieces.len()).filter(shown).map(|k| pieces.get(k)) {
        for &v in &p.vertices {
            let s = camera.project(v);
            for a in 0..2 {
                lo[a] = lo[a].min(s[a]);
                hi[a] = hi[a].max(s[a]);
            }
        }
    }
    let width = size.max(16);
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(f64::MIN_POSITIVE);
    let scale = 0.94 * width as f64 / span;
    let height = (((hi[1] - lo[1]).max(0.0) * scale) as usize + width / 16).clamp(16, 4 * width);
    let (cx, cy) = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]));
    let to_pixel =
        |s: V3| -> V3 { [(s[0] - cx) * scale + width as f64 / 2.0, height as f64 / 2.0 - (s[1] - cy) * scale, s[2]] };
    let mut depth = vec![f64::INFINITY; width * height];
    let mut rgb = vec![255u8; width * height * 3];
    let light = unit([-0.5, 0.3, 1.0]);
    let total = pieces.len() as u64;
    for i in 0..pieces.len() {
        if i % 4096 == 4095 {
            progress(i as u64 + 1, total);
        }
        if !shown(&i) {
            continue;
        }
        let piece = pieces.get(i);
        let base = colour(piece.site);
        for face in piece.faces() {
            let corners: Vec<V3> = face.iter().map(|&k| piece.vertices[k as usize]).collect();
            // Newell's normal: outward, as the loop runs counter-clockwise
            // seen from outside.
            let mut n = [0.0; 3];
            for (k, a) in corners.iter().enumerate() {
                let b = corners[(k + 1) % corners.len()];
                n = [
                    n[0] + (a[1] - b[1]) * (a[2] + b[2]),
                    n[1] + (a[2] - b[2]) * (a[0] + b[0]),
                    n[2] + (a[0] - b[0]) * (a[1] + b[1]),
                ];
            }
            let n = unit(n);
            if dot(n, camera.forward) >= 0.0 {
                continue;
            }
            let shade = 0.35 + 0.65 * dot(n, light).max(0.0);
            let c = base.map(|b| (b as f64 * shade).round().clamp(0.0, 255.0) as u8);
            let screen: Vec<V3> = corners.iter().map(|&p| to_pixel(camera.project(p))).collect();
            for k in 1..screen.len().saturating_sub(1) {
                triangle([screen[0], screen[k], screen[k + 1]], c, width, height, &mut depth, &mut rgb);
            }
        }
    }
    progress(total, total);
    super::write_png(path, width, height, &rgb)
}

/// Fills a triangle (pixel x, pixel y, depth) where it is nearer than what
/// is drawn.
fn triangle(t: [V3; 3], c: [u8; 3], width: usize, height: usize, depth: &mut [f64], rgb: &mut [u8]) {
    let area = (t[1][0] - t[0][0]) * (t[2][1] - t[0][1]) - (t[1][1] - t[0][1]) * (t[2][0] - t[0][0]);
    if area.abs() < 1e-12 {
        return;
    }
    let x0 = t.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
    let x1 = (t.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max).ceil() as usize).min(width.saturating_sub(1));
    let y0 = t.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min).floor().max(0.0) as usize;
    let y1 = (t.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max).ceil() as usize).min(height.saturating_sub(1));
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            // Barycentric weights by edge functions.
            let w = [1, 2, 0].map(|k| {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                ((b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0])) / area
            });
            if w.iter().all(|&v| v >= -1e-9) {
                let d = w[0] * t[0][2] + w[1] * t[1][2] + w[2] * t[2][2];
                let i = y * width + x;
                if d < depth[i] {
                    depth[i] = d;
                    rgb[3 * i..3 * i + 3].copy_from_slice(&c);
                }
            }
        }
    }
}
