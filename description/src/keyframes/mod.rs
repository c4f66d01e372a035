//! Keyframes in the scene file: the `[animation]` table (frames per second and the frame
//! range) and the `keys` of objects, the camera and lights, checked into animation tracks
//! and evaluated at one frame's shutter window. The tables themselves are serde structs in
//! `schema` (`AnimationDef`, `TransformKey`, ...).
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
//!
//! The parts: `clock` (the `[animation]` table checked), `tracks` (a table's keys checked
//! into a timeline and one track per value, with the Catmull-Rom tangents), `objects`,
//! `camera` and `lights` (each kind's keys into its tracks), and `evaluate` (every track
//! sampled at one frame into the description).

mod camera;
mod clock;
mod evaluate;
mod lights;
mod objects;
mod tracks;

#[cfg(test)]
mod tests;

pub(crate) use camera::{camera_tracks, CameraTracks};
pub(crate) use clock::{clock, Clock};
pub(crate) use evaluate::{evaluate, SceneTracks};
pub(crate) use lights::light_tracks;
pub(crate) use objects::{object_tracks, ObjectTracks};
