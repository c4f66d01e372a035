//! Object transforms (translate, rotate, scale) and their interpolation over the shutter.

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::Affine3A;

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
        Motion { start, end, id: NEXT_ID.fetch_add(1, Ordering::Relaxed) }
    }

    /// The transforms at shutter open and close.
    pub fn ends(&self) -> [Trs; 2] {
        [self.start, self.end]
    }

    /// `world_from_object` at shutter fraction `t`.
    pub fn at(&self, t: f32) -> Affine3A {
        self.start.lerp(&self.end, t).matrix()
    }

    /// `world_from_object` and `object_from_world` at shutter fraction `t`: [`Motion::at`]
    /// and its inverse, the same bits, from this thread's memo when they were made last.
    ///
    /// A moving mesh's every triangle is a primitive with this motion, and a ray's time is
    /// the same at each of them (and at its sample's shadow rays): worked out per triangle,
    /// the interpolation (a slerp, with its sines) and the inverse were a third of the
    /// showcase's profile. The memo is keyed by the motion's id and the time's bits, and an
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
