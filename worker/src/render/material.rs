//! Materials: the classic (Whitted/Phong) model of the seed paper, with Cook's gloss and
//! translucency, and the physically based family of `bsdf/`.

use glam::{Vec2, Vec3, Vec4};

pub use tessera_description::model::{AlphaMode, Pbr, TexRef};

use super::bsdf::{fresnel_diffuse_reflectance, Bsdf, MetallicRoughness, SMOOTH_ALPHA};
use super::texture::{Encoding, Tex, Texture};

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
    /// glTF 2.0 metallic-roughness, its textures read with the primitive's texture
    /// coordinate sets (`pbr_*` below).
    Pbr(Pbr),
}

/// What a glTF material is at one point, its textures looked up.
#[derive(Debug, Clone, Copy)]
pub struct PbrPoint {
    /// The BRDF.
    pub bsdf: MetallicRoughness,
    /// The tangent-space normal from the normal map (scaled in x and y), if it has one.
    pub normal: Option<Vec3>,
}

/// A texture reference's value at a point with texture coordinate sets `uvs`.
fn lookup(textures: &[Texture], r: TexRef, uvs: &[Vec2; 2], encoding: Encoding) -> Vec4 {
    let uv = uvs[(r.texcoord as usize).min(1)];
    textures[r.texture as usize].rgba(Vec3::ZERO, uv, encoding)
}

/// Base colour (linear RGBA): the factor times the sRGB texture.
pub fn pbr_base(m: &Pbr, textures: &[Texture], uvs: &[Vec2; 2]) -> Vec4 {
    match m.base_color_texture {
        Some(r) => m.base_color * lookup(textures, r, uvs, Encoding::Srgb),
        None => m.base_color,
    }
}

/// The material at a point: base colour, metallic and roughness (texture blue and green),
/// the normal map's tangent-space normal.
pub fn pbr_point(m: &Pbr, textures: &[Texture], uvs: &[Vec2; 2]) -> PbrPoint {
    let base = pbr_base(m, textures, uvs);
    let (mut metallic, mut roughness) = (m.metallic, m.roughness);
    if let Some(r) = m.metallic_roughness_texture {
        let t = lookup(textures, r, uvs, Encoding::Linear);
        metallic *= t.z;
        roughness *= t.y;
    }
    let normal = m.normal_texture.map(|(r, scale)| {
        let t = lookup(textures, r, uvs, Encoding::Linear);
        let n = t.truncate() * 2.0 - Vec3::ONE;
        Vec3::new(n.x * scale, n.y * scale, n.z)
    });
    let roughness = roughness.clamp(0.0, 1.0);
    PbrPoint {
        bsdf: MetallicRoughness {
            base: base.truncate().clamp(Vec3::ZERO, Vec3::ONE),
            metallic: metallic.clamp(0.0, 1.0),
            alpha: roughness * roughness,
            ior: m.ior,
            transmission: m.transmission.clamp(0.0, 1.0),
        },
        normal,
    }
}

/// What the emissive texture multiplies the primitive's emission by (the Object's
/// emission is the factor): its sRGB colour, or 1.
pub fn pbr_emission_scale(m: &Pbr, textures: &[Texture], uvs: &[Vec2; 2]) -> Vec3 {
    match m.emissive_texture {
        Some(r) => lookup(textures, r, uvs, Encoding::Srgb).truncate(),
        None => Vec3::ONE,
    }
}

/// Whether a hit on a glTF surface counts, by its alpha: `MASK` cuts out below the
/// cutoff; `BLEND` is stochastic coverage, the hit kept when alpha exceeds `threshold`
/// (a hash of the ray in [0, 1), so that on average a fraction alpha of the rays stop).
pub fn pbr_covers(m: &Pbr, textures: &[Texture], uvs: &[Vec2; 2], threshold: f32) -> bool {
    let alpha = || pbr_base(m, textures, uvs).w;
    match m.alpha {
        AlphaMode::Opaque => true,
        AlphaMode::Mask(cutoff) => alpha() >= cutoff,
        AlphaMode::Blend => alpha() > threshold,
    }
}

impl Material {
    /// Whether some hits on this material may be no hits (alpha cut-outs): only these pay
    /// for the any-hit test.
    pub fn has_alpha(&self) -> bool {
        matches!(self, Material::Pbr(m) if m.alpha != AlphaMode::Opaque)
    }
}

impl Material {
    /// The BSDF at a point, for the physically based materials.
    #[inline]
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
            // Both texture coordinate sets read `uv` here; the integrator shades glTF
            // surfaces through `pbr_point` with the primitive's own sets.
            Material::Pbr(m) => Bsdf::MetallicRoughness(pbr_point(m, textures, &[uv, uv]).bsdf),
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
            // glTF metallic-roughness: its base colour. The AOV ray knows the first texture
            // coordinate set only, so a base colour on TEXCOORD_1 is looked up on set 0.
            Material::Pbr(m) => pbr_base(m, textures, &[uv, uv]).truncate(),
        };
        a.clamp(Vec3::ZERO, Vec3::ONE)
    }

    /// Whether the material looks anything up in a texture (and so needs UVs).
    pub fn is_textured(&self) -> bool {
        match self {
            Material::Classic(c) => matches!(c.color, Tex::Map(_)),
            Material::Lambert { albedo } => matches!(albedo, Tex::Map(_)),
            Material::Plastic { diffuse, .. } => matches!(diffuse, Tex::Map(_)),
            Material::Pbr(m) => {
                m.base_color_texture.is_some()
                    || m.metallic_roughness_texture.is_some()
                    || m.normal_texture.is_some()
                    || m.emissive_texture.is_some()
            }
            _ => false,
        }
    }
}
