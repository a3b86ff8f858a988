//! Line charts (the CVT energy against iterations, benchmark times against
//! sizes), written as PNGs with axes, tick labels and a legend in a small
//! built-in font.

use cvd::error::Result;
use std::path::Path;

/// One line of the chart.
pub struct Series<'a> {
    /// Name in the legend (lowercase letters, digits and `-+.e()`).
    pub name: &'a str,
    /// Values, one per point.
    pub values: &'a [f64],
    /// Where each value lies on the horizontal axis; empty: 0, 1, 2, ...
    pub x: &'a [f64],
    /// Line colour.
    pub rgb: [u8; 3],
}

const WIDTH: usize = 800;
const HEIGHT: usize = 500;
const LEFT: usize = 90;
const RIGHT: usize = 20;
const TOP: usize = 36;
const BOTTOM: usize = 50;
/// Pixels per font dot.
const DOT: usize = 2;

struct Canvas {
    rgb: Vec<u8>,
}

impl Canvas {
    fn new() -> Self {
        Self { rgb: vec![255; WIDTH * HEIGHT * 3] }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < WIDTH && (y as usize) < HEIGHT {
            let i = (y as usize * WIDTH + x as usize) * 3;
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    fn rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.set(xx, yy, c);
            }
        }
    }

    /// A line two pixels wide (Bresenham).
    fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: [u8; 3]) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        loop {
            self.rect(x, y, 2, 2, c);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Text with its top-left corner at `(x, y)`.
    fn text(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let rows = glyph(ch);
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..3 {
                    if bits & (0b100 >> col) != 0 {
                        let px = x + ((k * 4 + col) * DOT) as i64;
                        self.rect(px, y + (r * DOT) as i64, DOT as i64, DOT as i64, c);
                    }
                }
            }
        }
    }
}

fn text_width(s: &str) -> i64 {
    (s.chars().count() * 4 * DOT) as i64
}

/// 3x5 dots per character, one row of 3 bits per entry.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 2, 2],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        'a' => [0, 7, 1, 7, 7],
        'b' => [4, 4, 7, 5, 7],
        'c' => [0, 7, 4, 4, 7],
        'd' => [1, 1, 7, 5, 7],
        'e' => [0, 7, 7, 4, 7],
        'f' => [3, 4, 7, 4, 4],
        'g' => [0, 7, 5, 7, 1],
        'h' => [4, 4, 7, 5, 5],
        'i' => [2, 0, 2, 2, 2],
        'j' => [1, 0, 1, 5, 7],
        'k' => [4, 5, 6, 5, 5],
        'l' => [6, 2, 2, 2, 7],
        'm' => [0, 7, 7, 5, 5],
        'n' => [0, 6, 5, 5, 5],
        'o' => [0, 7, 5, 5, 7],
        'p' => [7, 5, 7, 4, 4],
        'q' => [7, 5, 7, 1, 1],
        'r' => [0, 7, 4, 4, 4],
        's' => [7, 4, 7, 1, 7],
        't' => [2, 7, 2, 2, 3],
        'u' => [0, 5, 5, 5, 7],
        'v' => [0, 5, 5, 5, 2],
        'w' => [0, 5, 5, 7, 7],
        'x' => [0, 5, 2, 2, 5],
        'y' => [5, 5, 7, 1, 7],
        'z' => [0, 7, 1, 4, 7],
        '/' => [1, 1, 2, 4, 4],
        '_' => [0, 0, 0, 0, 7],
        ':' => [0, 2, 0, 2, 0],
        _ => [0; 5],
    }
}

/// `v` in three significant digits and a short exponent: `4.41e-4`.
fn label(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let e = v.abs().log10().floor() as i32;
    format!("{:.2}e{e}", v / 10f64.powi(e))
}

/// What a chart's axes show.
pub struct Axes<'a> {
    /// Label of the horizontal axis.
    pub x_name: &'a str,
    /// Label of the vertical axis.
    pub y_name: &'a str,
    /// A logarithmic vertical axis (values <= 0 are left out).
    pub log_y: bool,
}

/// Writes the chart of `series` against iterations to `path` (`y_name`
/// labels the vertical axis).
pub fn write_line_chart_png(path: &Path, y_name: &str, series: &[Series]) -> Result<()> {
    write_chart_png(path, &Axes { x_name: "iteration", y_name, log_y: false }, series)
}

