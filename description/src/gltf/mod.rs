//! glTF 2.0 import: `[[gltf]]` tables of a TOML scene, and the assets behind them.
//!
//! The `gltf` crate parses the document; what it lets through (indices out of range,
//! byte ranges past a buffer's end, index values past the vertex count, node cycles,
//! primitive modes other than triangles, …) is checked here, so that the renderer can
//! read a validated asset without a bounds check failing. Every refusal is one line
//! naming the file and the JSON path of what is wrong:
//! `model.gltf: meshes[2].primitives[0].indices: accessor 9 does not exist`.
//!
//! Buffers and images come from the bundle (the GLB's binary chunk, `data:` URIs, or
//! files beside the glTF file that the bundle carries): nothing here reads the file
//! system or the network. Supported, refused and the defaults: `docs/gltf.md`.

mod accessors;
mod animation;
mod cameras;
mod checks;
mod container;
mod geometry;
mod lights;
mod materials;
pub(crate) use materials::default_material;
mod nodes;
#[cfg(test)]
mod tests;
pub mod wrap;

use glam::Vec3;

pub use cameras::GltfCamera;
pub use container::external_assets;
pub use geometry::Geometry;
pub use nodes::SceneRef;

use crate::animation::FrameTime;
use crate::assets::Assets;
use crate::math;
use crate::model::{Light, Pbr};
use crate::transform::Trs;

/// `format!` for JSON paths.
macro_rules! at {
    ($($t:tt)*) => { format!($($t)*) };
}
pub(crate) use at;

/// A glTF asset that cannot be used: the file, the JSON path and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}: {}{message}", if path.is_empty() { String::new() } else { format!("{path}: ") })]
pub struct GltfError {
    /// The asset path of the glTF file.
    pub file: String,
    /// The JSON path of what is wrong (`meshes[2].primitives[0].indices`); empty for the
    /// file as a whole.
    pub path: String,
    /// What is wrong.
    pub message: String,
}

impl GltfError {
    pub(crate) fn new(file: &str, path: impl Into<String>, message: impl Into<String>) -> GltfError {
        GltfError { file: file.to_string(), path: path.into(), message: message.into() }
    }
}

/// A validated glTF asset: its document and the bytes of every buffer. The renderer
/// reads geometry and images from it with no check of its own.
pub struct Asset {
    /// The asset path of the glTF file (for messages).
    pub file: String,
    /// The document, validated.
    pub document: gltf::Document,
    /// Each buffer's bytes, in `buffers` order, at least `byteLength` long.
    pub buffers: Vec<Vec<u8>>,
}

impl Asset {
    /// Reads and validates the glTF asset `file` (a `.gltf` or `.glb`) with its buffers
    /// from `assets`.
    pub fn open(file: &str, assets: &dyn Assets) -> Result<Asset, GltfError> {
        let bytes = assets
            .get(file)
            .ok_or_else(|| GltfError::new(file, "", "the bundle does not carry this file"))?;
        let source = container::open(file, bytes, assets)?;
        checks::document(file, &source)?;
        Ok(Asset {
            file: file.to_string(),
            document: gltf::Document::from_json_without_validation(source.root),
            buffers: source.buffers,
        })
    }

    /// The encoded bytes (PNG, JPEG) of `images[image]`.
    pub fn image(&self, image: u32, assets: &dyn Assets) -> Result<Vec<u8>, GltfError> {
        materials::image_bytes(&self.file, self.document.as_json(), &self.buffers, image, assets)
    }

    /// The vertices and triangles of `meshes[mesh].primitives[primitive]`, in the mesh's
    /// own space.
    pub fn geometry(&self, mesh: u32, primitive: u32) -> Result<Geometry, GltfError> {
        geometry::read(&self.file, self.document.as_json(), &self.buffers, mesh, primitive)
    }
}

/// One use of a triangle primitive: a node of the chosen scene that holds its mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    /// The node.
    pub node: u32,
    /// Its mesh.
    pub mesh: u32,
    /// The primitive within the mesh.
    pub primitive: u32,
    /// Its glTF material; `None` is glTF's default material.
    pub material: Option<u32>,
    /// Triangles.
    pub triangles: u64,
    /// Vertices.
    pub vertices: u64,
    /// The largest |coordinate| of its vertices per axis, in mesh space.
    pub extent: Vec3,
    /// Its vertices' bounds in mesh space.
    pub bounds: (Vec3, Vec3),
    /// The node's world transform (at the frame's shutter open).
    pub world: Trs,
    /// The node's world transform at shutter close, when it moves.
    pub motion: Option<Trs>,
}

