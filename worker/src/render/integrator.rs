//! Cook's transport. At every hit: light from every light (area lights sampled over their
//! surface and combined with the BSDF sample by multiple importance sampling); then one
//! BSDF sample, followed when it picked a specular or glossy lobe, ended after a light
//! check when it picked a diffuse one (no diffuse interreflection). Smooth glass is not
//! picked from but followed both ways, as Whitted did, at a path's first two glass hits
//! ([`SPLITS`]). Surfaces of the classic
//! model are shaded as Whitted did, with Cook's blurred reflection and refraction: both
//! the reflected and the refracted ray are traced.

use glam::{Vec2, Vec3};
use tessera_description::math;

use super::bsdf::{Bsdf, BsdfSample, Frame, Lobe};
use super::geometry::{offset_ray_origin, Hit, Ray};
use super::light::ALL_LIGHTS_UP_TO;
use super::material::{Classic, Material};
use super::{Sampler, Scene, Seen, SurfaceHit};

/// Reflects `v` (pointing away from the surface) about the normal `n`.
#[inline]
pub fn reflect(v: Vec3, n: Vec3) -> Vec3 {
    2.0 * v.dot(n) * n - v
}

/// Refracts `wi` (pointing away from the surface, on the side of `n`) into a medium with
/// relative index `eta` (far side over near side); `None` on total internal reflection.
#[inline]
pub fn refract(wi: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = wi.dot(n);
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((-wi / eta + (cos_i / eta - cos_t) * n).normalize())
}

/// The power heuristic (β = 2) weight of a strategy with density `a` against one with `b`.
#[inline]
fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 == 0.0 || !a2.is_finite() {
        return 1.0;
    }
    a2 / (a2 + b2)
}

/// Shortens a shadow ray so that the light's own surface at its end does not count as a
/// blocker: relative, so it holds at every scale.
pub(crate) const SHADOW_SHORTEN: f32 = 1.0 - 1e-4;

/// What a ray leaving the scene along `dir` sees: the environment, weighted against its
/// light sample by MIS unless the ray was sampled from a Dirac lobe (density `prev_pdf`
/// otherwise); the background when there is no environment.
fn escaped(scene: &Scene, dir: Vec3, from_dirac: bool, prev_pdf: f32) -> Vec3 {
    let w = &*scene.world;
    let Some(i) = w.environment else { return scene.background };
    let super::light::Light::Environment(env) = &w.lights[i as usize] else { return scene.background };
    let le = env.radiance(dir);
    if from_dirac || le == Vec3::ZERO {
        return le;
    }
    le * power_heuristic(prev_pdf, w.light_choice.pmf(i as usize) * env.pdf(dir))
}

/// What a ray along `dir` sees of light `li`, which it hit at `sh`: the light's emission
/// and its weight, by MIS against the light's samples where the ray was sampled from a
/// lobe of density `pdf` at `p` (`sampled`), 1 where it came from a Dirac lobe; `None`
/// where the light emits nothing towards the ray.
#[inline(always)]
fn emission_seen(
    scene: &Scene,
    sh: &SurfaceHit,
    li: u32,
    dir: Vec3,
    sampled: Option<(Vec3, f32)>,
    time: f32,
) -> Option<(Vec3, f32)> {
    let light = &scene.world.lights[li as usize];
    let mut le = light.emitted(sh.hit.n, dir);
    if le != Vec3::ZERO && matches!(scene.world.materials[sh.material as usize], Material::Pbr(_)) {
        le *= scene.emission_scale(sh, time);
    }
    if le == Vec3::ZERO {
        return None;
    }
    let w = match sampled {
        None => 1.0,
        Some((p, pdf)) => {
            let pick = scene.world.light_choice.pmf(li as usize);
            power_heuristic(pdf, pick * light.pdf(p, dir, sh.hit.t, sh.hit.n))
        }
    };
    Some((le, w))
}

/// How many times a camera path may follow both lobes of a smooth dielectric instead of
/// picking one by its Fresnel reflectance. Picking costs nothing but is the noisiest
/// choice a path makes: a light seen in glass by reflection (a few percent) comes from a
/// few samples in a hundred, and in `spheres` those pixels held a quarter of the squared
/// error (docs/speed.md, fourteenth part). Whitted followed both at every hit; the budget
/// bounds the tree (2^SPLITS paths) where glass faces glass, and past it the path picks.
const SPLITS: u32 = 2;

/// The radiance arriving along `ray`; `depth` segments precede it.
pub fn radiance(scene: &Scene, sampler: &mut Sampler, ray: &Ray, depth: u32, time: f32) -> Vec3 {
    trace(scene, sampler, ray, depth, time, SPLITS)
}

