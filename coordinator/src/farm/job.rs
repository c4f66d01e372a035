//! One job: its scene, its batches, its framebuffer, and the figures of its progress.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
use tessera_description::ids::{JobId, WorkerId};
use tessera_description::job::{
    FrameProgress, JobProgress, JobSettings, JobState, HALTED_BY_NOISE, HALTED_BY_TIME,
};
use tessera_film::aov::AovLayers;
use tessera_film::Framebuffer;

use crate::checkpoint::Checkpoint;
use crate::persist::JobRecord;
use crate::scheduler::{Completed, PassQueue};

use super::fence::JobFence;
use super::pace::Speeds;
use super::SubmitError;

/// The window over which samples per second are measured.
pub(super) const RATE_WINDOW: Duration = Duration::from_secs(5);

/// A job: its scene, its batches and its framebuffer.
#[derive(Debug)]
pub struct Job {
    /// The id.
    pub id: JobId,
    /// The scene as submitted.
    pub bundle: Arc<Bundle>,
    /// The bundle's content hash.
    pub scene_hash: String,
    /// The settings.
    pub settings: JobSettings,
    /// Higher priorities are served first; equal ones oldest first.
    pub priority: i32,
    /// Samples per pixel in effect.
    pub spp: u32,
    /// State.
    pub state: JobState,
    /// The name of the principal that submitted it ("" for an in-process submission):
    /// submitters see and control only their own jobs.
    pub owner: String,
    pub(super) queue: PassQueue,
    pub(super) framebuffer: Framebuffer,
    /// The AOV layers, beside the framebuffer (empty when the job keeps none).
    pub(super) aov: AovLayers,
    pub(super) started: Option<Instant>,
    pub(super) finished: Option<Instant>,
    /// (time, samples done) points for the recent rate.
    pub(super) rate: VecDeque<(Instant, u64)>,
    /// Tokens released, failures by identity, deliveries, audits and repairs.
    pub(super) fence: JobFence,
    /// Each worker's speed on this job, for sizing its pass-two batches.
    pub(super) speeds: Speeds,
    pub(super) nonfinite_samples: u64,
    /// Rendering time before a restart, counted against a time budget.
    pub(super) spent_before: Duration,
    /// Time paused since `started`, not counted against a time budget, and when the
    /// current pause began (`None` unless paused after starting).
    pub(super) paused_for: Duration,
    pub(super) paused_at: Option<Instant>,
    pub(super) halted: Option<&'static str>,
    /// When every batch was merged and no repair was left, while audits still ran: the
    /// start of their grace (see `Farm::settle`).
    pub(super) audits_since: Option<Instant>,
}

impl Job {
    /// The framebuffer.
    pub fn framebuffer(&self) -> &Framebuffer {
        &self.framebuffer
    }

    /// The AOV layers (their sample counts are the framebuffer's).
    pub fn aov(&self) -> &AovLayers {
        &self.aov
    }

    /// Whether the job will hand out no more batches.
    pub fn is_over(&self) -> bool {
        matches!(self.state, JobState::Done | JobState::Cancelled | JobState::Failed(_))
    }

    /// A snapshot of progress.
    pub fn progress(&self, now: Instant) -> JobProgress {
        // A paused job renders nothing (the batches it had out still merge), and its
        // window starts again when it resumes (`set_paused`).
        let rate = match (self.rate.front(), self.rate.back()) {
            (Some(&(t0, s0)), Some(&(t1, s1))) if t1 > t0 && self.state != JobState::Paused => {
                (s1 - s0) as f64 / (t1 - t0).as_secs_f64()
            }
            _ => 0.0,
        };
        JobProgress {
            id: self.id,
            scene: self.bundle.name.clone(),
            state: self.state.clone(),
            width: self.framebuffer.width(),
            height: self.queue.frame_height(),
            spp: self.spp,
            pass: self.queue.pass().number(),
            samples_done: self.queue.samples_done(),
            samples_total: self.queue.samples_total(),
            samples_per_second: rate,
            elapsed: self.spent(now),
            pass_one_done: self.queue.pass_one_pixels_done(),
            nonfinite_samples: self.nonfinite_samples,
            priority: self.priority,
            halted: self.halted,
            settings: self.settings.clone(),
            frames: self.settings.frames,
            frame_progress: self.frame_progress(),
        }
    }

