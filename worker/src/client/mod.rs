//! The worker's side of the farm: connect to a coordinator, announce the threads, take
//! batches, render them on a pool of threads, and stream back per-pixel sums. The only
//! module of this crate that touches prost types.

mod failure;
mod pool;
mod preload;
mod scenes;

use std::future::Future;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use tessera_proto::connect::{Backoff, ConnectError, EndpointConfig};
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_message::Msg as In;
use tessera_proto::v1::worker_message::Msg as Out;
use tokio::sync::{mpsc, watch};
use tokio_stream::wrappers::ReceiverStream;
use tracing::{debug, info, warn};

use failure::Failure;
use pool::{Pool, Task};
use preload::Preload;
use scenes::SceneCache;

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
    /// The memory this worker may give one scene, in bytes: a scene whose estimate exceeds
    /// it is refused (`BatchFailed.scene_refused`) before anything is built, and the farm
    /// sends its job to other workers.
    pub memory: u64,
    /// A scene to build at start, before any job asks for it (`preload.rs`); jobs of the
    /// same content then start without building it.
    pub preload: Option<Arc<tessera_description::Bundle>>,
}

enum SessionEnd {
    /// The coordinator closed the stream.
    Closed,
    /// Told to stop: the worker said goodbye (ended its stream) and is leaving.
    Stopped,
}

/// How long a stopping worker waits for the coordinator to see its stream end; past it the
/// worker leaves anyway (the connection's close tells the coordinator the same, later).
const LEAVE_WAIT: Duration = Duration::from_secs(2);

