//! Watch streams. A viewer that joins gets a snapshot of the exact pixel state, then only
//! what changed. The changes are computed once per tick per job, from the framebuffer's
//! dirty tiles, by one publisher task, and the same encoded delta is handed to every
//! viewer at that version; a viewer that fell behind (it reads slowly, or asked for a
//! lower rate) catches up from a snapshot of its own, streamed a chunk at a time. Every
//! snapshot is a copy-on-write clone taken under the farm's lock in microseconds; the
//! scanning and encoding happen outside it. A chunk's pixels are encoded to bytes once
//! (`convert::pixels_to_wire`), so handing a delta to a viewer clones a reference count,
//! and tonic copies those bytes to each stream without encoding them again.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bytes::Bytes;
use tessera_description::ids::JobId;
use tessera_description::job::JobState;
use tessera_film::Framebuffer;
use tessera_proto::v1 as pb;
use tokio::sync::{mpsc, watch};
use tonic::Status;

use tessera_proto::convert;

use super::auth::Principal;
use super::{lock, CoordinatorService};

/// Pixels per watch update: about 1.8 MB, far below gRPC's message limit, and all a slow
/// viewer's task holds.
pub const WATCH_CHUNK_PIXELS: usize = 1 << 16;
/// Updates per second a viewer gets unless it asks for fewer; the publisher's rate.
pub const WATCH_DEFAULT_RATE: f64 = 10.0;
/// The most bytes per second the coordinator sends all its viewers together. Viewers
/// never slow rendering: past this, each viewer gets fewer (larger, coalesced) updates
/// instead of the coordinator spending the workers' CPU on encoding and sending. A pixel's
/// state is about 17 bytes, so 32 MB/s is about one full 1080p frame a second for all
/// viewers together; `tessera bench farm` measured sending to cost the farm about 0.15 %
/// of its commits per MB/s on two cores, so this keeps viewers within a few per cent of
/// the commits (at 128 MB/s they cost up to 80 %; docs/farm.md).
pub const VIEWER_BYTES_PER_SECOND: f64 = 32e6;
/// The most viewers of one job at once; a further `Watch` is `RESOURCE_EXHAUSTED`.
pub const MAX_VIEWERS_PER_JOB: usize = 128;
/// The most viewers at once in all. A viewer holds at most a chunk or two of its own
/// (catching up) and the HTTP/2 buffers of its stream: a few MB at worst here. The web
/// dashboard's live image is one such viewer per watched job, whatever its number of
/// sockets, with a replica of the job's framebuffer in the web crate (`web/src/live.rs`:
/// about 52 bytes a pixel per watched job).
pub const MAX_VIEWERS: usize = 256;
/// A publisher with nothing new still sends the status this often (samples/s, workers).
pub(super) const STATUS_REFRESH: Duration = Duration::from_secs(1);

/// One delta of a job's framebuffer, encoded once and shared by every viewer at `from`:
/// cloning an update clones its status and a pointer to its pixels.
#[derive(Debug, Default)]
pub(super) struct Delta {
    /// The version the delta starts from.
    from: u64,
    /// The version it brings a replica to.
    to: u64,
    /// The updates, in order, the last one with `chunk_end`.
    updates: Vec<pb::FramebufferUpdate>,
    /// The job is over and this is its final state.
    over: bool,
}

/// The publishers of jobs that have viewers.
#[derive(Default)]
pub(super) struct Feeds {
    by_job: Mutex<HashMap<JobId, watch::Receiver<Arc<Delta>>>>,
    /// The bytes all viewers may still be sent now.
    budget: Budget,
    /// Updates sent from a publisher's shared delta.
    pub(super) shared: AtomicU64,
    /// Updates a viewer's task made from a snapshot of its own (joining, or behind).
    pub(super) own: AtomicU64,
    /// Viewers now, by job.
    viewers: Arc<Mutex<HashMap<JobId, usize>>>,
}

/// A viewer's place among `MAX_VIEWERS`, held by its task and given back when it ends.
pub(super) struct ViewerSlot {
    job: JobId,
    viewers: Arc<Mutex<HashMap<JobId, usize>>>,
}

impl Drop for ViewerSlot {
    fn drop(&mut self) {
        let mut v = lock(&self.viewers);
        if let Some(n) = v.get_mut(&self.job) {
            *n -= 1;
            if *n == 0 {
                v.remove(&self.job);
            }
        }
    }
}

