//! The renderer: a Whitted ray tracer whose samples are pure functions of
//! (scene, seed, pixel, sample index), so that the farm can split, repeat and reorder work
//! freely.

pub mod camera;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod material;
pub mod sampler;

use glam::{UVec2, Vec3};

use camera::Camera;
use geometry::{Hit, Plane, Ray, Sphere};
use light::PointLight;
use material::Material;
pub use sampler::Sampler;

/// A scene ready to render.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Seed of every random choice; the same seed gives the same image.
    pub seed: u64,
    /// Deepest recursion of reflection and refraction.
    pub max_depth: u32,
    /// Radiance of rays that escape.
    pub background: Vec3,
    /// Ambient light of the classic model.
    pub ambient: Vec3,
    /// The camera.
    pub camera: Camera,
    /// Materials, referenced by index.
    pub materials: Vec<Material>,
    /// Spheres.
    pub spheres: Vec<Sphere>,
    /// Infinite planes.
    pub planes: Vec<Plane>,
    /// Point lights.
    pub lights: Vec<PointLight>,
}

impl Scene {
    /// The nearest surface the ray hits before `t_max`.
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_max = t_max;
        for s in &self.spheres {
            if let Some(h) = s.intersect(ray, t_max) {
                t_max = h.t;
                best = Some(h);
            }
        }
        for p in &self.planes {
            if let Some(h) = p.intersect(ray, t_max) {
                t_max = h.t;
                best = Some(h);
            }
        }
        best
    }

    /// Calls `f` with every surface the ray crosses before `t_max`, in no particular
    /// order, until `f` returns false.
    pub fn for_each_hit(&self, ray: &Ray, t_max: f32, mut f: impl FnMut(&Hit) -> bool) {
        for s in &self.spheres {
            for h in s.intersect_all(ray, t_max).into_iter().flatten() {
                if !f(&h) {
                    return;
                }
            }
        }
        for p in &self.planes {
            if let Some(h) = p.intersect(ray, t_max) {
                if !f(&h) {
                    return;
                }
            }
        }
    }

    /// Renders sample `index` of `pixel` (paper coordinates: y grows upward) and returns
    /// its radiance.
    pub fn render_sample(&self, sampler: &mut Sampler, pixel: UVec2, index: u32) -> Vec3 {
        sampler.start_pixel_sample(pixel, index);
        let p_film = pixel.as_vec2() + sampler.get_2d();
        let ray = self.camera.generate_ray(p_film);
        integrator::radiance(self, &ray, 0)
    }

    /// A sampler for this scene's pattern.
    pub fn sampler(&self) -> Sampler {
        Sampler::new(self.seed, self.spp)
    }
}
