//! Lights: point, spot and directional (Dirac) lights; area lights — emitting
//! rectangles, spheres and triangle meshes — sampled over their surface so that shadows
//! get penumbrae; and the environment, sampled by its luminance.
//!
//! Which lights a shading point samples: every light when the scene has at most
//! [`ALL_LIGHTS_UP_TO`] of them (the estimator the golden images were made with), else one
//! light chosen in proportion to its power ([`Light::power`]), its contribution divided by
//! the probability of the choice. Either way a BSDF sample that hits a light weighs itself
//! against the density with which that light would have been sampled, choice included.

use std::f32::consts::PI;
use std::sync::Arc;

use glam::{Vec2, Vec3};
use tessera_description::math;

use super::bsdf::Frame;
use super::distribution::Distribution1D;
use super::environment::{luminance, Environment};
use super::geometry::Sphere;
use super::shape::Rect;
use super::Sampler;

/// Scenes with at most this many lights sample each of them at every shading point; more
/// and one is chosen by power.
pub const ALL_LIGHTS_UP_TO: usize = 8;

/// A light.
#[derive(Debug, Clone)]
pub enum Light {
    /// A point of radiant intensity `intensity`: irradiance intensity / d².
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity per channel.
        intensity: Vec3,
    },
    /// Parallel light arriving from `direction`'s opposite with irradiance `irradiance`.
    Directional {
        /// Unit direction the light travels in.
        direction: Vec3,
        /// Irradiance on a surface facing the light.
        irradiance: Vec3,
    },
    /// A spot light (glTF `KHR_lights_punctual`): a point light whose intensity falls off
    /// smoothly between two cones around its axis, as the extension's recommended
    /// implementation does: t = clamp((cos θ − cos outer) / (cos inner − cos outer)), × t².
    Spot {
        /// Position.
        position: Vec3,
        /// Unit axis, the way the light travels.
        direction: Vec3,
        /// Radiant intensity per channel on the axis.
        intensity: Vec3,
        /// 1 / (cos inner − cos outer), the falloff's scale (at most 1000, as glTF's).
        scale: f32,
        /// −cos outer × scale.
        offset: f32,
    },
    /// An emitting parallelogram, front side only.
    Rect {
        /// The shape.
        rect: Rect,
        /// Emitted radiance.
        radiance: Vec3,
    },
    /// An emitting sphere, outwards.
    Sphere {
        /// The shape.
        sphere: Sphere,
        /// Emitted radiance.
        radiance: Vec3,
    },
    /// An emitting triangle mesh (or single triangle), both sides.
    Mesh(Arc<MeshLight>),
    /// Light from infinitely far away.
    Environment(Arc<Environment>),
}

/// The triangles of an emitting object, in world space, with a distribution over them by
/// area: a point chosen on a triangle so chosen, uniformly over its area, is uniform over
/// the whole surface (area density 1 / total area).
#[derive(Debug, Clone)]
pub struct MeshLight {
    /// Corners of each triangle.
    tris: Vec<[Vec3; 3]>,
    /// Unit geometric normal of each triangle.
    normals: Vec<Vec3>,
    /// Triangles by area.
    choice: Distribution1D,
    /// Total area.
    area: f32,
    /// Emitted radiance, the same from either side.
    radiance: Vec3,
}

impl MeshLight {
    /// The light of the triangles `tris` emitting `radiance`; `None` when they have no area.
    pub fn new(tris: Vec<[Vec3; 3]>, radiance: Vec3) -> Option<MeshLight> {
        if tris.is_empty() {
            return None;
        }
        let cross: Vec<Vec3> = tris.iter().map(|[a, b, c]| (*b - *a).cross(*c - *a)).collect();
        let areas: Vec<f32> = cross.iter().map(|x| 0.5 * x.length()).collect();
        let area = areas.iter().filter(|a| a.is_finite()).map(|&a| f64::from(a)).sum::<f64>() as f32;
        if !(area > 0.0 && area.is_finite()) {
            return None;
        }
        let normals = cross.iter().map(|x| x.normalize_or_zero()).collect();
        Some(MeshLight { tris, normals, choice: Distribution1D::new(&areas), area, radiance })
    }

