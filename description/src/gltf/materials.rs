//! glTF materials as `Pbr` (metallic-roughness with KHR_materials_emissive_strength,
//! KHR_materials_ior and KHR_materials_transmission), every factor checked, and the
//! images they use, sized from their headers only.

use std::io::Cursor;

use glam::{Vec3, Vec4};
use gltf::json::material::AlphaMode as GAlpha;
use gltf::json::validation::Checked;
use gltf::json::{self, Root};

use super::container::resolve;
use super::{at, GltfError, Instance};
use crate::assets::Assets;
use crate::limits;
use crate::model::{AlphaMode, Pbr, TexRef};

/// glTF's default material (§3.9.6): white, fully metallic and fully rough.
pub(crate) fn default_material() -> Pbr {
    Pbr {
        base_color: Vec4::ONE,
        base_color_texture: None,
        metallic: 1.0,
        roughness: 1.0,
        metallic_roughness_texture: None,
        normal_texture: None,
        emissive: Vec3::ZERO,
        emissive_texture: None,
        alpha: AlphaMode::Opaque,
        double_sided: false,
        ior: 1.5,
        transmission: 0.0,
    }
}

/// The encoded bytes of `images[image]`.
pub(crate) fn image_bytes(
    file: &str,
    root: &Root,
    buffers: &[Vec<u8>],
    image: u32,
    assets: &dyn Assets,
) -> Result<Vec<u8>, GltfError> {
    let path = at!("images[{image}]");
    let img = root
        .images
        .get(image as usize)
        .ok_or_else(|| GltfError::new(file, path.clone(), "does not exist"))?;
    match (&img.uri, img.buffer_view) {
        (Some(uri), _) => resolve(file, uri, assets).map_err(|m| GltfError::new(file, at!("{path}.uri"), m)),
        (None, Some(v)) => {
            let view = &root.buffer_views[v.value()];
            let start = view.byte_offset.map_or(0, |o| o.0) as usize;
            buffers
                .get(view.buffer.value())
                .and_then(|b| b.get(start..start + view.byte_length.0 as usize))
                .map(<[u8]>::to_vec)
                .ok_or_else(|| {
                    GltfError::new(
                        file,
                        at!("{path}.bufferView"),
                        format!("buffer view {} cannot be read", v.value()),
                    )
                })
        }
        (None, None) => Err(GltfError::new(file, path, "has neither a uri nor a bufferView")),
    }
}

/// Width and height of an image from its header.
fn image_size(file: &str, path: &str, bytes: &[u8]) -> Result<(u32, u32), GltfError> {
    let (w, h) = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())
        .and_then(|r| r.into_dimensions().map_err(|e| e.to_string()))
        .map_err(|e| GltfError::new(file, path, format!("not a readable image (PNG or JPEG): {e}")))?;
    if u64::from(w) * u64::from(h) > limits::MAX_TEXTURE_PIXELS {
        return Err(GltfError::new(
            file,
            path,
            format!(
                "the image is {w}x{h}, more than the limit of {} pixels for a texture",
                limits::MAX_TEXTURE_PIXELS
            ),
        ));
    }
    Ok((w, h))
}

/// A material's texture reference: `TexRef.texture` is the glTF *image* index here.
fn texref(root: &Root, info: &json::texture::Info) -> TexRef {
    TexRef { texture: root.textures[info.index.value()].source.value() as u32, texcoord: info.tex_coord }
}

fn unit(file: &str, path: String, v: f32) -> Result<f32, GltfError> {
    if (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(GltfError::new(file, path, format!("{v} is not in [0, 1]")))
    }
}