/// [`radiance`], with `splits` dielectric splits left to the path.
fn trace(scene: &Scene, sampler: &mut Sampler, ray: &Ray, depth: u32, time: f32, mut splits: u32) -> Vec3 {
    let mut l = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    let mut ray = *ray;
    // How the current ray was sampled, for weighting a light it hits.
    let mut from_dirac = true;
    let mut prev_pdf = 0.0f32;
    let mut prev_p = ray.origin;
    for depth in depth..scene.max_depth {
        // A camera ray is traced right after its pixel's previous sample's: coherent.
        let found = if depth == 0 {
            scene.intersect_coherent(&ray, f32::INFINITY, time)
        } else {
            scene.intersect(&ray, f32::INFINITY, time)
        };
        let Some(mut sh) = found else {
            l += beta * escaped(scene, ray.dir, from_dirac, prev_pdf);
            break;
        };
        if let Some(li) = sh.light {
            let sampled = (!from_dirac).then_some((prev_p, prev_pdf));
            if let Some((le, w)) = emission_seen(scene, &sh, li, ray.dir, sampled, time) {
                l += beta * le * w;
            }
            // Light surfaces reflect nothing.
            break;
        }
        let material = &scene.world.materials[sh.material as usize];
        if material.is_textured() {
            scene.complete_uv(&mut sh);
        }
        let hit = sh.hit;
        if let Material::Classic(c) = material {
            l += beta * classic(scene, sampler, -ray.dir, &hit, c, Along { depth, time, splits });
            break;
        }
        let wo_world = -ray.dir;
        let (bsdf, frame) = if let Material::Pbr(m) = material {
            // glTF: texture coordinate sets, normal map, single or double sided.
            let Some(shading) = scene.pbr_shading(&sh, m, wo_world, time) else { break };
            shading
        } else {
            let bsdf =
                material.bsdf(&scene.world.textures, hit.p, hit.uv).expect("physically based material");
            // Dielectrics need to know inside from outside; opaque surfaces shade both sides.
            let mut ns = hit.ns;
            if !matches!(material, Material::Dielectric { .. } | Material::RoughDielectric { .. })
                && ns.dot(wo_world) < 0.0
            {
                ns = -ns;
            }
            (bsdf, Frame::new(ns))
        };
        let wo = frame.to_local(wo_world);
        let split = if splits > 0 && depth + 1 < scene.max_depth { bsdf.split(wo) } else { None };
        // The light samples first, then the BSDF's sample, then the shadow rays: the draws
        // in the order they always had, but the BSDF's sample is worked out while the
        // lights' samples (a chain of divisions and square roots) are still in flight,
        // instead of after the shadow walks that wait on them.
        let w = &*scene.world;
        // `for_each` visits every light up to ALL_LIGHTS_UP_TO of them, else one.
        let mut pending = [None; ALL_LIGHTS_UP_TO];
        let mut taken = 0;
        if depth + 1 < scene.max_depth && !bsdf.is_delta() {
            w.light_choice.for_each(&w.lights, sampler, |i, light, pick, sampler| {
                let u = if light.is_delta() { Vec2::ZERO } else { sampler.get_2d() };
                if let Some(ls) = light.sample(hit.p, u) {
                    pending[taken] = Some((i, pick, ls));
                    taken += 1;
                }
            });
        }
        let (sampled, u_lobe) = if split.is_some() {
            // The draws a pick reads are passed over, so the dimensions after them keep
            // their numbers whichever way the path went.
            sampler.skip();
            sampler.skip();
            (None, 0.0)
        } else {
            let (reads_lobe, reads_u) = bsdf.draws();
            let u_lobe = if reads_lobe { sampler.get_1d() } else { sampler.skip() };
            let u = if reads_u { sampler.get_2d() } else { Vec2::splat(sampler.skip()) };
            (bsdf.sample(wo, u_lobe, u), u_lobe)
        };
        for &(i, pick, ls) in pending[..taken].iter().flatten() {
            let light = &w.lights[i as usize];
            let f = bsdf.eval(wo, frame.to_local(ls.wi));
            if f == Vec3::ZERO {
                continue;
            }
            let origin = offset_ray_origin(hit.p, hit.p_error, hit.n, ls.wi);
            let tr = scene.shadow(&Ray::new(origin, ls.wi), ls.dist * SHADOW_SHORTEN, time, i);
            if tr == Vec3::ZERO {
                continue;
            }
            let w = if light.is_delta() {
                1.0
            } else {
                power_heuristic(pick * ls.pdf, bsdf.pdf(wo, frame.to_local(ls.wi)))
            };
            l += beta * f * ls.weighted * tr * (w / pick);
        }
        let s = if let Some([reflected, refracted]) = split {
            splits -= 1;
            let wi = frame.to_world(reflected.wi).normalize();
            let ray = Ray::new(offset_ray_origin(hit.p, hit.p_error, hit.n, wi), wi);
            l += beta * reflected.weight * trace(scene, sampler, &ray, depth + 1, time, splits);
            refracted
        } else {
            let Some(s) = sampled else { break };
            s
        };
        if s.lobe == Lobe::Diffuse {
            // A diffuse lobe ends the path: its rays only look for light. (Where the
            // path's own sample failed, at a boundary value of a draw, the lobe is not
            // known and no ray is sent, as with one ray.)
            if depth + 1 < scene.max_depth {
                let diffuse = Diffuse { bsdf: &bsdf, frame: &frame, wo, hit: &hit, u_lobe };
                l += diffuse.light(scene, sampler, s, beta, time);
            }
            break;
        }
        beta *= s.weight;
        if beta == Vec3::ZERO || !beta.is_finite() {
            break;
        }
        let wi = frame.to_world(s.wi).normalize();
        prev_p = hit.p;
        prev_pdf = s.pdf;
        from_dirac = s.lobe == Lobe::Specular;
        ray = Ray::new(offset_ray_origin(hit.p, hit.p_error, hit.n, wi), wi);
    }
    l
}