    /// Total area.
    pub fn area(&self) -> f32 {
        self.area
    }

    /// The probability of choosing triangle `i`.
    pub fn triangle_pmf(&self, i: usize) -> f32 {
        self.choice.pmf(i)
    }

    /// A point uniform over the surface, with its triangle's normal, from the pair `u`.
    fn sample_point(&self, u: Vec2) -> (Vec3, Vec3) {
        let pick = self.choice.sample(u.x);
        let [a, b, c] = self.tris[pick.index];
        let r = pick.remapped.sqrt();
        let (b0, b1) = (1.0 - r, u.y * r);
        (a * b0 + b * b1 + c * (1.0 - b0 - b1), self.normals[pick.index])
    }
}

/// A sampled light contribution at a point.
#[derive(Debug, Clone, Copy)]
pub struct LightSample {
    /// Unit direction from the point towards the light.
    pub wi: Vec3,
    /// Distance to the sampled light point (infinite for directional light).
    pub dist: f32,
    /// Radiance (area lights) or irradiance-like value (Dirac lights) arriving, divided
    /// by the density: the estimator's light factor.
    pub weighted: Vec3,
    /// Solid-angle density (0 for Dirac lights).
    pub pdf: f32,
}

impl Light {
    /// Whether the light is a Dirac light (no area to sample, no MIS).
    pub fn is_delta(&self) -> bool {
        matches!(self, Light::Point { .. } | Light::Directional { .. } | Light::Spot { .. })
    }

    /// Whether the light is one convex primitive of the scene (a sphere or a
    /// parallelogram): a shadow ray to a point sampled on it cannot cross its own surface
    /// first, so the shadow test may pass that primitive over.
    pub fn is_one_convex_primitive(&self) -> bool {
        matches!(self, Light::Sphere { .. } | Light::Rect { .. })
    }

    /// A spot light from its cones' half-angles in radians (inner < outer).
    pub fn spot(position: Vec3, direction: Vec3, intensity: Vec3, inner_cone: f32, outer_cone: f32) -> Light {
        let (ci, co) = (math::cos(inner_cone), math::cos(outer_cone));
        let scale = 1.0 / (ci - co).max(1e-3);
        Light::Spot { position, direction, intensity, scale, offset: -co * scale }
    }

    /// Radiant power, in luminance, for choosing among many lights. `radius` bounds the
    /// scene: directional light and the environment deliver power through its disc. A
    /// spot light's is that of its full cone plus half the falloff ring.
    pub fn power(&self, radius: f32) -> f32 {
        let p = match self {
            Light::Point { intensity, .. } => 4.0 * PI * luminance(*intensity),
            Light::Spot { intensity, scale, offset, .. } => {
                let cos_outer = -offset / scale;
                let cos_inner = cos_outer + 1.0 / scale;
                2.0 * PI * (1.0 - 0.5 * (cos_inner + cos_outer)) * luminance(*intensity)
            }
            Light::Directional { irradiance, .. } => PI * radius * radius * luminance(*irradiance),
            Light::Rect { rect, radiance } => PI * rect.area() * luminance(*radiance),
            Light::Sphere { sphere, radiance } => {
                4.0 * PI * PI * sphere.radius * sphere.radius * luminance(*radiance)
            }
            Light::Mesh(m) => 2.0 * PI * m.area * luminance(m.radiance),
            Light::Environment(e) => e.power(radius),
        };
        if p.is_finite() {
            p.max(0.0)
        } else {
            0.0
        }
    }

