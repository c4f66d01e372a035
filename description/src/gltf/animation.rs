//! glTF animations (§3.11): translation, rotation and scale channels made into the
//! scene's animation tracks (`crate::animation::Track`, glTF's step/linear/cubic-spline
//! semantics) and sampled over a frame's shutter. Every animation is checked; the
//! first one (`animations[0]`) is the one played. Morph-target weights are not animated
//! (Tessera draws no morph targets).

use std::collections::BTreeMap;

use glam::{Quat, Vec3};
use gltf::json::accessor::{ComponentType, Type};
use gltf::json::animation::{Interpolation as GInterp, Property};
use gltf::json::validation::Checked;
use gltf::json::Root;

use super::accessors::{self, kind};
use super::{at, GltfError};
use crate::animation::{FrameTime, Interpolation, Track};

/// Which end of the shutter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum When {
    Open,
    Close,
}

/// A node's animated tracks.
#[derive(Debug, Default)]
struct NodeTracks {
    translation: Option<Track<Vec3>>,
    rotation: Option<Track<Quat>>,
    scale: Option<Track<Vec3>>,
}

/// The animated nodes' transforms at a frame's shutter open and close.
pub(crate) struct Poses {
    frame: Option<FrameTime>,
    tracks: BTreeMap<usize, NodeTracks>,
    rest: BTreeMap<usize, (Vec3, Quat, Vec3)>,
}

fn interpolation(i: &Checked<GInterp>) -> Interpolation {
    match i {
        Checked::Valid(GInterp::Step) => Interpolation::Step,
        Checked::Valid(GInterp::CubicSpline) => Interpolation::CubicSpline,
        _ => Interpolation::Linear,
    }
}

impl Poses {
    /// Checks every animation and keeps the first one's tracks.
    pub(crate) fn new(
        file: &str,
        root: &Root,
        buffers: &[Vec<u8>],
        frame: Option<FrameTime>,
    ) -> Result<Poses, GltfError> {
        let mut tracks: BTreeMap<usize, NodeTracks> = BTreeMap::new();
        for (a, anim) in root.animations.iter().enumerate() {
            for (c, ch) in anim.channels.iter().enumerate() {
                let path = at!("animations[{a}].channels[{c}]");
                let err = |p: String, m: String| GltfError::new(file, p, m);
                let s = ch.sampler.value();
                let Some(sampler) = anim.samplers.get(s) else {
                    return Err(err(at!("{path}.sampler"), format!("animation sampler {s} does not exist")));
                };
                let spath = at!("animations[{a}].samplers[{s}]");
                let (input, output) = (sampler.input.value(), sampler.output.value());
                let ia = &root.accessors[input];
                if kind(ia) != Some((ComponentType::F32, Type::Scalar)) {
                    return Err(err(
                        at!("{spath}.input"),
                        format!("accessor {input} must be SCALAR of FLOAT (key times)"),
                    ));
                }
                let prop = match &ch.target.path {
                    Checked::Valid(p) => *p,
                    Checked::Invalid => {
                        return Err(err(at!("{path}.target.path"), "is not a valid property".into()))
                    }
                };
                if prop == Property::MorphTargetWeights {
                    continue;
                }
                let oa = &root.accessors[output];
                let (want, ok) = match (prop, kind(oa)) {
                    (Property::Rotation, Some((c, Type::Vec4))) => (
                        "VEC4 of FLOAT or of normalized integers",
                        c == ComponentType::F32 || (oa.normalized && c != ComponentType::U32),
                    ),
                    (Property::Rotation, _) => ("VEC4 of FLOAT or of normalized integers", false),
                    (_, Some((c, t))) => ("VEC3 of FLOAT", c == ComponentType::F32 && t == Type::Vec3),
                    _ => ("VEC3 of FLOAT", false),
                };
                if !ok {
                    return Err(err(
                        at!("{spath}.output"),
                        format!("accessor {output} must be {want} for {prop:?}"),
                    ));
                }
                let unreadable = |i: usize, p: String| err(p, format!("accessor {i} cannot be read"));
                let times = accessors::floats(root, buffers, input)
                    .ok_or_else(|| unreadable(input, at!("{spath}.input")))?;
                let values = accessors::floats(root, buffers, output)
                    .ok_or_else(|| unreadable(output, at!("{spath}.output")))?;
                if values.iter().any(|v| !v.is_finite()) {
                    return Err(err(
                        at!("{spath}.output"),
                        format!("accessor {output} holds a value that is not finite"),
                    ));
                }
                let interpolation = interpolation(&sampler.interpolation);
                let node = ch.target.node.value();
                let check = |e: crate::animation::TrackError| err(spath.clone(), e.to_string());
                let entry = tracks.entry(node).or_default();
                let keep = a == 0;
                match prop {
                    Property::Rotation => {
                        let values: Vec<Quat> = values.chunks_exact(4).map(Quat::from_slice).collect();
                        let t = Track { interpolation, times, values };
                        t.check().map_err(check)?;
                        if keep {
                            entry.rotation = Some(t);
                        }
                    }
                    _ => {
                        let values: Vec<Vec3> = values.chunks_exact(3).map(Vec3::from_slice).collect();
                        let t = Track { interpolation, times, values };
                        t.check().map_err(check)?;
                        if keep && prop == Property::Translation {
                            entry.translation = Some(t);
                        } else if keep {
                            entry.scale = Some(t);
                        }
                    }
                }
            }
        }
        tracks.retain(|_, t| t.translation.is_some() || t.rotation.is_some() || t.scale.is_some());
        let rest = tracks
            .keys()
            .map(|&i| {
                let n = &root.nodes[i];
                let rest = (
                    n.translation.map_or(Vec3::ZERO, Vec3::from),
                    n.rotation.map_or(Quat::IDENTITY, |q| Quat::from_array(q.0)),
                    n.scale.map_or(Vec3::ONE, Vec3::from),
                );
                (i, rest)
            })
            .collect();
        Ok(Poses { frame, tracks, rest })
    }

    /// Whether animation drives node `i` (whether or not a frame is being evaluated).
    pub(crate) fn animates(&self, i: usize) -> bool {
        self.tracks.contains_key(&i)
    }

    /// Node `i`'s translation, rotation and scale at `when`, if animated and a frame is
    /// being evaluated (else the node's own values hold: its rest pose).
    pub(crate) fn trs(&self, i: usize, when: When) -> Option<(Vec3, Quat, Vec3)> {
        let f = self.frame?;
        let tracks = self.tracks.get(&i)?;
        let (t0, r0, s0) = *self.rest.get(&i)?;
        let t = if when == When::Open { f.open } else { f.close };
        Some((
            tracks.translation.as_ref().map_or(t0, |k| k.sample(t)),
            tracks.rotation.as_ref().map_or(r0, |k| k.sample(t)),
            tracks.scale.as_ref().map_or(s0, |k| k.sample(t)),
        ))
    }
}
