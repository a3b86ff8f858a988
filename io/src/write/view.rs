//! `cells.png`: a shaded 3D view of the clipped cells whose sites lie
//! below a horizontal plane (the mesh's middle by default), seen from above
//! at a slant, so that the cells' own faces show where the upper half was
//! lifted off — each cell in its colour (the section's), lit by a light
//! from the viewer's upper left. Drawn by a small software rasteriser:
//! orthographic projection, a depth buffer, each face fanned into
//! triangles and shaded by its normal.
//!
//! The image's frame is fixed by the mesh and the plane (not by the cells
//! drawn), and a pixel two faces cover at the same depth takes the larger
//! colour, whatever order they are drawn in: so the pieces can be drawn in
//! parts (each process of a distributed run its own cells') and the
//! parts' images combined ([`CellsView::combine`]) into the one image of
//! all of them.

use super::picture::colour;
use super::Progress;
use cvd::error::Result;
use cvd::geom::mesh::TetMesh;
use cvd::passes::pieces::Pieces;
use rayon::prelude::*;
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

/// A colour packed as `0xRRGGBB`.
fn pack(c: [u8; 3]) -> u32 {
    u32::from_be_bytes([0, c[0], c[1], c[2]])
}

/// Pieces drawn between two progress reports, split among the lanes.
const BATCH: usize = 1 << 16;

/// The most lanes (private images) a view is drawn in at once.
const LANES: usize = 8;

/// Where the view's pixels are: its size, the frame's centre on the screen
/// and pixels per world unit.
#[derive(Clone, Copy)]
struct Frame {
    width: usize,
    height: usize,
    centre: [f64; 2],
    scale: f64,
}

/// Per pixel: the depth of what is drawn there (infinite for nothing) and
/// its colour (`0xRRGGBB`).
#[derive(Clone)]
struct Pixels {
    depth: Vec<f64>,
    colour: Vec<u32>,
}

impl Pixels {
    fn new(n: usize) -> Self {
        Self { depth: vec![f64::INFINITY; n], colour: vec![0xff_ffff; n] }
    }

    /// Pixel `i` takes depth `d` and colour `c` if they are nearer than
    /// what it holds (or as near, and a larger colour): the order things
    /// are drawn in does not matter.
    #[inline]
    fn offer(&mut self, i: usize, d: f64, c: u32) {
        if d < self.depth[i] || (d == self.depth[i] && c > self.colour[i]) {
            (self.depth[i], self.colour[i]) = (d, c);
        }
    }

    /// Every pixel of `other` offered to this image.
    fn take(&mut self, other: &Pixels) {
        for i in 0..self.depth.len() {
            self.offer(i, other.depth[i], other.colour[i]);
        }
    }
}

/// The view of the cells whose sites lie at `z <= cut`: each pixel's
/// depth and colour, drawn from any number of sets of pieces, in any
/// order, the same image.
pub struct CellsView {
    cut: f64,
    frame: Frame,
    pixels: Pixels,
}

impl CellsView {
    /// An empty view, `size` pixels wide, framing every tet of `mesh` that
    /// reaches below the plane `z = cut` (the cells below it, and as much
    /// of them above it as such a tet spans).
    pub fn new(mesh: &TetMesh, cut: f64, size: usize) -> Self {
        let camera = Camera::new();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for tet in &mesh.tets {
            let corners = tet.map(|v| mesh.vertices[v as usize]);
            if corners.iter().all(|c| c[2] > cut) {
                continue;
            }
            for c in corners {
                let s = camera.project(c);
                for a in 0..2 {
                    lo[a] = lo[a].min(s[a]);
                    hi[a] = hi[a].max(s[a]);
                }
            }
        }
        if lo[0] > hi[0] {
            (lo, hi) = ([0.0; 2], [0.0; 2]);
        }
        let width = size.max(16);
        let span = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(f64::MIN_POSITIVE);
        let scale = 0.94 * width as f64 / span;
        let height = (((hi[1] - lo[1]).max(0.0) * scale) as usize + width / 16).clamp(16, 4 * width);
        let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
        Self { cut, frame: Frame { width, height, centre, scale }, pixels: Pixels::new(width * height) }
    }

