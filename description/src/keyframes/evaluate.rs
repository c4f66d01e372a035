//! Every track of a scene sampled at one frame's shutter window into its description.

use glam::Vec3;

use super::camera::CameraTracks;
use super::clock::Clock;
use super::lights::LightTracks;
use super::objects::ObjectTracks;
use crate::animation::{FrameTime, Sequence};
use crate::ctx::{Ctx, R};
use crate::model::{Description, Light, Shape};
use crate::transform::Trs;

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
