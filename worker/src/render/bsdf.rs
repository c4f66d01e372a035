//! Physically based scattering with the standard definitions, so that images compare with
//! established renderers: Lambertian, ideal mirror, smooth dielectric, rough conductor and
//! rough dielectric (GGX with separable Smith shadowing; Walter et al. 2007), and smooth
//! plastic (a dielectric coat over a diffuse base, Mitsuba's `plastic`). Directions are in
//! the local shading frame, z along the normal, both pointing away from the surface.

use std::f32::consts::{FRAC_1_PI, PI};

use glam::{Vec2, Vec3};

/// How a sampled direction was scattered; the transport continues along specular and
/// glossy lobes and stops at diffuse ones (Cook's transport).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lobe {
    /// A Dirac lobe: mirror reflection or refraction.
    Specular,
    /// A rough but directional lobe.
    Glossy,
    /// A diffuse lobe.
    Diffuse,
}

/// A sampled direction.
#[derive(Debug, Clone, Copy)]
pub struct BsdfSample {
    /// Incident direction (towards the light), local frame.
    pub wi: Vec3,
    /// f · |cos θi| / pdf.
    pub weight: Vec3,
    /// Solid-angle density (0 for specular lobes).
    pub pdf: f32,
    /// Which kind of lobe.
    pub lobe: Lobe,
}

/// A BSDF at a point, with textures already looked up.
#[derive(Debug, Clone, Copy)]
pub enum Bsdf {
    /// f = albedo / π.
    Lambert {
        /// Albedo.
        albedo: Vec3,
    },
    /// Perfect specular reflection times a constant, no Fresnel.
    Mirror {
        /// Reflectance.
        reflectance: Vec3,
    },
    /// Smooth dielectric: Fresnel-weighted reflection and refraction.
    Dielectric {
        /// Index of refraction inside over outside.
        eta: f32,
    },
    /// Smooth conductor (roughness 0).
    SmoothConductor {
        /// Complex index of refraction, real part.
        eta: Vec3,
        /// Imaginary part.
        k: Vec3,
    },
    /// GGX microfacet conductor.
    RoughConductor {
        /// Real part of the index.
        eta: Vec3,
        /// Imaginary part.
        k: Vec3,
        /// GGX roughness α.
        alpha: f32,
    },
    /// GGX microfacet dielectric (Walter et al. 2007).
    RoughDielectric {
        /// Index inside over outside.
        eta: f32,
        /// GGX roughness α.
        alpha: f32,
    },
    /// Smooth dielectric coat over a Lambertian base.
    Plastic {
        /// Base albedo.
        diffuse: Vec3,
        /// Coat index.
        eta: f32,
        /// Internal diffuse Fresnel reflectance of the coat.
        fdr: f32,
    },
}

/// Roughness below which a microfacet lobe is treated as perfectly smooth: GGX with
/// α → 0 tends to the Dirac lobe, and its density overflows f32 long before.
pub const SMOOTH_ALPHA: f32 = 1e-4;

#[inline]
fn cos_theta(w: Vec3) -> f32 {
    w.z
}

#[inline]
fn same_hemisphere(a: Vec3, b: Vec3) -> bool {
    a.z * b.z > 0.0
}

/// Exact unpolarised Fresnel reflectance of a dielectric interface; `cos_i` may be
/// negative (coming from inside), `eta` is inside over outside.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let (mut cos_i, mut eta) = (cos_i.clamp(-1.0, 1.0), eta);
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
    }
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    (r_parl * r_parl + r_perp * r_perp) * 0.5
}

#[derive(Clone, Copy)]
struct Complex {
    re: f32,
    im: f32,
}

