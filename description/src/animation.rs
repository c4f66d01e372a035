//! Animation curves: keyframed values sampled at a time, and a frame's time window.
//!
//! The curves follow glTF 2.0's animation sampler semantics (its section 3.11 and appendix
//! C), so that the glTF loader and the TOML keyframes share one evaluator:
//! - `Step` holds a key's value until the next key;
//! - `Linear` interpolates linearly (rotations by spherical linear interpolation along the
//!   shorter arc);
//! - `CubicSpline` is a cubic Hermite spline whose keys each hold an in-tangent, a value
//!   and an out-tangent; the tangents are derivatives per second, so they are scaled by
//!   the key interval (`t[k+1] - t[k]`) before use, as glTF defines.
//!
//! Before the first key a track holds its first value, after the last key its last value.

use glam::{Quat, Vec3};

use crate::math;

/// How a track's value goes from one key to the next.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// The key's value holds until the next key.
    Step,
    /// Linear between keys; spherical linear (shortest arc) for rotations.
    #[default]
    Linear,
    /// Cubic Hermite spline with explicit tangents per key (glTF's `CUBICSPLINE`).
    CubicSpline,
}

impl Interpolation {
    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Interpolation::Step => "step",
            Interpolation::Linear => "linear",
            Interpolation::CubicSpline => "cubic",
        }
    }
}

/// Keyframes of one value: times ascending (seconds); for CubicSpline each key holds
/// (in-tangent, value, out-tangent) as glTF does.
#[derive(Debug, Clone, PartialEq)]
pub struct Track<T> {
    /// How values are interpolated between keys.
    pub interpolation: Interpolation,
    /// Key times in seconds, strictly ascending.
    pub times: Vec<f32>,
    /// One value per key, or for `CubicSpline` three per key: in-tangent, value,
    /// out-tangent.
    pub values: Vec<T>,
}

/// Why a track cannot be sampled as it stands.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrackError {
    /// No keys at all.
    #[error("the track has no keys")]
    Empty,
    /// A time is not finite.
    #[error("key {index}: time {time} is not a finite number")]
    NonFinite {
        /// The key's index.
        index: usize,
        /// Its time.
        time: f32,
    },
    /// Times are not strictly ascending.
    #[error("key {index}: time {time} is not after the previous key's {previous}")]
    OutOfOrder {
        /// The key's index.
        index: usize,
        /// Its time.
        time: f32,
        /// The previous key's time.
        previous: f32,
    },
    /// The values do not match the keys.
    #[error("{values} values for {keys} keys ({interpolation} needs {expected})")]
    ValueCount {
        /// Number of values.
        values: usize,
        /// Number of keys.
        keys: usize,
        /// The interpolation's name.
        interpolation: &'static str,
        /// How many values it needs.
        expected: usize,
    },
}

impl<T> Track<T> {
    /// A track holding one value at all times.
    pub fn constant(value: T) -> Track<T> {
        Track { interpolation: Interpolation::Step, times: vec![0.0], values: vec![value] }
    }

    /// Checks what sampling relies on: at least one key, finite times strictly ascending,
    /// and one value per key (three for `CubicSpline`).
    pub fn check(&self) -> Result<(), TrackError> {
        if self.times.is_empty() {
            return Err(TrackError::Empty);
        }
        for (index, &time) in self.times.iter().enumerate() {
            if !time.is_finite() {
                return Err(TrackError::NonFinite { index, time });
            }
            if index > 0 && !(time > self.times[index - 1]) {
                let previous = self.times[index - 1];
                return Err(TrackError::OutOfOrder { index, time, previous });
            }
        }
        let per_key = if self.interpolation == Interpolation::CubicSpline { 3 } else { 1 };
        let expected = per_key * self.times.len();
        if self.values.len() != expected {
            return Err(TrackError::ValueCount {
                values: self.values.len(),
                keys: self.times.len(),
                interpolation: self.interpolation.name(),
                expected,
            });
        }
        Ok(())
    }

    /// Whether the value can change with time.
    pub fn is_animated(&self) -> bool {
        self.times.len() > 1
    }

