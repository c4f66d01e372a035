//! The renderer: Cook's distributed ray tracing on a Whitted core. Every sample is a pure
//! function of (scene, seed, pixel, sample index), so that the farm can split, repeat and
//! reorder work freely.

pub mod bsdf;
pub mod bvh;
pub mod camera;
pub mod distribution;
pub mod environment;
pub mod geometry;
pub mod instance;
pub mod integrator;
pub mod light;
pub mod material;
pub mod sample;
pub mod sampler;
mod search;
mod shadow;
pub mod shape;
pub mod surface;
pub mod texture;
pub mod transform;
pub mod triangles;

use std::sync::Arc;

use glam::Vec3;

use bvh::Bvh;
use camera::Camera;
use geometry::{Hit, Plane, Ray};
use light::Light;
use material::Material;
pub use sampler::{Sampler, SamplerKind};
use search::{Found, Search};
use shadow::Shadow;
use shape::{Mesh, Primitive};
use texture::Texture;
use transform::Motion;

/// A scene ready to render: the per-job settings and camera, with the heavy part shared.
/// Cloning is cheap, and so is [`Scene::apply`]: jobs of one scene share its world.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Seed of every random choice; the same seed gives the same image.
    pub seed: u64,
    /// The sample pattern.
    pub sampler: SamplerKind,
    /// Whether the job draws its pixels' samples in rounds (a time budget or a noise
    /// target), stopping at some prefix of the pattern: the stratified pattern is then
    /// Sobol's, whose prefixes are stratified too ([`Scene::sampler`]).
    pub progressive: bool,
    /// Most path segments (camera ray included) and depth of the classic ray tree.
    pub max_depth: u32,
    /// Rays a diffuse lobe sends to look for light where a path picks it (1: Cook's).
    pub diffuse_rays: u32,
    /// Radiance of rays that escape.
    pub background: Vec3,
    /// Ambient light of the classic model.
    pub ambient: Vec3,
    /// The camera.
    pub camera: Camera,
    /// What the scene holds: built once per scene, shared by every job that renders it.
    pub world: Arc<World>,
}

/// A scene's materials, textures, geometry and lights, independent of image size.
#[derive(Debug)]
pub struct World {
    /// Materials, referenced by index.
    pub materials: Vec<Material>,
    /// Textures, referenced by index.
    pub textures: Vec<Texture>,
    /// Bounded primitives: in the BVH, or in an instance's (a moving mesh's triangles).
    pub prims: Vec<Primitive>,
    /// The BVH over `prims` but the moving meshes', and over `instances`.
    pub bvh: Bvh,
    /// The moving meshes, each with a tree of its own (`instance.rs`).
    pub instances: Vec<instance::Instance>,
    /// The BVH's slots in leaf order: its static triangles inline (`triangles::slots`).
    pub slots: triangles::Slots,
    /// Infinite planes with their material (not in the BVH: they have no bounds).
    pub planes: Vec<(Plane, u32)>,
    /// Triangle meshes.
    pub meshes: Vec<Mesh>,
    /// Motions of moving primitives.
    pub motions: Vec<Motion>,
    /// Lights.
    pub lights: Vec<Light>,
    /// glTF surfaces: extra vertex attributes, which materials cut out hits.
    pub surfaces: surface::Surfaces,
    /// Which lights a shading point samples (all, or one by power).
    pub light_choice: light::LightChoice,
    /// The environment's index in `lights`, when the scene has one: escaping rays see it
    /// instead of the background.
    pub environment: Option<u32>,
    /// The emitting primitives, when there are at most [`FEW_EMITTERS`] of them: few enough
    /// to test a ray against each ([`Scene::may_find_light`]).
    pub emitters: Option<Vec<u32>>,
    /// For each light, the leaf its shadow rays' walk may leave out ([`own_leaves`]).
    pub own_leaves: Vec<bvh::LeftOut>,
}

/// For each of `lights`, the leaf of `bvh` that holds only its primitive, where that is
/// one convex primitive and still: the primitive [`Scene::shadow`] passes over, so the
/// leaf's visit would do nothing.
pub fn own_leaves(lights: &[Light], prims: &[Primitive], bvh: &Bvh) -> Vec<bvh::LeftOut> {
    let mut own = vec![bvh::LeftOut::NONE; lights.len()];
    for (k, &i) in bvh.indices().iter().enumerate() {
        // Padding and instances name no primitive.
        let Some(prim) = prims.get(i as usize) else { continue };
        let passed_over = |&l: &u32| prim.motion.is_none() && lights[l as usize].is_one_convex_primitive();
        if let Some(l) = prim.light.filter(passed_over) {
            own[l as usize] = bvh.lone_leaf(k);
        }
    }
    own
}