impl Complex {
    fn new(re: f32, im: f32) -> Self {
        Complex { re, im }
    }
    fn add(self, o: Self) -> Self {
        Complex::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Self) -> Self {
        Complex::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Self) -> Self {
        Complex::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
    fn div(self, o: Self) -> Self {
        let d = o.re * o.re + o.im * o.im;
        Complex::new((self.re * o.re + self.im * o.im) / d, (self.im * o.re - self.re * o.im) / d)
    }
    fn norm(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    fn sqrt(self) -> Self {
        let n = self.norm().sqrt();
        if n == 0.0 {
            return Complex::new(0.0, 0.0);
        }
        let t1 = (0.5 * (n + self.re.abs())).sqrt();
        let t2 = 0.5 * self.im / t1;
        if self.re >= 0.0 {
            Complex::new(t1, t2)
        } else {
            Complex::new(t2.abs(), t1.copysign(self.im))
        }
    }
}

/// Exact unpolarised Fresnel reflectance of a conductor with index `eta + i k` (outside
/// index 1), one channel.
fn fresnel_complex(cos_i: f32, eta: f32, k: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let eta = Complex::new(eta, k);
    let sin2_i = Complex::new(1.0 - cos_i * cos_i, 0.0);
    let sin2_t = sin2_i.div(eta.mul(eta));
    let cos_t = Complex::new(1.0, 0.0).sub(sin2_t).sqrt();
    let ci = Complex::new(cos_i, 0.0);
    let r_parl = eta.mul(ci).sub(cos_t).div(eta.mul(ci).add(cos_t));
    let r_perp = ci.sub(eta.mul(cos_t)).div(ci.add(eta.mul(cos_t)));
    (r_parl.norm() + r_perp.norm()) * 0.5
}

/// Fresnel reflectance of a conductor per channel.
pub fn fresnel_conductor(cos_i: f32, eta: Vec3, k: Vec3) -> Vec3 {
    Vec3::new(
        fresnel_complex(cos_i, eta.x, k.x),
        fresnel_complex(cos_i, eta.y, k.y),
        fresnel_complex(cos_i, eta.z, k.z),
    )
}

/// The internal diffuse Fresnel reflectance of a coat of index `eta` (Egan–Hilgeman fit,
/// as Mitsuba's `plastic`).
pub fn fresnel_diffuse_reflectance(eta: f32) -> f32 {
    let e = 1.0 / eta;
    0.0636 / e + e * (-1.4399 * e + 0.7099) + 0.6681
}

/// GGX (Trowbridge–Reitz) normal distribution.
pub fn ggx_d(m: Vec3, alpha: f32) -> f32 {
    let cos2 = m.z * m.z;
    if cos2 <= 0.0 {
        return 0.0;
    }
    let tan2 = (1.0 - cos2) / cos2;
    let a2 = alpha * alpha;
    let denom = PI * cos2 * cos2 * (a2 + tan2) * (a2 + tan2);
    a2 / denom
}

/// Smith's shadowing for one direction, GGX.
pub fn ggx_g1(w: Vec3, alpha: f32) -> f32 {
    let cos2 = w.z * w.z;
    if cos2 <= 0.0 {
        return 0.0;
    }
    let tan2 = (1.0 - cos2) / cos2;
    2.0 / (1.0 + (1.0 + alpha * alpha * tan2).sqrt())
}

/// Samples a microfacet normal with density D(m) cos θm.
fn ggx_sample_normal(u: Vec2, alpha: f32) -> Vec3 {
    let tan2 = alpha * alpha * u.x / (1.0 - u.x).max(1e-12);
    let cos_t = 1.0 / (1.0 + tan2).sqrt();
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)
}

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
    Vec2::new(r * theta.cos(), r * theta.sin())
}

fn reflect_z(w: Vec3) -> Vec3 {
    Vec3::new(-w.x, -w.y, w.z)
}

fn reflect_about(w: Vec3, m: Vec3) -> Vec3 {
    2.0 * w.dot(m) * m - w
}

/// Refraction of `w` about normal `n` (on w's side) with relative index `eta` (of the
/// far side over w's side); `None` on total internal reflection.
fn refract_about(w: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = w.dot(n);
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(-w / eta + (cos_i / eta - cos_t) * n)
}

