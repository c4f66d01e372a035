//! The transcendental functions and quaternion operations of everything that reaches a
//! sample, with the same bits on every machine (docs/determinism.md).
//!
//! `f32::sin` and its kin call the platform's C library, whose results differ between
//! glibc versions, musl and macOS; these come from the pure-Rust `libm` crate, the same
//! code on every target. glam's `Quat` and `Vec4` have SIMD paths (SSE2, NEON) that sum
//! their components in another order than its scalar path (`dot`, `normalize`, `*`) and
//! use a polynomial sine in `slerp`; the quaternion operations here are written out on
//! the components, so one build's result is every build's. Basic arithmetic and `sqrt` are
//! correctly rounded by IEEE 754 and stay as they are; clippy's `disallowed-methods`
//! (`clippy.toml`) keeps the platform's functions out of the renderer.

use glam::Quat;

/// Sine (radians).
#[inline]
pub fn sin(x: f32) -> f32 {
    libm::sinf(x)
}

/// Cosine (radians).
#[inline]
pub fn cos(x: f32) -> f32 {
    libm::cosf(x)
}

/// Sine and cosine (radians), as `(sin, cos)`: the bits of [`sin`] and [`cos`] (libm
/// 0.2.16's `sincosf` shares their range reduction and kernels; checked for all 2³² inputs
/// once, and on a sample of them by `tests::sin_cos_has_the_bits_of_sin_and_cos`), so the
/// renderer may use either without an image changing.
#[inline]
pub fn sin_cos(x: f32) -> (f32, f32) {
    libm::sincosf(x)
}

/// Tangent (radians).
#[inline]
pub fn tan(x: f32) -> f32 {
    libm::tanf(x)
}

/// Arctangent, in (−π/2, π/2).
#[inline]
pub fn atan(x: f32) -> f32 {
    libm::atanf(x)
}

/// The angle of `(x, y)` from the x axis, in [−π, π], as `f32::atan2(y, x)`.
#[inline]
pub fn atan2(y: f32, x: f32) -> f32 {
    libm::atan2f(y, x)
}

/// Arccosine, in [0, π]; NaN outside [−1, 1].
#[inline]
pub fn acos(x: f32) -> f32 {
    libm::acosf(x)
}

/// `x` to the power `y`.
#[inline]
pub fn powf(x: f32, y: f32) -> f32 {
    libm::powf(x, y)
}

/// The natural logarithm.
#[inline]
pub fn ln(x: f32) -> f32 {
    libm::logf(x)
}

/// The quaternions' dot product, summed x, y, z, w in that order.
#[inline]
pub fn quat_dot(a: Quat, b: Quat) -> f32 {
    a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w
}

/// `q` scaled to unit length (not finite for a zero quaternion, as `Quat::normalize`).
#[inline]
pub fn quat_normalize(q: Quat) -> Quat {
    let inv = 1.0 / quat_dot(q, q).sqrt();
    Quat::from_xyzw(q.x * inv, q.y * inv, q.z * inv, q.w * inv)
}

/// The Hamilton product `a * b`: the rotation `b`, then `a`.
#[inline]
pub fn quat_mul(a: Quat, b: Quat) -> Quat {
    Quat::from_xyzw(
        a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
        a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
        a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
        a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z,
    )
}

/// The rotation by `x` radians about x, then `y` about y, then `z` about z (glam's
/// `Quat::from_euler(EulerRot::ZYX, z, y, x)`).
pub fn quat_from_euler_zyx(z: f32, y: f32, x: f32) -> Quat {
    let (sz, cz) = sin_cos(z * 0.5);
    let (sy, cy) = sin_cos(y * 0.5);
    let (sx, cx) = sin_cos(x * 0.5);
    let qz = Quat::from_xyzw(0.0, 0.0, sz, cz);
    let qy = Quat::from_xyzw(0.0, sy, 0.0, cy);
    let qx = Quat::from_xyzw(sx, 0.0, 0.0, cx);
    quat_mul(quat_mul(qz, qy), qx)
}

