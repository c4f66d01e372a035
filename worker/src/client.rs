//! The worker's side of the farm: connect to a coordinator, announce the threads, take
//! batches, render them on a pool of threads, and stream back per-pixel sums. The only
//! module of this crate that touches prost types.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::UVec2;
use tessera_proto::connect::{Backoff, ConnectError, EndpointConfig};
use tessera_proto::convert::bundle_from_wire;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_message::Msg as In;
use tessera_proto::v1::worker_message::Msg as Out;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tracing::{debug, info, warn};

use crate::batch::render_batch_split;
use crate::render::Scene;

/// Scenes a worker keeps at once (one per recent job); older ones are dropped.
const SCENE_CACHE: usize = 8;
/// Batches a worker wants in hand per render thread: one rendering, one waiting, so that
/// no thread idles for a round trip to the coordinator.
pub const CREDIT_PER_THREAD: u32 = 2;

/// How a worker runs.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// Where the coordinator is.
    pub coordinator: EndpointConfig,
    /// Render threads.
    pub threads: usize,
    /// Name shown in status.
    pub name: String,
    /// Exit when the coordinator goes away instead of reconnecting (local render children).
    pub exit_on_disconnect: bool,
}

/// One batch for the render pool.
struct Task {
    generation: u64,
    scene: Arc<Scene>,
    batch: pb::Batch,
    pixels: Vec<UVec2>,
    reply: mpsc::UnboundedSender<pb::BatchResult>,
}

/// Render threads shared by every connection of the process.
struct Pool {
    tasks: crossbeam_channel::Sender<Task>,
    generation: Arc<AtomicU64>,
}

impl Pool {
    fn new(threads: usize) -> Pool {
        let (tasks, rx) = crossbeam_channel::unbounded::<Task>();
        let generation = Arc::new(AtomicU64::new(0));
        for i in 0..threads {
            let rx = rx.clone();
            let current = generation.clone();
            std::thread::Builder::new()
                .name(format!("render-{i}"))
                .spawn(move || {
                    for task in rx {
                        // Batches of a connection that is gone were taken back already.
                        if task.generation != current.load(Ordering::Relaxed) {
                            continue;
                        }
                        let start = Instant::now();
                        let b = &task.batch;
                        let range = b.sample_start..b.sample_end;
                        let sums = render_batch_split(&task.scene, &task.pixels, range, b.even_sums);
                        let _ = task.reply.send(pb::BatchResult {
                            job_id: b.job_id,
                            batch_id: b.batch_id,
                            attempt: b.attempt,
                            sums: sums.sums,
                            nonfinite_samples: sums.nonfinite,
                            render_micros: start.elapsed().as_micros() as u64,
                            even_sums: sums.even,
                        });
                    }
                })
                .expect("spawning a render thread");
        }
        Pool { tasks, generation }
    }
}

enum SessionEnd {
    /// The coordinator closed the stream.
    Closed,
}

/// Runs a worker until the coordinator refuses it, or (with `exit_on_disconnect`) until
/// the coordinator goes away. A coordinator that cannot be reached at start is an error;
/// one lost later is retried with backoff.
pub async fn run(config: WorkerConfig) -> Result<(), ConnectError> {
    // A worker sits on one long stream: pings notice a coordinator that vanished silently.
    let endpoint = config.coordinator.clone().keep_alive(Duration::from_secs(10), Duration::from_secs(20));
    let pool = Pool::new(config.threads.max(1));
    let mut connected_once = false;
    let mut backoff = Backoff::new(Duration::from_millis(250), Duration::from_secs(15));
    loop {
        let mut welcomed = false;
        let result = session(&endpoint, &config, &pool, &mut welcomed).await;
        pool.generation.fetch_add(1, Ordering::Relaxed);
        if welcomed {
            connected_once = true;
            backoff.reset();
        }
        let reason = match result {
            Ok(SessionEnd::Closed) => "the coordinator closed the connection".to_string(),
            Err(ConnectError::Unreachable { .. }) if connected_once => "unreachable".to_string(),
            Err(ConnectError::Lost(e)) => e,
            Err(e) => return Err(e),
        };
        if config.exit_on_disconnect {
            info!("coordinator gone ({reason}); exiting");
            return Ok(());
        }
        let wait = backoff.next_delay();
        warn!("coordinator lost ({reason}); reconnecting in {wait:?}");
        tokio::time::sleep(wait).await;
    }
}

