//! The smooth dielectric: Fresnel-weighted mirror reflection and refraction, chosen by the
//! Fresnel reflectance so the weights stay 1 (up to the radiance scaling). Dirac lobes only.

use glam::Vec3;

use super::frame::{reflect_z, refract_about};
use super::fresnel::fresnel_dielectric;
use super::{BsdfSample, Lobe};

/// Reflection with probability F, else refraction; `None` on total internal reflection's
/// refraction branch (which F = 1 never takes).
pub(super) fn sample(wo: Vec3, u_lobe: f32, eta: f32) -> Option<BsdfSample> {
    let f = fresnel_dielectric(wo.z, eta);
    if u_lobe < f {
        return Some(BsdfSample { wi: reflect_z(wo), weight: Vec3::ONE, pdf: 0.0, lobe: Lobe::Specular });
    }
    // Refraction; the relative index of the side the light goes to.
    let (n, rel) = if wo.z > 0.0 { (Vec3::Z, eta) } else { (Vec3::NEG_Z, 1.0 / eta) };
    let wi = refract_about(wo, n, rel)?;
    // Radiance is compressed into the denser medium: scale by 1/rel².
    Some(BsdfSample { wi, weight: Vec3::splat(1.0 / (rel * rel)), pdf: 0.0, lobe: Lobe::Specular })
}

/// Both lobes at once, each weighted by its Fresnel share (Whitted's reflected and
/// refracted rays): `None` on total internal reflection, whose one lobe [`sample`] takes
/// whatever `u_lobe`. Each weight is [`sample`]'s for that lobe times the probability it
/// picks it, so the pair estimates what one pick does, without the pick's noise.
pub(super) fn split(wo: Vec3, eta: f32) -> Option<[BsdfSample; 2]> {
    let f = fresnel_dielectric(wo.z, eta);
    let (n, rel) = if wo.z > 0.0 { (Vec3::Z, eta) } else { (Vec3::NEG_Z, 1.0 / eta) };
    let wi = refract_about(wo, n, rel).filter(|_| f < 1.0)?;
    Some([
        BsdfSample { wi: reflect_z(wo), weight: Vec3::splat(f), pdf: 0.0, lobe: Lobe::Specular },
        BsdfSample { wi, weight: Vec3::splat((1.0 - f) / (rel * rel)), pdf: 0.0, lobe: Lobe::Specular },
    ])
}