    /// Samples light arriving at `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        match self {
            Light::Point { position, intensity } => {
                let d = *position - p;
                let dist2 = d.length_squared();
                (dist2 > 0.0).then(|| {
                    let dist = dist2.sqrt();
                    LightSample { wi: d / dist, dist, weighted: *intensity / dist2, pdf: 0.0 }
                })
            }
            Light::Spot { position, direction, intensity, scale, offset } => {
                let d = *position - p;
                let dist2 = d.length_squared();
                if dist2 <= 0.0 {
                    return None;
                }
                let dist = dist2.sqrt();
                let wi = d / dist;
                let t = ((-wi).dot(*direction) * scale + offset).clamp(0.0, 1.0);
                (t > 0.0).then(|| LightSample { wi, dist, weighted: *intensity * (t * t) / dist2, pdf: 0.0 })
            }
            Light::Directional { direction, irradiance } => {
                Some(LightSample { wi: -*direction, dist: f32::INFINITY, weighted: *irradiance, pdf: 0.0 })
            }
            Light::Rect { rect, radiance } => {
                let q = rect.point(2.0 * u.x - 1.0, 2.0 * u.y - 1.0);
                let d = q - p;
                let dist2 = d.length_squared();
                let dist = dist2.sqrt();
                let wi = d / dist;
                let cos_l = -wi.dot(rect.normal());
                if cos_l <= 0.0 || dist2 == 0.0 {
                    return None;
                }
                let pdf = dist2 / (cos_l * rect.area());
                Some(LightSample { wi, dist, weighted: *radiance / pdf, pdf })
            }
            Light::Sphere { sphere, radiance } => {
                let (wi, pdf) = sample_sphere_cone(sphere, p, u)?;
                let dist = sphere_entry(sphere, p, wi)?;
                Some(LightSample { wi, dist, weighted: *radiance / pdf, pdf })
            }
            Light::Mesh(m) => {
                let (q, n) = m.sample_point(u);
                let d = q - p;
                let dist2 = d.length_squared();
                let dist = dist2.sqrt();
                let wi = d / dist;
                let cos_l = wi.dot(n).abs();
                if cos_l <= 0.0 || dist2 == 0.0 || !wi.is_finite() {
                    return None;
                }
                let pdf = dist2 / (cos_l * m.area);
                Some(LightSample { wi, dist, weighted: m.radiance / pdf, pdf })
            }
            Light::Environment(e) => {
                let s = e.sample(u)?;
                Some(LightSample { wi: s.wi, dist: f32::INFINITY, weighted: s.radiance / s.pdf, pdf: s.pdf })
            }
        }
    }

    /// The solid-angle density with which `sample` picks direction `wi` from `p`, given
    /// that the ray hits this light at distance `dist` where its geometric normal is `n`
    /// (for MIS).
    #[inline]
    pub fn pdf(&self, p: Vec3, wi: Vec3, dist: f32, n: Vec3) -> f32 {
        match self {
            Light::Mesh(m) => {
                let cos_l = wi.dot(n).abs();
                if cos_l <= 0.0 {
                    return 0.0;
                }
                dist * dist / (cos_l * m.area)
            }
            Light::Environment(e) => e.pdf(wi),
            Light::Point { .. } | Light::Directional { .. } | Light::Spot { .. } => 0.0,
            Light::Rect { rect, .. } => {
                let cos_l = -wi.dot(rect.normal());
                if cos_l <= 0.0 {
                    return 0.0;
                }
                dist * dist / (cos_l * rect.area())
            }
            Light::Sphere { sphere, .. } => {
                let d2 = (sphere.center - p).length_squared();
                let r2 = sphere.radius * sphere.radius;
                if d2 <= r2 {
                    return uniform_area_pdf(sphere, p, wi, dist);
                }
                1.0 / (2.0 * PI * one_minus_cos_max(r2, d2))
            }
        }
    }

    /// Radiance leaving the light's surface towards `-dir` at a point with normal `n`.
    pub fn emitted(&self, n: Vec3, dir: Vec3) -> Vec3 {
        match self {
            Light::Rect { radiance, rect } => {
                if dir.dot(rect.normal()) < 0.0 {
                    *radiance
                } else {
                    Vec3::ZERO
                }
            }
            Light::Sphere { radiance, .. } => {
                if dir.dot(n) < 0.0 {
                    *radiance
                } else {
                    Vec3::ZERO
                }
            }
            Light::Mesh(m) => m.radiance,
            _ => Vec3::ZERO,
        }
    }
}

/// How a scene's lights are sampled at a shading point: all of them, or one by power.
#[derive(Debug, Clone, Default)]
pub struct LightChoice {
    /// The distribution over lights by power; `None` when every light is sampled.
    by_power: Option<Distribution1D>,
}

