//! A fake worker: speaks the worker protocol on one `Work` stream and answers batches with
//! valid sums computed from the pixel coordinates, without rendering. Tests drive it step
//! by step (take a batch, answer, fail, go silent, drop); the farm benchmark lets it
//! `serve` with a simulated render time.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tessera_description::ids::WorkerId;
use tessera_proto::connect::Channel;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_message::Msg as In;
use tessera_proto::v1::worker_message::Msg as Out;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Streaming;

use crate::{worker_client, HarnessError, Result, PATIENCE};

/// Samples of the batch whose render time `serve` is given: a full pass-two batch as the
/// coordinator cuts it (`scheduler::PASS_TWO_SAMPLES`); smaller batches take
/// proportionally less.
pub const REFERENCE_BATCH_SAMPLES: u64 = 32_768;

/// The fixed-point radiance (r, g, b) every sample of pixel `(x, y)` returns: below 1.0 a
/// channel, so any sample count stays within `fixed::max_sum`, and different per pixel,
/// so that a pixel merged in the wrong place shows.
pub fn pixel_value(x: u32, y: u32) -> [u64; 3] {
    let r = u64::from((x.wrapping_mul(37) ^ y.wrapping_mul(11)) % 256);
    let g = u64::from((x.wrapping_mul(5).wrapping_add(y.wrapping_mul(3))) % 200);
    [r << 16, g << 16, 1 << 20]
}

/// The result a correct renderer of `pixel_value` returns for `batch`: every sum in range,
/// even-sample sums when the batch asks for them.
pub fn valid_result(batch: &pb::Batch) -> pb::BatchResult {
    let n = u64::from(batch.sample_end.saturating_sub(batch.sample_start));
    // Even sample indices in [start, end).
    let evens = u64::from(batch.sample_end.div_ceil(2) - batch.sample_start.div_ceil(2));
    let pixels = batch.pixels.len() / 2;
    let mut sums = Vec::with_capacity(pixels * 3);
    let mut even_sums = Vec::with_capacity(if batch.even_sums { pixels } else { 0 });
    for p in batch.pixels.chunks_exact(2) {
        let v = pixel_value(p[0], p[1]);
        sums.extend(v.iter().map(|c| c * n));
        if batch.even_sums {
            even_sums.push((v.iter().sum::<u64>() / 3) * evens);
        }
    }
    pb::BatchResult {
        job_id: batch.job_id,
        batch_id: batch.batch_id,
        attempt: batch.attempt,
        sums,
        nonfinite_samples: 0,
        render_micros: 0,
        even_sums,
        lease: batch.lease.clone(),
        // Layers as a scene of black, nowhere: a valid answer of the right length.
        aov_sums: vec![
            0;
            pixels * tessera_film::aov::Layout::from_bits(batch.aovs).map_or(0, |l| l.per_pixel())
        ],
    }
}

/// A worker connection with no renderer behind it.
pub struct FakeWorker {
    /// The id the coordinator gave it in `Welcome`.
    pub id: WorkerId,
    /// Jobs whose scene it received, in order.
    pub scenes: Vec<u64>,
    credit: u32,
    tx: mpsc::Sender<pb::WorkerMessage>,
    inbound: Streaming<pb::CoordinatorMessage>,
}

impl FakeWorker {
    /// Opens a `Work` stream, says `Hello` with the current protocol and renderer versions
    /// and `credit`, and waits for `Welcome`.
    pub async fn connect(channel: &Channel, name: &str, credit: u32) -> Result<FakeWorker> {
        // Room for a few messages: the fake never has more than a credit's worth in flight.
        let (tx, rx) = mpsc::channel(64);
        let hello = pb::Hello {
            protocol_version: pb::ProtocolVersion::Current as i32,
            renderer_version: tessera_description::RENDERER_VERSION.into(),
            name: name.into(),
            threads: 1,
            credit,
            frames: true,
            held_scenes: vec![],
        };
        tx.send(pb::WorkerMessage { msg: Some(Out::Hello(hello)) })
            .await
            .map_err(|_| HarnessError::Closed)?;
        let inbound = worker_client(channel).work(ReceiverStream::new(rx)).await?.into_inner();
        let mut w = FakeWorker { id: WorkerId(0), scenes: Vec::new(), credit, tx, inbound };
        match w.next().await? {
            In::Welcome(welcome) => w.id = WorkerId(welcome.worker_id),
            In::Refused(r) => return Err(HarnessError::Refused(r.reason)),
            other => return Err(HarnessError::Protocol(format!("expected Welcome, got {other:?}"))),
        }
        Ok(w)
    }

