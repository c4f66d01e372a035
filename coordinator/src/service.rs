//! The gRPC face of the coordinator: checks every request, turns wire types into the
//! farm's types and back, and is the only module of this crate that touches prost types.

use std::collections::HashMap;
use std::path::Path;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_message::Msg as Out;
use tessera_proto::v1::coordinator_server::{Coordinator, CoordinatorServer};
use tessera_proto::v1::worker_message::Msg as In;
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::Stream;
use tonic::{Request, Response, Status, Streaming};
use tracing::{debug, info, warn};

use crate::farm::{Farm, JobSettings, JobState, RestoreJobError, ResultError, SubmitError};
use crate::store::{Store, StoreError};
use tessera_description::ids::{BatchId, JobId, WorkerId};

/// Timing of the worker protocol.
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    /// How often workers must send at least a heartbeat.
    pub heartbeat: Duration,
    /// Silence after which a worker's leases are taken back: several heartbeats, so that
    /// a busy network or a paused scheduler does not cost work.
    pub silence_timeout: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Timing { heartbeat: Duration::from_secs(2), silence_timeout: Duration::from_secs(10) }
    }
}

/// The most batches a worker may ask to hold at once; bounds the coordinator's lease table.
pub const MAX_CREDIT: u32 = 256;
/// Rows per `ImageChunk`: about 1 MB at 4K width, far below gRPC's message limit.
const ROWS_PER_CHUNK_PIXELS: usize = 1 << 16;
/// The largest message the coordinator accepts (scene bundles with their assets).
pub const MAX_MESSAGE_BYTES: usize = 256 << 20;

/// The coordinator: the farm behind a lock, and a change counter that wakes the tasks
/// feeding workers whenever there may be new work.
#[derive(Clone)]
pub struct CoordinatorService {
    farm: Arc<Mutex<Farm>>,
    changed: Arc<watch::Sender<u64>>,
    timing: Timing,
    durable: Option<Arc<Durable>>,
}

/// The database behind a coordinator with a data directory, and what of each job it holds.
struct Durable {
    store: Mutex<Store>,
    /// How often a job with new samples is checkpointed.
    interval: Duration,
    saved: Mutex<HashMap<JobId, Saved>>,
}

/// The last checkpoint written of a job.
#[derive(Debug, Clone)]
struct Saved {
    version: u64,
    state: JobState,
    pass_one_complete: bool,
    at: Instant,
}

