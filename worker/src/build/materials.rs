//! Textures (images decoded to linear RGB) and materials, from their descriptions.

use glam::Vec3;
use tessera_description::bundle::Assets;
use tessera_description::model::{self as d, Description, Location, TextureKind};
use tessera_description::SceneError;

use crate::render::material::{Classic, Material};
use crate::render::texture::{Tex, Texture};

/// Every texture of the scene, images decoded.
pub(super) fn textures(
    desc: &Description,
    assets: &dyn Assets,
    files: &mut super::gltf::Files,
    err: &dyn Fn(Location, String) -> SceneError,
) -> Result<Vec<Texture>, SceneError> {
    let (srgb, linear) = roles(desc);
    desc.textures
        .iter()
        .enumerate()
        .map(|(i, t)| match &t.kind {
            TextureKind::Checker { even, odd, size, space } => {
                Ok(Texture::Checker { even: *even, odd: *odd, size: *size, space: *space })
            }
            TextureKind::Image { file, .. } => {
                let what = format!("textures.{}.file", t.name);
                let bytes = assets.get(file).ok_or_else(|| {
                    err(t.at, format!("{what}: cannot read {file:?} (relative to the scene's folder)"))
                })?;
                // The header was good; the pixels may still be damaged, and the scene may
                // not have been validated by this build's limits.
                let img = super::images::decode_image(bytes)
                    .map_err(|e| err(t.at, format!("{what}: {file:?} is not a readable image: {e}")))?;
                let (width, height, values) = crate::render::texture::linear_rgb(&img);
                let texels = values.chunks_exact(3).map(Vec3::from_slice).collect();
                Ok(Texture::Image { width, height, texels })
            }
            TextureKind::GltfImage { file, image, .. } => {
                let decoded = files
                    .get(file, assets)
                    .and_then(|a| super::gltf::image(a, *image, assets, srgb[i], linear[i] || !srgb[i]))
                    .map_err(|e| err(t.at, e))?;
                Ok(Texture::Rgba(Box::new(decoded)))
            }
        })
        .collect()
}

/// Per texture: whether a glTF material reads it as sRGB colour (base colour,
/// emissive) and whether as linear data (metallic-roughness, normals).
fn roles(desc: &Description) -> (Vec<bool>, Vec<bool>) {
    let (mut srgb, mut linear) = (vec![false; desc.textures.len()], vec![false; desc.textures.len()]);
    let mark = |v: &mut Vec<bool>, r: Option<d::TexRef>| {
        if let Some(slot) = r.and_then(|r| v.get_mut(r.texture as usize)) {
            *slot = true;
        }
    };
    for m in &desc.materials {
        if let d::Material::Pbr(p) = m {
            mark(&mut srgb, p.base_color_texture);
            mark(&mut srgb, p.emissive_texture);
            mark(&mut linear, p.metallic_roughness_texture);
            mark(&mut linear, p.normal_texture.map(|(r, _)| r));
        }
    }
    (srgb, linear)
}

fn tex(c: d::Color) -> Tex {
    match c {
        d::Color::Const(v) => Tex::Const(v),
        d::Color::Texture(i) => Tex::Map(i),
    }
}

/// The renderer's material for a described one.
pub(super) fn material(m: &d::Material) -> Material {
    match *m {
        d::Material::Classic(c) => Material::Classic(Classic {
            color: tex(c.color),
            ambient: c.ambient,
            diffuse: c.diffuse,
            specular: c.specular,
            shininess: c.shininess,
            reflect: c.reflect,
            transmit: c.transmit,
            ior: c.ior,
            gloss: c.gloss,
            translucency: c.translucency,
        }),
        d::Material::Lambert { albedo } => Material::Lambert { albedo: tex(albedo) },
        d::Material::Mirror { reflectance } => Material::Mirror { reflectance },
        d::Material::Dielectric { ior } => Material::Dielectric { ior },
        d::Material::Conductor { eta, k, roughness } => Material::Conductor { eta, k, roughness },
        d::Material::RoughDielectric { ior, roughness } => Material::RoughDielectric { ior, roughness },
        d::Material::Plastic { diffuse, ior } => Material::Plastic { diffuse: tex(diffuse), ior },
        d::Material::Pbr(p) => Material::Pbr(p),
    }
}