    /// Draws the pieces of `pieces` whose sites lie at `z <= cut`,
    /// reporting progress in pieces: in lanes on the threads, each into an
    /// image of its own, combined at the end.
    pub fn draw(&mut self, pieces: &Pieces, progress: Progress<'_>) {
        let total = pieces.len();
        let lanes = rayon::current_num_threads().clamp(1, LANES).min(total.div_ceil(BATCH / LANES).max(1));
        let mut others = vec![Pixels::new(self.pixels.depth.len()); lanes - 1];
        let (frame, cut) = (self.frame, self.cut);
        for start in (0..total).step_by(BATCH) {
            let end = (start + BATCH).min(total);
            let share = (end - start).div_ceil(lanes);
            let mut images: Vec<&mut Pixels> = std::iter::once(&mut self.pixels).chain(others.iter_mut()).collect();
            images.par_iter_mut().enumerate().for_each(|(lane, image)| {
                let from = (start + lane * share).min(end);
                draw_pieces(frame, cut, image, pieces, from..(from + share).min(end));
            });
            progress(end as u64, total as u64);
        }
        for other in &others {
            self.pixels.take(other);
        }
        progress(total as u64, total as u64);
    }

    /// Combines this view with the views of the same frame that other
    /// processes drew of other pieces: `max` replaces each value by its
    /// largest over the processes (an all-reduce). Every process ends with
    /// the view of all their pieces.
    pub fn combine(&mut self, max: &mut dyn FnMut(&mut [f64]) -> Result<()>) -> Result<()> {
        // The nearest depth, as the largest of the negatives; then, of the
        // colours drawn at that depth, the largest.
        let Pixels { depth, colour } = &mut self.pixels;
        let mut near: Vec<f64> = depth.iter().map(|&d| -d).collect();
        max(&mut near)?;
        let mut colours: Vec<f64> = depth
            .iter()
            .zip(&near)
            .zip(colour.iter())
            .map(|((&d, &n), &c)| if d == -n { f64::from(c) } else { -1.0 })
            .collect();
        max(&mut colours)?;
        for (k, (n, c)) in near.into_iter().zip(colours).enumerate() {
            (depth[k], colour[k]) = (-n, c as u32);
        }
        Ok(())
    }

    /// Writes the view as a PNG.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let rgb: Vec<u8> =
            self.pixels.colour.iter().flat_map(|&c| [(c >> 16) as u8, (c >> 8) as u8, c as u8]).collect();
        super::write_png(path, self.frame.width, self.frame.height, &rgb)
    }
}

/// Draws pieces `range` of `pieces` whose sites lie at `z <= cut` into
/// `image`.
fn draw_pieces(frame: Frame, cut: f64, image: &mut Pixels, pieces: &Pieces, range: std::ops::Range<usize>) {
    let light = unit([-0.5, 0.3, 1.0]);
    let camera = Camera::new();
    let (width, height) = (frame.width as f64, frame.height as f64);
    let to_pixel = |p: V3| -> V3 {
        let s = camera.project(p);
        [
            (s[0] - frame.centre[0]) * frame.scale + width / 2.0,
            height / 2.0 - (s[1] - frame.centre[1]) * frame.scale,
            s[2],
        ]
    };
    let mut drawn = Vec::new();
    for i in range {
        if pieces.origin(i)[2] > cut {
            continue;
        }
        let piece = pieces.get(i);
        let base = colour(piece.site);
        for face in piece.faces() {
            let corners = || face.iter().map(|&k| piece.vertices[k as usize]);
            // Newell's normal: outward, as the loop runs counter-clockwise
            // seen from outside.
            let mut n = [0.0; 3];
            for (a, b) in corners().zip(corners().cycle().skip(1)) {
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
            let c = pack(base.map(|b| (b as f64 * shade).round().clamp(0.0, 255.0) as u8));
            drawn.clear();
            drawn.extend(corners().map(to_pixel));
            for k in 1..drawn.len().saturating_sub(1) {
                triangle(frame, image, [drawn[0], drawn[k], drawn[k + 1]], c);
            }
        }
    }
}

/// Fills a triangle (pixel x, pixel y, depth) where it is nearer than what
/// is drawn (or as near, and of a larger colour).
fn triangle(frame: Frame, image: &mut Pixels, t: [V3; 3], c: u32) {
    let (width, height) = (frame.width, frame.height);
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
                image.offer(y * width + x, w[0] * t[0][2] + w[1] * t[1][2] + w[2] * t[2][2], c);
            }
        }
    }
}

/// Draws the cells of `pieces` whose sites lie at `z <= cut` into a PNG
/// `size` pixels wide (framing the tets of `mesh` that reach below the
/// plane), reporting progress in pieces.
pub fn write_cells_view_png(
    path: &Path,
    mesh: &TetMesh,
    pieces: &Pieces,
    cut: f64,
    size: usize,
    progress: Progress<'_>,
) -> Result<()> {
    let mut view = CellsView::new(mesh, cut, size);
    view.draw(pieces, progress);
    view.write_png(path)
}
