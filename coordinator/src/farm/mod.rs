//! The coordinator's state: jobs, workers, and who renders what. Pure: no I/O, no clock
//! (every function that needs the time takes it), no wire types and no storage; the
//! service wraps it and does those.

mod adaptive;
mod assign;
pub mod audit;
pub mod budget;
mod census;
mod entropy;
mod fence;
#[cfg(test)]
mod hostile_tests;
mod job;
mod pace;
mod repair;
mod restore;
mod strikes;
#[cfg(test)]
mod tests;

use std::collections::{BTreeMap, HashSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
use tessera_description::ids::{BatchId, JobId, WorkerId};
pub use tessera_description::job::{JobProgress, JobSettings, JobState};
use tessera_film::MergeError;

pub use adaptive::NOISE_FLOOR;
pub use assign::BatchFailure;
pub use audit::{AuditPolicy, DEFAULT_AUDIT_FRACTION};
pub use census::{Census, LeaseCounters, JOB_STATES};
pub use entropy::Entropy;
pub use job::{Job, Snapshot};
pub use repair::REPAIR_IDS;
pub use strikes::{FenceCounters, Standing, STRIKES_TO_QUARANTINE};

use crate::scheduler::{BatchSpec, CompleteError, LeaseToken, RestoreError};

/// Work streams one worker identity may hold at once: each holds copies of the scenes sent
/// to it until it reads them. As many as `tessera render --workers` may start, since its
/// local workers share one secret.
pub const MAX_CONNECTIONS_PER_IDENTITY: usize = 256;
/// A batch failing on this many distinct identities fails its job: the problem is not the
/// worker. (Failures from one identity count once, so a saboteur cannot fail others' jobs.)
pub const MAX_BATCH_FAILURES: u32 = 3;
/// A lease becomes a straggler, worth a speculative duplicate, after this many mean batch
/// times...
const SPECULATE_PATIENCE: u32 = 3;
/// ...and never sooner than this: duplicating work costs a worker's time too.
const SPECULATE_MIN_AGE: Duration = Duration::from_secs(1);

/// A connected worker.
#[derive(Debug, Clone)]
pub struct WorkerInfo {
    /// Name it gave.
    pub name: String,
    /// Who it is, as the service established it (strikes and quarantine hold against
    /// this, across reconnections).
    pub identity: String,
    /// Render threads.
    pub threads: u32,
    /// Jobs whose scene it has received.
    scenes: HashSet<JobId>,
    /// Batches done.
    pub batches_done: u64,
    /// Last message received.
    last_seen: Instant,
    /// (time, samples delivered so far) over the last `RATE_WINDOW`: its rate.
    delivered: VecDeque<(Instant, u64)>,
    /// Its leases were taken back for silence (until it is heard again): it is not
    /// counted on to render audits.
    silent: bool,
    /// It renders a batch's frame (`Hello.frames`): only then is it given sequences.
    pub renders_frames: bool,
}

impl WorkerInfo {
    /// Samples it delivered per second over the last few seconds; 0 once it has delivered
    /// nothing for that long.
    pub fn samples_per_second(&self, now: Instant) -> f64 {
        match (self.delivered.front(), self.delivered.back()) {
            (Some(&(t0, s0)), Some(&(t1, s1)))
                if t1 > t0 && now.saturating_duration_since(t1) <= job::RATE_WINDOW =>
            {
                (s1 - s0) as f64 / (t1 - t0).as_secs_f64()
            }
            _ => 0.0,
        }
    }

    /// How long since it was last heard from.
    pub fn last_heard(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.last_seen)
    }

    /// Books `samples` delivered at `now`.
    fn book(&mut self, samples: u64, now: Instant) {
        let total = self.delivered.back().map_or(0, |&(_, s)| s) + samples;
        self.delivered.push_back((now, total));
        while self.delivered.len() > 2
            && now.saturating_duration_since(self.delivered[1].0) > job::RATE_WINDOW
        {
            self.delivered.pop_front();
        }
    }
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
    /// The AOV layers the job wants back (`tessera_film::aov::Layout::bits`).
    pub aovs: u32,
    /// The lease's token, which the worker must send back.
    pub token: LeaseToken,
    /// The frame the batch renders (0 for a still).
    pub frame: u32,
    /// The stacked framebuffer's first row of that frame: the batch's pixels are
    /// `y - frame_row` in the frame.
    pub frame_row: u32,
}

impl Assignment {
    /// The answer to this lease with `sums` (and `even`), as an in-process worker gives it:
    /// its lease's token and attempt, no non-finite samples. For tests and benchmarks.
    pub fn answer<'a>(&'a self, sums: &'a [u64], even: Option<&'a [u64]>) -> BatchResult<'a> {
        BatchResult {
            job: self.job,
            batch: self.batch.id,
            sums,
            even,
            aov: &[],
            nonfinite: 0,
            attempt: self.attempt,
            lease: &self.token.0,
            render: Duration::ZERO,
        }
    }
}