/// One connection, from Hello to its end; sets `welcomed` once the coordinator accepted it.
async fn session(
    endpoint: &EndpointConfig,
    config: &WorkerConfig,
    pool: &Pool,
    welcomed: &mut bool,
) -> Result<SessionEnd, ConnectError> {
    let url = &endpoint.url;
    let mut client = tessera_proto::connect::client(endpoint).await?;
    let (out, out_rx) = mpsc::channel::<pb::WorkerMessage>(64);
    let threads = config.threads.max(1) as u32;
    let hello = pb::Hello {
        protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
        renderer_version: crate::RENDERER_VERSION.to_string(),
        name: config.name.clone(),
        threads,
        credit: threads * CREDIT_PER_THREAD,
    };
    out.send(pb::WorkerMessage { msg: Some(Out::Hello(hello)) }).await.expect("receiver is alive");
    let mut inbound = client
        .work(ReceiverStream::new(out_rx))
        .await
        .map_err(|s| ConnectError::Unreachable { url: url.clone(), reason: s.message().to_string() })?
        .into_inner();
    let heartbeat = match inbound.message().await {
        Ok(Some(pb::CoordinatorMessage { msg: Some(In::Welcome(w)) })) => {
            info!(worker_id = w.worker_id, threads, "connected to {url}");
            Duration::from_millis(u64::from(w.heartbeat_interval_ms.clamp(100, 60_000)))
        }
        Ok(Some(pb::CoordinatorMessage { msg: Some(In::Refused(r)) })) => {
            return Err(ConnectError::Refused(r.reason))
        }
        Ok(_) => return Err(ConnectError::Lost("the coordinator did not answer Hello with Welcome".into())),
        Err(s) => return Err(ConnectError::Lost(s.message().to_string())),
    };
    *welcomed = true;
    let generation = pool.generation.load(Ordering::Relaxed);
    let (reply, mut done) = mpsc::unbounded_channel::<pb::BatchResult>();
    let mut scenes: SceneCache = SceneCache::default();
    let mut tick = tokio::time::interval(heartbeat);
    loop {
        tokio::select! {
            msg = inbound.message() => {
                let m = match msg {
                    Ok(Some(m)) => m,
                    Ok(None) => return Ok(SessionEnd::Closed),
                    Err(s) => return Err(ConnectError::Lost(s.message().to_string())),
                };
                match m.msg {
                    Some(In::Scene(js)) => scenes.load(js).await,
                    Some(In::Batch(b)) => match scenes.prepare(&b) {
                        Ok((scene, pixels)) => {
                            let task = Task { generation, scene, batch: b, pixels, reply: reply.clone() };
                            pool.tasks.send(task).expect("render threads live as long as the process");
                        }
                        Err(error) => {
                            warn!(job = b.job_id, batch = b.batch_id, "cannot render batch: {error}");
                            let failed = pb::BatchFailed { job_id: b.job_id, batch_id: b.batch_id, attempt: b.attempt, error, credit: 1 };
                            send(&out, Out::Failed(failed)).await?;
                        }
                    },
                    Some(In::Refused(r)) => return Err(ConnectError::Refused(r.reason)),
                    Some(In::Welcome(_)) | None => debug!("ignored an unexpected message"),
                }
            }
            Some(first) = done.recv() => {
                let mut results = vec![first];
                while let Ok(r) = done.try_recv() {
                    results.push(r);
                }
                let credit = results.len() as u32;
                send(&out, Out::Results(pb::Results { results, credit })).await?;
                tick.reset();
            }
            _ = tick.tick() => send(&out, Out::Heartbeat(pb::Heartbeat {})).await?,
        }
    }
}

async fn send(out: &mpsc::Sender<pb::WorkerMessage>, msg: Out) -> Result<(), ConnectError> {
    out.send(pb::WorkerMessage { msg: Some(msg) })
        .await
        .map_err(|_| ConnectError::Lost("the outbound stream closed".into()))
}

/// The scenes of recent jobs, by job id: parsed, or the reason they could not be.
#[derive(Default)]
struct SceneCache {
    scenes: HashMap<u64, (String, Result<Arc<Scene>, String>)>,
    order: VecDeque<u64>,
}

impl SceneCache {
    async fn load(&mut self, js: pb::JobScene) {
        let job = js.job_id;
        let claimed = js.scene_hash.clone();
        let settings = js.settings.unwrap_or_default();
        let spp = (settings.spp != 0).then_some(settings.spp);
        let size = (settings.width != 0 && settings.height != 0).then_some((settings.width, settings.height));
        let parsed = match js.bundle {
            None => Err("the coordinator sent a job without its scene".to_string()),
            Some(b) => {
                let bundle = bundle_from_wire(b);
                // Parsing a large scene is CPU work: keep it off the async threads.
                tokio::task::spawn_blocking(move || {
                    let actual = bundle.hash();
                    if actual != claimed {
                        return Err(format!(
                            "scene content hashes to {actual}, but the coordinator named it {claimed}: refusing a scene that differs from the submitted one"
                        ));
                    }
                    let mut scene = crate::scene::parse_bundle(&bundle).map_err(|e| e.to_string())?;
                    scene.apply(spp, size);
                    Ok(Arc::new(scene))
                })
                .await
                .unwrap_or_else(|e| Err(format!("scene loading panicked: {e}")))
            }
        };
        if let Err(e) = &parsed {
            warn!(job, "scene refused: {e}");
        }
        self.scenes.insert(job, (js.scene_hash, parsed));
        self.order.push_back(job);
        while self.order.len() > SCENE_CACHE {
            if let Some(old) = self.order.pop_front() {
                self.scenes.remove(&old);
            }
        }
    }

    /// The scene and pixels of a batch, checked against each other.
    fn prepare(&self, b: &pb::Batch) -> Result<(Arc<Scene>, Vec<UVec2>), String> {
        let (hash, scene) =
            self.scenes.get(&b.job_id).ok_or_else(|| format!("no scene received for job {}", b.job_id))?;
        if *hash != b.scene_hash {
            return Err(format!("batch names scene {}, but job {} has scene {hash}", b.scene_hash, b.job_id));
        }
        let scene = scene.clone()?;
        if !b.pixels.len().is_multiple_of(2) {
            return Err("pixel list has an odd number of coordinates".into());
        }
        if b.sample_start >= b.sample_end || b.sample_end > crate::scene::limits::MAX_SPP {
            return Err(format!("bad sample range {}..{}", b.sample_start, b.sample_end));
        }
        let pixels: Vec<UVec2> = b.pixels.chunks_exact(2).map(|p| UVec2::new(p[0], p[1])).collect();
        if let Some(p) = pixels.iter().find(|p| p.x >= scene.width || p.y >= scene.height) {
            return Err(format!(
                "pixel {},{} is outside the {}x{} image",
                p.x, p.y, scene.width, scene.height
            ));
        }
        Ok((scene, pixels))
    }
}
