//! A shadow ray's visit of each leaf the any-hit walk enters ([`Scene::transmittance`]'s):
//! the leaf's triangles four at a time, its other slots one by one, multiplying the
//! transmissions of the surfaces crossed until the light is blocked.
//!
//! A struct whose visit is `#[inline(always)]` rather than a closure, for the reason of
//! `search.rs`: compiled into the walk, with the crossing of an inline triangle in a scene
//! whose surfaces all stop light (the common shadow ray's end) decided there, and the rest
//! out of line.

use glam::Vec3;

use super::bvh::{LeftOut, Visits};
use super::geometry::Ray;
use super::{triangles, World};

/// A shadow ray's state: the ray, the light it lets through so far, and whether it still
/// does.
pub(super) struct Shadow<'a, const ALPHA: bool> {
    along: Along<'a>,
    /// The ray in four lanes, where the scene has inline triangles to test at once.
    r4: Option<triangles::Ray4>,
    /// The leaf of the light's primitive that [`Along::cross`] passes over, where it holds
    /// nothing else.
    own_leaf: LeftOut,
    pub(super) passed: Passed,
}

/// The ray and what it is tested against.
struct Along<'a> {
    w: &'a World,
    ray: &'a Ray,
    dist: f32,
    time: f32,
    /// The light whose primitive is passed over, if any.
    own: Option<u32>,
}

/// The light a shadow ray lets through so far.
pub(super) struct Passed {
    /// The product of the transmissions crossed.
    pub(super) tr: Vec3,
    /// False once the light is blocked.
    pub(super) open: bool,
}

impl<'a, const ALPHA: bool> Shadow<'a, ALPHA> {
    /// A shadow ray along `ray` for `dist` at `time`, passing over light `own`'s primitive.
    pub(super) fn new(w: &'a World, ray: &'a Ray, dist: f32, time: f32, own: Option<u32>) -> Self {
        let r4 = w.slots.ray4::<ALPHA>(ray);
        let own_leaf = own.map_or(LeftOut::NONE, |l| w.own_leaves[l as usize]);
        let passed = Passed { tr: Vec3::ONE, open: true };
        Shadow { along: Along { w, ray, dist, time, own }, r4, own_leaf, passed }
    }
}

impl Passed {
    /// Crosses a surface of `material` of `w`; returns whether light still passes. An
    /// emitter's own surface does not shadow the light it sends.
    #[inline]
    pub(super) fn pass(&mut self, w: &World, material: u32, emitter: bool) -> bool {
        self.tr *= if emitter { Vec3::ZERO } else { w.materials[material as usize].shadow_transmission() };
        self.tr != Vec3::ZERO
    }
}

impl Along<'_> {
    /// [`Along::cross`] out of line: the walk the leaf's visit is inlined into stays
    /// small where an opaque scene's triangles end the visit without it.
    #[inline(never)]
    fn cross_out_of_line<const ALPHA: bool>(
        &self,
        p: &mut Passed,
        k: usize,
        tri: Option<(f32, f32, f32)>,
    ) -> bool {
        self.cross::<ALPHA>(p, k, tri)
    }

    /// Slot k's crossings, given its triangle's hit when it holds one; false ends the
    /// walk (the light is blocked). An opaque scene's crossed inline triangle has been
    /// taken before ([`Shadow`]'s visit): without alpha, a slot that holds a triangle is
    /// one of the inline triangles that only that visit tests.
    #[inline(always)]
    fn cross<const ALPHA: bool>(&self, p: &mut Passed, k: usize, tri_hit: Option<(f32, f32, f32)>) -> bool {
        let (w, ray, dist, time) = (self.w, self.ray, self.dist, self.time);
        let (i, crossings) = match w.slots[k].kind() {
            triangles::SlotKind::Triangle(i) => {
                let hit = match tri_hit {
                    Some((_, b1, b2)) if ALPHA => w.covers_slot(i, b1, b2, ray),
                    hit => hit.is_some(),
                };
                if !hit {
                    // Nothing crossed (`open` is true while the visit goes on).
                    return true;
                }
                if let Some(material) = w.slots[k].plain_material() {
                    // No light, and the material from the slot: the primitive is not read.
                    p.open = p.pass(w, material, false);
                    return p.open;
                }
                (i, 1)
            }
            triangles::SlotKind::Instance(j) => {
                let inst = &w.instances[j as usize];
                let material = &w.materials[inst.material as usize];
                // Past an opaque surface's first crossing the rest change nothing.
                let enough = if material.shadow_transmission() == Vec3::ZERO { 1 } else { u32::MAX };
                (inst.first, inst.crossings(ray, dist, time, enough, &w.meshes, &w.motions))
            }
            triangles::SlotKind::Generic(i) => {
                let prim = &w.prims[i as usize];
                // Validation keeps lights still; were one to move, its samples would
                // not lie on the primitive, so only a still one is passed over.
                if self.own.is_some() && prim.light == self.own && prim.motion.is_none() {
                    return true;
                }
                if ALPHA && w.surfaces.alpha[prim.material as usize] {
                    // A triangle, crossed at most once.
                    let hit = prim.intersect(ray, dist, time, &w.meshes, &w.motions);
                    (i, u32::from(hit.is_some_and(|h| w.covers_hit(i, h.p, h.uv, ray, time))))
                } else {
                    (i, prim.crossings(ray, dist, time, &w.meshes, &w.motions))
                }
            }
        };
        let prim = &w.prims[i as usize];
        for _ in 0..crossings {
            p.open = p.pass(w, prim.material, prim.light.is_some());
            if !p.open {
                break;
            }
        }
        p.open
    }

    /// A leaf without inline triangles, its slots one by one, out of line: one call a leaf,
    /// as when the visit was a closure.
    #[inline(never)]
    fn slots_out_of_line<const ALPHA: bool>(&self, p: &mut Passed, first: usize, count: usize) -> bool {
        let (w, ray, dist) = (self.w, self.ray, self.dist);
        (first..first + count).all(|k| {
            let hit = match w.slots[k].kind() {
                triangles::SlotKind::Triangle(_) => w.slots.hit(k, ray, dist),
                triangles::SlotKind::Generic(_) | triangles::SlotKind::Instance(_) => None,
            };
            self.cross::<ALPHA>(p, k, hit)
        })
    }
}

impl<const ALPHA: bool> Visits for Shadow<'_, ALPHA> {
    #[inline(always)]
    fn visit(&mut self, first: usize, count: usize) -> bool {
        let Shadow { along, r4, passed, .. } = self;
        let Some(r4) = r4 else { return along.slots_out_of_line::<ALPHA>(passed, first, count) };
        // The leaf's triangles tested at once; those crossed are taken in slot order with
        // the other slots.
        let (w, dist) = (along.w, along.dist);
        w.slots.leaf(first, count, r4, |k, tri| {
            let tri = tri.filter(|h| h.0 < dist);
            if !ALPHA && w.surfaces.opaque && tri.is_some() {
                // A triangle crossed, in a scene where every surface stops light: blocked,
                // without reading the slot (on a million triangles, a load that misses the
                // cache for most of the rays that end here). Decided here only, inside the
                // walk: without alpha, only this visit hands `Along::cross` a triangle's hit.
                passed.open = false;
                return false;
            }
            along.cross_out_of_line::<ALPHA>(passed, k, tri)
        })
    }

    #[inline(always)]
    fn left_out(&self) -> LeftOut {
        self.own_leaf
    }
}
