//! The GGX microfacet dielectric (Walter et al. 2007): reflection and transmission through a
//! rough interface, both lobes chosen by the Fresnel term of the sampled microfacet.

use glam::{Vec2, Vec3};

use super::frame::{reflect_about, refract_about, same_hemisphere};
use super::fresnel::fresnel_dielectric;
use super::microfacet::{ggx_d, ggx_g1, ggx_sample_visible, ggx_visible_pdf};
use super::{BsdfSample, Lobe};

/// The generalised half vector of a rough dielectric (Walter et al. 2007), facing +z, and
/// the relative index for the pair; `None` when the configuration is degenerate.
fn half(wo: Vec3, wi: Vec3, eta: f32) -> Option<(Vec3, f32, bool)> {
    let reflect = same_hemisphere(wo, wi);
    let rel = if reflect {
        1.0
    } else if wo.z > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    let m = wi * rel + wo;
    if m.length_squared() == 0.0 || wo.z == 0.0 || wi.z == 0.0 {
        return None;
    }
    let mut m = m.normalize();
    if m.z < 0.0 {
        m = -m;
    }
    // Back-facing microfacets contribute nothing.
    if m.dot(wi) * wi.z < 0.0 || m.dot(wo) * wo.z < 0.0 {
        return None;
    }
    Some((m, rel, reflect))
}

/// f(wo, wi) · |cos θi| (one value: the dielectric is grey).
pub(super) fn eval(wo: Vec3, wi: Vec3, eta: f32, alpha: f32) -> f32 {
    let Some((m, rel, reflect)) = half(wo, wi, eta) else { return 0.0 };
    let d = ggx_d(m, alpha);
    let g = ggx_g1(wo, alpha) * ggx_g1(wi, alpha);
    let f = fresnel_dielectric(wo.dot(m), eta);
    if reflect {
        // f · |cos θi|.
        return d * g * f / (4.0 * wo.z.abs());
    }
    let denom = wi.dot(m) + wo.dot(m) / rel;
    let ft = d * (1.0 - f) * g * (wi.dot(m) * wo.dot(m) / (wi.z * wo.z * denom * denom)).abs();
    // Radiance scaling for the medium the light ends in.
    ft / (rel * rel) * wi.z.abs()
}

/// Density of [`sample`] returning `wi`.
pub(super) fn pdf(wo: Vec3, wi: Vec3, eta: f32, alpha: f32) -> f32 {
    let Some((m, rel, reflect)) = half(wo, wi, eta) else { return 0.0 };
    // `half` keeps only facets `wo` sees, which the visible density is defined on.
    let pdf_m = ggx_visible_pdf(wo, m, alpha);
    let f = fresnel_dielectric(wo.dot(m), eta);
    if reflect {
        pdf_m / (4.0 * wo.dot(m).abs()) * f
    } else {
        let denom = wi.dot(m) + wo.dot(m) / rel;
        pdf_m * wi.dot(m).abs() / (denom * denom) * (1.0 - f)
    }
}

/// Samples a microfacet normal visible from `wo`, then reflects about it with probability F
/// or refracts.
pub(super) fn sample(wo: Vec3, u_lobe: f32, u: Vec2, eta: f32, alpha: f32) -> Option<BsdfSample> {
    if wo.z == 0.0 {
        return None;
    }
    // The microfacet normal faces +z whichever side wo is on; the Fresnel term
    // and the refraction then see from the sign of wo · m whether the light
    // leaves the inside.
    let m = ggx_sample_visible(wo, u, alpha);
    let f = fresnel_dielectric(wo.dot(m), eta);
    let wi = if u_lobe < f {
        let wi = reflect_about(wo, m);
        if !same_hemisphere(wo, wi) {
            return None;
        }
        wi
    } else {
        let rel = if wo.dot(m) > 0.0 { eta } else { 1.0 / eta };
        let n = if wo.dot(m) > 0.0 { m } else { -m };
        let wi = refract_about(wo, n, rel)?;
        if same_hemisphere(wo, wi) || wi.z == 0.0 {
            return None;
        }
        wi
    };
    let pdf = pdf(wo, wi, eta, alpha);
    if !(pdf > 0.0) {
        return None;
    }
    let weight = Vec3::splat(eval(wo, wi, eta, alpha) / pdf);
    Some(BsdfSample { wi, weight, pdf, lobe: Lobe::Glossy })
}