    /// The segment holding `t`: `Hold(k)` for the value of key `k` alone (clamped ends,
    /// steps), or `Between(k, s)` for `s` in [0, 1) from key `k` to key `k + 1`.
    fn locate(&self, t: f32) -> Segment {
        let keys = self.times.len().min(self.values.len() / self.per_key().max(1));
        if keys == 0 {
            return Segment::None;
        }
        let times = &self.times[..keys];
        // NaN times fall before every key: the first value, never a panic.
        if !(t > times[0]) {
            return Segment::Hold(0);
        }
        if t >= times[keys - 1] {
            return Segment::Hold(keys - 1);
        }
        // times[k] <= t < times[k + 1], with 0 <= k < keys - 1.
        let k = times.partition_point(|&x| x <= t) - 1;
        if self.interpolation == Interpolation::Step {
            return Segment::Hold(k);
        }
        let dt = times[k + 1] - times[k];
        if !(dt > 0.0) {
            return Segment::Hold(k + 1);
        }
        Segment::Between(k, ((t - times[k]) / dt).clamp(0.0, 1.0), dt)
    }

    fn per_key(&self) -> usize {
        if self.interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        }
    }

    /// Key `k`'s value.
    fn value(&self, k: usize) -> &T {
        &self.values[k * self.per_key() + usize::from(self.interpolation == Interpolation::CubicSpline)]
    }

    /// The Hermite control points of segment `k` scaled by its interval `dt`:
    /// (value k, out-tangent k × dt, value k+1, in-tangent k+1 × dt) as glTF's appendix C.
    fn hermite(&self, k: usize) -> (&T, &T, &T, &T) {
        let v = &self.values;
        (&v[3 * k + 1], &v[3 * k + 2], &v[3 * (k + 1) + 1], &v[3 * (k + 1)])
    }
}

enum Segment {
    None,
    Hold(usize),
    Between(usize, f32, f32),
}

/// The cubic Hermite basis at `s`: weights of p0, m0, p1, m1.
fn hermite_basis(s: f32) -> (f32, f32, f32, f32) {
    let (s2, s3) = (s * s, s * s * s);
    (2.0 * s3 - 3.0 * s2 + 1.0, s3 - 2.0 * s2 + s, -2.0 * s3 + 3.0 * s2, s3 - s2)
}

impl Track<Vec3> {
    /// The value at time `t` (seconds); zero for a track without keys.
    pub fn sample(&self, t: f32) -> Vec3 {
        match self.locate(t) {
            Segment::None => Vec3::ZERO,
            Segment::Hold(k) => *self.value(k),
            Segment::Between(k, s, dt) => match self.interpolation {
                Interpolation::CubicSpline => {
                    let (p0, m0, p1, m1) = self.hermite(k);
                    let (a, b, c, d) = hermite_basis(s);
                    *p0 * a + *m0 * (b * dt) + *p1 * c + *m1 * (d * dt)
                }
                _ => self.value(k).lerp(*self.value(k + 1), s),
            },
        }
    }
}

impl Track<f32> {
    /// The value at time `t` (seconds); zero for a track without keys.
    pub fn sample(&self, t: f32) -> f32 {
        match self.locate(t) {
            Segment::None => 0.0,
            Segment::Hold(k) => *self.value(k),
            Segment::Between(k, s, dt) => match self.interpolation {
                Interpolation::CubicSpline => {
                    let (p0, m0, p1, m1) = self.hermite(k);
                    let (a, b, c, d) = hermite_basis(s);
                    p0 * a + m0 * (b * dt) + p1 * c + m1 * (d * dt)
                }
                _ => {
                    let (a, b) = (*self.value(k), *self.value(k + 1));
                    a + (b - a) * s
                }
            },
        }
    }
}

impl Track<Quat> {
    /// The rotation at time `t` (seconds), normalised; identity for a track without keys.
    /// `Linear` takes the shorter arc between keys (a key and its negation are one
    /// rotation); `CubicSpline` interpolates the quaternions' components and normalises,
    /// as glTF specifies.
    pub fn sample(&self, t: f32) -> Quat {
        let q = match self.locate(t) {
            Segment::None => Quat::IDENTITY,
            Segment::Hold(k) => *self.value(k),
            Segment::Between(k, s, dt) => match self.interpolation {
                Interpolation::CubicSpline => {
                    let (p0, m0, p1, m1) = self.hermite(k);
                    let (a, b, c, d) = hermite_basis(s);
                    *p0 * a + *m0 * (b * dt) + *p1 * c + *m1 * (d * dt)
                }
                _ => math::slerp(
                    math::quat_normalize(*self.value(k)),
                    math::quat_normalize(*self.value(k + 1)),
                    s,
                ),
            },
        };
        let n = math::quat_normalize(q);
        if n.is_finite() {
            n
        } else {
            Quat::IDENTITY
        }
    }
}

/// A frame's time window: the scene is evaluated at `open` (Object.transform) and
/// `close` (Object.motion, when different), in seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTime {
    /// The frame number.
    pub frame: u32,
    /// When the shutter opens, seconds.
    pub open: f32,
    /// When the shutter closes, seconds.
    pub close: f32,
}