/// Where a path picked a diffuse lobe: what its rays need to weigh the light they find.
/// Cook's transport ends the path there (no diffuse interreflection), so a ray from it
/// only looks for light, and the lobe may send several (`[render] diffuse_rays`): the
/// lobe's share of the sample is then the mean of that many directions drawn from it, an
/// estimate of the same expectation with a fraction of the variance. Where the sky or an
/// environment lights a scene, that variance is most of the image's, and a ray that only
/// looks for light costs a fraction of a sample (docs/speed.md, twenty-ninth part).
struct Diffuse<'a> {
    bsdf: &'a Bsdf,
    frame: &'a Frame,
    wo: Vec3,
    hit: &'a Hit,
    /// The lobe choice that picked the diffuse lobe: every direction is drawn with it.
    u_lobe: f32,
}

impl Diffuse<'_> {
    /// The light the lobe's rays find on a path of throughput `beta`: with one ray, that of
    /// `first` (the path's own sample), the bits the path's next segment gave when it was
    /// a turn of the integrator's loop.
    #[inline(always)]
    fn light(&self, scene: &Scene, sampler: &mut Sampler, first: BsdfSample, beta: Vec3, time: f32) -> Vec3 {
        let count = scene.diffuse_rays;
        if count == 1 {
            return self.light_found(scene, first, beta, time);
        }
        // The rays' directions from one set (`Sampler::each_2d_of_set`), stratified among
        // themselves; the path's own draw is not one of them. The lobe is the same for
        // each: its choice reads only `u_lobe` (`Bsdf::sample`), so every ray is drawn
        // from the distribution the first was, given the lobe.
        let share = beta / count as f32;
        let mut l = Vec3::ZERO;
        sampler.each_2d_of_set(count, |u| {
            if let Some(s) = self.bsdf.sample(self.wo, self.u_lobe, u) {
                debug_assert_eq!(s.lobe, Lobe::Diffuse, "a lobe chosen by u, not u_lobe alone");
                l += self.light_found(scene, s, share, time);
            }
        });
        l
    }

    /// The light that sample `s`'s ray finds, weighted by `share` and the sample's
    /// weight: emission it hits, weighed by MIS against the light samples, or the sky
    /// where it escapes.
    #[inline(always)]
    fn light_found(&self, scene: &Scene, s: BsdfSample, share: Vec3, time: f32) -> Vec3 {
        let beta = share * s.weight;
        if beta == Vec3::ZERO || !beta.is_finite() {
            return Vec3::ZERO;
        }
        let hit = self.hit;
        let wi = self.frame.to_world(s.wi).normalize();
        let ray = Ray::new(offset_ray_origin(hit.p, hit.p_error, hit.n, wi), wi);
        // Where the ray can find no light, its hit is not needed.
        if !scene.may_find_light(&ray, time) {
            return Vec3::ZERO;
        }
        let sh = match scene.seen(&ray, time) {
            Seen::Nothing => return beta * escaped(scene, ray.dir, false, s.pdf),
            Seen::Surface => return Vec3::ZERO,
            Seen::Emitter(sh) => sh,
        };
        let Some(li) = sh.light else { return Vec3::ZERO };
        match emission_seen(scene, &sh, li, ray.dir, Some((hit.p, s.pdf)), time) {
            Some((le, w)) => beta * le * w,
            None => Vec3::ZERO,
        }
    }
}