/// Spherical linear interpolation from `a` (s = 0) to `b` (s = 1), both unit, along the
/// shorter arc; normalised linear interpolation where they are too close for the angle.
pub fn slerp(a: Quat, b: Quat, s: f32) -> Quat {
    let mut dot = quat_dot(a, b);
    let b = if dot < 0.0 {
        dot = -dot;
        -b
    } else {
        b
    };
    let (wa, wb) = if dot > 1.0 - f32::EPSILON {
        (1.0 - s, s)
    } else {
        let theta = acos(dot);
        let inv = 1.0 / sin(theta);
        (sin(theta * (1.0 - s)) * inv, sin(theta * s) * inv)
    };
    quat_normalize(Quat::from_xyzw(
        a.x * wa + b.x * wb,
        a.y * wa + b.y * wb,
        a.z * wa + b.z * wb,
        a.w * wa + b.w * wb,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{EulerRot, Vec3};

    // The written-out operations are the same rotations as glam's (to rounding): glam's
    // own are the expectation here, so the lint that keeps them out of the renderer is off.
    #[test]
    #[allow(clippy::disallowed_methods)]
    fn quaternion_operations_agree_with_glam() {
        let (z, y, x) = (0.3, -1.1, 2.0);
        let ours = quat_from_euler_zyx(z, y, x);
        let glams = Quat::from_euler(EulerRot::ZYX, z, y, x);
        assert!(quat_dot(ours, glams).abs() > 1.0 - 1e-6, "{ours} {glams}");
        let a = Quat::from_rotation_y(0.2);
        let b = Quat::from_rotation_x(1.4);
        for s in [0.0, 0.25, 0.5, 1.0] {
            let q = slerp(a, b, s);
            assert!(q.angle_between(a.slerp(b, s)) < 1e-3, "{s}: {q}");
        }
        // The shorter arc: -b is the same rotation.
        assert!(slerp(a, -b, 0.5).angle_between(a.slerp(b, 0.5)) < 1e-3);
        let p = quat_mul(a, b) * Vec3::new(1.0, 2.0, 3.0);
        assert!((p - (a * b) * Vec3::new(1.0, 2.0, 3.0)).length() < 1e-5);
        assert!((quat_normalize(Quat::from_xyzw(0.0, 0.0, 3.0, 4.0)).w - 0.8).abs() < 1e-7);
        assert!(slerp(a, a, 0.3).angle_between(a) < 1e-6);
    }

    #[test]
    fn functions_are_the_usual_ones() {
        assert_eq!(sin(0.0), 0.0);
        assert!((cos(std::f32::consts::PI) + 1.0).abs() < 1e-6);
        assert!((atan2(1.0, -1.0) - 3.0 * std::f32::consts::FRAC_PI_4).abs() < 1e-6);
        assert!((tan(std::f32::consts::FRAC_PI_4) - 1.0).abs() < 1e-6);
        assert!((powf(2.0, 10.0) - 1024.0).abs() < 1e-3);
        assert!((acos(0.0) - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((atan(1.0) - std::f32::consts::FRAC_PI_4).abs() < 1e-6);
        assert!((ln(std::f32::consts::E) - 1.0).abs() < 1e-6);
        let (s, c) = sin_cos(0.7);
        assert!((s - sin(0.7)).abs() < 1e-7 && (c - cos(0.7)).abs() < 1e-7);
    }

    /// Every 997th bit pattern of f32 (NaNs aside, whose payloads may differ), and the
    /// whole of [0, 2π) every 61st float: where the renderer draws its angles.
    #[test]
    fn sin_cos_has_the_bits_of_sin_and_cos() {
        let same = |x: f32| {
            let (s, c) = sin_cos(x);
            (s.to_bits() == sin(x).to_bits() && c.to_bits() == cos(x).to_bits()) || x.is_nan()
        };
        let everywhere = (0..=u32::MAX).step_by(997).map(f32::from_bits);
        let angles = (0..(2.0 * std::f32::consts::PI).to_bits()).step_by(61).map(f32::from_bits);
        for x in everywhere.chain(angles) {
            assert!(same(x), "sin_cos({x:e}) differs from (sin, cos)");
        }
    }
}
