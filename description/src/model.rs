//! A validated scene description: plain data, every value checked and every name resolved
//! to an index, in the order the renderer builds it. Nothing here holds geometry beyond
//! what the scene file itself spells out: meshes are named by their asset and counted,
//! images by their asset and size.

use glam::{Vec3, Vec4};

use crate::obj::ObjCounts;
use crate::transform::Trs;

/// Where in the scene file something was given: 1-based line and column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Location {
    /// 1-based line.
    pub line: usize,
    /// 1-based column.
    pub column: usize,
}

/// A scene, validated.
#[derive(Debug, Clone, PartialEq)]
pub struct Description {
    /// The scene's name in messages (the file it was read from).
    pub file: String,
    /// Image size, samples and the rest of `[render]`.
    pub render: RenderSettings,
    /// The camera.
    pub camera: Camera,
    /// Textures, referenced by index, in name order.
    pub textures: Vec<Texture>,
    /// Materials, referenced by index: the named ones in name order, then the black
    /// surface of emitters when the scene has any.
    pub materials: Vec<Material>,
    /// Bounded objects, in build order: spheres, rectangles, boxes, triangles, meshes.
    pub objects: Vec<Object>,
    /// Infinite planes.
    pub planes: Vec<Plane>,
    /// Point, spot and directional lights (emitting objects are lights too, built with them).
    pub lights: Vec<Light>,
    /// Light from infinitely far away: a uniform colour or an equirectangular image.
    pub environment: Option<Environment>,
    /// Bytes of the bundle: the scene text and every asset.
    pub bundle_bytes: u64,
    /// The frames of an animated scene and the frame this description stands at; `None`
    /// for a still scene.
    pub sequence: Option<crate::animation::Sequence>,
}

/// The `[render]` table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Seed of every random choice.
    pub seed: u64,
    /// The sample pattern.
    pub sampler: SamplerKind,
    /// Most path segments and depth of the classic ray tree.
    pub max_depth: u32,
    /// Rays a diffuse lobe sends, where a path picks it, to look for light (the sky, an
    /// environment, emitters): 1 is Cook's one ray a sample.
    pub diffuse_rays: u32,
    /// Radiance of rays that escape.
    pub background: Vec3,
    /// Ambient light of the classic model.
    pub ambient: Vec3,
}

/// Which pattern a pixel's samples follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SamplerKind {
    /// Cook's jittered strata: each 2-D dimension a correlated multi-jittered pattern over
    /// the pixel's samples, dimensions associated at random.
    #[default]
    Stratified,
    /// Independent uniform random numbers: the baseline every other pattern must beat.
    Independent,
    /// The first two dimensions of Sobol's sequence, Owen-scrambled per pixel and dimension
    /// (hash-based nested uniform scrambling), the sample order shuffled per dimension by a
    /// nested scramble of the index, so that every power-of-two prefix of a pixel's
    /// samples is a (0, 2) net in base 2. Jobs in rounds (a time budget or a noise target)
    /// draw it in place of `Stratified`.
    Sobol,
}

impl SamplerKind {
    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Stratified => "stratified",
            SamplerKind::Independent => "independent",
            SamplerKind::Sobol => "sobol",
        }
    }

    /// The kind of a scene-file name.
    pub fn from_name(name: &str) -> Option<Self> {
        [SamplerKind::Stratified, SamplerKind::Independent, SamplerKind::Sobol]
            .into_iter()
            .find(|k| k.name() == name)
    }
}

/// How the field of view is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FovAxis {
    /// The full vertical angle.
    Vertical,
    /// The full horizontal angle.
    Horizontal,
}

/// The `[camera]` table, resolved: lens radius and focus distance computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub position: Vec3,
    /// The point looked at.
    pub look_at: Vec3,
    /// Up direction (not necessarily orthogonal to the view).
    pub up: Vec3,
    /// Full field of view in radians along `axis`.
    pub fov: f32,
    /// Which angle `fov` is.
    pub axis: FovAxis,
    /// Lens radius; 0 is a pinhole.
    pub lens_radius: f32,
    /// Distance of the plane of focus along the view axis.
    pub focus_distance: f32,
    /// Shutter open and close, as fractions of the motion interval [0, 1].
    pub shutter: (f32, f32),
}

/// Where a checker takes its coordinates from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CheckerSpace {
    /// World x and z of the hit point (floors).
    WorldXz,
    /// The surface's UV coordinates.
    Uv,
}

/// A named texture.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Its name in the scene.
    pub name: String,
    /// What it is.
    pub kind: TextureKind,
    /// Its table in the scene file.
    pub at: Location,
}

