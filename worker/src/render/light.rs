//! Lights of a Whitted scene.

use glam::Vec3;

/// A point light of radiant intensity `intensity` (per channel): the irradiance at
/// distance d is intensity / d².
#[derive(Debug, Clone)]
pub struct PointLight {
    /// Position.
    pub position: Vec3,
    /// Radiant intensity per channel (colour times strength).
    pub intensity: Vec3,
}
