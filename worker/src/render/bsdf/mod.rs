//! Physically based scattering with the standard definitions, so that images compare with
//! established renderers: Lambertian, ideal mirror, smooth dielectric, rough conductor and
//! rough dielectric (GGX with separable Smith shadowing; Walter et al. 2007), and smooth
//! plastic (a dielectric coat over a diffuse base, Mitsuba's `plastic`). Directions are in
//! the local shading frame, z along the normal, both pointing away from the surface.
//!
//! One file per BSDF holds its eval, pdf and sample together (as pbrt and Mitsuba group
//! them); this file holds the enum and its dispatch, and the shared pieces (Fresnel, the
//! GGX distribution, the frame, the warps) have small files of their own.

mod dielectric;
mod frame;
mod fresnel;
mod lambert;
mod metallic_roughness;
mod microfacet;
mod mirror;
mod plastic;
mod rough_conductor;
mod rough_dielectric;
mod smooth_conductor;
mod warp;

use glam::{Vec2, Vec3};

pub use frame::Frame;
pub use fresnel::{fresnel_conductor, fresnel_dielectric, fresnel_diffuse_reflectance};
pub use metallic_roughness::MetallicRoughness;
pub use microfacet::{ggx_d, ggx_g1};
pub use warp::{concentric_disk, cosine_hemisphere};

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
    /// glTF 2.0's metallic-roughness BRDF (its specification's appendix B), with
    /// KHR_materials_transmission.
    MetallicRoughness(MetallicRoughness),
}

/// Roughness below which a microfacet lobe is treated as perfectly smooth: GGX with
/// α → 0 tends to the Dirac lobe, and its density overflows f32 long before.
pub const SMOOTH_ALPHA: f32 = 1e-4;

