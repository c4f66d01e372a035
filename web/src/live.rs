//! `GET /api/jobs/{id}/live`: a WebSocket carrying a job's image as it refines.
//!
//! Each socket subscribes through the coordinator's Watch RPC (one viewer slot, held until
//! the socket ends), keeps a replica of the job's framebuffer from the versioned updates
//! and, at most ten times a second while it changes, resolves it (the mosaic included),
//! encodes it to sRGB8 and sends the pixels that changed since the last message, in canvas
//! order (row 0 at the top). The format is in `docs/http-api.md`.

use std::time::Duration;

use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, State};
use axum::response::Response;
use tessera_film::Framebuffer;
use tessera_proto::convert::pixels_from_wire;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;
use tokio_stream::{Stream, StreamExt};

use crate::api::auth::Caller;
use crate::api::{job_id, request, the_job};
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

/// `GET /api/jobs/{id}/live`.
pub(crate) async fn live(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
    ws: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    let id = job_id(&raw)?;
    let job = the_job(&state, &caller, id).await?;
    let ws =
        ws.map_err(|e| ApiError::new(e.status(), format!("GET /api/jobs/{id}/live: {}", e.body_text())))?;
    let watch = pb::WatchRequest {
        job_id: id,
        max_rate: 10.0,
        protocol_version: pb::ProtocolVersion::Current as i32,
    };
    // The viewer slot is taken now: a full coordinator is a 503 before the upgrade.
    let updates = Coordinator::watch(&state.service, request(&caller.0, watch)).await?.into_inner();
    Ok(ws.on_upgrade(move |socket| async move {
        if let Err(e) = stream_job(socket, updates, job).await {
            tracing::debug!(job = id, "live socket ended: {e}");
        }
    }))
}

/// A replica of a job's framebuffer and what the browser was last sent of it.
#[derive(Default)]
pub(crate) struct Live {
    fb: Option<Framebuffer>,
    version: u64,
    /// RGBA8 of every pixel, canvas order, as last sent; `None` before the first message
    /// and after a reset.
    sent: Option<Vec<[u8; 4]>>,
    /// Pixels arrived since the last message.
    dirty: bool,
}

impl Live {
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
            self.sent = None;
        }
        let fb = self.fb.get_or_insert_with(|| Framebuffer::new(u.width, u.height));
        for p in pixels {
            fb.set(&p);
        }
        if u.chunk_end {
            self.version = u.version;
        }
        self.dirty = true;
        Ok(())
    }

    /// The binary message of what changed since the last one (everything, with the reset
    /// flag, for the first), or `None` when nothing did and `last` is not asked.
    pub(crate) fn message(&mut self, last: bool) -> Option<Vec<u8>> {
        let fb = self.fb.as_ref()?;
        if !self.dirty && !last {
            return None;
        }
        let rgba: Vec<[u8; 4]> = fb
            .resolve()
            .chunks_exact(3)
            .map(|p| {
                use tessera_film::output::srgb8;
                [srgb8(p[0]), srgb8(p[1]), srgb8(p[2]), 255]
            })
            .collect();
        let reset = self.sent.is_none();
        let runs = changed_runs(self.sent.as_deref(), &rgba);
        let flags = if reset { FLAG_RESET } else { 0 } | if last { FLAG_FINAL } else { 0 };
        let mut out = Vec::with_capacity(20 + runs.iter().map(|r| 8 + 4 * r.len()).sum::<usize>());
        out.extend_from_slice(&MAGIC.to_le_bytes());
        out.extend_from_slice(&self.version.to_le_bytes());
        out.extend_from_slice(&flags.to_le_bytes());
        out.extend_from_slice(&(runs.len() as u32).to_le_bytes());
        for r in &runs {
            out.extend_from_slice(&(r.start as u32).to_le_bytes());
            out.extend_from_slice(&(r.len() as u32).to_le_bytes());
            for p in &rgba[r.clone()] {
                out.extend_from_slice(p);
            }
        }
        self.sent = Some(rgba);
        self.dirty = false;
        Some(out)
    }
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

/// Feeds `socket` from the watch stream until the job ends or the browser leaves.
async fn stream_job(
    mut socket: WebSocket,
    updates: impl Stream<Item = Result<pb::FramebufferUpdate, tonic::Status>> + Unpin,
    job: pb::JobStatus,
) -> Result<(), String> {
    let mut updates = updates;
    let hello = serde_json::json!({ "type": "hello", "width": job.width, "height": job.height });
    send_text(&mut socket, hello).await?;
    let mut live = Live::default();
    let mut status: Option<pb::JobStatus> = None;
    let mut sent_status: Option<pb::JobStatus> = None;
    let mut tick = tokio::time::interval(MIN_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            u = updates.next() => match u {
                Some(Ok(u)) => {
                    live.apply(&u)?;
                    if let Some(s) = u.status.clone() {
                        status = Some(s);
                    }
                    if u.r#final {
                        send_status(&mut socket, &status, &mut sent_status).await?;
                        if let Some(m) = live.message(true) {
                            socket.send(Message::Binary(m.into())).await.map_err(|e| e.to_string())?;
                        }
                        close(&mut socket, 1000, "the job is over").await;
                        return Ok(());
                    }
                }
                Some(Err(s)) => {
                    close(&mut socket, 1011, s.message()).await;
                    return Err(s.message().to_string());
                }
                None => {
                    close(&mut socket, 1001, "the coordinator is shutting down").await;
                    return Ok(());
                }
            },
            _ = tick.tick() => {
                send_status(&mut socket, &status, &mut sent_status).await?;
                if let Some(m) = live.message(false) {
                    socket.send(Message::Binary(m.into())).await.map_err(|e| e.to_string())?;
                }
            }
            incoming = socket.recv() => match incoming {
                // The browser left (its viewer slot is freed when `updates` is dropped).
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return Ok(()),
                Some(Ok(_)) => {}
            },
        }
    }
}

async fn send_text(socket: &mut WebSocket, value: serde_json::Value) -> Result<(), String> {
    socket.send(Message::Text(Utf8Bytes::from(value.to_string()))).await.map_err(|e| e.to_string())
}

/// Sends the job's status if it changed since the last one sent.
async fn send_status(
    socket: &mut WebSocket,
    status: &Option<pb::JobStatus>,
    sent: &mut Option<pb::JobStatus>,
) -> Result<(), String> {
    match status {
        Some(s) if sent.as_ref() != Some(s) => {
            *sent = Some(s.clone());
            send_text(socket, serde_json::json!({ "type": "status", "job": Job::from(s.clone()) })).await
        }
        _ => Ok(()),
    }
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
