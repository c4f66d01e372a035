//! `GET /api/jobs/{id}/live`: a WebSocket carrying a job's image as it refines.
//!
//! The sockets of one job share one replica of its framebuffer: the first socket of a job
//! subscribes through the coordinator's Watch RPC (one viewer slot, held while any socket
//! of that job is open) and starts a task that applies the versioned updates and, at most
//! ten times a second while the image changes and only once an update has arrived whole
//! (its `chunk_end`), resolves it (the mosaic included) to sRGB8 once and publishes that
//! frame on a `watch` channel. Each socket sends the pixels that changed between the frame
//! it sent last and the newest one, in canvas order (row 0 at the top); a socket that falls
//! behind skips the frames in between. The task ends when the last socket leaves or the
//! job is over. The format is in `docs/http-api.md`.
//!
//! Memory: per watched job one `Framebuffer` (36 B/px), its newest frame (4 B/px) and, for
//! a tick, the resolved image (12 B/px); per socket its message (at most 4 B/px + 8 B per
//! run) and the frame it sent last, which is the newest one unless it is behind (4 B/px).
//! At most `MAX_SOCKETS_PER_JOB` sockets share a job. This memory is not counted in the
//! coordinator's memory budget (it has no public API for it); the bound is the number of
//! watched jobs, itself bounded by the coordinator's viewer limit.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::Response;
use tessera_film::Framebuffer;
use tessera_proto::convert::pixels_from_wire;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;
use tokio::sync::watch;
use tokio_stream::{Stream, StreamExt};

use crate::caller::{job_id, request, the_job, Caller};
use crate::errors::ApiError;
use crate::json::Job;
use crate::AppState;

/// "TSR1", the first four bytes of every binary message.
pub const MAGIC: u32 = 0x5453_5231;
/// Flag: clear the canvas before drawing the runs.
pub const FLAG_RESET: u32 = 1;
/// Flag: the job is over; this is the last image.
pub const FLAG_FINAL: u32 = 2;
/// The shortest time between two image messages (at most ten a second).
const MIN_INTERVAL: Duration = Duration::from_millis(100);
/// Unchanged pixels between two changed ones that still join one run: a run costs 8
/// bytes of header, two pixels 8 of data.
const JOIN_GAP: usize = 2;
/// Open live sockets of one job at most; one more is a 503.
pub const MAX_SOCKETS_PER_JOB: usize = 32;
/// The largest message or frame accepted from a browser: the server reads none but the
/// close, so a browser cannot make it buffer more.
const MAX_INCOMING: usize = 4096;

/// One resolved image of a job as its shared task published it (cloned cheaply: the
/// pixels are shared).
#[derive(Clone, Default)]
pub(crate) struct Frame {
    /// The update version the pixels are complete for.
    version: u64,
    /// Bumped when the image restarts (a reset): a socket then sends it whole.
    generation: u64,
    /// RGBA8 of every pixel, canvas order; empty before the first update.
    rgba: Arc<Vec<[u8; 4]>>,
    status: Option<pb::JobStatus>,
    /// The job is over: this is the last image.
    last: bool,
    /// The stream ended otherwise: the close code and reason.
    end: Option<(u16, String)>,
}

/// The jobs watched now through one router: (job id, frame of a sequence) -> the channel
/// of its shared task.
pub(crate) type Hubs = Arc<Mutex<HashMap<HubKey, watch::Sender<Arc<Frame>>>>>;
/// A job and the frame of it watched (`None`: a still, or a sequence's first frame).
pub(crate) type HubKey = (u64, Option<u32>);

fn lock(hubs: &Hubs) -> std::sync::MutexGuard<'_, HashMap<HubKey, watch::Sender<Arc<Frame>>>> {
    hubs.lock().unwrap_or_else(|e| e.into_inner())
}

/// `GET /api/jobs/{id}/live`.
pub(crate) async fn live(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
    Query(q): Query<crate::images::FrameQuery>,
    ws: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    let id = job_id(&raw)?;
    let job = the_job(&state, &caller, id).await?;
    let ws =
        ws.map_err(|e| ApiError::new(e.status(), format!("GET /api/jobs/{id}/live: {}", e.body_text())))?;
    let frames = subscribe(&state, &caller, id, q.frame).await?;
    let ws = ws.max_message_size(MAX_INCOMING).max_frame_size(MAX_INCOMING);
    Ok(ws.on_upgrade(move |socket| async move {
        if let Err(e) = stream_job(socket, frames, job).await {
            tracing::debug!(job = id, "live socket ended: {e}");
        }
    }))
}