impl Bsdf {
    /// Whether every lobe is a Dirac lobe (light sampling cannot help).
    pub fn is_delta(&self) -> bool {
        match self {
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } | Bsdf::SmoothConductor { .. } => true,
            Bsdf::RoughConductor { .. } | Bsdf::RoughDielectric { .. } => false,
            Bsdf::Lambert { .. } | Bsdf::Plastic { .. } => false,
            Bsdf::MetallicRoughness(b) => b.is_delta(),
        }
    }

    /// f(wo, wi) · |cos θi| for the non-Dirac lobes.
    // This and the other dispatchers on a bounce's path (`pdf`, `split`, `sample`,
    // `Material::bsdf`, `Light::sample` and `pdf`) are hinted inline: the profile-guided
    // build inlines them into the integrator's loop, and the hint gets a plain release
    // build a little of that (docs/speed.md, twentieth part).
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match *self {
            Bsdf::Lambert { albedo } => lambert::eval(wo, wi, albedo),
            Bsdf::Plastic { diffuse, eta, fdr } => plastic::eval(wo, wi, diffuse, eta, fdr),
            Bsdf::RoughConductor { eta, k, alpha } => rough_conductor::eval(wo, wi, eta, k, alpha),
            Bsdf::RoughDielectric { eta, alpha } => Vec3::splat(rough_dielectric::eval(wo, wi, eta, alpha)),
            Bsdf::MetallicRoughness(b) => b.eval(wo, wi),
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } | Bsdf::SmoothConductor { .. } => Vec3::ZERO,
        }
    }

    /// Density of `sample` returning `wi` (non-Dirac lobes only).
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match *self {
            Bsdf::Lambert { .. } => lambert::pdf(wo, wi),
            Bsdf::Plastic { diffuse, eta, .. } => plastic::pdf(wo, wi, diffuse, eta),
            Bsdf::RoughConductor { alpha, .. } => rough_conductor::pdf(wo, wi, alpha),
            Bsdf::RoughDielectric { eta, alpha } => rough_dielectric::pdf(wo, wi, eta, alpha),
            Bsdf::MetallicRoughness(b) => b.pdf(wo, wi),
            Bsdf::Mirror { .. } | Bsdf::Dielectric { .. } | Bsdf::SmoothConductor { .. } => 0.0,
        }
    }

    /// Which of [`Bsdf::sample`]'s random numbers it reads: the lobe choice `u_lobe`, the
    /// 2-D sample `u`. The integrator skips a draw that is not read (a draw costs more than
    /// a mirror's whole sample) and counts its dimension all the same, so that later draws
    /// keep their numbers; `tests::sample_reads_only_what_draws_says` holds every lobe to it.
    pub fn draws(&self) -> (bool, bool) {
        match self {
            Bsdf::Mirror { .. } | Bsdf::SmoothConductor { .. } => (false, false),
            Bsdf::Lambert { .. } | Bsdf::RoughConductor { .. } => (false, true),
            Bsdf::Dielectric { .. } => (true, false),
            Bsdf::Plastic { .. } | Bsdf::RoughDielectric { .. } | Bsdf::MetallicRoughness(_) => (true, true),
        }
    }

    /// Both lobes of a smooth dielectric, to be followed both (Whitted's two rays) where
    /// [`Bsdf::sample`] would pick one; `None` for every other BSDF, and on total
    /// internal reflection.
    #[inline]
    pub fn split(&self, wo: Vec3) -> Option<[BsdfSample; 2]> {
        match *self {
            Bsdf::Dielectric { eta } => dielectric::split(wo, eta),
            _ => None,
        }
    }

    /// Samples an incident direction given `wo`, with a lobe choice `u_lobe` and a 2-D
    /// sample `u`.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        match *self {
            Bsdf::Lambert { albedo } => lambert::sample(wo, u, albedo),
            Bsdf::Mirror { reflectance } => mirror::sample(wo, reflectance),
            Bsdf::SmoothConductor { eta, k } => smooth_conductor::sample(wo, eta, k),
            Bsdf::Dielectric { eta } => dielectric::sample(wo, u_lobe, eta),
            Bsdf::Plastic { diffuse, eta, fdr } => plastic::sample(wo, u_lobe, u, diffuse, eta, fdr),
            Bsdf::RoughConductor { eta, k, alpha } => rough_conductor::sample(wo, u, eta, k, alpha),
            Bsdf::RoughDielectric { eta, alpha } => rough_dielectric::sample(wo, u_lobe, u, eta, alpha),
            Bsdf::MetallicRoughness(b) => b.sample(wo, u_lobe, u),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::sampler::hash_words;
    use tessera_description::math;

    pub(super) fn u2(i: u64, k: u64) -> Vec2 {
        let h = hash_words(&[i, k]);
        Vec2::new(
            (h >> 40) as f32 / (1u64 << 24) as f32,
            ((h >> 16) & 0xff_ffff) as f32 / (1u64 << 24) as f32,
        )
    }

    /// `draws` tells what `sample` reads: with the numbers it says are not read changed,
    /// every lobe samples the same bits, from both sides of the surface.
    #[test]
    fn sample_reads_only_what_draws_says() {
        let metal = (Vec3::new(0.2, 0.9, 1.1), Vec3::new(3.9, 2.4, 2.2));
        let bsdfs = [
            Bsdf::Lambert { albedo: Vec3::splat(0.5) },
            Bsdf::Mirror { reflectance: Vec3::splat(0.9) },
            Bsdf::Dielectric { eta: 1.5 },
            Bsdf::SmoothConductor { eta: metal.0, k: metal.1 },
            Bsdf::RoughConductor { eta: metal.0, k: metal.1, alpha: 0.3 },
            Bsdf::RoughDielectric { eta: 1.5, alpha: 0.2 },
            Bsdf::Plastic { diffuse: Vec3::splat(0.5), eta: 1.5, fdr: fresnel_diffuse_reflectance(1.5) },
        ];
        let mut skipped = 0;
        for bsdf in bsdfs {
            let (lobe, dir) = bsdf.draws();
            for i in 0..4000 {
                let Some(wo) = (u2(i, 1).extend(u2(i, 2).x) * 2.0 - 1.0).try_normalize() else { continue };
                let (ul, u) = (u2(i, 3).x, u2(i, 4));
                let (other_ul, other_u) = (u2(i, 5).y, u2(i, 6));
                let want = bsdf.sample(wo, ul, u);
                let got = bsdf.sample(wo, if lobe { ul } else { other_ul }, if dir { u } else { other_u });
                let bits = |s: Option<BsdfSample>| {
                    s.map(|s| {
                        (
                            s.wi.to_array().map(f32::to_bits),
                            s.weight.to_array().map(f32::to_bits),
                            s.pdf.to_bits(),
                            s.lobe,
                        )
                    })
                };
                assert_eq!(bits(got), bits(want), "{bsdf:?} wo {wo}");
                skipped += usize::from(!lobe) + usize::from(!dir);
            }
        }
        assert!(skipped > 0);
    }

    /// A lobe is chosen by `u_lobe` (and `wo`) alone, never by `u`: a diffuse lobe's
    /// several rays (`[render] diffuse_rays`) are drawn again with the `u_lobe` that
    /// picked the lobe, and are each from that lobe only because of this. Every BSDF that
    /// has a diffuse lobe, and the others, from both sides of the surface.
    #[test]
    fn a_lobe_is_chosen_by_u_lobe_alone() {
        let metal = (Vec3::new(0.2, 0.9, 1.1), Vec3::new(3.9, 2.4, 2.2));
        let pbr = |metallic: f32, alpha: f32, transmission: f32| {
            Bsdf::MetallicRoughness(MetallicRoughness {
                base: Vec3::new(0.8, 0.5, 0.3),
                metallic,
                alpha,
                ior: 1.5,
                transmission,
            })
        };
        let bsdfs = [
            Bsdf::Lambert { albedo: Vec3::splat(0.5) },
            Bsdf::Plastic { diffuse: Vec3::splat(0.5), eta: 1.5, fdr: fresnel_diffuse_reflectance(1.5) },
            Bsdf::RoughConductor { eta: metal.0, k: metal.1, alpha: 0.3 },
            Bsdf::RoughDielectric { eta: 1.5, alpha: 0.2 },
            pbr(0.0, 0.25, 0.0),
            pbr(0.5, 0.04, 0.0),
            pbr(0.0, 0.0, 0.0),
            pbr(0.0, 0.3, 0.6),
        ];
        let mut diffuse = 0;
        for bsdf in bsdfs {
            for i in 0..4000 {
                let Some(wo) = (u2(i, 1).extend(u2(i, 2).x) * 2.0 - 1.0).try_normalize() else { continue };
                let ul = u2(i, 3).x;
                let lobes: Vec<Lobe> =
                    (4..12).filter_map(|k| bsdf.sample(wo, ul, u2(i, k)).map(|s| s.lobe)).collect();
                assert!(lobes.windows(2).all(|w| w[0] == w[1]), "{bsdf:?} wo {wo} u_lobe {ul}: {lobes:?}");
                diffuse += lobes.iter().filter(|&&l| l == Lobe::Diffuse).count();
            }
        }
        assert!(diffuse > 10_000, "{diffuse} diffuse samples");
    }

    /// A split dielectric follows the two directions its pick chooses between, each weighted
    /// by the pick's weight times its probability, so a path's expectation is the same
    /// either way; from both sides, grazing included. Total internal reflection and every
    /// other BSDF do not split.
    #[test]
    fn a_split_is_the_pick_weighted_by_its_probabilities() {
        let bits = |v: Vec3| v.to_array().map(f32::to_bits);
        let (mut split, mut whole) = (0, 0);
        for eta in [1.5, 1.0 / 1.33, 2.4] {
            let bsdf = Bsdf::Dielectric { eta };
            for i in 0..4000 {
                let Some(mut wo) = (u2(i, 1).extend(u2(i, 2).x) * 2.0 - 1.0).try_normalize() else {
                    continue;
                };
                if i % 97 == 0 {
                    wo = Vec3::new(1.0, 0.0, 1e-7 * wo.z.signum()).normalize();
                }
                let f = fresnel::fresnel_dielectric(wo.z, eta);
                let (Some(r), t) = (bsdf.sample(wo, 0.0, Vec2::ZERO), bsdf.sample(wo, ONE_BELOW, Vec2::ZERO))
                else {
                    panic!("reflection always exists")
                };
                match bsdf.split(wo) {
                    Some([rs, ts]) => {
                        let t = t.expect("refraction exists where the split has it");
                        assert!(f < 1.0);
                        assert_eq!((bits(rs.wi), bits(ts.wi)), (bits(r.wi), bits(t.wi)), "eta {eta} wo {wo}");
                        assert_eq!(bits(rs.weight), bits(r.weight * f));
                        let want = t.weight * (1.0 - f);
                        assert!((ts.weight - want).abs().max_element() <= 1e-6 * want.max_element());
                        assert!(rs.lobe == Lobe::Specular && ts.lobe == Lobe::Specular);
                        split += 1;
                    }
                    // Total internal reflection: the pick reflects whatever its number.
                    None => {
                        assert_eq!(f, 1.0, "eta {eta} wo {wo}");
                        whole += 1;
                    }
                }
            }
        }
        assert!(split > 5000 && whole > 100, "{split} split, {whole} whole");
        let wo = Vec3::new(0.3, 0.2, 0.9).normalize();
        assert!(Bsdf::Mirror { reflectance: Vec3::ONE }.split(wo).is_none());
        assert!(Bsdf::RoughDielectric { eta: 1.5, alpha: 0.2 }.split(wo).is_none());
    }

    /// The largest f32 below 1: a lobe number that picks refraction wherever F < 1.
    const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

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

    /// Sampling is unbiased: the mean weight of the sampled (non-Dirac) directions equals
    /// ∫ f |cos θi| over the sphere by uniform directions, for views above and below, so
    /// the density `pdf` reports is the one `sample` draws from.
    #[test]
    fn sampling_estimates_what_uniform_directions_estimate() {
        let views = [Vec3::new(0.3, -0.2, 0.93), Vec3::new(0.8, 0.1, 0.2), Vec3::new(0.5, 0.1, -0.7)];
        let bsdfs = [
            Bsdf::RoughConductor { eta: Vec3::splat(0.2), k: Vec3::splat(3.9), alpha: 0.3 },
            Bsdf::RoughDielectric { eta: 1.5, alpha: 0.3 },
            Bsdf::Plastic {
                diffuse: Vec3::new(0.7, 0.08, 0.08),
                eta: 1.5,
                fdr: fresnel_diffuse_reflectance(1.5),
            },
        ];
        for wo in views.map(Vec3::normalize) {
            for bsdf in bsdfs {
                let n = 400_000u64;
                let mut sampled = 0.0f64;
                for i in 0..n {
                    if let Some(s) = bsdf.sample(wo, u2(i, 21).x, u2(i, 22)) {
                        if s.lobe != Lobe::Specular {
                            sampled += f64::from(s.weight.x);
                        }
                    }
                }
                let mut uniform = 0.0f64;
                for i in 0..n {
                    let u = u2(i, 23);
                    let (z, phi) = (1.0 - 2.0 * u.x, 2.0 * std::f32::consts::PI * u.y);
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let wi = Vec3::new(r * math::cos(phi), r * math::sin(phi), z);
                    uniform += f64::from(bsdf.eval(wo, wi).x) * 4.0 * std::f64::consts::PI;
                }
                let (sampled, uniform) = (sampled / n as f64, uniform / n as f64);
                assert!(
                    (sampled - uniform).abs() < 0.01 + 0.02 * uniform,
                    "{bsdf:?} from {wo}: sampling gives {sampled}, uniform directions {uniform}"
                );
            }
        }
    }

    /// Visible-normal sampling bounds a rough conductor's weight by F · G1(wi) ≤ 1, at every
    /// view down to grazing (sampling D(m) cos θm let it grow as 1 / cos θo).
    #[test]
    fn rough_conductor_weights_stay_at_most_one() {
        let gold = Bsdf::RoughConductor {
            eta: Vec3::new(0.18, 0.42, 1.37),
            k: Vec3::new(3.42, 2.35, 1.77),
            alpha: 0.15,
        };
        for cos_o in [1.0f32, 0.5, 0.1, 0.02] {
            let wo = Vec3::new((1.0 - cos_o * cos_o).sqrt(), 0.0, cos_o);
            for i in 0..20_000u64 {
                let Some(s) = gold.sample(wo, 0.5, u2(i, 5)) else { continue };
                assert!(s.weight.max_element() <= 1.0 + 1e-4, "cos θo {cos_o}: weight {}", s.weight);
            }
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
}