impl FrameTime {
    /// Frame `frame` at `fps` frames per second with the shutter open over the fractions
    /// `shutter` of the frame interval: frame `f` starts at `f / fps` seconds (frame 0 at
    /// time 0, as glTF animations start), opens at `(f + shutter.0) / fps` and closes at
    /// `(f + shutter.1) / fps`.
    pub fn new(frame: u32, fps: f32, shutter: (f32, f32)) -> FrameTime {
        let f = frame as f64;
        let fps = fps as f64;
        FrameTime {
            frame,
            open: ((f + shutter.0 as f64) / fps) as f32,
            close: ((f + shutter.1 as f64) / fps) as f32,
        }
    }

    /// The time of frame `frame`'s start (a key at that frame sits here).
    pub fn frame_start(frame: f64, fps: f32) -> f32 {
        (frame / fps as f64) as f32
    }
}

/// An animated scene's frames, and the frame a description stands at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sequence {
    /// Frames per second.
    pub fps: f32,
    /// First and last frame, inclusive.
    pub frames: (u32, u32),
    /// The frame this description was evaluated at, with its shutter window.
    pub time: FrameTime,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::{FRAC_PI_2, PI};

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() < 1e-5
    }

    fn track<T>(interpolation: Interpolation, times: &[f32], values: Vec<T>) -> Track<T> {
        let t = Track { interpolation, times: times.to_vec(), values };
        t.check().unwrap();
        t
    }

    #[test]
    fn linear_midpoints_and_clamped_ends() {
        let t = track(Interpolation::Linear, &[1.0, 3.0], vec![Vec3::ZERO, Vec3::new(2.0, 4.0, -6.0)]);
        assert_eq!(t.sample(2.0), Vec3::new(1.0, 2.0, -3.0));
        assert_eq!(t.sample(1.5), Vec3::new(0.5, 1.0, -1.5));
        assert_eq!(t.sample(-10.0), Vec3::ZERO);
        assert_eq!(t.sample(1.0), Vec3::ZERO);
        assert_eq!(t.sample(3.0), Vec3::new(2.0, 4.0, -6.0));
        assert_eq!(t.sample(99.0), Vec3::new(2.0, 4.0, -6.0));
        assert_eq!(t.sample(f32::NAN), Vec3::ZERO);
        let s = track(Interpolation::Linear, &[0.0, 1.0, 2.0], vec![0.0, 10.0, 0.0]);
        assert_eq!(s.sample(0.25), 2.5);
        assert_eq!(s.sample(1.0), 10.0);
        assert_eq!(s.sample(1.75), 2.5);
    }

    #[test]
    fn step_holds_until_the_next_key() {
        let t = track(Interpolation::Step, &[0.0, 1.0, 2.0], vec![1.0, 5.0, 9.0]);
        assert_eq!(t.sample(-1.0), 1.0);
        assert_eq!(t.sample(0.0), 1.0);
        assert_eq!(t.sample(0.999), 1.0);
        assert_eq!(t.sample(1.0), 5.0);
        assert_eq!(t.sample(1.5), 5.0);
        assert_eq!(t.sample(2.0), 9.0);
        assert_eq!(t.sample(7.0), 9.0);
    }

    #[test]
    fn cubic_spline_passes_through_its_keys() {
        // Arbitrary tangents: a Hermite spline still takes each key's value at its knot.
        let v = |x: f32| Vec3::new(x, -x, 2.0 * x);
        let t = track(
            Interpolation::CubicSpline,
            &[0.0, 0.5, 2.0],
            vec![v(7.0), v(1.0), v(-3.0), v(4.0), v(2.0), v(9.0), v(-5.0), v(3.0), v(0.0)],
        );
        assert!(close(t.sample(0.0), v(1.0)));
        assert!(close(t.sample(0.5), v(2.0)));
        assert!(close(t.sample(2.0), v(3.0)));
        // Approaching a knot from below converges on its value too.
        assert!(close(t.sample(0.5 - 1e-6), v(2.0)));
        assert!(close(t.sample(-1.0), v(1.0)));
        assert!(close(t.sample(5.0), v(3.0)));
    }

    #[test]
    fn cubic_spline_scales_tangents_by_the_key_interval() {
        // p(s) = (2s³-3s²+1)p0 + (s³-2s²+s)·dt·b0 + (-2s³+3s²)p1 + (s³-s²)·dt·a1 (glTF
        // appendix C). Keys at t = 1 and t = 3 (dt = 2), values 0 and 1, out-tangent 1,
        // in-tangent 0: at s = 1/2 the weights are 1/2, 1/8, 1/2, -1/8, so
        // p = 0 + 2·1/8 + 1/2 + 0 = 0.75.
        let t = track(Interpolation::CubicSpline, &[1.0, 3.0], vec![0.0, 0.0, 1.0, 0.0, 1.0, 0.0]);
        assert!((t.sample(2.0) - 0.75).abs() < 1e-6);
        // The derivative per second at the first key is its out-tangent: p(1 + h) ≈ h·1.
        let h = 1e-3;
        assert!(((t.sample(1.0 + h) - t.sample(1.0)) / h - 1.0).abs() < 1e-2);
        // A straight line with tangents equal to its slope is reproduced exactly:
        // values 0 → 6 over 3 s, slope 2 per second.
        let line = track(Interpolation::CubicSpline, &[0.0, 3.0], vec![2.0, 0.0, 2.0, 2.0, 6.0, 2.0]);
        for x in [0.3f32, 1.0, 1.5, 2.9] {
            assert!((line.sample(x) - 2.0 * x).abs() < 1e-5, "{x}");
        }
    }

    #[test]
    fn rotations_slerp_along_the_shorter_arc() {
        let a = Quat::IDENTITY;
        let b = Quat::from_rotation_y(FRAC_PI_2);
        let t = track(Interpolation::Linear, &[0.0, 1.0], vec![a, b]);
        let mid = t.sample(0.5);
        assert!(mid.angle_between(Quat::from_rotation_y(FRAC_PI_2 / 2.0)) < 1e-4);
        assert!((math::quat_dot(mid, mid).sqrt() - 1.0).abs() < 1e-6);
        // The same end given as its negation (the same rotation) takes the same path.
        let neg = track(Interpolation::Linear, &[0.0, 1.0], vec![a, -b]);
        assert!(neg.sample(0.5).angle_between(mid) < 1e-4);
        // From +170° to -170° about z: the short way crosses 180°, not 0°.
        let deg = PI / 180.0;
        let wrap = track(
            Interpolation::Linear,
            &[0.0, 1.0],
            vec![Quat::from_rotation_z(170.0 * deg), Quat::from_rotation_z(-170.0 * deg)],
        );
        let m = wrap.sample(0.5);
        assert!(m.angle_between(Quat::from_rotation_z(PI)) < 1e-3, "{m:?}");
        // Clamped at both ends, and normalised.
        assert!(t.sample(-1.0).angle_between(a) < 1e-6);
        assert!(t.sample(2.0).angle_between(b) < 1e-6);
    }

    #[test]
    fn cubic_rotation_is_normalised_and_hits_its_keys() {
        let (a, b) = (Quat::IDENTITY, Quat::from_rotation_x(1.0));
        let z = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0);
        let t = track(Interpolation::CubicSpline, &[0.0, 2.0], vec![z, a, z, z, b, z]);
        assert!(t.sample(0.0).angle_between(a) < 1e-6);
        assert!(t.sample(2.0).angle_between(b) < 1e-4);
        let q = t.sample(0.7);
        assert!((math::quat_dot(q, q).sqrt() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn check_refuses_what_cannot_be_sampled() {
        let empty: Track<f32> = Track { interpolation: Interpolation::Linear, times: vec![], values: vec![] };
        assert_eq!(empty.check(), Err(TrackError::Empty));
        assert_eq!(empty.sample(1.0), 0.0);
        let order =
            Track { interpolation: Interpolation::Linear, times: vec![0.0, 0.0], values: vec![1.0, 2.0] };
        assert!(matches!(order.check(), Err(TrackError::OutOfOrder { index: 1, .. })));
        let count = Track {
            interpolation: Interpolation::CubicSpline,
            times: vec![0.0, 1.0],
            values: vec![1.0, 2.0],
        };
        assert_eq!(count.check().unwrap_err().to_string(), "2 values for 2 keys (cubic needs 6)");
        // A malformed track samples without panicking.
        let _ = count.sample(0.5);
        let nan = Track { interpolation: Interpolation::Linear, times: vec![f32::NAN], values: vec![1.0] };
        assert!(matches!(nan.check(), Err(TrackError::NonFinite { index: 0, .. })));
    }

    #[test]
    fn frame_times_follow_the_shutter() {
        let f = FrameTime::new(12, 24.0, (0.0, 0.5));
        assert_eq!(f.open, 0.5);
        assert_eq!(f.close, 12.5 / 24.0);
        let still = FrameTime::new(3, 24.0, (0.0, 0.0));
        assert_eq!(still.open, still.close);
    }
}