/// A receiver of job `id`'s frames (of `frame` of a sequence), starting its shared task
/// (and taking the viewer slot, so a full coordinator is a 503 before the upgrade) if no
/// socket watches it yet.
async fn subscribe(
    state: &AppState,
    caller: &Caller,
    id: u64,
    frame: Option<u32>,
) -> Result<watch::Receiver<Arc<Frame>>, ApiError> {
    let key = (id, frame);
    let joined = |hubs: &HashMap<HubKey, watch::Sender<Arc<Frame>>>| -> Option<Result<watch::Receiver<Arc<Frame>>, ApiError>> {
        let tx = hubs.get(&key)?;
        if tx.receiver_count() >= MAX_SOCKETS_PER_JOB {
            return Some(Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("job {id} already has {MAX_SOCKETS_PER_JOB} live sockets"),
            )));
        }
        Some(Ok(tx.subscribe()))
    };
    if let Some(r) = joined(&lock(&state.hubs)) {
        return r;
    }
    let watch_req = pb::WatchRequest {
        job_id: id,
        max_rate: 10.0,
        protocol_version: pb::ProtocolVersion::Current as i32,
        frame,
        // The hub keeps an exact replica: its PNGs are the coordinator's bits.
        previews: false,
    };
    let updates = Coordinator::watch(&state.service, request(&caller.0, watch_req)).await?.into_inner();
    let mut all = lock(&state.hubs);
    // Another socket may have started the job's task meanwhile: ours is then dropped.
    if let Some(r) = joined(&all) {
        return r;
    }
    let (tx, rx) = watch::channel(Arc::new(Frame::default()));
    all.insert(key, tx.clone());
    drop(all);
    let hubs = state.hubs.clone();
    tokio::spawn(async move { replicate(updates, &tx, &hubs, key).await });
    Ok(rx)
}

/// The shared task of one job: applies the updates, publishes frames until the job is
/// over, the stream ends or no socket is left; then leaves the registry.
async fn replicate(
    mut updates: impl Stream<Item = Result<pb::FramebufferUpdate, tonic::Status>> + Unpin,
    tx: &watch::Sender<Arc<Frame>>,
    hubs: &Hubs,
    key: HubKey,
) {
    let leave = || {
        let mut all = lock(hubs);
        if all.get(&key).is_some_and(|t| t.same_channel(tx)) {
            all.remove(&key);
        }
    };
    let mut replica = Replica::default();
    let mut tick = tokio::time::interval(MIN_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            u = updates.next() => match u {
                Some(Ok(u)) => {
                    if let Err(e) = replica.apply(&u) {
                        leave();
                        publish_end(tx, 1011, &e);
                        return;
                    }
                    if u.r#final {
                        // Registry first: a socket arriving now starts a fresh Watch.
                        leave();
                        let mut f = resolve(&mut replica).await;
                        f.last = true;
                        tx.send_replace(Arc::new(f));
                        return;
                    }
                }
                Some(Err(s)) => {
                    leave();
                    publish_end(tx, 1011, s.message());
                    return;
                }
                None => {
                    leave();
                    publish_end(tx, 1001, "the coordinator is shutting down");
                    return;
                }
            },
            _ = tick.tick() => {
                if replica.ready() {
                    let f = resolve(&mut replica).await;
                    tx.send_replace(Arc::new(f));
                } else if replica.status_changed {
                    replica.status_changed = false;
                    let old = tx.borrow().clone();
                    let f = Frame { status: replica.status.clone(), ..Frame::clone(&old) };
                    tx.send_replace(Arc::new(f));
                }
            }
            _ = tx.closed() => {
                // Under the lock no socket can subscribe between the count and the removal.
                let mut all = lock(hubs);
                if tx.receiver_count() == 0 {
                    if all.get(&key).is_some_and(|t| t.same_channel(tx)) {
                        all.remove(&key);
                    }
                    return;
                }
            }
        }
    }
}

fn publish_end(tx: &watch::Sender<Arc<Frame>>, code: u16, reason: &str) {
    let old = tx.borrow().clone();
    let f = Frame { end: Some((code, reason.to_string())), ..Frame::clone(&old) };
    tx.send_replace(Arc::new(f));
}

/// The replica's frame, resolved on a blocking thread: a large image takes milliseconds.
async fn resolve(replica: &mut Replica) -> Frame {
    let mut taken = std::mem::take(replica);
    match tokio::task::spawn_blocking(move || {
        let f = taken.frame();
        (taken, f)
    })
    .await
    {
        Ok((back, f)) => {
            *replica = back;
            f
        }
        Err(e) => Frame { end: Some((1011, format!("encoding the image failed: {e}"))), ..Frame::default() },
    }
}

/// A replica of a job's framebuffer from its watch updates.
#[derive(Default)]
pub(crate) struct Replica {
    fb: Option<Framebuffer>,
    version: u64,
    generation: u64,
    /// Pixels arrived since the last frame.
    dirty: bool,
    /// An update's chunks arrived but not yet its last (`chunk_end`): not to publish.
    partial: bool,
    status: Option<pb::JobStatus>,
    status_changed: bool,
}

