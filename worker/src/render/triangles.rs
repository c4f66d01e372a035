//! The BVH's primitives in its leaf order, with static triangles stored inline (their
//! corners, ready for Möller–Trumbore): a leaf's triangles sit next to each other in
//! memory, and a triangle test reads one record instead of following primitive → mesh →
//! index → vertex. A plain triangle (no normals or texture coordinates in its mesh, no
//! emission) also completes its hit from the slot, which holds its material: on a million
//! triangles those three dependent loads were a quarter of a random ray's time
//! (docs/speed.md, "Seventh part"). Everything else (spheres, parallelograms, moving or
//! degenerate triangles) points back to its primitive.

use glam::Vec3;

use super::bvh::Bvh;
use super::geometry::{Hit, Ray};
use super::shape::{moller_trumbore, normal, plain_hit, Mesh, Primitive, Shape};

/// Marks a slot that is not an inline triangle: intersect its primitive.
const GENERIC: u32 = 1 << 31;
/// Marks an inline triangle whose hit the slot completes (see the module's comment).
const PLAIN: u32 = 1 << 30;
/// The primitive's index.
const INDEX: u32 = PLAIN - 1;

/// One BVH slot.
#[derive(Debug, Clone, Copy)]
pub struct Slot {
    /// An inline triangle's corners (the same ones as its mesh's, so the edges Möller–Trumbore
    /// takes are the same differences and the hits the same bits).
    p: [Vec3; 3],
    /// The primitive's index, with [`GENERIC`] set unless the slot is an inline triangle
    /// and [`PLAIN`] set if it is a plain one.
    prim: u32,
    /// The primitive's material, read only for a plain triangle.
    material: u32,
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
            SlotKind::Triangle(self.prim & INDEX)
        } else {
            SlotKind::Generic(self.prim & INDEX)
        }
    }

    /// For an inline triangle: (t, b1, b2) of its hit in (0, t_max), the same bits as
    /// [`Mesh::intersect`] gives.
    #[inline(always)]
    pub fn hit(&self, ray: &Ray, t_max: f32) -> Option<(f32, f32, f32)> {
        let [p0, p1, p2] = self.p;
        moller_trumbore(p0, p1 - p0, p2 - p0, ray, t_max)
    }

    /// The primitive's index.
    #[inline(always)]
    pub fn index(&self) -> u32 {
        self.prim & INDEX
    }

    /// A plain triangle's material; `None` for any other slot.
    #[inline(always)]
    pub fn plain_material(&self) -> Option<u32> {
        (self.prim & (GENERIC | PLAIN) == PLAIN).then_some(self.material)
    }

    /// For a plain triangle: the hit at (t, b1, b2) from [`Slot::hit`], the bits
    /// [`Mesh::hit_at`] gives (inline triangles have finite normals, so it is never `None`
    /// for them).
    #[inline]
    pub fn plain_hit(&self, t: f32, b1: f32, b2: f32) -> Option<Hit> {
        plain_hit(self.p, t, b1, b2)
    }
}

/// The corners of `prim` when its slot holds it inline: a still triangle whose normal is
/// finite (one whose normal is not is never hit: the generic path says so). Everything
/// else is intersected through its primitive.
pub fn inline(prim: &Primitive, meshes: &[Mesh]) -> Option<[Vec3; 3]> {
    let (Shape::Triangle { mesh, tri }, None) = (&prim.shape, prim.motion) else { return None };
    let [p0, p1, p2] = meshes[*mesh as usize].corners(*tri);
    normal(p1 - p0, p2 - p0).map(|_| [p0, p1, p2])
}

/// Whether an inline triangle's hit is completed from its slot: its mesh gives it no
/// normals and no texture coordinates, and it emits no light.
fn plain(prim: &Primitive, meshes: &[Mesh]) -> bool {
    let Shape::Triangle { mesh, tri } = prim.shape else { return false };
    let c = &meshes[mesh as usize].tris[tri as usize];
    prim.light.is_none() && c[0][1] == u32::MAX && c[0][2] == u32::MAX
}

/// The slots of a BVH built over `prims`, in its leaf order (slot k holds primitive
/// `bvh.indices()[k]`).
pub fn slots(bvh: &Bvh, prims: &[Primitive], meshes: &[Mesh]) -> Vec<Slot> {
    use rayon::prelude::*;
    assert!(prims.len() <= INDEX as usize, "more primitives than slots can index");
    // A map in order: the same slots on any number of threads.
    bvh.indices()
        .par_iter()
        .map(|&i| {
            let prim = &prims[i as usize];
            match inline(prim, meshes) {
                Some(p) if plain(prim, meshes) => Slot { p, prim: i | PLAIN, material: prim.material },
                Some(p) => Slot { p, prim: i, material: prim.material },
                None => Slot { p: [Vec3::ZERO; 3], prim: i | GENERIC, material: prim.material },
            }
        })
        .collect()
}

#[cfg(test)]
#[path = "triangles_tests.rs"]
mod tests;
