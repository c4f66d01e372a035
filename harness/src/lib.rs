//! An in-process Tessera farm for tests and benchmarks: a real `CoordinatorService` served
//! with tonic on loopback, fake workers that answer batches with valid sums without
//! rendering, fake viewers that keep a framebuffer replica, and typed helpers for the
//! client calls. Service behaviour (leases, failures, viewers) can then be tested without
//! spawning processes or parsing the status table.
//!
//! It uses the coordinator only through `CoordinatorService::new`, `Timing`,
//! `into_server`, `spawn_reaper` and the gRPC surface, so that it keeps working while the
//! coordinator's internals change.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

mod viewer;
mod worker;

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tessera_coordinator::{Auth, CoordinatorService, Timing};
use tessera_description::ids::{JobId, WorkerId};
use tessera_description::job::JobProgress;
pub use tessera_proto::connect::Channel;
use tessera_proto::connect::{ConnectError, EndpointConfig, MAX_MESSAGE_BYTES};
use tessera_proto::convert::status_from_wire;
use tessera_proto::credentials::{ClientTls, ServerTls, Token};
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_client::CoordinatorClient;
use tessera_proto::v1::workers_client::WorkersClient;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

pub use viewer::FakeViewer;
pub use worker::{pixel_value, valid_result, FakeWorker, ServeStats, REFERENCE_BATCH_SAMPLES};

/// The small end-to-end test scene (64×48, 4 spp); sizes are usually overridden.
pub const SMALL_SCENE: &str = include_str!("../../tests/scenes/small.toml");

/// How long a harness call waits for the coordinator before it reports a timeout, so that
/// a broken service fails a test instead of hanging it.
pub const PATIENCE: Duration = Duration::from_secs(20);

/// A gRPC client of the coordinator.
pub type Client = CoordinatorClient<Channel>;

/// What went wrong talking to the coordinator.
#[derive(Debug, thiserror::Error)]
pub enum HarnessError {
    /// The coordinator could not be reached.
    #[error(transparent)]
    Connect(#[from] ConnectError),
    /// A call returned an error status.
    #[error("call failed: {0}")]
    Status(Box<tonic::Status>),
    /// The coordinator refused a worker, with its reason.
    #[error("refused by the coordinator: {0}")]
    Refused(String),
    /// The coordinator closed a stream.
    #[error("the coordinator closed the stream")]
    Closed,
    /// Nothing came in time.
    #[error("timed out waiting for {0}")]
    Timeout(String),
    /// The coordinator sent something the protocol does not allow here.
    #[error("protocol: {0}")]
    Protocol(String),
    /// A socket could not be opened.
    #[error("io: {0}")]
    Io(#[from] std::io::Error),
}

impl From<tonic::Status> for HarnessError {
    fn from(s: tonic::Status) -> Self {
        // Boxed: a `Status` is large, and every `Result` of this crate would carry its size.
        HarnessError::Status(Box::new(s))
    }
}

/// Results of this crate.
pub type Result<T, E = HarnessError> = std::result::Result<T, E>;

/// A worker as `Status` reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WorkerView {
    /// The worker.
    pub id: WorkerId,
    /// Its name.
    pub name: String,
    /// Batches leased to it now.
    pub in_flight: u32,
    /// Batches it returned that were merged.
    pub batches_done: u64,
}

/// The answer to `Status`, typed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FarmStatus {
    /// Jobs.
    pub jobs: Vec<JobProgress>,
    /// Connected workers.
    pub workers: Vec<WorkerView>,
}

impl FarmStatus {
    /// The worker with this id, if connected.
    pub fn worker(&self, id: WorkerId) -> Option<&WorkerView> {
        self.workers.iter().find(|w| w.id == id)
    }
}

/// A job's image as `FetchImage` streams it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Linear RGB f32 little-endian, top row first, exactly as it travelled.
    pub bytes: Vec<u8>,
}

/// A channel to the coordinator at `url` (e.g. `http://127.0.0.1:7878`), as every client
/// of the project connects.
pub async fn connect(url: &str) -> Result<Channel> {
    connect_with(&EndpointConfig::new(url)?).await
}

/// A channel to the coordinator `config` describes (TLS, token).
pub async fn connect_with(config: &EndpointConfig) -> Result<Channel> {
    Ok(tessera_proto::connect::connect(config).await?)
}

/// A client on `channel`, with the coordinator's message limits.
pub fn client(channel: &Channel) -> Client {
    CoordinatorClient::new(channel.clone())
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES)
}