    /// The next message from the coordinator, waiting at most `limit`; `None` on timeout.
    pub async fn next_within(&mut self, limit: Duration) -> Result<Option<In>> {
        match tokio::time::timeout(limit, self.inbound.message()).await {
            Err(_) => Ok(None),
            Ok(Ok(Some(pb::CoordinatorMessage { msg: Some(m) }))) => Ok(Some(m)),
            Ok(Ok(Some(_))) => Err(HarnessError::Protocol("empty coordinator message".into())),
            Ok(Ok(None)) => Err(HarnessError::Closed),
            Ok(Err(status)) => Err(status.into()),
        }
    }

    /// The next message from the coordinator (at most `PATIENCE`).
    pub async fn next(&mut self) -> Result<In> {
        self.next_within(PATIENCE).await?.ok_or_else(|| HarnessError::Timeout("a coordinator message".into()))
    }

    /// The next batch, noting scenes on the way; a `Refused` is an error.
    pub async fn next_batch(&mut self) -> Result<pb::Batch> {
        loop {
            match self.next().await? {
                In::Batch(b) => return Ok(b),
                In::Scene(s) => self.scenes.push(s.job_id),
                In::Refused(r) => return Err(HarnessError::Refused(r.reason)),
                In::Welcome(_) => return Err(HarnessError::Protocol("Welcome sent twice".into())),
            }
        }
    }

    /// Reads until the coordinator refuses this worker; returns the reason.
    pub async fn refusal(&mut self) -> Result<String> {
        loop {
            match self.next().await? {
                In::Refused(r) => return Ok(r.reason),
                In::Scene(s) => self.scenes.push(s.job_id),
                _ => {}
            }
        }
    }

    /// Sends one message on the stream.
    pub async fn send(&mut self, msg: Out) -> Result<()> {
        self.tx.send(pb::WorkerMessage { msg: Some(msg) }).await.map_err(|_| HarnessError::Closed)
    }

    /// Returns `results` and grants `credit` more batches.
    pub async fn send_results(&mut self, results: Vec<pb::BatchResult>, credit: u32) -> Result<()> {
        self.send(Out::Results(pb::Results { results, credit })).await
    }

    /// Answers `batch` with valid sums and one more credit.
    pub async fn answer(&mut self, batch: &pb::Batch) -> Result<()> {
        self.send_results(vec![valid_result(batch)], 1).await
    }

    /// Answers `batch` with valid sums changed by `edit` (doubled, zeroed, another
    /// attempt number or lease token...), and one more credit: a hostile worker.
    pub async fn answer_with(
        &mut self,
        batch: &pb::Batch,
        edit: impl FnOnce(&mut pb::BatchResult),
    ) -> Result<()> {
        let mut r = valid_result(batch);
        edit(&mut r);
        self.send_results(vec![r], 1).await
    }

    /// Sends a result for a batch this worker was never given: `job`, `batch` and `lease`
    /// as named (another worker's, or made up), sums valid for `pixels` × `samples`.
    pub async fn forge(&mut self, template: &pb::Batch, lease: Vec<u8>) -> Result<()> {
        let mut r = valid_result(template);
        r.lease = lease;
        self.send_results(vec![r], 0).await
    }

    /// Reports `batch` as failed with `error`, and one more credit.
    pub async fn fail(&mut self, batch: &pb::Batch, error: &str) -> Result<()> {
        self.fail_with(batch, error, |_| {}).await
    }

    /// Reports `batch` as failed, the report changed by `edit` (a scene refusal, another
    /// lease token, no credit...).
    pub async fn fail_with(
        &mut self,
        batch: &pb::Batch,
        error: &str,
        edit: impl FnOnce(&mut pb::BatchFailed),
    ) -> Result<()> {
        let mut f = pb::BatchFailed {
            job_id: batch.job_id,
            batch_id: batch.batch_id,
            attempt: batch.attempt,
            error: error.into(),
            credit: 1,
            lease: batch.lease.clone(),
            scene_refused: false,
        };
        edit(&mut f);
        self.send(Out::Failed(f)).await
    }

    /// Sends a heartbeat.
    pub async fn heartbeat(&mut self) -> Result<()> {
        self.send(Out::Heartbeat(pb::Heartbeat {})).await
    }

    /// Ends the stream at once, whatever it holds (a crashed worker, or one pulled out).
    pub fn disconnect(self) {
        drop(self);
    }

    /// Answers every batch until the stream ends, one at a time as a one-thread worker
    /// does: each after `batch_time` scaled by its samples over
    /// `REFERENCE_BATCH_SAMPLES` (zero: at once), with one more credit. Counts into
    /// `stats`. Returns when the coordinator closes the stream or refuses it.
    pub async fn serve(self, batch_time: Duration, stats: Arc<ServeStats>) -> Result<()> {
        self.serve_with(batch_time, stats, |_, _| {}).await
    }

