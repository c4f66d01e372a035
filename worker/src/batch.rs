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
    let mut rays = Vec::with_capacity(PLANNED.min(samples.len() as u32) as usize);
    let (mut run_start, mut camera_dimensions) = (0, 0);
    for (k, &pixel) in pixels.iter().enumerate() {
        let mut acc = [0u64; 3];
        let mut acc_even = 0u64;
        for index in samples.clone() {
            // Runs of as many samples as the sampler's table holds: a farm's second pass
            // renders all but one of a pixel's samples in one batch. The run's camera
            // rays are made first (`Scene::camera_rays`).
            if (index - samples.start).is_multiple_of(PLANNED) {
                let run = index..samples.end.min(index.saturating_add(PLANNED));
                sampler.plan_pixel(pixel, run.clone());
                run_start = index;
                camera_dimensions = scene.camera_rays(&mut sampler, pixel, run, &mut rays);
            }
            if per > 0 {
                let hit = aov::first_hit(scene, &mut aov_sampler, pixel, index);
                layout.accumulate(&mut layers[k * per..(k + 1) * per], hit.as_ref(), background);
            }
            let camera = rays[(index - run_start) as usize];
            let l = scene.render_from(&mut sampler, pixel, index, camera, camera_dimensions);
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

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_description::bundle::Bundle;

    /// A batch traces camera rays made a run ahead (`Scene::camera_rays`), and its sums
    /// are the bits of rendering each sample alone (`Scene::render_sample`, the sampler
    /// positioned afresh at each), with a lens, with motion blur's time dimension, and in
    /// runs that start inside a pixel's pattern and cross the table's limit, and with several
    /// diffuse rays a sample.
    #[test]
    fn camera_rays_made_ahead_give_each_sample_s_bits() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
        for (name, spp, samples, rays) in [
            ("spheres.toml", 512, 3..300, 1),
            ("motion_blur.toml", 16, 0..16, 1),
            ("cornell.toml", 4, 1..3, 1),
            // Several diffuse rays, each set drawn from the sample's own place in the pattern.
            ("environment.toml", 16, 2..16, 4),
        ] {
            let mut scene = crate::build::parse_bundle(&Bundle::read(&root.join(name)).unwrap()).unwrap();
            scene.apply(Some(spp), Some((8, 6)));
            scene.diffuse_rays = rays;
            let pixels: Vec<UVec2> = (0..6).map(|i| UVec2::new(i + 1, i % 6)).collect();
            let batch = render_batch(&scene, &pixels, samples.clone(), Sums::Radiance);
            let mut sampler = scene.sampler();
            let alone: Vec<u64> = pixels
                .iter()
                .flat_map(|&pixel| {
                    let mut acc = [0u64; 3];
                    for index in samples.clone() {
                        let l = scene.render_sample(&mut sampler, pixel, index);
                        for (a, v) in acc.iter_mut().zip([l.x, l.y, l.z]) {
                            *a += fixed::to_fixed(v).unwrap_or(0);
                        }
                    }
                    acc
                })
                .collect();
            assert_eq!(batch.sums, alone, "{name}");
        }
    }
}
