//! Object transforms (translate, rotate, scale) and their interpolation over the shutter.

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{Affine3A, Vec3};

use super::bvh::Aabb;
use tessera_description::math;

pub use tessera_description::transform::Trs;

/// An object's motion over the shutter: its transform when the shutter opens and when it
/// closes.
#[derive(Debug, Clone)]
pub struct Motion {
    start: Trs,
    end: Trs,
    /// Names these two transforms for this thread's memo of frames (`Motion::frames`):
    /// unique to each `Motion::new`, and a clone has the same transforms.
    id: u64,
    /// `world_from_object` and the scale at each step of `Motion::swept_ball`, and the
    /// turn between two steps: the same for every primitive of the object, so made once
    /// (each a slerp) rather than once per triangle of a moving mesh.
    steps: Box<[(Affine3A, Vec3)]>,
    step_turn: f32,
}

/// Motions are equal when their transforms are: the id only names them for the memo.
impl PartialEq for Motion {
    fn eq(&self, other: &Motion) -> bool {
        (self.start, self.end) == (other.start, other.end)
    }
}

/// The next `Motion::new`'s id.
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

impl Motion {
    /// The motion from `start` (shutter open) to `end` (shutter close).
    pub fn new(start: Trs, end: Trs) -> Motion {
        // φ = 2 asin(sin(φ/2)), and sin(φ/2) is the length of the relative rotation's
        // vector part; 2 asin(x) ≤ π x on [0, 1], which needs no arcsine.
        let cos_half = math::quat_dot(start.rotate, end.rotate).abs().min(1.0);
        let phi = std::f32::consts::PI * (1.0 - cos_half * cos_half).max(0.0).sqrt();
        let n = if phi > 0.0 { SWEEP_STEPS } else { 1 };
        let steps = (0..=n)
            .map(|k| {
                let trs = start.lerp(&end, k as f32 / n as f32);
                (trs.matrix(), trs.scale)
            })
            .collect();
        Motion { start, end, id: NEXT_ID.fetch_add(1, Ordering::Relaxed), steps, step_turn: phi / n as f32 }
    }

    /// `world_from_object` at shutter fraction `t`.
    pub fn at(&self, t: f32) -> Affine3A {
        self.start.lerp(&self.end, t).matrix()
    }

    /// A box holding, at every moment of the shutter, the object-space ball of `center` and
    /// `radius` as this motion moves it: the box of a moving primitive in the BVH.
    ///
    /// The ball at `t` is centred on `T(t) + R(t) v(t)`, `v(t) = S(t) ∘ center`, of radius
    /// at most `radius · max|S|` (each scale is linear in `t`, so its largest is at an
    /// end). `T` and `S` are linear; `R` turns at a constant rate about one axis (a slerp
    /// along the shorter arc), through `φ` in all. So between steps `a` and `b` of the
    /// shutter, where `R` turns through `Δ`, the centre strays from the chord of its ends by
    /// at most `|v| (Δ²/8 + Δ³/24)` (the arc's sagitta, and its uneven pace along the chord)
    /// `+ Δ |v(b) − v(a)| / 4` (the scale's change, turned): each step's box is the two
    /// balls' box grown by that. The ends' balls alone miss the arc where it bulges past
    /// them, by up to `|v| (1 − cos(φ/2))`: a spinning mesh lost triangles mid-shutter.
    pub fn swept_ball(&self, center: Vec3, radius: f32) -> Aabb {
        let largest = |s: Vec3| s.abs().max_element();
        let r = radius * largest(self.start.scale).max(largest(self.end.scale));
        let delta = self.step_turn;
        let at = |(world_from_object, scale): &(Affine3A, Vec3)| {
            (world_from_object.transform_point3(center), *scale * center)
        };
        let (mut pa, mut va) = at(&self.steps[0]);
        let mut out = Aabb::EMPTY;
        for step in &self.steps[1..] {
            let (pb, vb) = at(step);
            let v = va.length().max(vb.length());
            let stray =
                v * (delta * delta / 8.0 + delta * delta * delta / 24.0) + delta * (vb - va).length() / 4.0;
            // The transforms' rounding, and slerp's from a constant pace, relative to the
            // coordinates' size.
            let slack = (pa.abs().max(pb.abs()).max_element() + v + r) * 1e-4;
            let grow = Vec3::splat(r + stray + slack);
            out = out.union(Aabb { min: pa.min(pb) - grow, max: pa.max(pb) + grow });
            (pa, va) = (pb, vb);
        }
        out
    }

    /// `world_from_object` and `object_from_world` at shutter fraction `t`: [`Motion::at`]
    /// and its inverse, the same bits, from this thread's memo when they were made last.
    ///
    /// A ray's time is the same at every primitive with this motion (and at its sample's
    /// shadow rays): worked out per triangle of a moving mesh, when each was a primitive,
    /// the interpolation (a slerp, with its sines) and the inverse were a third of the
    /// showcase's profile; a moving mesh is now one instance that asks once a visit, and
    /// the memo still spares a sample's shadow rays and other moving objects the work. The memo is keyed by the motion's id and the time's bits, and an
    /// id is never given twice, so another scene's motion can never be taken for this one.
    pub fn frames(&self, t: f32) -> (Affine3A, Affine3A) {
        let key = (self.id, t.to_bits());
        let slot = (self.id % MEMO_SLOTS as u64) as usize;
        MEMO.with(|memo| {
            if let Some(kept) = memo[slot].get().filter(|kept| kept.key == key) {
                return (kept.world_from_object, kept.object_from_world);
            }
            let world_from_object = self.at(t);
            let object_from_world = world_from_object.inverse();
            memo[slot].set(Some(Frames { key, world_from_object, object_from_world }));
            (world_from_object, object_from_world)
        })
    }
}

