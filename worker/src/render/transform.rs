//! Object transforms (translate, rotate, scale) and their interpolation over the shutter.

use glam::{Affine3A, EulerRot, Quat, Vec3};

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
        Trs { translate, rotate: Quat::from_euler(EulerRot::ZYX, r.z, r.y, r.x), scale }
    }

    /// The matrix `world_from_object`.
    pub fn matrix(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotate, self.translate)
    }

    /// Whether this is the identity.
    pub fn is_identity(&self) -> bool {
        *self == Trs::default()
    }

    /// Interpolates at `t` in [0, 1]: linear in translation and scale, spherical in rotation.
    pub fn lerp(&self, end: &Trs, t: f32) -> Trs {
        Trs {
            translate: self.translate.lerp(end.translate, t),
            rotate: self.rotate.slerp(end.rotate, t),
            scale: self.scale.lerp(end.scale, t),
        }
    }
}

/// An object's motion over the shutter: its transform when the shutter opens and when it
/// closes.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// Transform at shutter open.
    pub start: Trs,
    /// Transform at shutter close.
    pub end: Trs,
}

impl Motion {
    /// `world_from_object` at shutter fraction `t`.
    pub fn at(&self, t: f32) -> Affine3A {
        self.start.lerp(&self.end, t).matrix()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_order_and_interpolation() {
        let t = Trs::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 90.0, 0.0), Vec3::splat(2.0));
        // Scale, rotate 90° about y (x → -z), translate.
        let p = t.matrix().transform_point3(Vec3::X);
        assert!((p - Vec3::new(1.0, 0.0, -2.0)).length() < 1e-5, "{p}");
        let m = Motion {
            start: Trs::default(),
            end: Trs { translate: Vec3::new(4.0, 0.0, 0.0), ..Trs::default() },
        };
        assert!((m.at(0.25).transform_point3(Vec3::ZERO) - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-6);
    }
}
