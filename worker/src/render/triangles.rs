//! The BVH's primitives in its leaf order, with static triangles stored inline (their
//! corners, ready for Möller–Trumbore): a leaf's triangles sit next to each other in
//! memory, and a triangle test reads them instead of following primitive → mesh → index →
//! vertex. The corners are kept four slots to a [`Pack`], lane by lane, so that a leaf's
//! triangles are tested at once: Möller–Trumbore in four SIMD lanes, the scalar test's
//! operations lane for lane (the same bits), then each lane's distance compared in slot
//! order with the `t_max` the slots before it left, as one test after another would
//! (docs/speed.md, sixteenth part). A plain triangle (no normals or texture coordinates in
//! its mesh, no emission) also completes its hit from its slot, which holds its material:
//! on a million triangles those three dependent loads were a quarter of a random ray's time
//! (docs/speed.md, "Seventh part"). A moving mesh is one slot, its instance
//! (`instance.rs`). Everything else (spheres, parallelograms, degenerate triangles, the
//! triangles of a moving mesh that cannot be an instance) points back to its primitive.

use glam::{Vec3, Vec4};

use super::bvh::Bvh;
use super::geometry::{Hit, Ray};
use super::shape::{moller_trumbore, normal, plain_hit, Mesh, Primitive, Shape};

/// Marks a slot that is not an inline triangle: intersect its primitive.
const GENERIC: u32 = 1 << 31;
/// Marks an inline triangle whose hit the slot completes (see the module's comment);
/// with [`GENERIC`], a moving mesh's instance.
const PLAIN: u32 = 1 << 30;
/// The primitive's index.
const INDEX: u32 = PLAIN - 1;

/// One BVH slot; an inline triangle's corners are in its [`Pack`].
#[derive(Debug, Clone, Copy)]
pub struct Slot {
    /// The primitive's index, with [`GENERIC`] set unless the slot is an inline triangle
    /// and [`PLAIN`] set if it is a plain one; both set: an instance's index.
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
    /// Moving mesh `.0` (`World::instances`), to intersect through its own tree.
    Instance(u32),
}

impl Slot {
    /// What the slot holds.
    #[inline(always)]
    pub fn kind(&self) -> SlotKind {
        if self.prim & GENERIC == 0 {
            SlotKind::Triangle(self.prim & INDEX)
        } else if self.prim & PLAIN == 0 {
            SlotKind::Generic(self.prim & INDEX)
        } else {
            SlotKind::Instance(self.prim & INDEX)
        }
    }

    /// The primitive's index (the instance's, for [`SlotKind::Instance`]).
    #[inline(always)]
    pub fn index(&self) -> u32 {
        self.prim & INDEX
    }