/// `materials[i]` as Tessera's `Pbr`.
fn material(file: &str, root: &Root, i: usize) -> Result<Pbr, GltfError> {
    let m = &root.materials[i];
    let path = at!("materials[{i}]");
    let p = &m.pbr_metallic_roughness;
    let base = Vec4::from(p.base_color_factor.0);
    if !base.cmpge(Vec4::ZERO).all() || !base.cmple(Vec4::ONE).all() {
        return Err(GltfError::new(
            file,
            at!("{path}.pbrMetallicRoughness.baseColorFactor"),
            format!("{base} is not in [0, 1]"),
        ));
    }
    let metallic = unit(file, at!("{path}.pbrMetallicRoughness.metallicFactor"), p.metallic_factor.0)?;
    let roughness = unit(file, at!("{path}.pbrMetallicRoughness.roughnessFactor"), p.roughness_factor.0)?;
    let ext = m.extensions.as_ref();
    let strength = ext.and_then(|e| e.emissive_strength.as_ref()).map_or(1.0, |s| s.emissive_strength.0);
    let emissive = Vec3::from(m.emissive_factor.0) * strength;
    if !emissive.is_finite() || emissive.min_element() < 0.0 {
        return Err(GltfError::new(
            file,
            at!("{path}.emissiveFactor"),
            format!("{emissive} (times the emissive strength) must be finite and not negative"),
        ));
    }
    let ior = ext.and_then(|e| e.ior.as_ref()).map_or(1.5, |i| i.ior.0);
    if !(1.0..=10.0).contains(&ior) {
        return Err(GltfError::new(
            file,
            at!("{path}.extensions.KHR_materials_ior.ior"),
            format!("{ior} is not in [1, 10]"),
        ));
    }
    let transmission = ext.and_then(|e| e.transmission.as_ref()).map_or(0.0, |t| t.transmission_factor.0);
    let transmission =
        unit(file, at!("{path}.extensions.KHR_materials_transmission.transmissionFactor"), transmission)?;
    let alpha = match m.alpha_mode {
        Checked::Valid(GAlpha::Mask) => {
            let cutoff = m.alpha_cutoff.map_or(0.5, |c| c.0);
            AlphaMode::Mask(unit(file, at!("{path}.alphaCutoff"), cutoff)?)
        }
        Checked::Valid(GAlpha::Blend) => AlphaMode::Blend,
        _ => AlphaMode::Opaque,
    };
    Ok(Pbr {
        base_color: base,
        base_color_texture: p.base_color_texture.as_ref().map(|t| texref(root, t)),
        metallic,
        roughness,
        metallic_roughness_texture: p.metallic_roughness_texture.as_ref().map(|t| texref(root, t)),
        normal_texture: m.normal_texture.as_ref().map(|n| {
            (
                TexRef {
                    texture: root.textures[n.index.value()].source.value() as u32,
                    texcoord: n.tex_coord,
                },
                n.scale,
            )
        }),
        emissive,
        emissive_texture: m.emissive_texture.as_ref().map(|t| texref(root, t)),
        alpha,
        double_sided: m.double_sided,
        ior,
        transmission,
    })
}

/// The materials the instances use (by glTF index, in index order) and the images those
/// use (glTF index, width, height, in index order).
#[allow(clippy::type_complexity)]
pub(crate) fn used(
    file: &str,
    root: &Root,
    buffers: &[Vec<u8>],
    assets: &dyn Assets,
    instances: &[Instance],
) -> Result<(Vec<(u32, Pbr)>, Vec<(u32, u32, u32)>), GltfError> {
    let mut indices: Vec<u32> = instances.iter().filter_map(|i| i.material).collect();
    indices.sort_unstable();
    indices.dedup();
    let mut materials = Vec::with_capacity(indices.len());
    let mut images = std::collections::BTreeSet::new();
    for i in indices {
        let m = material(file, root, i as usize)?;
        let refs = [
            m.base_color_texture,
            m.metallic_roughness_texture,
            m.normal_texture.map(|n| n.0),
            m.emissive_texture,
        ];
        images.extend(refs.into_iter().flatten().map(|t| t.texture));
        materials.push((i, m));
    }
    let mut sized = Vec::with_capacity(images.len());
    for image in images {
        let bytes = image_bytes(file, root, buffers, image, assets)?;
        let (w, h) = image_size(file, &at!("images[{image}]"), &bytes)?;
        sized.push((image, w, h));
    }
    Ok((materials, sized))
}
