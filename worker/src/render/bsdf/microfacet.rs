//! The GGX (Trowbridge–Reitz) microfacet distribution with separable Smith shadowing, shared
//! by the rough conductor and the rough dielectric.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};
use tessera_description::math;

/// GGX (Trowbridge–Reitz) normal distribution.
pub fn ggx_d(m: Vec3, alpha: f32) -> f32 {
    let cos2 = m.z * m.z;
    if cos2 <= 0.0 {
        return 0.0;
    }
    let tan2 = (1.0 - cos2) / cos2;
    let a2 = alpha * alpha;
    let denom = PI * cos2 * cos2 * (a2 + tan2) * (a2 + tan2);
    a2 / denom
}

/// Smith's shadowing for one direction, GGX.
pub fn ggx_g1(w: Vec3, alpha: f32) -> f32 {
    let cos2 = w.z * w.z;
    if cos2 <= 0.0 {
        return 0.0;
    }
    let tan2 = (1.0 - cos2) / cos2;
    2.0 / (1.0 + (1.0 + alpha * alpha * tan2).sqrt())
}

/// Samples a microfacet normal with density D(m) cos θm.
pub(super) fn ggx_sample_normal(u: Vec2, alpha: f32) -> Vec3 {
    let tan2 = alpha * alpha * u.x / (1.0 - u.x).max(1e-12);
    let cos_t = 1.0 / (1.0 + tan2).sqrt();
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_t * math::cos(phi), sin_t * math::sin(phi), cos_t)
}

#[cfg(test)]
mod tests {
    use super::super::tests::u2;
    use super::*;

    #[test]
    fn ggx_distribution_is_normalised() {
        // ∫ D(m) cos θm dω = 1, by Monte Carlo with uniform hemisphere samples.
        for alpha in [0.05f32, 0.3, 1.0] {
            let n = 200_000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let u = u2(i, 7);
                let z = u.x;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * u.y;
                let m = Vec3::new(r * math::cos(phi), r * math::sin(phi), z);
                sum += f64::from(ggx_d(m, alpha) * m.z) * 2.0 * std::f64::consts::PI;
            }
            let est = sum / n as f64;
            let tol = if alpha < 0.1 { 0.15 } else { 0.02 };
            assert!((est - 1.0).abs() < tol, "alpha {alpha}: {est}");
        }
    }
}