    /// Each frame's progress, in frame order (empty for a still).
    fn frame_progress(&self) -> Vec<FrameProgress> {
        let Some((first, _)) = self.settings.frames else { return Vec::new() };
        let frame_pixels = u64::from(self.framebuffer.width()) * u64::from(self.queue.frame_height());
        let frame_total = frame_pixels * u64::from(self.spp);
        let done = self.queue.frames_done().iter().enumerate();
        done.map(|(k, &(pass_one_done, samples_done))| FrameProgress {
            frame: first + k as u32,
            pass_one_done,
            samples_done,
            samples_total: frame_total,
        })
        .collect()
    }

    /// The frames of a sequence, inclusive; `None` for a still.
    pub fn frames(&self) -> Option<(u32, u32)> {
        self.settings.frames
    }

    /// One frame's height (the framebuffer stacks a sequence's frames: frame `first + k`
    /// is rows `k · frame_height ..`).
    pub fn frame_height(&self) -> u32 {
        self.queue.frame_height()
    }

    /// The stacked index (0 for the first frame) of frame `frame`, or of the first frame
    /// when `None`; `None` when the job has no such frame. A still's only frame is
    /// `None` or 0.
    pub fn frame_index(&self, frame: Option<u32>) -> Option<u32> {
        match (self.settings.frames, frame) {
            (None, None | Some(0)) => Some(0),
            (None, Some(_)) => None,
            (Some(_), None) => Some(0),
            (Some((first, last)), Some(f)) => (first..=last).contains(&f).then(|| f - first),
        }
    }

    /// Rendering time so far, across restarts: the time since the first lease, less the
    /// time paused, which a user pausing a job with a budget does not mean to spend.
    pub fn spent(&self, now: Instant) -> Duration {
        let Some(started) = self.started else { return self.spent_before };
        let end = self.finished.unwrap_or(now);
        let paused =
            self.paused_for + self.paused_at.map_or(Duration::ZERO, |p| end.saturating_duration_since(p));
        self.spent_before + end.saturating_duration_since(started).saturating_sub(paused)
    }

    /// Pauses or resumes the job at `now`; a job that is over stays as it is.
    pub(super) fn set_paused(&mut self, paused: bool, now: Instant) {
        match (&self.state, paused) {
            (JobState::Queued | JobState::Running, true) => {
                self.state = JobState::Paused;
                if self.started.is_some() {
                    self.paused_at = Some(now);
                }
            }
            (JobState::Paused, false) => {
                if let Some(at) = self.paused_at.take() {
                    self.paused_for += now.saturating_duration_since(at);
                    // The rate's window restarts here: measured across the pause, the
                    // samples of its first seconds back would be spread over the pause
                    // too, and the rate and a client's time left off by as much.
                    self.rate.clear();
                    self.rate.push_back((now, self.queue.samples_done()));
                }
                self.state = if self.started.is_some() { JobState::Running } else { JobState::Queued }
            }
            _ => {}
        }
    }

    /// Ends the job if its time budget is spent; returns whether it did.
    pub(super) fn enforce_deadline(&mut self, now: Instant) -> bool {
        let Some(limit) = self.settings.time_limit else { return false };
        if self.is_over() || self.state == JobState::Paused || self.spent(now) < limit {
            return false;
        }
        self.abandon_all();
        self.state = JobState::Done;
        self.finished = Some(now);
        self.halted = Some(HALTED_BY_TIME);
        true
    }

    /// When its first batch was leased (this run of the coordinator; `None` before).
    pub fn started(&self) -> Option<Instant> {
        self.started
    }

    /// Whether every pixel has its pass-one sample.
    pub fn pass_one_complete(&self) -> bool {
        let fb = &self.framebuffer;
        self.queue.pass_one_pixels_done() == u64::from(fb.width()) * u64::from(fb.height())
    }

    /// The job's state now, for a checkpoint: merged batches and accumulators. Leased
    /// batches are not in it; a restart renders them again. Cheap (the framebuffer is
    /// shared, copy-on-write), so it is taken under the farm's lock; the copying and the
    /// writing happen outside it, from the snapshot.
    pub fn snapshot(&self, now: Instant) -> Snapshot {
        Snapshot {
            job: self.id,
            spp: self.spp,
            spent: self.spent(now),
            completed: self.queue.completed(),
            nonfinite_samples: self.nonfinite_samples,
            samples_done: self.queue.samples_done(),
            framebuffer: self.framebuffer.clone(),
            aov: self.aov.clone(),
        }
    }