/// Why a submission was not queued.
#[derive(Debug, thiserror::Error)]
pub enum SubmitFailure {
    /// The scene or settings are refused.
    #[error(transparent)]
    Invalid(#[from] SubmitError),
    /// The job could not be written to the data directory, so it was not queued.
    #[error("the job could not be stored: {0}")]
    Store(#[from] StoreError),
}

/// A job taken up again from a data directory.
#[derive(Debug, Clone)]
pub struct Resumed {
    /// The job.
    pub id: JobId,
    /// Its state.
    pub state: JobState,
    /// Samples kept from its checkpoint.
    pub samples_kept: u64,
    /// Samples in the job.
    pub samples_total: u64,
}

/// What opening a data directory found.
#[derive(Debug, Default)]
pub struct Recovery {
    /// Jobs taken up again, oldest first.
    pub resumed: Vec<Resumed>,
    /// Damage found and how it was handled; jobs that could not be taken up.
    pub problems: Vec<String>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock must not take every later request down with it: the
    // holders keep their data consistent at every return.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl CoordinatorService {
    /// A coordinator with no jobs, keeping nothing on disk.
    pub fn new(timing: Timing) -> Self {
        let (changed, _) = watch::channel(0);
        CoordinatorService {
            farm: Arc::new(Mutex::new(Farm::new())),
            changed: Arc::new(changed),
            timing,
            durable: None,
        }
    }

    /// A coordinator keeping its jobs in `dir`, with every unfinished job found there taken
    /// up again from its newest good checkpoint. Checkpoints are written every `interval`
    /// while samples come in, at the end of pass one, and when a job ends.
    pub fn open(timing: Timing, dir: &Path, interval: Duration) -> Result<(Self, Recovery), StoreError> {
        let (store, loaded) = Store::open(dir)?;
        let mut this = CoordinatorService::new(timing);
        let mut recovery = Recovery { problems: loaded.problems, ..Recovery::default() };
        let mut saved = HashMap::new();
        {
            let mut farm = this.farm();
            farm.reserve_ids_through(store.max_job_id());
            let now = Instant::now();
            for job in loaded.jobs {
                let id = job.record.id;
                let record = job.record.clone();
                let restored = match farm.restore(job, now) {
                    // A checkpoint that does not fit its job is not resumed from: the job
                    // starts over, its last good state.
                    Err(e @ (RestoreJobError::Mismatch { .. } | RestoreJobError::Batches(_))) => {
                        recovery.problems.push(format!("{id}: {e}; it restarts from the beginning"));
                        farm.restore(crate::store::LoadedJob { record, checkpoint: None }, now)
                    }
                    other => other,
                };
                match restored {
                    Ok(id) => {
                        let j = farm.job(id).expect("just restored");
                        let p = j.progress(now);
                        let pass_one_complete = j.pass_one_complete();
                        let version = j.framebuffer().version();
                        saved.insert(
                            id,
                            Saved { version, state: j.state.clone(), pass_one_complete, at: now },
                        );
                        recovery.resumed.push(Resumed {
                            id,
                            state: p.state,
                            samples_kept: p.samples_done,
                            samples_total: p.samples_total,
                        });
                    }
                    Err(e) => recovery.problems.push(format!("{id} cannot be taken up again: {e}")),
                }
            }
        }
        for r in &recovery.resumed {
            info!(id = %r.id, kept = r.samples_kept, total = r.samples_total, state = ?r.state, "job taken up from the data directory");
        }
        this.durable =
            Some(Arc::new(Durable { store: Mutex::new(store), interval, saved: Mutex::new(saved) }));
        Ok((this, recovery))
    }

    /// The farm, locked. Held only for short, non-blocking work.
    pub fn farm(&self) -> MutexGuard<'_, Farm> {
        lock(&self.farm)
    }

    /// Wakes every worker feeder: a job arrived, leases came back, or a worker left.
    pub fn notify(&self) {
        self.changed.send_modify(|v| *v = v.wrapping_add(1));
    }

    /// A receiver of change notifications (also for in-process clients such as `render`).
    pub fn subscribe(&self) -> watch::Receiver<u64> {
        self.changed.subscribe()
    }

    /// Queues a job (also in-process, as `tessera render` does). With a data directory the
    /// job is on disk before this returns.
    pub async fn submit(
        &self,
        bundle: Bundle,
        settings: JobSettings,
        priority: i32,
    ) -> Result<JobId, SubmitFailure> {
        let this = self.clone();
        let id = tokio::task::spawn_blocking(move || {
            // The store's lock is taken first and held until the job's row is written, so
            // the checkpointer never writes a checkpoint of a job that has no row yet.
            let mut store = this.durable.as_ref().map(|d| lock(&d.store));
            let id = this.farm().submit(bundle, settings, priority)?;
            if let Some(store) = store.as_mut() {
                let record = this.farm().job(id).expect("just submitted").record();
                if let Err(e) = store.add_job(&record) {
                    this.farm().remove_job(id);
                    return Err(SubmitFailure::Store(e));
                }
            }
            Ok(id)
        })
        .await
        .expect("submit does not panic")?;
        info!(%id, priority, "job queued");
        self.notify();
        Ok(id)
    }

    /// Records a job's new state on disk (paused, resumed, cancelled).
    async fn persist_state(&self, id: JobId) -> Result<(), Status> {
        let Some(durable) = self.durable.clone() else { return Ok(()) };
        let Some(state) = self.farm().job(id).map(|j| j.state.clone()) else { return Ok(()) };
        tokio::task::spawn_blocking(move || {
            lock(&durable.store).set_state(id, &state)?;
            if let Some(s) = lock(&durable.saved).get_mut(&id) {
                s.state = state;
            }
            Ok::<_, StoreError>(())
        })
        .await
        .expect("set_state does not panic")
        .map_err(|e| Status::unavailable(format!("the change is made but not on disk: {e}")))
    }

    /// Writes a checkpoint of every job that has new samples and is due: its interval has
    /// passed, it finished pass one, or it ended; with `all`, of every job with anything
    /// new (at shutdown). Returns how many were written.
    pub async fn checkpoint(&self, all: bool) -> Result<usize, StoreError> {
        let Some(durable) = self.durable.clone() else { return Ok(0) };
        let now = Instant::now();
        let due: Vec<JobId> = {
            let farm = self.farm();
            let saved = lock(&durable.saved);
            farm.jobs()
                .filter(|j| {
                    let last = saved.get(&j.id);
                    let changed = last.is_none_or(|s| s.version != j.framebuffer().version());
                    let ended = j.is_over() && last.is_none_or(|s| s.state != j.state);
                    let due = all
                        || ended
                        || last.is_none_or(|s| {
                            now.saturating_duration_since(s.at) >= durable.interval
                                || (j.pass_one_complete() && !s.pass_one_complete)
                        });
                    (changed || ended) && due
                })
                .map(|j| j.id)
                .collect()
        };
        // One job at a time: a snapshot is the size of its framebuffer, and memory stays
        // bounded by the largest job, not by all of them at once.
        for &id in &due {
            let Some((checkpoint, saved)) = self.farm().job(id).map(|j| {
                let saved = Saved {
                    version: j.framebuffer().version(),
                    state: j.state.clone(),
                    pass_one_complete: j.pass_one_complete(),
                    at: now,
                };
                (j.checkpoint(), saved)
            }) else {
                continue;
            };
            let durable = durable.clone();
            tokio::task::spawn_blocking(move || {
                let started = Instant::now();
                let generation = lock(&durable.store).save(&checkpoint, &saved.state)?;
                debug!(job = %checkpoint.job, generation, samples = checkpoint.samples_done, took = ?started.elapsed(), "checkpoint written");
                lock(&durable.saved).insert(checkpoint.job, saved);
                Ok::<_, StoreError>(())
            })
            .await
            .expect("checkpoint writing does not panic")?;
        }
        Ok(due.len())
    }

    /// Checkpoints jobs as they fall due, until the service is dropped.
    pub fn spawn_checkpointer(&self) -> Option<tokio::task::JoinHandle<()>> {
        // A job falls due at most a quarter interval late.
        let tick = (self.durable.as_ref()?.interval / 4).min(Duration::from_millis(250));
        let this = self.clone();
        Some(tokio::spawn(async move {
            loop {
                tokio::time::sleep(tick).await;
                if let Err(e) = this.checkpoint(false).await {
                    // The farm goes on; the next tick tries again, and status shows the age.
                    warn!("checkpoint failed: {e}");
                }
                if Arc::strong_count(&this.farm) == 1 {
                    return;
                }
            }
        }))
    }

    /// The tonic server for this service, with message limits set.
    pub fn into_server(self) -> CoordinatorServer<Self> {
        CoordinatorServer::new(self)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES)
    }