/// Runs a worker until `stop` completes (SIGTERM, say: a scheduler ending the job), the
/// coordinator refuses it, or (with `exit_on_disconnect`) the coordinator goes away. A
/// coordinator that cannot be reached at start is an error; one lost later is retried with
/// backoff.
///
/// On `stop` the worker ends its work stream at once instead of finishing the batches in
/// hand, waits (briefly) for the coordinator to close its side, and returns: the
/// coordinator sees a goodbye (`worker left (closed)`), not a lost connection, and leases
/// the batches to others right away. The process then exits 0, which is what schedulers
/// (Slurm's scancel, systemd, Kubernetes) expect of a SIGTERM.
pub async fn run(
    mut config: WorkerConfig,
    stop: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ConnectError> {
    // The pool that builds scenes (BVH subtrees, OBJ chunks) is made here, with names of
    // its own: made lazily, its threads would take the name of the thread that first used
    // it (`preload`, or a tokio worker's), which is what `top -H` and profilers would show.
    // An error means a pool exists already (an embedding program made one): it is used.
    let _ = rayon::ThreadPoolBuilder::new().thread_name(|i| format!("build-{i}")).build_global();
    let (stop_tx, mut stopping) = watch::channel(false);
    tokio::spawn(async move {
        stop.await;
        let _ = stop_tx.send(true);
    });
    // A worker sits on one long stream: pings notice a coordinator that vanished silently.
    let endpoint = config.coordinator.clone().keep_alive(Duration::from_secs(10), Duration::from_secs(20));
    let pool = Pool::new(config.threads.max(1));
    let mut connected_once = false;
    let mut backoff = Backoff::new(Duration::from_millis(250), Duration::from_secs(15));
    // Built while the worker connects; a session that reconnects finds it if no job took it.
    // Taken out of the config: the bundle's bytes are not kept once the build has them.
    let preload = config.preload.take().map(|b| Preload::start(b, config.memory));
    loop {
        let mut welcomed = false;
        let result = session(&endpoint, &config, &pool, &preload, &mut welcomed, &mut stopping).await;
        pool.generation.fetch_add(1, Ordering::Relaxed);
        if welcomed {
            connected_once = true;
            backoff.reset();
        }
        let reason = match result {
            Ok(SessionEnd::Stopped) => return Ok(()),
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
        tokio::select! {
            _ = tokio::time::sleep(wait) => {}
            _ = stopped(&mut stopping) => {
                info!("stopping while disconnected");
                return Ok(());
            }
        }
    }
}

/// Completes once the worker is told to stop (at once if it was already).
async fn stopped(stopping: &mut watch::Receiver<bool>) {
    // An error means the sender is gone, and with it any stop: wait forever.
    if stopping.wait_for(|s| *s).await.is_err() {
        std::future::pending::<()>().await;
    }
}

/// One connection, from Hello to its end; sets `welcomed` once the coordinator accepted it.
async fn session(
    endpoint: &EndpointConfig,
    config: &WorkerConfig,
    pool: &Pool,
    preload: &Option<Preload>,
    welcomed: &mut bool,
    stopping: &mut watch::Receiver<bool>,
) -> Result<SessionEnd, ConnectError> {
    let url = &endpoint.url;
    let mut client = tokio::select! {
        c = tessera_proto::connect::worker_client(endpoint) => c?,
        _ = stopped(stopping) => return Ok(SessionEnd::Stopped),
    };
    let (out, out_rx) = mpsc::channel::<pb::WorkerMessage>(64);
    let threads = config.threads.max(1) as u32;
    let hello = pb::Hello {
        protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
        renderer_version: crate::RENDERER_VERSION.to_string(),
        name: config.name.clone(),
        threads,
        credit: threads * CREDIT_PER_THREAD,
        frames: true,
        held_scenes: preload.iter().map(|p| p.hash().to_owned()).collect(),
    };
    out.send(pb::WorkerMessage { msg: Some(Out::Hello(hello)) }).await.expect("receiver is alive");
    let opened = tokio::select! {
        r = client.work(ReceiverStream::new(out_rx)) => r,
        _ = stopped(stopping) => return Ok(SessionEnd::Stopped),
    };
    let mut inbound = opened.map_err(|s| ConnectError::from_call(url, &s))?.into_inner();
    let first = tokio::select! {
        m = inbound.message() => m,
        _ = stopped(stopping) => return Ok(SessionEnd::Stopped),
    };
    let heartbeat = match first {
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
    let mut scenes = SceneCache::new(config.memory, preload.clone());
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
                    Some(In::Batch(b)) => match scenes.prepare_frame(&b).await {
                        Ok((scene, pixels)) => {
                            let task = Task { generation, scene, batch: b, pixels, reply: reply.clone() };
                            pool.tasks.send(task).expect("render threads live as long as the process");
                        }
                        Err(Failure { message, scene_refused }) => {
                            warn!(job = b.job_id, batch = b.batch_id, scene_refused, "cannot render batch: {message}");
                            let failed = pb::BatchFailed {
                                job_id: b.job_id,
                                batch_id: b.batch_id,
                                attempt: b.attempt,
                                error: message,
                                credit: 1,
                                lease: b.lease.clone(),
                                scene_refused,
                            };
                            send(&out, Out::Failed(failed)).await?;
                        }
                    },
                    Some(In::Refused(r)) => return Err(ConnectError::Refused(r.reason)),
                    Some(In::Welcome(_)) | None => debug!("ignored an unexpected message"),
                }
            }
            Some(first) = done.recv() => {
                let mut results = vec![first];
                while results.len() < tessera_proto::MAX_RESULTS_PER_MESSAGE {
                    let Ok(r) = done.try_recv() else { break };
                    results.push(r);
                }
                let credit = results.len() as u32;
                send(&out, Out::Results(pb::Results { results, credit })).await?;
                tick.reset();
            }
            _ = tick.tick() => send(&out, Out::Heartbeat(pb::Heartbeat {})).await?,
            _ = stopped(stopping) => {
                // Batches queued for the render threads are dropped, not rendered.
                pool.generation.fetch_add(1, Ordering::Relaxed);
                info!("stopping: ending the work stream; the coordinator takes back the batches in hand");
                drop(out);
                // The coordinator answers the end of our stream by ending its own once it
                // has taken the leases back; wait for that, briefly.
                let drained = tokio::time::timeout(LEAVE_WAIT, async {
                    while let Ok(Some(_)) = inbound.message().await {}
                })
                .await;
                if drained.is_err() {
                    warn!("the coordinator did not close the stream within {LEAVE_WAIT:?}; leaving anyway");
                }
                return Ok(SessionEnd::Stopped);
            }
        }
    }
}

async fn send(out: &mpsc::Sender<pb::WorkerMessage>, msg: Out) -> Result<(), ConnectError> {
    out.send(pb::WorkerMessage { msg: Some(msg) })
        .await
        .map_err(|_| ConnectError::Lost("the outbound stream closed".into()))
}
