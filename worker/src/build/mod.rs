//! Building the render scene from a validated description: textures decoded, materials,
//! primitives, lights and motions made, the BVH built. Validation happened before, in
//! `tessera_description`; what can still fail here is only what a header could not tell
//! (an image whose pixels are damaged) or assets that differ from the ones validated.

mod gltf;
mod images;
mod materials;
mod shapes;

use std::collections::BTreeMap;
use std::sync::Arc;

use tessera_description::bundle::{Assets, NoAssets};
use tessera_description::model::{Description, Location};
use tessera_description::obj::{parse_obj_scanned, ParsedObj};
use tessera_description::{Bundle, SceneError};

use crate::render::bvh::{Aabb, Bvh, LeafPolicy};
use crate::render::camera::Camera;
use crate::render::instance;
use crate::render::light::{Light, LightChoice};
use crate::render::{Scene, World};

pub use tessera_description::limits;

/// A step of loading a scene, for timing it (`tessera bench load`): an observer is told,
/// at the end of each stretch of work, which step it was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// OBJ files read into meshes.
    ReadObj,
    /// The description validated (with its scan of the meshes it was not handed).
    Validation,
    /// Primitives made from the objects, and their boxes.
    Primitives,
    /// The BVH built.
    Bvh,
    /// The BVH's slots made.
    Slots,
    /// Everything else: images, materials, lights.
    Rest,
}

/// Builds the scene a description describes, with its meshes and images from `assets`.
pub fn build(desc: &Description, assets: &dyn Assets) -> Result<Scene, SceneError> {
    build_observed(desc, assets, Meshes::new(), &mut |_| {})
}

/// [`build`] from meshes already parsed (the others are parsed from `assets`), telling
/// `mark` what each stretch of work was.
fn build_observed(
    desc: &Description,
    assets: &dyn Assets,
    meshes: Meshes,
    mark: &mut dyn FnMut(Phase),
) -> Result<Scene, SceneError> {
    let r = &desc.render;
    let c = &desc.camera;
    let mut camera = Camera::new(c.position, c.look_at, c.up, c.fov, c.axis, r.width, r.height);
    camera.focus_distance = c.focus_distance;
    camera.lens_radius = c.lens_radius;
    camera.shutter = c.shutter;
    let err = |at: Location, message: String| SceneError {
        file: desc.file.clone(),
        line: at.line,
        column: at.column,
        message,
    };
    let mut shapes = shapes::Shapes::with_meshes(meshes.into_iter().map(|(f, p)| (f, p.mesh)), &desc.objects);
    let textures = materials::textures(desc, assets, &mut shapes.gltf, &err)?;
    mark(Phase::Rest);
    for o in &desc.objects {
        shapes.object(o, &desc.objects, assets, &err, mark)?;
    }
    mark(Phase::Primitives);
    let planes = desc
        .planes
        .iter()
        .map(|p| (crate::render::geometry::Plane::new(p.point, p.normal), p.material))
        .collect();
    let mut lights = shapes.lights;
    for l in &desc.lights {
        lights.push(match *l {
            tessera_description::model::Light::Point { position, intensity } => {
                Light::Point { position, intensity }
            }
            tessera_description::model::Light::Directional { direction, irradiance } => {
                Light::Directional { direction, irradiance }
            }
            tessera_description::model::Light::Spot {
                position,
                direction,
                intensity,
                inner_cone,
                outer_cone,
            } => Light::spot(position, direction, intensity, inner_cone, outer_cone),
        });
    }
    let environment = match &desc.environment {
        Some(env) => {
            lights.push(Light::Environment(Arc::new(environment(env, assets, &err)?)));
            Some(lights.len() as u32 - 1)
        }
        None => None,
    };
    let materials: Vec<_> = desc.materials.iter().map(materials::material).collect();
    let surfaces = crate::render::surface::Surfaces::new(&materials, std::mem::take(&mut shapes.extras));
    let mut bounds: Vec<_> = {
        use rayon::prelude::*;
        mark(Phase::Rest);
        let bounds = shapes.prims.par_iter().map(|p| p.bounds(&shapes.meshes, &shapes.motions)).collect();
        mark(Phase::Primitives);
        bounds
    };
    // The light choice weighs lights against the scene's size: every primitive's box,
    // the moving meshes' triangles one by one (as before they were instances).
    let radius = scene_radius(bounds.iter().fold(Aabb::EMPTY, |b, p| b.union(*p)));
    let runs = instance::moving_meshes(&shapes.prims, &shapes.meshes, &surfaces.alpha);
    let instances: Vec<_> =
        runs.iter().map(|r| instance::Instance::new(r, &shapes.meshes, &shapes.motions)).collect();
    // The tree's items: the primitives of no moving mesh (`free[k]` is item k's), then the
    // instances.
    let free: Option<Vec<u32>> = (!runs.is_empty()).then(|| {
        let mut moving = vec![false; shapes.prims.len()];
        for r in &runs {
            moving[r.first as usize..(r.first + r.count) as usize].fill(true);
        }
        let free: Vec<u32> = (0..shapes.prims.len() as u32).filter(|&i| !moving[i as usize]).collect();
        bounds = free.iter().map(|&i| bounds[i as usize]).collect();
        bounds.extend(instances.iter().map(|inst| inst.bounds(&shapes.motions)));
        free
    });
    let inline_triangles = {
        use rayon::prelude::*;
        let meshes = &shapes.meshes;
        shapes.prims.par_iter().filter(|p| crate::render::triangles::inline(p, meshes).is_some()).count()
    };
    let policy = LeafPolicy::for_scene(inline_triangles, bounds.len() - inline_triangles);
    let mut bvh = Bvh::build_with(&bounds, policy);
    drop(bounds);
    if let Some(free) = free {
        // Item k names its primitive, or instance i as `prims.len() + i` (`triangles::slots`).
        let prims = shapes.prims.len() as u32;
        bvh.rename(|k| free.get(k as usize).copied().unwrap_or(prims + k - free.len() as u32));
    }
    mark(Phase::Bvh);
    let light_choice = LightChoice::new(&lights, radius);
    mark(Phase::Rest);
    let slots = crate::render::triangles::slots(&bvh, &shapes.prims, &shapes.meshes);
    mark(Phase::Slots);
    let emitters = crate::render::few_emitters(&shapes.prims);
    let own_leaves = crate::render::own_leaves(&lights, &shapes.prims, &bvh);
    let world = World {
        emitters,
        own_leaves,
        materials,
        textures,
        prims: shapes.prims,
        bvh,
        instances,
        slots,
        planes,
        meshes: shapes.meshes,
        motions: shapes.motions,
        lights,
        surfaces,
        light_choice,
        environment,
    };
    let scene = Scene {
        width: r.width,
        height: r.height,
        spp: r.spp,
        seed: r.seed,
        sampler: r.sampler,
        progressive: false,
        max_depth: r.max_depth,
        diffuse_rays: r.diffuse_rays,
        background: r.background,
        ambient: r.ambient,
        camera,
        world: Arc::new(world),
    };
    mark(Phase::Rest);
    Ok(scene)
}

