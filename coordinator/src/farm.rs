//! The coordinator's state: jobs, workers, and who renders what. Pure: no I/O and no wire
//! types; `service.rs` wraps it.

use std::collections::{BTreeMap, HashMap, HashSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
pub use tessera_description::job::{JobProgress, JobSettings, JobState};

use crate::checkpoint::Checkpoint;
use crate::scheduler::{BatchSpec, CompleteError, PassQueue, RestoreError};
use crate::store::{JobRecord, LoadedJob};
use tessera_description::ids::{BatchId, JobId, WorkerId};
use tessera_film::framebuffer::{Framebuffer, MergeError};
use tessera_film::quadtree::Quad;

/// A batch failing this many times fails its job: the problem is not the worker.
pub const MAX_BATCH_FAILURES: u32 = 3;
/// The window over which samples per second are measured.
const RATE_WINDOW: Duration = Duration::from_secs(5);
/// A lease becomes a straggler, worth a speculative duplicate, after this many mean batch
/// times...
const SPECULATE_PATIENCE: u32 = 3;
/// ...and never sooner than this: duplicating work costs a worker's time too.
const SPECULATE_MIN_AGE: Duration = Duration::from_secs(1);

/// Luminance below which a pixel's noise is measured against this floor instead: black
/// pixels would otherwise never reach a relative target.
pub const NOISE_FLOOR: f64 = 0.05;
/// Samples a pixel takes before its noise estimate may stop it: fewer give estimates too
/// rough to trust.
pub const NOISE_MIN_SAMPLES: u32 = 16;
/// The radius of the window over which pixels' error estimates are pooled (5×5).
const NOISE_WINDOW: u32 = 2;

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
    /// Rendering time before a restart, counted against a time budget.
    spent_before: Duration,
    halted: Option<&'static str>,
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
            halted: self.halted,
        }
    }

    /// Rendering time so far, across restarts.
    pub fn spent(&self, now: Instant) -> Duration {
        let end = self.finished.unwrap_or(now);
        self.spent_before + self.started.map_or(Duration::ZERO, |s| end.saturating_duration_since(s))
    }

    /// Ends the job if its time budget is spent; returns whether it did.
    fn enforce_deadline(&mut self, now: Instant) -> bool {
        let Some(limit) = self.settings.time_limit else { return false };
        if self.is_over() || self.state == JobState::Paused || self.spent(now) < limit {
            return false;
        }
        self.queue.abandon();
        self.state = JobState::Done;
        self.finished = Some(now);
        self.halted = Some("time budget");
        true
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
            even: self.framebuffer.even().to_vec(),
            spent: self.spent(Instant::now()),
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
    /// The job wants even-sample sums back (it has a noise target).
    pub even_sums: bool,
}

