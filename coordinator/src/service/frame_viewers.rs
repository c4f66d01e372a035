//! Watch streams of one frame of a sequence. A sequence's frames are stacked in one
//! framebuffer, so its viewers do not share the still's publisher (whose deltas cover the
//! whole stack): each such viewer's task takes a snapshot each tick (a pointer per tile,
//! under the lock), and streams the pixels of its frame that changed since the version its
//! replica holds, re-indexed to the frame, outside the lock, within the viewers' byte
//! budget. The first update carries `reset`, the last `final`, as for a still.

use std::time::{Duration, Instant};

use bytes::Bytes;
use tessera_description::ids::JobId;
use tessera_proto::convert;
use tessera_proto::v1 as pb;
use tokio::sync::mpsc;
use tonic::Status;

use super::viewers::WATCH_CHUNK_PIXELS;
use super::CoordinatorService;
use crate::frames::FrameRows;

impl CoordinatorService {
    /// Feeds one viewer of frame `frame` (stacked index `index`) of sequence `job` until
    /// the job is over, the viewer leaves, or the coordinator shuts down.
    pub(super) async fn feed_frame_viewer(
        self,
        job: JobId,
        frame: u32,
        index: u32,
        interval: Duration,
        tx: mpsc::Sender<Result<pb::FramebufferUpdate, Status>>,
    ) {
        let mut changed = self.subscribe();
        let mut stop = self.shutting_down();
        let mut sent: Option<u64> = None;
        let mut last_status: Option<pb::JobStatus> = None;
        loop {
            let round = Instant::now();
            let snap = {
                let farm = self.farm();
                let Some(j) = farm.job(job) else { return };
                let rows = FrameRows { row: index * j.frame_height(), height: j.frame_height() };
                let status = pb::JobStatus {
                    owner: j.owner.clone(),
                    workers: farm.workers_on(job),
                    ..convert::status_to_wire(&j.progress(Instant::now()))
                };
                (j.framebuffer().clone(), rows, status, farm.workers().count() as u32, j.is_over())
            };
            let (fb, rows, status, workers, over) = snap;
            let news = sent != Some(fb.version()) || last_status.as_ref() != Some(&status) || over;
            if news {
                let since = sent.unwrap_or(0);
                let (width, version) = (fb.width(), fb.version());
                let chunks = tokio::task::spawn_blocking(move || {
                    let mut chunks: Vec<Bytes> = Vec::new();
                    let mut pending = Vec::new();
                    for chunk in fb.changes(since, WATCH_CHUNK_PIXELS) {
                        pending.extend(rows.select(width, chunk));
                        while pending.len() >= WATCH_CHUNK_PIXELS {
                            let rest = pending.split_off(WATCH_CHUNK_PIXELS);
                            chunks.push(convert::pixels_to_wire(&pending));
                            pending = rest;
                        }
                    }
                    if !pending.is_empty() || chunks.is_empty() {
                        chunks.push(if pending.is_empty() {
                            Bytes::new()
                        } else {
                            convert::pixels_to_wire(&pending)
                        });
                    }
                    chunks
                })
                .await;
                let Ok(chunks) = chunks else { return };
                let n = chunks.len();
                for (k, pixels) in chunks.into_iter().enumerate() {
                    let first = sent.is_none() && k == 0;
                    let end = k + 1 == n;
                    let u = pb::FramebufferUpdate {
                        job_id: job.0,
                        width,
                        height: rows.height,
                        version,
                        chunk_end: end,
                        pixels,
                        status: Some(status.clone()),
                        workers,
                        r#final: over && end,
                        reset: first,
                        protocol_version: if first { tessera_proto::PROTOCOL_VERSION as i32 } else { 0 },
                        frame,
                        preview: Default::default(),
                    };
                    self.within_budget(&u).await;
                    if tx.send(Ok(u)).await.is_err() {
                        return;
                    }
                }
                sent = Some(version);
                last_status = Some(status);
                if over {
                    return;
                }
            }
            tokio::select! {
                _ = changed.changed() => {}
                _ = tokio::time::sleep(Duration::from_secs(1)) => {}
                _ = tx.closed() => return,
                _ = stop.changed() => return,
            }
            tokio::time::sleep(interval.saturating_sub(round.elapsed())).await;
        }
    }
}
