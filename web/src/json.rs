//! The JSON of jobs and workers, from the gRPC status (`docs/http-api.md`).

use serde::Serialize;
use tessera_description::job::Noise;
use tessera_proto::convert::{halted_from_wire, settings_from_wire};
use tessera_proto::v1 as pb;

/// A job as the API shows it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct Job {
    pub id: u64,
    pub scene: String,
    pub state: &'static str,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub pass: u32,
    pub samples_done: u64,
    pub samples_total: u64,
    pub progress: f64,
    pub samples_per_second: f64,
    pub elapsed_seconds: f64,
    pub eta_seconds: Option<f64>,
    pub priority: i32,
    pub workers: u32,
    pub error: Option<String>,
    pub owner: String,
    /// The job's time budget, if it has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_limit_seconds: Option<f64>,
    /// The job's noise target, if it has one: then pixels stop as they reach it, and
    /// `progress` counts samples against the most (`spp`) a pixel may take.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseTarget>,
    /// What ended a job that is done short of its spp: `time budget` or `noise target`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ended_by: Option<&'static str>,
    /// A sequence's frames, `[first, last]` (absent for a still).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frames: Option<[u32; 2]>,
    /// Each frame of a sequence, in frame order (absent for a still).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub frame_progress: Vec<FrameProgress>,
}

/// A job's noise target as the API shows it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct NoiseTarget {
    /// `relative` or `absolute`.
    pub kind: &'static str,
    pub target: f64,
    /// Samples every pixel takes before the target may stop it.
    pub min_samples: u32,
}

/// One frame of a sequence as the API shows it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct FrameProgress {
    pub frame: u32,
    /// 0..=1.
    pub progress: f64,
    /// Whether every pixel of the frame has its pass-one sample (its preview is whole).
    pub previewed: bool,
}

/// A worker as the API shows it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct Worker {
    pub id: u64,
    pub name: String,
    pub threads: u32,
    pub batches_in_flight: u32,
    pub batches_done: u64,
    pub samples_per_second: f64,
    pub last_heard_seconds: f64,
    pub strikes: u32,
    pub quarantined: bool,
    pub quarantine_reason: Option<String>,
}

/// `GET /api/jobs` and the `status` event.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct Listing {
    pub jobs: Vec<Job>,
    pub workers: Vec<Worker>,
}

/// A job state's name in the API.
pub(crate) fn state_name(state: i32) -> &'static str {
    match pb::JobState::try_from(state) {
        Ok(pb::JobState::Queued) => "queued",
        Ok(pb::JobState::Running) => "running",
        Ok(pb::JobState::Paused) => "paused",
        Ok(pb::JobState::Done) => "done",
        Ok(pb::JobState::Cancelled) => "cancelled",
        Ok(pb::JobState::Failed) => "failed",
        _ => "unknown",
    }
}

fn nonempty(s: String) -> Option<String> {
    (!s.is_empty()).then_some(s)
}

impl From<pb::JobStatus> for Job {
    fn from(j: pb::JobStatus) -> Self {
        // A job its noise target or time budget ended is done, short of its spp.
        let finished = j.state == pb::JobState::Done as i32;
        let progress = if finished {
            1.0
        } else if j.samples_total == 0 {
            0.0
        } else {
            j.samples_done as f64 / j.samples_total as f64
        };
        let left = j.samples_total.saturating_sub(j.samples_done);
        let running = j.state == pb::JobState::Running as i32;
        // Settings a coordinator cannot have accepted are shown as none.
        let settings = j.settings.and_then(|s| settings_from_wire(s).ok()).unwrap_or_default();
        let time_limit_seconds = settings.time_limit.map(|t| t.as_secs_f64());
        let noise = settings.adaptive().map(|(n, min_samples)| NoiseTarget {
            kind: match n {
                Noise::Relative(_) => "relative",
                Noise::Absolute(_) => "absolute",
            },
            // The f32 the job keeps, as its shortest decimal (0.05, not 0.0500000007).
            target: n.value().to_string().parse().unwrap_or(f64::from(n.value())),
            min_samples,
        });
        // Where pixels stop at a noise target, the samples left are a bound, not a
        // forecast: no estimate. A time budget ends the job at its end at the latest.
        let eta_seconds =
            (running && noise.is_none() && j.samples_per_second > 0.0 && j.samples_per_second.is_finite())
                .then(|| left as f64 / j.samples_per_second);
        let budget_left = time_limit_seconds.map(|t| (t - j.elapsed_seconds).max(0.0)).filter(|_| running);
        let eta_seconds = match (eta_seconds, budget_left) {
            (Some(e), Some(b)) => Some(e.min(b)),
            (e, b) => e.or(b),
        };
        let frame_pixels = u64::from(j.width) * u64::from(j.height);
        let frame_progress = j
            .frame_status
            .iter()
            .map(|f| FrameProgress {
                frame: f.frame,
                progress: (f.samples_done as f64 / f.samples_total.max(1) as f64).clamp(0.0, 1.0),
                previewed: f.pass_one_done >= frame_pixels,
            })
            .collect();
        Job {
            id: j.job_id,
            state: state_name(j.state),
            scene: j.scene,
            width: j.width,
            height: j.height,
            spp: j.spp,
            pass: j.pass,
            samples_done: j.samples_done,
            samples_total: j.samples_total,
            progress: progress.clamp(0.0, 1.0),
            samples_per_second: j.samples_per_second,
            elapsed_seconds: j.elapsed_seconds,
            eta_seconds,
            priority: j.priority,
            workers: j.workers,
            error: nonempty(j.error),
            owner: j.owner,
            time_limit_seconds,
            noise,
            ended_by: halted_from_wire(&j.halted).filter(|_| finished),
            frames: j.frames.map(|f| [f.first, f.last]),
            frame_progress,
        }
    }
}