impl Bsdf {
    /// Whether every lobe is a Dirac lobe (light sampling cannot help).
    pub fn is_delta(&self) -> bool {
        match self {
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } | Bsdf::SmoothConductor { .. } => true,
            Bsdf::RoughConductor { .. } | Bsdf::RoughDielectric { .. } => false,
            Bsdf::Lambert { .. } | Bsdf::Plastic { .. } => false,
        }
    }

    /// f(wo, wi) · |cos θi| for the non-Dirac lobes.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let cos_i = cos_theta(wi);
        match *self {
            Bsdf::Lambert { albedo } => {
                if wo.z <= 0.0 || cos_i <= 0.0 {
                    return Vec3::ZERO;
                }
                albedo * FRAC_1_PI * cos_i
            }
            Bsdf::Plastic { diffuse, eta, fdr } => {
                if wo.z <= 0.0 || cos_i <= 0.0 {
                    return Vec3::ZERO;
                }
                let fo = fresnel_dielectric(wo.z, eta);
                let fi = fresnel_dielectric(cos_i, eta);
                diffuse / (1.0 - fdr) / (eta * eta) * (1.0 - fo) * (1.0 - fi) * FRAC_1_PI * cos_i
            }
            Bsdf::RoughConductor { eta, k, alpha } => {
                if wo.z <= 0.0 || cos_i <= 0.0 {
                    return Vec3::ZERO;
                }
                let h = (wo + wi).normalize();
                let d = ggx_d(h, alpha);
                let g = ggx_g1(wo, alpha) * ggx_g1(wi, alpha);
                fresnel_conductor(wi.dot(h), eta, k) * (d * g / (4.0 * wo.z))
            }
            Bsdf::RoughDielectric { eta, alpha } => Vec3::splat(rough_dielectric_eval(wo, wi, eta, alpha)),
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } | Bsdf::SmoothConductor { .. } => Vec3::ZERO,
        }
    }

    /// Density of `sample` returning `wi` (non-Dirac lobes only).
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Lambert { .. } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    0.0
                } else {
                    wi.z * FRAC_1_PI
                }
            }
            Bsdf::Plastic { diffuse, eta, .. } => {
                if wo.z <= 0.0 || wi.z <= 0.0 {
                    return 0.0;
                }
                (1.0 - plastic_specular_probability(wo.z, eta, diffuse)) * wi.z * FRAC_1_PI
            }
            Bsdf::RoughConductor { alpha, .. } => {
                if !same_hemisphere(wo, wi) || wo.z <= 0.0 {
                    return 0.0;
                }
                let h = (wo + wi).normalize();
                ggx_d(h, alpha) * h.z / (4.0 * wo.dot(h).abs())
            }
            Bsdf::RoughDielectric { eta, alpha } => rough_dielectric_pdf(wo, wi, eta, alpha),
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } | Bsdf::SmoothConductor { .. } => 0.0,
        }
    }

    /// Samples an incident direction given `wo`, with a lobe choice `u_lobe` and a 2-D
    /// sample `u`.
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        match *self {
            Bsdf::Lambert { albedo } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let wi = cosine_hemisphere(u);
                (wi.z > 0.0).then_some(BsdfSample {
                    wi,
                    weight: albedo,
                    pdf: wi.z * FRAC_1_PI,
                    lobe: Lobe::Diffuse,
                })
            }
            Bsdf::Mirror { reflectance } => (wo.z > 0.0).then_some(BsdfSample {
                wi: reflect_z(wo),
                weight: reflectance,
                pdf: 0.0,
                lobe: Lobe::Specular,
            }),
            Bsdf::SmoothConductor { eta, k } => (wo.z > 0.0).then(|| BsdfSample {
                wi: reflect_z(wo),
                weight: fresnel_conductor(wo.z, eta, k),
                pdf: 0.0,
                lobe: Lobe::Specular,
            }),
            Bsdf::Dielectric { eta } => {
                let f = fresnel_dielectric(wo.z, eta);
                if u_lobe < f {
                    return Some(BsdfSample {
                        wi: reflect_z(wo),
                        weight: Vec3::ONE,
                        pdf: 0.0,
                        lobe: Lobe::Specular,
                    });
                }
                // Refraction; the relative index of the side the light goes to.
                let (n, rel) = if wo.z > 0.0 { (Vec3::Z, eta) } else { (Vec3::NEG_Z, 1.0 / eta) };
                let wi = refract_about(wo, n, rel)?;
                // Radiance is compressed into the denser medium: scale by 1/rel².
                Some(BsdfSample {
                    wi,
                    weight: Vec3::splat(1.0 / (rel * rel)),
                    pdf: 0.0,
                    lobe: Lobe::Specular,
                })
            }
            Bsdf::Plastic { diffuse, eta, fdr } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let p_spec = plastic_specular_probability(wo.z, eta, diffuse);
                if u_lobe < p_spec {
                    let f = fresnel_dielectric(wo.z, eta);
                    return Some(BsdfSample {
                        wi: reflect_z(wo),
                        weight: Vec3::splat(f / p_spec),
                        pdf: 0.0,
                        lobe: Lobe::Specular,
                    });
                }
                let wi = cosine_hemisphere(u);
                if wi.z <= 0.0 {
                    return None;
                }
                let pdf = (1.0 - p_spec) * wi.z * FRAC_1_PI;
                let f = Bsdf::Plastic { diffuse, eta, fdr }.eval(wo, wi);
                Some(BsdfSample { wi, weight: f / pdf, pdf, lobe: Lobe::Diffuse })
            }
            Bsdf::RoughConductor { alpha, .. } => {
                if wo.z <= 0.0 {
                    return None;
                }
                let m = ggx_sample_normal(u, alpha);
                let wi = reflect_about(wo, m);
                if wi.z <= 0.0 {
                    return None;
                }
                let pdf = self.pdf(wo, wi);
                (pdf > 0.0).then(|| BsdfSample {
                    wi,
                    weight: self.eval(wo, wi) / pdf,
                    pdf,
                    lobe: Lobe::Glossy,
                })
            }
            Bsdf::RoughDielectric { eta, alpha } => {
                if wo.z == 0.0 {
                    return None;
                }
                // The microfacet normal faces +z whichever side wo is on; the Fresnel term
                // and the refraction then see from the sign of wo · m whether the light
                // leaves the inside.
                let m = ggx_sample_normal(u, alpha);
                let f = fresnel_dielectric(wo.dot(m), eta);
                let wi = if u_lobe < f {
                    let wi = reflect_about(wo, m);
                    if !same_hemisphere(wo, wi) {
                        return None;
                    }
                    wi
                } else {
                    let rel = if wo.dot(m) > 0.0 { eta } else { 1.0 / eta };
                    let n = if wo.dot(m) > 0.0 { m } else { -m };
                    let wi = refract_about(wo, n, rel)?;
                    if same_hemisphere(wo, wi) || wi.z == 0.0 {
                        return None;
                    }
                    wi
                };
                let pdf = rough_dielectric_pdf(wo, wi, eta, alpha);
                if !(pdf > 0.0) {
                    return None;
                }
                let weight = Vec3::splat(rough_dielectric_eval(wo, wi, eta, alpha) / pdf);
                Some(BsdfSample { wi, weight, pdf, lobe: Lobe::Glossy })
            }
        }
    }
}

