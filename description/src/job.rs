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
    /// Stop sampling each pixel once its estimated relative error is below this.
    pub noise: Option<f32>,
    /// Frames to render, inclusive; None: one still image.
    pub frames: Option<(u32, u32)>,
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
    /// Time since the first lease (to the end, once over).
    pub elapsed: Duration,
    /// Pass-one pixels merged.
    pub pass_one_done: u64,
    /// Samples that came back NaN or infinite (counted as black).
    pub nonfinite_samples: u64,
    /// The job's priority.
    pub priority: i32,
    /// Why the job ended before its sample count: "time budget", or "noise target" when
    /// every pixel reached it.
    pub halted: Option<&'static str>,
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