    /// The job as stored.
    pub fn record(&self) -> JobRecord {
        JobRecord {
            id: self.id,
            bundle: self.bundle.clone(),
            settings: self.settings.clone(),
            priority: self.priority,
            state: self.state.clone(),
            owner: self.owner.clone(),
        }
    }
}

impl Job {
    /// Validates a submission and makes its job: the costly part of submitting (reading
    /// the scene, allocating the framebuffer), done before the farm is touched so that
    /// nobody waits for it.
    pub fn prepare(
        id: JobId,
        bundle: Arc<Bundle>,
        settings: JobSettings,
        priority: i32,
    ) -> Result<Job, SubmitError> {
        Job::prepare_within(id, bundle, settings, priority, &mut |_| Ok(()))
    }

    /// As `prepare`, with `admit` asked about the job's memory after the scene validated
    /// and before its framebuffer is allocated.
    pub fn prepare_within(
        id: JobId,
        bundle: Arc<Bundle>,
        settings: JobSettings,
        priority: i32,
        admit: super::budget::Admit<'_>,
    ) -> Result<Job, SubmitError> {
        // Validation only: the coordinator never builds geometry or decodes images.
        let mut desc = tessera_description::Description::parse(&bundle)?;
        use tessera_description::limits;
        if let Some(s) = settings.spp.filter(|&s| s == 0 || s > limits::MAX_SPP) {
            return Err(SubmitError::Spp { got: s, max: limits::MAX_SPP });
        }
        if let Some((width, height)) = settings.size {
            let pixels = u64::from(width) * u64::from(height);
            if width == 0
                || height == 0
                || width > limits::MAX_SIDE
                || height > limits::MAX_SIDE
                || pixels > limits::MAX_PIXELS
            {
                let (max_side, max_pixels) = (limits::MAX_SIDE, limits::MAX_PIXELS);
                return Err(SubmitError::Size { width, height, max_side, max_pixels });
            }
        }
        desc.apply(settings.spp, settings.size);
        let scene = desc.render;
        if let Some((first, last)) = settings.frames {
            tessera_description::job::check_frames(first, last)
                .map_err(|e| SubmitError::Frames(format!("{first}-{last}: {e}")))?;
            if let Some((a, b)) = desc.frames().filter(|&(a, b)| first < a || last > b) {
                return Err(SubmitError::Frames(format!(
                    "{first}-{last}: the scene's animation has frames {a}-{b} ([animation] frames)"
                )));
            }
            if settings.in_rounds() {
                return Err(SubmitError::Frames(format!(
                    "{first}-{last}: a sequence renders to its sample count; a time budget or noise target is for stills"
                )));
            }
        }
        let frames = settings.frame_count();
        // A sequence's frames are stacked in one framebuffer; a pixel's index must fit the
        // viewers' u32.
        let stacked = u64::from(scene.width) * u64::from(scene.height) * u64::from(frames);
        if stacked > u64::from(u32::MAX) {
            return Err(SubmitError::Frames(format!(
                "{frames} frames of {}x{} are {stacked} pixels, more than the {} one job may hold",
                scene.width,
                scene.height,
                u32::MAX
            )));
        }
        settings.checked_noise_for(scene.spp).map_err(SubmitError::Noise)?;
        if settings.time_limit.is_some_and(|t| t.is_zero()) {
            return Err(SubmitError::TimeLimit);
        }
        let spp = scene.spp;
        admit(&super::budget::Footprint {
            width: scene.width,
            height: scene.height * frames,
            even_sums: settings.in_rounds() && settings.noise.is_some(),
            bundle_bytes: desc.bundle_bytes,
            aovs: layout_of(settings.aovs),
        })?;
        let (queue, framebuffer) = match (settings.in_rounds(), settings.noise.is_some()) {
            (false, _) => (
                PassQueue::sequence(scene.width, scene.height, frames, spp),
                Framebuffer::new(scene.width, scene.height * frames),
            ),
            (true, adaptive) => (
                PassQueue::with_rounds(scene.width, scene.height, spp),
                if adaptive {
                    Framebuffer::with_even(scene.width, scene.height)
                } else {
                    Framebuffer::new(scene.width, scene.height)
                },
            ),
        };
        let aov = AovLayers::new(layout_of(settings.aovs), scene.width, scene.height * frames);
        Ok(Job {
            id,
            scene_hash: bundle.hash(),
            bundle,
            settings,
            priority,
            spp,
            state: JobState::Queued,
            owner: String::new(),
            queue,
            aov,
            framebuffer,
            started: None,
            finished: None,
            rate: VecDeque::new(),
            fence: JobFence::default(),
            speeds: Speeds::default(),
            nonfinite_samples: 0,
            spent_before: Duration::ZERO,
            paused_for: Duration::ZERO,
            paused_at: None,
            halted: None,
            audits_since: None,
        })
    }

