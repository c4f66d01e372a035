//! Watch streams of viewers that read previews (`WatchRequest.previews`): while the job
//! renders they are sent display values of blocks (`tessera_film::preview`), as coarse as
//! the viewers' byte budget needs, instead of exact pixel states; when it is over, the
//! exact state of every pixel, so that their final image has the coordinator's bits.
//!
//! One publisher task per job ticks at the default rate: it takes a snapshot under the
//! farm's lock (a pointer per tile), and outside it chooses and encodes the tick's blocks
//! once for every viewer, sized to this tick's share of the budget (`budget / viewers /
//! rate`). Its deltas go into a short history, so that a viewer that read slowly or asked
//! for fewer updates is sent the ones it missed (each is small); one that fell further
//! behind, and one that joins, starts again from a snapshot of its own, the exact states
//! of the pixels that have samples, as an exact viewer joins (few bytes in pass one, where
//! viewers of a render join; its replica paints the mosaic), and rejoins the shared
//! deltas. Exact replicas need about 17 bytes a pixel each time it
//! changes; previews need 6 bytes a block, so a hundred viewers of a farm of 256 workers
//! stay within the budget (docs/farm.md has the figures).

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tessera_description::ids::JobId;
use tessera_film::preview::{Blocks, Publisher};
use tessera_proto::preview::preview_to_wire;
use tessera_proto::v1 as pb;
use tokio::sync::{mpsc, watch};
use tonic::Status;

use super::viewers::{ViewSnapshot, STATUS_REFRESH, WATCH_DEFAULT_RATE};
use super::{lock, CoordinatorService};

/// What a job's preview viewers are sent together, at most, while it renders: half the
/// viewers' budget (`VIEWER_BYTES_PER_SECOND`), because previews are most of what a
/// coordinator with many viewers sends, and `tessera bench farm` measured 100 preview
/// viewers of 256 workers sharing 23 MB/s costing 5–10 % of the commits (docs/farm.md).
/// 100 viewers still get 16 KB an update, 2 000 blocks: a 4K frame in 64-pixel blocks
/// while every tile changes, refined as soon as fewer do.
const PREVIEW_BYTES_PER_SECOND: f64 = 16e6;
/// The share of one core a job's preview publisher may take (snapshot, tick, encoding, as
/// wall time): the farm's merges come first. A 4K tick of a farm of 256 workers takes
/// about 5 ms, so its viewers get about six updates a second instead of ten.
const PREVIEW_CORE_SHARE: f64 = 0.03;
/// Ticks are never further apart than this (5.5 a second), however long they take.
const SLOWEST_TICK: Duration = Duration::from_millis(180);
/// A tick's blocks for each viewer are at least this many bytes (a 1080p frame in
/// 64-pixel blocks), however many viewers share the budget, so that a preview stays
/// recognisable; more viewers than the budget affords then get fewer updates instead.
const MIN_TICK_BYTES: usize = 4 << 10;
/// And at most this many (as estimated by `BLOCK_BYTES`; scattered blocks' runs can take a
/// message a third past it): a message about HTTP/2's initial window of 64 KiB goes out
/// without waiting long for the viewer's window updates, and a tick stays quick to encode
/// (`tessera bench farm` measured 320 KB ticks to 10 viewers costing 16 % of the commits,
/// against 3 % for 100 viewers at 24 KB).
const MAX_TICK_BYTES: usize = 60 << 10;
/// The history of deltas a viewer that fell behind catches up from, in bytes and in
/// entries (a paused job's status-only deltas are tiny, and every viewer round scans it).
const HISTORY_BYTES: usize = 8 << 20;
const HISTORY_ENTRIES: usize = 256;

/// One tick of a job's previews, encoded once, shared by every viewer.
#[derive(Debug)]
pub(super) struct PreviewDelta {
    /// Its place in the publisher's sequence (from 1).
    seq: u64,
    /// The framebuffer version a viewer must show at least for this delta to follow on.
    from: u64,
    /// The version it brings a viewer to.
    to: u64,
    /// The messages (one per tick; the final state in chunks).
    updates: Vec<pb::FramebufferUpdate>,
    /// The job is over: these are exact pixels and the last of them is `final`.
    over: bool,
    bytes: usize,
}

