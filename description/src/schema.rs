//! The scene file's schema: the TOML tables as serde structs, parsed strictly (unknown
//! keys are errors) with the span of every table kept for located errors. Checking the
//! values is `validate`'s job.
//!
//! Conventions: right-handed world, y up; lengths in scene units; angles in degrees;
//! colours linear RGB. The format is documented, with an example per feature, in
//! `docs/scene-format.md`.

use std::collections::BTreeMap;
use std::fmt;

use glam::Vec3;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;
use toml::Spanned;

/// A colour given as one number (grey) or as `[r, g, b]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rgb(pub Vec3);

struct RgbVisitor;

impl<'de> Visitor<'de> for RgbVisitor {
    type Value = Vec3;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a colour: a number or an array [r, g, b]")
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Vec3, E> {
        Ok(Vec3::splat(v as f32))
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> Result<Vec3, E> {
        Ok(Vec3::splat(v as f32))
    }
    fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<Vec3, A::Error> {
        read_vec3(seq, &self)
    }
}

impl<'de> Deserialize<'de> for Rgb {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(RgbVisitor).map(Rgb)
    }
}

/// A colour, or the name of a texture.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum ColorOrTexture {
    /// A constant colour.
    Color(Vec3),
    /// A texture's name.
    Texture(String),
}

impl<'de> Deserialize<'de> for ColorOrTexture {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = ColorOrTexture;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a colour (a number or [r, g, b]) or the name of a texture")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(ColorOrTexture::Color(Vec3::splat(v as f32)))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(ColorOrTexture::Color(Vec3::splat(v as f32)))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Self::Value, E> {
                Ok(ColorOrTexture::Texture(v.to_string()))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<Self::Value, A::Error> {
                read_vec3(seq, &RgbVisitor).map(ColorOrTexture::Color)
            }
        }
        d.deserialize_any(V)
    }
}

/// A point or direction `[x, y, z]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct V3(pub Vec3);

impl<'de> Deserialize<'de> for V3 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = V3;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an array of three numbers [x, y, z]")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<V3, A::Error> {
                Ok(V3(read_vec3(seq, &self)?))
            }
        }
        d.deserialize_seq(V)
    }
}

