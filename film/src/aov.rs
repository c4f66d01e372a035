//! AOV layers (arbitrary output variables): per-pixel first-hit albedo, shading normal and
//! depth, accumulated beside the radiance framebuffer in the same fixed point, so that
//! they too are the same bits for any worker count, merge order or resume.
//!
//! Per pixel a layout's values follow one another in this order, each a sum over the
//! pixel's samples of a fixed-point value (`fixed::SCALE` units):
//! - albedo: 3 sums of the reflectance, each sample's clamped to `[0, 1]`;
//! - normal: 3 sums of `n + 1` (the unit normal offset by one, so that a signed component
//!   in `[-1, 1]` is an unsigned `[0, 2]`; a sample that hits nothing adds 1, i.e. a zero
//!   normal); the mean minus one is the mean normal;
//! - depth: the number of samples that hit something, then the sum of their camera-ray
//!   distances (clamped to `[0, fixed::SAMPLE_MAX]`); the mean is over hits only, and a
//!   pixel none of whose samples hit anything has infinite depth.
//!
//! The sample count of a pixel is the framebuffer's: every radiance sample is also an AOV
//! sample. The layers are held in chunks behind `Arc`s, so that a snapshot under the
//! coordinator's lock copies pointers, and a merge copies only the chunks a snapshot holds.

use std::sync::Arc;

use crate::fixed;
use crate::quadtree::Quad;

/// Which layers a job keeps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Layout {
    /// First-hit reflectance, RGB.
    pub albedo: bool,
    /// First-hit world-space shading normal, XYZ.
    pub normal: bool,
    /// Camera-ray distance to the first hit.
    pub depth: bool,
}

/// Bits of `Layout::bits`, as the wire carries them.
pub const ALBEDO_BIT: u32 = 1;
/// See `ALBEDO_BIT`.
pub const NORMAL_BIT: u32 = 2;
/// See `ALBEDO_BIT`.
pub const DEPTH_BIT: u32 = 4;

/// One fixed-point unit of albedo or normal (1.0).
const ONE: u64 = 1 << fixed::FRACTION_BITS;

impl Layout {
    /// No layers.
    pub fn is_empty(&self) -> bool {
        !(self.albedo || self.normal || self.depth)
    }

    /// The `u64` values a pixel holds.
    pub fn per_pixel(&self) -> usize {
        3 * usize::from(self.albedo) + 3 * usize::from(self.normal) + 2 * usize::from(self.depth)
    }

    /// As wire bits.
    pub fn bits(&self) -> u32 {
        ALBEDO_BIT * u32::from(self.albedo)
            + NORMAL_BIT * u32::from(self.normal)
            + DEPTH_BIT * u32::from(self.depth)
    }

    /// From wire bits; `None` if a bit names no layer.
    pub fn from_bits(bits: u32) -> Option<Layout> {
        (bits & !(ALBEDO_BIT | NORMAL_BIT | DEPTH_BIT) == 0).then_some(Layout {
            albedo: bits & ALBEDO_BIT != 0,
            normal: bits & NORMAL_BIT != 0,
            depth: bits & DEPTH_BIT != 0,
        })
    }

    /// Adds one sample's first-hit values to a pixel's `per_pixel()` accumulators. `hit` is
    /// `None` when the camera ray hit nothing. Non-finite inputs count as 0 (a zero normal,
    /// a miss for depth), so that nothing but finite sums can come out.
    pub fn accumulate(&self, acc: &mut [u64], hit: Option<&FirstHit>, background_albedo: [f32; 3]) {
        let mut k = 0;
        if self.albedo {
            let a = hit.map_or(background_albedo, |h| h.albedo);
            for c in a {
                acc[k] += unit(c.clamp(0.0, 1.0));
                k += 1;
            }
        }
        if self.normal {
            let n = hit.map_or([0.0; 3], |h| h.normal);
            for c in n {
                acc[k] += unit(c.clamp(-1.0, 1.0) + 1.0);
                k += 1;
            }
        }
        if self.depth {
            if let Some(d) = hit.and_then(|h| fixed::to_fixed(h.distance)) {
                acc[k] += 1;
                acc[k + 1] += d;
            }
        }
    }
}

/// Fixed point of a value already in range; NaN is 0.
fn unit(v: f32) -> u64 {
    if v.is_finite() {
        (f64::from(v) * fixed::SCALE).round() as u64
    } else {
        0
    }
}