/// What a glTF scene puts into a Tessera scene. Texture references in `materials` are
/// glTF image indices, for the caller to map to its own textures.
#[derive(Debug, Clone, PartialEq)]
pub struct Imported {
    /// Every triangle primitive of every node instance, in node order.
    pub instances: Vec<Instance>,
    /// The glTF materials the instances use, by glTF index.
    pub materials: Vec<(u32, Pbr)>,
    /// The images those materials use: glTF index, width, height (from their headers).
    pub images: Vec<(u32, u32, u32)>,
    /// The first perspective camera of the scene, in world space.
    pub camera: Option<GltfCamera>,
    /// Its punctual lights, in world space.
    pub lights: Vec<Light>,
    /// The world bounds of all instances.
    pub bounds: Option<(Vec3, Vec3)>,
}

/// Validates the glTF asset `file` and reads what its scene `scene` (default: the
/// document's `scene`, else its first) puts into a Tessera scene placed by `base`, with
/// animation evaluated over `frame`'s shutter when given (else its rest pose).
pub fn import(
    file: &str,
    assets: &dyn Assets,
    scene: Option<&SceneRef>,
    base: &Trs,
    frame: Option<FrameTime>,
) -> Result<Imported, GltfError> {
    let bytes =
        assets.get(file).ok_or_else(|| GltfError::new(file, "", "the bundle does not carry this file"))?;
    let source = container::open(file, bytes, assets)?;
    checks::document(file, &source)?;
    let root = &source.root;
    let poses = animation::Poses::new(file, root, &source.buffers, frame)?;
    let walked = nodes::walk(file, root, scene, base, &poses)?;
    let mut instances = Vec::new();
    let mut shapes = std::collections::BTreeMap::new();
    for placed in &walked {
        let Some(mesh) = root.nodes[placed.node as usize].mesh else { continue };
        let m = mesh.value() as u32;
        for (p, prim) in root.meshes[m as usize].primitives.iter().enumerate() {
            let key = (m, p as u32);
            let scan = match shapes.get(&key) {
                Some(s) => *s,
                None => {
                    let s = geometry::scan(file, root, &source.buffers, m, p as u32)?;
                    shapes.insert(key, s);
                    s
                }
            };
            instances.push(Instance {
                node: placed.node,
                mesh: m,
                primitive: p as u32,
                material: prim.material.map(|i| i.value() as u32),
                triangles: scan.triangles,
                vertices: scan.vertices,
                extent: scan.min.abs().max(scan.max.abs()),
                bounds: (scan.min, scan.max),
                world: placed.world,
                motion: placed.motion,
            });
        }
    }
    let (materials, images) = materials::used(file, root, &source.buffers, assets, &instances)?;
    let camera = cameras::first(file, root, &walked)?;
    let lights = lights::punctual(file, root, &walked)?;
    let bounds = instances.iter().fold(None, |b: Option<(Vec3, Vec3)>, i| {
        let m = i.world.matrix();
        let (lo, hi) = i.bounds;
        let corners = (0..8).map(|c| {
            m.transform_point3(Vec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            ))
        });
        corners.fold(b, |b, p| Some(b.map_or((p, p), |(a, z)| (a.min(p), z.max(p)))))
    });
    Ok(Imported { instances, materials, images, camera, lights, bounds })
}

/// The camera that frames `bounds` (a world box) from the front and a little above,
/// looking at its centre with the vertical field of view `fov` (radians) and the image
/// aspect `aspect` (width / height): what a glTF file without a camera is rendered with.
pub fn framing_camera(bounds: (Vec3, Vec3), fov: f32, aspect: f32) -> GltfCamera {
    let (lo, hi) = bounds;
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    // The bounding sphere fits the narrower of the two angles, with a 10 % margin.
    let half = (fov * 0.5).min(math::atan(aspect * math::tan(fov * 0.5)));
    let distance = 1.1 * radius / math::sin(half);
    let direction = Vec3::new(0.0, 0.35, 1.0).normalize();
    GltfCamera {
        position: centre + direction * distance,
        look_at: centre,
        up: Vec3::Y,
        yfov: fov,
        aspect_ratio: None,
    }
}