/// A token bucket of bytes for all viewers together, refilled at
/// `VIEWER_BYTES_PER_SECOND` and holding at most one second's worth.
#[derive(Debug)]
struct Budget {
    /// Bytes that may be sent now (negative: owed), and when that was worked out.
    state: Mutex<(f64, Instant)>,
}

impl Default for Budget {
    fn default() -> Self {
        Budget { state: Mutex::new((VIEWER_BYTES_PER_SECOND, Instant::now())) }
    }
}

impl Budget {
    /// Spends `bytes`; returns how long to wait before sending them.
    fn spend(&self, bytes: usize) -> Duration {
        let mut state = lock(&self.state);
        let now = Instant::now();
        let (tokens, at) = &mut *state;
        let refill = now.saturating_duration_since(*at).as_secs_f64() * VIEWER_BYTES_PER_SECOND;
        *tokens = (*tokens + refill).min(VIEWER_BYTES_PER_SECOND) - bytes as f64;
        *at = now;
        if *tokens >= 0.0 {
            Duration::ZERO
        } else {
            Duration::from_secs_f64(-*tokens / VIEWER_BYTES_PER_SECOND)
        }
    }
}

/// How viewers' updates were made, since the coordinator started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ViewerUpdates {
    /// Sent from the delta one publisher computed for every viewer of a job.
    pub shared: u64,
    /// Made by a viewer's own task from a snapshot (a viewer joining or catching up).
    pub own: u64,
}

/// A job's framebuffer and status at one moment, taken under the lock.
pub(super) struct ViewSnapshot {
    pub(super) fb: Framebuffer,
    pub(super) status: pb::JobStatus,
    pub(super) workers: u32,
    pub(super) over: bool,
}

impl ViewSnapshot {
    /// The updates bringing a replica at version `since` to this snapshot, one chunk at a
    /// time, each chunk's pixels encoded once; at least one update, so that a viewer always
    /// hears the status. The first update with `reset` also names the protocol version.
    pub(super) fn updates(
        &self,
        job: JobId,
        since: u64,
        reset: bool,
    ) -> impl Iterator<Item = pb::FramebufferUpdate> + '_ {
        let mut chunks = self.fb.changes(since, WATCH_CHUNK_PIXELS).peekable();
        let mut first = true;
        std::iter::from_fn(move || {
            let pixels = chunks.next();
            if pixels.is_none() && !first {
                return None;
            }
            let end = chunks.peek().is_none();
            let update = pb::FramebufferUpdate {
                job_id: job.0,
                width: self.fb.width(),
                height: self.fb.height(),
                version: self.fb.version(),
                chunk_end: end,
                pixels: pixels.map_or_else(Bytes::new, |p| convert::pixels_to_wire(&p)),
                status: Some(self.status.clone()),
                workers: self.workers,
                r#final: self.over && end,
                reset: reset && first,
                protocol_version: if reset && first { tessera_proto::PROTOCOL_VERSION as i32 } else { 0 },
                frame: 0,
                preview: Bytes::new(),
            };
            first = false;
            Some(update)
        })
    }
}

impl CoordinatorService {
    /// How viewers' updates were made so far: shared deltas against per-viewer catch-ups.
    pub fn viewer_updates(&self) -> ViewerUpdates {
        ViewerUpdates {
            shared: self.feeds.shared.load(Ordering::Relaxed),
            own: self.feeds.own.load(Ordering::Relaxed),
        }
    }

    /// A place for one more viewer of `job`, or `RESOURCE_EXHAUSTED` past the limits.
    pub(super) fn viewer_slot(&self, job: JobId) -> Result<ViewerSlot, Status> {
        let mut v = lock(&self.feeds.viewers);
        let all: usize = v.values().sum();
        let of_job = v.get(&job).copied().unwrap_or(0);
        if all >= MAX_VIEWERS {
            return Err(Status::resource_exhausted(format!(
                "the coordinator has {all} viewers, its limit ({MAX_VIEWERS}); try again when one leaves"
            )));
        }
        if of_job >= MAX_VIEWERS_PER_JOB {
            return Err(Status::resource_exhausted(format!(
                "{job} has {of_job} viewers, the limit per job ({MAX_VIEWERS_PER_JOB}); try again when one leaves"
            )));
        }
        *v.entry(job).or_insert(0) += 1;
        Ok(ViewerSlot { job, viewers: self.feeds.viewers.clone() })
    }

