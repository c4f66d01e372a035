//! A nearest-hit search's test at each leaf the walk visits ([`Scene::search`]'s): the
//! leaf's triangles four at a time, its other slots one by one, keeping the nearest hit.
//!
//! A struct whose test is `#[inline(always)]` rather than a closure, so that the test is
//! compiled into the walk that visits the leaves (the AVX2 one too): as a closure it was a
//! call at every leaf, the AVX state cleared before it and the ray's lanes loaded again
//! after it (docs/speed.md, thirty-seventh part).

use super::bvh::Leaves;
use super::geometry::Ray;
use super::{shape, triangles, Candidate, SurfaceHit, World};

/// A search's state: the ray, and what it has found so far.
pub(super) struct Search<'a, const ALPHA: bool> {
    w: &'a World,
    ray: &'a Ray,
    time: f32,
    /// The ray in four lanes, where the scene has inline triangles to test at once.
    r4: Option<triangles::Ray4>,
    /// What the search has found so far.
    pub(super) found: Found,
}

impl<const ALPHA: bool> Search<'_, ALPHA> {
    /// The search's state for `ray` in `w` at `time`, nothing found yet.
    pub(super) fn new<'a>(w: &'a World, ray: &'a Ray, time: f32) -> Search<'a, ALPHA> {
        Search { w, ray, time, r4: w.slots.ray4::<ALPHA>(ray), found: Found { nearest: None, best: None } }
    }
}

/// What a nearest-hit search found: a candidate its completion turns into the hit, or a
/// hit its primitive or instance made whole (a moving one, or one whose material has an
/// alpha cut-out).
pub(super) struct Found {
    /// The nearest hit of a primitive that completes it later: an inline triangle's, a
    /// still parallelogram's or a still sphere's hit is completed (point, normals, uv) only
    /// once it is known to be the nearest; it is the same hit `Primitive::intersect` would
    /// have made.
    pub(super) nearest: Option<Candidate>,
    /// The nearest hit made whole where it was found (a moving primitive's, an instance's,
    /// one whose material cuts out hits).
    pub(super) best: Option<SurfaceHit>,
}

impl Found {
    /// The hit of an inline triangle in slot k that its leaf's test found (only without
    /// alpha cut-outs), which then needs neither the slot nor a test of its own.
    #[inline(always)]
    fn inline_triangle(&mut self, k: usize, t_max: f32, (t, b1, b2): (f32, f32, f32)) -> Option<f32> {
        if !(t < t_max) {
            return None;
        }
        self.nearest = Some(Candidate::Triangle(k, t, b1, b2));
        self.best = None;
        Some(t)
    }

    /// [`Found::slot`] out of line, so that the walk the leaf's test is inlined into stays
    /// small where the slots are inline triangles, whose hits do not come here.
    #[inline(never)]
    fn slot_out_of_line<const ALPHA: bool>(
        &mut self,
        at: (&World, &Ray, f32),
        k: usize,
        t_max: f32,
    ) -> Option<f32> {
        self.slot::<ALPHA>(at, k, t_max)
    }

    /// A leaf's slots tested one by one, out of line: the leaves of a scene without inline
    /// triangles, one call a leaf as when the leaf's test was a closure.
    #[inline(never)]
    fn slots_out_of_line<const ALPHA: bool>(
        &mut self,
        at: (&World, &Ray, f32),
        first: usize,
        count: usize,
        t_max: f32,
    ) -> f32 {
        super::bvh::nearest_in_leaf(first, count, t_max, |k, t_max| self.slot::<ALPHA>(at, k, t_max))
    }

    /// Slot k's test for `ray` in `w` at `time`; returns the distance of a hit nearer than
    /// `t_max`.
    #[inline(always)]
    fn slot<const ALPHA: bool>(
        &mut self,
        (w, ray, time): (&World, &Ray, f32),
        k: usize,
        t_max: f32,
    ) -> Option<f32> {
        match w.slots[k].kind() {
            triangles::SlotKind::Triangle(i) => {
                let (t, b1, b2) = w.slots.hit(k, ray, t_max)?;
                if ALPHA && !w.covers_slot(i, b1, b2, ray) {
                    return None;
                }
                self.nearest = Some(Candidate::Triangle(k, t, b1, b2));
                self.best = None;
                Some(t)
            }
            triangles::SlotKind::Instance(j) => {
                let inst = &w.instances[j as usize];
                let hit = inst.intersect(ray, t_max, time, &w.meshes, &w.motions)?;
                self.nearest = None;
                self.best = Some(SurfaceHit { hit, material: inst.material, light: None });
                Some(hit.t)
            }
            triangles::SlotKind::Generic(i) => {
                let prim = &w.prims[i as usize];
                let alpha = ALPHA && w.surfaces.alpha[prim.material as usize];
                match (&prim.shape, prim.motion, alpha) {
                    (shape::Shape::Rect(r), None, false) => {
                        let (t, s, tt) = r.candidate(ray, t_max)?;
                        self.nearest = Some(Candidate::Rect(i, t, s, tt));
                        self.best = None;
                        return Some(t);
                    }
                    (shape::Shape::Sphere(s), None, false) => {
                        let t = s.candidate(ray, t_max)?;
                        self.nearest = Some(Candidate::Sphere(i, t));
                        self.best = None;
                        return Some(t);
                    }
                    _ => {}
                }
                let mut hit = prim.intersect(ray, t_max, time, &w.meshes, &w.motions)?;
                if alpha && !w.covers_hit(i, hit.p, hit.uv, ray, time) {
                    return None;
                }
                hit.prim = i;
                self.nearest = None;
                self.best = Some(SurfaceHit { hit, material: prim.material, light: prim.light });
                Some(hit.t)
            }
        }
    }
}

impl<const ALPHA: bool> Leaves for Search<'_, ALPHA> {
    #[inline(always)]
    fn leaf(&mut self, first: usize, count: usize, mut t_max: f32) -> f32 {
        let Search { w, ray, time, r4, found } = self;
        let at = (*w, *ray, *time);
        if let Some(r4) = r4 {
            // The leaf's triangles tested at once, then taken in slot order with the other
            // slots, each against the `t_max` the ones before it left.
            w.slots.leaf(first, count, r4, |k, tri| {
                let hit = match tri {
                    Some(tri) => found.inline_triangle(k, t_max, tri),
                    None => found.slot_out_of_line::<ALPHA>(at, k, t_max),
                };
                if let Some(t) = hit {
                    t_max = t_max.min(t);
                }
                true
            });
            return t_max;
        }
        found.slots_out_of_line::<ALPHA>(at, first, count, t_max)
    }
}