    /// Takes back the leases of silent workers, once a second, until the service is dropped.
    pub fn spawn_reaper(&self) -> tokio::task::JoinHandle<()> {
        let this = self.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                tick.tick().await;
                let ended = this.farm().enforce_deadlines(Instant::now());
                for id in &ended {
                    info!(%id, "time budget spent; job ends");
                }
                if !ended.is_empty() {
                    this.notify();
                }
                let expired = this.farm().expire_silent(Instant::now(), this.timing.silence_timeout);
                for (worker, n) in &expired {
                    warn!(%worker, batches = n, "worker silent; its batches go to others");
                }
                if !expired.is_empty() {
                    this.notify();
                }
                if Arc::strong_count(&this.farm) == 1 {
                    return;
                }
            }
        })
    }

    /// Feeds one worker stream until it ends.
    async fn serve_worker(
        self,
        mut inbound: Streaming<pb::WorkerMessage>,
        tx: mpsc::Sender<Result<pb::CoordinatorMessage, Status>>,
    ) {
        let refuse =
            |reason: String| pb::CoordinatorMessage { msg: Some(Out::Refused(pb::Refused { reason })) };
        let hello = match inbound.message().await {
            Ok(Some(pb::WorkerMessage { msg: Some(In::Hello(h)) })) => h,
            Ok(_) => {
                let _ =
                    tx.send(Ok(refuse("the first message of a worker stream must be Hello".into()))).await;
                return;
            }
            Err(e) => {
                debug!("worker stream failed before Hello: {e}");
                return;
            }
        };
        if hello.protocol_version != pb::ProtocolVersion::Current as i32 {
            let reason = format!(
                "protocol version {} is not supported; this coordinator speaks version {}",
                hello.protocol_version,
                pb::ProtocolVersion::Current as i32
            );
            warn!(name = %hello.name, "{reason}");
            let _ = tx.send(Ok(refuse(reason))).await;
            return;
        }
        if hello.renderer_version != tessera_description::RENDERER_VERSION {
            let reason = format!(
                "worker runs renderer {}, coordinator {}: images would not be bit-identical; run the same tessera build everywhere",
                hello.renderer_version,
                tessera_description::RENDERER_VERSION
            );
            warn!(name = %hello.name, "{reason}");
            let _ = tx.send(Ok(refuse(reason))).await;
            return;
        }
        let threads = hello.threads.clamp(1, 4096);
        let id = self.farm().add_worker(hello.name.clone(), threads, Instant::now());
        info!(worker = %id, name = %hello.name, threads, "worker joined");
        let welcome =
            pb::Welcome { worker_id: id.0, heartbeat_interval_ms: self.timing.heartbeat.as_millis() as u32 };
        if tx.send(Ok(pb::CoordinatorMessage { msg: Some(Out::Welcome(welcome)) })).await.is_err() {
            self.farm().remove_worker(id);
            return;
        }
        let mut credit = hello.credit.min(MAX_CREDIT);
        let mut changed = self.subscribe();
        let end = loop {
            // Hand out work while the worker wants it and there is some.
            while credit > 0 {
                let Some(a) = self.farm().assign(id, Instant::now()) else { break };
                credit -= 1;
                if a.speculative {
                    info!(worker = %id, job = %a.job, batch = %a.batch.id, attempt = a.attempt, "speculative duplicate of a straggler's batch");
                }
                if let Some((bundle, hash, settings)) = a.scene {
                    let scene = pb::JobScene {
                        job_id: a.job.0,
                        scene_hash: hash,
                        bundle: Some(bundle_to_wire(&bundle)),
                        settings: Some(settings_to_wire(&settings)),
                    };
                    if tx.send(Ok(pb::CoordinatorMessage { msg: Some(Out::Scene(scene)) })).await.is_err() {
                        break;
                    }
                }
                let pixels = a.batch.quads.iter().flat_map(|q| [q.x, q.y]).collect();
                let batch = pb::Batch {
                    job_id: a.job.0,
                    batch_id: a.batch.id.0,
                    attempt: a.attempt,
                    scene_hash: a.scene_hash,
                    pass: a.batch.pass.number(),
                    sample_start: a.batch.samples.start,
                    sample_end: a.batch.samples.end,
                    pixels,
                    even_sums: a.even_sums,
                };
                if tx.send(Ok(pb::CoordinatorMessage { msg: Some(Out::Batch(batch)) })).await.is_err() {
                    break;
                }
            }
            tokio::select! {
                msg = inbound.message() => match msg {
                    Ok(Some(m)) => {
                        self.farm().touch(id, Instant::now());
                        match self.handle(id, m, &mut credit) {
                            Ok(()) => {}
                            Err(reason) => {
                                warn!(worker = %id, "{reason}; disconnecting it");
                                let _ = tx.send(Ok(refuse(reason))).await;
                                break "refused";
                            }
                        }
                    }
                    Ok(None) => break "closed",
                    Err(e) => { debug!(worker = %id, "stream error: {e}"); break "lost" }
                },
                r = changed.changed() => if r.is_err() { break "shutdown" },
                _ = tx.closed() => break "lost",
            }
        };
        let n = self.farm().remove_worker(id);
        info!(worker = %id, batches_taken_back = n, "worker left ({end})");
        self.notify();
    }

    /// Applies one worker message; `Err` is a reason to disconnect the worker.
    fn handle(&self, id: WorkerId, m: pb::WorkerMessage, credit: &mut u32) -> Result<(), String> {
        match m.msg {
            Some(In::Results(r)) => {
                let now = Instant::now();
                let mut merged = false;
                for res in r.results {
                    let (job, batch) = (JobId(res.job_id), BatchId(res.batch_id));
                    let done = self.farm().complete_split(
                        id,
                        job,
                        batch,
                        &res.sums,
                        &res.even_sums,
                        res.nonfinite_samples,
                        now,
                    );
                    match done {
                        Ok(()) => merged = true,
                        Err(ResultError::Duplicate(e)) => {
                            debug!(worker = %id, %job, "dropped duplicate: {e}")
                        }
                        Err(ResultError::UnknownJob(j)) => debug!(worker = %id, "result for unknown {j}"),
                        Err(e @ ResultError::Malformed { .. }) => {
                            self.notify();
                            return Err(format!("malformed result: {e}"));
                        }
                    }
                }
                *credit = credit.saturating_add(r.credit).min(MAX_CREDIT);
                if merged {
                    self.notify();
                }
                Ok(())
            }
            Some(In::Heartbeat(_)) => Ok(()),
            Some(In::Failed(f)) => {
                warn!(worker = %id, job = f.job_id, batch = f.batch_id, "batch failed: {}", f.error);
                self.farm().fail_batch(JobId(f.job_id), BatchId(f.batch_id), &f.error);
                *credit = credit.saturating_add(f.credit).min(MAX_CREDIT);
                self.notify();
                Ok(())
            }
            Some(In::Hello(_)) => Err("Hello sent twice".into()),
            None => Err("empty message".into()),
        }
    }
}

