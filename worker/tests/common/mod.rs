//! Rendering a scene text in this process, for the renderer's tests.

use glam::UVec2;
use tessera_film::fixed;
use tessera_worker::batch::{render_batch, Sums};
use tessera_worker::build::parse_scene;

/// Renders a scene text; returns width, height and linear RGB, top row first. Fails on any
/// non-finite sample or pixel: no test image may hide a NaN.
pub fn render(text: &str) -> (u32, u32, Vec<[f32; 3]>) {
    let scene = parse_scene("test.toml", text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    let (w, h) = (scene.width, scene.height);
    let mut out = Vec::with_capacity((w * h) as usize);
    for row in 0..h {
        let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, h - 1 - row)).collect();
        let r = render_batch(&scene, &pixels, 0..scene.spp, Sums::Radiance);
        assert_eq!(r.nonfinite, 0, "non-finite samples in row {row}");
        out.extend(r.sums.chunks(3).map(|s| [0, 1, 2].map(|c| fixed::mean(s[c], scene.spp))));
    }
    assert!(out.iter().flatten().all(|v| v.is_finite() && *v >= 0.0), "a pixel is not finite");
    (w, h, out)
}

/// Mean of the three channels.
pub fn lum(p: [f32; 3]) -> f32 {
    (p[0] + p[1] + p[2]) / 3.0
}