/// A texture's kind and parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum TextureKind {
    /// A procedural checker.
    Checker {
        /// Colour of even squares.
        even: Vec3,
        /// Colour of odd squares.
        odd: Vec3,
        /// Edge of one square.
        size: f32,
        /// Coordinates.
        space: CheckerSpace,
    },
    /// An image asset, checked from its header only.
    Image {
        /// The normalised asset path.
        file: String,
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// An image inside (or beside) a glTF asset: glTF `images[image]` of `file`.
    GltfImage {
        /// The normalised asset path of the glTF file.
        file: String,
        /// Index into the asset's `images`.
        image: u32,
        /// Width in pixels, from the image's header.
        width: u32,
        /// Height in pixels, from the image's header.
        height: u32,
    },
}

/// A glTF texture reference, resolved: which texture of the scene and which texture
/// coordinate set of the primitive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TexRef {
    /// Index into `Description::textures`.
    pub texture: u32,
    /// The primitive's `TEXCOORD_n` set.
    pub texcoord: u32,
}

/// How a glTF material's alpha is used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlphaMode {
    /// Alpha ignored: fully opaque.
    Opaque,
    /// Cut-out: a hit whose alpha is below the cutoff is no hit.
    Mask(f32),
    /// Blended with what lies behind by alpha.
    Blend,
}

/// glTF 2.0 metallic-roughness (spec appendix B), with the extensions Tessera reads.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pbr {
    /// Base colour factor, linear RGBA.
    pub base_color: Vec4,
    /// Base colour texture, sRGB-encoded.
    pub base_color_texture: Option<TexRef>,
    /// Metallic factor.
    pub metallic: f32,
    /// Perceptual roughness factor (α = roughness²).
    pub roughness: f32,
    /// Linear texture: blue is metallic, green is roughness.
    pub metallic_roughness_texture: Option<TexRef>,
    /// Tangent-space normal map (linear) and its scale.
    pub normal_texture: Option<(TexRef, f32)>,
    /// Emissive factor times `KHR_materials_emissive_strength`.
    pub emissive: Vec3,
    /// Emissive texture, sRGB.
    pub emissive_texture: Option<TexRef>,
    /// Alpha use.
    pub alpha: AlphaMode,
    /// glTF `doubleSided`: back faces are shaded like front faces.
    pub double_sided: bool,
    /// `KHR_materials_ior`, default 1.5.
    pub ior: f32,
    /// `KHR_materials_transmission` factor; 0 is none.
    pub transmission: f32,
}

/// A colour parameter: constant or textured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Color {
    /// A constant colour.
    Const(Vec3),
    /// A texture by index.
    Texture(u32),
}

/// The classic (Whitted/Cook) model's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Classic {
    /// Surface colour.
    pub color: Color,
    /// Weight of the ambient term.
    pub ambient: f32,
    /// Weight of the diffuse term.
    pub diffuse: f32,
    /// Weight of the specular highlight.
    pub specular: f32,
    /// Phong exponent of the highlight.
    pub shininess: f32,
    /// Mirror reflection per channel.
    pub reflect: Vec3,
    /// Transmission per channel.
    pub transmit: Vec3,
    /// Index of refraction.
    pub ior: f32,
    /// Spread of glossy reflection.
    pub gloss: f32,
    /// Spread of translucent transmission.
    pub translucency: f32,
}

/// A material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Material {
    /// The classic model.
    Classic(Classic),
    /// Lambertian.
    Lambert {
        /// Albedo.
        albedo: Color,
    },
    /// Ideal mirror.
    Mirror {
        /// Reflectance.
        reflectance: Vec3,
    },
    /// Smooth dielectric.
    Dielectric {
        /// Index of refraction.
        ior: f32,
    },
    /// Conductor with a complex index.
    Conductor {
        /// Real part.
        eta: Vec3,
        /// Imaginary part.
        k: Vec3,
        /// GGX roughness.
        roughness: f32,
    },
    /// Rough dielectric.
    RoughDielectric {
        /// Index of refraction.
        ior: f32,
        /// GGX roughness.
        roughness: f32,
    },
    /// Dielectric coat over a diffuse base.
    Plastic {
        /// Base albedo.
        diffuse: Color,
        /// Index of the coat.
        ior: f32,
    },
    /// glTF 2.0 metallic-roughness (spec appendix B).
    Pbr(Pbr),
}