impl Replica {
    /// Applies one watch update (checked whole before anything changes).
    pub(crate) fn apply(&mut self, u: &pb::FramebufferUpdate) -> Result<(), String> {
        let n = u64::from(u.width) * u64::from(u.height);
        if n == 0 {
            return Err("an update of an empty image".into());
        }
        let same_size = self.fb.as_ref().is_none_or(|fb| (fb.width(), fb.height()) == (u.width, u.height));
        if !u.reset && !same_size {
            return Err(format!("the image size changed to {}x{}", u.width, u.height));
        }
        let pixels = pixels_from_wire(&u.pixels, n).map_err(|e| e.to_string())?;
        if u.reset {
            self.fb = None;
            self.generation += 1;
        }
        let fb = self.fb.get_or_insert_with(|| Framebuffer::new(u.width, u.height));
        for p in pixels {
            fb.set(&p);
        }
        if u.chunk_end {
            self.version = u.version;
        }
        self.partial = !u.chunk_end;
        self.dirty = true;
        if let Some(s) = &u.status {
            if self.status.as_ref() != Some(s) {
                self.status = Some(s.clone());
                self.status_changed = true;
            }
        }
        Ok(())
    }

    /// Whether a frame is due: pixels changed and the last update is whole.
    pub(crate) fn ready(&self) -> bool {
        self.dirty && !self.partial && self.fb.is_some()
    }

    /// The image as it is now, resolved to sRGB8.
    fn frame(&mut self) -> Frame {
        let rgba: Vec<[u8; 4]> = self.fb.as_ref().map_or_else(Vec::new, |fb| {
            fb.resolve()
                .chunks_exact(3)
                .map(|p| {
                    use tessera_film::output::srgb8;
                    [srgb8(p[0]), srgb8(p[1]), srgb8(p[2]), 255]
                })
                .collect()
        });
        self.dirty = false;
        self.status_changed = false;
        Frame {
            version: self.version,
            generation: self.generation,
            rgba: Arc::new(rgba),
            status: self.status.clone(),
            last: false,
            end: None,
        }
    }
}

/// The binary message taking a browser from `sent` (nothing, or another generation: the
/// whole image with the reset flag) to `now`, or `None` when nothing changed and `now`
/// is not the last.
fn message(sent: Option<&Frame>, now: &Frame) -> Option<Vec<u8>> {
    if now.rgba.is_empty() {
        return None;
    }
    let before = sent.filter(|s| s.generation == now.generation && s.rgba.len() == now.rgba.len());
    if before.is_some_and(|s| Arc::ptr_eq(&s.rgba, &now.rgba)) && !now.last {
        return None;
    }
    let rgba = &now.rgba;
    let reset = before.is_none();
    let runs = changed_runs(before.map(|s| s.rgba.as_slice()), rgba);
    let flags = if reset { FLAG_RESET } else { 0 } | if now.last { FLAG_FINAL } else { 0 };
    let mut out = Vec::with_capacity(20 + runs.iter().map(|r| 8 + 4 * r.len()).sum::<usize>());
    out.extend_from_slice(&MAGIC.to_le_bytes());
    out.extend_from_slice(&now.version.to_le_bytes());
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&(runs.len() as u32).to_le_bytes());
    for r in &runs {
        out.extend_from_slice(&(r.start as u32).to_le_bytes());
        out.extend_from_slice(&(r.len() as u32).to_le_bytes());
        for p in &rgba[r.clone()] {
            out.extend_from_slice(p);
        }
    }
    Some(out)
}

/// The runs of pixels of `now` that differ from `before` (all of them without `before`),
/// with gaps of up to `JOIN_GAP` unchanged pixels joined.
fn changed_runs(before: Option<&[[u8; 4]]>, now: &[[u8; 4]]) -> Vec<std::ops::Range<usize>> {
    let Some(before) = before else {
        return std::iter::once(0..now.len()).collect();
    };
    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
    for i in (0..now.len()).filter(|&i| before[i] != now[i]) {
        match runs.last_mut() {
            Some(r) if i - r.end <= JOIN_GAP => r.end = i + 1,
            _ => runs.push(i..i + 1),
        }
    }
    runs
}