    /// Viewers connected now.
    pub fn viewers(&self) -> usize {
        lock(&self.feeds.viewers).values().sum()
    }

    /// Waits until the viewers' byte budget allows sending `u`.
    pub(super) async fn within_budget(&self, u: &pb::FramebufferUpdate) {
        use prost::Message;
        let wait = self.feeds.budget.spend(u.encoded_len());
        if !wait.is_zero() {
            tokio::time::sleep(wait).await;
        }
    }

    /// A snapshot of what viewers see of `job`, or `None` if there is no such job.
    pub(super) fn view_snapshot(&self, job: JobId) -> Option<ViewSnapshot> {
        let farm = self.farm();
        let j = farm.job(job)?;
        Some(ViewSnapshot {
            fb: j.framebuffer().clone(),
            status: pb::JobStatus {
                owner: j.owner.clone(),
                workers: farm.workers_on(job),
                ..convert::status_to_wire(&j.progress(Instant::now()))
            },
            workers: farm.workers().count() as u32,
            over: j.is_over(),
        })
    }

    /// The job a viewer asks for: by id; or (0) the active job (running, else paused, else
    /// queued, oldest first), or the only job; otherwise the jobs to choose from.
    pub(super) fn pick_job(&self, who: &Principal, id: u64) -> Result<JobId, Status> {
        let farm = self.farm();
        if id != 0 {
            return farm
                .job(JobId(id))
                .map(|j| j.id)
                .ok_or_else(|| Status::not_found(format!("no job {id} on this coordinator")));
        }
        // A submitter chooses among its own jobs only, and is told of no others.
        let visible = || farm.jobs().filter(|j| CoordinatorService::sees_jobs_of(who, &j.owner));
        for state in [JobState::Running, JobState::Paused, JobState::Queued] {
            if let Some(j) = visible().find(|j| j.state == state) {
                return Ok(j.id);
            }
        }
        let jobs: Vec<_> = visible().collect();
        match jobs.as_slice() {
            [] => Err(Status::not_found("this coordinator has no jobs yet")),
            [only] => Ok(only.id),
            all => {
                let list: Vec<String> = all
                    .iter()
                    .map(|j| format!("{} ({}, {})", j.id.0, j.state.name(), j.bundle.name))
                    .collect();
                Err(Status::failed_precondition(format!(
                    "no job is running; choose one with --job: {}",
                    list.join(", ")
                )))
            }
        }
    }

    /// The shared deltas of `job`, starting its publisher if it has none.
    fn feed(&self, job: JobId) -> watch::Receiver<Arc<Delta>> {
        let mut feeds = lock(&self.feeds.by_job);
        if let Some(rx) = feeds.get(&job).filter(|rx| rx.has_changed().is_ok()) {
            return rx.clone();
        }
        let (tx, rx) = watch::channel(Arc::new(Delta::default()));
        feeds.insert(job, rx.clone());
        tokio::spawn(self.clone().publish(job, tx));
        rx
    }

    /// Computes `job`'s delta once per tick, while it has viewers, and hands it to all of
    /// them. Ends when the last viewer leaves, after the job's final state, or at shutdown.
    async fn publish(self, job: JobId, tx: watch::Sender<Arc<Delta>>) {
        let interval = Duration::from_secs_f64(1.0 / WATCH_DEFAULT_RATE);
        let mut changed = self.subscribe();
        let mut stop = self.shutting_down();
        // The version and status last published; the first tick only sets the baseline
        // (a viewer that joins takes a snapshot of its own, so no delta from 0 is made).
        let mut last: Option<(u64, pb::JobStatus, u32)> = None;
        loop {
            let tick = Instant::now();
            let Some(snap) = self.view_snapshot(job) else { break };
            let version = snap.fb.version();
            let news = match &last {
                None => true,
                Some((v, status, workers)) => {
                    *v != version || *status != snap.status || *workers != snap.workers || snap.over
                }
            };
            if news {
                let since = last.as_ref().map_or(version, |(v, _, _)| *v);
                let mark = (version, snap.status.clone(), snap.workers);
                let baseline = last.is_none();
                let delta = tokio::task::spawn_blocking(move || Delta {
                    from: since,
                    to: snap.fb.version(),
                    updates: if baseline && !snap.over {
                        Vec::new()
                    } else {
                        snap.updates(job, since, false).collect()
                    },
                    over: snap.over,
                })
                .await;
                let Ok(delta) = delta else { break };
                let over = delta.over;
                if tx.send(Arc::new(delta)).is_err() || over {
                    break;
                }
                last = Some(mark);
            }
            if tx.receiver_count() <= 1 {
                // Only the feeds table holds a receiver: no viewer is left.
                break;
            }
            tokio::select! {
                _ = changed.changed() => {}
                _ = tokio::time::sleep(STATUS_REFRESH) => {}
                _ = stop.changed() => break,
            }
            tokio::time::sleep(interval.saturating_sub(tick.elapsed())).await;
        }
        let mut feeds = lock(&self.feeds.by_job);
        if feeds.get(&job).is_some_and(|rx| rx.same_channel(&tx.subscribe())) {
            feeds.remove(&job);
        }
    }

