//! The BVH's primitives in its leaf order, with static triangles stored inline (first
//! corner and both edges, ready for Möller–Trumbore): a leaf's triangles sit next to each
//! other in memory, and a triangle test reads one record instead of following primitive →
//! mesh → index → vertex. Everything else (spheres, parallelograms, moving or degenerate
//! triangles) points back to its primitive.

use glam::Vec3;

use super::bvh::Bvh;
use super::geometry::Ray;
use super::shape::{moller_trumbore, normal, Mesh, Primitive, Shape};

/// Marks a slot that is not an inline triangle: intersect its primitive.
const GENERIC: u32 = 1 << 31;

/// One BVH slot.
#[derive(Debug, Clone, Copy)]
pub struct Slot {
    p0: Vec3,
    e1: Vec3,
    e2: Vec3,
    /// The primitive's index, with [`GENERIC`] set unless the slot is an inline triangle.
    prim: u32,
}

/// What a slot holds.
pub enum SlotKind {
    /// An inline triangle of primitive `.0`.
    Triangle(u32),
    /// Primitive `.0`, to intersect through [`Primitive::intersect`].
    Generic(u32),
}

impl Slot {
    /// What the slot holds.
    #[inline(always)]
    pub fn kind(&self) -> SlotKind {
        if self.prim & GENERIC == 0 {
            SlotKind::Triangle(self.prim)
        } else {
            SlotKind::Generic(self.prim & !GENERIC)
        }
    }

    /// For an inline triangle: (t, b1, b2) of its hit in (0, t_max), the same bits as
    /// [`Mesh::intersect`] gives.
    #[inline(always)]
    pub fn hit(&self, ray: &Ray, t_max: f32) -> Option<(f32, f32, f32)> {
        moller_trumbore(self.p0, self.e1, self.e2, ray, t_max)
    }
}

/// The first corner and both edges of `prim` when its slot holds it inline: a still
/// triangle whose normal is finite (one whose normal is not is never hit: the generic
/// path says so). Everything else is intersected through its primitive.
pub fn inline(prim: &Primitive, meshes: &[Mesh]) -> Option<(Vec3, Vec3, Vec3)> {
    let (Shape::Triangle { mesh, tri }, None) = (&prim.shape, prim.motion) else { return None };
    let [p0, p1, p2] = meshes[*mesh as usize].corners(*tri);
    let (e1, e2) = (p1 - p0, p2 - p0);
    normal(e1, e2).map(|_| (p0, e1, e2))
}

/// The slots of a BVH built over `prims`, in its leaf order (slot k holds primitive
/// `bvh.indices()[k]`).
pub fn slots(bvh: &Bvh, prims: &[Primitive], meshes: &[Mesh]) -> Vec<Slot> {
    use rayon::prelude::*;
    assert!(prims.len() < GENERIC as usize, "more primitives than slots can index");
    // A map in order: the same slots on any number of threads.
    bvh.indices()
        .par_iter()
        .map(|&i| match inline(&prims[i as usize], meshes) {
            Some((p0, e1, e2)) => Slot { p0, e1, e2, prim: i },
            None => Slot { p0: Vec3::ZERO, e1: Vec3::ZERO, e2: Vec3::ZERO, prim: i | GENERIC },
        })
        .collect()
}

#[cfg(test)]
#[path = "triangles_tests.rs"]
mod tests;