    /// `serve`, with every result passed through `edit` before it is sent, with the batch
    /// it answers (a worker that lies: doubles its sums, zeroes one batch in fifty...).
    pub async fn serve_with(
        self,
        batch_time: Duration,
        stats: Arc<ServeStats>,
        mut edit: impl FnMut(&pb::Batch, &mut pb::BatchResult) + Send,
    ) -> Result<()> {
        let FakeWorker { mut inbound, tx, credit, .. } = self;
        // When each credit was granted, oldest first: the coordinator leases in grant
        // order, so the next batch to arrive is the one the oldest grant bought. The
        // grants of `Hello` are not timed (their moment is not known here).
        let grants: Arc<Mutex<VecDeque<Option<Instant>>>> =
            Arc::new(Mutex::new((0..credit).map(|_| None).collect()));
        // A reader of its own, so that a batch's arrival is timed when it arrives, not
        // when the simulated render of the one before ends.
        let (batches_tx, mut batches) = mpsc::unbounded_channel();
        let reader = {
            let (grants, stats) = (grants.clone(), stats.clone());
            tokio::spawn(async move {
                while let Ok(Some(m)) = inbound.message().await {
                    match m.msg {
                        Some(In::Batch(b)) => {
                            let granted = lock(&grants).pop_front().flatten();
                            if let Some(t) = granted.filter(|_| stats.measuring()) {
                                lock(&stats.lease_micros).push(t.elapsed().as_micros() as u64);
                            }
                            if batches_tx.send(b).is_err() {
                                return;
                            }
                        }
                        Some(In::Refused(_)) | None => return,
                        Some(In::Scene(_) | In::Welcome(_)) => {}
                    }
                }
            })
        };
        while let Some(batch) = batches.recv().await {
            let samples = (batch.pixels.len() / 2) as u64
                * u64::from(batch.sample_end.saturating_sub(batch.sample_start));
            let render = batch_time.mul_f64(samples as f64 / REFERENCE_BATCH_SAMPLES as f64);
            if render.is_zero() {
                tokio::task::yield_now().await;
            } else {
                tokio::time::sleep(render).await;
            }
            let mut result = valid_result(&batch);
            // As a real worker does: the coordinator sizes later batches from it.
            result.render_micros = render.as_micros() as u64;
            edit(&batch, &mut result);
            let measuring = stats.measuring();
            let now = Instant::now();
            if measuring && stats.track_pixels && batch.pass == 2 {
                if let [x, y, ..] = batch.pixels[..] {
                    lock(&stats.sent).insert((batch.job_id, x, y), now);
                }
            }
            lock(&grants).push_back(Some(now));
            let msg = pb::WorkerMessage {
                msg: Some(Out::Results(pb::Results { results: vec![result], credit: 1 })),
            };
            if tx.send(msg).await.is_err() {
                break;
            }
            if measuring {
                stats.results.fetch_add(1, Ordering::Relaxed);
                stats.simulated_micros.fetch_add(render.as_micros() as u64, Ordering::Relaxed);
            }
        }
        reader.abort();
        Ok(())
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// What serving workers did while `measuring` was set; shared by all of a run's workers.
#[derive(Debug, Default)]
pub struct ServeStats {
    measuring: AtomicBool,
    /// Whether to note when each pass-two batch's first pixel was sent (`sent`), for a
    /// viewer to time when it sees it.
    pub track_pixels: bool,
    /// Results sent.
    pub results: AtomicU64,
    /// Simulated render time of those results, in microseconds: the CPU the workers would
    /// have spent.
    pub simulated_micros: AtomicU64,
    /// Per batch received, microseconds from the credit that bought it to its arrival.
    pub lease_micros: Mutex<Vec<u64>>,
    /// (job, x, y) of each pass-two batch's first pixel → when its result was sent.
    pub sent: Mutex<HashMap<(u64, u32, u32), Instant>>,
}

impl ServeStats {
    /// Stats that note sent pixels when `track_pixels`.
    pub fn new(track_pixels: bool) -> Self {
        ServeStats { track_pixels, ..ServeStats::default() }
    }

    /// Starts or stops counting.
    pub fn set_measuring(&self, on: bool) {
        self.measuring.store(on, Ordering::SeqCst);
    }

    /// Whether counting.
    pub fn measuring(&self) -> bool {
        self.measuring.load(Ordering::Relaxed)
    }

    /// Takes the time a result for `(job, x, y)` was sent, if one was noted.
    pub fn take_sent(&self, job: u64, x: u32, y: u32) -> Option<Instant> {
        lock(&self.sent).remove(&(job, x, y))
    }
}