/// Feeds `socket` from the job's shared frames until the job ends or the browser leaves.
async fn stream_job(
    mut socket: WebSocket,
    mut frames: watch::Receiver<Arc<Frame>>,
    job: pb::JobStatus,
) -> Result<(), String> {
    let hello = serde_json::json!({ "type": "hello", "width": job.width, "height": job.height });
    send_text(&mut socket, hello).await?;
    let mut sent: Option<Arc<Frame>> = None;
    let mut sent_status: Option<pb::JobStatus> = None;
    // The frame there is now (a socket joining a watched job starts from it), then each new.
    let mut now = frames.borrow_and_update().clone();
    loop {
        if let Some(s) = &now.status {
            if sent_status.as_ref() != Some(s) {
                sent_status = Some(s.clone());
                send_text(&mut socket, serde_json::json!({ "type": "status", "job": Job::from(s.clone()) }))
                    .await?;
            }
        }
        let (before, after) = (sent.clone(), now.clone());
        let m = tokio::task::spawn_blocking(move || message(before.as_deref(), &after))
            .await
            .map_err(|e| format!("encoding the image failed: {e}"))?;
        if let Some(m) = m {
            socket.send(Message::Binary(m.into())).await.map_err(|e| e.to_string())?;
            sent = Some(now.clone());
        }
        if now.last {
            close(&mut socket, 1000, "the job is over").await;
            return Ok(());
        }
        if let Some((code, reason)) = &now.end {
            close(&mut socket, *code, reason).await;
            return Err(reason.clone());
        }
        tokio::select! {
            changed = frames.changed() => {
                if changed.is_err() {
                    close(&mut socket, 1011, "the job's live stream ended").await;
                    return Ok(());
                }
                now = frames.borrow_and_update().clone();
            }
            incoming = socket.recv() => match incoming {
                // The browser left (the job's viewer slot is freed with its last socket).
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return Ok(()),
                Some(Ok(_)) => {}
            },
        }
    }
}

async fn send_text(socket: &mut WebSocket, value: serde_json::Value) -> Result<(), String> {
    socket.send(Message::Text(Utf8Bytes::from(value.to_string()))).await.map_err(|e| e.to_string())
}

async fn close(socket: &mut WebSocket, code: u16, reason: &str) {
    // A close reason is at most 123 bytes.
    let mut reason = reason.to_string();
    while reason.len() > 120 {
        reason.pop();
    }
    let _ = socket.send(Message::Close(Some(CloseFrame { code, reason: Utf8Bytes::from(reason) }))).await;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn update(version: u64, chunk_end: bool, index: u32, sum: u64) -> pb::FramebufferUpdate {
        let p = tessera_film::PixelState { index, sums: [sum; 3], count: 1 };
        pb::FramebufferUpdate {
            width: 4,
            height: 2,
            version,
            chunk_end,
            pixels: tessera_proto::convert::pixels_to_wire(&[p]),
            ..Default::default()
        }
    }

    #[test]
    fn a_frame_is_due_only_once_an_update_has_arrived_whole() {
        let mut r = Replica::default();
        assert!(!r.ready());
        r.apply(&update(1, true, 0, 1 << 30)).unwrap();
        assert!(r.ready());
        let f = r.frame();
        assert_eq!((f.version, f.rgba.len()), (1, 8));
        // Version 2 in two chunks: after the first, nothing is due (it would carry half of
        // version 2 stamped 1).
        r.apply(&update(2, false, 1, 0)).unwrap();
        assert!(!r.ready());
        r.apply(&update(2, true, 2, 0)).unwrap();
        assert!(r.ready());
        let g = r.frame();
        assert_eq!(g.version, 2);
        let m = message(Some(&f), &g).unwrap();
        // Drawn over what was sent (the mosaic may change unrendered pixels too), the
        // delta gives the new image; it is not a reset.
        let at = |i: usize| u32::from_le_bytes(m[i..i + 4].try_into().unwrap()) as usize;
        assert_eq!(at(12), 0, "flags");
        let mut canvas = f.rgba.as_ref().clone();
        let mut i = 20;
        for _ in 0..at(16) {
            let (start, len) = (at(i), at(i + 4));
            for (k, px) in m[i + 8..i + 8 + 4 * len].chunks_exact(4).enumerate() {
                canvas[start + k] = px.try_into().unwrap();
            }
            i += 8 + 4 * len;
        }
        assert_eq!(i, m.len());
        assert!(canvas != *f.rgba && canvas == *g.rgba);
        assert!(message(Some(&g), &g).is_none(), "nothing new, not the last: no message");
    }

    #[test]
    fn runs_cover_exactly_the_changes_with_small_gaps_joined() {
        let a = vec![[0u8; 4]; 20];
        assert_eq!(changed_runs(None, &a), std::iter::once(0..20).collect::<Vec<_>>());
        let mut b = a.clone();
        for i in [1, 3, 10, 19] {
            b[i] = [9, 9, 9, 255];
        }
        assert_eq!(changed_runs(Some(&a), &b), vec![1..4, 10..11, 19..20]);
        assert!(changed_runs(Some(&a), &a).is_empty());
    }
}
