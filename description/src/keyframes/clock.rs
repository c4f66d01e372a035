//! The scene's frame clock: the `[animation]` table checked.

use std::ops::Range;

use toml::Spanned;

use crate::animation::FrameTime;
use crate::ctx::{Ctx, R};
use crate::limits;
use crate::schema::AnimationDef;

/// The scene's frame clock: the checked `[animation]` table.
#[derive(Debug, Clone)]
pub(crate) struct Clock {
    pub(crate) fps: f32,
    pub(crate) first: u32,
    pub(crate) last: u32,
    pub(crate) span: Range<usize>,
}

impl Clock {
    /// The time of a key at `frame`, seconds.
    pub(super) fn time(&self, frame: f64) -> f32 {
        FrameTime::frame_start(frame, self.fps)
    }
}

/// Checks the `[animation]` table.
pub(crate) fn clock(ctx: &Ctx, def: &Spanned<AnimationDef>) -> R<Clock> {
    let span = def.span();
    let d = def.get_ref();
    if !(d.fps.is_finite() && d.fps > 0.0 && d.fps <= 1000.0) {
        return Err(ctx.err(&span, format!("animation.fps must be in (0, 1000], got {}", d.fps)));
    }
    let [first, last] = d.frames;
    if first > last {
        return Err(ctx.err(
            &span,
            format!("animation.frames must be [first, last] with first <= last, got [{first}, {last}]"),
        ));
    }
    if last - first >= limits::MAX_FRAMES {
        return Err(ctx.err(
            &span,
            format!(
                "animation.frames: {} frames, more than the limit of {}",
                u64::from(last - first) + 1,
                limits::MAX_FRAMES
            ),
        ));
    }
    Ok(Clock { fps: d.fps, first, last, span })
}
