//! The ideal mirror: perfect specular reflection times a constant, no Fresnel. A Dirac lobe, so
//! it only samples (eval and pdf are 0).

use glam::Vec3;

use super::frame::reflect_z;
use super::{BsdfSample, Lobe};

/// The mirrored direction, weighted by the reflectance.
pub(super) fn sample(wo: Vec3, reflectance: Vec3) -> Option<BsdfSample> {
    (wo.z > 0.0).then_some(BsdfSample {
        wi: reflect_z(wo),
        weight: reflectance,
        pdf: 0.0,
        lobe: Lobe::Specular,
    })
}
