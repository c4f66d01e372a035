//! An object's keys: its animated transform.

use std::ops::Range;

use glam::Vec3;

use super::clock::Clock;
use super::tracks::{channel, nothing_set, overshoot, timeline};
use crate::animation::Track;
use crate::ctx::{Ctx, R};
use crate::schema::{KeysDef, TransformKey};
use crate::transform::Trs;

/// An object's animated transform.
#[derive(Debug, Clone)]
pub(crate) struct ObjectTracks {
    pub(crate) object: usize,
    pub(super) span: Range<usize>,
    pub(super) what: &'static str,
    translate: Option<Track<Vec3>>,
    /// Euler angles in degrees, as the scene gives them.
    rotate: Option<Track<Vec3>>,
    scale: Option<Track<Vec3>>,
    overshoot: f32,
}

impl ObjectTracks {
    /// The transform at time `t`: the keyed parts sampled, the rest from `base`.
    pub(super) fn at(&self, base: &Trs, t: f32) -> Trs {
        let mut trs = *base;
        if let Some(track) = &self.translate {
            trs.translate = track.sample(t);
        }
        if let Some(track) = &self.rotate {
            trs.rotate = Trs::new(Vec3::ZERO, track.sample(t), Vec3::ONE).rotate;
        }
        if let Some(track) = &self.scale {
            trs.scale = track.sample(t);
        }
        trs
    }

    /// A transform that reaches at least as far as any the animation takes: the largest
    /// translation and scale of the keys per axis, with room for a spline's overshoot.
    pub(crate) fn reach_bound(&self, base: &Trs) -> Trs {
        let most = |track: &Option<Track<Vec3>>, base: Vec3| {
            track.as_ref().map_or(base.abs(), |t| {
                t.values.iter().fold(Vec3::ZERO, |m, v| m.max(v.abs())) * self.overshoot
            })
        };
        Trs {
            translate: most(&self.translate, base.translate),
            rotate: base.rotate,
            scale: most(&self.scale, base.scale),
        }
    }

    /// Whether every scale key is uniform (spheres need it).
    pub(crate) fn uniform_scale(&self) -> bool {
        self.scale.as_ref().is_none_or(|t| t.values.iter().all(|s| s.x == s.y && s.y == s.z))
    }
}

/// Checks an object's keys (`what` names its table) into tracks, for the object pushed
/// next; `None` without keys.
pub(crate) fn object_tracks(
    ctx: &Ctx,
    clock: Option<&Clock>,
    what: &'static str,
    span: &Range<usize>,
    def: &KeysDef<TransformKey>,
    has_motion: bool,
    object: usize,
) -> R<Option<ObjectTracks>> {
    let Some(line) = timeline(ctx, clock, what, def, |k| k.frame)? else { return Ok(None) };
    if has_motion {
        return Err(ctx.err(
            span,
            format!("{what}: give `motion` or `keys`, not both (keys make each frame's motion blur)"),
        ));
    }
    for key in def.keys {
        let k = key.get_ref();
        let set = k.translate.is_some() || k.rotate.is_some() || k.scale.is_some();
        nothing_set(ctx, what, &key.span(), k.frame, set)?;
    }
    let translate = channel(def.keys, &line, |s, k| {
        k.translate.map(|v| ctx.finite(s, &format!("{what}.keys.translate"), v.0)).transpose()
    })?;
    let rotate = channel(def.keys, &line, |s, k| {
        k.rotate.map(|v| ctx.finite(s, &format!("{what}.keys.rotate (degrees)"), v.0)).transpose()
    })?;
    let scale = channel(def.keys, &line, |s, k| {
        let Some(v) = k.scale else { return Ok(None) };
        let v = ctx.finite(s, &format!("{what}.keys.scale"), v.0)?;
        if v.abs().min_element() < 1e-12 {
            return Err(ctx.err(s, format!("{what}.keys.scale must not be zero, got {v}")));
        }
        Ok(Some(v))
    })?;
    Ok(Some(ObjectTracks {
        object,
        span: span.clone(),
        what,
        translate,
        rotate,
        scale,
        overshoot: overshoot(line.interpolation),
    }))
}
