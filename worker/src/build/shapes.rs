//! Primitives, meshes, motions and area lights, from the described objects, in their order.

use std::collections::HashMap;
use std::sync::Arc;

use glam::Vec3;
use tessera_description::bundle::Assets;
use tessera_description::model::{box_faces, placed_rect, Location, Object, Shape as S};
use tessera_description::obj::{parse_obj, ObjMesh};
use tessera_description::SceneError;

use crate::render::geometry::Sphere;
use crate::render::light::{Light, MeshLight};
use crate::render::shape::{Mesh, Primitive, Rect, Shape};
use crate::render::surface::Extras;
use crate::render::transform::{Motion, Trs};

/// How many of `objects` use the mesh file `f`.
fn uses(objects: &[Object], f: &str) -> usize {
    objects.iter().filter(|o| matches!(&o.shape, S::Mesh { file, .. } if file == f)).count()
}

/// The error for geometry that a transform overflowed.
const NOT_FINITE: &str = "the transformed geometry overflows to non-finite coordinates";

/// What the objects make, in the order the renderer indexes it.
#[derive(Default)]
pub(super) struct Shapes {
    pub(super) prims: Vec<Primitive>,
    pub(super) meshes: Vec<Mesh>,
    pub(super) motions: Vec<Motion>,
    pub(super) lights: Vec<Light>,
    /// Meshes read and still to be used again, by asset, with the uses left: a mesh used
    /// again is copied, not parsed again, and dropped at its last use.
    read: HashMap<String, (ObjMesh, usize)>,
    /// The glTF files read, each once.
    pub(super) gltf: super::gltf::Files,
    /// Extra vertex attributes of glTF meshes, by mesh index.
    pub(super) extras: HashMap<u32, Extras>,
}

impl Shapes {
    /// Shapes to be made with `meshes` (by asset path) already parsed, for `objects`.
    pub(super) fn with_meshes(meshes: impl Iterator<Item = (String, ObjMesh)>, objects: &[Object]) -> Shapes {
        let mut read = HashMap::new();
        for (file, mesh) in meshes {
            let uses = uses(objects, &file);
            if uses > 0 {
                read.insert(file, (mesh, uses));
            }
        }
        Shapes { read, ..Shapes::default() }
    }