/// A worker's client on `channel` (the `Workers` service), with the coordinator's message
/// limits.
pub fn worker_client(channel: &Channel) -> WorkersClient<Channel> {
    WorkersClient::new(channel.clone())
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES)
}

/// Submits the scene `text` (named `name`) with `settings`; returns the job.
pub async fn submit(
    channel: &Channel,
    name: &str,
    text: &str,
    settings: pb::RenderSettings,
) -> Result<JobId> {
    let request = pb::SubmitRequest {
        protocol_version: pb::ProtocolVersion::Current as i32,
        bundle: Some(pb::SceneBundle { name: name.into(), text: text.into(), assets: vec![] }),
        settings: Some(settings),
        priority: 0,
    };
    Ok(JobId(client(channel).submit(request).await?.into_inner().job_id))
}

/// The coordinator's jobs and workers.
pub async fn status(channel: &Channel) -> Result<FarmStatus> {
    let s = client(channel).status(pb::StatusRequest { job_id: 0 }).await?.into_inner();
    let jobs = s
        .jobs
        .into_iter()
        .map(|j| status_from_wire(j).map_err(|e| HarnessError::Protocol(e.to_string())))
        .collect::<Result<_>>()?;
    let workers = s
        .workers
        .into_iter()
        .map(|w| WorkerView {
            id: WorkerId(w.worker_id),
            name: w.name,
            in_flight: w.batches_in_flight,
            batches_done: w.batches_done,
        })
        .collect();
    Ok(FarmStatus { jobs, workers })
}

/// One job's status.
pub async fn job(channel: &Channel, id: JobId) -> Result<JobProgress> {
    status(channel)
        .await?
        .jobs
        .into_iter()
        .find(|j| j.id == id)
        .ok_or_else(|| HarnessError::Protocol(format!("{id} missing from Status")))
}

