//! `picture.png`: the cells cut by a plane `z = const`, seen from +z (x to
//! the right, y up). Each piece the plane crosses is cut into a convex
//! polygon and filled with its site's colour; pixels where the site
//! changes are drawn dark (cell walls) and pixels where the mesh ends
//! black (the mesh's cross-section outline).
//!
//! A pixel two pieces cover takes the lower site, whatever order they are
//! drawn in: so the pieces can be drawn in parts (each process of a
//! distributed run its own cells') and the parts' images combined
//! ([`SectionImage::combine`]) into the one image of all of them.

use super::Progress;
use cvd::error::Result;
use cvd::geom::mesh::TetMesh;
use cvd::passes::pieces::{Piece, Pieces};
use rayon::prelude::*;
use std::path::Path;

/// Pieces cut between two progress reports.
const BATCH: usize = 1 << 16;

/// The cutting plane `z = z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Section {
    /// Height of the plane.
    pub z: f64,
}

impl Section {
    /// The plane through the middle of the mesh's bounding box — just off
    /// it, by 0.07% of the height: a regular mesh has tet faces in its
    /// middle plane, where pieces would touch the plane without crossing it.
    pub fn middle(mesh: &TetMesh) -> Self {
        let (lo, hi) = mesh.bounding_box();
        Self { z: lo[2] + 0.5007 * (hi[2] - lo[2]) }
    }
}

/// No site here (outside the mesh, or in no piece).
const NONE: u32 = u32::MAX;

/// The image: the mesh's box in x and y with a margin.
struct Raster {
    width: usize,
    height: usize,
    /// World x of the left edge and y of the top edge.
    x0: f64,
    y1: f64,
    /// Pixels per world unit.
    scale: f64,
    /// How far (world units) a polygon is widened: the pieces' shared
    /// walls agree only to f32 precision, and a pixel centre between two
    /// copies of a wall must not be left to neither piece.
    slack: f64,
    /// Site of each pixel, row by row from the top.
    label: Vec<u32>,
}

impl Raster {
    /// `size` pixels along the longer side.
    fn new(mesh: &TetMesh, size: usize) -> Self {
        let (lo, hi) = mesh.bounding_box();
        let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
        let side = w.max(h).max(f64::MIN_POSITIVE);
        let margin = 0.02 * side;
        let scale = size as f64 / (side + 2.0 * margin);
        let pixels = |extent: f64| (((extent + 2.0 * margin) * scale).ceil() as usize).clamp(1, size);
        let (width, height) = (pixels(w), pixels(h));
        Self {
            width,
            height,
            x0: lo[0] - margin,
            y1: hi[1] + margin,
            scale,
            slack: 1e-5 * side,
            label: vec![NONE; width * height],
        }
    }

    /// Fills the convex polygon `poly` (world x, y, in order) with `site`:
    /// every pixel whose centre lies inside (and holds no lower site).
    fn fill(&mut self, poly: &[[f64; 2]], site: u32) {
        let (ymin, ymax) = poly.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p[1]), b.max(p[1])));
        // Rows and columns whose pixel centres lie in [from, to].
        let rows = |from: f64, to: f64| {
            let r = |y: f64| (self.y1 - y) * self.scale - 0.5;
            (r(to).ceil().max(0.0), r(from).floor().min(self.height as f64 - 1.0))
        };
        let cols = |from: f64, to: f64| {
            let c = |x: f64| (x - self.x0) * self.scale - 0.5;
            (c(from).ceil().max(0.0), c(to).floor().min(self.width as f64 - 1.0))
        };
        let (first, last) = rows(ymin - self.slack, ymax + self.slack);
        if first > last {
            return;
        }
        for r in first as usize..=last as usize {
            let y = (self.y1 - (r as f64 + 0.5) / self.scale).clamp(ymin, ymax);
            let (mut xmin, mut xmax) = (f64::INFINITY, f64::NEG_INFINITY);
            for (i, &a) in poly.iter().enumerate() {
                let b = poly[(i + 1) % poly.len()];
                let (lo, hi) = if a[1] <= b[1] { (a, b) } else { (b, a) };
                if y < lo[1] || y > hi[1] {
                    continue;
                }
                let xs = if hi[1] > lo[1] {
                    let x = lo[0] + (y - lo[1]) / (hi[1] - lo[1]) * (hi[0] - lo[0]);
                    [x, x]
                } else {
                    [lo[0], hi[0]]
                };
                xmin = xmin.min(xs[0].min(xs[1]));
                xmax = xmax.max(xs[0].max(xs[1]));
            }
            let (c0, c1) = cols(xmin - self.slack, xmax + self.slack);
            if c0 <= c1 {
                for label in &mut self.label[r * self.width..][c0 as usize..=c1 as usize] {
                    *label = (*label).min(site);
                }
            }
        }
    }
}