/// Half the diagonal of the bounded objects' box (1 without any): the disc through which
/// directional light and the environment reach the scene, for weighing lights by power.
fn scene_radius(b: Aabb) -> f32 {
    let r = 0.5 * (b.max - b.min).length();
    if b.is_empty() || !(r.is_finite() && r > 0.0) {
        1.0
    } else {
        r
    }
}

/// The environment light: a uniform radiance, or an image decoded (its header was checked
/// in validation; its pixels may still be damaged) with non-finite and negative texels
/// taken as black.
fn environment(
    env: &tessera_description::model::Environment,
    assets: &dyn Assets,
    err: &dyn Fn(Location, String) -> SceneError,
) -> Result<crate::render::environment::Environment, SceneError> {
    use crate::render::environment::Environment;
    use tessera_description::model::EnvironmentKind;
    match &env.kind {
        EnvironmentKind::Uniform(c) => Ok(Environment::uniform(*c * env.strength, env.rotation)),
        EnvironmentKind::Map { file, .. } => {
            // The environment has no table position of its own in the description.
            let at = Location { line: 1, column: 1 };
            let bytes = assets.get(file).ok_or_else(|| {
                err(at, format!("environment.file: cannot read {file:?} (relative to the scene's folder)"))
            })?;
            let img = images::decode_image(bytes)
                .map_err(|e| err(at, format!("environment.file: {file:?} is not a readable image: {e}")))?;
            let (width, height, values) = crate::render::texture::linear_rgb(&img);
            drop(img);
            let texels = values
                .chunks_exact(3)
                .map(|c| {
                    let v = glam::Vec3::from_slice(c) * env.strength;
                    if v.is_finite() {
                        v.max(glam::Vec3::ZERO)
                    } else {
                        glam::Vec3::ZERO
                    }
                })
                .collect();
            Ok(Environment::map(width as usize, height as usize, texels, env.rotation))
        }
    }
}

/// Validates and builds a bundle's scene.
pub fn parse_bundle(bundle: &Bundle) -> Result<Scene, SceneError> {
    parse_bundle_observed(bundle, &mut |_| {})
}

/// [`parse_bundle`], telling `mark` at the end of each stretch of work which [`Phase`] it
/// was (the time since the previous call, or since the start, went to that phase).
pub fn parse_bundle_observed(bundle: &Bundle, mark: &mut dyn FnMut(Phase)) -> Result<Scene, SceneError> {
    let (desc, meshes) = validated(bundle, None, u64::MAX, mark)?;
    build_observed(&desc, bundle, meshes, mark)
}