/// The most emitting primitives [`Scene::may_find_light`] tests one by one; a scene with
/// more (an emissive mesh) traces every ray.
pub const FEW_EMITTERS: usize = 8;

/// The emitting primitives of `prims`, if there are at most [`FEW_EMITTERS`].
pub fn few_emitters(prims: &[Primitive]) -> Option<Vec<u32>> {
    let mut emitters = Vec::new();
    for (i, p) in prims.iter().enumerate() {
        if p.light.is_some() {
            if emitters.len() == FEW_EMITTERS {
                return None;
            }
            emitters.push(i as u32);
        }
    }
    Some(emitters)
}

/// The nearest hit found so far, before it is completed: the primitive, the distance and
/// the surface coordinates its completion needs.
#[derive(Debug, Clone, Copy)]
enum Candidate {
    /// An inline triangle, by its slot: barycentrics b1, b2.
    Triangle(usize, f32, f32, f32),
    /// A still parallelogram: coordinates s, t in [-1, 1].
    Rect(u32, f32, f32, f32),
    /// A still sphere: the distance alone.
    Sphere(u32, f32),
}

/// What a ray that only looks for light meets first ([`Scene::seen`]).
#[derive(Debug, Clone, Copy)]
pub enum Seen {
    /// Nothing: it escapes.
    Nothing,
    /// A surface that does not emit.
    Surface,
    /// An emitting surface, its hit completed (`light` is set).
    Emitter(SurfaceHit),
}

/// A hit with what lies at it.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceHit {
    /// The geometry.
    pub hit: Hit,
    /// Material index.
    pub material: u32,
    /// Area light index, when the surface emits.
    pub light: Option<u32>,
}

impl Scene {
    /// Applies a job's overrides: samples per pixel, image size (the field of view is kept
    /// along the camera's axis).
    pub fn apply(&mut self, spp: Option<u32>, size: Option<(u32, u32)>) {
        if let Some(spp) = spp {
            self.spp = spp;
        }
        if let Some((w, h)) = size {
            self.width = w;
            self.height = h;
            self.camera.set_resolution(w, h);
        }
    }

    /// Whether the time dimension is sampled: only with motion and an open shutter.
    pub fn has_motion_blur(&self) -> bool {
        !self.world.motions.is_empty() && self.camera.shutter.1 > self.camera.shutter.0
    }

    /// The nearest surface the ray hits before `t_max`, at shutter fraction `time`.
    pub fn intersect(&self, ray: &Ray, t_max: f32, time: f32) -> Option<SurfaceHit> {
        self.intersect_as::<false>(ray, t_max, time)
    }

    /// [`Scene::intersect`] for a ray traced among others like it, a pixel's camera rays:
    /// the same hit, by a walk whose branches such rays predict (`Bvh::traverse_slots`).
    pub fn intersect_coherent(&self, ray: &Ray, t_max: f32, time: f32) -> Option<SurfaceHit> {
        self.intersect_as::<true>(ray, t_max, time)
    }

    #[inline]
    fn intersect_as<const COHERENT: bool>(&self, ray: &Ray, t_max: f32, time: f32) -> Option<SurfaceHit> {
        // Only scenes with alpha cut-outs pay for the any-hit test.
        if self.world.surfaces.any_alpha {
            self.nearest::<true, COHERENT>(ray, t_max, time)
        } else {
            self.nearest::<false, COHERENT>(ray, t_max, time)
        }
    }

    /// [`Scene::intersect`] for a ray that only looks for light (a path's last, or a
    /// diffuse lobe's): the nearest hit is completed (point, normals, uv) only where its
    /// surface emits, since that is all such a ray reads. Same search, same answer.
    pub fn seen(&self, ray: &Ray, time: f32) -> Seen {
        let (found, t_max) = if self.world.surfaces.any_alpha {
            self.search::<true, false>(ray, f32::INFINITY, time)
        } else {
            self.search::<false, false>(ray, f32::INFINITY, time)
        };
        if self.nearest_plane(ray, t_max).is_some() {
            // Planes do not emit.
            return Seen::Surface;
        }
        let w = &*self.world;
        let light = match (found.nearest, &found.best) {
            // Plain triangles do not emit (`Scene::complete` gives them no light); where no
            // inline triangle does, the slot is not read (on a big mesh, a cache miss).
            (Some(Candidate::Triangle(..)), _) if !w.slots.any_inline_emitter() => None,
            (Some(Candidate::Triangle(k, ..)), _) => match w.slots[k].plain_material() {
                Some(_) => None,
                None => w.prims[w.slots[k].index() as usize].light,
            },
            (Some(Candidate::Rect(i, ..) | Candidate::Sphere(i, _)), _) => w.prims[i as usize].light,
            (None, Some(sh)) => sh.light,
            (None, None) => return Seen::Nothing,
        };
        if light.is_none() {
            return Seen::Surface;
        }
        // A candidate always completes (an inline triangle's normal is finite).
        match self.complete(ray, found) {
            Some(sh) => Seen::Emitter(sh),
            None => Seen::Nothing,
        }
    }