/// What a camera ray found at its first hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirstHit {
    /// Reflectance, in [0, 1] (clamped when accumulated).
    pub albedo: [f32; 3],
    /// World-space unit shading normal.
    pub normal: [f32; 3],
    /// Distance along the camera ray.
    pub distance: f32,
}

/// Why a batch's AOV sums could not be merged.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AovError {
    /// Not `per_pixel` sums for each pixel.
    #[error("expected {expected} AOV sums ({per_pixel} per pixel), got {got}")]
    WrongLength {
        /// Pixels × per pixel.
        expected: usize,
        /// Per pixel.
        per_pixel: usize,
        /// What came.
        got: usize,
    },
    /// A sum no `samples` samples can produce.
    #[error("AOV sum {value} of pixel {x},{y} (the {layer} layer) is impossible for {samples} samples")]
    OutOfRange {
        /// Column.
        x: u32,
        /// Row from the bottom.
        y: u32,
        /// The layer.
        layer: &'static str,
        /// The value.
        value: u64,
        /// Samples it claims to hold.
        samples: u32,
    },
}

/// Pixels per chunk: 4096 pixels of all three layers are 256 KB, so a snapshot of a 4K
/// frame holds ~2000 pointers and a merge into a chunk a snapshot still holds copies a
/// fraction of a millisecond.
const CHUNK: usize = 4096;

/// A job's AOV sums, pixel index `y · width + x` (paper coordinates, y up).
#[derive(Debug, Clone, PartialEq)]
pub struct AovLayers {
    layout: Layout,
    width: u32,
    height: u32,
    chunks: Vec<Arc<Vec<u64>>>,
}

impl AovLayers {
    /// Empty layers for a `width × height` image (none at all for an empty layout).
    pub fn new(layout: Layout, width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        let per = layout.per_pixel();
        let chunks = if per == 0 {
            Vec::new()
        } else {
            (0..n.div_ceil(CHUNK)).map(|c| Arc::new(vec![0; (n - c * CHUNK).min(CHUNK) * per])).collect()
        };
        AovLayers { layout, width, height, chunks }
    }

    /// The bytes the layers of a `width × height` image hold: what a job's memory estimate
    /// counts before they are allocated.
    pub fn bytes_for(layout: Layout, width: u32, height: u32) -> u64 {
        if layout.is_empty() {
            return 0;
        }
        let n = u64::from(width) * u64::from(height);
        let per_chunk = (std::mem::size_of::<Vec<u64>>() + 2 * std::mem::size_of::<usize>()) as u64;
        n * layout.per_pixel() as u64 * 8 + n.div_ceil(CHUNK as u64) * per_chunk
    }