/// A bundle as it travels.
pub fn bundle_to_wire(b: &Bundle) -> pb::SceneBundle {
    pb::SceneBundle {
        name: b.name.clone(),
        text: b.text.clone(),
        assets: b
            .assets
            .iter()
            .map(|(path, data)| pb::Asset { path: path.clone(), data: data.clone() })
            .collect(),
    }
}

/// A bundle from the wire.
pub fn bundle_from_wire(b: pb::SceneBundle) -> Bundle {
    let mut assets: Vec<(String, Vec<u8>)> = b.assets.into_iter().map(|a| (a.path, a.data)).collect();
    assets.sort();
    Bundle { name: b.name, text: b.text, assets }
}

/// Job settings as they travel.
pub fn settings_to_wire(s: &JobSettings) -> pb::RenderSettings {
    let (width, height) = s.size.unwrap_or((0, 0));
    pb::RenderSettings {
        spp: s.spp.unwrap_or(0),
        width,
        height,
        time_limit_seconds: s.time_limit.map_or(0.0, |t| t.as_secs_f64()),
        noise: s.noise.map_or(0.0, f64::from),
    }
}

/// Job settings from the wire; 0 means "keep the scene's".
pub fn settings_from_wire(s: pb::RenderSettings) -> Result<JobSettings, String> {
    let size = match (s.width, s.height) {
        (0, 0) => None,
        (0, _) | (_, 0) => return Err(format!("give both width and height, got {}x{}", s.width, s.height)),
        (w, h) => Some((w, h)),
    };
    let time_limit = match s.time_limit_seconds {
        0.0 => None,
        t if t.is_finite() && t > 0.0 && t < 1e9 => Some(Duration::from_secs_f64(t)),
        t => return Err(format!("time_limit_seconds must be a positive number of seconds, got {t}")),
    };
    let noise = match s.noise {
        0.0 => None,
        n if n.is_finite() && n > 0.0 && n < 1.0 => Some(n as f32),
        n => return Err(format!("noise must be a relative error in (0, 1), got {n}")),
    };
    Ok(JobSettings { spp: (s.spp != 0).then_some(s.spp), size, time_limit, noise })
}