    /// Adds the primitives of `o`, one of `objects`.
    pub(super) fn object(
        &mut self,
        o: &Object,
        objects: &[Object],
        assets: &dyn Assets,
        err: &dyn Fn(Location, String) -> SceneError,
        mark: &mut dyn FnMut(super::Phase),
    ) -> Result<(), SceneError> {
        let trs = o.transform;
        let motion = o.motion.map(|end| {
            self.motions.push(Motion::new(trs, end));
            self.motions.len() as u32 - 1
        });
        match &o.shape {
            S::Sphere { center, radius } => {
                let shape = match motion {
                    Some(_) => Sphere::new(*center, *radius),
                    None => Sphere::new(trs.matrix().transform_point3(*center), radius * trs.scale.abs().x),
                };
                if !(shape.center.is_finite() && shape.radius.is_finite()) {
                    return Err(err(o.at, NOT_FINITE.into()));
                }
                let light = o.emission.map(|radiance| {
                    self.lights.push(Light::Sphere { sphere: shape.clone(), radiance });
                    self.lights.len() as u32 - 1
                });
                self.push(Shape::Sphere(shape), o.material, light, motion);
            }
            S::Rectangle { center, u, v } => self.rect((*center, *u, *v), o, &trs, motion),
            S::Box { min, max } => {
                for face in box_faces(*min, *max) {
                    self.rect(face, o, &trs, motion);
                }
            }
            S::Triangle { vertices } => {
                let mesh = Mesh {
                    p: vertices.to_vec(),
                    tris: vec![[[0, u32::MAX, u32::MAX], [1, u32::MAX, u32::MAX], [2, u32::MAX, u32::MAX]]],
                    ..Mesh::default()
                };
                self.mesh(mesh, o, &trs, motion, err)?;
            }
            S::Mesh { file, .. } => {
                if !self.read.contains_key(file) {
                    // Validation read this asset; a bundle that changed since is caught here.
                    let text =
                        assets.get(file).and_then(|b| std::str::from_utf8(b).ok()).ok_or_else(|| {
                            err(
                                o.at,
                                format!("mesh.file: cannot read {file:?} (relative to the scene's folder)"),
                            )
                        })?;
                    mark(super::Phase::Primitives);
                    let m = parse_obj(text).map_err(|e| err(o.at, format!("mesh {file:?}: {e}")))?;
                    mark(super::Phase::ReadObj);
                    self.read.insert(file.clone(), (m, uses(objects, file)));
                }
                // Each use is its own copy: a static one is baked into world space.
                let (_, left) = self.read.get_mut(file).expect("read above");
                *left -= 1;
                let m = if *left == 0 {
                    self.read.remove(file).expect("read above").0
                } else {
                    self.read[file].0.clone()
                };
                let mesh = Mesh { p: m.p, n: m.n, uv: m.uv, tris: m.tris };
                self.mesh(mesh, o, &trs, motion, err)?;
            }
            S::GltfPrimitive { file, mesh, primitive, .. } => {
                let (mesh, mut extras) = self
                    .gltf
                    .get(file, assets)
                    .and_then(|a| super::gltf::primitive(a, *mesh, *primitive))
                    .map_err(|e| err(o.at, e))?;
                if let Some(x) = extras.as_mut().filter(|_| motion.is_none() && !trs.is_identity()) {
                    // Baked like the positions; a mirroring transform flips the handedness.
                    let m = trs.matrix();
                    let flip = if m.matrix3.determinant() < 0.0 { -1.0 } else { 1.0 };
                    for t in &mut x.tangents {
                        let v = m.transform_vector3(t.truncate()).normalize_or_zero();
                        *t = v.extend(t.w * flip);
                    }
                }
                if let Some(x) = extras {
                    self.extras.insert(self.meshes.len() as u32, x);
                }
                self.mesh(mesh, o, &trs, motion, err)?;
            }
        }
        Ok(())
    }

    fn push(&mut self, shape: Shape, material: u32, light: Option<u32>, motion: Option<u32>) {
        self.prims.push(Primitive { shape, material, light, motion });
    }

    /// A parallelogram `(c, u, v)` of object `o` (validated: its edges span, it does not
    /// both emit and move).
    fn rect(&mut self, rect: (Vec3, Vec3, Vec3), o: &Object, trs: &Trs, motion: Option<u32>) {
        let (c, u, v) = placed_rect(rect, trs, motion.is_some());
        let rect = Rect::new(c, u, v);
        let light = o.emission.map(|radiance| {
            self.lights.push(Light::Rect { rect: rect.clone(), radiance });
            self.lights.len() as u32 - 1
        });
        self.push(Shape::Rect(Box::new(rect)), o.material, light, motion);
    }

    /// Adds a mesh of object `o`, baked into world space unless it moves.
    fn mesh(
        &mut self,
        mut mesh: Mesh,
        o: &Object,
        trs: &Trs,
        motion: Option<u32>,
        err: &dyn Fn(Location, String) -> SceneError,
    ) -> Result<(), SceneError> {
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
        // Validation bounds where a transform takes an object; this catches any geometry
        // that still overflowed, which would otherwise never be hit and vanish silently.
        if !mesh.p.iter().all(|p| p.is_finite()) {
            return Err(err(o.at, NOT_FINITE.into()));
        }
        let index = self.meshes.len() as u32;
        // An emitting mesh is one light over all its triangles (validation keeps it still,
        // so it is in world space here).
        let light = match o.emission {
            Some(radiance) if motion.is_none() => {
                let tris = (0..mesh.tris.len() as u32).map(|t| mesh.corners(t)).collect();
                MeshLight::new(tris, radiance).map(|m| {
                    self.lights.push(Light::Mesh(Arc::new(m)));
                    self.lights.len() as u32 - 1
                })
            }
            _ => None,
        };
        self.prims.reserve(mesh.tris.len());
        for tri in 0..mesh.tris.len() as u32 {
            self.push(Shape::Triangle { mesh: index, tri }, o.material, light, motion);
        }
        self.meshes.push(mesh);
        Ok(())
    }
}
