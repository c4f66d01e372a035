//! The Lambertian BSDF: f = albedo / π, sampled with cosine-weighted directions.

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};

use super::frame::cos_theta;
use super::warp::cosine_hemisphere;
use super::{BsdfSample, Lobe};

/// f(wo, wi) · |cos θi|.
pub(super) fn eval(wo: Vec3, wi: Vec3, albedo: Vec3) -> Vec3 {
    let cos_i = cos_theta(wi);
    if wo.z <= 0.0 || cos_i <= 0.0 {
        return Vec3::ZERO;
    }
    albedo * FRAC_1_PI * cos_i
}

/// Density of [`sample`] returning `wi`.
pub(super) fn pdf(wo: Vec3, wi: Vec3) -> f32 {
    if wo.z <= 0.0 || wi.z <= 0.0 {
        0.0
    } else {
        wi.z * FRAC_1_PI
    }
}

/// Samples the cosine-weighted hemisphere; the weight is the albedo.
pub(super) fn sample(wo: Vec3, u: Vec2, albedo: Vec3) -> Option<BsdfSample> {
    if wo.z <= 0.0 {
        return None;
    }
    let wi = cosine_hemisphere(u);
    (wi.z > 0.0).then_some(BsdfSample { wi, weight: albedo, pdf: wi.z * FRAC_1_PI, lobe: Lobe::Diffuse })
}