fn state_to_wire(s: &JobState) -> pb::JobState {
    match s {
        JobState::Queued => pb::JobState::Queued,
        JobState::Running => pb::JobState::Running,
        JobState::Done => pb::JobState::Done,
        JobState::Cancelled => pb::JobState::Cancelled,
        JobState::Failed(_) => pb::JobState::Failed,
        JobState::Paused => pb::JobState::Paused,
    }
}

/// Pixels per watch update: about 1.8 MB, far below gRPC's message limit, and all a slow
/// viewer's task holds.
pub const WATCH_CHUNK_PIXELS: usize = 1 << 16;
/// Updates per second a viewer gets unless it asks for fewer.
pub const WATCH_DEFAULT_RATE: f64 = 10.0;

/// A job's progress as it travels.
fn status_to_wire(p: &crate::farm::JobProgress) -> pb::JobStatus {
    pb::JobStatus {
        job_id: p.id.0,
        scene: p.scene.clone(),
        state: state_to_wire(&p.state) as i32,
        width: p.width,
        height: p.height,
        spp: p.spp,
        pass: p.pass,
        samples_done: p.samples_done,
        samples_total: p.samples_total,
        samples_per_second: p.samples_per_second,
        elapsed_seconds: p.elapsed.as_secs_f64(),
        error: match &p.state {
            JobState::Failed(e) => e.clone(),
            _ => String::new(),
        },
        pass_one_done: p.pass_one_done,
        priority: p.priority,
    }
}