/// Writes the chart of `series` to `path`.
pub fn write_chart_png(path: &Path, axes: &Axes, series: &[Series]) -> Result<()> {
    let fy = |v: f64| {
        if axes.log_y {
            if v > 0.0 {
                v.log10()
            } else {
                f64::NAN
            }
        } else {
            v
        }
    };
    let points: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|s| {
            let x = |i: usize| s.x.get(i).copied().unwrap_or(i as f64);
            (0..s.values.len())
                .map(|i| (x(i), fy(s.values[i])))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect()
        })
        .collect();
    let range = |vals: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        match (lo.is_finite(), hi - lo <= 1e-12 * hi.abs().max(1e-300)) {
            (false, _) => (0.0, 1.0),
            (true, true) => (lo - 0.5 * lo.abs().max(1e-12), hi + 0.5 * hi.abs().max(1e-12)),
            (true, false) => (lo, hi),
        }
    };
    let (xlo, xhi) = range(&mut points.iter().flatten().map(|p| p.0));
    let (lo, hi) = range(&mut points.iter().flatten().map(|p| p.1));
    let pad = 0.05 * (hi - lo);
    // Times and counts start from zero; energies and logarithms do not.
    let from_zero = !axes.log_y && lo >= 0.0 && lo < 0.5 * hi && !series.iter().all(|s| s.x.is_empty());
    let (lo, hi) = (if from_zero { 0.0 } else { lo - pad }, hi + pad);
    let (x0, x1) = (LEFT as i64, (WIDTH - RIGHT) as i64);
    let (y0, y1) = (TOP as i64, (HEIGHT - BOTTOM) as i64);
    let px = |x: f64| x0 + (((x - xlo) / (xhi - xlo)) * (x1 - x0) as f64).round() as i64;
    let py = |v: f64| y1 - (((v - lo) / (hi - lo)) * (y1 - y0) as f64).round() as i64;

    let mut c = Canvas::new();
    const GRID: [u8; 3] = [225, 225, 225];
    const INK: [u8; 3] = [40, 40, 40];
    let integral_x = points.iter().flatten().all(|p| p.0.fract() == 0.0);
    for k in 0..=5 {
        let v = lo + (hi - lo) * k as f64 / 5.0;
        let y = py(v);
        c.line((x0, y), (x1, y), GRID);
        let t = label(if axes.log_y { 10f64.powf(v) } else { v });
        c.text(x0 - 8 - text_width(&t), y - 5, &t, INK);
        let mut xv = xlo + (xhi - xlo) * k as f64 / 5.0;
        if integral_x {
            xv = xv.round();
        }
        let x = px(xv);
        c.line((x, y0), (x, y1), GRID);
        let t = if integral_x && xv.abs() < 1e7 { format!("{}", xv as i64) } else { label(xv) };
        c.text(x - text_width(&t) / 2, y1 + 8, &t, INK);
    }
    c.line((x0, y0), (x0, y1), INK);
    c.line((x0, y1), (x1, y1), INK);
    c.text((x0 + x1) / 2 - text_width(axes.x_name) / 2, y1 + 26, axes.x_name, INK);
    let y_name = if axes.log_y { format!("{} (log)", axes.y_name) } else { axes.y_name.to_string() };
    c.text(4, y0 - 30, &y_name, INK);
    for (k, (s, pts)) in series.iter().zip(&points).enumerate() {
        let pts: Vec<(i64, i64)> = pts.iter().map(|&(x, y)| (px(x), py(y))).collect();
        for w in pts.windows(2) {
            c.line(w[0], w[1], s.rgb);
        }
        if !s.x.is_empty() {
            for &(x, y) in &pts {
                c.rect(x - 2, y - 2, 6, 6, s.rgb);
            }
        }
        // Legend, top right.
        let y = y0 + 6 + 16 * k as i64;
        let x = x1 - 20 - text_width(s.name) - 24;
        c.rect(x, y + 2, 16, 6, s.rgb);
        c.text(x + 22, y, s.name, INK);
    }

    super::write_png(path, WIDTH, HEIGHT, &c.rgb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chart_draws_lines_where_the_values_are() {
        let path = std::env::temp_dir().join(format!("cvd-plot-{}.png", std::process::id()));
        let down: Vec<f64> = (0..50).map(|i| 4.4e-4 - 1e-6 * i as f64).collect();
        let flat = vec![4.0e-4; 50];
        let series = [
            Series { name: "lloyd", values: &down, x: &[], rgb: [200, 30, 30] },
            Series { name: "lbfgs", values: &flat, x: &[], rgb: [30, 30, 200] },
        ];
        write_line_chart_png(&path, "energy", &series).unwrap();
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let at = |x: usize, y: usize| &buf[(y * WIDTH + x) * 3..(y * WIDTH + x) * 3 + 3];
        // The flat series is a horizontal line in the middle of the plot
        // area's columns; the falling one starts at the top left.
        let column = (LEFT + WIDTH - RIGHT) / 2;
        let blue = (TOP..HEIGHT - BOTTOM).filter(|&y| at(column, y) == [30, 30, 200]).count();
        assert!(blue >= 2, "no flat line in column {column}");
        let red_top_left = (TOP..TOP + 60).any(|y| at(LEFT + 1, y) == [200, 30, 30]);
        assert!(red_top_left, "the falling line does not start at the top left");
        let _ = std::fs::remove_file(path);
    }
}
