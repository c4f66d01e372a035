//! Keyframes in the scene file: the `[animation]` table (frames per second and the frame
//! range) and the `keys` of objects, the camera and lights, checked into animation tracks
//! and evaluated at one frame's shutter window.
//!
//! A key sets some of its table's animatable values at a frame; each value is its own
//! track (as glTF channels are), holding only the keys that set it, and the table's own
//! value wherever it has no key. Times are `frame / fps` seconds. `interpolation` on the
//! table applies to all its tracks; `"cubic"` is a Catmull-Rom spline: each key's tangent
//! is the slope between its neighbours (one-sided at the ends), so the curve passes
//! through every key. Rotations interpolate their Euler angles in degrees, so that
//! `[0, 720, 0]` spins twice.
//!
//! Over a frame, a moving object is placed where its animation has it when the shutter
//! opens (`Object::transform`) and when it closes (`Object::motion`, only when they
//! differ), and the renderer interpolates between the two: the scene's shutter becomes the
//! whole motion interval. The camera, lights and emitting objects take their values at
//! shutter open and do not blur.

use std::ops::{Add, Mul, Range, Sub};

use glam::Vec3;
use serde::Deserialize;
use toml::Spanned;

use crate::animation::{FrameTime, Interpolation, Sequence, Track};
use crate::limits;
use crate::model::{Description, Light, Shape};
use crate::schema::{Rgb, V3};
use crate::transform::Trs;
use crate::validate::{Ctx, R};

/// The `[animation]` table.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct AnimationDef {
    #[serde(default = "default_fps")]
    pub(crate) fps: f32,
    pub(crate) frames: [u32; 2],
}

fn default_fps() -> f32 {
    24.0
}

/// A key of an object's transform.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct TransformKey {
    pub(crate) frame: f64,
    pub(crate) translate: Option<V3>,
    pub(crate) rotate: Option<V3>,
    pub(crate) scale: Option<Rgb>,
}

/// A key of the camera.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CameraKey {
    pub(crate) frame: f64,
    pub(crate) position: Option<V3>,
    pub(crate) look_at: Option<V3>,
    pub(crate) up: Option<V3>,
    pub(crate) fov: Option<f32>,
    pub(crate) focus_distance: Option<f32>,
    pub(crate) aperture: Option<f32>,
}

/// A key of a point light.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PointLightKey {
    pub(crate) frame: f64,
    pub(crate) position: Option<V3>,
    pub(crate) color: Option<Rgb>,
    pub(crate) intensity: Option<f32>,
}

/// A key of a directional light.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct DirectionalLightKey {
    pub(crate) frame: f64,
    pub(crate) direction: Option<V3>,
    pub(crate) color: Option<Rgb>,
    pub(crate) irradiance: Option<f32>,
}