/// Consecutive pixels grouped into runs.
fn runs(pixels: &[tessera_film::framebuffer::PixelState]) -> Vec<pb::PixelRun> {
    let mut out: Vec<pb::PixelRun> = Vec::new();
    for p in pixels {
        match out.last_mut() {
            Some(r) if r.start as usize + r.counts.len() == p.index as usize => {
                r.sums.extend_from_slice(&p.sums);
                r.counts.push(p.count);
            }
            _ => out.push(pb::PixelRun { start: p.index, sums: p.sums.to_vec(), counts: vec![p.count] }),
        }
    }
    out
}

impl CoordinatorService {
    /// The job a viewer asks for: by id; or (0) the active job (running, else paused, else
    /// queued, oldest first), or the only job; otherwise the jobs to choose from.
    fn pick_job(&self, id: u64) -> Result<JobId, Status> {
        let farm = self.farm();
        if id != 0 {
            return farm
                .job(JobId(id))
                .map(|j| j.id)
                .ok_or_else(|| Status::not_found(format!("no job {id} on this coordinator")));
        }
        for state in [JobState::Running, JobState::Paused, JobState::Queued] {
            if let Some(j) = farm.jobs().find(|j| j.state == state) {
                return Ok(j.id);
            }
        }
        let jobs: Vec<_> = farm.jobs().collect();
        match jobs.as_slice() {
            [] => Err(Status::not_found("this coordinator has no jobs yet")),
            [only] => Ok(only.id),
            all => {
                let list: Vec<String> = all
                    .iter()
                    .map(|j| {
                        format!(
                            "{} ({}, {})",
                            j.id.0,
                            state_to_wire(&j.state)
                                .as_str_name()
                                .trim_start_matches("JOB_STATE_")
                                .to_lowercase(),
                            j.bundle.name
                        )
                    })
                    .collect();
                Err(Status::failed_precondition(format!(
                    "no job is running; choose one with --job: {}",
                    list.join(", ")
                )))
            }
        }
    }

    /// Feeds one viewer: the changes since what it has, in bounded chunks, at most
    /// `1 / interval` rounds a second. It waits on its own channel only: a stalled viewer
    /// stalls this task alone, and when it reads again it gets the newest state.
    async fn feed_viewer(
        self,
        job: JobId,
        interval: Duration,
        tx: mpsc::Sender<Result<pb::FramebufferUpdate, Status>>,
    ) {
        let mut changed = self.subscribe();
        let mut sent = 0u64;
        loop {
            let round = Instant::now();
            let until = match self.farm().job(job) {
                Some(j) => j.framebuffer().version(),
                None => return,
            };
            let mut from = Some(0);
            let mut over = false;
            while let Some(f) = from {
                let update = {
                    let farm = self.farm();
                    let Some(j) = farm.job(job) else { return };
                    let fb = j.framebuffer();
                    let (pixels, next) = fb.changes(sent, until, f, WATCH_CHUNK_PIXELS);
                    from = next;
                    // Over, and everything up to the final version sent: the last update.
                    over = j.is_over() && fb.version() == until;
                    pb::FramebufferUpdate {
                        job_id: job.0,
                        width: fb.width(),
                        height: fb.height(),
                        version: until,
                        chunk_end: next.is_none(),
                        runs: runs(&pixels),
                        status: Some(status_to_wire(&j.progress(Instant::now()))),
                        workers: farm.workers().count() as u32,
                        r#final: over && next.is_none(),
                        reset: sent == 0 && f == 0,
                    }
                };
                if tx.send(Ok(update)).await.is_err() {
                    return;
                }
            }
            sent = until;
            if over {
                return;
            }
            tokio::select! {
                r = changed.changed() => if r.is_err() { return },
                _ = tx.closed() => return,
            }
            tokio::time::sleep(interval.saturating_sub(round.elapsed())).await;
        }
    }
}

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send + 'static>>;

