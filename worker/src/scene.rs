//! The scene file: TOML, parsed strictly (unknown keys are errors) and validated, with
//! every error naming the file, line and column and what was expected.
//!
//! Conventions: right-handed world, y up; lengths in scene units; angles in degrees;
//! colours linear RGB. The format is documented in `docs/scene-format.md`.

use std::collections::HashMap;
use std::fmt;
use std::ops::Range;

use glam::Vec3;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;
use toml::Spanned;

use crate::render::camera::Camera;
use crate::render::geometry::{Plane, Sphere};
use crate::render::light::PointLight;
use crate::render::material::Material;
use crate::render::Scene;

/// A scene error with its location.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}:{line}:{column}: {message}")]
pub struct SceneError {
    /// The scene file's name as given.
    pub file: String,
    /// 1-based line.
    pub line: usize,
    /// 1-based column.
    pub column: usize,
    /// What is wrong and what was expected.
    pub message: String,
}

/// Limits that keep a hostile scene from exhausting a worker.
pub mod limits {
    /// The longest image side, in pixels.
    pub const MAX_SIDE: u32 = 65_536;
    /// The most pixels an image may have (256 Mpixel).
    pub const MAX_PIXELS: u64 = 1 << 28;
    /// The most samples per pixel.
    pub const MAX_SPP: u32 = 1 << 20;
    /// The deepest recursion of reflection and refraction.
    pub const MAX_DEPTH: u32 = 64;
}

/// A colour given as one number (grey) or as `[r, g, b]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rgb(pub Vec3);