    pub(super) fn queue_leases_of(&self, worker: WorkerId) -> usize {
        let audits =
            self.fence.audits.iter().filter(|a| a.lease.as_ref().is_some_and(|l| l.worker == worker));
        let repairs = self.fence.repairs.leased.iter().filter(|l| l.worker == worker);
        self.queue.leased_by(worker) + audits.count() + repairs.count()
    }

    /// Drops every lease, audit and repair (the job is over); the tokens stay released, so
    /// that answers still on their way are harmless duplicates.
    pub(super) fn abandon_all(&mut self) {
        let dropped = self.queue.abandon();
        self.fence.release_all(dropped);
        self.fence.abandon();
    }

    /// Ends the job if every batch is merged and its audits and repairs are resolved.
    pub(super) fn finish_if_done(&mut self, now: Instant) {
        if self.is_over() || !self.queue.is_finished() || !self.fence.is_idle() {
            return;
        }
        self.state = JobState::Done;
        self.finished = Some(now);
        if self.settings.noise.is_some() && self.queue.samples_done() < self.queue.samples_total() {
            self.halted = Some(HALTED_BY_NOISE);
        }
        self.fence.abandon();
    }

    pub(super) fn after_merge(&mut self, nonfinite: u64, now: Instant) {
        self.nonfinite_samples += nonfinite;
        self.rate.push_back((now, self.queue.samples_done()));
        while self.rate.len() > 2 && now.saturating_duration_since(self.rate[1].0) > RATE_WINDOW {
            self.rate.pop_front();
        }
        // The job ends in `Farm::settle`, once its audits and repairs are resolved too.
    }
}

/// A job's merged state at one moment, taken under the farm's lock in microseconds: what a
/// checkpoint is made of.
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// The job.
    pub job: JobId,
    /// Samples per pixel in effect.
    pub spp: u32,
    /// Rendering time so far, across restarts.
    pub spent: Duration,
    /// The merged batches.
    pub completed: Completed,
    /// Samples that came back NaN or infinite.
    pub nonfinite_samples: u64,
    /// Samples merged.
    pub samples_done: u64,
    /// The framebuffer as it was (a copy-on-write clone).
    pub framebuffer: Framebuffer,
    /// The AOV layers as they were (a copy-on-write clone).
    pub aov: AovLayers,
}

impl Snapshot {
    /// The checkpoint: the accumulators copied out in pixel order. O(pixels): call it
    /// outside the farm's lock.
    pub fn checkpoint(&self) -> Checkpoint {
        let fb = &self.framebuffer;
        let (sums, counts) = fb.accumulators();
        Checkpoint {
            even: fb.even(),
            spent: self.spent,
            job: self.job,
            width: fb.width(),
            height: fb.height(),
            spp: self.spp,
            completed: self.completed.clone(),
            nonfinite_samples: self.nonfinite_samples,
            samples_done: self.samples_done,
            sums,
            counts,
            aov_layout: self.aov.layout().bits(),
            aov: self.aov.sums(),
            renderer: tessera_description::RENDERER_VERSION.into(),
        }
    }
}

/// The film's layout of a job's AOV settings.
pub(crate) fn layout_of(a: tessera_description::job::Aovs) -> tessera_film::aov::Layout {
    tessera_film::aov::Layout { albedo: a.albedo, normal: a.normal, depth: a.depth }
}
