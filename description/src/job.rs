//! What a job asks of the farm beyond its scene, and where it stands: the settings a
//! submission may override and the job's state, shared by the coordinator, the wire
//! conversions and every client.

use std::time::Duration;

use crate::ids::JobId;

/// Settings a submission may override.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JobSettings {
    /// Samples per pixel (the most, with a time budget or noise target); `None` keeps the
    /// scene's.
    pub spp: Option<u32>,
    /// Image size; `None` keeps the scene's.
    pub size: Option<(u32, u32)>,
    /// Stop after this much rendering time, wherever the job is.
    pub time_limit: Option<Duration>,
    /// Stop sampling each pixel once its estimated error is below this.
    pub noise: Option<Noise>,
    /// Samples every pixel takes before the noise target may stop it; `None`: the
    /// target's own minimum ([`Noise::default_min_samples`]). Only with a target.
    pub noise_min: Option<u32>,
    /// First-hit layers to accumulate beside radiance.
    pub aovs: Aovs,
    /// Frames to render, inclusive; None: one still image.
    pub frames: Option<(u32, u32)>,
}

/// A per-pixel noise target (adaptive sampling): a pixel stops taking samples once the
/// estimated standard error of its mean, pooled with its neighbours', is below it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Noise {
    /// Relative to the pixel's brightness (the mean of its channels, floored at 0.05 so that
    /// black pixels converge too), in (0, 1): every pixel to the same relative quality,
    /// which is what an eye judges.
    Relative(f32),
    /// In the image's own linear units, positive: every pixel to the same absolute error,
    /// which is what an RMSE against a reference counts. The samples go where the absolute
    /// noise is, the bright highlights, and dark pixels stop at the minimum.
    Absolute(f32),
}

impl Noise {
    /// The target's number.
    pub fn value(self) -> f32 {
        match self {
            Noise::Relative(v) | Noise::Absolute(v) => v,
        }
    }

    /// The target if its number is in range (relative: in (0, 1); absolute: positive and
    /// finite), else a one-line reason that names it.
    pub fn checked(self) -> Result<Noise, String> {
        match self {
            Noise::Relative(v) if !(v.is_finite() && v > 0.0 && v < 1.0) => {
                Err(format!("the noise target must be a relative error in (0, 1), e.g. 0.01, got {v}"))
            }
            Noise::Absolute(v) if !(v.is_finite() && v > 0.0) => {
                Err(format!("the absolute noise target must be a positive number, e.g. 0.02, got {v}"))
            }
            n => Ok(n),
        }
    }

    /// Samples a pixel takes before this target may stop it, unless the job names its own
    /// minimum: 16 for a relative target (fewer give estimates too rough to trust); 64 for
    /// an absolute one, which stops the dark pixels at the minimum. Those are where rare
    /// bright paths hide (a glossy highlight's tail, light through frosted glass), and a
    /// pixel whose first samples missed them looks smooth and stops with the miss, low. On
    /// `spheres` at an absolute target of 0.05 (seeds 1–4), 64 instead of 16 halved that
    /// bias (0.12 % → 0.055 % of the image's light) and lowered the error for the time
    /// (docs/accuracy.md).
    pub fn default_min_samples(self) -> u32 {
        match self {
            Noise::Relative(_) => 16,
            Noise::Absolute(_) => 64,
        }
    }
}

/// A duration in seconds, as the command line takes it: `90s`, `2.5s`.
fn seconds_text(t: Duration) -> String {
    format!("{}s", t.as_secs_f64())
}

/// The fewest samples a noise target's minimum may be: a pixel's estimate compares its even
/// and odd samples, so it needs one of each.
pub const NOISE_MIN_SAMPLES_LEAST: u32 = 2;

impl std::fmt::Display for Noise {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Noise::Relative(v) => write!(f, "relative {v}"),
            Noise::Absolute(v) => write!(f, "absolute {v}"),
        }
    }
}

/// Which first-hit layers (arbitrary output variables) a job accumulates beside radiance:
/// what a compositor or a denoiser needs from the camera ray's first hit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Aovs {
    /// The surface's reflectance at the first hit.
    pub albedo: bool,
    /// The world-space shading normal at the first hit.
    pub normal: bool,
    /// The distance along the camera ray to the first hit.
    pub depth: bool,
}