/// Polls the job's status until `done` holds of it, for at most `limit`.
pub async fn wait_for(
    channel: &Channel,
    id: JobId,
    limit: Duration,
    mut done: impl FnMut(&JobProgress) -> bool,
) -> Result<JobProgress> {
    let start = Instant::now();
    loop {
        let j = job(channel, id).await?;
        if done(&j) {
            return Ok(j);
        }
        if start.elapsed() > limit {
            return Err(HarnessError::Timeout(format!(
                "{id} (last seen {:?}, {} samples)",
                j.state, j.samples_done
            )));
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// A job's current image.
pub async fn fetch_image(channel: &Channel, id: JobId) -> Result<Image> {
    fetch_frame_image(channel, id, None).await
}

/// The current image of frame `frame` of a sequence (`None`: its first).
pub async fn fetch_frame_image(channel: &Channel, id: JobId, frame: Option<u32>) -> Result<Image> {
    let request = pb::FetchImageRequest { job_id: id.0, frame, ..Default::default() };
    let mut stream = client(channel).fetch_image(request).await?.into_inner();
    let mut image = Image { width: 0, height: 0, bytes: Vec::new() };
    while let Some(chunk) = stream.message().await? {
        image.width = chunk.width;
        image.height = chunk.height;
        image.bytes.extend_from_slice(&chunk.rgb);
    }
    Ok(image)
}

/// Pauses (`true`) or resumes (`false`) a job.
pub async fn pause(channel: &Channel, id: JobId, paused: bool) -> Result<()> {
    client(channel).pause(pb::PauseRequest { job_id: id.0, paused }).await?;
    Ok(())
}

/// How a harness's coordinator is secured, and how the harness's own channel reaches it.
#[derive(Debug, Clone, Default)]
pub struct Security {
    /// Who the coordinator lets in.
    pub auth: Auth,
    /// Its TLS (then the URL is `https://HOST:PORT`).
    pub tls: Option<ServerTls>,
    /// What the harness's clients trust and show over TLS (the CA of `tls`).
    pub client_tls: ClientTls,
    /// The token of the harness's own channel.
    pub token: Option<Token>,
    /// The host in the URL, a name `tls`'s certificate holds [default: 127.0.0.1].
    pub host: Option<String>,
}

/// A coordinator service served in this process on 127.0.0.1, with its reaper running;
/// stopped when dropped.
pub struct Harness {
    /// Its URL, for clients that want one.
    pub url: String,
    /// Its address.
    pub addr: SocketAddr,
    endpoint: EndpointConfig,
    channel: Channel,
    service: CoordinatorService,
    shutdown: Option<oneshot::Sender<()>>,
    server: JoinHandle<()>,
    reaper: JoinHandle<()>,
}

impl Harness {
    /// A coordinator with the default timing.
    pub async fn start() -> Result<Harness> {
        Harness::start_with(Timing::default()).await
    }

    /// A coordinator with `timing` (short timeouts make lease expiry testable in seconds).
    pub async fn start_with(timing: Timing) -> Result<Harness> {
        Harness::start_secured(timing, Security::default()).await
    }

    /// A coordinator with `timing`, secured as `security` says.
    pub async fn start_secured(timing: Timing, security: Security) -> Result<Harness> {
        let service = CoordinatorService::new(timing).with_auth(security.auth);
        let reaper = service.spawn_reaper();
        let handle = service.clone();
        // Loopback TCP rather than an in-memory pipe: the same transport as production,
        // and the coordinator sees real connection ends when a fake worker drops.
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let addr = listener.local_addr()?;
        let (shutdown, stop) = oneshot::channel::<()>();
        let mut builder = tessera_coordinator::service::server();
        if let Some(tls) = &security.tls {
            builder = builder
                .tls_config(tls.config())
                .map_err(|e| HarnessError::Protocol(format!("the TLS configuration: {e}")))?;
        }
        let server = tokio::spawn(async move {
            let _ = builder
                .add_routes(service.into_server())
                .serve_with_incoming_shutdown(tessera_coordinator::service::incoming(listener), async {
                    let _ = stop.await;
                })
                .await;
        });
        let host = security.host.unwrap_or_else(|| addr.ip().to_string());
        let scheme = if security.tls.is_some() { "https" } else { "http" };
        let url = format!("{scheme}://{host}:{}", addr.port());
        let endpoint = EndpointConfig::new(&url)?.tls(security.client_tls)?.token(security.token);
        let channel = connect_with(&endpoint).await?;
        Ok(Harness {
            url,
            addr,
            endpoint,
            channel,
            service: handle,
            shutdown: Some(shutdown),
            server,
            reaper,
        })
    }

    /// How to reach it (its URL and TLS) with no token.
    pub fn endpoint(&self) -> EndpointConfig {
        self.endpoint.clone().token(None)
    }

    /// A fresh connection of its own that sends `token`.
    pub async fn channel_with(&self, token: Option<Token>) -> Result<Channel> {
        connect_with(&self.endpoint.clone().token(token)).await
    }

    /// The service itself, for what only the coordinator can see (how viewers were fed).
    pub fn service(&self) -> &CoordinatorService {
        &self.service
    }

    /// A channel to it (cheap to clone; one HTTP/2 connection).
    pub fn channel(&self) -> Channel {
        self.channel.clone()
    }

    /// A fresh connection of its own, as a separate process would have (with the harness's
    /// token).
    pub async fn new_channel(&self) -> Result<Channel> {
        connect_with(&self.endpoint).await
    }

    /// Submits the small test scene at `width`×`height` and `spp`.
    pub async fn submit_small(&self, width: u32, height: u32, spp: u32) -> Result<JobId> {
        let settings = pb::RenderSettings { spp, width, height, ..Default::default() };
        submit(&self.channel, "small.toml", SMALL_SCENE, settings).await
    }

    /// The coordinator's jobs and workers.
    pub async fn status(&self) -> Result<FarmStatus> {
        status(&self.channel).await
    }

    /// One job's status.
    pub async fn job(&self, id: JobId) -> Result<JobProgress> {
        job(&self.channel, id).await
    }

    /// Waits (at most `PATIENCE`) until the job is over: done, cancelled or failed.
    pub async fn wait_over(&self, id: JobId) -> Result<JobProgress> {
        wait_for(&self.channel, id, PATIENCE, |j| j.state.is_over()).await
    }

    /// A job's current image.
    pub async fn fetch_image(&self, id: JobId) -> Result<Image> {
        fetch_image(&self.channel, id).await
    }

    /// Pauses (`true`) or resumes (`false`) a job.
    pub async fn pause(&self, id: JobId, paused: bool) -> Result<()> {
        pause(&self.channel, id, paused).await
    }
}

impl Drop for Harness {
    fn drop(&mut self) {
        if let Some(s) = self.shutdown.take() {
            let _ = s.send(());
        }
        // Streams still open would keep a graceful shutdown waiting; nothing of a test
        // outlives its harness.
        self.server.abort();
        self.reaper.abort();
    }
}