/// The section of a piece by the plane, as a convex polygon in order
/// (empty when the plane misses it).
fn cut(piece: &Piece, z: f64) -> Vec<[f64; 2]> {
    let mut points = Vec::new();
    for face in piece.faces() {
        for (k, &a) in face.iter().enumerate() {
            let b = face[(k + 1) % face.len()];
            // Each edge is in two faces, once each way: take it once.
            if a > b {
                continue;
            }
            let (p, q) = (piece.vertices[a as usize], piece.vertices[b as usize]);
            if (p[2] < z) != (q[2] < z) {
                let t = (z - p[2]) / (q[2] - p[2]);
                points.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
            }
        }
    }
    if points.len() < 3 {
        return Vec::new();
    }
    let n = points.len() as f64;
    let c = points.iter().fold([0.0, 0.0], |s, p| [s[0] + p[0] / n, s[1] + p[1] / n]);
    points.sort_by(|p, q| {
        let (a, b) = ((p[1] - c[1]).atan2(p[0] - c[0]), (q[1] - c[1]).atan2(q[0] - c[0]));
        a.total_cmp(&b)
    });
    points
}

/// A light colour for each site, from a hash of its index.
pub(super) fn colour(site: u32) -> [u8; 3] {
    let mut h = site as u64 ^ 0x9e37_79b9_7f4a_7c15;
    h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^= h >> 31;
    // Each channel in 110..=250: light enough for dark walls to show.
    [0, 1, 2].map(|k| 110 + ((h >> (16 * k)) % 141) as u8)
}

/// The section of a diagram's pieces by a plane, as each pixel's site:
/// drawn from any number of sets of pieces, in any order, the same image.
pub struct SectionImage {
    raster: Raster,
    section: Section,
}

impl SectionImage {
    /// An empty image of `mesh`'s section by `section`, `size` pixels
    /// along the longer side of the mesh's box.
    pub fn new(mesh: &TetMesh, section: Section, size: usize) -> Self {
        Self { raster: Raster::new(mesh, size.max(16)), section }
    }

    /// Draws the section of `pieces`, reporting progress in pieces (the
    /// pieces cut on the threads, their polygons filled in order).
    pub fn draw(&mut self, pieces: &Pieces, progress: Progress<'_>) {
        let z = self.section.z;
        let total = pieces.len();
        for start in (0..total).step_by(BATCH) {
            let end = (start + BATCH).min(total);
            let polygons: Vec<(u32, Vec<[f64; 2]>)> = (start..end)
                .into_par_iter()
                .filter_map(|k| {
                    let piece = pieces.get(k);
                    let (lo, hi) = piece
                        .vertices
                        .iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v[2]), b.max(v[2])));
                    let poly = if lo <= z && z <= hi { cut(&piece, z) } else { Vec::new() };
                    (!poly.is_empty()).then_some((piece.site, poly))
                })
                .collect();
            for (site, poly) in polygons {
                self.raster.fill(&poly, site);
            }
            progress(end as u64, total as u64);
        }
        progress(total as u64, total as u64);
    }

    /// Combines this image with the images of the same section that other
    /// processes drew of other pieces: `max` replaces each value by its
    /// largest over the processes (an all-reduce). Every process ends with
    /// the image of all their pieces.
    pub fn combine(&mut self, max: &mut dyn FnMut(&mut [f64]) -> Result<()>) -> Result<()> {
        // The lowest site as the largest of their negatives (exact: a u32
        // is exact in an f64).
        let mut values: Vec<f64> = self.raster.label.iter().map(|&l| -f64::from(l)).collect();
        max(&mut values)?;
        for (label, v) in self.raster.label.iter_mut().zip(values) {
            *label = (-v) as u32;
        }
        Ok(())
    }

    /// Writes the image as a PNG.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        super::write_png(path, self.raster.width, self.raster.height, &paint(&self.raster))
    }
}

/// Draws the pieces' section by `section` into a PNG of `size` pixels
/// along the longer side of the mesh's box, reporting progress in pieces.
pub fn write_section_png(
    path: &Path,
    mesh: &TetMesh,
    pieces: &Pieces,
    section: Section,
    size: usize,
    progress: Progress<'_>,
) -> Result<()> {
    let mut image = SectionImage::new(mesh, section, size);
    image.draw(pieces, progress);
    image.write_png(path)
}

/// RGB pixels: white outside, site colours inside, walls dark grey, the
/// mesh's outline black.
fn paint(r: &Raster) -> Vec<u8> {
    const WALL: [u8; 3] = [60, 60, 60];
    const OUTLINE: [u8; 3] = [0, 0, 0];
    let (w, h) = (r.width, r.height);
    let mut rgb = vec![255u8; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let here = r.label[y * w + x];
            let mut colour = if here == NONE { [255; 3] } else { colour(here) };
            let neighbours = [(x + 1, y), (x, y + 1), (x.wrapping_sub(1), y), (x, y.wrapping_sub(1))];
            for (nx, ny) in neighbours {
                let there = if nx < w && ny < h { r.label[ny * w + nx] } else { NONE };
                if there != here {
                    if here == NONE || there == NONE {
                        colour = OUTLINE;
                        break;
                    }
                    colour = WALL;
                }
            }
            rgb[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&colour);
        }
    }
    rgb
}
