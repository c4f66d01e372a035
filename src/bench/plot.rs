//! Line plots as PNG for the benchmarks' figures: linear or log axes, one polyline with
//! markers per series, a legend. No font library: labels use the bitmap glyphs of `font.rs`.

use std::path::Path;

use anyhow::{Context, Result};
use image::{Rgb, RgbImage};

use super::font;

/// One line of a plot.
pub struct Series {
    /// Its name in the legend.
    pub name: String,
    /// Its points (x, y); on a log axis, non-positive values are left out.
    pub points: Vec<(f64, f64)>,
}

/// A plot.
pub struct Plot {
    /// Above the frame.
    pub title: String,
    /// Under the x axis.
    pub x_label: String,
    /// Above the y axis.
    pub y_label: String,
    /// Logarithmic x axis.
    pub log_x: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// The lines.
    pub series: Vec<Series>,
}

const WIDTH: u32 = 760;
const HEIGHT: u32 = 500;
const LEFT: u32 = 78;
const RIGHT: u32 = 24;
const TOP: u32 = 40;
const BOTTOM: u32 = 56;
const COLOURS: [[u8; 3]; 6] =
    [[31, 119, 180], [214, 39, 40], [44, 160, 44], [148, 103, 189], [255, 127, 14], [23, 190, 207]];

/// An axis: data range mapped to pixels, and where its ticks go.
struct Axis {
    log: bool,
    lo: f64,
    hi: f64,
}

impl Axis {
    fn new(values: impl Iterator<Item = f64>, log: bool) -> Axis {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
            let v = if log { v.log10() } else { v };
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if !lo.is_finite() {
            (lo, hi) = (0.0, 1.0);
        }
        if log {
            (lo, hi) = (lo.floor(), hi.ceil().max(lo.floor() + 1.0));
        } else {
            let pad = ((hi - lo) * 0.05).max(1e-9);
            (lo, hi) = (lo - pad, hi + pad);
        }
        Axis { log, lo, hi }
    }

    /// Position of `v` in 0..=1 along the axis, if it can be shown.
    fn frac(&self, v: f64) -> Option<f64> {
        let v = if self.log {
            if v <= 0.0 {
                return None;
            }
            v.log10()
        } else {
            v
        };
        v.is_finite().then(|| (v - self.lo) / (self.hi - self.lo))
    }

    /// Tick values and their labels.
    fn ticks(&self) -> Vec<(f64, String)> {
        if self.log {
            (self.lo as i32..=self.hi as i32).map(|e| (10f64.powi(e), format!("1e{e}"))).collect()
        } else {
            let span = self.hi - self.lo;
            let raw = span / 6.0;
            let mag = 10f64.powf(raw.log10().floor());
            let step =
                [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| span / s <= 7.0).unwrap_or(mag * 10.0);
            let mut v = (self.lo / step).ceil() * step;
            let mut out = Vec::new();
            while v <= self.hi + step * 1e-9 {
                out.push((v, format!("{}", (v * 1e6).round() / 1e6)));
                v += step;
            }
            out
        }
    }
}

fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, colour: [u8; 3]) {
    for (i, c) in s.chars().enumerate() {
        let code = c as u32;
        let glyph =
            if (32..127).contains(&code) { &font::GLYPHS[(code - 32) as usize] } else { &font::GLYPHS[0] };
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..font::WIDTH {
                if bits & (1 << col) != 0 {
                    put(img, x + (i as u32 * font::WIDTH) as i64 + col as i64, y + row as i64, colour);
                }
            }
        }
    }
}

fn text_width(s: &str) -> i64 {
    (s.chars().count() as u32 * font::WIDTH) as i64
}

fn put(img: &mut RgbImage, x: i64, y: i64, colour: [u8; 3]) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, Rgb(colour));
    }
}

/// A line `thickness` pixels wide.
fn line(img: &mut RgbImage, (x0, y0): (f64, f64), (x1, y1): (f64, f64), colour: [u8; 3], thickness: i64) {
    let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
    for k in 0..=steps {
        let t = k as f64 / steps as f64;
        let (x, y) = ((x0 + (x1 - x0) * t).round() as i64, (y0 + (y1 - y0) * t).round() as i64);
        for dx in 0..thickness {
            for dy in 0..thickness {
                put(img, x + dx - thickness / 2, y + dy - thickness / 2, colour);
            }
        }
    }
}

/// Draws the plot and writes it as PNG.
pub fn write_png(plot: &Plot, path: &Path) -> Result<()> {
    let mut img = RgbImage::from_pixel(WIDTH, HEIGHT, Rgb([255, 255, 255]));
    let xs = Axis::new(plot.series.iter().flat_map(|s| s.points.iter().map(|p| p.0)), plot.log_x);
    let ys = Axis::new(plot.series.iter().flat_map(|s| s.points.iter().map(|p| p.1)), plot.log_y);
    let (x0, x1) = (LEFT as f64, (WIDTH - RIGHT) as f64);
    let (y0, y1) = ((HEIGHT - BOTTOM) as f64, TOP as f64);
    let to_px = |x: f64, y: f64| -> Option<(f64, f64)> {
        Some((x0 + xs.frac(x)? * (x1 - x0), y0 + ys.frac(y)? * (y1 - y0)))
    };
    let (grey, black) = ([225, 225, 225], [0, 0, 0]);
    for (v, label) in xs.ticks() {
        let Some(f) = xs.frac(v) else { continue };
        let x = x0 + f * (x1 - x0);
        line(&mut img, (x, y0), (x, y1), grey, 1);
        text(&mut img, x as i64 - text_width(&label) / 2, y0 as i64 + 6, &label, black);
    }
    for (v, label) in ys.ticks() {
        let Some(f) = ys.frac(v) else { continue };
        let y = y0 + f * (y1 - y0);
        line(&mut img, (x0, y), (x1, y), grey, 1);
        text(&mut img, x0 as i64 - 6 - text_width(&label), y as i64 - 6, &label, black);
    }
    line(&mut img, (x0, y0), (x1, y0), black, 1);
    line(&mut img, (x0, y0), (x0, y1), black, 1);
    text(&mut img, (WIDTH as i64 - text_width(&plot.title)) / 2, 10, &plot.title, black);
    text(
        &mut img,
        ((x0 + x1) / 2.0) as i64 - text_width(&plot.x_label) / 2,
        y0 as i64 + 26,
        &plot.x_label,
        black,
    );
    text(&mut img, 8, TOP as i64 - 18, &plot.y_label, black);
    for (i, s) in plot.series.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let pts: Vec<(f64, f64)> = s.points.iter().filter_map(|&(x, y)| to_px(x, y)).collect();
        for w in pts.windows(2) {
            line(&mut img, w[0], w[1], colour, 2);
        }
        for &(x, y) in &pts {
            for dx in -3..=3 {
                for dy in -3..=3 {
                    put(&mut img, x as i64 + dx, y as i64 + dy, colour);
                }
            }
        }
        // The legend, top right inside the frame.
        let (lx, ly) = (x1 as i64 - 190, TOP as i64 + 8 + i as i64 * (font::HEIGHT as i64 + 3));
        line(&mut img, (lx as f64, ly as f64 + 6.0), (lx as f64 + 22.0, ly as f64 + 6.0), colour, 3);
        text(&mut img, lx + 30, ly, &s.name, black);
    }
    img.save(path).with_context(|| format!("writing {}", path.display()))
}
