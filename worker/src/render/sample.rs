//! Where a pixel sample starts: its sampler, its camera ray and shutter time, and the
//! radiance traced from them, alone or from camera rays made a run ahead.

use glam::{UVec2, Vec2, Vec3};

use super::geometry::Ray;
use super::{integrator, Sampler, SamplerKind, Scene};

impl Scene {
    /// Renders sample `index` of `pixel` (paper coordinates: y grows upward) and returns
    /// its radiance. Dimensions are drawn only for what the scene uses: the lens only with
    /// an aperture, time only with motion and an open shutter.
    pub fn render_sample(&self, sampler: &mut Sampler, pixel: UVec2, index: u32) -> Vec3 {
        let (ray, time) = self.camera_ray(sampler, pixel, index);
        integrator::radiance(self, sampler, &ray, 0, time)
    }

    /// The camera rays and shutter times of samples `run` of `pixel`, into `out`, for
    /// [`Scene::render_from`] to trace: a sample's camera draws and ray are a chain of
    /// dependent steps (a lens point's sine and cosine, a normalisation) that its trace
    /// waits on, and computed for a run of samples in one loop they overlap, as the
    /// sampler's table overlaps the draws. Returns the dimensions a camera ray draws.
    pub fn camera_rays(
        &self,
        sampler: &mut Sampler,
        pixel: UVec2,
        run: std::ops::Range<u32>,
        out: &mut Vec<(Ray, f32)>,
    ) -> u32 {
        out.clear();
        out.extend(run.map(|index| self.camera_ray(sampler, pixel, index)));
        sampler.dimensions_used()
    }

    /// [`Scene::render_sample`] from its camera ray and time, as [`Scene::camera_rays`]
    /// made them having drawn `camera_dimensions`: the sampler goes on where
    /// `render_sample`'s camera left it, so the radiance is the same bits.
    pub fn render_from(
        &self,
        sampler: &mut Sampler,
        pixel: UVec2,
        index: u32,
        (ray, time): (Ray, f32),
        camera_dimensions: u32,
    ) -> Vec3 {
        sampler.resume_pixel_sample(pixel, index, camera_dimensions);
        integrator::radiance(self, sampler, &ray, 0, time)
    }

    /// Sample `index` of `pixel`'s camera ray and shutter time: its film, lens and time
    /// dimensions, the first ones the sample draws (the AOV layers trace the same ray with
    /// a sampler of their own).
    pub fn camera_ray(&self, sampler: &mut Sampler, pixel: UVec2, index: u32) -> (Ray, f32) {
        sampler.start_pixel_sample(pixel, index);
        let (film, p_lens) =
            if self.camera.has_lens() { sampler.get_4d() } else { (sampler.get_2d(), Vec2::ZERO) };
        let p_film = pixel.as_vec2() + film;
        let time = if self.has_motion_blur() {
            let (open, close) = self.camera.shutter;
            open + sampler.get_1d() * (close - open)
        } else {
            self.camera.shutter.0
        };
        (self.camera.generate_ray(p_film, p_lens), time)
    }

    /// A sampler for this scene's pattern. Cook's jittered strata are stratified as a
    /// whole, and a prefix of them is spread about as independent samples are; a job in
    /// rounds ends at a prefix it cannot know beforehand, so it draws Sobol's pattern,
    /// every power-of-two prefix of which is a net (`sampler::sobol::nested_order`).
    pub fn sampler(&self) -> Sampler {
        let kind = match self.sampler {
            SamplerKind::Stratified if self.progressive => SamplerKind::Sobol,
            kind => kind,
        };
        Sampler::new(kind, self.seed, self.spp)
    }
}
