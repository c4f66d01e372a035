//! The coordinator's state: jobs, workers, and who renders what. Pure: no I/O and no wire
//! types; `service.rs` wraps it.

use std::collections::{BTreeMap, HashMap, HashSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_worker::bundle::Bundle;

use crate::checkpoint::Checkpoint;
use crate::framebuffer::{Framebuffer, MergeError};
use crate::ids::{BatchId, JobId, WorkerId};
use crate::scheduler::{BatchSpec, CompleteError, PassQueue, RestoreError};
use crate::store::{JobRecord, LoadedJob};

/// A batch failing this many times fails its job: the problem is not the worker.
pub const MAX_BATCH_FAILURES: u32 = 3;
/// The window over which samples per second are measured.
const RATE_WINDOW: Duration = Duration::from_secs(5);
/// A lease becomes a straggler, worth a speculative duplicate, after this many mean batch
/// times...
const SPECULATE_PATIENCE: u32 = 3;
/// ...and never sooner than this: duplicating work costs a worker's time too.
const SPECULATE_MIN_AGE: Duration = Duration::from_secs(1);

/// Settings a submission may override.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JobSettings {
    /// Samples per pixel; `None` keeps the scene's.
    pub spp: Option<u32>,
    /// Image size; `None` keeps the scene's.
    pub size: Option<(u32, u32)>,
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
    queue: PassQueue,
    framebuffer: Framebuffer,
    started: Option<Instant>,
    finished: Option<Instant>,
    /// (time, samples done) points for the recent rate.
    rate: VecDeque<(Instant, u64)>,
    failures: HashMap<BatchId, u32>,
    nonfinite_samples: u64,
}

impl Job {
    /// The framebuffer.
    pub fn framebuffer(&self) -> &Framebuffer {
        &self.framebuffer
    }

    /// Whether the job will hand out no more batches.
    pub fn is_over(&self) -> bool {
        matches!(self.state, JobState::Done | JobState::Cancelled | JobState::Failed(_))
    }

    /// A snapshot of progress.
    pub fn progress(&self, now: Instant) -> JobProgress {
        let rate = match (self.rate.front(), self.rate.back()) {
            (Some(&(t0, s0)), Some(&(t1, s1))) if t1 > t0 => (s1 - s0) as f64 / (t1 - t0).as_secs_f64(),
            _ => 0.0,
        };
        let end = self.finished.unwrap_or(now);
        JobProgress {
            id: self.id,
            scene: self.bundle.name.clone(),
            state: self.state.clone(),
            width: self.framebuffer.width(),
            height: self.framebuffer.height(),
            spp: self.spp,
            pass: self.queue.pass().number(),
            samples_done: self.queue.samples_done(),
            samples_total: self.queue.samples_total(),
            samples_per_second: rate,
            elapsed: self.started.map_or(Duration::ZERO, |s| end.saturating_duration_since(s)),
            pass_one_done: self.queue.pass_one_pixels_done(),
            nonfinite_samples: self.nonfinite_samples,
            priority: self.priority,
        }
    }

    /// Whether every pixel has its pass-one sample.
    pub fn pass_one_complete(&self) -> bool {
        let fb = &self.framebuffer;
        self.queue.pass_one_pixels_done() == u64::from(fb.width()) * u64::from(fb.height())
    }

    /// The job's state now, for a checkpoint: merged batches and accumulators. Leased
    /// batches are not in it; a restart renders them again.
    pub fn checkpoint(&self) -> Checkpoint {
        let (sums, counts) = self.framebuffer.accumulators();
        Checkpoint {
            job: self.id,
            width: self.framebuffer.width(),
            height: self.framebuffer.height(),
            spp: self.spp,
            completed: self.queue.completed(),
            nonfinite_samples: self.nonfinite_samples,
            samples_done: self.queue.samples_done(),
            sums: sums.to_vec(),
            counts: counts.to_vec(),
        }
    }

