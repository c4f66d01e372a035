//! The JSON of jobs and workers, from the gRPC status (`docs/http-api.md`).

use serde::Serialize;
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
    /// A sequence's frames, `[first, last]` (absent for a still).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frames: Option<[u32; 2]>,
    /// Each frame of a sequence, in frame order (absent for a still).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub frame_progress: Vec<FrameProgress>,
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
        let progress =
            if j.samples_total == 0 { 0.0 } else { j.samples_done as f64 / j.samples_total as f64 };
        let left = j.samples_total.saturating_sub(j.samples_done);
        let running = j.state == pb::JobState::Running as i32;
        let eta_seconds = (running && j.samples_per_second > 0.0 && j.samples_per_second.is_finite())
            .then(|| left as f64 / j.samples_per_second);
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