/// A worker's result for one batch, as the farm merges it.
#[derive(Debug, Clone, Copy)]
pub struct BatchResult<'a> {
    /// The job.
    pub job: JobId,
    /// The batch.
    pub batch: BatchId,
    /// Three fixed-point sums per pixel, in the batch's pixel order.
    pub sums: &'a [u64],
    /// One even-sample luminance sum per pixel, for jobs with a noise target.
    pub even: Option<&'a [u64]>,
    /// The AOV layers' sums per pixel, for jobs that keep layers (`tessera_film::aov`).
    pub aov: &'a [u64],
    /// Samples that came back NaN or infinite (counted as black).
    pub nonfinite: u64,
    /// The attempt number the worker names; must be its lease's.
    pub attempt: u32,
    /// The lease token the worker sent back.
    pub lease: &'a [u8],
    /// How long the worker says the batch took it on one thread (zero: it did not say);
    /// sizes its later batches (`pace.rs`), within bounds the coordinator's own clock
    /// sets.
    pub render: Duration,
}

/// Why a submission was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SubmitError {
    /// The submission could not be processed (a bug, reported rather than a crash).
    #[error("the coordinator could not process the submission: {0}")]
    Internal(String),
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
    /// Noise target out of range (`Noise::checked`'s reason).
    #[error("{0}")]
    Noise(String),
    /// A zero time budget.
    #[error("the time budget must be positive")]
    TimeLimit,
    /// A frame range that cannot be rendered.
    #[error("frames {0}")]
    Frames(String),
    /// The job does not fit the coordinator's memory budget (`RESOURCE_EXHAUSTED`).
    #[error("{0}")]
    OverBudget(String),
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
    /// No such job (any more: harmless).
    #[error("unknown {0}")]
    UnknownJob(JobId),
    /// The sender is not a connected worker.
    #[error("the sender is not a connected worker")]
    NotConnected,
    /// The sender holds no lease for it: refused, and a strike.
    #[error("{job} {batch}: refused: {why}")]
    Forged {
        /// The job named.
        job: JobId,
        /// The batch named.
        batch: BatchId,
        /// What was wrong.
        why: String,
    },
    /// From the lease's holder, but impossible (attempt number, non-finite count): the
    /// batch goes back to the queue, and a strike.
    #[error("{job} {batch}: {why}")]
    Invalid {
        /// The job.
        job: JobId,
        /// The batch.
        batch: BatchId,
        /// What is wrong.
        why: String,
    },
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
    /// Strikes and quarantine by identity.
    standing: BTreeMap<String, Standing>,
    counters: FenceCounters,
    lease_counters: LeaseCounters,
    /// Lease tokens and audit choices (see `entropy.rs`).
    entropy: Entropy,
    audit: AuditPolicy,
    /// What a paced pass-two batch should take one thread (`None`: `PASS_TWO_BATCH_TIME`).
    batch_time: Option<Duration>,
    /// The connected workers' render threads, kept as they come and go: every assign
    /// needs it, and summing hundreds of workers' records there cost the bench's 256
    /// workers a few µs a batch.
    threads: u64,
}

impl Farm {
    /// An empty farm, its entropy keyed by the OS.
    pub fn new() -> Self {
        Farm::default()
    }

    /// An empty farm with reproducible tokens and audits (tests and benchmarks).
    pub fn with_seed(seed: [u8; 32]) -> Self {
        Farm { entropy: Entropy::from_seed(seed), ..Farm::default() }
    }

    /// Sets how often delivered batches are audited.
    pub fn set_audit_policy(&mut self, policy: AuditPolicy) {
        self.audit = policy;
    }

    /// How often delivered batches are audited.
    pub fn audit_policy(&self) -> AuditPolicy {
        self.audit
    }

    /// Sets what a pass-two batch should take one of a worker's threads once the worker's
    /// speed on the job is measured (the default, `PASS_TWO_BATCH_TIME`, suits most
    /// farms; shorter refines previews more often and costs more round trips). The
    /// batches cut stay within `PASS_TWO_MAX_PIXELS`, and the end of a pass still shrinks
    /// them; a restored job replays the sizes it logged whatever the batch time.
    pub fn set_batch_time(&mut self, batch_time: Duration) {
        self.batch_time = Some(batch_time);
    }

    /// What a paced pass-two batch should take one thread.
    pub fn batch_time(&self) -> Duration {
        self.batch_time.unwrap_or(crate::scheduler::PASS_TWO_BATCH_TIME)
    }

    /// Validates and queues a job, in one step (tests and in-process tools; the service
    /// prepares outside its lock and then inserts).
    pub fn submit(
        &mut self,
        bundle: Bundle,
        settings: JobSettings,
        priority: i32,
    ) -> Result<JobId, SubmitError> {
        let job = Job::prepare(JobId(0), Arc::new(bundle), settings, priority)?;
        Ok(self.insert(job))
    }