    /// The primitive (`u32::MAX` for an infinite plane) and distance of the nearest hit
    /// before `t_max`: [`Scene::intersect`]'s search, without completing the hit (its
    /// point, normals and uv), which is what a ray-casting library such as Embree returns.
    /// `bench rays` measures this beside Embree's closest-hit queries.
    pub fn nearest_primitive(&self, ray: &Ray, t_max: f32, time: f32, coherent: bool) -> Option<(u32, f32)> {
        let (found, t_max) = match (self.world.surfaces.any_alpha, coherent) {
            (false, false) => self.search::<false, false>(ray, t_max, time),
            (false, true) => self.search::<false, true>(ray, t_max, time),
            (true, false) => self.search::<true, false>(ray, t_max, time),
            (true, true) => self.search::<true, true>(ray, t_max, time),
        };
        if let Some((hit, _)) = self.nearest_plane(ray, t_max) {
            return Some((hit.prim, hit.t));
        }
        match (found.nearest, found.best) {
            (Some(Candidate::Triangle(k, t, ..)), _) => Some((self.world.slots[k].index(), t)),
            (Some(Candidate::Rect(i, t, ..) | Candidate::Sphere(i, t)), _) => Some((i, t)),
            (None, best) => best.map(|sh| (sh.hit.prim, sh.hit.t)),
        }
    }

