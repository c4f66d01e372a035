//! Rendering one batch: pixels × a sample range, summed per pixel in fixed point.

use std::ops::Range;

use glam::UVec2;

use crate::aov;
use crate::render::sampler::MOST_PLANNED as PLANNED;
use crate::render::Scene;
use tessera_film::aov::Layout;
use tessera_film::fixed;

/// The per-pixel sums of a rendered batch.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BatchSums {
    /// r, g, b fixed-point sums per pixel, in the batch's pixel order.
    pub sums: Vec<u64>,
    /// Samples whose radiance was NaN or infinite (counted as black).
    pub nonfinite: u64,
    /// Per pixel, the sum of the fixed-point luminance ((r + g + b) / 3, rounded down) of
    /// the samples with an even index; empty unless asked for (jobs with a noise target).
    pub even: Vec<u64>,
    /// Per pixel, the AOV layers' sums in `tessera_film::aov`'s order; empty unless asked.
    pub aov: Vec<u64>,
}

/// Which sums a batch returns besides the radiance sums.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sums {
    /// The radiance sums only.
    Radiance,
    /// Also the luminance of even-indexed samples (jobs with a noise target).
    WithEven,
}

/// Renders samples `samples` of each pixel. The result depends only on the scene and the
/// arguments: fixed-point sums make it independent of how the work is split.
pub fn render_batch(scene: &Scene, pixels: &[UVec2], samples: Range<u32>, want: Sums) -> BatchSums {
    render_batch_layers(scene, pixels, samples, want, Layout::default())
}

/// `render_batch`, with the AOV layers of `layout` too: each sample's first hit, found by
/// a camera ray of its own (`aov::first_hit`), so the radiance sums are the same bits.
pub fn render_batch_layers(
    scene: &Scene,
    pixels: &[UVec2],
    samples: Range<u32>,
    want: Sums,
    layout: Layout,
) -> BatchSums {
    let even = want == Sums::WithEven;
    let mut sampler = scene.sampler();
    let mut aov_sampler = scene.sampler();
    let per = layout.per_pixel();
    let background = aov::background_albedo(scene);
    let mut sums = Vec::with_capacity(pixels.len() * 3);
    let mut evens = Vec::with_capacity(if even { pixels.len() } else { 0 });
    let mut layers = vec![0u64; pixels.len() * per];
    let mut nonfinite = 0;
    for (k, &pixel) in pixels.iter().enumerate() {
        let mut acc = [0u64; 3];
        let mut acc_even = 0u64;
        for index in samples.clone() {
            // Runs of as many samples as the sampler's table holds: a farm's second pass
            // renders all but one of a pixel's samples in one batch.
            if (index - samples.start).is_multiple_of(PLANNED) {
                sampler.plan_pixel(pixel, index..samples.end.min(index.saturating_add(PLANNED)));
            }
            if per > 0 {
                let hit = aov::first_hit(scene, &mut aov_sampler, pixel, index);
                layout.accumulate(&mut layers[k * per..(k + 1) * per], hit.as_ref(), background);
            }
            let l = scene.render_sample(&mut sampler, pixel, index);
            match (fixed::to_fixed(l.x), fixed::to_fixed(l.y), fixed::to_fixed(l.z)) {
                (Some(r), Some(g), Some(b)) => {
                    acc[0] += r;
                    acc[1] += g;
                    acc[2] += b;
                    if index % 2 == 0 {
                        acc_even += (r + g + b) / 3;
                    }
                }
                _ => nonfinite += 1,
            }
        }
        sums.extend_from_slice(&acc);
        if even {
            evens.push(acc_even);
        }
    }
    BatchSums { sums, nonfinite, even: evens, aov: layers }
}
