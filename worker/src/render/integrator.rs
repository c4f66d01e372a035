//! Whitted's transport: direct light from every light with shadow rays, then recursive
//! mirror reflection and refraction.

use glam::Vec3;

use super::geometry::{offset_ray_origin, Ray};
use super::Scene;

/// Reflects `v` (pointing away from the surface) about the normal `n`.
#[inline]
pub fn reflect(v: Vec3, n: Vec3) -> Vec3 {
    2.0 * v.dot(n) * n - v
}

/// Refracts `wi` (pointing away from the surface, on the side of `n`) into a medium with
/// relative index `eta` (inside over outside); `None` on total internal reflection.
#[inline]
pub fn refract(wi: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = wi.dot(n);
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((-wi / eta + (cos_i / eta - cos_t) * n).normalize())
}

/// Light that reaches `to` from `from` through the scene: zero behind an opaque surface,
/// tinted by the transmission of every transparent surface crossed (the classic model's
/// coloured shadows; refraction of shadow rays is not followed).
fn transmittance(scene: &Scene, from: Vec3, to: Vec3) -> Vec3 {
    let d = to - from;
    let dist = d.length();
    let ray = Ray::new(from, d / dist);
    let mut tr = Vec3::ONE;
    // Stop just short of the light: rounding of `dist` must not count the light's own
    // position as a blocker.
    scene.for_each_hit(&ray, dist * (1.0 - 1e-5), |hit| {
        tr *= scene.materials[hit.material as usize].transmit;
        tr != Vec3::ZERO
    });
    tr
}

/// The radiance arriving along `ray`, recursion depth `depth`.
pub fn radiance(scene: &Scene, ray: &Ray, depth: u32) -> Vec3 {
    let Some(hit) = scene.intersect(ray, f32::INFINITY) else {
        return scene.background;
    };
    let m = &scene.materials[hit.material as usize];
    let wo = -ray.dir;
    let entering = hit.n.dot(wo) >= 0.0;
    // The normal on the side the ray comes from.
    let n = if entering { hit.n } else { -hit.n };

    let mut l = scene.ambient * m.ambient * m.color;
    for light in &scene.lights {
        let to_light = light.position - hit.p;
        let dist2 = to_light.length_squared();
        if dist2 == 0.0 {
            continue;
        }
        let wi = to_light / dist2.sqrt();
        let cos = n.dot(wi);
        if cos <= 0.0 {
            continue;
        }
        let origin = offset_ray_origin(hit.p, hit.p_error, n, wi);
        let tr = transmittance(scene, origin, light.position);
        if tr == Vec3::ZERO {
            continue;
        }
        let irradiance = light.intensity * tr / dist2;
        let mut f = m.color * (m.diffuse * cos);
        if m.specular > 0.0 {
            let highlight = reflect(wi, n).dot(wo).max(0.0).powf(m.shininess);
            f += Vec3::splat(m.specular * highlight);
        }
        l += irradiance * f;
    }

    if depth + 1 >= scene.max_depth {
        return l;
    }
    let mut mirror = m.reflect;
    if m.transmit != Vec3::ZERO {
        let eta = if entering { m.ior } else { 1.0 / m.ior };
        match refract(wo, n, eta) {
            Some(wt) => {
                let origin = offset_ray_origin(hit.p, hit.p_error, n, wt);
                l += m.transmit * radiance(scene, &Ray::new(origin, wt), depth + 1);
            }
            // Total internal reflection: the transmitted light is reflected instead.
            None => mirror += m.transmit,
        }
    }
    if mirror != Vec3::ZERO {
        let wr = reflect(wo, n);
        let origin = offset_ray_origin(hit.p, hit.p_error, n, wr);
        l += mirror * radiance(scene, &Ray::new(origin, wr), depth + 1);
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snell_and_total_internal_reflection() {
        let n = Vec3::Y;
        let wi = Vec3::new(0.5f32.sqrt(), 0.5f32.sqrt(), 0.0);
        let wt = refract(wi, n, 1.5).unwrap();
        // sin θt = sin θi / η
        assert!((wt.x.abs() - 0.5f32.sqrt() / 1.5).abs() < 1e-6 && wt.y < 0.0);
        assert!(refract(wi, n, 1.0 / 1.5).is_none());
        // Index 1: the ray goes straight on.
        assert!((refract(wi, n, 1.0).unwrap() + wi).length() < 1e-6);
    }
}
