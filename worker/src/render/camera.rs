//! The camera: a pinhole looking from `position` at `look_at`.

use glam::{Vec2, Vec3};

use super::geometry::Ray;

/// A pinhole camera. Film coordinates are pixels, origin at the lower-left corner.
#[derive(Debug, Clone)]
pub struct Camera {
    origin: Vec3,
    /// World-space vector from the origin to the lower-left corner of the film at distance 1.
    lower_left: Vec3,
    /// World-space span of one pixel along x and y on that film.
    pixel_dx: Vec3,
    pixel_dy: Vec3,
}

impl Camera {
    /// A camera with vertical field of view `fov` (radians) for a `width × height` image.
    pub fn new(position: Vec3, look_at: Vec3, up: Vec3, fov: f32, width: u32, height: u32) -> Self {
        let forward = (look_at - position).normalize();
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let half_h = (fov * 0.5).tan();
        let half_w = half_h * width as f32 / height as f32;
        Camera {
            origin: position,
            lower_left: forward - right * half_w - true_up * half_h,
            pixel_dx: right * (2.0 * half_w / width as f32),
            pixel_dy: true_up * (2.0 * half_h / height as f32),
        }
    }

    /// The primary ray through film point `p_film` (pixels).
    pub fn generate_ray(&self, p_film: Vec2) -> Ray {
        let dir = self.lower_left + self.pixel_dx * p_film.x + self.pixel_dy * p_film.y;
        Ray::new(self.origin, dir.normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_of_film_looks_at_target() {
        let cam = Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 0.7, 64, 32);
        let ray = cam.generate_ray(Vec2::new(32.0, 16.0));
        assert!((ray.dir - Vec3::NEG_Z).length() < 1e-6);
        // y grows upward on the film.
        assert!(cam.generate_ray(Vec2::new(32.0, 31.0)).dir.y > 0.0);
        assert!(cam.generate_ray(Vec2::new(63.0, 16.0)).dir.x > 0.0);
    }
}
