//! Maps of the unit square onto disks and hemispheres, for diffuse sampling and the thin lens.

use glam::{Vec2, Vec3};
use tessera_description::math;

/// Cosine-weighted hemisphere sample (Malley's method on a concentric disk).
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    Vec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt())
}

/// Shirley–Chiu concentric map of the unit square onto the unit disk.
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = u * 2.0 - Vec2::ONE;
    if o == Vec2::ZERO {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, std::f32::consts::FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (o.x / o.y))
    };
    let (sin, cos) = math::sin_cos(theta);
    Vec2::new(r * cos, r * sin)
}