/// Why a submission was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SubmitError {
    /// The scene does not parse or validate.
    #[error(transparent)]
    Scene(#[from] tessera_description::SceneError),
    /// spp override out of range.
    #[error("spp must be 1..={max}, got {got}")]
    Spp {
        /// Requested.
        got: u32,
        /// Limit.
        max: u32,
    },
    /// Noise target out of range.
    #[error("the noise target must be a relative error in (0, 1), e.g. 0.01, got {0}")]
    Noise(f32),
    /// A zero time budget.
    #[error("the time budget must be positive")]
    TimeLimit,
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
            if c.even.is_empty() == job.framebuffer.has_even() {
                return Err(RestoreJobError::Mismatch {
                    expected: format!("noise target {:?}", job.settings.noise),
                    got: "a checkpoint with other accumulators".into(),
                });
            }
            let fb = Framebuffer::from_accumulators(w, h, c.sums, c.counts, c.even)
                .expect("decode checked lengths");
            job.queue = if job.settings.in_rounds() {
                let target = job.settings.noise;
                let keep = |q: Quad| !converged(&fb, q, target);
                let decide: Option<&dyn Fn(Quad) -> bool> = if target.is_some() { Some(&keep) } else { None };
                PassQueue::restore_rounds(w, h, job.spp, &c.completed, fb.accumulators().1, decide)?
            } else {
                PassQueue::restore(w, h, job.spp, &c.completed)?
            };
            if job.queue.samples_done() != c.samples_done {
                return Err(RestoreJobError::Mismatch {
                    expected: format!("{} samples for its merged batches", job.queue.samples_done()),
                    got: format!("{} samples", c.samples_done),
                });
            }
            job.framebuffer = fb;
            job.nonfinite_samples = c.nonfinite_samples;
            job.spent_before = c.spent;
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

    /// Ends every job whose time budget is spent; returns them.
    pub fn enforce_deadlines(&mut self, now: Instant) -> Vec<JobId> {
        self.jobs.values_mut().filter_map(|j| j.enforce_deadline(now).then_some(j.id)).collect()
    }

    /// Makes sure ids stay above `id` (one that was used, even if its job is lost).
    pub fn reserve_ids_through(&mut self, id: u64) {
        self.next_job = self.next_job.max(id);
    }

    fn prepare(id: JobId, bundle: Bundle, settings: JobSettings, priority: i32) -> Result<Job, SubmitError> {
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
        if let Some(n) = settings.noise.filter(|n| !(n.is_finite() && *n > 0.0 && *n < 1.0)) {
            return Err(SubmitError::Noise(n));
        }
        if settings.time_limit.is_some_and(|t| t.is_zero()) {
            return Err(SubmitError::TimeLimit);
        }
        let spp = scene.spp;
        let (queue, framebuffer) = match (settings.in_rounds(), settings.noise.is_some()) {
            (false, _) => {
                (PassQueue::new(scene.width, scene.height, spp), Framebuffer::new(scene.width, scene.height))
            }
            (true, adaptive) => (
                PassQueue::with_rounds(scene.width, scene.height, spp),
                if adaptive {
                    Framebuffer::with_even(scene.width, scene.height)
                } else {
                    Framebuffer::new(scene.width, scene.height)
                },
            ),
        };
        Ok(Job {
            id,
            scene_hash: bundle.hash(),
            bundle: Arc::new(bundle),
            settings,
            priority,
            spp,
            state: JobState::Queued,
            queue,
            framebuffer,
            started: None,
            finished: None,
            rate: VecDeque::new(),
            failures: HashMap::new(),
            nonfinite_samples: 0,
            spent_before: Duration::ZERO,
            halted: None,
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
        self.enforce_deadlines(now);
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
        let even_sums = job.framebuffer.has_even();
        Some(Assignment {
            job: job.id,
            scene,
            scene_hash: job.scene_hash.clone(),
            batch,
            attempt,
            speculative,
            even_sums,
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
        self.complete_split(worker, job_id, batch, sums, &[], nonfinite, now)
    }

    /// `complete`, with the batch's even-sample sums (needed by jobs with a noise target).
    #[allow(clippy::too_many_arguments)]
    pub fn complete_split(
        &mut self,
        worker: WorkerId,
        job_id: JobId,
        batch: BatchId,
        sums: &[u64],
        even: &[u64],
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
        let checked = Framebuffer::check(&spec.quads, samples, sums).and_then(|()| {
            if job.framebuffer.has_even() {
                Framebuffer::check_even(&spec.quads, samples, even)
            } else {
                Ok(())
            }
        });
        if let Err(source) = checked {
            job.queue.take_back(batch);
            return Err(ResultError::Malformed { job: job_id, batch, source });
        }
        job.queue.complete(batch, now)?;
        job.framebuffer.merge_split(&spec.quads, samples, sums, even).expect("sums were checked above");
        if let Some((round, tile)) = job.queue.round_of(batch) {
            // The tile's next round: every pixel, or those still above the noise target
            // (decided on merged samples only, so the same whatever the arrival order).
            let next = job.settings.noise.map(|target| {
                spec.quads
                    .iter()
                    .copied()
                    .filter(|q| !converged(&job.framebuffer, *q, Some(target)))
                    .collect()
            });
            job.queue.schedule_round(tile, round + 1, next);
        }
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

/// Whether pixel `q` has reached the noise target (never without one).
///
/// One pixel's estimate (half the difference of its even and odd halves) is a single draw
/// of the error, often far below it by chance; stopping on it would stop noisy pixels
/// early. So the relative errors of the pixels around it, within its own tile (whose
/// samples are all merged when its round ends, which keeps the decision deterministic), are
/// averaged in square: an estimate with about 25 degrees of freedom instead of one.
fn converged(fb: &Framebuffer, q: Quad, target: Option<f32>) -> bool {
    let Some(target) = target else { return false };
    let count = fb.accumulators().1[(q.y * fb.width() + q.x) as usize];
    if count < NOISE_MIN_SAMPLES {
        return false;
    }
    let tile = |v: u32, size: u32| {
        let start = v / crate::rounds::TILE * crate::rounds::TILE;
        (start, (start + crate::rounds::TILE).min(size))
    };
    let ((x0, x1), (y0, y1)) = (tile(q.x, fb.width()), tile(q.y, fb.height()));
    let (mut sum, mut n) = (0.0f64, 0u32);
    for y in q.y.saturating_sub(NOISE_WINDOW).max(y0)..(q.y + NOISE_WINDOW + 1).min(y1) {
        for x in q.x.saturating_sub(NOISE_WINDOW).max(x0)..(q.x + NOISE_WINDOW + 1).min(x1) {
            if let Some(e) = fb.noise(x, y, NOISE_FLOOR) {
                sum += e * e;
                n += 1;
            }
        }
    }
    n > 0 && (sum / f64::from(n)).sqrt() <= f64::from(target)
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
            if self.settings.noise.is_some() && self.queue.samples_done() < self.queue.samples_total() {
                self.halted = Some("noise target");
            }
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
        JobSettings::sized(Some(spp), Some((w, h)))
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

    /// Per-sample values of a fake scene: a flat left part (it reaches any noise target)
    /// and a noisy right part (it does not), as fixed-point r = g = b.
    fn fake_sample(q: &Quad, i: u32) -> u64 {
        if q.x < 20 {
            5 << 22
        } else {
            (u64::from(i).wrapping_mul(2_654_435_761) % 1000) << 14
        }
    }

    /// A worker's result with even-sample sums.
    fn fake_split(spec: &BatchSpec) -> (Vec<u64>, Vec<u64>) {
        let mut sums = Vec::new();
        let mut even = Vec::new();
        for q in &spec.quads {
            let vals: Vec<u64> = spec.samples.clone().map(|i| fake_sample(q, i)).collect();
            let total: u64 = vals.iter().sum();
            sums.extend([total; 3]);
            even.push(spec.samples.clone().zip(&vals).filter(|(i, _)| i % 2 == 0).map(|(_, v)| *v).sum());
        }
        (sums, even)
    }

    /// Runs a job to its end, merging each window of `window` leases in reverse order.
    fn run_adaptive(farm: &mut Farm, limit: usize, window: usize) -> usize {
        let w = farm.add_worker("w".into(), 1, Instant::now());
        let now = Instant::now();
        let mut merged = 0;
        while merged < limit {
            let held: Vec<Assignment> = (0..window).map_while(|_| farm.assign(w, now)).collect();
            if held.is_empty() {
                break;
            }
            for a in held.iter().rev() {
                let (sums, even) = fake_split(&a.batch);
                farm.complete_split(w, a.job, a.batch.id, &sums, &even, 0, now).unwrap();
                merged += 1;
            }
        }
        merged
    }

    /// With a noise target, flat pixels stop early and noisy ones go on; the result is the
    /// same bits whatever the merge order, and after a restore from a mid-run checkpoint.
    #[test]
    fn adaptive_sampling_is_deterministic_and_resumable() {
        let adaptive = JobSettings { noise: Some(0.02), ..settings(40, 36, 256) };
        let mut reference = Farm::new();
        let id = reference.submit(bundle(), adaptive.clone(), 0).unwrap();
        run_adaptive(&mut reference, usize::MAX, 1);
        let done = reference.job(id).unwrap();
        assert_eq!(done.state, JobState::Done);
        assert_eq!(done.progress(Instant::now()).halted, Some("noise target"));
        let counts = done.framebuffer().accumulators().1;
        // Flat pixels stop at the minimum, but for those whose window reaches the noise.
        let flat = counts.iter().enumerate().filter(|(i, _)| i % 40 < 18).map(|(_, &c)| c);
        assert!(flat.clone().all(|c| c == NOISE_MIN_SAMPLES), "flat pixels stop at the minimum");
        let noisy = counts.iter().enumerate().filter(|(i, _)| i % 40 >= 20).map(|(_, &c)| c);
        assert!(noisy.clone().all(|c| c == 256), "noisy pixels take every sample");

        let mut shuffled = Farm::new();
        shuffled.submit(bundle(), adaptive.clone(), 0).unwrap();
        run_adaptive(&mut shuffled, usize::MAX, 7);
        let got = shuffled.job(id).unwrap().framebuffer();
        assert_eq!(got.accumulators(), done.framebuffer().accumulators());
        assert_eq!(got.even(), done.framebuffer().even());

        for stop in [3, 40, 90] {
            let mut first = Farm::new();
            first.submit(bundle(), adaptive.clone(), 0).unwrap();
            run_adaptive(&mut first, stop, 3);
            let job = first.job(id).unwrap();
            let stored = LoadedJob { record: job.record(), checkpoint: Some(job.checkpoint()) };
            let mut restarted = Farm::new();
            restarted.restore(stored, Instant::now()).unwrap();
            run_adaptive(&mut restarted, usize::MAX, 2);
            let got = restarted.job(id).unwrap();
            assert_eq!(got.state, JobState::Done, "stop {stop}");
            assert_eq!(got.framebuffer().accumulators(), done.framebuffer().accumulators(), "stop {stop}");
        }
    }

    /// A time budget ends the job wherever it is, even mid-round, and says so.
    #[test]
    fn a_spent_time_budget_ends_the_job() {
        let mut farm = Farm::new();
        let timed = JobSettings { time_limit: Some(Duration::from_secs(5)), ..settings(16, 16, 1000) };
        let id = farm.submit(bundle(), timed, 0).unwrap();
        let w = farm.add_worker("w".into(), 1, Instant::now());
        let t0 = Instant::now();
        let a = farm.assign(w, t0).unwrap();
        farm.complete(w, id, a.batch.id, &fake_sums(&a.batch), 0, t0).unwrap();
        assert!(farm.enforce_deadlines(t0 + Duration::from_secs(4)).is_empty());
        assert!(farm.assign(w, t0 + Duration::from_secs(6)).is_none());
        let job = farm.job(id).unwrap();
        assert_eq!((job.state.clone(), job.progress(t0).halted), (JobState::Done, Some("time budget")));
    }
}