/// A bounded object's shape, in object space.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f32,
    },
    /// A parallelogram: centre and the two half-edges.
    Rectangle {
        /// Centre.
        center: Vec3,
        /// First half-edge.
        u: Vec3,
        /// Second half-edge.
        v: Vec3,
    },
    /// An axis-aligned box, built as six rectangles.
    Box {
        /// Lower corner.
        min: Vec3,
        /// Upper corner.
        max: Vec3,
    },
    /// One triangle.
    Triangle {
        /// Its corners.
        vertices: [Vec3; 3],
    },
    /// An OBJ mesh asset.
    Mesh {
        /// The normalised asset path.
        file: String,
        /// What the file holds, from a validating scan.
        counts: ObjCounts,
    },
    /// One triangle primitive of a glTF asset's mesh (mode TRIANGLES), vertices in the
    /// mesh's own space; the node's world transform is the Object's transform.
    GltfPrimitive {
        /// The normalised asset path of the glTF file.
        file: String,
        /// Index into the asset's `meshes`.
        mesh: u32,
        /// Index into that mesh's `primitives`.
        primitive: u32,
        /// Triangles it holds.
        triangles: u64,
        /// Vertices (the POSITION accessor's count).
        vertices: u64,
    },
}

/// A bounded object.
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    /// Its shape.
    pub shape: Shape,
    /// Material index.
    pub material: u32,
    /// Emitted radiance, for lights.
    pub emission: Option<Vec3>,
    /// Its transform (at shutter open).
    pub transform: Trs,
    /// Its transform at shutter close, when it moves.
    pub motion: Option<Trs>,
    /// Its table in the scene file.
    pub at: Location,
}

impl Object {
    /// How many primitives the renderer makes of it.
    pub fn primitives(&self) -> u64 {
        match &self.shape {
            Shape::Box { .. } => 6,
            Shape::Mesh { counts, .. } => counts.triangles as u64,
            Shape::GltfPrimitive { triangles, .. } => *triangles,
            _ => 1,
        }
    }

    /// How many triangles it has.
    pub fn triangles(&self) -> u64 {
        match &self.shape {
            Shape::Triangle { .. } => 1,
            Shape::Mesh { counts, .. } => counts.triangles as u64,
            Shape::GltfPrimitive { triangles, .. } => *triangles,
            _ => 0,
        }
    }
}

/// An infinite plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// A point on it.
    pub point: Vec3,
    /// Its normal (not necessarily unit).
    pub normal: Vec3,
    /// Material index.
    pub material: u32,
}

/// A Dirac light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// A point light.
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity per channel (colour times intensity).
        intensity: Vec3,
    },
    /// A directional light.
    Directional {
        /// Unit direction the light travels in.
        direction: Vec3,
        /// Irradiance per channel (colour times irradiance).
        irradiance: Vec3,
    },
    /// A spot light (glTF KHR_lights_punctual semantics: smooth falloff between the cones).
    Spot {
        /// Position.
        position: Vec3,
        /// Unit direction the light travels in (the cone's axis).
        direction: Vec3,
        /// Radiant intensity per channel on the axis (colour times intensity).
        intensity: Vec3,
        /// Half-angle in radians inside which the intensity is full.
        inner_cone: f32,
        /// Half-angle in radians outside which there is no light.
        outer_cone: f32,
    },
}

/// Light from infinitely far away, seen by every ray that escapes the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Environment {
    /// Its radiance: uniform or an image.
    pub kind: EnvironmentKind,
    /// Factor on the radiance.
    pub strength: f32,
    /// Turn about +y in radians (right-handed: +x towards -z for a positive angle).
    pub rotation: f32,
}

/// Where an environment's radiance comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum EnvironmentKind {
    /// The same radiance from every direction.
    Uniform(Vec3),
    /// An equirectangular image asset (Radiance `.hdr` or OpenEXR), checked from its
    /// header only; its pixels are the renderer's to decode.
    Map {
        /// The normalised asset path.
        file: String,
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
}

/// The six faces `(centre, u, v)` of a box, each with u × v pointing out of the box.
pub fn box_faces(min: Vec3, max: Vec3) -> [(Vec3, Vec3, Vec3); 6] {
    let (c, h) = ((min + max) * 0.5, (max - min) * 0.5);
    let (x, y, z) = (Vec3::X * h.x, Vec3::Y * h.y, Vec3::Z * h.z);
    [(c + x, y, z), (c - x, z, y), (c + y, z, x), (c - y, x, z), (c + z, x, y), (c - z, y, x)]
}

/// A parallelogram as the renderer holds it: in world space when static, in object space
/// when it moves (its motion transforms it at render time).
pub fn placed_rect((c, u, v): (Vec3, Vec3, Vec3), trs: &Trs, moves: bool) -> (Vec3, Vec3, Vec3) {
    if moves {
        return (c, u, v);
    }
    let m = trs.matrix();
    (m.transform_point3(c), m.transform_vector3(u), m.transform_vector3(v))
}
