//! A light's keys: its place (position or direction), colour and strength over time,
//! whatever its kind.

use std::ops::Range;

use glam::Vec3;
use toml::Spanned;

use super::clock::Clock;
use super::tracks::{channel, nothing_set, timeline};
use crate::animation::Track;
use crate::ctx::{Ctx, R};
use crate::schema::{DirectionalLightKey, KeysDef, PointLightKey, Rgb, V3};

/// A light's animation: its position (point) or direction (directional), colour and
/// strength (intensity or irradiance).
#[derive(Debug, Clone)]
pub(crate) struct LightTracks {
    pub(super) light: usize,
    pub(super) span: Range<usize>,
    pub(super) place: Option<Track<Vec3>>,
    pub(super) color: Option<Track<Vec3>>,
    pub(super) strength: Option<Track<f32>>,
    pub(super) base_color: Vec3,
    pub(super) base_strength: f32,
}

/// What a light's keys set, whatever its kind.
pub(crate) struct LightKeyParts {
    frame: f64,
    place: Option<V3>,
    color: Option<Rgb>,
    strength: Option<f32>,
}

impl From<&PointLightKey> for LightKeyParts {
    fn from(k: &PointLightKey) -> Self {
        LightKeyParts { frame: k.frame, place: k.position, color: k.color, strength: k.intensity }
    }
}

impl From<&DirectionalLightKey> for LightKeyParts {
    fn from(k: &DirectionalLightKey) -> Self {
        LightKeyParts { frame: k.frame, place: k.direction, color: k.color, strength: k.irradiance }
    }
}

/// Checks a light's keys into tracks; `what` names its table, `names` its place and
/// strength (`position`/`direction`, `intensity`/`irradiance`), `light` its index.
#[allow(clippy::too_many_arguments)]
pub(crate) fn light_tracks<K>(
    ctx: &Ctx,
    clock: Option<&Clock>,
    what: &'static str,
    names: (&str, &str),
    span: &Range<usize>,
    def: &KeysDef<K>,
    light: usize,
    base: (Vec3, f32),
) -> R<Option<LightTracks>>
where
    for<'k> LightKeyParts: From<&'k K>,
{
    let Some(line) = timeline(ctx, clock, what, def, |k| LightKeyParts::from(k).frame)? else {
        return Ok(None);
    };
    let parts: Vec<Spanned<LightKeyParts>> =
        def.keys.iter().map(|k| Spanned::new(k.span(), LightKeyParts::from(k.get_ref()))).collect();
    for key in &parts {
        let k = key.get_ref();
        let set = k.place.is_some() || k.color.is_some() || k.strength.is_some();
        nothing_set(ctx, what, &key.span(), k.frame, set)?;
    }
    let (place_name, strength_name) = names;
    let directional = place_name == "direction";
    let place = channel(&parts, &line, |s, k| {
        let Some(v) = k.place else { return Ok(None) };
        let v = ctx.finite(s, &format!("{what}.keys.{place_name}"), v.0)?;
        if directional && v.length_squared() == 0.0 {
            return Err(ctx.err(s, format!("{what}.keys.direction must not be the zero vector")));
        }
        Ok(Some(v))
    })?;
    let color = channel(&parts, &line, |s, k| {
        k.color.map(|v| ctx.colour(s, &format!("{what}.keys.color"), v.0)).transpose()
    })?;
    let strength = channel(&parts, &line, |s, k| {
        k.strength
            .map(|v| ctx.number(s, &format!("{what}.keys.{strength_name}"), v, 0.0..f32::MAX))
            .transpose()
    })?;
    Ok(Some(LightTracks {
        light,
        span: span.clone(),
        place,
        color,
        strength,
        base_color: base.0,
        base_strength: base.1,
    }))
}