impl<'de> Deserialize<'de> for Rgb {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Rgb;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a colour: a number or an array [r, g, b]")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Rgb, E> {
                Ok(Rgb(Vec3::splat(v as f32)))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Rgb, E> {
                Ok(Rgb(Vec3::splat(v as f32)))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<Rgb, A::Error> {
                Ok(Rgb(read_vec3(seq, &self)?))
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
    materials: HashMap<String, Spanned<MaterialDef>>,
    #[serde(default)]
    sphere: Vec<Spanned<SphereDef>>,
    #[serde(default)]
    plane: Vec<Spanned<PlaneDef>>,
    #[serde(default)]
    point_light: Vec<Spanned<PointLightDef>>,
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
fn default_up() -> V3 {
    V3(Vec3::Y)
}
fn default_fov() -> f32 {
    40.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraDef {
    position: V3,
    look_at: V3,
    #[serde(default = "default_up")]
    up: V3,
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    fov: f32,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialDef {
    #[serde(default = "grey")]
    color: Rgb,
    #[serde(default = "one")]
    ambient: f32,
    #[serde(default = "one")]
    diffuse: f32,
    #[serde(default)]
    specular: f32,
    #[serde(default = "default_shininess")]
    shininess: f32,
    #[serde(default = "black")]
    reflect: Rgb,
    #[serde(default = "black")]
    transmit: Rgb,
    #[serde(default = "default_ior")]
    ior: f32,
}

fn grey() -> Rgb {
    Rgb(Vec3::splat(0.8))
}
fn one() -> f32 {
    1.0
}
fn default_shininess() -> f32 {
    32.0
}
fn default_ior() -> f32 {
    1.5
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SphereDef {
    center: V3,
    radius: f32,
    material: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlaneDef {
    #[serde(default = "origin")]
    point: V3,
    normal: V3,
    material: String,
}

fn origin() -> V3 {
    V3(Vec3::ZERO)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PointLightDef {
    position: V3,
    #[serde(default = "white")]
    color: Rgb,
    /// Radiant intensity; irradiance falls off with the square of the distance.
    intensity: f32,
}

fn white() -> Rgb {
    Rgb(Vec3::ONE)
}

/// Where in the text an error points: 1-based line and column of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

struct Ctx<'a> {
    file: &'a str,
    text: &'a str,
}

impl Ctx<'_> {
    fn err(&self, span: Range<usize>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_column(self.text, span.start);
        SceneError { file: self.file.to_string(), line, column, message: message.into() }
    }

    fn finite(&self, span: &Range<usize>, what: &str, v: Vec3) -> Result<Vec3, SceneError> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(span.clone(), format!("{what} must be finite numbers, got {v}")))
        }
    }

    fn colour(&self, span: &Range<usize>, what: &str, c: Rgb) -> Result<Vec3, SceneError> {
        let v = self.finite(span, what, c.0)?;
        if v.min_element() < 0.0 {
            return Err(self.err(span.clone(), format!("{what} must not be negative, got {v}")));
        }
        Ok(v)
    }

    fn number(&self, span: &Range<usize>, what: &str, v: f32, ok: Range<f32>) -> Result<f32, SceneError> {
        if v.is_finite() && v >= ok.start && v <= ok.end {
            Ok(v)
        } else {
            Err(self.err(span.clone(), format!("{what} must be in [{}, {}], got {v}", ok.start, ok.end)))
        }
    }
}

/// Parses and validates a scene. `file` names the scene in error messages.
pub fn parse_scene(file: &str, text: &str) -> Result<Scene, SceneError> {
    let ctx = Ctx { file, text };
    let raw: SceneFile = toml::from_str(text).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        ctx.err(span, e.message().trim().to_string())
    })?;

    let rspan = raw.render.span();
    let r = raw.render.into_inner();
    if r.width == 0 || r.height == 0 || r.width > limits::MAX_SIDE || r.height > limits::MAX_SIDE {
        return Err(ctx.err(
            rspan,
            format!("image size must be 1..={} on each side, got {}x{}", limits::MAX_SIDE, r.width, r.height),
        ));
    }
    if u64::from(r.width) * u64::from(r.height) > limits::MAX_PIXELS {
        return Err(ctx.err(rspan, format!("image has more than {} pixels", limits::MAX_PIXELS)));
    }
    if r.spp == 0 || r.spp > limits::MAX_SPP {
        return Err(ctx.err(rspan, format!("spp must be 1..={}, got {}", limits::MAX_SPP, r.spp)));
    }
    if r.max_depth > limits::MAX_DEPTH {
        return Err(
            ctx.err(rspan, format!("max_depth must be at most {}, got {}", limits::MAX_DEPTH, r.max_depth))
        );
    }
    let background = ctx.colour(&rspan, "render.background", r.background)?;
    let ambient = ctx.colour(&rspan, "render.ambient", r.ambient)?;

    let cspan = raw.camera.span();
    let c = raw.camera.into_inner();
    let position = ctx.finite(&cspan, "camera.position", c.position.0)?;
    let look_at = ctx.finite(&cspan, "camera.look_at", c.look_at.0)?;
    let up = ctx.finite(&cspan, "camera.up", c.up.0)?;
    let fov = ctx.number(&cspan, "camera.fov (degrees)", c.fov, 1e-4..179.9)?;
    let forward = look_at - position;
    if forward.length_squared() == 0.0 || forward.cross(up).length_squared() == 0.0 {
        return Err(
            ctx.err(cspan, "camera.look_at must differ from camera.position and not lie along camera.up")
        );
    }
    let camera = Camera::new(position, look_at, up, fov.to_radians(), r.width, r.height);

    // Materials are named; sort the names so that indices never depend on hash order.
    let mut names: Vec<&String> = raw.materials.keys().collect();
    names.sort();
    let mut index = HashMap::new();
    let mut materials = Vec::with_capacity(names.len());
    for name in names {
        let spanned = &raw.materials[name];
        let span = spanned.span();
        let m = spanned.get_ref();
        let what = |field: &str| format!("materials.{name}.{field}");
        let material = Material {
            color: ctx.colour(&span, &what("color"), m.color)?,
            ambient: ctx.number(&span, &what("ambient"), m.ambient, 0.0..1e3)?,
            diffuse: ctx.number(&span, &what("diffuse"), m.diffuse, 0.0..1e3)?,
            specular: ctx.number(&span, &what("specular"), m.specular, 0.0..1e3)?,
            shininess: ctx.number(&span, &what("shininess"), m.shininess, 0.0..1e6)?,
            reflect: ctx.colour(&span, &what("reflect"), m.reflect)?,
            transmit: ctx.colour(&span, &what("transmit"), m.transmit)?,
            ior: ctx.number(&span, &what("ior"), m.ior, 1e-3..100.0)?,
        };
        index.insert(name.as_str(), materials.len() as u32);
        materials.push(material);
    }
    let material_of = |span: &Range<usize>, name: &str| -> Result<u32, SceneError> {
        index.get(name).copied().ok_or_else(|| {
            let mut known: Vec<&str> = index.keys().copied().collect();
            known.sort();
            ctx.err(span.clone(), format!("unknown material \"{name}\"; defined: [{}]", known.join(", ")))
        })
    };

    let mut spheres = Vec::new();
    for s in &raw.sphere {
        let span = s.span();
        let d = s.get_ref();
        let center = ctx.finite(&span, "sphere.center", d.center.0)?;
        if !(d.radius.is_finite() && d.radius > 0.0) {
            return Err(ctx.err(span, format!("sphere.radius must be a positive number, got {}", d.radius)));
        }
        spheres.push(Sphere::new(center, d.radius, material_of(&span, &d.material)?));
    }
    let mut planes = Vec::new();
    for p in &raw.plane {
        let span = p.span();
        let d = p.get_ref();
        let point = ctx.finite(&span, "plane.point", d.point.0)?;
        let normal = ctx.finite(&span, "plane.normal", d.normal.0)?;
        if normal.length_squared() == 0.0 {
            return Err(ctx.err(span, "plane.normal must not be the zero vector"));
        }
        planes.push(Plane::new(point, normal, material_of(&span, &d.material)?));
    }
    let mut lights = Vec::new();
    for l in &raw.point_light {
        let span = l.span();
        let d = l.get_ref();
        let position = ctx.finite(&span, "point_light.position", d.position.0)?;
        let color = ctx.colour(&span, "point_light.color", d.color)?;
        let intensity = ctx.number(&span, "point_light.intensity", d.intensity, 0.0..f32::MAX)?;
        lights.push(PointLight { position, intensity: color * intensity });
    }

    Ok(Scene {
        width: r.width,
        height: r.height,
        spp: r.spp,
        seed: r.seed,
        max_depth: r.max_depth,
        background,
        ambient,
        camera,
        materials,
        spheres,
        planes,
        lights,
    })
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
        assert_eq!(s.spheres.len(), 1);
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
    }

    #[test]
    fn bad_image_size_and_camera_are_refused() {
        assert!(err(&MINIMAL.replace("width = 8", "width = 0")).message.contains("image size"));
        assert!(err(&MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 5]"))
            .message
            .contains("look_at"));
        assert!(err(&MINIMAL.replace("[camera]", "[cam]")).message.contains("cam"));
    }

    #[test]
    fn vectors_need_three_numbers() {
        let e = err(&MINIMAL.replace("center = [0, 0, 0]", "center = [0, 0]"));
        assert!(e.message.contains("three numbers"), "{e}");
    }
}
