//! A table's keys checked into a timeline (its interpolation and key times) and one track
//! per value it sets, with Catmull-Rom tangents for `"cubic"`.

use std::ops::{Add, Mul, Range, Sub};

use toml::Spanned;

use super::clock::Clock;
use crate::animation::{Interpolation, Track};
use crate::ctx::{Ctx, R};
use crate::schema::KeysDef;

/// What the curves need of a value: sums, differences and scaling.
pub(super) trait Curve:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<f32, Output = Self>
{
}
impl<T: Copy + Add<Output = T> + Sub<Output = T> + Mul<f32, Output = T>> Curve for T {}

/// A track through `values` at `times`; for `CubicSpline`, Catmull-Rom tangents (the
/// slope between a key's neighbours, one-sided at the ends, zero for a single key).
pub(super) fn make_track<T: Curve>(
    interpolation: Interpolation,
    times: Vec<f32>,
    values: Vec<T>,
) -> Track<T> {
    if interpolation != Interpolation::CubicSpline {
        return Track { interpolation, times, values };
    }
    let n = values.len();
    let mut spline = Vec::with_capacity(3 * n);
    for k in 0..n {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        // A single key has no slope (key values are finite, so × 0 is zero).
        let tangent =
            if a == b { values[k] * 0.0 } else { (values[b] - values[a]) * (1.0 / (times[b] - times[a])) };
        spline.extend([tangent, values[k], tangent]);
    }
    Track { interpolation, times, values: spline }
}

/// How far a track's values may stray beyond its keys: a Catmull-Rom segment stays within
/// 1 + 16/27 of the largest key value (Hermite weights of the tangents are at most 4/27,
/// each scaled tangent at most twice the largest value).
pub(super) fn overshoot(interpolation: Interpolation) -> f32 {
    if interpolation == Interpolation::CubicSpline {
        2.0
    } else {
        1.0
    }
}

/// A table's keys checked: their interpolation and times, or `None` without keys.
pub(super) struct Timeline {
    pub(super) interpolation: Interpolation,
    pub(super) times: Vec<f32>,
}

pub(super) fn timeline<K>(
    ctx: &Ctx,
    clock: Option<&Clock>,
    what: &str,
    def: &KeysDef<K>,
    frame_of: impl Fn(&K) -> f64,
) -> R<Option<Timeline>> {
    if def.keys.is_empty() {
        if let Some(i) = def.interpolation {
            return Err(ctx.err(&i.span(), format!("{what}.interpolation is given without keys")));
        }
        return Ok(None);
    }
    let Some(clock) = clock else {
        return Err(ctx.err(
            &def.keys[0].span(),
            format!("{what}.keys need an [animation] table (fps and frames) in the scene"),
        ));
    };
    let interpolation = match def.interpolation {
        None => Interpolation::Linear,
        Some(i) => match i.get_ref().as_str() {
            "linear" => Interpolation::Linear,
            "step" => Interpolation::Step,
            "cubic" => Interpolation::CubicSpline,
            other => {
                return Err(ctx.err(
                    &i.span(),
                    format!(
                        "{what}.interpolation: expected \"linear\", \"step\" or \"cubic\", got {other:?}"
                    ),
                ))
            }
        },
    };
    let mut times: Vec<f32> = Vec::with_capacity(def.keys.len());
    let mut previous: Option<f64> = None;
    for key in def.keys {
        let kspan = key.span();
        let frame = frame_of(key.get_ref());
        if !(frame >= f64::from(clock.first) && frame <= f64::from(clock.last)) {
            return Err(ctx.err(
                &kspan,
                format!(
                    "{what}.keys: frame {frame} is outside the animation's frames [{}, {}]",
                    clock.first, clock.last
                ),
            ));
        }
        let time = clock.time(frame);
        if let (Some(p), Some(&pt)) = (previous, times.last()) {
            if !(time > pt) {
                return Err(ctx.err(
                    &kspan,
                    format!("{what}.keys: frame {frame} must come after the previous key's frame {p}"),
                ));
            }
        }
        previous = Some(frame);
        times.push(time);
    }
    Ok(Some(Timeline { interpolation, times }))
}

/// The track of one value over the keys that set it (`get` checks each key's value).
pub(super) fn channel<K, T: Curve>(
    keys: &[Spanned<K>],
    line: &Timeline,
    mut get: impl FnMut(&Range<usize>, &K) -> R<Option<T>>,
) -> R<Option<Track<T>>> {
    let (mut times, mut values) = (Vec::new(), Vec::new());
    for (key, &time) in keys.iter().zip(&line.times) {
        if let Some(v) = get(&key.span(), key.get_ref())? {
            times.push(time);
            values.push(v);
        }
    }
    Ok((!times.is_empty()).then(|| make_track(line.interpolation, times, values)))
}

pub(super) fn nothing_set(ctx: &Ctx, what: &str, span: &Range<usize>, frame: f64, set: bool) -> R<()> {
    if set {
        Ok(())
    } else {
        Err(ctx.err(span, format!("{what}.keys: the key at frame {frame} sets nothing")))
    }
}