/// A table's keys as the schema holds them: `keys = [...]` (or `[[table.keys]]`) and the
/// table's `interpolation`.
pub(crate) struct KeysDef<'a, K> {
    pub(crate) keys: &'a [Spanned<K>],
    pub(crate) interpolation: &'a Option<Spanned<String>>,
}

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
    fn time(&self, frame: f64) -> f32 {
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

/// What the curves need of a value: sums, differences and scaling.
trait Curve: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<f32, Output = Self> {}
impl<T: Copy + Add<Output = T> + Sub<Output = T> + Mul<f32, Output = T>> Curve for T {}

/// A track through `values` at `times`; for `CubicSpline`, Catmull-Rom tangents (the
/// slope between a key's neighbours, one-sided at the ends, zero for a single key).
fn make_track<T: Curve>(interpolation: Interpolation, times: Vec<f32>, values: Vec<T>) -> Track<T> {
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
fn overshoot(interpolation: Interpolation) -> f32 {
    if interpolation == Interpolation::CubicSpline {
        2.0
    } else {
        1.0
    }
}

/// A table's keys checked: their interpolation and times, or `None` without keys.
struct Timeline {
    interpolation: Interpolation,
    times: Vec<f32>,
}

fn timeline<K>(
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
fn channel<K, T: Curve>(
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

fn nothing_set(ctx: &Ctx, what: &str, span: &Range<usize>, frame: f64, set: bool) -> R<()> {
    if set {
        Ok(())
    } else {
        Err(ctx.err(span, format!("{what}.keys: the key at frame {frame} sets nothing")))
    }
}

/// An object's animated transform.
#[derive(Debug, Clone)]
pub(crate) struct ObjectTracks {
    pub(crate) object: usize,
    span: Range<usize>,
    what: &'static str,
    translate: Option<Track<Vec3>>,
    /// Euler angles in degrees, as the scene gives them.
    rotate: Option<Track<Vec3>>,
    scale: Option<Track<Vec3>>,
    overshoot: f32,
}

impl ObjectTracks {
    /// The transform at time `t`: the keyed parts sampled, the rest from `base`.
    fn at(&self, base: &Trs, t: f32) -> Trs {
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

/// The camera's animation.
#[derive(Debug, Clone)]
pub(crate) struct CameraTracks {
    span: Range<usize>,
    position: Option<Track<Vec3>>,
    look_at: Option<Track<Vec3>>,
    up: Option<Track<Vec3>>,
    /// Degrees.
    fov: Option<Track<f32>>,
    focus_distance: Option<Track<f32>>,
    aperture: Option<Track<f32>>,
    /// Focus follows the distance to `look_at` (the scene gives no `focus_distance`).
    auto_focus: bool,
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

/// A light's animation: its position (point) or direction (directional), colour and
/// strength (intensity or irradiance).
#[derive(Debug, Clone)]
pub(crate) struct LightTracks {
    light: usize,
    span: Range<usize>,
    place: Option<Track<Vec3>>,
    color: Option<Track<Vec3>>,
    strength: Option<Track<f32>>,
    base_color: Vec3,
    base_strength: f32,
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

/// Every animation of a scene, with its clock.
#[derive(Debug, Clone)]
pub(crate) struct SceneTracks {
    pub(crate) clock: Clock,
    pub(crate) objects: Vec<ObjectTracks>,
    pub(crate) camera: Option<CameraTracks>,
    pub(crate) lights: Vec<LightTracks>,
}

/// The value of a transform's interpolation at shutter fraction `s`, exactly its ends at
/// 0 and 1 (so a full shutter keeps a still object's bits).
fn lerp_exact(start: &Trs, end: &Trs, s: f32) -> Trs {
    if s == 0.0 {
        *start
    } else if s == 1.0 {
        *end
    } else {
        start.lerp(end, s)
    }
}

/// Evaluates the animation at `time` (a frame over its shutter) into `d` (the scene as
/// validated, its values those of the tables).
pub(crate) fn evaluate(ctx: &Ctx, d: &mut Description, tracks: &SceneTracks, time: FrameTime) -> R<()> {
    let clock = &tracks.clock;
    let frame = time.frame;
    if frame < clock.first || frame > clock.last {
        return Err(ctx.err(
            &clock.span,
            format!("frame {frame} is outside the animation's frames [{}, {}]", clock.first, clock.last),
        ));
    }
    let (s0, s1) = d.camera.shutter;
    let blur = s1 > s0;

    let mut animated = vec![false; d.objects.len()];
    for t in &tracks.objects {
        animated[t.object] = true;
        let o = &mut d.objects[t.object];
        let check = |trs: &Trs| -> R<()> {
            let s = trs.scale;
            if !(s.abs().min_element() >= 1e-12) || !trs.matrix().is_finite() {
                return Err(ctx.err(
                    &t.span,
                    format!("{}: at frame {frame} its scale is {s}; the keys take it through zero", t.what),
                ));
            }
            if matches!(o.shape, Shape::Sphere { .. }) && !(s.x == s.y && s.y == s.z) {
                return Err(
                    ctx.err(&t.span, format!("sphere: at frame {frame} its scale {s} is not uniform"))
                );
            }
            Ok(())
        };
        let open = t.at(&o.transform, time.open);
        check(&open)?;
        // Emitters are sampled as lights where they stand: they do not blur.
        let close = if blur && o.emission.is_none() { t.at(&o.transform, time.close) } else { open };
        check(&close)?;
        o.transform = open;
        o.motion = (close != open).then_some(close);
    }
    // A scene-given motion spans each frame's interval; re-expressed over the shutter.
    for (o, _) in d.objects.iter_mut().zip(&animated).filter(|(_, a)| !**a) {
        if let Some(end) = o.motion {
            let open = lerp_exact(&o.transform, &end, s0);
            let close = lerp_exact(&o.transform, &end, s1);
            o.transform = open;
            o.motion = (blur && close != open).then_some(close);
        }
    }
    if blur {
        d.camera.shutter = (0.0, 1.0);
    }

    if let Some(c) = &tracks.camera {
        let t = time.open;
        let cam = &mut d.camera;
        if let Some(tr) = &c.position {
            cam.position = tr.sample(t);
        }
        if let Some(tr) = &c.look_at {
            cam.look_at = tr.sample(t);
        }
        if let Some(tr) = &c.up {
            cam.up = tr.sample(t);
        }
        let forward = cam.look_at - cam.position;
        if !(forward.length_squared() > 0.0) || !(forward.cross(cam.up).length_squared() > 0.0) {
            return Err(ctx.err(
                &c.span,
                format!(
                    "camera: at frame {frame} look_at {} and position {} coincide or lie along up {}",
                    cam.look_at, cam.position, cam.up
                ),
            ));
        }
        if let Some(tr) = &c.fov {
            let fov = ctx.number(
                &c.span,
                &format!("camera.fov (degrees) at frame {frame}"),
                tr.sample(t),
                1e-4..179.9,
            )?;
            cam.fov = fov.to_radians();
        }
        if let Some(tr) = &c.focus_distance {
            cam.focus_distance = ctx.number(
                &c.span,
                &format!("camera.focus_distance at frame {frame}"),
                tr.sample(t),
                1e-6..f32::MAX,
            )?;
        } else if c.auto_focus && (c.position.is_some() || c.look_at.is_some()) {
            cam.focus_distance = forward.length();
        }
        if let Some(tr) = &c.aperture {
            cam.lens_radius = tr.sample(t).max(0.0);
        }
    }

    for l in &tracks.lights {
        let t = time.open;
        let strength = |l: &LightTracks| {
            let color = l.color.as_ref().map_or(l.base_color, |c| c.sample(t).max(Vec3::ZERO));
            let s = l.strength.as_ref().map_or(l.base_strength, |s| s.sample(t).max(0.0));
            color * s
        };
        let keyed_strength = l.color.is_some() || l.strength.is_some();
        let light = &mut d.lights[l.light];
        if let Light::Point { position, intensity } = light {
            if let Some(tr) = &l.place {
                *position = tr.sample(t);
            }
            if keyed_strength {
                *intensity = strength(l);
            }
        } else if let Light::Directional { direction, irradiance } = light {
            if let Some(tr) = &l.place {
                *direction = tr.sample(t).try_normalize().ok_or_else(|| {
                    ctx.err(&l.span, format!("directional_light: at frame {frame} its direction is zero"))
                })?;
            }
            if keyed_strength {
                *irradiance = strength(l);
            }
        }
    }
    d.sequence = Some(Sequence { fps: clock.fps, frames: (clock.first, clock.last), time });
    Ok(())
}

#[cfg(test)]
mod tests {
    use glam::{Quat, Vec3};

    use crate::model::{Description, Light};
    use crate::{Bundle, SceneError};

    const BASE: &str = r#"
[render]
width = 8
height = 6

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
shutter = [0, 0.5]

[materials.red]
color = [1, 0, 0]
"#;

    fn bundle(text: &str) -> Bundle {
        Bundle { name: "a.toml".into(), text: text.to_string(), assets: vec![], refused: vec![] }
    }

    fn frame(text: &str, f: u32) -> Description {
        Description::parse_frame(&bundle(text), f).unwrap_or_else(|e| panic!("{e}"))
    }

    fn err(text: &str, f: u32) -> SceneError {
        Description::parse_frame(&bundle(text), f).expect_err("should be refused")
    }

    /// A sphere keyed from x = 0 at frame 0 to x = 8 at frame 8 at 4 fps.
    fn moving(interpolation: &str, shutter: &str) -> String {
        format!(
            "{}\n[animation]\nfps = 4\nframes = [0, 8]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
             interpolation = \"{interpolation}\"\n\
             keys = [{{ frame = 0, translate = [0, 0, 0] }}, {{ frame = 8, translate = [8, 0, 0] }}]\n",
            BASE.replace("shutter = [0, 0.5]", shutter)
        )
    }

    #[test]
    fn a_still_scene_is_the_same_at_every_frame() {
        let text = format!(
            "{BASE}\n[[sphere]]\nradius = 1\nmaterial = \"red\"\nmotion = {{ translate = [1, 0, 0] }}\n"
        );
        let still = Description::parse(&bundle(&text)).unwrap();
        assert_eq!(still.frames(), None);
        assert_eq!(frame(&text, 7), still);
        assert_eq!(still.camera.shutter, (0.0, 0.5));
    }

    #[test]
    fn parse_is_the_first_frame() {
        let text = moving("linear", "shutter = [0, 0.5]");
        let first = Description::parse(&bundle(&text)).unwrap();
        assert_eq!(first, frame(&text, 0));
        assert_eq!(first.frames(), Some((0, 8)));
        assert_eq!(first.sequence.unwrap().fps, 4.0);
    }

    #[test]
    fn each_frame_blurs_over_its_shutter() {
        let text = moving("linear", "shutter = [0, 0.5]");
        let d = frame(&text, 2);
        let o = &d.objects[0];
        // Frame 2 opens at 2/4 s (x = 2) and closes half a frame later (x = 2.5).
        assert_eq!(o.transform.translate, Vec3::new(2.0, 0.0, 0.0));
        assert_eq!(o.motion.unwrap().translate, Vec3::new(2.5, 0.0, 0.0));
        // The renderer's motion interval is now the shutter itself.
        assert_eq!(d.camera.shutter, (0.0, 1.0));
        let t = d.sequence.unwrap().time;
        assert_eq!((t.frame, t.open, t.close), (2, 0.5, 0.625));
        // The last frame's shutter lies past the last key: held, no motion.
        let last = frame(&text, 8);
        assert_eq!(last.objects[0].transform.translate, Vec3::new(8.0, 0.0, 0.0));
        assert_eq!(last.objects[0].motion, None);
    }

    #[test]
    fn a_closed_shutter_or_step_keys_make_no_motion() {
        let instant = frame(&moving("linear", "shutter = [0, 0]"), 3);
        assert_eq!(instant.objects[0].transform.translate, Vec3::new(3.0, 0.0, 0.0));
        assert_eq!(instant.objects[0].motion, None);
        assert_eq!(instant.camera.shutter, (0.0, 0.0));
        let step = frame(&moving("step", "shutter = [0, 0.5]"), 5);
        assert_eq!(step.objects[0].transform.translate, Vec3::ZERO);
        assert_eq!(step.objects[0].motion, None);
    }

    #[test]
    fn a_frame_on_its_key_has_the_tables_bits() {
        // Keyed where the table stands, with a shutter that sees no change: the same
        // description as the still scene, so its image keeps its bytes.
        let still = format!(
            "{BASE}\n[[sphere]]\nradius = 1\nmaterial = \"red\"\ntransform = {{ translate = [1, 2, 3] }}\n"
        );
        let keyed = format!(
            "{still}keys = [{{ frame = 1, translate = [1, 2, 3] }}, {{ frame = 2, translate = [1, 2, 3] }}]\n\
             [animation]\nframes = [1, 2]\n"
        );
        let (a, b) = (frame(&still, 1), frame(&keyed, 1));
        assert_eq!(a.objects, b.objects);
        assert_eq!(b.objects[0].motion, None);
    }

    #[test]
    fn cubic_keys_follow_catmull_rom() {
        // Keys 0, 1, 0 at 0, 1 and 2 s. At 0.5 s: tangents 1 (one-sided) and 0 (centred),
        // p = ½·0 + ⅛·1 + ½·1 − ⅛·0 = 0.625. On a key the value is the key's.
        let text = format!(
            "{}\n[animation]\nfps = 2\nframes = [0, 4]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
             interpolation = \"cubic\"\n\
             [[sphere.keys]]\nframe = 0\ntranslate = [0, 0, 0]\n\
             [[sphere.keys]]\nframe = 2\ntranslate = [0, 1, 0]\n\
             [[sphere.keys]]\nframe = 4\ntranslate = [0, 0, 0]\n",
            BASE.replace("shutter = [0, 0.5]", "shutter = [0, 0]")
        );
        let y = |f| frame(&text, f).objects[0].transform.translate.y;
        assert!((y(1) - 0.625).abs() < 1e-6, "{}", y(1));
        assert_eq!(y(2), 1.0);
        assert!((y(3) - 0.625).abs() < 1e-6, "{}", y(3));
        assert_eq!(y(4), 0.0);
    }

    #[test]
    fn rotations_interpolate_their_angles() {
        // Two full turns over 8 frames: a quarter of the way is half a turn.
        let text = format!(
            "{}\n[animation]\nframes = [0, 8]\n\n[[box]]\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\nmaterial = \"red\"\n\
             keys = [{{ frame = 0, rotate = [0, 0, 0] }}, {{ frame = 8, rotate = [0, 720, 0] }}]\n",
            BASE.replace("shutter = [0, 0.5]", "shutter = [0, 0]")
        );
        let q = frame(&text, 2).objects[0].transform.rotate;
        assert!(q.angle_between(Quat::from_rotation_y(std::f32::consts::PI)) < 1e-4, "{q:?}");
        let q = frame(&text, 4).objects[0].transform.rotate;
        assert!(q.angle_between(Quat::IDENTITY) < 1e-4, "{q:?}");
    }

    #[test]
    fn a_scene_motion_spans_each_frame_and_is_cut_to_the_shutter() {
        let text = format!(
            "{BASE}\n[animation]\nframes = [1, 3]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
             motion = {{ translate = [4, 0, 0] }}\n"
        );
        let d = frame(&text, 2);
        assert_eq!(d.objects[0].transform.translate, Vec3::ZERO);
        assert_eq!(d.objects[0].motion.unwrap().translate, Vec3::new(2.0, 0.0, 0.0));
        assert_eq!(d.camera.shutter, (0.0, 1.0));
    }

    #[test]
    fn camera_and_lights_take_their_values_at_shutter_open() {
        let text = format!(
            "{BASE}\n[animation]\nfps = 1\nframes = [0, 4]\n\n\
             [[point_light]]\nposition = [0, 5, 0]\nintensity = 10\ncolor = [1, 0.5, 0]\n\
             keys = [{{ frame = 0, intensity = 0 }}, {{ frame = 4, intensity = 40, position = [4, 5, 0] }}]\n\
             [[directional_light]]\ndirection = [0, -1, 0]\nirradiance = 2\n\
             keys = [{{ frame = 0, direction = [1, 0, 0] }}, {{ frame = 2, direction = [0, 0, -1] }}]\n"
        )
        .replace(
            "look_at = [0, 0, 0]\n",
            "look_at = [0, 0, 0]\nfov = 40\n\
             keys = [{ frame = 0, position = [0, 0, 5], fov = 40 }, { frame = 4, position = [0, 0, 9], fov = 20 }]\n",
        );
        let d = frame(&text, 1);
        assert_eq!(d.camera.position, Vec3::new(0.0, 0.0, 6.0));
        assert!((d.camera.fov - 35f32.to_radians()).abs() < 1e-6);
        // No focus distance given: focus follows the distance to look_at.
        assert_eq!(d.camera.focus_distance, 6.0);
        let Light::Point { position, intensity } = d.lights[0] else { panic!() };
        // The position track has one key: held.
        assert_eq!(position, Vec3::new(4.0, 5.0, 0.0));
        assert_eq!(intensity, Vec3::new(10.0, 5.0, 0.0));
        let Light::Directional { direction, irradiance } = d.lights[1] else { panic!() };
        assert!((direction - Vec3::new(0.5, 0.0, -0.5).normalize()).length() < 1e-6);
        assert_eq!(irradiance, Vec3::splat(2.0));
    }

    #[test]
    fn refusals_name_what_and_where() {
        let ok = moving("linear", "shutter = [0, 0.5]");
        let cases: Vec<(String, u32, &str)> = vec![
            (ok.replace("translate = [8, 0, 0]", "translat = [8, 0, 0]"), 0, "translat"),
            (ok.replace("frame = 8", "frame = 9"), 0, "frame 9 is outside the animation's frames [0, 8]"),
            (ok.replace("frame = 0,", "frame = 8,"), 0, "frame 8 must come after the previous key's frame 8"),
            (ok.replace("\"linear\"", "\"bezier\""), 0, "expected \"linear\", \"step\" or \"cubic\""),
            (ok.replace("[animation]\nfps = 4\nframes = [0, 8]\n", ""), 0, "need an [animation] table"),
            (ok.clone(), 9, "frame 9 is outside the animation's frames [0, 8]"),
            (ok.replace("frames = [0, 8]", "frames = [8, 0]"), 0, "first <= last"),
            (ok.replace("fps = 4", "fps = 0"), 0, "animation.fps must be in (0, 1000]"),
            (
                ok.replace(
                    "material = \"red\"\n",
                    "material = \"red\"\nmotion = { translate = [1, 0, 0] }\n",
                ),
                0,
                "`motion` or `keys`",
            ),
            (ok.replace("translate = [8, 0, 0]", "scale = [1, 2, 1]"), 0, "scale must be uniform"),
            (ok.replace(", translate = [8, 0, 0]", ""), 0, "the key at frame 8 sets nothing"),
            (ok.replace("translate = [8, 0, 0]", "translate = [1e30, 0, 0]"), 0, "beyond the limit"),
        ];
        for (text, f, want) in cases {
            let e = err(&text, f);
            assert!(e.message.contains(want), "want {want:?}, got {e}");
            assert_eq!(e.file, "a.toml");
            assert!(e.line > 1, "{e}");
        }
        // Scale keys that cross zero are refused at the frame that reaches it.
        let through = ok
            .replace("[[sphere]]\nradius = 1", "[[box]]\nmin = [-1, -1, -1]\nmax = [1, 1, 1]")
            .replace("translate = [0, 0, 0]", "scale = 1")
            .replace("translate = [8, 0, 0]", "scale = -1");
        frame(&through, 3);
        let e = err(&through, 4);
        assert!(e.message.contains("box: at frame 4 its scale is"), "{e}");
        // The camera flying through its look_at point.
        let cam = BASE.replace(
            "look_at = [0, 0, 0]\n",
            "look_at = [0, 0, 0]\nkeys = [{ frame = 0, position = [0, 0, 5] }, { frame = 2, position = [0, 0, -5] }]\n",
        ) + "[animation]\nframes = [0, 2]\n";
        let e = err(&cam, 1);
        assert!(e.message.contains("camera: at frame 1"), "{e}");
        assert_eq!(e.line, 6, "{e}");
    }
}