impl From<pb::WorkerStatus> for Worker {
    fn from(w: pb::WorkerStatus) -> Self {
        Worker {
            id: w.worker_id,
            name: w.name,
            threads: w.threads,
            batches_in_flight: w.batches_in_flight,
            batches_done: w.batches_done,
            samples_per_second: w.samples_per_second,
            last_heard_seconds: w.last_heard_seconds,
            strikes: w.strikes,
            quarantined: w.quarantined,
            quarantine_reason: nonempty(w.quarantine_reason),
        }
    }
}

/// The listing of a status response.
pub(crate) fn listing(s: pb::StatusResponse) -> Listing {
    Listing {
        jobs: s.jobs.into_iter().map(Job::from).collect(),
        workers: s.workers.into_iter().map(Worker::from).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;
    use tessera_description::job::JobSettings;
    use tessera_proto::convert::settings_to_wire;

    fn running(settings: JobSettings, elapsed_seconds: f64) -> Job {
        Job::from(pb::JobStatus {
            state: pb::JobState::Running as i32,
            samples_done: 1000,
            samples_total: 5000,
            samples_per_second: 100.0,
            elapsed_seconds,
            settings: Some(settings_to_wire(&settings)),
            ..Default::default()
        })
    }

    #[test]
    fn the_eta_is_the_samples_left_unless_a_budget_ends_sooner_or_a_target_decides() {
        assert_eq!(running(JobSettings::default(), 5.0).eta_seconds, Some(40.0));
        let budget = JobSettings { time_limit: Some(Duration::from_secs(15)), ..JobSettings::default() };
        let j = running(budget.clone(), 5.0);
        assert_eq!((j.eta_seconds, j.time_limit_seconds), (Some(10.0), Some(15.0)));
        assert_eq!(running(budget, 100.0).eta_seconds, Some(0.0));
        let target = JobSettings { noise: Some(Noise::Absolute(0.05)), ..JobSettings::default() };
        let j = running(target, 5.0);
        assert_eq!(j.eta_seconds, None);
        assert_eq!(j.noise, Some(NoiseTarget { kind: "absolute", target: 0.05, min_samples: 64 }));
        let json = serde_json::to_value(&j).unwrap();
        assert_eq!(json["noise"]["kind"], "absolute");
        assert_eq!(json["noise"]["min_samples"], 64);
        assert!(json.get("time_limit_seconds").is_none());
    }

    #[test]
    fn a_job_its_target_ended_is_done_and_says_so() {
        let j = Job::from(pb::JobStatus {
            state: pb::JobState::Done as i32,
            samples_done: 1000,
            samples_total: 5000,
            halted: "noise target".into(),
            ..Default::default()
        });
        assert_eq!((j.progress, j.ended_by), (1.0, Some("noise target")));
        let running = Job::from(pb::JobStatus {
            state: pb::JobState::Running as i32,
            samples_done: 1000,
            samples_total: 5000,
            ..Default::default()
        });
        assert_eq!((running.progress, running.ended_by), (0.2, None));
    }

    #[test]
    fn settings_that_make_no_sense_show_as_none() {
        let mut wire = settings_to_wire(&JobSettings::default());
        wire.noise = 0.1;
        wire.noise_absolute = 0.1;
        let j = Job::from(pb::JobStatus { settings: Some(wire), ..Default::default() });
        assert_eq!((j.noise, j.time_limit_seconds), (None, None));
    }
}
