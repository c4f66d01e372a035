//! The AOV layers' samples: what a camera ray finds at its first hit (reflectance, shading
//! normal, distance), for the layers of `tessera_film::aov`.
//!
//! Each sample traces its own camera ray with a sampler of its own, drawing the same film,
//! lens and time dimensions as the radiance sample (`Scene::camera_ray`: a dimension is a
//! pure function of seed, pixel, index and dimension number), so it is the radiance
//! sample's ray exactly, and the radiance path's sampler stream is untouched: images
//! rendered with or without layers have the same bits.

use glam::{UVec2, Vec3};

use crate::render::{Sampler, Scene};
use tessera_film::aov::FirstHit;

/// An emitted colour as an albedo in [0, 1]: brighter colours scaled down to a maximum
/// component of 1, keeping their hue (the denoiser wants the colour of what is seen,
/// independent of illumination, within [0, 1]).
pub(crate) fn emitted_albedo(c: Vec3) -> [f32; 3] {
    let m = c.max_element();
    let c = if m > 1.0 && m.is_finite() { c / m } else { c };
    c.clamp(Vec3::ZERO, Vec3::ONE).to_array()
}

/// The albedo a sample that hits nothing contributes: the background's colour.
pub fn background_albedo(scene: &Scene) -> [f32; 3] {
    emitted_albedo(scene.background)
}

/// What sample `index` of `pixel`'s camera ray hits first; `None` if it escapes.
/// `sampler` is the layers' own (it is restarted at the sample).
pub fn first_hit(scene: &Scene, sampler: &mut Sampler, pixel: UVec2, index: u32) -> Option<FirstHit> {
    let (ray, time) = scene.camera_ray(sampler, pixel, index);
    let mut sh = scene.intersect_coherent(&ray, f32::INFINITY, time)?;
    // Facing the camera, as the integrator shades opaque surfaces from either side.
    let ns = if sh.hit.ns.dot(ray.dir) > 0.0 { -sh.hit.ns } else { sh.hit.ns };
    let albedo = match sh.light {
        Some(li) => emitted_albedo(scene.world.lights[li as usize].emitted(sh.hit.n, ray.dir)),
        None => {
            let material = &scene.world.materials[sh.material as usize];
            if material.is_textured() {
                scene.complete_uv(&mut sh);
            }
            material.albedo(&scene.world.textures, sh.hit.p, sh.hit.uv).to_array()
        }
    };
    Some(FirstHit { albedo, normal: ns.normalize_or_zero().to_array(), distance: sh.hit.t })
}
