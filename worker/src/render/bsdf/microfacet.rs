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

/// Samples a microfacet normal among those visible from `w` (Heitz 2018, "Sampling the
/// GGX Distribution of Visible Normals"), with density [`ggx_visible_pdf`]; `w` below the
/// surface samples as `-w`, and the normal faces +z either way. Against sampling D(m) cos θm
/// this never picks a facet `w` cannot see, and a reflection's weight is F · G1(wi) ≤ 1
/// instead of growing as 1 / cos θo at grazing views (the spheres' rims and the frosted
/// glass: docs/speed.md).
pub(super) fn ggx_sample_visible(w: Vec3, u: Vec2, alpha: f32) -> Vec3 {
    let w = if w.z < 0.0 { -w } else { w };
    // The view in the stretched space where the distribution is the unit hemisphere's.
    let vh = Vec3::new(alpha * w.x, alpha * w.y, w.z).normalize();
    let len2 = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len2 > 0.0 { Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt() } else { Vec3::X };
    let t2 = vh.cross(t1);
    // A point on the disk, its upper half squeezed by the projection of the hemisphere.
    let r = u.x.sqrt();
    let phi = 2.0 * PI * u.y;
    let (sin, cos) = math::sin_cos(phi);
    let p1 = r * cos;
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * (r * sin);
    let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(1e-6)).normalize()
}

/// Density of [`ggx_sample_visible`] returning `m`: G1(w) |w · m| D(m) / |cos θw|, zero for
/// a facet `w` does not see.
pub(super) fn ggx_visible_pdf(w: Vec3, m: Vec3, alpha: f32) -> f32 {
    let wm = w.dot(m);
    if w.z == 0.0 || wm * w.z <= 0.0 {
        return 0.0;
    }
    ggx_g1(w, alpha) * wm.abs() * ggx_d(m, alpha) / w.z.abs()
}

/// Samples a microfacet normal with density D(m) cos θm.
pub(super) fn ggx_sample_normal(u: Vec2, alpha: f32) -> Vec3 {
    let tan2 = alpha * alpha * u.x / (1.0 - u.x).max(1e-12);
    let cos_t = 1.0 / (1.0 + tan2).sqrt();
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (sin, cos) = math::sin_cos(2.0 * PI * u.y);
    Vec3::new(sin_t * cos, sin_t * sin, cos_t)
}

#[cfg(test)]
mod tests {
    use super::super::tests::u2;
    use super::*;

    /// The visible normals' density is what the sampler draws: for views from overhead to
    /// grazing, above and below, the mean of a g(m) that weighs the hemisphere unevenly over
    /// sampled normals equals ∫ g · pdf (by uniform samples of the hemisphere), and the
    /// density integrates to one.
    #[test]
    fn visible_normals_are_drawn_with_their_density() {
        let views = [
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(0.6, 0.2, 0.77),
            Vec3::new(-0.3, 0.94, 0.1),
            Vec3::new(0.5, -0.3, -0.81),
        ];
        for alpha in [0.1f32, 0.3, 0.7] {
            for w in views.map(Vec3::normalize) {
                let g = |m: Vec3| f64::from(1.0 + m.x + 0.5 * m.y * m.y);
                let n = 200_000u64;
                let mut mean_g = 0.0;
                for i in 0..n {
                    let m = ggx_sample_visible(w, u2(i, 11), alpha);
                    assert!(m.z > 0.0 && m.is_normalized(), "{m}");
                    assert!(ggx_visible_pdf(w, m, alpha) > 0.0, "alpha {alpha} w {w}: a facet of density 0");
                    mean_g += g(m);
                }
                let (mut want, mut mass) = (0.0, 0.0);
                for i in 0..n {
                    let u = u2(i, 12);
                    let (z, phi) = (u.x, 2.0 * PI * u.y);
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let m = Vec3::new(r * math::cos(phi), r * math::sin(phi), z);
                    let pdf = f64::from(ggx_visible_pdf(w, m, alpha)) * 2.0 * std::f64::consts::PI;
                    want += g(m) * pdf;
                    mass += pdf;
                }
                let (mean_g, want, mass) = (mean_g / n as f64, want / n as f64, mass / n as f64);
                let tol = if alpha < 0.2 { 0.06 } else { 0.02 };
                assert!((mass - 1.0).abs() < tol, "alpha {alpha} w {w}: density integrates to {mass}");
                assert!(
                    (mean_g - want).abs() < tol * want.abs().max(1.0),
                    "alpha {alpha} w {w}: E[g] {mean_g}, ∫ g pdf {want}"
                );
            }
        }
    }

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
