//! Object transforms (translate, rotate, scale) and their interpolation over the shutter.

use glam::Affine3A;

pub use tessera_description::transform::Trs;

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
    use glam::Vec3;

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