/// Perturbs the unit direction `w` around itself by a GGX-distributed normal of roughness
/// `alpha` (Cook's blurred reflection and refraction); keeps it on the side of `n` it must
/// stay on (`side` = +1 above, -1 below).
fn blur(w: Vec3, n: Vec3, alpha: f32, u: Vec2, side: f32) -> Vec3 {
    let tan2 = alpha * alpha * u.x / (1.0 - u.x).max(1e-12);
    let cos_t = 1.0 / (1.0 + tan2).sqrt();
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (sin, cos) = math::sin_cos(2.0 * std::f32::consts::PI * u.y);
    let frame = Frame::new(w);
    let d = frame.to_world(Vec3::new(sin_t * cos, sin_t * sin, cos_t)).normalize();
    // A lobe that dips through the surface is folded back, as a blurred mirror would.
    if d.dot(n) * side < 0.0 {
        (d - 2.0 * d.dot(n) * n).normalize()
    } else {
        d
    }
}

/// Where a ray stands in its path: the segments before it, its shutter time and the
/// dielectric splits left to it.
#[derive(Debug, Clone, Copy)]
struct Along {
    depth: u32,
    time: f32,
    splits: u32,
}

/// The classic model at a hit: ambient, diffuse and Phong highlight from every light
/// (with coloured shadows through transmissive surfaces), then the reflected and
/// refracted rays, blurred by `gloss` and `translucency`; `wo` points back along the ray.
fn classic(
    scene: &Scene,
    sampler: &mut Sampler,
    wo: Vec3,
    hit: &Hit,
    m: &Classic,
    Along { depth, time, splits }: Along,
) -> Vec3 {
    let entering = hit.n.dot(wo) >= 0.0;
    // The normals on the side the ray comes from.
    let (n, ns) = if entering { (hit.n, hit.ns) } else { (-hit.n, -hit.ns) };
    let color = m.color.eval(&scene.world.textures, hit.p, hit.uv);

    let mut l = scene.ambient * m.ambient * color;
    let world = &*scene.world;
    world.light_choice.for_each(&world.lights, sampler, |i, light, pick, sampler| {
        let u = if light.is_delta() { Vec2::ZERO } else { sampler.get_2d() };
        let Some(ls) = light.sample(hit.p, u) else { return };
        let cos = ns.dot(ls.wi);
        if cos <= 0.0 || n.dot(ls.wi) <= 0.0 {
            return;
        }
        let origin = offset_ray_origin(hit.p, hit.p_error, n, ls.wi);
        let tr = scene.shadow(&Ray::new(origin, ls.wi), ls.dist * SHADOW_SHORTEN, time, i);
        if tr == Vec3::ZERO {
            return;
        }
        let mut f = color * (m.diffuse * cos);
        if m.specular > 0.0 {
            f += Vec3::splat(m.specular * math::powf(reflect(ls.wi, ns).dot(wo).max(0.0), m.shininess));
        }
        l += ls.weighted * tr * f / pick;
    });

    if depth + 1 >= scene.max_depth {
        return l;
    }
    let mut mirror = m.reflect;
    if m.transmit != Vec3::ZERO {
        let eta = if entering { m.ior } else { 1.0 / m.ior };
        match refract(wo, ns, eta) {
            Some(mut wt) => {
                if m.translucency > 0.0 {
                    wt = blur(wt, n, m.translucency, sampler.get_2d(), -1.0);
                }
                let origin = offset_ray_origin(hit.p, hit.p_error, n, wt);
                l += m.transmit * trace(scene, sampler, &Ray::new(origin, wt), depth + 1, time, splits);
            }
            // Total internal reflection: the transmitted light is reflected instead.
            None => mirror += m.transmit,
        }
    }
    if mirror != Vec3::ZERO {
        let mut wr = reflect(wo, ns);
        if m.gloss > 0.0 {
            wr = blur(wr, n, m.gloss, sampler.get_2d(), 1.0);
        }
        let origin = offset_ray_origin(hit.p, hit.p_error, n, wr);
        l += mirror * trace(scene, sampler, &Ray::new(origin, wr), depth + 1, time, splits);
    }
    l
}

#[cfg(test)]
#[path = "integrator_tests.rs"]
mod tests;
