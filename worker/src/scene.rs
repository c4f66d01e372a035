//! The scene file: TOML, parsed strictly (unknown keys are errors) and validated, with
//! every error naming the file, line and column and what was expected.
//!
//! Conventions: right-handed world, y up; lengths in scene units; angles in degrees;
//! colours linear RGB. The format is documented, with an example per feature, in
//! `docs/scene-format.md`.

use std::collections::BTreeMap;
use std::fmt;
use std::ops::Range;

use glam::Vec3;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;
use toml::Spanned;

use crate::render::bvh::Bvh;
use crate::render::camera::{Camera, FovAxis};
use crate::render::geometry::{Plane, Sphere};
use crate::render::light::Light;
use crate::render::material::{Classic, Material};
use crate::render::shape::{Mesh, Primitive, Rect, Shape};
use crate::render::texture::{CheckerSpace, Tex, Texture};
use crate::render::transform::{Motion, Trs};
use crate::render::Scene;
pub use tessera_description::bundle::{check_asset_path, Assets, NoAssets};
pub use tessera_description::error::SceneError;
pub use tessera_description::limits;

/// A colour given as one number (grey) or as `[r, g, b]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rgb(pub Vec3);

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
pub enum ColorOrTexture {
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
pub struct V3(pub Vec3);

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
struct SceneFile {
    render: Spanned<RenderDef>,
    camera: Spanned<CameraDef>,
    #[serde(default)]
    textures: BTreeMap<String, Spanned<TextureDef>>,
    #[serde(default)]
    materials: BTreeMap<String, Spanned<MaterialDef>>,
    #[serde(default)]
    sphere: Vec<Spanned<SphereDef>>,
    #[serde(default)]
    plane: Vec<Spanned<PlaneDef>>,
    #[serde(default)]
    rectangle: Vec<Spanned<RectangleDef>>,
    #[serde(default, rename = "box")]
    boxes: Vec<Spanned<BoxDef>>,
    #[serde(default)]
    triangle: Vec<Spanned<TriangleDef>>,
    #[serde(default)]
    mesh: Vec<Spanned<MeshDef>>,
    #[serde(default)]
    point_light: Vec<Spanned<PointLightDef>>,
    #[serde(default)]
    directional_light: Vec<Spanned<DirectionalLightDef>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderDef {
    width: u32,
    height: u32,
    #[serde(default = "default_spp")]
    spp: u32,
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    sampler: Option<Spanned<String>>,
    #[serde(default = "default_depth")]
    max_depth: u32,
    #[serde(default = "black")]
    background: Rgb,
    #[serde(default = "black")]
    ambient: Rgb,
}

fn default_spp() -> u32 {
    16
}
fn default_depth() -> u32 {
    8
}
fn black() -> Rgb {
    Rgb(Vec3::ZERO)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDef {
    position: V3,
    look_at: V3,
    up: Option<V3>,
    fov: Option<f32>,
    fov_axis: Option<String>,
    aperture: Option<f32>,
    f_number: Option<f32>,
    focal_length: Option<f32>,
    focus_distance: Option<f32>,
    shutter: Option<[f32; 2]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TextureDef {
    #[serde(rename = "type")]
    kind: String,
    even: Option<Rgb>,
    odd: Option<Rgb>,
    size: Option<f32>,
    space: Option<String>,
    file: Option<String>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct MaterialDef {
    #[serde(rename = "type")]
    kind: Option<String>,
    // classic
    color: Option<ColorOrTexture>,
    ambient: Option<f32>,
    diffuse: Option<f32>,
    specular: Option<f32>,
    shininess: Option<f32>,
    reflect: Option<Rgb>,
    transmit: Option<Rgb>,
    gloss: Option<f32>,
    translucency: Option<f32>,
    // shared
    ior: Option<f32>,
    // physically based
    albedo: Option<ColorOrTexture>,
    reflectance: Option<Rgb>,
    eta: Option<Rgb>,
    k: Option<Rgb>,
    metal: Option<String>,
    roughness: Option<f32>,
}

#[derive(Debug, Deserialize, Default, Clone, Copy)]
#[serde(deny_unknown_fields)]
struct TransformDef {
    translate: Option<V3>,
    rotate: Option<V3>,
    scale: Option<Rgb>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SphereDef {
    #[serde(default = "origin")]
    center: V3,
    #[serde(default = "unit")]
    radius: f32,
    material: Option<String>,
    emission: Option<Rgb>,
    transform: Option<TransformDef>,
    motion: Option<TransformDef>,
}

fn origin() -> V3 {
    V3(Vec3::ZERO)
}
fn unit() -> f32 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlaneDef {
    #[serde(default = "origin")]
    point: V3,
    normal: V3,
    material: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RectangleDef {
    #[serde(default = "origin")]
    center: V3,
    u: V3,
    v: V3,
    material: Option<String>,
    emission: Option<Rgb>,
    transform: Option<TransformDef>,
    motion: Option<TransformDef>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxDef {
    min: V3,
    max: V3,
    material: String,
    transform: Option<TransformDef>,
    motion: Option<TransformDef>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TriangleDef {
    vertices: [V3; 3],
    material: String,
    transform: Option<TransformDef>,
    motion: Option<TransformDef>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshDef {
    file: String,
    material: String,
    transform: Option<TransformDef>,
    motion: Option<TransformDef>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PointLightDef {
    position: V3,
    #[serde(default = "white")]
    color: Rgb,
    intensity: f32,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DirectionalLightDef {
    direction: V3,
    #[serde(default = "white")]
    color: Rgb,
    irradiance: f32,
}

fn white() -> Rgb {
    Rgb(Vec3::ONE)
}

/// Where in the text an error points: 1-based line and column of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// Complex indices of refraction of common metals (R, G, B), as in the benchmark scenes.
fn metal_preset(name: &str) -> Option<(Vec3, Vec3)> {
    Some(match name {
        "gold" => (Vec3::new(0.143, 0.374, 1.442), Vec3::new(3.983, 2.385, 1.603)),
        "copper" => (Vec3::new(0.200, 0.924, 1.102), Vec3::new(3.912, 2.452, 2.142)),
        "aluminium" | "aluminum" => (Vec3::new(1.657, 0.880, 0.521), Vec3::new(9.224, 6.270, 4.837)),
        "silver" => (Vec3::new(0.155, 0.117, 0.138), Vec3::new(4.828, 3.122, 2.147)),
        _ => return None,
    })
}

struct Ctx<'a> {
    file: &'a str,
    text: &'a str,
}

type R<T> = Result<T, SceneError>;

impl Ctx<'_> {
    fn err(&self, span: &Range<usize>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_column(self.text, span.start);
        SceneError { file: self.file.to_string(), line, column, message: message.into() }
    }

    fn finite(&self, span: &Range<usize>, what: &str, v: Vec3) -> R<Vec3> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(span, format!("{what} must be finite numbers, got {v}")))
        }
    }

    fn colour(&self, span: &Range<usize>, what: &str, c: Vec3) -> R<Vec3> {
        let v = self.finite(span, what, c)?;
        if v.min_element() < 0.0 {
            return Err(self.err(span, format!("{what} must not be negative, got {v}")));
        }
        Ok(v)
    }

    fn number(&self, span: &Range<usize>, what: &str, v: f32, ok: Range<f32>) -> R<f32> {
        if v.is_finite() && v >= ok.start && v <= ok.end {
            Ok(v)
        } else {
            Err(self.err(span, format!("{what} must be in [{}, {}], got {v}", ok.start, ok.end)))
        }
    }
}

/// Builds the render-ready scene piece by piece.
struct Builder<'a> {
    ctx: Ctx<'a>,
    assets: &'a dyn Assets,
    textures: Vec<Texture>,
    texture_index: BTreeMap<String, u32>,
    materials: Vec<Material>,
    material_index: BTreeMap<String, u32>,
    prims: Vec<Primitive>,
    planes: Vec<(Plane, u32)>,
    meshes: Vec<Mesh>,
    motions: Vec<Motion>,
    lights: Vec<Light>,
    emitter_material: Option<u32>,
    triangles: usize,
}

impl Builder<'_> {
    fn tex(&self, span: &Range<usize>, what: &str, c: &ColorOrTexture) -> R<Tex> {
        match c {
            ColorOrTexture::Color(v) => Ok(Tex::Const(self.ctx.colour(span, what, *v)?)),
            ColorOrTexture::Texture(name) => {
                self.texture_index.get(name).map(|i| Tex::Map(*i)).ok_or_else(|| {
                    let known: Vec<&str> = self.texture_index.keys().map(String::as_str).collect();
                    self.ctx.err(
                        span,
                        format!("{what}: unknown texture \"{name}\"; defined: [{}]", known.join(", ")),
                    )
                })
            }
        }
    }

    fn texture(&mut self, name: &str, span: &Range<usize>, d: &TextureDef) -> R<()> {
        let ctx = &self.ctx;
        let what = |f: &str| format!("textures.{name}.{f}");
        let texture = match d.kind.as_str() {
            "checker" => {
                if d.file.is_some() {
                    return Err(ctx.err(span, format!("{}: a checker has no file", what("file"))));
                }
                let space = match d.space.as_deref().unwrap_or("world_xz") {
                    "world_xz" => CheckerSpace::WorldXz,
                    "uv" => CheckerSpace::Uv,
                    other => {
                        return Err(ctx.err(
                            span,
                            format!("{}: expected \"world_xz\" or \"uv\", got {other:?}", what("space")),
                        ))
                    }
                };
                Texture::Checker {
                    even: ctx.colour(span, &what("even"), d.even.unwrap_or(Rgb(Vec3::splat(0.8))).0)?,
                    odd: ctx.colour(span, &what("odd"), d.odd.unwrap_or(Rgb(Vec3::splat(0.2))).0)?,
                    size: ctx.number(span, &what("size"), d.size.unwrap_or(1.0), 1e-6..1e9)?,
                    space,
                }
            }
            "image" => {
                if d.even.is_some() || d.odd.is_some() || d.size.is_some() || d.space.is_some() {
                    return Err(ctx.err(span, format!("textures.{name}: an image texture takes only `file`")));
                }
                let file = d
                    .file
                    .as_deref()
                    .ok_or_else(|| ctx.err(span, format!("{} is required", what("file"))))?;
                let path = check_asset_path(file).map_err(|e| ctx.err(span, e))?;
                let bytes = self.assets.get(&path).ok_or_else(|| {
                    ctx.err(
                        span,
                        format!("{}: cannot read {file:?} (relative to the scene's folder)", what("file")),
                    )
                })?;
                let img = image::load_from_memory(bytes).map_err(|e| {
                    ctx.err(span, format!("{}: {file:?} is not a readable image: {e}", what("file")))
                })?;
                let (width, height, values) = crate::render::texture::linear_rgb(&img);
                let texels = values.chunks_exact(3).map(Vec3::from_slice).collect();
                Texture::Image { width, height, texels }
            }
            other => {
                return Err(ctx.err(
                    span,
                    format!("textures.{name}.type: expected \"checker\" or \"image\", got {other:?}"),
                ))
            }
        };
        self.texture_index.insert(name.to_string(), self.textures.len() as u32);
        self.textures.push(texture);
        Ok(())
    }

    fn material(&mut self, name: &str, span: &Range<usize>, d: &MaterialDef) -> R<()> {
        let kind = d.kind.as_deref().unwrap_or("classic");
        let allowed: &[&str] = match kind {
            "classic" => &["color", "ambient", "diffuse", "specular", "shininess", "reflect", "transmit", "ior", "gloss", "translucency"],
            "lambert" => &["albedo"],
            "mirror" => &["reflectance"],
            "dielectric" => &["ior"],
            "conductor" => &["eta", "k", "metal", "roughness"],
            "rough_dielectric" => &["ior", "roughness"],
            "plastic" => &["albedo", "ior"],
            other => {
                return Err(self.ctx.err(
                    span,
                    format!("materials.{name}.type: unknown material {other:?}; expected one of classic, lambert, mirror, dielectric, conductor, rough_dielectric, plastic"),
                ))
            }
        };
        let set: [(&str, bool); 16] = [
            ("color", d.color.is_some()),
            ("ambient", d.ambient.is_some()),
            ("diffuse", d.diffuse.is_some()),
            ("specular", d.specular.is_some()),
            ("shininess", d.shininess.is_some()),
            ("reflect", d.reflect.is_some()),
            ("transmit", d.transmit.is_some()),
            ("gloss", d.gloss.is_some()),
            ("translucency", d.translucency.is_some()),
            ("ior", d.ior.is_some()),
            ("albedo", d.albedo.is_some()),
            ("reflectance", d.reflectance.is_some()),
            ("eta", d.eta.is_some()),
            ("k", d.k.is_some()),
            ("metal", d.metal.is_some()),
            ("roughness", d.roughness.is_some()),
        ];
        if let Some((field, _)) = set.iter().find(|(f, on)| *on && !allowed.contains(f)) {
            return Err(self.ctx.err(
                span,
                format!(
                    "materials.{name}: `{field}` does not apply to a {kind} material (it takes: {})",
                    allowed.join(", ")
                ),
            ));
        }
        let ctx = &self.ctx;
        let what = |f: &str| format!("materials.{name}.{f}");
        let ior = |default: f32| ctx.number(span, &what("ior"), d.ior.unwrap_or(default), 1e-3..100.0);
        let roughness = || ctx.number(span, &what("roughness"), d.roughness.unwrap_or(0.0), 0.0..4.0);
        let material = match kind {
            "classic" => Material::Classic(Classic {
                color: self.tex(
                    span,
                    &what("color"),
                    d.color.as_ref().unwrap_or(&ColorOrTexture::Color(Vec3::splat(0.8))),
                )?,
                ambient: ctx.number(span, &what("ambient"), d.ambient.unwrap_or(1.0), 0.0..1e3)?,
                diffuse: ctx.number(span, &what("diffuse"), d.diffuse.unwrap_or(1.0), 0.0..1e3)?,
                specular: ctx.number(span, &what("specular"), d.specular.unwrap_or(0.0), 0.0..1e3)?,
                shininess: ctx.number(span, &what("shininess"), d.shininess.unwrap_or(32.0), 0.0..1e6)?,
                reflect: ctx.colour(span, &what("reflect"), d.reflect.unwrap_or(black()).0)?,
                transmit: ctx.colour(span, &what("transmit"), d.transmit.unwrap_or(black()).0)?,
                ior: ior(1.5)?,
                gloss: ctx.number(span, &what("gloss"), d.gloss.unwrap_or(0.0), 0.0..4.0)?,
                translucency: ctx.number(
                    span,
                    &what("translucency"),
                    d.translucency.unwrap_or(0.0),
                    0.0..4.0,
                )?,
            }),
            "lambert" => Material::Lambert {
                albedo: self.tex(
                    span,
                    &what("albedo"),
                    d.albedo.as_ref().unwrap_or(&ColorOrTexture::Color(Vec3::splat(0.8))),
                )?,
            },
            "mirror" => Material::Mirror {
                reflectance: ctx.colour(
                    span,
                    &what("reflectance"),
                    d.reflectance.unwrap_or(Rgb(Vec3::ONE)).0,
                )?,
            },
            "dielectric" => Material::Dielectric { ior: ior(1.5)? },
            "rough_dielectric" => Material::RoughDielectric { ior: ior(1.5)?, roughness: roughness()? },
            "plastic" => Material::Plastic {
                diffuse: self.tex(
                    span,
                    &what("albedo"),
                    d.albedo.as_ref().unwrap_or(&ColorOrTexture::Color(Vec3::splat(0.5))),
                )?,
                ior: ior(1.5)?,
            },
            _ => {
                let (eta, k) = match (&d.metal, d.eta, d.k) {
                    (Some(m), None, None) => metal_preset(m).ok_or_else(|| {
                        ctx.err(
                            span,
                            format!(
                                "{}: unknown metal {m:?}; expected gold, copper, aluminium or silver",
                                what("metal")
                            ),
                        )
                    })?,
                    (None, Some(eta), Some(k)) => {
                        (ctx.colour(span, &what("eta"), eta.0)?, ctx.colour(span, &what("k"), k.0)?)
                    }
                    _ => {
                        return Err(ctx.err(
                            span,
                            format!(
                                "materials.{name}: a conductor takes either `metal` or both `eta` and `k`"
                            ),
                        ))
                    }
                };
                Material::Conductor { eta, k, roughness: roughness()? }
            }
        };
        self.material_index.insert(name.to_string(), self.materials.len() as u32);
        self.materials.push(material);
        Ok(())
    }

    fn material_of(&self, span: &Range<usize>, name: &str) -> R<u32> {
        self.material_index.get(name).copied().ok_or_else(|| {
            let known: Vec<&str> = self.material_index.keys().map(String::as_str).collect();
            self.ctx.err(span, format!("unknown material \"{name}\"; defined: [{}]", known.join(", ")))
        })
    }

    /// The material of an object, or the black surface of an emitter.
    fn surface(
        &mut self,
        span: &Range<usize>,
        what: &str,
        material: Option<&String>,
        emission: Option<Rgb>,
    ) -> R<(u32, Option<Vec3>)> {
        let emission =
            emission.map(|e| self.ctx.colour(span, &format!("{what}.emission"), e.0)).transpose()?;
        match (material, emission) {
            (Some(_), Some(_)) => Err(self.ctx.err(
                span,
                format!("{what}: an emitter reflects nothing; give `material` or `emission`, not both"),
            )),
            (Some(m), None) => Ok((self.material_of(span, m)?, None)),
            (None, Some(e)) => {
                let black = *self.emitter_material.get_or_insert_with(|| {
                    self.materials.push(Material::Lambert { albedo: Tex::Const(Vec3::ZERO) });
                    self.materials.len() as u32 - 1
                });
                Ok((black, Some(e)))
            }
            (None, None) => {
                Err(self.ctx.err(span, format!("{what} needs a `material` (or an `emission`, for a light)")))
            }
        }
    }

    fn trs(&self, span: &Range<usize>, what: &str, t: &TransformDef, base: &Trs) -> R<Trs> {
        let translate =
            t.translate.map(|v| self.ctx.finite(span, &format!("{what}.translate"), v.0)).transpose()?;
        let rotate =
            t.rotate.map(|v| self.ctx.finite(span, &format!("{what}.rotate (degrees)"), v.0)).transpose()?;
        let scale = t.scale.map(|v| self.ctx.finite(span, &format!("{what}.scale"), v.0)).transpose()?;
        if let Some(s) = scale {
            if s.abs().min_element() < 1e-12 {
                return Err(self.ctx.err(span, format!("{what}.scale must not be zero, got {s}")));
            }
        }
        let mut trs = *base;
        if let Some(v) = translate {
            trs.translate = v;
        }
        if let Some(v) = rotate {
            trs.rotate = Trs::new(Vec3::ZERO, v, Vec3::ONE).rotate;
        }
        if let Some(v) = scale {
            trs.scale = v;
        }
        Ok(trs)
    }

    /// The static transform and the motion (if any) of an object.
    fn placement(
        &mut self,
        span: &Range<usize>,
        what: &str,
        t: &Option<TransformDef>,
        m: &Option<TransformDef>,
    ) -> R<(Trs, Option<u32>)> {
        let start = self.trs(span, &format!("{what}.transform"), &t.unwrap_or_default(), &Trs::default())?;
        let Some(m) = m else { return Ok((start, None)) };
        let end = self.trs(span, &format!("{what}.motion"), m, &start)?;
        if end == start {
            return Ok((start, None));
        }
        self.motions.push(Motion { start, end });
        Ok((start, Some(self.motions.len() as u32 - 1)))
    }

    fn push(&mut self, shape: Shape, material: u32, light: Option<u32>, motion: Option<u32>) {
        self.prims.push(Primitive { shape, material, light, motion });
    }

    fn sphere(&mut self, span: &Range<usize>, d: &SphereDef) -> R<()> {
        let center = self.ctx.finite(span, "sphere.center", d.center.0)?;
        if !(d.radius.is_finite() && d.radius > 0.0) {
            return Err(self
                .ctx
                .err(span, format!("sphere.radius must be a positive number, got {}", d.radius)));
        }
        let (material, emission) = self.surface(span, "sphere", d.material.as_ref(), d.emission)?;
        let (trs, motion) = self.placement(span, "sphere", &d.transform, &d.motion)?;
        let uniform = |t: &Trs| {
            (t.scale.abs().max_element() - t.scale.abs().min_element()) <= 1e-6 * t.scale.abs().max_element()
        };
        if !uniform(&trs) || motion.is_some_and(|m| !uniform(&self.motions[m as usize].end)) {
            return Err(self
                .ctx
                .err(span, "sphere: scale must be uniform (one number); use a mesh for ellipsoids"));
        }
        let shape = match motion {
            Some(_) => Sphere::new(center, d.radius),
            None => Sphere::new(trs.matrix().transform_point3(center), d.radius * trs.scale.abs().x),
        };
        let light = match (emission, motion) {
            (Some(_), Some(_)) => {
                return Err(self
                    .ctx
                    .err(span, "sphere: lights cannot move (give `emission` or `motion`, not both)"))
            }
            (Some(radiance), None) => {
                self.lights.push(Light::Sphere { sphere: shape.clone(), radiance });
                Some(self.lights.len() as u32 - 1)
            }
            (None, _) => None,
        };
        self.push(Shape::Sphere(shape), material, light, motion);
        Ok(())
    }

    /// A parallelogram `(c, u, v)` with its material and emission.
    fn rect(
        &mut self,
        span: &Range<usize>,
        what: &str,
        (c, u, v): (Vec3, Vec3, Vec3),
        (material, emission): (u32, Option<Vec3>),
        trs: &Trs,
        motion: Option<u32>,
    ) -> R<()> {
        let (c, u, v) = match motion {
            Some(_) => (c, u, v),
            None => {
                let m = trs.matrix();
                (m.transform_point3(c), m.transform_vector3(u), m.transform_vector3(v))
            }
        };
        if !(u.cross(v).length_squared() > 0.0) {
            return Err(self
                .ctx
                .err(span, format!("{what}: the edges u and v must not be parallel or zero")));
        }
        let rect = Rect::new(c, u, v);
        let light = match (emission, motion) {
            (Some(_), Some(_)) => return Err(self.ctx.err(span, format!("{what}: lights cannot move"))),
            (Some(radiance), None) => {
                self.lights.push(Light::Rect { rect: rect.clone(), radiance });
                Some(self.lights.len() as u32 - 1)
            }
            (None, _) => None,
        };
        self.push(Shape::Rect(rect), material, light, motion);
        Ok(())
    }

    fn mesh(
        &mut self,
        span: &Range<usize>,
        mut mesh: Mesh,
        material: u32,
        trs: &Trs,
        motion: Option<u32>,
    ) -> R<()> {
        self.triangles += mesh.tris.len();
        if self.triangles > limits::MAX_TRIANGLES {
            return Err(self
                .ctx
                .err(span, format!("the scene has more than {} triangles", limits::MAX_TRIANGLES)));
        }
        if motion.is_none() && !trs.is_identity() {
            let m = trs.matrix();
            let normal_matrix = m.matrix3.inverse().transpose();
            for p in &mut mesh.p {
                *p = m.transform_point3(*p);
            }
            for n in &mut mesh.n {
                *n = Vec3::from(normal_matrix * glam::Vec3A::from(*n)).normalize_or_zero();
            }
        }
        let index = self.meshes.len() as u32;
        for tri in 0..mesh.tris.len() as u32 {
            self.push(Shape::Triangle { mesh: index, tri }, material, None, motion);
        }
        self.meshes.push(mesh);
        Ok(())
    }
}

/// Parses and validates a bundle's scene, with its assets.
pub fn parse_bundle(bundle: &tessera_description::Bundle) -> Result<Scene, SceneError> {
    parse_scene_with_assets(&bundle.name, &bundle.text, bundle)
}

/// Parses and validates a scene without assets. `file` names the scene in messages.
pub fn parse_scene(file: &str, text: &str) -> Result<Scene, SceneError> {
    parse_scene_with_assets(file, text, &NoAssets)
}

/// Parses and validates a scene whose meshes and images come from `assets`.
pub fn parse_scene_with_assets(file: &str, text: &str, assets: &dyn Assets) -> Result<Scene, SceneError> {
    let ctx = Ctx { file, text };
    let raw: SceneFile = toml::from_str(text).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        ctx.err(&span, e.message().trim().to_string())
    })?;

    let rspan = raw.render.span();
    let r = raw.render.into_inner();
    if r.width == 0 || r.height == 0 || r.width > limits::MAX_SIDE || r.height > limits::MAX_SIDE {
        return Err(ctx.err(
            &rspan,
            format!("image size must be 1..={} on each side, got {}x{}", limits::MAX_SIDE, r.width, r.height),
        ));
    }
    if u64::from(r.width) * u64::from(r.height) > limits::MAX_PIXELS {
        return Err(ctx.err(&rspan, format!("image has more than {} pixels", limits::MAX_PIXELS)));
    }
    if r.spp == 0 || r.spp > limits::MAX_SPP {
        return Err(ctx.err(&rspan, format!("spp must be 1..={}, got {}", limits::MAX_SPP, r.spp)));
    }
    if r.max_depth == 0 || r.max_depth > limits::MAX_DEPTH {
        return Err(
            ctx.err(&rspan, format!("max_depth must be 1..={}, got {}", limits::MAX_DEPTH, r.max_depth))
        );
    }
    let sampler = match &r.sampler {
        None => crate::render::SamplerKind::default(),
        Some(name) => crate::render::SamplerKind::from_name(name.get_ref()).ok_or_else(|| {
            ctx.err(
                &name.span(),
                format!(
                    "unknown sampler {:?}: use \"stratified\", \"independent\" or \"sobol\"",
                    name.get_ref()
                ),
            )
        })?,
    };
    let background = ctx.colour(&rspan, "render.background", r.background.0)?;
    let ambient = ctx.colour(&rspan, "render.ambient", r.ambient.0)?;
    let camera = camera(&ctx, raw.camera, r.width, r.height)?;

    let mut b = Builder {
        ctx,
        assets,
        textures: Vec::new(),
        texture_index: BTreeMap::new(),
        materials: Vec::new(),
        material_index: BTreeMap::new(),
        prims: Vec::new(),
        planes: Vec::new(),
        meshes: Vec::new(),
        motions: Vec::new(),
        lights: Vec::new(),
        emitter_material: None,
        triangles: 0,
    };
    for (name, t) in &raw.textures {
        b.texture(name, &t.span(), t.get_ref())?;
    }
    for (name, m) in &raw.materials {
        b.material(name, &m.span(), m.get_ref())?;
    }
    for s in &raw.sphere {
        b.sphere(&s.span(), s.get_ref())?;
    }
    for p in &raw.plane {
        let span = p.span();
        let d = p.get_ref();
        let point = b.ctx.finite(&span, "plane.point", d.point.0)?;
        let normal = b.ctx.finite(&span, "plane.normal", d.normal.0)?;
        if normal.length_squared() == 0.0 {
            return Err(b.ctx.err(&span, "plane.normal must not be the zero vector"));
        }
        let material = b.material_of(&span, &d.material)?;
        b.planes.push((Plane::new(point, normal), material));
    }
    for r in &raw.rectangle {
        let span = r.span();
        let d = r.get_ref();
        let c = b.ctx.finite(&span, "rectangle.center", d.center.0)?;
        let u = b.ctx.finite(&span, "rectangle.u", d.u.0)?;
        let v = b.ctx.finite(&span, "rectangle.v", d.v.0)?;
        let (material, emission) = b.surface(&span, "rectangle", d.material.as_ref(), d.emission)?;
        let (trs, motion) = b.placement(&span, "rectangle", &d.transform, &d.motion)?;
        b.rect(&span, "rectangle", (c, u, v), (material, emission), &trs, motion)?;
    }
    for bx in &raw.boxes {
        let span = bx.span();
        let d = bx.get_ref();
        let (lo, hi) = (b.ctx.finite(&span, "box.min", d.min.0)?, b.ctx.finite(&span, "box.max", d.max.0)?);
        if !lo.cmplt(hi).all() {
            return Err(b
                .ctx
                .err(&span, format!("box.min must be below box.max on every axis, got {lo} and {hi}")));
        }
        let material = b.material_of(&span, &d.material)?;
        let (trs, motion) = b.placement(&span, "box", &d.transform, &d.motion)?;
        let (c, h) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
        let (x, y, z) = (Vec3::X * h.x, Vec3::Y * h.y, Vec3::Z * h.z);
        // Six faces, each with u × v pointing out of the box.
        for (center, u, v) in
            [(c + x, y, z), (c - x, z, y), (c + y, z, x), (c - y, x, z), (c + z, x, y), (c - z, y, x)]
        {
            b.rect(&span, "box", (center, u, v), (material, None), &trs, motion)?;
        }
    }
    for t in &raw.triangle {
        let span = t.span();
        let d = t.get_ref();
        let mut mesh = Mesh::default();
        for (i, v) in d.vertices.iter().enumerate() {
            mesh.p.push(b.ctx.finite(&span, &format!("triangle.vertices[{i}]"), v.0)?);
        }
        mesh.tris.push([[0, u32::MAX, u32::MAX], [1, u32::MAX, u32::MAX], [2, u32::MAX, u32::MAX]]);
        let material = b.material_of(&span, &d.material)?;
        let (trs, motion) = b.placement(&span, "triangle", &d.transform, &d.motion)?;
        b.mesh(&span, mesh, material, &trs, motion)?;
    }
    for m in &raw.mesh {
        let span = m.span();
        let d = m.get_ref();
        let path = check_asset_path(&d.file).map_err(|e| b.ctx.err(&span, format!("mesh.file: {e}")))?;
        let bytes = assets.get(&path).ok_or_else(|| {
            b.ctx.err(&span, format!("mesh.file: cannot read {:?} (relative to the scene's folder)", d.file))
        })?;
        let text = std::str::from_utf8(bytes)
            .map_err(|_| b.ctx.err(&span, format!("mesh.file: {:?} is not text", d.file)))?;
        let mesh =
            crate::obj::parse_obj(text).map_err(|e| b.ctx.err(&span, format!("mesh {:?}: {e}", d.file)))?;
        let material = b.material_of(&span, &d.material)?;
        let (trs, motion) = b.placement(&span, "mesh", &d.transform, &d.motion)?;
        b.mesh(&span, mesh, material, &trs, motion)?;
    }
    for l in &raw.point_light {
        let span = l.span();
        let d = l.get_ref();
        let position = b.ctx.finite(&span, "point_light.position", d.position.0)?;
        let color = b.ctx.colour(&span, "point_light.color", d.color.0)?;
        let intensity = b.ctx.number(&span, "point_light.intensity", d.intensity, 0.0..f32::MAX)?;
        b.lights.push(Light::Point { position, intensity: color * intensity });
    }
    for l in &raw.directional_light {
        let span = l.span();
        let d = l.get_ref();
        let direction = b.ctx.finite(&span, "directional_light.direction", d.direction.0)?;
        let direction = direction
            .try_normalize()
            .ok_or_else(|| b.ctx.err(&span, "directional_light.direction must not be the zero vector"))?;
        let color = b.ctx.colour(&span, "directional_light.color", d.color.0)?;
        let irradiance = b.ctx.number(&span, "directional_light.irradiance", d.irradiance, 0.0..f32::MAX)?;
        b.lights.push(Light::Directional { direction, irradiance: color * irradiance });
    }

    let bounds: Vec<_> = b.prims.iter().map(|p| p.bounds(&b.meshes, &b.motions)).collect();
    let bvh = Bvh::build(&bounds);
    Ok(Scene {
        width: r.width,
        height: r.height,
        spp: r.spp,
        seed: r.seed,
        sampler,
        max_depth: r.max_depth,
        background,
        ambient,
        camera,
        materials: b.materials,
        textures: b.textures,
        prims: b.prims,
        bvh,
        planes: b.planes,
        meshes: b.meshes,
        motions: b.motions,
        lights: b.lights,
    })
}

fn camera(ctx: &Ctx, c: Spanned<CameraDef>, width: u32, height: u32) -> R<Camera> {
    let span = c.span();
    let c = c.into_inner();
    let position = ctx.finite(&span, "camera.position", c.position.0)?;
    let look_at = ctx.finite(&span, "camera.look_at", c.look_at.0)?;
    let up = ctx.finite(&span, "camera.up", c.up.map_or(Vec3::Y, |u| u.0))?;
    let fov = ctx.number(&span, "camera.fov (degrees)", c.fov.unwrap_or(40.0), 1e-4..179.9)?;
    let axis = match c.fov_axis.as_deref().unwrap_or("vertical") {
        "vertical" => FovAxis::Vertical,
        "horizontal" => FovAxis::Horizontal,
        other => {
            return Err(ctx.err(
                &span,
                format!("camera.fov_axis: expected \"vertical\" or \"horizontal\", got {other:?}"),
            ))
        }
    };
    let forward = look_at - position;
    if forward.length_squared() == 0.0 || forward.cross(up).length_squared() == 0.0 {
        return Err(
            ctx.err(&span, "camera.look_at must differ from camera.position and not lie along camera.up")
        );
    }
    let mut camera = Camera::new(position, look_at, up, fov.to_radians(), axis, width, height);
    camera.focus_distance = match c.focus_distance {
        Some(d) => ctx.number(&span, "camera.focus_distance", d, 1e-6..f32::MAX)?,
        None => forward.length(),
    };
    camera.lens_radius = match (c.aperture, c.f_number, c.focal_length) {
        (Some(a), None, None) => ctx.number(&span, "camera.aperture (lens radius)", a, 0.0..f32::MAX)?,
        (None, Some(n), Some(f)) => {
            let n = ctx.number(&span, "camera.f_number", n, 1e-3..1e6)?;
            let f = ctx.number(&span, "camera.focal_length", f, 1e-9..f32::MAX)?;
            f / (2.0 * n)
        }
        (None, None, None) => 0.0,
        _ => {
            return Err(ctx.err(
                &span,
                "camera: give `aperture` (lens radius), or `f_number` with `focal_length`, not a mix",
            ))
        }
    };
    let [open, close] = c.shutter.unwrap_or([0.0, 1.0]);
    if !(open.is_finite()
        && close.is_finite()
        && (0.0..=1.0).contains(&open)
        && (open..=1.0).contains(&close))
    {
        return Err(ctx.err(
            &span,
            format!(
                "camera.shutter must be [open, close] with 0 <= open <= close <= 1, got [{open}, {close}]"
            ),
        ));
    }
    camera.shutter = (open, close);
    Ok(camera)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[render]
width = 8
height = 6

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]

[materials.red]
color = [1, 0, 0]

[[sphere]]
center = [0, 0, 0]
radius = 1
material = "red"
"#;

    fn err(text: &str) -> SceneError {
        parse_scene("t.toml", text).expect_err("scene should be refused")
    }

    #[test]
    fn minimal_scene_parses_with_defaults() {
        let s = parse_scene("t.toml", MINIMAL).unwrap();
        assert_eq!((s.width, s.height, s.spp, s.max_depth), (8, 6, 16, 8));
        assert_eq!(s.prims.len(), 1);
        assert!(!s.camera.has_lens() && !s.has_motion_blur());
    }

    #[test]
    fn unknown_key_is_an_error_with_location() {
        let e = err(&MINIMAL.replace("radius = 1", "radius = 1\nradius_typo = 2"));
        assert_eq!((e.file.as_str(), e.line), ("t.toml", 16));
        assert!(e.message.contains("radius_typo"), "{e}");
    }

    #[test]
    fn malformed_number_names_line_and_column() {
        let e = err(&MINIMAL.replace("width = 8", "width = 8x"));
        assert_eq!(e.line, 3, "{e}");
        assert!(e.column > 1, "{e}");
    }

    #[test]
    fn negative_radius_is_refused() {
        let e = err(&MINIMAL.replace("radius = 1", "radius = -1"));
        assert!(e.message.contains("positive"), "{e}");
        // The sphere's table header.
        assert_eq!(e.line, 13);
    }

    #[test]
    fn nan_is_refused() {
        let e = err(&MINIMAL.replace("center = [0, 0, 0]", "center = [nan, 0, 0]"));
        assert!(e.message.contains("finite"), "{e}");
    }

    #[test]
    fn unknown_material_lists_known_ones() {
        let e = err(&MINIMAL.replace("material = \"red\"", "material = \"blue\""));
        assert!(e.message.contains("unknown material \"blue\"") && e.message.contains("red"), "{e}");
        let e = err(&MINIMAL.replace("color = [1, 0, 0]", "type = \"velvet\""));
        assert!(e.message.contains("unknown material \"velvet\""), "{e}");
        let e = err(&MINIMAL.replace("color = [1, 0, 0]", "type = \"lambert\"\nior = 1.3"));
        assert!(e.message.contains("`ior` does not apply to a lambert"), "{e}");
    }

    #[test]
    fn bad_image_size_and_camera_are_refused() {
        assert!(err(&MINIMAL.replace("width = 8", "width = 0")).message.contains("image size"));
        assert!(err(&MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 5]"))
            .message
            .contains("look_at"));
        assert!(err(&MINIMAL.replace("[camera]", "[cam]")).message.contains("cam"));
        let e =
            err(&MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0]\naperture = 0.1\nf_number = 2"));
        assert!(e.message.contains("not a mix"), "{e}");
    }

    #[test]
    fn vectors_need_three_numbers() {
        let e = err(&MINIMAL.replace("center = [0, 0, 0]", "center = [0, 0]"));
        assert!(e.message.contains("three numbers"), "{e}");
    }

    #[test]
    fn asset_paths_stay_in_the_scene_folder() {
        assert_eq!(check_asset_path("meshes/../bunny.obj").unwrap(), "bunny.obj");
        assert!(check_asset_path("../secret.obj").unwrap_err().contains("escapes"));
        assert!(check_asset_path("a/../../b.obj").unwrap_err().contains("escapes"));
        assert!(check_asset_path("/etc/passwd").unwrap_err().contains("relative"));
        let e = err(&format!("{MINIMAL}\n[[mesh]]\nfile = \"../x.obj\"\nmaterial = \"red\"\n"));
        assert!(e.message.contains("escapes") && e.line == 18, "{e}");
        let e = err(&format!("{MINIMAL}\n[[mesh]]\nfile = \"x.obj\"\nmaterial = \"red\"\n"));
        assert!(e.message.contains("cannot read \"x.obj\""), "{e}");
    }

    #[test]
    fn broken_obj_is_reported_with_its_line() {
        struct One(&'static [u8]);
        impl Assets for One {
            fn get(&self, path: &str) -> Option<&[u8]> {
                (path == "m.obj").then_some(self.0)
            }
        }
        let text = format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n");
        let e = parse_scene_with_assets("t.toml", &text, &One(b"v 0 0 0\nf 1 2 3\n")).unwrap_err();
        assert!(e.message.contains("line 2") && e.message.contains("out of range"), "{e}");
        let ok =
            parse_scene_with_assets("t.toml", &text, &One(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")).unwrap();
        assert_eq!(ok.prims.len(), 2);
    }

    /// Contract 6: a sample draws only the dimensions the scene uses.
    #[test]
    fn samples_pay_only_for_the_dimensions_used() {
        let used = |text: &str| {
            let s = parse_scene("t.toml", text).unwrap();
            let mut sampler = s.sampler();
            s.render_sample(&mut sampler, glam::UVec2::new(4, 3), 0);
            sampler.dimensions_used()
        };
        // A classic scene with no light at all: the pixel position only.
        assert_eq!(used(MINIMAL), 1);
        let lens = MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0]\naperture = 0.1");
        assert_eq!(used(&lens), 2);
        let moving =
            MINIMAL.replace("material = \"red\"", "material = \"red\"\nmotion = { translate = [1, 0, 0] }");
        assert_eq!(used(&moving), 2);
        let closed = moving.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0]\nshutter = [0, 0]");
        assert_eq!(used(&closed), 1);
    }

    #[test]
    fn emitters_and_motion_are_validated() {
        let e = err(&MINIMAL.replace("material = \"red\"", "material = \"red\"\nemission = 5"));
        assert!(e.message.contains("not both"), "{e}");
        let moving_light =
            MINIMAL.replace("material = \"red\"", "emission = 5\nmotion = { translate = [1, 0, 0] }");
        assert!(err(&moving_light).message.contains("cannot move"));
        let moving = parse_scene(
            "t.toml",
            &MINIMAL.replace("material = \"red\"", "material = \"red\"\nmotion = { translate = [1, 0, 0] }"),
        )
        .unwrap();
        assert!(moving.has_motion_blur());
        let e =
            err(&MINIMAL
                .replace("material = \"red\"", "material = \"red\"\ntransform = { scale = [1, 2, 1] }"));
        assert!(e.message.contains("uniform"), "{e}");
    }
}