    /// Feeds one viewer: a snapshot, then the shared deltas, at most `1 / interval` rounds
    /// a second. It waits on its own channel only: a stalled viewer stalls this task alone,
    /// and when it reads again it catches up to the newest state.
    pub(super) async fn feed_viewer(
        self,
        job: JobId,
        interval: Duration,
        tx: mpsc::Sender<Result<pb::FramebufferUpdate, Status>>,
    ) {
        let mut feed = self.feed(job);
        let mut stop = self.shutting_down();
        // The version the viewer's replica holds (`None`: nothing yet).
        let mut sent: Option<u64> = None;
        let mut seen: Option<Arc<Delta>> = None;
        loop {
            let round = Instant::now();
            let delta = feed.borrow_and_update().clone();
            let fresh = !seen.as_ref().is_some_and(|d| Arc::ptr_eq(d, &delta));
            seen = Some(delta.clone());
            let over = match sent {
                // In step with the publisher: its delta, shared, as it is. Pixel states are
                // absolute (sums and counts, not increments), so a delta from `from` brings
                // any replica between `from` and `to` to `to`; a replica that caught up on
                // its own is therefore in step again with the next delta.
                Some(v)
                    if fresh
                        && delta.from <= v
                        && (v < delta.to || delta.over)
                        && !delta.updates.is_empty() =>
                {
                    for u in &delta.updates {
                        self.within_budget(u).await;
                        if tx.send(Ok(u.clone())).await.is_err() {
                            return;
                        }
                        self.feeds.shared.fetch_add(1, Ordering::Relaxed);
                    }
                    sent = Some(delta.to);
                    delta.over
                }
                // Already there.
                Some(v) if delta.to <= v && !delta.over => false,
                // Joining, or behind: a snapshot of its own, streamed a chunk at a time.
                _ => {
                    let Some(snap) = self.view_snapshot(job) else { return };
                    for u in snap.updates(job, sent.unwrap_or(0), sent.is_none()) {
                        self.within_budget(&u).await;
                        if tx.send(Ok(u)).await.is_err() {
                            return;
                        }
                        self.feeds.own.fetch_add(1, Ordering::Relaxed);
                    }
                    sent = Some(snap.fb.version());
                    snap.over
                }
            };
            if over {
                return;
            }
            tokio::select! {
                r = feed.changed() => if r.is_err() {
                    // The publisher ended (no viewer was left for a moment): start another.
                    feed = self.feed(job);
                },
                _ = tx.closed() => return,
                _ = stop.changed() => return,
            }
            tokio::time::sleep(interval.saturating_sub(round.elapsed())).await;
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::Timing;
    use tessera_description::job::JobSettings;
    use tessera_description::Bundle;

    /// A service with one 8 × 8 job of the small test scene at 2 spp.
    pub(in crate::service) async fn small_job() -> (CoordinatorService, JobId) {
        let service = CoordinatorService::new(Timing::default());
        let bundle = Bundle {
            name: "small.toml".into(),
            text: include_str!("../../../tests/scenes/small.toml").into(),
            assets: vec![],
            refused: vec![],
        };
        let job = service.submit(bundle, JobSettings::sized(Some(2), Some((8, 8))), 0).await.unwrap();
        (service, job)
    }

    /// Merges `job`'s first batch, every sum one (white), and tells the viewers; returns
    /// its pixel count.
    pub(in crate::service) fn merge_first_batch(service: &CoordinatorService, job: JobId) -> usize {
        let w = service.farm().add_worker("w".into(), 1, Instant::now());
        let lease = service.farm().assign(w, Instant::now()).unwrap();
        let sums = vec![1 << 24; lease.batch.quads.len() * 3];
        let r = crate::farm::BatchResult {
            job,
            batch: lease.batch.id,
            sums: &sums,
            even: None,
            aov: &[],
            nonfinite: 0,
            attempt: lease.attempt,
            lease: &lease.token.0,
            render: std::time::Duration::ZERO,
        };
        service.farm().complete(w, &r, Instant::now()).unwrap();
        service.notify();
        lease.batch.quads.len()
    }

    /// Reads one viewer's updates until one carries pixels, and returns those.
    async fn next_pixels(rx: &mut mpsc::Receiver<Result<pb::FramebufferUpdate, Status>>) -> Bytes {
        loop {
            let u = rx.recv().await.expect("the stream stays open").expect("no error");
            if !u.pixels.is_empty() {
                return u.pixels;
            }
        }
    }

    /// Two viewers in step with the publisher receive the same delta: one encoding, the
    /// same buffer behind both copies.
    #[tokio::test]
    async fn viewers_in_step_share_the_encoded_delta() {
        let (service, job) = small_job().await;
        let interval = Duration::from_millis(10);
        let (tx_a, mut a) = mpsc::channel(1);
        let (tx_b, mut b) = mpsc::channel(1);
        tokio::spawn(service.clone().feed_viewer(job, interval, tx_a));
        tokio::spawn(service.clone().feed_viewer(job, interval, tx_b));
        // Each viewer's own snapshot (nothing rendered yet), then the publisher's baseline.
        for rx in [&mut a, &mut b] {
            let u = rx.recv().await.unwrap().unwrap();
            assert!(u.reset && u.chunk_end && u.pixels.is_empty());
            assert_eq!(u.protocol_version, tessera_proto::PROTOCOL_VERSION as i32);
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
        let merged = merge_first_batch(&service, job);
        let (pa, pb) = tokio::join!(next_pixels(&mut a), next_pixels(&mut b));
        assert_eq!(pa.as_ptr(), pb.as_ptr());
        let pixels: Vec<_> = convert::pixels_from_wire(&pa, 64).unwrap().collect();
        assert_eq!(pixels.len(), merged);
        service.shutdown();
    }

    /// The budget lets a second's worth through at once, then makes senders wait in
    /// proportion to what they send.
    #[test]
    fn the_viewer_budget_makes_senders_wait_past_its_rate() {
        let b = Budget::default();
        assert_eq!(b.spend(VIEWER_BYTES_PER_SECOND as usize / 2), Duration::ZERO);
        assert_eq!(b.spend(VIEWER_BYTES_PER_SECOND as usize / 2 - 1000), Duration::ZERO);
        let wait = b.spend(VIEWER_BYTES_PER_SECOND as usize / 4);
        assert!(wait > Duration::from_millis(200) && wait <= Duration::from_millis(251), "{wait:?}");
    }

    #[tokio::test]
    async fn viewers_past_the_limits_are_refused_and_leaving_frees_a_place() {
        let service = CoordinatorService::new(Timing::default());
        let slots: Vec<ViewerSlot> =
            (0..MAX_VIEWERS_PER_JOB).map(|_| service.viewer_slot(JobId(1)).unwrap()).collect();
        let e = service.viewer_slot(JobId(1)).err().unwrap();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        assert_eq!(e.message(), "job 1 has 128 viewers, the limit per job (128); try again when one leaves");
        let mut others: Vec<ViewerSlot> = (0..MAX_VIEWERS - MAX_VIEWERS_PER_JOB)
            .map(|i| service.viewer_slot(JobId(2 + i as u64 % 7)).unwrap())
            .collect();
        let e = service.viewer_slot(JobId(99)).err().unwrap();
        assert!(
            e.message().starts_with("the coordinator has 256 viewers, its limit (256)"),
            "{}",
            e.message()
        );
        others.pop();
        assert!(service.viewer_slot(JobId(99)).is_ok());
        drop(slots);
        drop(others);
        assert_eq!(service.viewers(), 0);
    }
}
