//! A moving mesh as one object: its triangles in a BVH of their own, in object space, and
//! one box in the scene's tree that holds the mesh over the whole shutter. A ray that
//! enters that box is taken into object space once, at its moment of the shutter, and
//! walks the mesh's tree, testing its triangles four at a time from their packs as a still
//! mesh's are.
//!
//! Before, each moving triangle was a primitive of the scene's tree with a box of its own
//! around its arc, and each test moved the ray into object space and went through the
//! mesh's indices: on the showcase, whose knot turns during the shutter, those tests were
//! a third of the render (docs/speed.md, twenty-eighth part). A triangle's test and the
//! hit it makes are the same operations on the same values as before (the ray moved by
//! the same frames, Möller–Trumbore on the same corners, the hit taken back to world
//! space by [`to_world`]); the order of the tests differs, which chooses among hits at
//! exactly one distance, and so do the boxes that decide which triangles are tested: each
//! triangle's own box in object space, as a still mesh's, where before a box around its
//! whole arc let its test run. A ray that grazes an edge by less than the test's rounding,
//! which the test may still accept, can pass outside the tight box, as with a still mesh.

use super::bvh::{Aabb, Bvh, LeafPolicy};
use super::geometry::{Hit, Ray};
use super::shape::{moller_trumbore, to_object, to_world, Mesh, Primitive, Shape};
use super::transform::Motion;
use super::triangles::{self, Ray4, SlotKind, Slots};

/// A moving mesh's triangles: primitives `first..first + count` of the scene, all of mesh
/// `mesh` with motion `motion` and material `material`.
#[derive(Debug, Clone)]
pub struct Instance {
    /// The mesh.
    pub mesh: u32,
    /// Its motion.
    pub motion: u32,
    /// Its material.
    pub material: u32,
    /// The scene's primitive of the mesh's triangle 0 (triangle t is `first + t`).
    pub first: u32,
    /// The triangles' tree, in object space (its primitive t is triangle t).
    bvh: Bvh,
    /// The tree's slots: its triangles inline, in object space.
    slots: Slots,
}

impl Instance {
    /// The instance of the moving mesh `run` (`moving_meshes` finds them).
    pub fn new(run: &Run, meshes: &[Mesh], motions: &[Motion]) -> Instance {
        let Run { first, mesh, motion, material, .. } = *run;
        // The triangles as still ones: their slots hold them inline, in object space.
        let still: Vec<Primitive> = (0..meshes[mesh as usize].tris.len() as u32)
            .map(|tri| Primitive {
                shape: Shape::Triangle { mesh, tri },
                material,
                light: None,
                motion: None,
            })
            .collect();
        let bounds: Vec<Aabb> = still.iter().map(|s| s.bounds(meshes, motions)).collect();
        let inline = still.iter().filter(|s| triangles::inline(s, meshes).is_some()).count();
        let bvh = Bvh::build_with(&bounds, LeafPolicy::for_scene(inline, still.len() - inline));
        let slots = triangles::slots(&bvh, &still, meshes);
        Instance { mesh, motion, material, first, bvh, slots }
    }

    /// The box that holds the mesh over the whole shutter: its object-space box's bounding
    /// ball, swept (`Motion::swept_ball`).
    pub fn bounds(&self, motions: &[Motion]) -> Aabb {
        let b = self.bvh.bounds();
        motions[self.motion as usize].swept_ball(b.centroid(), (b.max - b.min).length() * 0.5)
    }

    /// The ray in object space at shutter fraction `time`, as `Primitive::intersect`
    /// moves it.
    #[inline]
    fn local(&self, ray: &Ray, time: f32, motions: &[Motion]) -> Ray {
        to_object(ray, &motions[self.motion as usize].frames(time).1)
    }