/// The preview publishers of jobs with viewers that read previews, one a job.
#[derive(Default)]
pub(super) struct PreviewFeeds {
    by_job: Mutex<HashMap<JobId, Arc<PreviewFeed>>>,
}

/// A job's preview publisher, as its viewers see it.
#[derive(Debug)]
pub(super) struct PreviewFeed {
    /// Recent deltas, oldest first, at most `HISTORY_BYTES` together.
    history: Mutex<VecDeque<Arc<PreviewDelta>>>,
    /// The newest delta's `seq`; every viewer holds a receiver, so the publisher knows how
    /// many share the budget and when the last one left.
    newest: watch::Sender<u64>,
}

impl PreviewFeed {
    fn push(&self, d: PreviewDelta) {
        let seq = d.seq;
        {
            let mut h = lock(&self.history);
            h.push_back(Arc::new(d));
            let mut total: usize = h.iter().map(|d| d.bytes).sum();
            while (total > HISTORY_BYTES || h.len() > HISTORY_ENTRIES) && h.len() > 1 {
                total -= h.pop_front().map_or(0, |d| d.bytes);
            }
        }
        self.newest.send_replace(seq);
    }

    /// The deltas after `seq`, oldest first.
    fn after(&self, seq: u64) -> Vec<Arc<PreviewDelta>> {
        lock(&self.history).iter().filter(|d| d.seq > seq).cloned().collect()
    }
}

fn delta(seq: u64, from: u64, to: u64, updates: Vec<pb::FramebufferUpdate>, over: bool) -> PreviewDelta {
    use prost::Message;
    let bytes = updates.iter().map(|u| u.encoded_len()).sum();
    PreviewDelta { seq, from, to, updates, over, bytes }
}

impl ViewSnapshot {
    /// One message carrying `preview` (already encoded) and this snapshot's status.
    fn preview_update(&self, job: JobId, preview: bytes::Bytes, chunk_end: bool) -> pb::FramebufferUpdate {
        pb::FramebufferUpdate {
            job_id: job.0,
            width: self.fb.width(),
            height: self.fb.height(),
            version: self.fb.version(),
            chunk_end,
            preview,
            status: Some(self.status.clone()),
            workers: self.workers,
            ..Default::default()
        }
    }
}

impl CoordinatorService {
    /// `job`'s preview feed and a receiver of it, starting its publisher if it has none.
    /// Subscribing under the table's lock means a publisher never leaves a viewer behind:
    /// it ends only when, under the same lock, it sees no receiver.
    fn preview_feed(&self, job: JobId) -> (Arc<PreviewFeed>, watch::Receiver<u64>) {
        let mut feeds = lock(&self.previews.by_job);
        if let Some(feed) = feeds.get(&job) {
            return (feed.clone(), feed.newest.subscribe());
        }
        let (newest, rx) = watch::channel(0);
        let feed = Arc::new(PreviewFeed { history: Mutex::default(), newest });
        feeds.insert(job, feed.clone());
        tokio::spawn(self.clone().publish_previews(job, feed.clone()));
        (feed, rx)
    }