impl LightChoice {
    /// The choice for `lights` in a scene of bounding radius `radius`.
    pub fn new(lights: &[Light], radius: f32) -> LightChoice {
        if lights.len() <= ALL_LIGHTS_UP_TO {
            return LightChoice { by_power: None };
        }
        let powers: Vec<f32> = lights.iter().map(|l| l.power(radius)).collect();
        LightChoice { by_power: Some(Distribution1D::new(&powers)) }
    }

    /// The probability that a shading point samples light `i`.
    pub fn pmf(&self, i: usize) -> f32 {
        self.by_power.as_ref().map_or(1.0, |d| d.pmf(i))
    }

    /// Calls `each(index, light, probability, sampler)` for the lights a shading point samples:
    /// all of them with probability 1 (no sample drawn), or one drawn with the sampler's
    /// next 1-D number.
    pub fn for_each(
        &self,
        lights: &[Light],
        sampler: &mut Sampler,
        mut each: impl FnMut(u32, &Light, f32, &mut Sampler),
    ) {
        match &self.by_power {
            None => lights.iter().enumerate().for_each(|(i, l)| each(i as u32, l, 1.0, sampler)),
            Some(d) => {
                let pick = d.sample(sampler.get_1d());
                let pmf = d.pmf(pick.index);
                if pmf > 0.0 {
                    each(pick.index as u32, &lights[pick.index], pmf, sampler);
                }
            }
        }
    }
}

/// Samples a direction uniformly inside the cone that the sphere subtends from `p`; from
/// inside the sphere, a uniform direction (every direction sees the sphere).
fn sample_sphere_cone(sphere: &Sphere, p: Vec3, u: Vec2) -> Option<(Vec3, f32)> {
    let to_c = sphere.center - p;
    let d2 = to_c.length_squared();
    let r2 = sphere.radius * sphere.radius;
    if d2 <= r2 {
        let z = 1.0 - 2.0 * u.x;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = 2.0 * PI * u.y;
        let (sin, cos) = math::sin_cos(phi);
        return Some((Vec3::new(r * cos, r * sin, z), 1.0 / (4.0 * PI)));
    }
    // Work with 1 − cos θ, not cos θ: for a small or far sphere cos θmax rounds to 1 and
    // the cone would vanish, with an infinite density.
    let cone = one_minus_cos_max(r2, d2);
    let k = u.x * cone;
    let (cos_t, sin_t) = (1.0 - k, (k * (2.0 - k)).max(0.0).sqrt());
    let phi = 2.0 * PI * u.y;
    let frame = Frame::new(to_c / d2.sqrt());
    let (sin, cos) = math::sin_cos(phi);
    let wi = frame.to_world(Vec3::new(sin_t * cos, sin_t * sin, cos_t));
    Some((wi.normalize(), 1.0 / (2.0 * PI * cone)))
}

/// 1 − cos θmax of the cone a sphere of squared radius `r2` subtends from squared distance
/// `d2`, as sin²θ / (1 + cos θ): exact where 1 − √(1 − sin²θ) cancels to 0.
fn one_minus_cos_max(r2: f32, d2: f32) -> f32 {
    let sin2 = (r2 / d2).min(1.0);
    sin2 / (1.0 + (1.0 - sin2).sqrt())
}

fn uniform_area_pdf(_sphere: &Sphere, _p: Vec3, _wi: Vec3, _dist: f32) -> f32 {
    1.0 / (4.0 * PI)
}

/// The distance along `wi` from `p` to the sphere's surface (its near side from outside,
/// its far side from inside). A grazing cone sample that misses by rounding takes the
/// closest approach.
fn sphere_entry(sphere: &Sphere, p: Vec3, wi: Vec3) -> Option<f32> {
    let oc = (p - sphere.center).as_dvec3();
    let d = wi.as_dvec3();
    let b = oc.dot(d);
    let r = f64::from(sphere.radius);
    let perp = oc - d * b;
    let disc = (r * r - perp.length_squared()).max(0.0);
    let c = oc.length_squared() - r * r;
    let t = if c > 0.0 { -b - disc.sqrt() } else { -b + disc.sqrt() };
    (t > 0.0).then_some(t as f32)
}

#[cfg(test)]
#[path = "light_tests.rs"]
mod tests;