    /// Which layers.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    fn slot(&self, x: u32, y: u32) -> (usize, usize) {
        let g = y as usize * self.width as usize + x as usize;
        (g / CHUNK, (g % CHUNK) * self.layout.per_pixel())
    }

    /// Checks that `sums` can be `samples` samples of each of `quads`' pixels.
    pub fn check(&self, quads: &[Quad], samples: u32, sums: &[u64]) -> Result<(), AovError> {
        let per = self.layout.per_pixel();
        if sums.len() != quads.len() * per {
            return Err(AovError::WrongLength {
                expected: quads.len() * per,
                per_pixel: per,
                got: sums.len(),
            });
        }
        if per == 0 {
            return Ok(());
        }
        let n = u64::from(samples);
        for (q, s) in quads.iter().zip(sums.chunks_exact(per)) {
            let bad = |layer, value| AovError::OutOfRange { x: q.x, y: q.y, layer, value, samples };
            let mut k = 0;
            if self.layout.albedo {
                if let Some(&v) = s[k..k + 3].iter().find(|&&v| v > n * ONE) {
                    return Err(bad("albedo", v));
                }
                k += 3;
            }
            if self.layout.normal {
                if let Some(&v) = s[k..k + 3].iter().find(|&&v| v > 2 * n * ONE) {
                    return Err(bad("normal", v));
                }
                k += 3;
            }
            if self.layout.depth {
                let (hits, sum) = (s[k], s[k + 1]);
                if hits > n {
                    return Err(bad("depth", hits));
                }
                if sum > fixed::max_sum(hits as u32) {
                    return Err(bad("depth", sum));
                }
            }
        }
        Ok(())
    }

    /// Adds a checked batch's sums (`check` first: this refuses what it refuses).
    pub fn merge(&mut self, quads: &[Quad], samples: u32, sums: &[u64]) -> Result<(), AovError> {
        self.check(quads, samples, sums)?;
        let per = self.layout.per_pixel();
        if per == 0 {
            return Ok(());
        }
        for (q, s) in quads.iter().zip(sums.chunks_exact(per)) {
            let (c, i) = self.slot(q.x, q.y);
            let chunk = Arc::make_mut(&mut self.chunks[c]);
            for (acc, v) in chunk[i..i + per].iter_mut().zip(s) {
                *acc = acc.saturating_add(*v);
            }
        }
        Ok(())
    }

    /// Empties pixel `(x, y)` (a lying worker's pixel, before it is rendered again).
    pub fn reset(&mut self, x: u32, y: u32) {
        let per = self.layout.per_pixel();
        if per == 0 || x >= self.width || y >= self.height {
            return;
        }
        let (c, i) = self.slot(x, y);
        Arc::make_mut(&mut self.chunks[c])[i..i + per].fill(0);
    }

    /// A copy of every sum, pixel-major (for checkpoints).
    pub fn sums(&self) -> Vec<u64> {
        self.chunks.iter().flat_map(|c| c.iter().copied()).collect()
    }

    /// Layers holding `sums` (a checkpoint read back), or `None` if their length does not
    /// fit the size and layout.
    pub fn from_sums(layout: Layout, width: u32, height: u32, sums: Vec<u64>) -> Option<Self> {
        let per = layout.per_pixel();
        if sums.len() != width as usize * height as usize * per {
            return None;
        }
        let mut layers = AovLayers::new(layout, width, height);
        let mut rest = &sums[..];
        for chunk in &mut layers.chunks {
            let c = Arc::get_mut(chunk).expect("not shared yet");
            let len = c.len();
            c.copy_from_slice(&rest[..len]);
            rest = &rest[len..];
        }
        Some(layers)
    }

    /// The layers resolved to floats, top row first (image order), with each pixel's
    /// sample count from `count(x, y)` (the framebuffer's). Pixels without samples are
    /// zero (infinitely far for depth).
    pub fn resolve(&self, count: impl Fn(u32, u32) -> u32) -> Resolved {
        self.resolve_rows(0, self.height, count)
    }

    /// As [`AovLayers::resolve`], rows `row0 .. row0 + h` only (y up, as the framebuffer
    /// counts them): one frame of a sequence's stacked layers, top row first. `count`
    /// takes the stacked (absolute) coordinates.
    pub fn resolve_rows(&self, row0: u32, h: u32, count: impl Fn(u32, u32) -> u32) -> Resolved {
        let w = self.width;
        let h = h.min(self.height.saturating_sub(row0));
        let n = w as usize * h as usize;
        let mut out = Resolved {
            albedo: Vec::with_capacity(if self.layout.albedo { 3 * n } else { 0 }),
            normal: Vec::with_capacity(if self.layout.normal { 3 * n } else { 0 }),
            depth: Vec::with_capacity(if self.layout.depth { n } else { 0 }),
        };
        let per = self.layout.per_pixel();
        if per == 0 {
            return out;
        }
        for row in 0..h {
            let y = row0 + h - 1 - row;
            for x in 0..w {
                let (c, i) = self.slot(x, y);
                let s = &self.chunks[c][i..i + per];
                let samples = count(x, y);
                let mut k = 0;
                if self.layout.albedo {
                    out.albedo.extend(s[k..k + 3].iter().map(|&v| fixed::mean(v, samples)));
                    k += 3;
                }
                if self.layout.normal {
                    let m = |v: u64| if samples == 0 { 0.0 } else { fixed::mean(v, samples) - 1.0 };
                    out.normal.extend(s[k..k + 3].iter().map(|&v| m(v)));
                    k += 3;
                }
                if self.layout.depth {
                    let hits = s[k].min(u64::from(u32::MAX)) as u32;
                    out.depth.push(if hits == 0 { f32::INFINITY } else { fixed::mean(s[k + 1], hits) });
                }
            }
        }
        out
    }
}

