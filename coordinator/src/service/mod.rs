//! The gRPC face of the coordinator: checks every request, turns wire types into the
//! farm's types and back, and is the only part of this crate that touches prost types.
//!
//! One rule holds the farm together: its lock is held only for short, bounded work
//! (a lease, a merge, a status listing, a copy-on-write snapshot). Parsing scenes,
//! resolving images, encoding viewer deltas and writing checkpoints happen outside it, on
//! snapshots. The files here are split by RPC family: `workers.rs` (the work stream),
//! `clients.rs` (submit, status, images, control), `viewers.rs` (watch streams fed from
//! one shared delta per job), `durability.rs` (the store, checkpoints, recovery),
//! `auth.rs` (who is calling and what each role may do), and `rpc.rs` (the trait impl
//! that routes each RPC, checking the caller's role first). Wire ↔ domain conversions live
//! next to the contract, in `tessera_proto::convert`.

mod auth;
mod budget;
mod clients;
mod durability;
mod frame_viewers;
mod gate;
mod previews;
pub mod probes;
mod rpc;
mod scan;
mod scrape;
mod submit;
mod viewers;
mod workers;

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tessera_description::ids::JobId;
use tessera_description::job::{JobProgress, JobSettings, JobState};
use tessera_proto::v1::coordinator_server::CoordinatorServer;
use tessera_proto::v1::workers_server::WorkersServer;
use tokio::sync::watch;
use tonic::service::Routes;
use tonic::transport::Server;
use tracing::{info, warn};

use crate::farm::Farm;

pub use auth::{Auth, AuthError, Principal, Role, Tokens, DEFAULT_MAX_PRIORITY, MIN_TOKEN_CHARS};
pub use budget::{default_budget, SUBMITS_AT_ONCE};
pub use durability::{Recovery, Resumed};
pub use gate::Admission;
pub use submit::{SubmitFailure, FAULT_STALL_VALIDATION_ENV};
pub use viewers::{ViewerUpdates, MAX_VIEWERS, MAX_VIEWERS_PER_JOB, WATCH_CHUNK_PIXELS, WATCH_DEFAULT_RATE};
pub use workers::MAX_CREDIT;

/// Finished jobs a coordinator keeps (their images fetchable, their memory held) unless
/// told otherwise; the oldest beyond it are dropped from memory and the store.
pub const KEEP_FINISHED: usize = 64;

/// Timing of the worker protocol.
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    /// How often workers must send at least a heartbeat.
    pub heartbeat: Duration,
    /// Silence after which a worker's leases are taken back: several heartbeats, so that
    /// a busy network or a paused scheduler does not cost work.
    pub silence_timeout: Duration,
    /// What a pass-two batch should take one of a worker's threads once its speed is
    /// measured (`Farm::set_batch_time`).
    pub batch_time: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            heartbeat: Duration::from_secs(2),
            silence_timeout: Duration::from_secs(10),
            batch_time: crate::scheduler::PASS_TWO_BATCH_TIME,
        }
    }
}

/// The largest message the coordinator accepts from clients or sends (scene bundles with
/// their assets, to workers too).
pub use tessera_proto::connect::MAX_MESSAGE_BYTES;

mod limits;
pub use limits::{MAX_LEASE_TOKEN_BYTES, MAX_WORKER_MESSAGE_BYTES};

/// The coordinator: the farm behind a lock held only briefly, a change counter that wakes
/// the tasks feeding workers and viewers, and a shutdown signal for its background tasks.
#[derive(Clone)]
pub struct CoordinatorService {
    farm: Arc<Mutex<Farm>>,
    changed: Arc<watch::Sender<u64>>,
    shutdown: Arc<watch::Sender<bool>>,
    timing: Timing,
    durable: Option<Arc<durability::Durable>>,
    feeds: Arc<viewers::Feeds>,
    previews: Arc<previews::PreviewFeeds>,
    budget: budget::MemoryBudget,
    /// Finished jobs kept in memory (and the store); older ones are dropped.
    keep_finished: usize,
    /// Submissions being decoded and validated (`budget::SUBMITS_AT_ONCE`).
    submits: Arc<tokio::sync::Semaphore>,
    auth: Arc<Auth>,
    /// Timings and failures recorded where they happen (`crate::metrics`).
    metrics: crate::metrics::Metrics,
}

