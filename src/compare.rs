//! Image error against a reference: what the speed/accuracy figures are made of.

use std::path::Path;

use anyhow::{bail, Context, Result};

/// Errors of an image against a reference, over all pixels and the three channels.
#[derive(Debug, Clone, Copy)]
pub struct ImageError {
    /// Root mean square error.
    pub rmse: f64,
    /// Mean of (x - ref)² / (ref² + 0.01): relative MSE, robust where the reference is dark.
    pub relmse: f64,
    /// Peak signal-to-noise ratio with peak 1 (dB).
    pub psnr: f64,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
}

/// Linear RGB pixels of an image file (EXR as stored; 8-bit formats decoded from sRGB).
pub fn read_linear(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let img = image::open(path).with_context(|| format!("cannot read image {}", path.display()))?;
    Ok(tessera_worker::render::texture::linear_rgb(&img))
}

/// The errors of `image` against `reference`, which must have the same size.
pub fn errors(w: u32, h: u32, image: &[f32], reference: &[f32]) -> ImageError {
    let n = image.len().max(1) as f64;
    let (mut se, mut rel) = (0.0f64, 0.0f64);
    for (&a, &b) in image.iter().zip(reference) {
        let d = f64::from(a) - f64::from(b);
        se += d * d;
        rel += d * d / (f64::from(b) * f64::from(b) + 0.01);
    }
    let mse = se / n;
    ImageError {
        rmse: mse.sqrt(),
        relmse: rel / n,
        psnr: -10.0 * mse.max(1e-300).log10(),
        width: w,
        height: h,
    }
}

/// The `n` pixels that differ most (x, y from the top-left, image value, reference value).
pub fn worst_pixels(
    w: u32,
    image: &[f32],
    reference: &[f32],
    n: usize,
) -> Vec<(u32, u32, [f32; 3], [f32; 3])> {
    let mut px: Vec<(f32, usize)> = image
        .chunks_exact(3)
        .zip(reference.chunks_exact(3))
        .enumerate()
        .map(|(i, (a, b))| (a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>(), i))
        .collect();
    px.sort_by(|a, b| b.0.total_cmp(&a.0));
    px.into_iter()
        .take(n)
        .map(|(_, i)| {
            let rgb = |v: &[f32]| [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
            ((i % w as usize) as u32, (i / w as usize) as u32, rgb(image), rgb(reference))
        })
        .collect()
}

/// An image and its reference, read once, of the same size; with `clamp`, both clamped to
/// [0, clamp] (so that a few pixels that see a light directly do not drown the rest).
/// Returns width, height, image and reference.
pub fn load_pair(
    image: &Path,
    reference: &Path,
    clamp: Option<f32>,
) -> Result<(u32, u32, Vec<f32>, Vec<f32>)> {
    let (w, h, mut a) = read_linear(image)?;
    let (rw, rh, mut b) = read_linear(reference)?;
    if (w, h) != (rw, rh) {
        bail!("{} is {w}x{h} but the reference {} is {rw}x{rh}", image.display(), reference.display());
    }
    if let Some(c) = clamp {
        for v in a.iter_mut().chain(b.iter_mut()) {
            *v = v.clamp(0.0, c);
        }
    }
    Ok((w, h, a, b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_no_error() {
        let e = errors(1, 1, &[0.5, 0.2, 0.1], &[0.5, 0.2, 0.1]);
        assert_eq!(e.rmse, 0.0);
        let e = errors(1, 1, &[1.0, 0.0, 0.0], &[0.0, 0.0, 0.0]);
        assert!((e.rmse - (1.0f64 / 3.0).sqrt()).abs() < 1e-12);
    }
}