    /// The job as stored.
    pub fn record(&self) -> JobRecord {
        JobRecord {
            id: self.id,
            bundle: (*self.bundle).clone(),
            settings: self.settings.clone(),
            priority: self.priority,
            state: self.state.clone(),
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

/// A connected worker.
#[derive(Debug, Clone)]
pub struct WorkerInfo {
    /// Name it gave.
    pub name: String,
    /// Render threads.
    pub threads: u32,
    /// Jobs whose scene it has received.
    scenes: HashSet<JobId>,
    /// Batches done.
    pub batches_done: u64,
    /// Last message received.
    last_seen: Instant,
}

/// What a worker is handed: the job's scene first if it lacks it, then a batch.
#[derive(Debug, Clone)]
pub struct Assignment {
    /// The job.
    pub job: JobId,
    /// The scene, when this worker has not had it.
    pub scene: Option<(Arc<Bundle>, String, JobSettings)>,
    /// The scene hash the batch needs.
    pub scene_hash: String,
    /// The batch.
    pub batch: BatchSpec,
    /// Its attempt number.
    pub attempt: u32,
    /// A duplicate of a straggler's batch, leased to another worker too.
    pub speculative: bool,
}

/// Why a submission was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SubmitError {
    /// The scene does not parse or validate.
    #[error(transparent)]
    Scene(#[from] tessera_worker::scene::SceneError),
    /// spp override out of range.
    #[error("spp must be 1..={max}, got {got}")]
    Spp {
        /// Requested.
        got: u32,
        /// Limit.
        max: u32,
    },
    /// Size override out of range.
    #[error("image size must be 1..={max_side} on each side and at most {max_pixels} pixels, got {width}x{height}")]
    Size {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
        /// Limit per side.
        max_side: u32,
        /// Limit of pixels.
        max_pixels: u64,
    },
}

/// Why a stored job could not be taken up again.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RestoreJobError {
    /// The stored scene no longer parses (a different tessera version?).
    #[error(transparent)]
    Scene(#[from] SubmitError),
    /// The checkpoint does not fit the job.
    #[error("its checkpoint is {got}, the job is {expected}")]
    Mismatch {
        /// What the job's scene and settings give, `WxH@spp`.
        expected: String,
        /// What the checkpoint holds.
        got: String,
    },
    /// The checkpoint's batches are not the job's.
    #[error(transparent)]
    Batches(#[from] RestoreError),
}

/// Why a worker's result was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResultError {
    /// No such job.
    #[error("unknown {0}")]
    UnknownJob(JobId),
    /// Already merged or never cut (harmless: a duplicate).
    #[error(transparent)]
    Duplicate(#[from] CompleteError),
    /// The sums are malformed; the batch goes back to the queue.
    #[error("{job} {batch}: {source}")]
    Malformed {
        /// The job.
        job: JobId,
        /// The batch.
        batch: BatchId,
        /// What is wrong.
        source: MergeError,
    },
}

/// Everything the coordinator knows.
#[derive(Debug, Default)]
pub struct Farm {
    jobs: BTreeMap<JobId, Job>,
    workers: BTreeMap<WorkerId, WorkerInfo>,
    next_job: u64,
    next_worker: u64,
}

impl Farm {
    /// An empty farm.
    pub fn new() -> Self {
        Farm::default()
    }

    /// Validates and queues a job.
    pub fn submit(
        &mut self,
        bundle: Bundle,
        settings: JobSettings,
        priority: i32,
    ) -> Result<JobId, SubmitError> {
        let job = Self::prepare(JobId(self.next_job + 1), bundle, settings, priority)?;
        self.next_job += 1;
        let id = job.id;
        self.jobs.insert(id, job);
        Ok(id)
    }

    /// Takes up a stored job again: from its checkpoint if it has one, else from the start.
    /// Its id is kept, and later jobs get higher ones.
    pub fn restore(&mut self, stored: LoadedJob, now: Instant) -> Result<JobId, RestoreJobError> {
        let LoadedJob { record, checkpoint } = stored;
        let id = record.id;
        self.next_job = self.next_job.max(id.0);
        let mut job = Self::prepare(id, record.bundle, record.settings, record.priority)?;
        if let Some(c) = checkpoint {
            let (w, h) = (job.framebuffer.width(), job.framebuffer.height());
            if (c.width, c.height, c.spp) != (w, h, job.spp) {
                return Err(RestoreJobError::Mismatch {
                    expected: format!("{w}x{h}@{}", job.spp),
                    got: format!("{}x{}@{}", c.width, c.height, c.spp),
                });
            }
            job.queue = PassQueue::restore(w, h, job.spp, &c.completed)?;
            if job.queue.samples_done() != c.samples_done {
                return Err(RestoreJobError::Mismatch {
                    expected: format!("{} samples for its merged batches", job.queue.samples_done()),
                    got: format!("{} samples", c.samples_done),
                });
            }
            job.framebuffer =
                Framebuffer::from_accumulators(w, h, c.sums, c.counts).expect("decode checked lengths");
            job.nonfinite_samples = c.nonfinite_samples;
        }
        job.state = match record.state {
            JobState::Cancelled | JobState::Failed(_) => {
                job.queue.abandon();
                job.finished = Some(now);
                record.state
            }
            JobState::Paused => JobState::Paused,
            // A job recorded as done whose final checkpoint did not survive renders the rest.
            _ if job.queue.is_finished() => {
                job.finished = Some(now);
                JobState::Done
            }
            _ => JobState::Queued,
        };
        self.jobs.insert(id, job);
        Ok(id)
    }

    /// Drops a job that could not be stored (its submission failed).
    pub fn remove_job(&mut self, id: JobId) {
        self.jobs.remove(&id);
        for w in self.workers.values_mut() {
            w.scenes.remove(&id);
        }
    }

    /// Makes sure ids stay above `id` (one that was used, even if its job is lost).
    pub fn reserve_ids_through(&mut self, id: u64) {
        self.next_job = self.next_job.max(id);
    }

    fn prepare(id: JobId, bundle: Bundle, settings: JobSettings, priority: i32) -> Result<Job, SubmitError> {
        let mut scene = bundle.parse()?;
        use tessera_worker::scene::limits;
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
        scene.apply(settings.spp, settings.size);
        let spp = scene.spp;
        Ok(Job {
            id,
            scene_hash: bundle.hash(),
            bundle: Arc::new(bundle),
            settings,
            priority,
            spp,
            state: JobState::Queued,
            queue: PassQueue::new(scene.width, scene.height, spp),
            framebuffer: Framebuffer::new(scene.width, scene.height),
            started: None,
            finished: None,
            rate: VecDeque::new(),
            failures: HashMap::new(),
            nonfinite_samples: 0,
        })
    }

    /// A job.
    pub fn job(&self, id: JobId) -> Option<&Job> {
        self.jobs.get(&id)
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> impl Iterator<Item = &Job> {
        self.jobs.values()
    }

    /// Job ids in the order they are served: highest priority first, then oldest first.
    fn service_order(&self) -> Vec<JobId> {
        let mut ids: Vec<(i32, JobId)> = self
            .jobs
            .values()
            .filter(|j| !j.is_over() && j.state != JobState::Paused)
            .map(|j| (j.priority, j.id))
            .collect();
        ids.sort_by_key(|&(p, id)| (std::cmp::Reverse(p), id));
        ids.into_iter().map(|(_, id)| id).collect()
    }

    /// Registers a worker.
    pub fn add_worker(&mut self, name: String, threads: u32, now: Instant) -> WorkerId {
        self.next_worker += 1;
        let id = WorkerId(self.next_worker);
        let info = WorkerInfo { name, threads, scenes: HashSet::new(), batches_done: 0, last_seen: now };
        self.workers.insert(id, info);
        id
    }

    /// The connected workers.
    pub fn workers(&self) -> impl Iterator<Item = (WorkerId, &WorkerInfo)> {
        self.workers.iter().map(|(id, w)| (*id, w))
    }

    /// Batches leased to `worker` now.
    pub fn in_flight(&self, worker: WorkerId) -> usize {
        self.jobs.values().map(|j| j.queue_leases_of(worker)).sum()
    }

    /// Notes that `worker` is alive.
    pub fn touch(&mut self, worker: WorkerId, now: Instant) {
        if let Some(w) = self.workers.get_mut(&worker) {
            w.last_seen = now;
        }
    }

    /// A worker left: its leases go back to the queue at once.
    pub fn remove_worker(&mut self, worker: WorkerId) -> usize {
        self.workers.remove(&worker);
        self.jobs.values_mut().map(|j| j.queue.take_back_worker(worker).len()).sum()
    }

    /// Takes back the leases of workers silent for longer than `timeout` (frozen, or cut
    /// off without the connection noticing). They stay connected: should they wake up,
    /// their results are still taken once.
    pub fn expire_silent(&mut self, now: Instant, timeout: Duration) -> Vec<(WorkerId, usize)> {
        let silent: Vec<WorkerId> = self
            .workers
            .iter()
            .filter(|(_, w)| now.saturating_duration_since(w.last_seen) > timeout)
            .map(|(id, _)| *id)
            .collect();
        silent
            .into_iter()
            .filter_map(|id| {
                let n: usize = self.jobs.values_mut().map(|j| j.queue.take_back_worker(id).len()).sum();
                (n > 0).then_some((id, n))
            })
            .collect()
    }

    /// The next batch for `worker`: from the first job in service order that has a new or
    /// taken-back batch; failing that, a speculative duplicate of a straggler at the end
    /// of a job, so that one slow or stuck worker does not hold the last of a job up.
    pub fn assign(&mut self, worker: WorkerId, now: Instant) -> Option<Assignment> {
        if !self.workers.contains_key(&worker) {
            return None;
        }
        let order = self.service_order();
        let pick = |job: &mut Job, speculate: bool| {
            let lease = if speculate {
                job.queue.lease_speculative(worker, now, SPECULATE_PATIENCE, SPECULATE_MIN_AGE)
            } else {
                job.queue.lease_next(worker, now)
            };
            lease.map(|l| (l.spec.clone(), l.attempt))
        };
        let (id, batch, attempt, speculative) = [false, true].into_iter().find_map(|speculate| {
            order.iter().find_map(|id| {
                let job = self.jobs.get_mut(id).expect("ordered ids exist");
                pick(job, speculate).map(|(b, a)| (*id, b, a, speculate))
            })
        })?;
        let job = self.jobs.get_mut(&id).expect("picked above");
        let info = self.workers.get_mut(&worker).expect("checked above");
        if job.state == JobState::Queued {
            job.state = JobState::Running;
            job.started = Some(now);
            job.rate.push_back((now, job.queue.samples_done()));
        }
        let scene = info
            .scenes
            .insert(job.id)
            .then(|| (job.bundle.clone(), job.scene_hash.clone(), job.settings.clone()));
        Some(Assignment {
            job: job.id,
            scene,
            scene_hash: job.scene_hash.clone(),
            batch,
            attempt,
            speculative,
        })
    }

    /// Merges a batch's result, exactly once.
    pub fn complete(
        &mut self,
        worker: WorkerId,
        job_id: JobId,
        batch: BatchId,
        sums: &[u64],
        nonfinite: u64,
        now: Instant,
    ) -> Result<(), ResultError> {
        let job = self.jobs.get_mut(&job_id).ok_or(ResultError::UnknownJob(job_id))?;
        if job.is_over() {
            return Err(CompleteError::NotOutstanding { batch }.into());
        }
        // Check the sums before accepting the batch, so that a malformed result neither
        // merges nor marks the batch done.
        let spec = job.queue.outstanding(batch).ok_or(CompleteError::NotOutstanding { batch })?.clone();
        let samples = spec.samples.end - spec.samples.start;
        if let Err(source) = Framebuffer::check(&spec.quads, samples, sums) {
            job.queue.take_back(batch);
            return Err(ResultError::Malformed { job: job_id, batch, source });
        }
        job.queue.complete(batch, now)?;
        job.framebuffer.merge(&spec.quads, samples, sums).expect("sums were checked above");
        job.after_merge(nonfinite, now);
        if let Some(w) = self.workers.get_mut(&worker) {
            w.batches_done += 1;
        }
        Ok(())
    }

    /// A worker could not render a batch: retry elsewhere, or fail the job if the batch
    /// keeps failing.
    pub fn fail_batch(&mut self, job_id: JobId, batch: BatchId, error: &str) {
        let Some(job) = self.jobs.get_mut(&job_id) else { return };
        if job.is_over() || !job.queue.take_back(batch) {
            return;
        }
        let n = job.failures.entry(batch).or_default();
        *n += 1;
        if *n >= MAX_BATCH_FAILURES {
            job.queue.abandon();
            job.state = JobState::Failed(format!("{batch} failed {n} times; last error: {error}"));
            job.finished = Some(Instant::now());
        }
    }

    /// Pauses or resumes a job; `false` if there is no such job. A job that is over stays
    /// as it is.
    pub fn set_paused(&mut self, job_id: JobId, paused: bool) -> bool {
        let Some(job) = self.jobs.get_mut(&job_id) else { return false };
        match (&job.state, paused) {
            (JobState::Queued | JobState::Running, true) => job.state = JobState::Paused,
            (JobState::Paused, false) => {
                job.state = if job.started.is_some() { JobState::Running } else { JobState::Queued }
            }
            _ => {}
        }
        true
    }

    /// Stops a job; its image stays.
    pub fn cancel(&mut self, job_id: JobId) -> bool {
        let Some(job) = self.jobs.get_mut(&job_id) else { return false };
        if !job.is_over() {
            job.queue.abandon();
            job.state = JobState::Cancelled;
            job.finished = Some(Instant::now());
        }
        true
    }
}

impl Job {
    fn queue_leases_of(&self, worker: WorkerId) -> usize {
        self.queue.leased_by(worker)
    }

    fn after_merge(&mut self, nonfinite: u64, now: Instant) {
        self.nonfinite_samples += nonfinite;
        self.rate.push_back((now, self.queue.samples_done()));
        while self.rate.len() > 2 && now.saturating_duration_since(self.rate[1].0) > RATE_WINDOW {
            self.rate.pop_front();
        }
        if self.queue.is_finished() {
            self.state = JobState::Done;
            self.finished = Some(now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENE: &str = include_str!("../../tests/scenes/small.toml");

    fn bundle() -> Bundle {
        Bundle { name: "small.toml".into(), text: SCENE.into(), assets: vec![] }
    }

    fn settings(w: u32, h: u32, spp: u32) -> JobSettings {
        JobSettings { spp: Some(spp), size: Some((w, h)) }
    }

    /// What a worker would send: sums that depend on pixel and samples only.
    fn fake_sums(spec: &BatchSpec) -> Vec<u64> {
        let n = u64::from(spec.samples.end - spec.samples.start);
        spec.quads
            .iter()
            .flat_map(|q| [1, 2, 3].map(|c| u64::from((q.x * 7 + q.y * 3 + c) % 11) * n))
            .collect()
    }

    /// Leases and completes up to `limit` batches for one worker; returns how many.
    fn work(farm: &mut Farm, worker: WorkerId, limit: usize) -> usize {
        let now = Instant::now();
        let mut n = 0;
        while n < limit {
            let Some(a) = farm.assign(worker, now) else { break };
            farm.complete(worker, a.job, a.batch.id, &fake_sums(&a.batch), 0, now).unwrap();
            n += 1;
        }
        n
    }

    #[test]
    fn higher_priorities_are_served_first_then_the_oldest() {
        let mut farm = Farm::new();
        let low = farm.submit(bundle(), settings(16, 16, 2), -1).unwrap();
        let normal_old = farm.submit(bundle(), settings(16, 16, 2), 0).unwrap();
        let high = farm.submit(bundle(), settings(16, 16, 2), 5).unwrap();
        let normal_new = farm.submit(bundle(), settings(16, 16, 2), 0).unwrap();
        let w = farm.add_worker("w".into(), 1, Instant::now());
        let mut served = Vec::new();
        while let Some(a) = farm.assign(w, Instant::now()) {
            if served.last() != Some(&a.job) {
                served.push(a.job);
            }
            farm.complete(w, a.job, a.batch.id, &fake_sums(&a.batch), 0, Instant::now()).unwrap();
        }
        assert_eq!(served, vec![high, normal_old, normal_new, low]);
    }

    /// A job checkpointed mid-pass and restored into a new farm (a restarted coordinator)
    /// ends with exactly the accumulators of a job never interrupted, whatever was leased
    /// and lost at the moment of the checkpoint.
    #[test]
    fn a_restored_job_ends_with_the_uninterrupted_accumulators() {
        let (w, h, spp) = (37, 23, 5);
        let mut clean = Farm::new();
        let id = clean.submit(bundle(), settings(w, h, spp), 0).unwrap();
        let cw = clean.add_worker("clean".into(), 1, Instant::now());
        work(&mut clean, cw, usize::MAX);
        assert_eq!(clean.job(id).unwrap().state, JobState::Done);

        for stop_after in [0, 1, 3, 9, 20] {
            let mut farm = Farm::new();
            let id = farm.submit(bundle(), settings(w, h, spp), 0).unwrap();
            let a = farm.add_worker("a".into(), 1, Instant::now());
            work(&mut farm, a, stop_after);
            // Leases in flight at the checkpoint, one of them finished out of order.
            let now = Instant::now();
            let held: Vec<_> = (0..3).filter_map(|_| farm.assign(a, now)).collect();
            if let Some(x) = held.get(1) {
                farm.complete(a, x.job, x.batch.id, &fake_sums(&x.batch), 0, now).unwrap();
            }
            let job = farm.job(id).unwrap();
            let stored = LoadedJob { record: job.record(), checkpoint: Some(job.checkpoint()) };

            let mut restarted = Farm::new();
            assert_eq!(restarted.restore(stored, Instant::now()).unwrap(), id);
            let b = restarted.add_worker("b".into(), 1, Instant::now());
            work(&mut restarted, b, usize::MAX);
            let (got, want) = (restarted.job(id).unwrap(), clean.job(id).unwrap());
            assert_eq!(got.state, JobState::Done, "stopped after {stop_after}");
            assert_eq!(
                got.framebuffer().accumulators(),
                want.framebuffer().accumulators(),
                "stopped after {stop_after}"
            );
            assert_eq!(got.progress(now).samples_done, want.progress(now).samples_done);
            // New jobs never reuse the restored id.
            assert!(restarted.submit(bundle(), settings(4, 4, 1), 0).unwrap() > id);
        }
    }

    #[test]
    fn restored_states_are_kept_and_a_mismatched_checkpoint_is_refused() {
        let mut farm = Farm::new();
        let id = farm.submit(bundle(), settings(8, 8, 2), 0).unwrap();
        let job = farm.job(id).unwrap();
        for (state, want) in [
            (JobState::Paused, JobState::Paused),
            (JobState::Cancelled, JobState::Cancelled),
            (JobState::Running, JobState::Queued),
        ] {
            let mut record = job.record();
            record.state = state;
            let mut f = Farm::new();
            f.restore(LoadedJob { record, checkpoint: Some(job.checkpoint()) }, Instant::now()).unwrap();
            assert_eq!(f.job(id).unwrap().state, want);
            let w = f.add_worker("w".into(), 1, Instant::now());
            assert_eq!(f.assign(w, Instant::now()).is_some(), want == JobState::Queued);
        }
        let mut wrong = job.checkpoint();
        wrong.spp = 3;
        let e =
            Farm::new().restore(LoadedJob { record: job.record(), checkpoint: Some(wrong) }, Instant::now());
        assert!(matches!(e, Err(RestoreJobError::Mismatch { .. })), "{e:?}");
    }
}