/// A job's identity and what it was submitted with, for clients that look for a job.
#[derive(Debug, Clone, PartialEq)]
pub struct JobSummary {
    /// The job.
    pub id: JobId,
    /// Its scene's content hash.
    pub scene_hash: String,
    /// Its settings.
    pub settings: JobSettings,
}

/// A job's image, resolved outside the farm's lock.
#[derive(Debug, Clone)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear RGB, top row first; the mosaic where pass one has not reached.
    pub rgb: Vec<f32>,
    /// The job's state when the snapshot was taken.
    pub state: JobState,
    /// The job's AOV layers, resolved like `rgb` (empty layers for a job without them).
    pub layers: tessera_film::aov::Resolved,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock must not take every later request down with it: the
    // holders keep their data consistent at every return.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl CoordinatorService {
    /// A coordinator with no jobs, keeping nothing on disk, with the default memory budget
    /// (`default_budget`).
    pub fn new(timing: Timing) -> Self {
        Self::with_memory_budget(timing, default_budget())
    }

    /// A coordinator with no jobs, keeping nothing on disk, whose jobs may hold at most
    /// `bytes` of memory (framebuffers and bundles): one that does not fit is refused.
    pub fn with_memory_budget(timing: Timing, bytes: u64) -> Self {
        let (changed, _) = watch::channel(0);
        let (shutdown, _) = watch::channel(false);
        let mut farm = Farm::new();
        farm.set_batch_time(timing.batch_time);
        CoordinatorService {
            farm: Arc::new(Mutex::new(farm)),
            changed: Arc::new(changed),
            shutdown: Arc::new(shutdown),
            timing,
            durable: None,
            feeds: Arc::default(),
            previews: Arc::default(),
            budget: budget::MemoryBudget::new(bytes),
            keep_finished: KEEP_FINISHED,
            submits: Arc::new(tokio::sync::Semaphore::new(SUBMITS_AT_ONCE)),
            auth: Arc::new(Auth::open()),
            metrics: crate::metrics::Metrics::default(),
        }
    }

    /// With callers authenticated by `auth` (the default is `Auth::open`: everyone is admin).
    pub fn with_auth(mut self, auth: Auth) -> Self {
        self.auth = Arc::new(auth);
        self
    }

    /// How callers are authenticated (the web API checks its tokens with it).
    pub fn auth(&self) -> &Auth {
        &self.auth
    }

    /// The farm, locked: for short, bounded work only.
    fn farm(&self) -> MutexGuard<'_, Farm> {
        lock(&self.farm)
    }

    /// Wakes every worker and viewer feeder: a job arrived, leases came back, a result
    /// merged, or a worker left.
    pub fn notify(&self) {
        self.changed.send_modify(|v| *v = v.wrapping_add(1));
    }

    /// A receiver of change notifications (also for in-process clients such as `render`).
    pub fn subscribe(&self) -> watch::Receiver<u64> {
        self.changed.subscribe()
    }

    /// Stops the background tasks (reaper, checkpointer, viewer feeds) and ends every
    /// worker and viewer stream.
    pub fn shutdown(&self) {
        self.shutdown.send_replace(true);
    }

    /// A receiver that turns true when the service shuts down.
    fn shutting_down(&self) -> watch::Receiver<bool> {
        self.shutdown.subscribe()
    }

    /// With `n` (at least 1) finished jobs kept, instead of `KEEP_FINISHED`: older finished
    /// jobs are dropped from memory and the store, once a second.
    pub fn keeping_finished(mut self, n: usize) -> Self {
        self.keep_finished = n.max(1);
        self
    }

    /// The memory budget of its jobs and what of it is held now, in bytes.
    pub fn memory(&self) -> (u64, u64) {
        (self.budget.limit(), self.budget.held())
    }

    /// Every job, oldest first.
    pub fn jobs(&self) -> Vec<JobSummary> {
        self.farm()
            .jobs()
            .map(|j| JobSummary { id: j.id, scene_hash: j.scene_hash.clone(), settings: j.settings.clone() })
            .collect()
    }

    /// A job's progress now.
    pub fn progress(&self, job: JobId) -> Option<JobProgress> {
        self.farm().job(job).map(|j| j.progress(Instant::now()))
    }

    /// A job's image now: a snapshot under the lock, resolved outside it. A sequence's
    /// is its first frame's.
    pub fn image(&self, job: JobId) -> Option<Image> {
        self.frame_image(job, None, true)
    }

    /// The image of `frame` of a sequence now (`None`: its first; a still has only frame
    /// `None` or 0), with its AOV layers; `None` if there is no such job or frame.
    /// Finished frames are whole while later ones render.
    pub fn frame_image(&self, job: JobId, frame: Option<u32>, with_layers: bool) -> Option<Image> {
        let (fb, aov, state, rows) = {
            let farm = self.farm();
            let j = farm.job(job)?;
            let index = j.frame_index(frame)?;
            let rows = crate::frames::FrameRows { row: index * j.frame_height(), height: j.frame_height() };
            (j.framebuffer().clone(), j.aov().clone(), j.state.clone(), rows)
        };
        let layers = if with_layers {
            aov.resolve_rows(rows.row, rows.height, |x, y| fb.count(x, y))
        } else {
            Default::default()
        };
        Some(Image { width: fb.width(), height: rows.height, rgb: rows.resolve(&fb), state, layers })
    }

    /// The tonic services of this coordinator, each with its message limits: `Coordinator`
    /// (clients and viewers) decodes up to a scene bundle, `Workers` only up to the largest
    /// legal worker message, so that a worker cannot make it buffer a bundle's worth.
    /// Every call is authenticated before its message is decoded, and before a submission
    /// waits at the gate. Beside them, unauthenticated: the gRPC health service and server
    /// reflection (`probes.rs`). Serve them with [`server`]'s settings, within a Tokio
    /// runtime: `server().add_routes(service.into_server())`.
    pub fn into_server(self) -> Routes {
        use tonic::service::interceptor::InterceptedService;
        let authenticate = auth::Authenticate(self.auth.clone());
        let workers = WorkersServer::new(self.clone())
            .max_decoding_message_size(MAX_WORKER_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        let (permits, budget) = (self.submits.clone(), self.budget.clone());
        let this = self.clone();
        let clients = CoordinatorServer::new(self)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        // Authentication first: an unknown caller is refused before the gate reads
        // anything of its body or reserves any of the budget for it.
        let routes = Routes::new(InterceptedService::new(workers, authenticate.clone())).add_service(
            InterceptedService::new(gate::SubmitGate::new(clients, permits, budget), authenticate),
        );
        probes::add(routes, &this)
    }

    /// Takes back the leases of silent workers and ends jobs whose time budget is spent,
    /// once a second, until the service shuts down.
    pub fn spawn_reaper(&self) -> tokio::task::JoinHandle<()> {
        let this = self.clone();
        let mut stop = self.shutting_down();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                tokio::select! {
                    _ = tick.tick() => {}
                    _ = stop.changed() => return,
                }
                let now = Instant::now();
                let (ended, expired) = {
                    let mut farm = this.farm();
                    (farm.enforce_deadlines(now), farm.expire_silent(now, this.timing.silence_timeout))
                };
                for id in &ended {
                    info!(%id, "time budget spent; job ends");
                }
                for (worker, n) in &expired {
                    warn!(%worker, batches = n, "worker silent; its batches go to others");
                }
                let retired = this.retire_finished(this.keep_finished).await;
                if !retired.is_empty() {
                    info!(jobs = ?retired, "finished jobs past the retention count dropped");
                }
                if !ended.is_empty() || !expired.is_empty() || !retired.is_empty() {
                    this.notify();
                }
            }
        })
    }
}

/// A tonic server builder with the coordinator's connection limits (`limits.rs`): streams
/// per connection, HTTP/2 keep-alive that drops a peer that stopped answering, a header
/// list bound, and resets a client may cause.
pub fn server() -> Server {
    limits::configure(Server::builder())
}

/// The connections a listener accepts, with Nagle's algorithm off: the work stream sends
/// small messages (a batch, a result with credit) that must not wait for the previous
/// one's acknowledgement (tens of milliseconds with delayed ACKs). tonic's own
/// `tcp_nodelay` applies only to listeners it binds itself.
pub fn incoming(
    listener: tokio::net::TcpListener,
) -> impl tokio_stream::Stream<Item = std::io::Result<tokio::net::TcpStream>> {
    use tokio_stream::StreamExt;
    tokio_stream::wrappers::TcpListenerStream::new(listener).map(|conn| {
        let conn = conn?;
        conn.set_nodelay(true)?;
        Ok(conn)
    })
}