    /// Ticks `job`'s previews while it has viewers; publishes its exact final state and
    /// ends when it is over, or at shutdown.
    async fn publish_previews(self, job: JobId, feed: Arc<PreviewFeed>) {
        let interval = Duration::from_secs_f64(1.0 / WATCH_DEFAULT_RATE);
        let mut changed = self.subscribe();
        let mut stop = self.shutting_down();
        let mut publisher: Option<Publisher> = None;
        let mut seq = 0;
        let mut last_status: Option<(pb::JobStatus, u32, Instant)> = None;
        loop {
            let tick = Instant::now();
            let Some(snap) = self.view_snapshot(job) else { break };
            let from = publisher.as_ref().and_then(Publisher::version).unwrap_or(0);
            if snap.over && publisher.is_none() {
                // Over before this publisher's first tick: its viewers joined after the end
                // and take the final state from a snapshot of their own.
                break;
            }
            if snap.over {
                let work = tokio::task::spawn_blocking(move || {
                    let updates: Vec<_> = snap.updates(job, 0, false).collect();
                    (snap.fb.version(), updates)
                });
                let Ok((to, updates)) = work.await else { break };
                seq += 1;
                // Exact states of every pixel: they follow on from any picture.
                feed.push(delta(seq, 0, to, updates, true));
                break;
            }
            let viewers = feed.newest.receiver_count().max(1);
            let budget = ((PREVIEW_BYTES_PER_SECOND / WATCH_DEFAULT_RATE) as usize / viewers)
                .clamp(MIN_TICK_BYTES, MAX_TICK_BYTES);
            let mut p = publisher.take().unwrap_or_else(|| Publisher::new(snap.fb.width(), snap.fb.height()));
            let baseline = p.version().is_none();
            let work = tokio::task::spawn_blocking(move || {
                let blocks: Vec<Blocks> = p.tick(&snap.fb, budget);
                let wire = preview_to_wire(&blocks);
                (p, snap, wire)
            });
            let Ok((p, snap, wire)) = work.await else { break };
            publisher = Some(p);
            let status_due = last_status.as_ref().is_none_or(|(s, w, at)| {
                *s != snap.status || *w != snap.workers || at.elapsed() >= STATUS_REFRESH
            });
            if !baseline && (!wire.is_empty() || status_due) {
                seq += 1;
                let to = snap.fb.version();
                feed.push(delta(seq, from, to, vec![snap.preview_update(job, wire, true)], false));
                last_status = Some((snap.status.clone(), snap.workers, Instant::now()));
            }
            // Before waiting: a snapshot held makes every merge copy the tiles it touches
            // (at 4K with 256 workers that halved the publisher's rate).
            drop(snap);
            let busy = tick.elapsed();
            {
                let mut feeds = lock(&self.previews.by_job);
                if feed.newest.receiver_count() == 0 {
                    feeds.remove(&job);
                    return;
                }
            }
            tokio::select! {
                _ = changed.changed() => {}
                _ = tokio::time::sleep(STATUS_REFRESH) => {}
                _ = stop.changed() => break,
            }
            // A tick's cost grows with the image and the farm's rate of change, not with its
            // viewers; past a share of a core, ticks space out, down to SLOWEST_TICK.
            let pause = interval.max(busy.div_f64(PREVIEW_CORE_SHARE)).min(SLOWEST_TICK.max(interval));
            tokio::time::sleep(pause.saturating_sub(tick.elapsed())).await;
        }
        let mut feeds = lock(&self.previews.by_job);
        if feeds.get(&job).is_some_and(|f| Arc::ptr_eq(f, &feed)) {
            feeds.remove(&job);
        }
    }

    /// Sends `updates` in order within the viewers' budget; false if the viewer left.
    async fn send_all(
        &self,
        updates: &[pb::FramebufferUpdate],
        tx: &mpsc::Sender<Result<pb::FramebufferUpdate, Status>>,
    ) -> bool {
        for u in updates {
            self.within_budget(u).await;
            if tx.send(Ok(u.clone())).await.is_err() {
                return false;
            }
        }
        true
    }

