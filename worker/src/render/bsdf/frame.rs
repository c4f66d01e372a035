//! The local shading frame and the direction helpers that work in it (z along the normal).

use glam::Vec3;

/// An orthonormal frame around a unit normal (Duff et al. 2017).
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    /// Tangent.
    pub s: Vec3,
    /// Bitangent.
    pub t: Vec3,
    /// Normal.
    pub n: Vec3,
}

impl Frame {
    /// The frame of normal `n`.
    pub fn new(n: Vec3) -> Frame {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }

    /// World to local.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local to world.
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

#[inline]
pub(super) fn cos_theta(w: Vec3) -> f32 {
    w.z
}

#[inline]
pub(super) fn same_hemisphere(a: Vec3, b: Vec3) -> bool {
    a.z * b.z > 0.0
}

pub(super) fn reflect_z(w: Vec3) -> Vec3 {
    Vec3::new(-w.x, -w.y, w.z)
}

pub(super) fn reflect_about(w: Vec3, m: Vec3) -> Vec3 {
    2.0 * w.dot(m) * m - w
}

/// Refraction of `w` about normal `n` (on w's side) with relative index `eta` (of the
/// far side over w's side); `None` on total internal reflection.
pub(super) fn refract_about(w: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = w.dot(n);
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(-w / eta + (cos_i / eta - cos_t) * n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal() {
        for n in [Vec3::Z, Vec3::NEG_Z, Vec3::new(0.3, -0.4, 0.866).normalize(), Vec3::X] {
            let f = Frame::new(n);
            assert!(
                f.s.dot(f.t).abs() < 1e-6 && f.s.dot(n).abs() < 1e-6 && (f.s.cross(f.t) - n).length() < 1e-5
            );
            let v = Vec3::new(0.2, 0.5, -0.3);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-6);
        }
    }
}
