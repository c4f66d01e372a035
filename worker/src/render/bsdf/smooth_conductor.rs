//! The smooth conductor (roughness 0): mirror reflection weighted by the conductor's Fresnel
//! reflectance. A Dirac lobe, so it only samples.

use glam::Vec3;

use super::frame::reflect_z;
use super::fresnel::fresnel_conductor;
use super::{BsdfSample, Lobe};

/// The mirrored direction, weighted by the Fresnel reflectance of `eta + i k`.
pub(super) fn sample(wo: Vec3, eta: Vec3, k: Vec3) -> Option<BsdfSample> {
    (wo.z > 0.0).then(|| BsdfSample {
        wi: reflect_z(wo),
        weight: fresnel_conductor(wo.z, eta, k),
        pdf: 0.0,
        lobe: Lobe::Specular,
    })
}