fn read_vec3<'de, A: SeqAccess<'de>>(mut seq: A, exp: &dyn de::Expected) -> Result<Vec3, A::Error> {
    let mut v = [0f32; 3];
    for (i, slot) in v.iter_mut().enumerate() {
        *slot = seq.next_element::<f64>()?.ok_or_else(|| de::Error::invalid_length(i, exp))? as f32;
    }
    if seq.next_element::<de::IgnoredAny>()?.is_some() {
        return Err(de::Error::invalid_length(4, exp));
    }
    Ok(Vec3::from(v))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct SceneFile {
    pub(crate) render: Spanned<RenderDef>,
    /// Optional when a `[[gltf]]` asset has a camera.
    pub(crate) camera: Option<Spanned<CameraDef>>,
    pub(crate) animation: Option<Spanned<AnimationDef>>,
    #[serde(default)]
    pub(crate) textures: BTreeMap<String, Spanned<TextureDef>>,
    #[serde(default)]
    pub(crate) materials: BTreeMap<String, Spanned<MaterialDef>>,
    #[serde(default)]
    pub(crate) sphere: Vec<Spanned<SphereDef>>,
    #[serde(default)]
    pub(crate) plane: Vec<Spanned<PlaneDef>>,
    #[serde(default)]
    pub(crate) rectangle: Vec<Spanned<RectangleDef>>,
    #[serde(default, rename = "box")]
    pub(crate) boxes: Vec<Spanned<BoxDef>>,
    #[serde(default)]
    pub(crate) triangle: Vec<Spanned<TriangleDef>>,
    #[serde(default)]
    pub(crate) mesh: Vec<Spanned<MeshDef>>,
    #[serde(default)]
    pub(crate) gltf: Vec<Spanned<GltfDef>>,
    #[serde(default)]
    pub(crate) point_light: Vec<Spanned<PointLightDef>>,
    #[serde(default)]
    pub(crate) directional_light: Vec<Spanned<DirectionalLightDef>>,
    #[serde(default)]
    pub(crate) spot_light: Vec<Spanned<SpotLightDef>>,
    #[serde(default)]
    pub(crate) environment: Option<Spanned<EnvironmentDef>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RenderDef {
    pub(crate) width: u32,
    pub(crate) height: u32,
    #[serde(default = "default_spp")]
    pub(crate) spp: u32,
    #[serde(default)]
    pub(crate) seed: u64,
    #[serde(default)]
    pub(crate) sampler: Option<Spanned<String>>,
    #[serde(default = "default_depth")]
    pub(crate) max_depth: u32,
    #[serde(default)]
    pub(crate) diffuse_rays: Option<Spanned<u32>>,
    #[serde(default = "black")]
    pub(crate) background: Rgb,
    #[serde(default = "black")]
    pub(crate) ambient: Rgb,
}

fn default_spp() -> u32 {
    16
}
fn default_depth() -> u32 {
    8
}
pub(crate) fn black() -> Rgb {
    Rgb(Vec3::ZERO)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CameraDef {
    pub(crate) position: V3,
    pub(crate) look_at: V3,
    pub(crate) up: Option<V3>,
    pub(crate) fov: Option<f32>,
    pub(crate) fov_axis: Option<String>,
    pub(crate) aperture: Option<f32>,
    pub(crate) f_number: Option<f32>,
    pub(crate) focal_length: Option<f32>,
    pub(crate) focus_distance: Option<f32>,
    pub(crate) shutter: Option<[f32; 2]>,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<CameraKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct TextureDef {
    #[serde(rename = "type")]
    pub(crate) kind: String,
    pub(crate) even: Option<Rgb>,
    pub(crate) odd: Option<Rgb>,
    pub(crate) size: Option<f32>,
    pub(crate) space: Option<String>,
    pub(crate) file: Option<String>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(crate) struct MaterialDef {
    #[serde(rename = "type")]
    pub(crate) kind: Option<String>,
    // classic
    pub(crate) color: Option<ColorOrTexture>,
    pub(crate) ambient: Option<f32>,
    pub(crate) diffuse: Option<f32>,
    pub(crate) specular: Option<f32>,
    pub(crate) shininess: Option<f32>,
    pub(crate) reflect: Option<Rgb>,
    pub(crate) transmit: Option<Rgb>,
    pub(crate) gloss: Option<f32>,
    pub(crate) translucency: Option<f32>,
    // shared
    pub(crate) ior: Option<f32>,
    // physically based
    pub(crate) albedo: Option<ColorOrTexture>,
    pub(crate) reflectance: Option<Rgb>,
    pub(crate) eta: Option<Rgb>,
    pub(crate) k: Option<Rgb>,
    pub(crate) metal: Option<String>,
    pub(crate) roughness: Option<f32>,
}

#[derive(Debug, Deserialize, Default, Clone, Copy)]
#[serde(deny_unknown_fields)]
pub(crate) struct TransformDef {
    pub(crate) translate: Option<V3>,
    pub(crate) rotate: Option<V3>,
    pub(crate) scale: Option<Rgb>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct SphereDef {
    #[serde(default = "origin")]
    pub(crate) center: V3,
    #[serde(default = "unit")]
    pub(crate) radius: f32,
    pub(crate) material: Option<String>,
    pub(crate) emission: Option<Rgb>,
    pub(crate) transform: Option<TransformDef>,
    pub(crate) motion: Option<TransformDef>,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<TransformKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

fn origin() -> V3 {
    V3(Vec3::ZERO)
}
fn unit() -> f32 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PlaneDef {
    #[serde(default = "origin")]
    pub(crate) point: V3,
    pub(crate) normal: V3,
    pub(crate) material: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RectangleDef {
    #[serde(default = "origin")]
    pub(crate) center: V3,
    pub(crate) u: V3,
    pub(crate) v: V3,
    pub(crate) material: Option<String>,
    pub(crate) emission: Option<Rgb>,
    pub(crate) transform: Option<TransformDef>,
    pub(crate) motion: Option<TransformDef>,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<TransformKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct BoxDef {
    pub(crate) min: V3,
    pub(crate) max: V3,
    pub(crate) material: String,
    pub(crate) transform: Option<TransformDef>,
    pub(crate) motion: Option<TransformDef>,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<TransformKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct TriangleDef {
    pub(crate) vertices: [V3; 3],
    pub(crate) material: Option<String>,
    pub(crate) emission: Option<Rgb>,
    pub(crate) transform: Option<TransformDef>,
    pub(crate) motion: Option<TransformDef>,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<TransformKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct MeshDef {
    pub(crate) file: String,
    pub(crate) material: Option<String>,
    pub(crate) emission: Option<Rgb>,
    pub(crate) transform: Option<TransformDef>,
    pub(crate) motion: Option<TransformDef>,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<TransformKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

/// A glTF asset placed in the scene.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct GltfDef {
    pub(crate) file: String,
    pub(crate) scene: Option<crate::gltf::SceneRef>,
    pub(crate) transform: Option<TransformDef>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PointLightDef {
    pub(crate) position: V3,
    #[serde(default = "white")]
    pub(crate) color: Rgb,
    pub(crate) intensity: f32,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<PointLightKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct DirectionalLightDef {
    pub(crate) direction: V3,
    #[serde(default = "white")]
    pub(crate) color: Rgb,
    pub(crate) irradiance: f32,
    #[serde(default)]
    pub(crate) keys: Vec<Spanned<DirectionalLightKey>>,
    pub(crate) interpolation: Option<Spanned<String>>,
}

fn white() -> Rgb {
    Rgb(Vec3::ONE)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct SpotLightDef {
    pub(crate) position: V3,
    pub(crate) direction: V3,
    #[serde(default = "white")]
    pub(crate) color: Rgb,
    pub(crate) intensity: f32,
    /// Half-angle in degrees of full intensity (glTF `innerConeAngle`, default 0).
    pub(crate) inner_cone: Option<f32>,
    /// Half-angle in degrees where the light ends (glTF `outerConeAngle`, default 45).
    pub(crate) outer_cone: Option<f32>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct EnvironmentDef {
    pub(crate) file: Option<String>,
    pub(crate) color: Option<Rgb>,
    pub(crate) strength: Option<f32>,
    /// Degrees about +y.
    pub(crate) rotation: Option<f32>,
}

/// The `[animation]` table.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct AnimationDef {
    #[serde(default = "default_fps")]
    pub(crate) fps: f32,
    pub(crate) frames: [u32; 2],
}

fn default_fps() -> f32 {
    24.0
}

/// A key of an object's transform.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct TransformKey {
    pub(crate) frame: f64,
    pub(crate) translate: Option<V3>,
    pub(crate) rotate: Option<V3>,
    pub(crate) scale: Option<Rgb>,
}

/// A key of the camera.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CameraKey {
    pub(crate) frame: f64,
    pub(crate) position: Option<V3>,
    pub(crate) look_at: Option<V3>,
    pub(crate) up: Option<V3>,
    pub(crate) fov: Option<f32>,
    pub(crate) focus_distance: Option<f32>,
    pub(crate) aperture: Option<f32>,
}

/// A key of a point light.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PointLightKey {
    pub(crate) frame: f64,
    pub(crate) position: Option<V3>,
    pub(crate) color: Option<Rgb>,
    pub(crate) intensity: Option<f32>,
}

/// A key of a directional light.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct DirectionalLightKey {
    pub(crate) frame: f64,
    pub(crate) direction: Option<V3>,
    pub(crate) color: Option<Rgb>,
    pub(crate) irradiance: Option<f32>,
}

/// A table's keys as the schema holds them: `keys = [...]` (or `[[table.keys]]`) and the
/// table's `interpolation`.
pub(crate) struct KeysDef<'a, K> {
    pub(crate) keys: &'a [Spanned<K>],
    pub(crate) interpolation: &'a Option<Spanned<String>>,
}