    /// Queues a prepared job under the next id, which it gets now.
    pub fn insert(&mut self, mut job: Job) -> JobId {
        self.next_job += 1;
        job.id = JobId(self.next_job);
        let id = job.id;
        self.jobs.insert(id, job);
        id
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

    /// Registers a worker whose identity is its name (in-process tools and tests).
    pub fn add_worker(&mut self, name: String, threads: u32, now: Instant) -> WorkerId {
        self.register(name.clone(), name, threads, now)
    }

    /// Registers a worker of `identity`; refused, with the reason, if that identity is
    /// quarantined or holds `MAX_CONNECTIONS_PER_IDENTITY` connections already.
    pub fn add_worker_as(
        &mut self,
        identity: String,
        name: String,
        threads: u32,
        now: Instant,
    ) -> Result<WorkerId, String> {
        if let Some(why) = self.standing.get(&identity).and_then(|s| s.quarantined.as_ref()) {
            return Err(format!("worker {identity} is quarantined: {why}"));
        }
        // Each connection of a worker holds the scenes sent to it until it reads them: an
        // identity that opened connections without end could hold that many copies.
        let open = self.workers.values().filter(|w| w.identity == identity).count();
        if open >= MAX_CONNECTIONS_PER_IDENTITY {
            return Err(format!(
                "worker {identity} has {open} connections already, the most one identity may hold"
            ));
        }
        Ok(self.register(identity, name, threads, now))
    }

    /// Says whether worker `id` renders a batch's frame; one that does not (an older
    /// build) is given stills only.
    pub fn set_renders_frames(&mut self, id: WorkerId, renders: bool) {
        if let Some(w) = self.workers.get_mut(&id) {
            w.renders_frames = renders;
        }
    }

    fn register(&mut self, identity: String, name: String, threads: u32, now: Instant) -> WorkerId {
        self.next_worker += 1;
        let id = WorkerId(self.next_worker);
        let info = WorkerInfo {
            name,
            identity,
            threads,
            scenes: HashSet::new(),
            batches_done: 0,
            last_seen: now,
            delivered: VecDeque::from([(now, 0)]),
            silent: false,
            renders_frames: true,
        };
        self.workers.insert(id, info);
        self.threads += u64::from(threads);
        id
    }

    /// The connected workers' render threads.
    pub(super) fn render_threads(&self) -> u32 {
        u32::try_from(self.threads).unwrap_or(u32::MAX)
    }

    /// The connected workers.
    pub fn workers(&self) -> impl Iterator<Item = (WorkerId, &WorkerInfo)> {
        self.workers.iter().map(|(id, w)| (*id, w))
    }

    /// Connected workers holding at least one lease of `job` now.
    pub fn workers_on(&self, job: JobId) -> u32 {
        let Some(j) = self.jobs.get(&job) else { return 0 };
        self.workers.keys().filter(|&&w| j.queue_leases_of(w) > 0).count() as u32
    }

    /// Sets a job's priority; `false` if there is no such job.
    pub fn set_priority(&mut self, job_id: JobId, priority: i32) -> bool {
        let Some(job) = self.jobs.get_mut(&job_id) else { return false };
        job.priority = priority;
        true
    }

    /// Batches leased to `worker` now.
    pub fn in_flight(&self, worker: WorkerId) -> usize {
        self.jobs.values().map(|j| j.queue_leases_of(worker)).sum()
    }

    /// Notes that `worker` is alive.
    pub fn touch(&mut self, worker: WorkerId, now: Instant) {
        if let Some(w) = self.workers.get_mut(&worker) {
            w.last_seen = now;
            w.silent = false;
        }
    }

    /// A worker left: its leases go back to the queue at once. Jobs waiting only for
    /// audits no connected worker can render any more end (see `settle`).
    pub fn remove_worker(&mut self, worker: WorkerId, now: Instant) -> usize {
        let n = self.take_back_all(worker, false);
        self.lease_counters.taken_back_left += n as u64;
        if let Some(w) = self.workers.remove(&worker) {
            self.threads -= u64::from(w.threads);
        }
        self.jobs.values_mut().for_each(|j| j.speeds.forget(worker));
        self.settle(now);
        n
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
        let expired = silent
            .into_iter()
            .filter_map(|id| {
                if let Some(w) = self.workers.get_mut(&id) {
                    w.silent = true;
                }
                let n = self.take_back_all(id, true);
                self.lease_counters.taken_back_silent += n as u64;
                (n > 0).then_some((id, n))
            })
            .collect();
        // Jobs waiting only for audits that no worker still heard from can render end.
        self.settle(now);
        expired
    }

    /// Pauses or resumes a job at `now`; `false` if there is no such job. A job that is
    /// over stays as it is. The time it stays paused is not counted against its budget.
    pub fn set_paused(&mut self, job_id: JobId, paused: bool, now: Instant) -> bool {
        let Some(job) = self.jobs.get_mut(&job_id) else { return false };
        job.set_paused(paused, now);
        true
    }

    /// Stops a job; its image stays.
    pub fn cancel(&mut self, job_id: JobId, now: Instant) -> bool {
        let Some(job) = self.jobs.get_mut(&job_id) else { return false };
        if !job.is_over() {
            job.abandon_all();
            job.state = JobState::Cancelled;
            job.finished = Some(now);
        }
        true
    }
}
