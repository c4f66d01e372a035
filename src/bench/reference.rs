//! A minimal Whitted ray tracer, kept only as the yardstick of "pay for what you use": it
//! knows spheres, planes, point lights and the classic material, loops over the objects
//! with no acceleration structure and no sampler beyond the pixel position. The real
//! renderer must trace a scene of only those things as fast as this does.

use glam::{UVec2, Vec3};
use tessera_description::math;
use tessera_worker::render::geometry::{offset_ray_origin, Hit, Plane, Ray, Sphere};
use tessera_worker::render::integrator::{reflect, refract};
use tessera_worker::render::light::Light;
use tessera_worker::render::material::{Classic, Material};
use tessera_worker::render::shape::Shape;
use tessera_worker::render::texture::Tex;
use tessera_worker::render::Scene;

/// The reference's view of a Whitted scene.
pub struct Whitted<'a> {
    scene: &'a Scene,
    spheres: Vec<(Sphere, &'a Classic)>,
    planes: Vec<(&'a Plane, &'a Classic)>,
    lights: Vec<(Vec3, Vec3)>,
}

fn classic(m: &Material) -> Option<&Classic> {
    match m {
        Material::Classic(c)
            if matches!(c.color, Tex::Const(_)) && c.gloss == 0.0 && c.translucency == 0.0 =>
        {
            Some(c)
        }
        _ => None,
    }
}

impl<'a> Whitted<'a> {
    /// The reference for `scene`, if the scene is a plain Whitted scene.
    pub fn new(scene: &'a Scene) -> Option<Whitted<'a>> {
        if scene.camera.has_lens() || scene.has_motion_blur() {
            return None;
        }
        let mut spheres = Vec::new();
        for p in &scene.world.prims {
            match &p.shape {
                Shape::Sphere(s) if p.light.is_none() && p.motion.is_none() => {
                    spheres.push((s.clone(), classic(&scene.world.materials[p.material as usize])?))
                }
                _ => return None,
            }
        }
        let planes = scene
            .world
            .planes
            .iter()
            .map(|(p, m)| Some((p, classic(&scene.world.materials[*m as usize])?)))
            .collect::<Option<Vec<_>>>()?;
        let lights = scene
            .world
            .lights
            .iter()
            .map(|l| match l {
                Light::Point { position, intensity } => Some((*position, *intensity)),
                _ => None,
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Whitted { scene, spheres, planes, lights })
    }

    fn intersect(&self, ray: &Ray, mut t_max: f32) -> Option<(Hit, &'a Classic)> {
        let mut best = None;
        for (s, m) in &self.spheres {
            if let Some(h) = s.intersect(ray, t_max) {
                t_max = h.t;
                best = Some((h, *m));
            }
        }
        for (p, m) in &self.planes {
            if let Some(h) = p.intersect(ray, t_max) {
                t_max = h.t;
                best = Some((h, *m));
            }
        }
        best
    }

    fn transmittance(&self, ray: &Ray, dist: f32) -> Vec3 {
        let mut tr = Vec3::ONE;
        for (s, m) in &self.spheres {
            for _ in 0..s.crossings(ray, dist) {
                tr *= m.transmit;
            }
        }
        for (p, m) in &self.planes {
            if p.intersect(ray, dist).is_some() {
                tr *= m.transmit;
            }
        }
        tr
    }

    fn radiance(&self, ray: &Ray, depth: u32) -> Vec3 {
        let Some((hit, m)) = self.intersect(ray, f32::INFINITY) else { return self.scene.background };
        let wo = -ray.dir;
        let entering = hit.n.dot(wo) >= 0.0;
        let n = if entering { hit.n } else { -hit.n };
        let Tex::Const(color) = m.color else { unreachable!("checked in new") };
        let mut l = self.scene.ambient * m.ambient * color;
        for &(position, intensity) in &self.lights {
            let d = position - hit.p;
            let dist2 = d.length_squared();
            let dist = dist2.sqrt();
            let wi = d / dist;
            let cos = n.dot(wi);
            if cos <= 0.0 {
                continue;
            }
            let origin = offset_ray_origin(hit.p, hit.p_error, n, wi);
            let tr = self.transmittance(&Ray::new(origin, wi), dist * (1.0 - 1e-4));
            if tr == Vec3::ZERO {
                continue;
            }
            let mut f = color * (m.diffuse * cos);
            if m.specular > 0.0 {
                f += Vec3::splat(m.specular * math::powf(reflect(wi, n).dot(wo).max(0.0), m.shininess));
            }
            l += intensity / dist2 * tr * f;
        }
        if depth + 1 >= self.scene.max_depth {
            return l;
        }
        let mut mirror = m.reflect;
        if m.transmit != Vec3::ZERO {
            let eta = if entering { m.ior } else { 1.0 / m.ior };
            match refract(wo, n, eta) {
                Some(wt) => {
                    let o = offset_ray_origin(hit.p, hit.p_error, n, wt);
                    l += m.transmit * self.radiance(&Ray::new(o, wt), depth + 1);
                }
                None => mirror += m.transmit,
            }
        }
        if mirror != Vec3::ZERO {
            let wr = reflect(wo, n);
            let o = offset_ray_origin(hit.p, hit.p_error, n, wr);
            l += mirror * self.radiance(&Ray::new(o, wr), depth + 1);
        }
        l
    }

    /// Sample `index` of `pixel`, with the renderer's own pixel sample positions.
    pub fn sample(&self, sampler: &mut tessera_worker::render::Sampler, pixel: UVec2, index: u32) -> Vec3 {
        sampler.start_pixel_sample(pixel, index);
        let p_film = pixel.as_vec2() + sampler.get_2d();
        self.radiance(&self.scene.camera.generate_ray(p_film, glam::Vec2::ZERO), 0)
    }
}