impl JobSettings {
    /// Only spp and size: a job that runs to its sample count in the paper's two passes.
    pub fn sized(spp: Option<u32>, size: Option<(u32, u32)>) -> Self {
        JobSettings { spp, size, ..JobSettings::default() }
    }

    /// Whether pass two runs in rounds over the image (a time budget or a noise target).
    pub fn in_rounds(&self) -> bool {
        self.time_limit.is_some() || self.noise.is_some()
    }

    /// The noise target and the samples a pixel takes before it may stop it.
    pub fn adaptive(&self) -> Option<(Noise, u32)> {
        self.noise.map(|n| (n, self.noise_min.unwrap_or(n.default_min_samples())))
    }

    /// How a job with these settings may end before its sample count, in a few words for
    /// people (`tessera status`): its noise target with the samples a pixel takes first,
    /// its time budget; `None` when it runs to its sample count.
    pub fn early_end(&self) -> Option<String> {
        let noise = self.adaptive().map(|(n, min)| {
            let (kind, v) = match n {
                Noise::Relative(v) => ("a relative", v),
                Noise::Absolute(v) => ("an absolute", v),
            };
            format!("at {kind} noise of {v}, each pixel after at least {min} samples")
        });
        let time = self.time_limit.map(|t| format!("when its time budget of {} is spent", seconds_text(t)));
        match (noise, time) {
            (Some(n), Some(t)) => Some(format!("{n}, or {t}")),
            (one, other) => one.or(other),
        }
    }

    /// Whether `other` renders the same job: equal settings, where a noise minimum given as
    /// the target's own is the same as none (a `--resume` with it spelled out takes up the
    /// job started without it).
    pub fn same_job_as(&self, other: &JobSettings) -> bool {
        let plain = |s: &JobSettings| JobSettings { noise_min: None, ..s.clone() };
        plain(self) == plain(other) && self.adaptive() == other.adaptive()
    }

    /// The noise target and its minimum, if they make sense whatever the sample count: a
    /// target in range, and a minimum only beside a target and of at least
    /// [`NOISE_MIN_SAMPLES_LEAST`]. A one-line reason otherwise.
    pub fn checked_noise(&self) -> Result<(), String> {
        if let Some(n) = self.noise {
            n.checked()?;
        }
        match (self.noise, self.noise_min) {
            (None, Some(m)) => Err(format!(
                "a minimum of {m} samples for the noise target was given without a noise target"
            )),
            (Some(_), Some(m)) if m < NOISE_MIN_SAMPLES_LEAST => Err(format!(
                "the noise target's minimum must be at least {NOISE_MIN_SAMPLES_LEAST} samples (a pixel's estimate compares its even and odd samples), got {m}"
            )),
            _ => Ok(()),
        }
    }

    /// [`JobSettings::checked_noise`], and the minimum at most `spp`, the samples a pixel
    /// takes at most.
    pub fn checked_noise_for(&self, spp: u32) -> Result<(), String> {
        self.checked_noise()?;
        match self.noise_min {
            Some(m) if m > spp => Err(format!(
                "the noise target's minimum of {m} samples is more than the job's {spp} samples per pixel (its spp, or the scene's where it gives none)"
            )),
            _ => Ok(()),
        }
    }

    /// Frames the job renders: 1 for a still.
    pub fn frame_count(&self) -> u32 {
        self.frames.map_or(1, |(first, last)| last.saturating_sub(first).saturating_add(1))
    }
}

/// The most frames one job may hold.
pub const MAX_FRAMES: u32 = 10_000;

/// A frame range as people write it: `1-48` (inclusive) or one frame, `12`. The message
/// of an error is one line that names the input.
pub fn parse_frames(s: &str) -> Result<(u32, u32), String> {
    let number = |t: &str| {
        t.trim().parse::<u32>().map_err(|_| {
            format!(
                "--frames {s}: expected a frame range such as 1-48 (or one frame, 12), got {:?}",
                t.trim()
            )
        })
    };
    let (first, last) = match s.trim().split_once('-') {
        Some((a, b)) => (number(a)?, number(b)?),
        None => {
            let f = number(s)?;
            (f, f)
        }
    };
    check_frames(first, last).map_err(|e| format!("--frames {s}: {e}"))?;
    Ok((first, last))
}

