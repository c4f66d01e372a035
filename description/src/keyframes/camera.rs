//! The camera's keys: its position, aim, field of view and lens over time.

use std::ops::Range;

use glam::Vec3;

use super::clock::Clock;
use super::tracks::{channel, nothing_set, timeline};
use crate::animation::Track;
use crate::ctx::{Ctx, R};
use crate::schema::{CameraKey, KeysDef, V3};

/// The camera's animation.
#[derive(Debug, Clone)]
pub(crate) struct CameraTracks {
    pub(super) span: Range<usize>,
    pub(super) position: Option<Track<Vec3>>,
    pub(super) look_at: Option<Track<Vec3>>,
    pub(super) up: Option<Track<Vec3>>,
    /// Degrees.
    pub(super) fov: Option<Track<f32>>,
    pub(super) focus_distance: Option<Track<f32>>,
    pub(super) aperture: Option<Track<f32>>,
    /// Focus follows the distance to `look_at` (the scene gives no `focus_distance`).
    pub(super) auto_focus: bool,
}

/// Checks the camera's keys into tracks; `None` without keys.
pub(crate) fn camera_tracks(
    ctx: &Ctx,
    clock: Option<&Clock>,
    span: &Range<usize>,
    def: &KeysDef<CameraKey>,
    auto_focus: bool,
) -> R<Option<CameraTracks>> {
    let what = "camera";
    let Some(line) = timeline(ctx, clock, what, def, |k| k.frame)? else { return Ok(None) };
    for key in def.keys {
        let k = key.get_ref();
        let set = k.position.is_some()
            || k.look_at.is_some()
            || k.up.is_some()
            || k.fov.is_some()
            || k.focus_distance.is_some()
            || k.aperture.is_some();
        nothing_set(ctx, what, &key.span(), k.frame, set)?;
    }
    let vec = |name: &'static str, get: fn(&CameraKey) -> Option<V3>| {
        channel(def.keys, &line, move |s, k| {
            get(k).map(|v| ctx.finite(s, &format!("camera.keys.{name}"), v.0)).transpose()
        })
    };
    let position = vec("position", |k| k.position)?;
    let look_at = vec("look_at", |k| k.look_at)?;
    let up = vec("up", |k| k.up)?;
    let fov = channel(def.keys, &line, |s, k| {
        k.fov.map(|v| ctx.number(s, "camera.keys.fov (degrees)", v, 1e-4..179.9)).transpose()
    })?;
    let focus_distance = channel(def.keys, &line, |s, k| {
        k.focus_distance.map(|v| ctx.number(s, "camera.keys.focus_distance", v, 1e-6..f32::MAX)).transpose()
    })?;
    let aperture = channel(def.keys, &line, |s, k| {
        k.aperture.map(|v| ctx.number(s, "camera.keys.aperture (lens radius)", v, 0.0..f32::MAX)).transpose()
    })?;
    Ok(Some(CameraTracks {
        span: span.clone(),
        position,
        look_at,
        up,
        fov,
        focus_distance,
        aperture,
        auto_focus,
    }))
}