    /// [`Scene::intersect`], with hits on materials with alpha tested when `ALPHA`.
    fn nearest<const ALPHA: bool, const COHERENT: bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        time: f32,
    ) -> Option<SurfaceHit> {
        let (found, t_max) = self.search::<ALPHA, COHERENT>(ray, t_max, time);
        let best = self.complete(ray, found);
        match self.nearest_plane(ray, t_max) {
            Some((hit, material)) => Some(SurfaceHit { hit, material, light: None }),
            None => best,
        }
    }

    /// The nearest infinite plane the ray hits before `t_max`, and its material. Planes
    /// are not in the BVH (they have no bounds) nor in `prims`: no index may point there,
    /// so the hit's `prim` is `u32::MAX`.
    #[inline]
    fn nearest_plane(&self, ray: &Ray, mut t_max: f32) -> Option<(Hit, u32)> {
        let mut nearest = None;
        for (plane, material) in &self.world.planes {
            if let Some(mut hit) = plane.intersect(ray, t_max) {
                hit.prim = u32::MAX;
                t_max = hit.t;
                nearest = Some((hit, *material));
            }
        }
        nearest
    }

    /// The nearest hit among the BVH's primitives before `t_max`, not yet completed where
    /// its shape completes it later, and the distance the search ended with.
    #[inline(always)]
    fn search<const ALPHA: bool, const COHERENT: bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        time: f32,
    ) -> (Found, f32) {
        let w = &*self.world;
        let mut search = Search::<ALPHA>::new(w, ray, time);
        let t_max = w.bvh.traverse_leaves::<COHERENT>(ray, t_max, &mut search);
        (search.found, t_max)
    }

    /// The hit `found` names, completed (point, normals, uv).
    #[inline(always)]
    fn complete(&self, ray: &Ray, found: Found) -> Option<SurfaceHit> {
        let w = &*self.world;
        let Found { nearest, mut best } = found;
        let complete = |i: u32, hit: Option<Hit>| {
            let prim = &w.prims[i as usize];
            hit.map(|mut hit| {
                hit.prim = i;
                SurfaceHit { hit, material: prim.material, light: prim.light }
            })
        };
        match nearest {
            Some(Candidate::Triangle(k, t, b1, b2)) => {
                let slot = &w.slots[k];
                let i = slot.index();
                if let Some(material) = slot.plain_material() {
                    // Neither the primitive nor its mesh is read (`triangles`'s comment).
                    best = w.slots.plain_hit(k, t, b1, b2).map(|mut hit| {
                        hit.prim = i;
                        SurfaceHit { hit, material, light: None }
                    });
                } else if let shape::Shape::Triangle { mesh, tri } = w.prims[i as usize].shape {
                    best = complete(i, w.meshes[mesh as usize].hit_at(tri, t, b1, b2));
                }
            }
            Some(Candidate::Rect(i, t, s, tt)) => {
                if let shape::Shape::Rect(r) = &w.prims[i as usize].shape {
                    best = complete(i, Some(r.hit_at(t, s, tt)));
                }
            }
            Some(Candidate::Sphere(i, t)) => {
                if let shape::Shape::Sphere(s) = &w.prims[i as usize].shape {
                    best = complete(i, Some(s.hit_at(ray, t)));
                }
            }
            None => {}
        }
        best
    }

    /// Whether `ray` can find any light: false only when escaping rays see black (no
    /// environment, a black background) and the ray meets none of the scene's few emitting
    /// primitives at any distance. Then the nearest hit of a ray that only looks for light
    /// (a path's last, after a diffuse bounce) adds nothing, whatever it is, and need not be
    /// found. Each emitter is tested as the nearest-hit search tests it, without its alpha
    /// cut-out (a cut-out and a nearer `t_max` only reject more), so `true` whenever that
    /// search could end on an emitter.
    pub fn may_find_light(&self, ray: &Ray, time: f32) -> bool {
        let w = &*self.world;
        let Some(emitters) = &w.emitters else { return true };
        w.environment.is_some()
            || self.background != Vec3::ZERO
            || emitters
                .iter()
                .any(|&i| w.prims[i as usize].is_hit(ray, f32::INFINITY, time, &w.meshes, &w.motions))
    }

    /// Fills in the texture coordinates of a hit where the shape computes them lazily
    /// (spheres: two transcendental functions, paid only by textured materials).
    pub fn complete_uv(&self, sh: &mut SurfaceHit) {
        if let Some(shape::Shape::Sphere(_)) = self.world.prims.get(sh.hit.prim as usize).map(|p| &p.shape) {
            sh.hit.uv = geometry::sphere_uv(sh.hit.n);
        }
    }

    /// The fraction of light that passes from `ray.origin` along `ray.dir` for `dist`:
    /// zero if an opaque surface is in the way, else the product of the transmissions of
    /// the classic-model surfaces crossed (coloured shadows).
    pub fn transmittance(&self, ray: &Ray, dist: f32, time: f32) -> Vec3 {
        self.transmittance_past(ray, dist, time, None)
    }

    /// [`Scene::transmittance`] of a shadow ray towards a point sampled on light `light`.
    /// A light that is one convex primitive cannot block a ray to a point on itself, so
    /// its primitive is passed over. Testing it cost every such ray a test at the end of
    /// its walk (for a sphere light, the f64 roots), and by rounding a grazing ray now and
    /// then met the light's own surface short of the sampled point.
    pub fn shadow(&self, ray: &Ray, dist: f32, time: f32, light: u32) -> Vec3 {
        let own = self.world.lights[light as usize].is_one_convex_primitive().then_some(light);
        self.transmittance_past(ray, dist, time, own)
    }

    fn transmittance_past(&self, ray: &Ray, dist: f32, time: f32, own: Option<u32>) -> Vec3 {
        if self.world.surfaces.any_alpha {
            self.transmittance_with::<true>(ray, dist, time, own)
        } else {
            self.transmittance_with::<false>(ray, dist, time, own)
        }
    }

    /// [`Scene::transmittance`], with crossings of materials with alpha tested when
    /// `ALPHA` (a cut-out crossing is no crossing), and the primitive of light `own`, if
    /// any, passed over.
    fn transmittance_with<const ALPHA: bool>(
        &self,
        ray: &Ray,
        dist: f32,
        time: f32,
        own: Option<u32>,
    ) -> Vec3 {
        let w = &*self.world;
        let mut shadow = Shadow::<ALPHA>::new(w, ray, dist, time, own);
        w.bvh.visit_leaves(ray, dist, &mut shadow);
        let mut passed = shadow.passed;
        if !passed.open {
            return Vec3::ZERO;
        }
        for (plane, material) in &w.planes {
            if plane.intersect(ray, dist).is_some() && !passed.pass(w, *material, false) {
                return Vec3::ZERO;
            }
        }
        passed.tr
    }
}