/// Why a worker does not build a bundle's scene.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LoadError {
    /// The scene does not validate or build.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The scene's own estimate of its memory (`Description::summary`) exceeds this worker's.
    #[error(
        "{file}: the scene needs about {needs} bytes to build ({triangles} triangles, {textures} textures), more than this worker's {memory} (--memory)"
    )]
    TooLarge {
        /// The scene's name.
        file: String,
        /// Estimated bytes.
        needs: u64,
        /// The worker's memory budget.
        memory: u64,
        /// Triangles, every use counted.
        triangles: u64,
        /// Image textures.
        textures: usize,
    },
}

/// Validates and builds a bundle's scene as it stands during `frame`: its animation
/// evaluated over that frame's shutter (a still scene is the same at every frame).
pub fn parse_bundle_frame(bundle: &Bundle, frame: u32) -> Result<Scene, SceneError> {
    let (desc, meshes) = validated(bundle, Some(frame), u64::MAX, &mut |_| {})?;
    build_observed(&desc, bundle, meshes, &mut |_| {})
}

/// Validates a bundle's scene and builds it if its estimated memory fits in `memory`
/// bytes; checked before any geometry is built or image decoded.
pub fn parse_bundle_within(bundle: &Bundle, memory: u64) -> Result<Scene, LoadError> {
    parse_bundle_frame_within(bundle, None, memory)
}

/// [`parse_bundle_within`] for frame `frame` of an animated scene (`None`: its first).
pub fn parse_bundle_frame_within(
    bundle: &Bundle,
    frame: Option<u32>,
    memory: u64,
) -> Result<Scene, LoadError> {
    let (desc, meshes) = validated(bundle, frame, memory, &mut |_| {})?;
    let summary = desc.summary(false);
    if summary.worker_bytes > memory {
        return Err(LoadError::TooLarge {
            file: desc.file.clone(),
            needs: summary.worker_bytes,
            memory,
            triangles: summary.triangles,
            textures: summary.textures.len(),
        });
    }
    Ok(build_observed(&desc, bundle, meshes, &mut |_| {})?)
}

/// An upper bound of the bytes parsing an OBJ file allocates per byte of its text: a
/// triangle (36 bytes) takes at least two bytes of a face line (`"1 "`), vectors grow to at
/// most twice their length, and a file read in chunks holds a chunk's part beside the
/// whole while joining them.
const PARSE_BYTES_PER_OBJ_BYTE: u64 = 64;

/// The description of a bundle's scene at `frame`, with the meshes it names already
/// parsed: each OBJ file is read once, here, in parallel across files, and validation is
/// handed their counts and extents instead of scanning them again. A file that is missing,
/// not text or does not parse is left to validation, which refuses it with the words and
/// at the place it always did. When parsing could take more than `memory` bytes the meshes
/// are not read ahead (validation scans them, the build parses them after the memory check),
/// so that a scene too large for this worker is still refused before it is built.
fn validated(
    bundle: &Bundle,
    frame: Option<u32>,
    memory: u64,
    mark: &mut dyn FnMut(Phase),
) -> Result<(Description, Meshes), SceneError> {
    let files = Description::mesh_files(bundle);
    let text_bytes: u64 = files.iter().filter_map(|f| bundle.get(f)).map(|b| b.len() as u64).sum();
    let meshes = if text_bytes.saturating_mul(PARSE_BYTES_PER_OBJ_BYTE) <= memory {
        read_meshes(bundle, &files)
    } else {
        Meshes::new()
    };
    mark(Phase::ReadObj);
    let scans = meshes.iter().map(|(f, p)| (f.clone(), (p.counts, p.extent))).collect();
    let desc = Description::parse_scanned(bundle, frame, scans)?;
    mark(Phase::Validation);
    Ok((desc, meshes))
}

/// OBJ files parsed, by asset path.
type Meshes = BTreeMap<String, ParsedObj>;

/// The files of `files` that parse, parsed in parallel (a large one in parallel chunks too).
fn read_meshes(bundle: &Bundle, files: &[String]) -> Meshes {
    use rayon::prelude::*;
    files
        .par_iter()
        .filter_map(|f| {
            let text = bundle.get(f).and_then(|b| std::str::from_utf8(b).ok())?;
            parse_obj_scanned(text).ok().map(|p| (f.clone(), p))
        })
        .collect()
}

/// Validates and builds a scene without assets. `file` names the scene in messages.
pub fn parse_scene(file: &str, text: &str) -> Result<Scene, SceneError> {
    parse_scene_with_assets(file, text, &NoAssets)
}

/// Validates and builds a scene whose meshes and images come from `assets`.
pub fn parse_scene_with_assets(file: &str, text: &str, assets: &dyn Assets) -> Result<Scene, SceneError> {
    build(&Description::parse_text(file, text, assets)?, assets)
}

#[cfg(test)]
mod tests;
