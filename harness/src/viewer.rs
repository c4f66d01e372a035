//! A fake viewer: one `Watch` stream, its updates applied to a `Framebuffer` replica and,
//! for a viewer of previews, an `Overlay` (or only counted, for benchmarks with many
//! viewers).

use std::time::{Duration, Instant};

use tessera_film::framebuffer::Framebuffer;
use tessera_film::preview::Overlay;
use tessera_proto::connect::Channel;
use tessera_proto::convert::pixels_from_wire;
use tessera_proto::preview::preview_from_wire;
use tessera_proto::v1 as pb;
use tonic::Streaming;

use crate::{client, HarnessError, Result, PATIENCE};

/// A viewer of one job.
pub struct FakeViewer {
    stream: Streaming<pb::FramebufferUpdate>,
    keep_replica: bool,
    replica: Option<Framebuffer>,
    overlay: Option<Overlay>,
    /// Updates that carried a preview.
    pub previews: u64,
    /// Updates that carried exact pixel states.
    pub exact: u64,
    /// The version of the last complete update (its last chunk arrived).
    pub version: u64,
    /// Updates received.
    pub updates: u64,
    /// Updates that completed a version (`chunk_end`).
    pub versions_seen: u64,
    /// Encoded bytes of the updates received.
    pub bytes: u64,
    /// Updates with `reset` set: the first of the stream, every time.
    pub resets: u64,
    /// The final update arrived.
    pub finished: bool,
    /// The job's status in the last update.
    pub status: Option<pb::JobStatus>,
}

impl FakeViewer {
    /// Watches job `job` at up to `max_rate` updates a second (0: the coordinator's
    /// default), keeping a replica if `keep_replica`.
    pub async fn watch(channel: &Channel, job: u64, max_rate: f64, keep_replica: bool) -> Result<FakeViewer> {
        Self::open(channel, job, None, max_rate, keep_replica, false).await
    }

    /// As `watch`, reading previews while the job renders (`WatchRequest.previews`), as
    /// `tessera view` does.
    pub async fn watch_previews(
        channel: &Channel,
        job: u64,
        max_rate: f64,
        keep_replica: bool,
    ) -> Result<FakeViewer> {
        Self::open(channel, job, None, max_rate, keep_replica, true).await
    }

    /// As `watch`, of frame `frame` of a sequence (`None`: its first).
    pub async fn watch_frame(
        channel: &Channel,
        job: u64,
        frame: Option<u32>,
        max_rate: f64,
        keep_replica: bool,
    ) -> Result<FakeViewer> {
        Self::open(channel, job, frame, max_rate, keep_replica, false).await
    }

    async fn open(
        channel: &Channel,
        job: u64,
        frame: Option<u32>,
        max_rate: f64,
        keep_replica: bool,
        previews: bool,
    ) -> Result<FakeViewer> {
        let stream = client(channel)
            .watch(pb::WatchRequest {
                job_id: job,
                max_rate,
                protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
                frame,
                previews,
            })
            .await?
            .into_inner();
        Ok(FakeViewer {
            stream,
            keep_replica,
            replica: None,
            overlay: None,
            previews: 0,
            exact: 0,
            version: 0,
            updates: 0,
            versions_seen: 0,
            bytes: 0,
            resets: 0,
            finished: false,
            status: None,
        })
    }

    /// The next update, applied (checked first, as a real viewer does); `None` when the
    /// stream has ended.
    pub async fn next(&mut self) -> Result<Option<pb::FramebufferUpdate>> {
        let Some(u) = self.stream.message().await? else { return Ok(None) };
        self.bytes += prost::Message::encoded_len(&u) as u64;
        self.updates += 1;
        if u.reset {
            if u.protocol_version != tessera_proto::PROTOCOL_VERSION as i32 {
                return Err(HarnessError::Protocol(format!(
                    "the coordinator speaks protocol version {}",
                    u.protocol_version
                )));
            }
            self.resets += 1;
            self.replica = None;
            self.overlay = None;
            self.version = 0;
        }
        if self.keep_replica {
            let n = u64::from(u.width) * u64::from(u.height);
            let pixels = pixels_from_wire(&u.pixels, n).map_err(|e| HarnessError::Protocol(e.to_string()))?;
            let fb = self.replica.get_or_insert_with(|| Framebuffer::new(u.width, u.height));
            if (fb.width(), fb.height()) != (u.width, u.height) {
                return Err(HarnessError::Protocol("the image size changed mid-stream".into()));
            }
            let preview = preview_from_wire(&u.preview, u.width, u.height)
                .map_err(|e| HarnessError::Protocol(e.to_string()))?;
            for p in pixels {
                fb.set(&p);
                if let Some(o) = self.overlay.as_mut() {
                    o.clear(p.index);
                }
            }
            if !preview.is_empty() {
                let o = self.overlay.get_or_insert_with(|| Overlay::new(u.width, u.height));
                for b in &preview {
                    o.paint(b);
                }
            }
            if u.r#final {
                self.overlay = None;
            }
        }
        self.previews += u64::from(!u.preview.is_empty());
        self.exact += u64::from(!u.pixels.is_empty());
        if u.chunk_end {
            self.version = u.version;
            self.versions_seen += 1;
        }
        self.finished |= u.r#final;
        if u.status.is_some() {
            self.status = u.status.clone();
        }
        Ok(Some(u))
    }

    /// Reads until the final update, for at most `PATIENCE`.
    pub async fn until_final(&mut self) -> Result<()> {
        let start = Instant::now();
        while !self.finished {
            let left = PATIENCE.saturating_sub(start.elapsed());
            match tokio::time::timeout(left, self.next()).await {
                Err(_) => return Err(HarnessError::Timeout("the final watch update".into())),
                Ok(Ok(None)) => return Err(HarnessError::Closed),
                Ok(r) => {
                    r?;
                }
            }
        }
        Ok(())
    }

    /// The next update, waiting at most `limit`.
    pub async fn next_within(&mut self, limit: Duration) -> Result<pb::FramebufferUpdate> {
        match tokio::time::timeout(limit, self.next()).await {
            Err(_) => Err(HarnessError::Timeout("a watch update".into())),
            Ok(r) => r?.ok_or(HarnessError::Closed),
        }
    }

    /// The replica (with `keep_replica`, once the first update arrived).
    pub fn replica(&self) -> Option<&Framebuffer> {
        self.replica.as_ref()
    }

    /// What the viewer shows (with `keep_replica`): the replica's image, preview values
    /// painted over it where newer; linear RGB, top row first.
    pub fn shown(&self) -> Option<Vec<f32>> {
        self.replica.as_ref().map(|fb| {
            let mut img = fb.resolve();
            if let Some(o) = &self.overlay {
                o.over(&mut img);
            }
            img
        })
    }

    /// The replica's image as `FetchImage` sends it: linear RGB f32 little-endian, top
    /// row first.
    pub fn image_bytes(&self) -> Option<Vec<u8>> {
        self.replica.as_ref().map(|fb| fb.resolve().iter().flat_map(|v| v.to_le_bytes()).collect())
    }
}