/// Checks a frame range (inclusive): ascending and at most `MAX_FRAMES` frames.
pub fn check_frames(first: u32, last: u32) -> Result<(), String> {
    if last < first {
        return Err("the range is reversed".into());
    }
    let count = u64::from(last - first) + 1;
    if count > u64::from(MAX_FRAMES) {
        return Err(format!("{count} frames, more than the limit of {MAX_FRAMES} in one job"));
    }
    Ok(())
}

/// The progress of one frame of a sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameProgress {
    /// The frame number.
    pub frame: u32,
    /// Pass-one pixels merged.
    pub pass_one_done: u64,
    /// Samples merged.
    pub samples_done: u64,
    /// Samples in the frame.
    pub samples_total: u64,
}

/// Where a job stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum JobState {
    /// Waiting for its first batch to be leased.
    Queued,
    /// Batches are out.
    Running,
    /// Every sample is merged.
    Done,
    /// Stopped by a client.
    Cancelled,
    /// Stopped by an error.
    Failed(String),
    /// Paused by a client: no new batches until resumed.
    Paused,
}

impl JobState {
    /// Whether the job will hand out no more batches.
    pub fn is_over(&self) -> bool {
        matches!(self, JobState::Done | JobState::Cancelled | JobState::Failed(_))
    }

    /// The state's name as people read it: `queued`, `running`, `done`, …
    pub fn name(&self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Cancelled => "cancelled",
            JobState::Failed(_) => "failed",
            JobState::Paused => "paused",
        }
    }
}

/// [`JobProgress::halted`] of a job whose time budget ended it.
pub const HALTED_BY_TIME: &str = "time budget";
/// [`JobProgress::halted`] of a job whose every pixel reached its noise target.
pub const HALTED_BY_NOISE: &str = "noise target";

/// Progress figures of a job.
#[derive(Debug, Clone, PartialEq)]
pub struct JobProgress {
    /// The job.
    pub id: JobId,
    /// Scene name.
    pub scene: String,
    /// State.
    pub state: JobState,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// The pass being handed out.
    pub pass: u32,
    /// Samples merged.
    pub samples_done: u64,
    /// Samples in the job.
    pub samples_total: u64,
    /// Recent samples per second.
    pub samples_per_second: f64,
    /// Time since the first lease, across restarts (to the end, once over): what a time
    /// budget counts.
    pub elapsed: Duration,
    /// Pass-one pixels merged.
    pub pass_one_done: u64,
    /// Samples that came back NaN or infinite (counted as black).
    pub nonfinite_samples: u64,
    /// The job's priority.
    pub priority: i32,
    /// Why the job ended before its sample count: [`HALTED_BY_TIME`], or
    /// [`HALTED_BY_NOISE`] when every pixel reached its target.
    pub halted: Option<&'static str>,
    /// The settings the job was submitted with: how it may end before its sample count.
    pub settings: JobSettings,
    /// The frames of a sequence, inclusive (`None`: a still); the other figures are the
    /// whole sequence's, `width` and `height` one frame's.
    pub frames: Option<(u32, u32)>,
    /// Per frame of a sequence, in frame order (empty for a still).
    pub frame_progress: Vec<FrameProgress>,
}

impl JobProgress {
    /// Fraction done, 0..=1.
    pub fn fraction(&self) -> f64 {
        if self.samples_total == 0 {
            1.0
        } else {
            self.samples_done as f64 / self.samples_total as f64
        }
    }
}