    /// The nearest hit in (0, t_max) at shutter fraction `time`, in world space, and the
    /// scene's primitive it is on.
    #[inline]
    pub fn intersect(
        &self,
        ray: &Ray,
        t_max: f32,
        time: f32,
        meshes: &[Mesh],
        motions: &[Motion],
    ) -> Option<Hit> {
        let local = self.local(ray, time, motions);
        let mesh = &meshes[self.mesh as usize];
        let r4 = Ray4::new(&local);
        let mut nearest = None;
        self.bvh.traverse_leaves::<false>(&local, t_max, &mut |first, count, mut t_max| {
            self.slots.leaf(first, count, &r4, |k, tri| {
                let slot = &self.slots[k];
                let found = match (slot.kind(), tri) {
                    (SlotKind::Triangle(t), Some((d, b1, b2))) => (d < t_max).then_some((t, d, b1, b2)),
                    // A degenerate triangle: its own test says it is never hit, as
                    // `Mesh::intersect` would.
                    (SlotKind::Generic(t), _) => {
                        let [p0, p1, p2] = mesh.corners(t);
                        moller_trumbore(p0, p1 - p0, p2 - p0, &local, t_max)
                            .filter(|&(d, b1, b2)| mesh.hit_at(t, d, b1, b2).is_some())
                            .map(|(d, b1, b2)| (t, d, b1, b2))
                    }
                    _ => None,
                };
                if let Some(f) = found {
                    t_max = f.1;
                    nearest = Some(f);
                }
                true
            });
            t_max
        });
        let (tri, t, b1, b2) = nearest?;
        let (world_from_object, _) = motions[self.motion as usize].frames(time);
        let mut hit = to_world(&mesh.hit_at(tri, t, b1, b2)?, &world_from_object);
        hit.prim = self.first + tri;
        Some(hit)
    }

    /// How many of its triangles the segment (0, dist) crosses at shutter fraction `time`,
    /// counting no further than `enough`.
    #[inline]
    pub fn crossings(
        &self,
        ray: &Ray,
        dist: f32,
        time: f32,
        enough: u32,
        meshes: &[Mesh],
        motions: &[Motion],
    ) -> u32 {
        let local = self.local(ray, time, motions);
        let mesh = &meshes[self.mesh as usize];
        let r4 = Ray4::new(&local);
        let mut crossed = 0;
        self.bvh.visit_leaves(&local, dist, &mut |first, count| {
            self.slots.leaf(first, count, &r4, |k, tri| {
                let hit = match (self.slots[k].kind(), tri) {
                    (SlotKind::Triangle(_), Some((d, ..))) => d < dist,
                    // A degenerate triangle, by its own test (`Mesh::intersect`).
                    (SlotKind::Generic(t), _) => mesh.intersect(t, &local, dist).is_some(),
                    _ => false,
                };
                crossed += u32::from(hit);
                crossed < enough
            })
        });
        crossed
    }

    /// The bytes of its tree and slots.
    pub fn bytes(&self) -> usize {
        self.bvh.bytes() + self.slots.len() * Slots::BYTES_PER_SLOT
    }
}

/// A moving mesh's triangles among the scene's primitives: `first..first + count`, its
/// triangles 0..count in order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Run {
    /// The primitive of triangle 0.
    pub first: u32,
    /// Its triangles.
    pub count: u32,
    /// The mesh.
    pub mesh: u32,
    /// Its motion.
    pub motion: u32,
    /// Its material.
    pub material: u32,
}

/// The fewest triangles a moving mesh needs to be an instance. An instance's tree, slots
/// and record take about half a kilobyte whatever its size, which the memory estimate
/// (`tessera_description::summary`, per primitive) does not count: a scene of many moving
/// `[[triangle]]`s, each a mesh of one, would outgrow its estimate, and a tree over a few
/// triangles spares nothing.
pub const MIN_TRIANGLES: u32 = 64;

/// The moving meshes among `prims` that can be instances: runs of one mesh's triangles
/// 0..n in order (at least [`MIN_TRIANGLES`]) with one motion, emitting nothing, of a
/// material that `alpha` does not say cuts out hits (a cut-out is decided triangle by
/// triangle, through its primitive).
pub fn moving_meshes(prims: &[Primitive], meshes: &[Mesh], alpha: &[bool]) -> Vec<Run> {
    let mut runs = Vec::new();
    let mut i = 0;
    while i < prims.len() {
        let p = &prims[i];
        let run = match (&p.shape, p.motion) {
            (Shape::Triangle { mesh, tri: 0 }, Some(motion))
                if p.light.is_none() && !alpha[p.material as usize] =>
            {
                let count = meshes[*mesh as usize].tris.len() as u32;
                Some(Run { first: i as u32, count, mesh: *mesh, motion, material: p.material })
            }
            _ => None,
        };
        let whole = run.filter(|r| {
            prims.get(i..i + r.count as usize).is_some_and(|triangles| {
                triangles.iter().enumerate().all(|(t, q)| {
                    matches!(q.shape, Shape::Triangle { mesh, tri } if mesh == r.mesh && tri as usize == t)
                        && q.motion == Some(r.motion)
                        && q.material == r.material
                        && q.light.is_none()
                })
            })
        });
        match whole {
            Some(r) if r.count >= MIN_TRIANGLES => {
                runs.push(r);
                i += r.count as usize;
            }
            _ => i += 1,
        }
    }
    runs
}

#[cfg(test)]
#[path = "instance_tests.rs"]
mod tests;
