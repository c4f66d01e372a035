//! Materials: the classic (Whitted/Phong) model of the seed paper, with Cook's gloss and
//! translucency, and the physically based family of `bsdf/`.

use glam::{Vec2, Vec3};

use super::bsdf::{fresnel_diffuse_reflectance, Bsdf, SMOOTH_ALPHA};
use super::texture::{Tex, Texture};

/// The classic model: ambient, diffuse colour, Phong highlight, mirror reflection and
/// refraction coefficients. Colours are reflectances of the classic model, not
/// energy-conserving BSDFs. `gloss` and `translucency` blur the reflected and refracted
/// rays (Cook 1984): the roughness of a lobe around the ideal direction; 0 is sharp.
#[derive(Debug, Clone, PartialEq)]
pub struct Classic {
    /// Diffuse colour.
    pub color: Tex,
    /// Fraction of the scene's ambient light reflected (times `color`).
    pub ambient: f32,
    /// Diffuse coefficient (times `color`).
    pub diffuse: f32,
    /// Phong highlight coefficient (white highlight).
    pub specular: f32,
    /// Phong exponent.
    pub shininess: f32,
    /// Mirror reflection per channel.
    pub reflect: Vec3,
    /// Refraction (transmission) per channel; also tints light passing through.
    pub transmit: Vec3,
    /// Index of refraction of the inside.
    pub ior: f32,
    /// Roughness of the reflection lobe (0: sharp mirror).
    pub gloss: f32,
    /// Roughness of the refraction lobe (0: clear).
    pub translucency: f32,
}

/// A material.
#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    /// The classic model.
    Classic(Classic),
    /// Lambertian, albedo/π.
    Lambert {
        /// Albedo.
        albedo: Tex,
    },
    /// Ideal mirror, no Fresnel.
    Mirror {
        /// Reflectance.
        reflectance: Vec3,
    },
    /// Smooth dielectric (glass).
    Dielectric {
        /// Index of refraction inside (outside 1).
        ior: f32,
    },
    /// Conductor with a complex index, smooth or rough (GGX).
    Conductor {
        /// Real part.
        eta: Vec3,
        /// Imaginary part.
        k: Vec3,
        /// GGX roughness (0: smooth).
        roughness: f32,
    },
    /// Rough dielectric (frosted glass).
    RoughDielectric {
        /// Index inside.
        ior: f32,
        /// GGX roughness.
        roughness: f32,
    },
    /// Smooth plastic: dielectric coat over a diffuse base.
    Plastic {
        /// Base albedo.
        diffuse: Tex,
        /// Coat index.
        ior: f32,
    },
}

impl Material {
    /// The BSDF at a point, for the physically based materials.
    pub fn bsdf(&self, textures: &[Texture], p: Vec3, uv: Vec2) -> Option<Bsdf> {
        Some(match self {
            Material::Classic(_) => return None,
            Material::Lambert { albedo } => Bsdf::Lambert { albedo: albedo.eval(textures, p, uv) },
            Material::Mirror { reflectance } => Bsdf::Mirror { reflectance: *reflectance },
            Material::Dielectric { ior } => Bsdf::Dielectric { eta: *ior },
            Material::Conductor { eta, k, roughness } if *roughness < SMOOTH_ALPHA => {
                Bsdf::SmoothConductor { eta: *eta, k: *k }
            }
            Material::Conductor { eta, k, roughness } => {
                Bsdf::RoughConductor { eta: *eta, k: *k, alpha: *roughness }
            }
            Material::RoughDielectric { ior, roughness } if *roughness < SMOOTH_ALPHA => {
                Bsdf::Dielectric { eta: *ior }
            }
            Material::RoughDielectric { ior, roughness } => {
                Bsdf::RoughDielectric { eta: *ior, alpha: *roughness }
            }
            Material::Plastic { diffuse, ior } => Bsdf::Plastic {
                diffuse: diffuse.eval(textures, p, uv),
                eta: *ior,
                fdr: fresnel_diffuse_reflectance(*ior),
            },
        })
    }

    /// What fraction of light a shadow ray passes through this surface: the classic
    /// model's transmission (coloured shadows), all of it for a dielectric of index 1 (no
    /// interface at all: it neither bends nor reflects), zero for everything else (Cook's
    /// transport: shadows through glass are black, no caustics).
    pub fn shadow_transmission(&self) -> Vec3 {
        match self {
            Material::Classic(c) => c.transmit,
            Material::Dielectric { ior } | Material::RoughDielectric { ior, .. } if *ior == 1.0 => Vec3::ONE,
            _ => Vec3::ZERO,
        }
    }

    /// The material's reflectance at a point, in [0, 1]: what the albedo AOV layer holds
    /// (`crate::aov`), as Open Image Denoise asks for it: the diffuse colour of matte
    /// surfaces, the reflectivity at normal incidence of metals, 1 for glass.
    pub fn albedo(&self, textures: &[Texture], p: Vec3, uv: Vec2) -> Vec3 {
        let a = match self {
            Material::Classic(c) => c.color.eval(textures, p, uv),
            Material::Lambert { albedo } => albedo.eval(textures, p, uv),
            Material::Mirror { reflectance } => *reflectance,
            Material::Dielectric { .. } | Material::RoughDielectric { .. } => Vec3::ONE,
            // The conductor Fresnel reflectance at normal incidence: ((η−1)² + k²) / ((η+1)² + k²).
            Material::Conductor { eta, k, .. } => {
                let k2 = *k * *k;
                ((*eta - 1.0) * (*eta - 1.0) + k2) / ((*eta + 1.0) * (*eta + 1.0) + k2)
            }
            Material::Plastic { diffuse, .. } => diffuse.eval(textures, p, uv),
            // New materials add their arm here (glTF metallic-roughness: base colour).
        };
        a.clamp(Vec3::ZERO, Vec3::ONE)
    }

    /// Whether the material looks anything up in a texture (and so needs UVs).
    pub fn is_textured(&self) -> bool {
        match self {
            Material::Classic(c) => matches!(c.color, Tex::Map(_)),
            Material::Lambert { albedo } => matches!(albedo, Tex::Map(_)),
            Material::Plastic { diffuse, .. } => matches!(diffuse, Tex::Map(_)),
            _ => false,
        }
    }
}
