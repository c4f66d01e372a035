//! Materials of the classic (Whitted / Phong) model.

use glam::Vec3;

/// The classic model's material: ambient, diffuse colour, Phong highlight, and mirror
/// reflection and refraction coefficients. Colours are reflectances of the classic model,
/// not energy-conserving BSDFs.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Diffuse colour.
    pub color: Vec3,
    /// Fraction of the scene's ambient light reflected (times `color`).
    pub ambient: f32,
    /// Diffuse coefficient (times `color`).
    pub diffuse: f32,
    /// Phong highlight coefficient (white highlight).
    pub specular: f32,
    /// Phong exponent.
    pub shininess: f32,
    /// Mirror reflection per channel.
    pub reflect: Vec3,
    /// Refraction (transmission) per channel; also tints light passing through.
    pub transmit: Vec3,
    /// Index of refraction of the inside.
    pub ior: f32,
}