#[tonic::async_trait]
impl Coordinator for CoordinatorService {
    type WorkStream = BoxStream<pb::CoordinatorMessage>;
    type FetchImageStream = BoxStream<pb::ImageChunk>;
    type WatchStream = BoxStream<pb::FramebufferUpdate>;

    async fn watch(&self, request: Request<pb::WatchRequest>) -> Result<Response<Self::WatchStream>, Status> {
        let req = request.into_inner();
        let job = self.pick_job(req.job_id)?;
        let rate =
            if req.max_rate > 0.0 { req.max_rate.min(WATCH_DEFAULT_RATE * 10.0) } else { WATCH_DEFAULT_RATE };
        if !rate.is_finite() {
            return Err(Status::invalid_argument("max_rate must be a finite number"));
        }
        let interval = Duration::from_secs_f64(1.0 / rate.max(1.0 / 60.0));
        // One update in flight: a viewer that does not read holds one chunk, no backlog.
        let (tx, rx) = mpsc::channel(1);
        tokio::spawn(self.clone().feed_viewer(job, interval, tx));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn work(
        &self,
        request: Request<Streaming<pb::WorkerMessage>>,
    ) -> Result<Response<Self::WorkStream>, Status> {
        let inbound = request.into_inner();
        // Room for a full credit's worth of batches plus scenes, so that handing out work
        // never waits on the worker reading.
        let (tx, rx) = mpsc::channel(MAX_CREDIT as usize + 16);
        tokio::spawn(self.clone().serve_worker(inbound, tx));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn submit(
        &self,
        request: Request<pb::SubmitRequest>,
    ) -> Result<Response<pb::SubmitResponse>, Status> {
        let req = request.into_inner();
        if req.protocol_version != pb::ProtocolVersion::Current as i32 {
            return Err(Status::failed_precondition(format!(
                "client speaks protocol version {}, coordinator {}",
                req.protocol_version,
                pb::ProtocolVersion::Current as i32
            )));
        }
        let bundle = req.bundle.ok_or_else(|| Status::invalid_argument("submit without a scene bundle"))?;
        let settings =
            settings_from_wire(req.settings.unwrap_or_default()).map_err(Status::invalid_argument)?;
        let id =
            self.submit(bundle_from_wire(bundle), settings, req.priority).await.map_err(|e| match e {
                SubmitFailure::Invalid(e) => Status::invalid_argument(e.to_string()),
                e @ SubmitFailure::Store(_) => Status::unavailable(e.to_string()),
            })?;
        let farm = self.farm();
        let job = farm.job(id).expect("just submitted");
        let fb = job.framebuffer();
        Ok(Response::new(pb::SubmitResponse {
            job_id: id.0,
            width: fb.width(),
            height: fb.height(),
            spp: job.spp,
        }))
    }

    async fn status(
        &self,
        request: Request<pb::StatusRequest>,
    ) -> Result<Response<pb::StatusResponse>, Status> {
        let want = request.into_inner().job_id;
        let farm = self.farm();
        let now = Instant::now();
        if want != 0 && farm.job(JobId(want)).is_none() {
            return Err(Status::not_found(format!("no job {want} on this coordinator")));
        }
        let jobs = farm
            .jobs()
            .filter(|j| want == 0 || j.id.0 == want)
            .map(|j| status_to_wire(&j.progress(now)))
            .collect();
        let workers = farm
            .workers()
            .map(|(id, w)| pb::WorkerStatus {
                worker_id: id.0,
                name: w.name.clone(),
                threads: w.threads,
                batches_in_flight: farm.in_flight(id) as u32,
                batches_done: w.batches_done,
            })
            .collect();
        Ok(Response::new(pb::StatusResponse { jobs, workers }))
    }

    async fn fetch_image(
        &self,
        request: Request<pb::FetchImageRequest>,
    ) -> Result<Response<Self::FetchImageStream>, Status> {
        let id = JobId(request.into_inner().job_id);
        let (width, height, rgb, state) = {
            let farm = self.farm();
            let job =
                farm.job(id).ok_or_else(|| Status::not_found(format!("no {id} on this coordinator")))?;
            let fb = job.framebuffer();
            (fb.width(), fb.height(), fb.resolve(), state_to_wire(&job.state))
        };
        let rows_per_chunk = (ROWS_PER_CHUNK_PIXELS / width.max(1) as usize).max(1);
        let row_floats = width as usize * 3;
        let chunks: Vec<Result<pb::ImageChunk, Status>> = rgb
            .chunks(rows_per_chunk * row_floats)
            .enumerate()
            .map(|(i, rows)| {
                Ok(pb::ImageChunk {
                    width,
                    height,
                    row_start: (i * rows_per_chunk) as u32,
                    rows: (rows.len() / row_floats) as u32,
                    rgb: rows.iter().flat_map(|v| v.to_le_bytes()).collect(),
                    state: state as i32,
                })
            })
            .collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }

    async fn pause(&self, request: Request<pb::PauseRequest>) -> Result<Response<pb::PauseResponse>, Status> {
        let req = request.into_inner();
        let id = JobId(req.job_id);
        if !self.farm().set_paused(id, req.paused) {
            return Err(Status::not_found(format!("no {id} on this coordinator")));
        }
        info!(%id, paused = req.paused, "job paused or resumed");
        self.notify();
        self.persist_state(id).await?;
        Ok(Response::new(pb::PauseResponse {}))
    }

    async fn cancel(
        &self,
        request: Request<pb::CancelRequest>,
    ) -> Result<Response<pb::CancelResponse>, Status> {
        let id = JobId(request.into_inner().job_id);
        if !self.farm().cancel(id) {
            return Err(Status::not_found(format!("no {id} on this coordinator")));
        }
        info!(%id, "job cancelled");
        self.notify();
        self.persist_state(id).await?;
        Ok(Response::new(pb::CancelResponse {}))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::Checkpoint;
    use crate::scheduler::Completed;
    use crate::store::JobRecord;

    /// A checkpoint that does not fit its job (here: another spp) is reported and the job
    /// starts over, instead of being resumed from or dropped.
    #[test]
    fn a_checkpoint_that_does_not_fit_restarts_its_job() {
        let dir = tempfile::tempdir().unwrap();
        {
            let (mut store, _) = Store::open(dir.path()).unwrap();
            let bundle = Bundle {
                name: "small.toml".into(),
                text: include_str!("../../tests/scenes/small.toml").into(),
                assets: vec![],
            };
            let settings = JobSettings::sized(Some(4), Some((8, 8)));
            let record = JobRecord { id: JobId(3), bundle, settings, priority: 0, state: JobState::Running };
            store.add_job(&record).unwrap();
            let wrong = Checkpoint {
                job: JobId(3),
                width: 8,
                height: 8,
                spp: 3,
                completed: Completed { below: 1, above: vec![] },
                nonfinite_samples: 0,
                samples_done: 16,
                sums: vec![[0; 3]; 64],
                counts: [vec![1; 16], vec![0; 48]].concat(),
                even: vec![],
                spent: Duration::ZERO,
            };
            store.save(&wrong, &JobState::Running).unwrap();
        }
        let (service, recovery) =
            CoordinatorService::open(Timing::default(), dir.path(), Duration::from_secs(1)).unwrap();
        assert!(
            recovery.problems.iter().any(|p| p.contains("restarts from the beginning")),
            "{:?}",
            recovery.problems
        );
        assert_eq!(recovery.resumed.len(), 1);
        assert_eq!(recovery.resumed[0].samples_kept, 0);
        let farm = service.farm();
        assert_eq!(farm.job(JobId(3)).unwrap().state, JobState::Queued);
        drop(farm);
        // Ids go on above the stored ones.
        assert!(
            service
                .farm()
                .submit(
                    Bundle {
                        name: "s".into(),
                        text: include_str!("../../tests/scenes/small.toml").into(),
                        assets: vec![]
                    },
                    JobSettings::default(),
                    0
                )
                .unwrap()
                > JobId(3)
        );
    }
}