/// The probability of sampling the coat of a plastic: its Fresnel reflectance against the
/// base's expected contribution, so that neither lobe is starved.
fn plastic_specular_probability(cos_o: f32, eta: f32, diffuse: Vec3) -> f32 {
    let f = fresnel_dielectric(cos_o, eta);
    let d = (1.0 - f) * diffuse.max_element().clamp(0.0, 1.0);
    if f + d <= 0.0 {
        return 1.0;
    }
    (f / (f + d)).clamp(0.05, 0.95)
}

/// The generalised half vector of a rough dielectric (Walter et al. 2007), facing +z, and
/// the relative index for the pair; `None` when the configuration is degenerate.
fn rough_dielectric_half(wo: Vec3, wi: Vec3, eta: f32) -> Option<(Vec3, f32, bool)> {
    let reflect = same_hemisphere(wo, wi);
    let rel = if reflect {
        1.0
    } else if wo.z > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    let m = wi * rel + wo;
    if m.length_squared() == 0.0 || wo.z == 0.0 || wi.z == 0.0 {
        return None;
    }
    let mut m = m.normalize();
    if m.z < 0.0 {
        m = -m;
    }
    // Back-facing microfacets contribute nothing.
    if m.dot(wi) * wi.z < 0.0 || m.dot(wo) * wo.z < 0.0 {
        return None;
    }
    Some((m, rel, reflect))
}

fn rough_dielectric_eval(wo: Vec3, wi: Vec3, eta: f32, alpha: f32) -> f32 {
    let Some((m, rel, reflect)) = rough_dielectric_half(wo, wi, eta) else { return 0.0 };
    let d = ggx_d(m, alpha);
    let g = ggx_g1(wo, alpha) * ggx_g1(wi, alpha);
    let f = fresnel_dielectric(wo.dot(m), eta);
    if reflect {
        // f · |cos θi|.
        return d * g * f / (4.0 * wo.z.abs());
    }
    let denom = wi.dot(m) + wo.dot(m) / rel;
    let ft = d * (1.0 - f) * g * (wi.dot(m) * wo.dot(m) / (wi.z * wo.z * denom * denom)).abs();
    // Radiance scaling for the medium the light ends in.
    ft / (rel * rel) * wi.z.abs()
}

