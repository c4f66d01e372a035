//! The GGX microfacet conductor: Fresnel of `eta + i k` times D G / (4 cos θo), sampled by
//! reflecting about a microfacet normal drawn among those visible from `wo`.

use glam::{Vec2, Vec3};

use super::frame::{cos_theta, reflect_about, same_hemisphere};
use super::fresnel::fresnel_conductor;
use super::microfacet::{ggx_d, ggx_g1, ggx_sample_visible, ggx_visible_pdf};
use super::{BsdfSample, Lobe};

/// f(wo, wi) · |cos θi|.
pub(super) fn eval(wo: Vec3, wi: Vec3, eta: Vec3, k: Vec3, alpha: f32) -> Vec3 {
    let cos_i = cos_theta(wi);
    if wo.z <= 0.0 || cos_i <= 0.0 {
        return Vec3::ZERO;
    }
    let h = (wo + wi).normalize();
    let d = ggx_d(h, alpha);
    let g = ggx_g1(wo, alpha) * ggx_g1(wi, alpha);
    fresnel_conductor(wi.dot(h), eta, k) * (d * g / (4.0 * wo.z))
}

/// Density of [`sample`] returning `wi`: the visible normal's density over the
/// reflection's Jacobian, G1(wo) D(h) / (4 cos θo).
pub(super) fn pdf(wo: Vec3, wi: Vec3, alpha: f32) -> f32 {
    if !same_hemisphere(wo, wi) || wo.z <= 0.0 {
        return 0.0;
    }
    let h = (wo + wi).normalize();
    ggx_visible_pdf(wo, h, alpha) / (4.0 * wo.dot(h).abs())
}

/// Reflects `wo` about a sampled visible microfacet normal (weight F · G1(wi)).
pub(super) fn sample(wo: Vec3, u: Vec2, eta: Vec3, k: Vec3, alpha: f32) -> Option<BsdfSample> {
    if wo.z <= 0.0 {
        return None;
    }
    let m = ggx_sample_visible(wo, u, alpha);
    let wi = reflect_about(wo, m);
    if wi.z <= 0.0 {
        return None;
    }
    let pdf = pdf(wo, wi, alpha);
    (pdf > 0.0).then(|| BsdfSample { wi, weight: eval(wo, wi, eta, k, alpha) / pdf, pdf, lobe: Lobe::Glossy })
}
