//! Object transforms as their parts (translate, rotate, scale): what a scene gives, and
//! what the renderer interpolates over the shutter.

use glam::{Affine3A, Quat, Vec3};

use crate::math;

/// A transform as its parts: scale, then rotation, then translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trs {
    /// Translation.
    pub translate: Vec3,
    /// Rotation.
    pub rotate: Quat,
    /// Scale per axis.
    pub scale: Vec3,
}

impl Default for Trs {
    fn default() -> Self {
        Trs { translate: Vec3::ZERO, rotate: Quat::IDENTITY, scale: Vec3::ONE }
    }
}

impl Trs {
    /// A transform from Euler angles in degrees, applied about x, then y, then z.
    pub fn new(translate: Vec3, rotate_degrees: Vec3, scale: Vec3) -> Trs {
        let r = rotate_degrees * (std::f32::consts::PI / 180.0);
        Trs { translate, rotate: math::quat_from_euler_zyx(r.z, r.y, r.x), scale }
    }

    /// The matrix `world_from_object`.
    pub fn matrix(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotate, self.translate)
    }

    /// Whether this is the identity.
    pub fn is_identity(&self) -> bool {
        *self == Trs::default()
    }

    /// Interpolates at `t` in [0, 1]: linear in translation and scale, spherical in rotation
    /// (along the shorter arc; `math::slerp`, the same bits on every machine).
    pub fn lerp(&self, end: &Trs, t: f32) -> Trs {
        Trs {
            translate: self.translate.lerp(end.translate, t),
            rotate: math::slerp(self.rotate, end.rotate, t),
            scale: self.scale.lerp(end.scale, t),
        }
    }
}
