//! The camera: a pinhole, or a thin lens with an aperture and a plane of focus (depth of
//! field), with a shutter interval (motion blur).

use glam::{Vec2, Vec3};
use tessera_description::math;

use super::bsdf::concentric_disk;
use super::geometry::Ray;

/// A camera. Film coordinates are pixels, origin at the lower-left corner, y up.
#[derive(Debug, Clone)]
pub struct Camera {
    origin: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half_w: f32,
    tan_half_h: f32,
    axis: FovAxis,
    width: f32,
    height: f32,
    /// Lens radius; 0 is a pinhole (and the lens dimension is never sampled).
    pub lens_radius: f32,
    /// Distance of the plane of focus along the view axis.
    pub focus_distance: f32,
    /// Shutter open and close, as fractions of the motion interval [0, 1].
    pub shutter: (f32, f32),
}

pub use tessera_description::model::FovAxis;

impl Camera {
    /// A camera with full field of view `fov` (radians) along `axis`, for a
    /// `width × height` image.
    pub fn new(
        position: Vec3,
        look_at: Vec3,
        up: Vec3,
        fov: f32,
        axis: FovAxis,
        width: u32,
        height: u32,
    ) -> Self {
        let forward = (look_at - position).normalize();
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let aspect = width as f32 / height as f32;
        let t = math::tan(fov * 0.5);
        let (tan_half_w, tan_half_h) = match axis {
            FovAxis::Vertical => (t * aspect, t),
            FovAxis::Horizontal => (t, t / aspect),
        };
        Camera {
            origin: position,
            forward,
            right,
            up: true_up,
            tan_half_w,
            tan_half_h,
            axis,
            width: width as f32,
            height: height as f32,
            lens_radius: 0.0,
            focus_distance: 1.0,
            shutter: (0.0, 0.0),
        }
    }

    /// Renders at another resolution, keeping the field of view along the scene's axis.
    pub fn set_resolution(&mut self, width: u32, height: u32) {
        let aspect = width as f32 / height as f32;
        match self.axis {
            FovAxis::Vertical => self.tan_half_w = self.tan_half_h * aspect,
            FovAxis::Horizontal => self.tan_half_h = self.tan_half_w / aspect,
        }
        self.width = width as f32;
        self.height = height as f32;
    }

    /// Whether the lens dimension is sampled.
    pub fn has_lens(&self) -> bool {
        self.lens_radius > 0.0
    }

    /// The unnormalised direction through film point `p_film`, with unit length along
    /// the view axis.
    fn film_dir(&self, p_film: Vec2) -> Vec3 {
        let x = (2.0 * p_film.x / self.width - 1.0) * self.tan_half_w;
        let y = (2.0 * p_film.y / self.height - 1.0) * self.tan_half_h;
        self.forward + self.right * x + self.up * y
    }

    /// The primary ray through film point `p_film` (pixels), from lens point `p_lens`
    /// (a sample of the unit square; ignored by a pinhole).
    pub fn generate_ray(&self, p_film: Vec2, p_lens: Vec2) -> Ray {
        let d = self.film_dir(p_film);
        if self.lens_radius <= 0.0 {
            return Ray::new(self.origin, d.normalize());
        }
        // Every ray through the film point meets at its point on the plane of focus.
        let focus = self.origin + d * self.focus_distance;
        let l = concentric_disk(p_lens) * self.lens_radius;
        let origin = self.origin + self.right * l.x + self.up * l.y;
        Ray::new(origin, (focus - origin).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_of_film_looks_at_target() {
        let cam = Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 0.7, FovAxis::Vertical, 64, 32);
        let ray = cam.generate_ray(Vec2::new(32.0, 16.0), Vec2::ZERO);
        assert!((ray.dir - Vec3::NEG_Z).length() < 1e-6);
        // y grows upward on the film.
        assert!(cam.generate_ray(Vec2::new(32.0, 31.0), Vec2::ZERO).dir.y > 0.0);
        assert!(cam.generate_ray(Vec2::new(63.0, 16.0), Vec2::ZERO).dir.x > 0.0);
    }

    #[test]
    fn horizontal_fov_spans_the_width() {
        let fov = 1.0f32;
        let cam = Camera::new(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y, fov, FovAxis::Horizontal, 200, 100);
        let edge = cam.generate_ray(Vec2::new(200.0, 50.0), Vec2::ZERO).dir;
        assert!((math::atan2(edge.x, -edge.z) - fov / 2.0).abs() < 1e-5);
    }

    /// Rays from any lens point through one film point meet on the plane of focus.
    #[test]
    fn thin_lens_focuses_on_the_focal_plane() {
        let mut cam = Camera::new(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y, 0.8, FovAxis::Vertical, 64, 64);
        cam.lens_radius = 0.5;
        cam.focus_distance = 7.0;
        let film = Vec2::new(10.3, 40.7);
        let meet = |u: Vec2| {
            let r = cam.generate_ray(film, u);
            r.at(-7.0 / r.dir.z + r.origin.z / r.dir.z)
        };
        let a = meet(Vec2::new(0.1, 0.2));
        let b = meet(Vec2::new(0.9, 0.7));
        assert!((a - b).length() < 1e-4, "{a} vs {b}");
    }
}