/// A duration such as `90`, `90s`, `2m`, `1h30m` or `1.5h`.
pub fn parse_duration(s: &str) -> Result<std::time::Duration, String> {
    let bad = || format!("expected a duration such as 90s, 2m or 1h30m, got {s:?}");
    let mut total = 0.0f64;
    let mut number = String::new();
    let mut any = false;
    for c in s.trim().chars() {
        if c.is_ascii_digit() || c == '.' {
            number.push(c);
            continue;
        }
        let unit = match c {
            's' => 1.0,
            'm' => 60.0,
            'h' => 3600.0,
            _ => return Err(bad()),
        };
        total += number.parse::<f64>().map_err(|_| bad())? * unit;
        number.clear();
        any = true;
    }
    if !number.is_empty() {
        total += number.parse::<f64>().map_err(|_| bad())?;
        any = true;
    }
    if !(any && total.is_finite() && total > 0.0 && total < 1e9) {
        return Err(bad());
    }
    Ok(std::time::Duration::from_secs_f64(total))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_early_end_says_the_target_its_minimum_and_the_budget() {
        assert_eq!(JobSettings::sized(Some(64), None).early_end(), None);
        let noise = JobSettings { noise: Some(Noise::Absolute(0.05)), ..JobSettings::default() };
        assert_eq!(
            noise.early_end().as_deref(),
            Some("at an absolute noise of 0.05, each pixel after at least 64 samples")
        );
        let both = JobSettings {
            noise: Some(Noise::Relative(0.1)),
            noise_min: Some(32),
            time_limit: Some(Duration::from_millis(2500)),
            ..JobSettings::default()
        };
        assert_eq!(
            both.early_end().as_deref(),
            Some("at a relative noise of 0.1, each pixel after at least 32 samples, or when its time budget of 2.5s is spent")
        );
        let time = JobSettings { time_limit: Some(Duration::from_secs(90)), ..JobSettings::default() };
        assert_eq!(time.early_end().as_deref(), Some("when its time budget of 90s is spent"));
        let short = JobSettings { time_limit: Some(Duration::from_micros(500)), ..JobSettings::default() };
        assert_eq!(short.early_end().as_deref(), Some("when its time budget of 0.0005s is spent"));
    }

    #[test]
    fn frame_ranges_parse_and_bad_ones_get_one_line() {
        assert_eq!(parse_frames("1-48"), Ok((1, 48)));
        assert_eq!(parse_frames(" 7 "), Ok((7, 7)));
        assert_eq!(parse_frames("0-0"), Ok((0, 0)));
        assert_eq!(parse_frames("5-2"), Err("--frames 5-2: the range is reversed".into()));
        assert_eq!(
            parse_frames("1-20000"),
            Err("--frames 1-20000: 20000 frames, more than the limit of 10000 in one job".into())
        );
        assert_eq!(
            parse_frames("a-3"),
            Err("--frames a-3: expected a frame range such as 1-48 (or one frame, 12), got \"a\"".into())
        );
        assert!(parse_frames("-3").is_err() && parse_frames("1-").is_err() && parse_frames("").is_err());
        assert_eq!(JobSettings { frames: Some((3, 5)), ..JobSettings::default() }.frame_count(), 3);
        assert_eq!(JobSettings::default().frame_count(), 1);
    }

    #[test]
    fn a_noise_minimum_needs_a_target_and_fits_the_sample_count() {
        let with = |noise, noise_min| JobSettings { noise, noise_min, ..JobSettings::default() };
        let abs = Some(Noise::Absolute(0.05));
        assert_eq!(with(abs, None).adaptive(), Some((Noise::Absolute(0.05), 64)));
        assert_eq!(with(Some(Noise::Relative(0.1)), None).adaptive(), Some((Noise::Relative(0.1), 16)));
        assert_eq!(with(abs, Some(200)).adaptive(), Some((Noise::Absolute(0.05), 200)));
        assert_eq!(with(None, None).adaptive(), None);
        assert!(with(abs, Some(256)).checked_noise_for(256).is_ok());
        assert!(with(abs, Some(2)).checked_noise_for(256).is_ok());
        let no_target = with(None, Some(32)).checked_noise().unwrap_err();
        assert!(no_target.contains("without a noise target"), "{no_target}");
        let one = with(abs, Some(1)).checked_noise().unwrap_err();
        assert!(one.contains("at least 2 samples") && one.contains("got 1"), "{one}");
        let over = with(abs, Some(300)).checked_noise_for(256).unwrap_err();
        assert!(over.contains("minimum of 300 samples is more than the job's 256"), "{over}");
        assert!(with(abs, Some(64)).same_job_as(&with(abs, None)));
        assert!(!with(abs, Some(32)).same_job_as(&with(abs, None)));
        assert!(!with(abs, Some(16)).same_job_as(&with(Some(Noise::Relative(0.05)), Some(16))));
        let range = with(Some(Noise::Relative(2.0)), Some(32)).checked_noise().unwrap_err();
        assert!(range.contains("relative error in (0, 1)"), "{range}");
    }
}