fn rough_dielectric_pdf(wo: Vec3, wi: Vec3, eta: f32, alpha: f32) -> f32 {
    let Some((m, rel, reflect)) = rough_dielectric_half(wo, wi, eta) else { return 0.0 };
    let pdf_m = ggx_d(m, alpha) * m.z;
    let f = fresnel_dielectric(wo.dot(m), eta);
    if reflect {
        pdf_m / (4.0 * wo.dot(m).abs()) * f
    } else {
        let denom = wi.dot(m) + wo.dot(m) / rel;
        pdf_m * wi.dot(m).abs() / (denom * denom) * (1.0 - f)
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::sampler::hash_words;

    fn u2(i: u64, k: u64) -> Vec2 {
        let h = hash_words(&[i, k]);
        Vec2::new(
            (h >> 40) as f32 / (1u64 << 24) as f32,
            ((h >> 16) & 0xff_ffff) as f32 / (1u64 << 24) as f32,
        )
    }

    #[test]
    fn fresnel_known_values() {
        // Normal incidence on glass: ((1.5 - 1) / (1.5 + 1))² = 0.04.
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        // Total internal reflection from inside past the critical angle.
        assert_eq!(fresnel_dielectric(-0.2, 1.5), 1.0);
        // Index 1: no reflection at all.
        assert!(fresnel_dielectric(0.3, 1.0) < 1e-6);
        // A conductor with k = 0 is a dielectric.
        assert!((fresnel_complex(0.7, 1.5, 0.0) - fresnel_dielectric(0.7, 1.5)).abs() < 1e-5);
        // Gold at normal incidence: ((n-1)² + k²) / ((n+1)² + k²).
        let (n, k) = (0.143f32, 3.983f32);
        let want = ((n - 1.0).powi(2) + k * k) / ((n + 1.0).powi(2) + k * k);
        assert!((fresnel_complex(1.0, n, k) - want).abs() < 1e-5);
        assert!((fresnel_diffuse_reflectance(1.5) - 0.596811).abs() < 1e-4);
    }

    #[test]
    fn ggx_distribution_is_normalised() {
        // ∫ D(m) cos θm dω = 1, by Monte Carlo with uniform hemisphere samples.
        for alpha in [0.05f32, 0.3, 1.0] {
            let n = 200_000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let u = u2(i, 7);
                let z = u.x;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * u.y;
                let m = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                sum += f64::from(ggx_d(m, alpha) * m.z) * 2.0 * std::f64::consts::PI;
            }
            let est = sum / n as f64;
            let tol = if alpha < 0.1 { 0.15 } else { 0.02 };
            assert!((est - 1.0).abs() < tol, "alpha {alpha}: {est}");
        }
    }

    /// Sampling agrees with evaluation: the mean of weight equals ∫ f cos, which for the
    /// estimator with eval/pdf must match, and pdf integrates to at most 1.
    #[test]
    fn sampled_weights_match_eval_over_pdf() {
        for (wo, bsdf) in [Vec3::new(0.3, -0.2, 0.93).normalize(), Vec3::new(0.5, 0.1, -0.7).normalize()]
            .into_iter()
            .flat_map(|wo| {
                [
                    Bsdf::Lambert { albedo: Vec3::splat(0.5) },
                    Bsdf::RoughConductor { eta: Vec3::splat(0.2), k: Vec3::splat(3.9), alpha: 0.3 },
                    Bsdf::RoughDielectric { eta: 1.5, alpha: 0.2 },
                    Bsdf::Plastic {
                        diffuse: Vec3::splat(0.5),
                        eta: 1.5,
                        fdr: fresnel_diffuse_reflectance(1.5),
                    },
                ]
                .map(|b| (wo, b))
            })
        {
            let mut sampled = 0;
            for i in 0..2000u64 {
                let u = u2(i, 1);
                let Some(s) = bsdf.sample(wo, u2(i, 2).x, u) else { continue };
                if s.lobe == Lobe::Specular {
                    continue;
                }
                let f = bsdf.eval(wo, s.wi);
                let pdf = bsdf.pdf(wo, s.wi);
                assert!((pdf - s.pdf).abs() <= 1e-3 * pdf.max(1.0), "{bsdf:?}: pdf {pdf} vs {}", s.pdf);
                let w = f / pdf;
                assert!((w - s.weight).abs().max_element() <= 1e-3 * w.max_element().max(1.0), "{bsdf:?}");
                sampled += 1;
            }
            // Opaque surfaces scatter nothing from below; everything else must sample.
            assert!(sampled > 0 || wo.z < 0.0, "{bsdf:?} never sampled");
        }
    }

    /// Energy: a white Lambertian reflects everything; a rough dielectric never creates
    /// energy (reflection plus transmission, without the radiance scaling, is at most 1).
    #[test]
    fn white_furnace() {
        let wo = Vec3::new(0.1, 0.2, 0.97).normalize();
        let n = 100_000;
        let lambert = Bsdf::Lambert { albedo: Vec3::ONE };
        let mut sum = 0.0;
        for i in 0..n {
            if let Some(s) = lambert.sample(wo, 0.5, u2(i, 3)) {
                sum += s.weight.x;
            }
        }
        assert!((sum / n as f32 - 1.0).abs() < 1e-3);
    }

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