/// Steps of the shutter a rotating object's box is made of (`Motion::swept_ball`): at
/// eight, a quarter turn strays from its chords by 0.5 % of its radius.
const SWEEP_STEPS: u32 = 8;

/// Entries in a thread's memo: a scene's motions have consecutive ids, so up to this many
/// moving objects keep their frames while a ray passes between them.
const MEMO_SLOTS: usize = 4;

/// A motion's frames at one time: the motion's id and the time's bits.
#[derive(Debug, Clone, Copy)]
struct Frames {
    key: (u64, u32),
    world_from_object: Affine3A,
    object_from_world: Affine3A,
}

thread_local! {
    static MEMO: [Cell<Option<Frames>>; MEMO_SLOTS] = const { [const { Cell::new(None) }; MEMO_SLOTS] };
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn rotation_order_and_interpolation() {
        let t = Trs::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 90.0, 0.0), Vec3::splat(2.0));
        // Scale, rotate 90° about y (x → -z), translate.
        let p = t.matrix().transform_point3(Vec3::X);
        assert!((p - Vec3::new(1.0, 0.0, -2.0)).length() < 1e-5, "{p}");
        let m = Motion::new(Trs::default(), Trs { translate: Vec3::new(4.0, 0.0, 0.0), ..Trs::default() });
        assert!((m.at(0.25).transform_point3(Vec3::ZERO) - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-6);
    }

    /// A ball swept by random motions (turns up to half a turn about any axis, scales
    /// growing and shrinking, translations) stays in its box at 257 moments, at points on
    /// its surface along the axes and the diagonals; with the ends' boxes alone (one step,
    /// nothing for the arc) it does not.
    #[test]
    fn a_swept_ball_holds_the_ball_at_every_moment() {
        use crate::render::sampler::hash_words;
        let mut strayed_from_the_ends = 0;
        for k in 0..300u64 {
            let u = |j: u64| (hash_words(&[k, j]) >> 40) as f32 / (1u64 << 24) as f32;
            let v = |j: u64| Vec3::new(u(j), u(j + 1), u(j + 2));
            let trs = |j: u64| Trs::new(v(j) * 20.0 - 10.0, v(j + 3) * 360.0 - 180.0, v(j + 6) * 3.0 + 0.05);
            let m = Motion::new(trs(0), trs(10));
            let (center, radius) = (v(20) * 8.0 - 4.0, u(23) * 0.3);
            let b = m.swept_ball(center, radius);
            let ends = [0.0, 1.0].map(|t| {
                let trs = m.start.lerp(&m.end, t);
                let r = Vec3::splat(radius * trs.scale.abs().max_element());
                let c = trs.matrix().transform_point3(center);
                Aabb { min: c - r, max: c + r }
            });
            let ends = ends[0].union(ends[1]);
            let dirs = (0..27)
                .map(|i| Vec3::new((i % 3) as f32 - 1.0, (i / 3 % 3) as f32 - 1.0, (i / 9) as f32 - 1.0));
            let dirs: Vec<Vec3> = dirs.filter_map(|d| d.try_normalize()).collect();
            for i in 0..=256 {
                let t = i as f32 / 256.0;
                let world_from_object = m.at(t);
                for d in &dirs {
                    let p = world_from_object.transform_point3(center + *d * radius);
                    assert!(
                        p.cmpge(b.min).all() && p.cmple(b.max).all(),
                        "motion {k} at {t}: {p} outside {b:?}"
                    );
                    strayed_from_the_ends +=
                        usize::from(!(p.cmpge(ends.min).all() && p.cmple(ends.max).all()));
                }
            }
        }
        assert!(strayed_from_the_ends > 1000, "{strayed_from_the_ends}");
    }

    fn bits(a: Affine3A) -> Vec<u32> {
        a.to_cols_array().iter().map(|x| x.to_bits()).collect()
    }

    /// The memo's frames are the ones made afresh, to the bit, whichever motions and times
    /// come in whatever order: more motions than entries, the same slot taken in turn,
    /// times repeated and new, -0.0 beside 0.0, and motions whose transforms differ only
    /// in the sign of a zero.
    #[test]
    fn memoised_frames_are_the_frames_made_afresh() {
        let spin = |y: f32, z: f32| {
            Motion::new(
                Trs::new(Vec3::new(0.0, z, 1.0), Vec3::new(10.0, y, 0.0), Vec3::splat(0.5)),
                Trs::new(
                    Vec3::new(2.0, -1.0, 1.0),
                    Vec3::new(80.0, y + 90.0, 30.0),
                    Vec3::new(1.0, 2.0, 0.5),
                ),
            )
        };
        let motions: Vec<Motion> =
            [0.0, 45.0, -30.0, 170.0, 12.5, 90.0].into_iter().map(|y| spin(y, 0.0)).collect();
        let signed = [spin(0.0, 0.0), spin(0.0, -0.0)];
        assert_eq!(signed[0], signed[1], "equal as values");
        let times = [0.0, -0.0, 0.25, 0.5, 1.0, 0.25, 0.7, 0.0];
        let mut made = 0;
        for round in 0..3 {
            for (i, &t) in times.iter().enumerate() {
                for m in motions.iter().chain(&signed).skip((i + round) % 3) {
                    let (w, o) = m.frames(t);
                    let fresh = m.at(t);
                    assert_eq!(bits(w), bits(fresh), "world_from_object at {t}");
                    assert_eq!(bits(o), bits(fresh.inverse()), "object_from_world at {t}");
                    made += 1;
                }
            }
        }
        assert!(made > 100);
        // A clone names the same transforms and takes their frames.
        let c = motions[1].clone();
        assert_eq!(bits(c.frames(0.3).0), bits(motions[1].at(0.3)));
    }
}