    /// Feeds one preview viewer: a snapshot of its own, then the shared deltas (those it missed, in
    /// order, when it fell behind), at most `1 / interval` rounds a second, until the
    /// job's exact final state.
    pub(super) async fn feed_preview_viewer(
        self,
        job: JobId,
        interval: Duration,
        tx: mpsc::Sender<Result<pb::FramebufferUpdate, Status>>,
    ) {
        let (mut feed, mut newest) = self.preview_feed(job);
        let mut stop = self.shutting_down();
        // The version the viewer's picture is current through (`None`: nothing yet), and
        // the last delta of this feed it has dealt with.
        let mut at: Option<u64> = None;
        let mut seen = 0;
        loop {
            let round = Instant::now();
            newest.borrow_and_update();
            let pending = feed.after(seen);
            let mut next: Vec<Arc<PreviewDelta>> = Vec::new();
            if let Some(v) = at {
                // `>=`: a tick without merges (refinement of coarse blocks, a status)
                // brings no new version but must reach viewers in step.
                next = pending.iter().filter(|d| d.to >= v || d.over).cloned().collect();
                if next.first().is_some_and(|d| d.from > v) {
                    // Fell behind the history: it starts afresh.
                    next.clear();
                    at = None;
                }
            }
            seen = pending.last().map_or(seen, |d| d.seq);
            if at.is_none() {
                let Some(snap) = self.view_snapshot(job) else { return };
                let version = snap.fb.version();
                // Encoded and sent a chunk at a time, as an exact viewer's catch-up: a
                // viewer holds one chunk, however large the image.
                for u in snap.updates(job, 0, true) {
                    if !self.send_all(std::slice::from_ref(&u), &tx).await {
                        return;
                    }
                    self.feeds.own.fetch_add(1, Ordering::Relaxed);
                }
                if snap.over {
                    return;
                }
                drop(snap);
                at = Some(version);
                // Deltas published meanwhile that go past the snapshot are sent next round.
                seen = feed
                    .after(0)
                    .iter()
                    .filter(|d| d.to <= version && !d.over)
                    .map(|d| d.seq)
                    .max()
                    .unwrap_or(0);
            }
            for d in next {
                if !self.send_all(&d.updates, &tx).await {
                    return;
                }
                self.feeds.shared.fetch_add(d.updates.len() as u64, Ordering::Relaxed);
                if d.over {
                    return;
                }
                at = Some(d.to);
            }
            tokio::select! {
                // Never an error: this task's `feed` holds the sender.
                _ = newest.changed() => {}
                // A publisher ends without a word when its job is gone from the farm.
                _ = tokio::time::sleep(2 * STATUS_REFRESH) => {
                    if self.farm().job(job).is_none() {
                        return;
                    }
                    if !lock(&self.previews.by_job).get(&job).is_some_and(|f| Arc::ptr_eq(f, &feed)) {
                        // The publisher ended: another one's blocks assume viewers that
                        // joined it, so this one starts afresh.
                        (feed, newest) = self.preview_feed(job);
                        seen = 0;
                        at = None;
                    }
                },
                _ = tx.closed() => return,
                _ = stop.changed() => return,
            }
            tokio::time::sleep(interval.saturating_sub(round.elapsed())).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::viewers::tests::{merge_first_batch, small_job};
    use super::*;

    type Rx = mpsc::Receiver<Result<pb::FramebufferUpdate, Status>>;

    /// Reads one viewer's updates until one carries a delta's preview.
    async fn next_delta(rx: &mut Rx) -> pb::FramebufferUpdate {
        loop {
            let u = rx.recv().await.expect("the stream stays open").expect("no error");
            if !u.reset && !u.preview.is_empty() {
                return u;
            }
        }
    }

    /// Two viewers in step with the publisher receive the same encoded preview: one
    /// encoding, the same buffer behind both copies; it paints what was merged.
    #[tokio::test]
    async fn preview_viewers_in_step_share_the_encoded_delta() {
        let (service, job) = small_job().await;
        let interval = Duration::from_millis(10);
        let (tx_a, mut a) = mpsc::channel(1);
        let (tx_b, mut b) = mpsc::channel(1);
        tokio::spawn(service.clone().feed_preview_viewer(job, interval, tx_a));
        tokio::spawn(service.clone().feed_preview_viewer(job, interval, tx_b));
        for rx in [&mut a, &mut b] {
            let u = rx.recv().await.unwrap().unwrap();
            assert!(u.reset && u.chunk_end && u.pixels.is_empty(), "an empty snapshot first");
            assert_eq!(u.protocol_version, tessera_proto::PROTOCOL_VERSION as i32);
        }
        // Past the publisher's baseline tick.
        tokio::time::sleep(Duration::from_millis(300)).await;
        merge_first_batch(&service, job);
        let (ua, ub) = tokio::join!(next_delta(&mut a), next_delta(&mut b));
        assert_eq!(ua.preview.as_ptr(), ub.preview.as_ptr(), "one encoding for both");
        assert!(ua.pixels.is_empty(), "no exact states while the job renders");
        let blocks = tessera_proto::preview::preview_from_wire(&ua.preview, 8, 8).unwrap();
        // The first batch holds the root pixel: its sample paints the whole frame white.
        let mut overlay = tessera_film::preview::Overlay::new(8, 8);
        for b in &blocks {
            overlay.paint(b);
        }
        let mut img = vec![0.0; 8 * 8 * 3];
        overlay.over(&mut img);
        assert!(img.iter().all(|&v| v == 1.0), "{img:?}");
        service.shutdown();
    }
}