    /// A plain triangle's material; `None` for any other slot.
    #[inline(always)]
    pub fn plain_material(&self) -> Option<u32> {
        (self.prim & (GENERIC | PLAIN) == PLAIN).then_some(self.material)
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

/// Four consecutive slots (slot 4j + l in lane l of pack j) and their triangle corners,
/// lane by lane: corner, axis, lane. A slot that is not an inline triangle has NaN
/// corners, which no ray hits and which mark it for its leaf's walk ([`Slots::leaf`]); a
/// lane past the last slot, or of the padding between leaves (`bvh::PADDING`), has zeros,
/// and is never in a leaf.
///
/// The slots sit in the corners' third cache line, which the leaf's test has just read:
/// in an array of their own, the nearest hit's slot (its primitive, its material) was
/// one more load that missed the cache on a million triangles, 9 % of a random ray's time
/// on the terrain. Three lines a pack either way (144 bytes at 16-byte alignment always
/// spanned three); a slot takes 48 bytes instead of 44 (docs/speed.md, forty-second part).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
pub struct Pack {
    p: [[Vec4; 3]; 3],
    slots: [Slot; 4],
}

const _: () = assert!(std::mem::size_of::<Pack>() == 192);

/// A ray's origin and direction splatted over four lanes, for [`Slots::leaf`].
pub struct Ray4 {
    o: [Vec4; 3],
    d: [Vec4; 3],
}

impl Ray4 {
    /// The ray in every lane.
    #[inline(always)]
    pub fn new(ray: &Ray) -> Ray4 {
        let (o, d) = (ray.origin, ray.dir);
        Ray4 {
            o: [Vec4::splat(o.x), Vec4::splat(o.y), Vec4::splat(o.z)],
            d: [Vec4::splat(d.x), Vec4::splat(d.y), Vec4::splat(d.z)],
        }
    }
}

/// glam's `Vec3::cross`, lane by lane: the same products and differences in the same order.
#[inline(always)]
fn cross4(a: [Vec4; 3], b: [Vec4; 3]) -> [Vec4; 3] {
    [a[1] * b[2] - b[1] * a[2], a[2] * b[0] - b[2] * a[0], a[0] * b[1] - b[0] * a[1]]
}

/// glam's `Vec3::dot`, lane by lane: (x + y) + z.
#[inline(always)]
fn dot4(a: [Vec4; 3], b: [Vec4; 3]) -> Vec4 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Pack {
    /// A pack before its lanes are filled: what the lanes of padding (`bvh::PADDING`) and
    /// those past the last slot keep, never visited.
    const EMPTY: Pack =
        Pack { p: [[Vec4::ZERO; 3]; 3], slots: [Slot { prim: INDEX | GENERIC, material: 0 }; 4] };

    /// [`moller_trumbore`] in four lanes without its last comparison (`t < t_max`, which
    /// the caller makes in slot order): bit l set where lane l's line meets its triangle at
    /// t > 0, and t, b1, b2. Every operation is the scalar test's, lane for lane, with the
    /// same operands (`leaf_tests_give_each_slot_s_bits`).
    #[inline(always)]
    fn hit(&self, r: &Ray4) -> (u32, Vec4, Vec4, Vec4) {
        let [p0, p1, p2] = self.p;
        let sub = |a: [Vec4; 3], b: [Vec4; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let (e1, e2) = (sub(p1, p0), sub(p2, p0));
        let pv = cross4(r.d, e2);
        let det = dot4(e1, pv);
        let inv = Vec4::ONE / det;
        let tv = sub(r.o, p0);
        let b1 = dot4(tv, pv) * inv;
        let qv = cross4(tv, e1);
        let b2 = dot4(r.d, qv) * inv;
        let t = dot4(e2, qv) * inv;
        // The scalar test's rejections, negated: NaN fails each as it fails there.
        let ok = det.cmpne(Vec4::ZERO)
            & det.is_finite_mask()
            & b1.cmpge(Vec4::ZERO)
            & b1.cmple(Vec4::ONE)
            & !b2.cmplt(Vec4::ZERO)
            & !(b1 + b2).cmpgt(Vec4::ONE)
            & t.cmpgt(Vec4::ZERO);
        (ok.bitmask(), t, b1, b2)
    }
}

/// The BVH's slots and their triangles' corners.
#[derive(Debug, Clone, Default)]
pub struct Slots {
    packs: Vec<Pack>,
    /// How many slots: the BVH's leaf order, of which the last pack may hold fewer than four.
    len: usize,
    /// Some slot is an inline triangle: leaves are tested pack by pack.
    any_inline: bool,
    /// Some inline triangle emits light.
    any_inline_emitter: bool,
}

impl std::ops::Index<usize> for Slots {
    type Output = Slot;

    #[inline(always)]
    fn index(&self, k: usize) -> &Slot {
        // The bound the slots' own array had: the last pack's lanes past `len` are not slots.
        assert!(k < self.len, "slot {k} of {}", self.len);
        &self.packs[k / 4].slots[k % 4]
    }
}

impl Slots {
    /// Bytes a slot takes: a quarter of a pack.
    pub const BYTES_PER_SLOT: usize = std::mem::size_of::<Pack>() / 4;

    /// The slots.
    pub fn iter(&self) -> impl Iterator<Item = &Slot> {
        self.packs.iter().flat_map(|p| &p.slots).take(self.len)
    }

    /// How many.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// `ray` in four lanes for [`Slots::leaf`], where leaves are tested pack by pack: some
    /// slot is an inline triangle and, without `ALPHA` (no material cuts out hits), no
    /// triangle's hit needs a test of its own. Made for every search without a check, it
    /// was 1 % of `spheres`' instructions.
    #[inline(always)]
    pub fn ray4<const ALPHA: bool>(&self, ray: &Ray) -> Option<Ray4> {
        (!ALPHA && self.any_inline).then(|| Ray4::new(ray))
    }

    /// Whether some inline triangle emits light: where none does, a ray that only looks
    /// for light and ends on one need not read its slot (`Scene::seen`).
    #[inline(always)]
    pub fn any_inline_emitter(&self) -> bool {
        self.any_inline_emitter
    }

    /// Slot `k`'s corners (NaN for a slot that is not an inline triangle, zeros for
    /// padding).
    #[inline(always)]
    fn corners(&self, k: usize) -> [Vec3; 3] {
        let (p, l) = (&self.packs[k / 4].p, k % 4);
        p.map(|c| Vec3::new(c[0][l], c[1][l], c[2][l]))
    }

    /// For an inline triangle in slot `k`: (t, b1, b2) of its hit in (0, t_max), the same
    /// bits as [`Mesh::intersect`] gives.
    #[inline(always)]
    pub fn hit(&self, k: usize, ray: &Ray, t_max: f32) -> Option<(f32, f32, f32)> {
        let [p0, p1, p2] = self.corners(k);
        moller_trumbore(p0, p1 - p0, p2 - p0, ray, t_max)
    }

    /// Walks the leaf `first..first + count` (at most eight slots, so at most three
    /// packs), each pack's triangles tested at once: calls `f(slot, hit)` in slot order for
    /// each slot that needs a look, an inline triangle its line meets at t > 0 with
    /// `Some((t, b1, b2))` ([`Slots::hit`]'s bits but the last comparison with `t_max`, which
    /// is the caller's) and a slot that is not an inline triangle with `None`, until `f`
    /// returns false; returns whether the walk went through. A pack's test does not depend
    /// on `t_max`, so testing the next pack after the slots before it have been looked at
    /// gives what testing them all first would. Nothing is gathered into a record: a
    /// leaf's hits returned as one (three arrays of twelve) were copied by `memcpy` on every
    /// leaf, 3 % of a random ray's instructions on the torus knot (callgrind, 2026-12-05).
    #[inline(always)]
    pub fn leaf(
        &self,
        first: usize,
        count: usize,
        r: &Ray4,
        mut f: impl FnMut(usize, Option<(f32, f32, f32)>) -> bool,
    ) -> bool {
        let end = first + count;
        let mut base = first & !3;
        while base < end {
            let pack = &self.packs[base / 4];
            let (hit, t, b1, b2) = pack.hit(r);
            let generic = pack.p[0][0].is_nan_mask().bitmask();
            // The pack's lanes that are in the leaf.
            let window = ((1u32 << (end - base).min(4)) - 1) & !((1u32 << first.saturating_sub(base)) - 1);
            let mut look = (hit | generic) & window;
            if look != 0 {
                let (t, b1, b2) = (t.to_array(), b1.to_array(), b2.to_array());
                while look != 0 {
                    let l = look.trailing_zeros() as usize;
                    look &= look - 1;
                    if !f(base + l, (generic >> l & 1 == 0).then(|| (t[l], b1[l], b2[l]))) {
                        return false;
                    }
                }
            }
            base += 4;
        }
        true
    }

    /// For a plain triangle in slot `k`: the hit at (t, b1, b2) from [`Slots::hit`], the
    /// bits [`Mesh::hit_at`] gives (inline triangles have finite normals, so it is never
    /// `None` for them).
    #[inline]
    pub fn plain_hit(&self, k: usize, t: f32, b1: f32, b2: f32) -> Option<Hit> {
        plain_hit(self.corners(k), t, b1, b2)
    }
}

/// The slots of a BVH built over `prims`, in its leaf order (slot k holds primitive
/// `bvh.indices()[k]`, or nothing where that is `bvh::PADDING`, or instance i where it is
/// `prims.len() + i`).
pub fn slots(bvh: &Bvh, prims: &[Primitive], meshes: &[Mesh]) -> Slots {
    use rayon::prelude::*;
    assert!(prims.len() <= INDEX as usize, "more primitives than slots can index");
    let indices = bvh.indices();
    // A pack's four slots and their corners in one pass, each primitive's corners found
    // once (and whether one of them is an emitting inline triangle, read from the
    // primitive in hand rather than by a second pass over the slots); maps in order: the
    // same slots on any number of threads.
    let (packs, emits): (Vec<Pack>, Vec<bool>) = indices
        .par_chunks(4)
        .map(|four| {
            let mut pack = Pack::EMPTY;
            let slots = &mut pack.slots;
            let mut emits = false;
            for (l, &i) in four.iter().enumerate() {
                let Some(prim) = prims.get(i as usize) else {
                    if i != super::bvh::PADDING {
                        // An instance: NaN corners mark its lane for the leaf's walk as
                        // a slot that is not an inline triangle (padding keeps zeros).
                        slots[l] = Slot { prim: (i - prims.len() as u32) | GENERIC | PLAIN, material: 0 };
                        for c in 0..3 {
                            for a in 0..3 {
                                pack.p[c][a][l] = f32::NAN;
                            }
                        }
                    }
                    continue;
                };
                let corners = inline(prim, meshes);
                emits |= corners.is_some() && prim.light.is_some();
                slots[l] = match corners {
                    Some(_) if plain(prim, meshes) => Slot { prim: i | PLAIN, material: prim.material },
                    Some(_) => Slot { prim: i, material: prim.material },
                    None => Slot { prim: i | GENERIC, material: prim.material },
                };
                // A slot that is not an inline triangle is marked by NaN corners.
                for (c, p) in corners.unwrap_or([Vec3::NAN; 3]).iter().enumerate() {
                    for a in 0..3 {
                        pack.p[c][a][l] = p[a];
                    }
                }
            }
            (pack, emits)
        })
        .unzip();
    let any_inline_emitter = emits.into_iter().any(|e| e);
    // Lanes past the last slot are GENERIC, so the whole last pack may be asked.
    let any_inline = packs.par_iter().any(|p| p.slots.iter().any(|s| s.prim & GENERIC == 0));
    Slots { packs, len: indices.len(), any_inline, any_inline_emitter }
}

#[cfg(test)]
#[path = "triangles_tests.rs"]
mod tests;