/// Resolved layers, top row first; a layer the layout lacks is empty.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Resolved {
    /// RGB, 3 floats a pixel.
    pub albedo: Vec<f32>,
    /// XYZ, 3 floats a pixel.
    pub normal: Vec<f32>,
    /// One float a pixel.
    pub depth: Vec<f32>,
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: Layout = Layout { albedo: true, normal: true, depth: true };

    fn quad(x: u32, y: u32) -> Quad {
        Quad { x, y, w: 1, h: 1 }
    }

    fn sample(layout: Layout, hit: Option<&FirstHit>) -> Vec<u64> {
        let mut acc = vec![0; layout.per_pixel()];
        layout.accumulate(&mut acc, hit, [0.25; 3]);
        acc
    }

    #[test]
    fn bits_round_trip_and_unknown_bits_are_refused() {
        for bits in 0..8 {
            assert_eq!(Layout::from_bits(bits).unwrap().bits(), bits);
        }
        assert_eq!(Layout::from_bits(8), None);
    }

    #[test]
    fn accumulates_resolves_and_offsets_signed_normals() {
        let hit = FirstHit { albedo: [0.8, 0.5, 2.0], normal: [0.0, -1.0, 0.0], distance: 3.5 };
        let mut layers = AovLayers::new(ALL, 2, 1);
        let mut s = sample(ALL, Some(&hit));
        s.iter_mut().zip(sample(ALL, Some(&hit))).for_each(|(a, b)| *a += b);
        let miss = sample(ALL, None);
        let mut both = vec![0; 16];
        both[..8].copy_from_slice(&s);
        let mut miss2 = miss.clone();
        miss2.iter_mut().zip(&miss).for_each(|(a, b)| *a += b);
        both[8..].copy_from_slice(&miss2);
        layers.merge(&[quad(0, 0), quad(1, 0)], 2, &both).unwrap();
        let r = layers.resolve(|_, _| 2);
        assert_eq!(&r.albedo[..3], &[0.8, 0.5, 1.0]);
        assert_eq!(&r.albedo[3..], &[0.25; 3]);
        assert_eq!(&r.normal[..3], &[0.0, -1.0, 0.0]);
        assert_eq!(&r.normal[3..], &[0.0; 3]);
        assert_eq!(r.depth, vec![3.5, f32::INFINITY]);
    }

    #[test]
    fn impossible_sums_are_refused_and_change_nothing() {
        let mut layers = AovLayers::new(ALL, 1, 1);
        let before = layers.clone();
        let q = [quad(0, 0)];
        assert!(matches!(layers.merge(&q, 1, &[0; 7]), Err(AovError::WrongLength { .. })));
        let mut s = vec![0; 8];
        s[0] = ONE + 1;
        assert!(matches!(layers.merge(&q, 1, &s), Err(AovError::OutOfRange { layer: "albedo", .. })));
        s[0] = 0;
        s[5] = 2 * ONE + 1;
        assert!(matches!(layers.merge(&q, 1, &s), Err(AovError::OutOfRange { layer: "normal", .. })));
        s[5] = 0;
        s[6] = 2;
        assert!(matches!(layers.merge(&q, 1, &s), Err(AovError::OutOfRange { layer: "depth", .. })));
        s[6] = 0;
        s[7] = 1;
        assert!(matches!(layers.merge(&q, 1, &s), Err(AovError::OutOfRange { layer: "depth", .. })));
        assert_eq!(layers, before);
    }

    #[test]
    fn sums_round_trip_across_chunks_and_reset_empties_a_pixel() {
        let layout = Layout { albedo: false, normal: false, depth: true };
        let (w, h) = (100, 50);
        let mut layers = AovLayers::new(layout, w, h);
        let quads: Vec<Quad> = (0..h).flat_map(|y| (0..w).map(move |x| quad(x, y))).collect();
        let sums: Vec<u64> = quads.iter().flat_map(|q| [1, u64::from(q.x + q.y) << 24]).collect();
        layers.merge(&quads, 1, &sums).unwrap();
        let back = AovLayers::from_sums(layout, w, h, layers.sums()).unwrap();
        assert_eq!(back, layers);
        assert!(AovLayers::from_sums(layout, w, h, vec![0; 3]).is_none());
        layers.reset(3, 2);
        let r = layers.resolve(|_, _| 1);
        assert_eq!(r.depth[((h - 1 - 2) * w + 3) as usize], f32::INFINITY);
        assert_eq!(r.depth[((h - 1) * w + 5) as usize], 5.0);
        assert!(AovLayers::bytes_for(layout, w, h) >= u64::from(w * h) * 16);
    }
}
