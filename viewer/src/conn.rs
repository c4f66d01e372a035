//! The viewer's connection: one watch stream, turned into updates, reopened when the
//! coordinator goes away. Its errors are the client side's `ConnectError`.

use std::time::Duration;

use tessera_description::ids::JobId;
use tessera_proto::connect::{Backoff, ConnectError, EndpointConfig};
use tessera_proto::convert::job_to_wire;
use tessera_proto::v1 as pb;
use tracing::{info, warn};

/// How long a viewer keeps trying to reconnect to a lost coordinator by default: long
/// enough for a coordinator to be restarted on its data directory.
pub const RECONNECT_FOR: Duration = Duration::from_secs(60);

/// An open watch stream, reopened with backoff when the coordinator goes away.
pub struct Watch {
    stream: tonic::Streaming<pb::FramebufferUpdate>,
    endpoint: EndpointConfig,
    job: Option<JobId>,
    /// The frame of a sequence watched (`None`: its first).
    frame: Option<u32>,
    max_rate: f64,
    reconnect_for: Duration,
}

/// The largest update message accepted.
const MAX_MESSAGE_BYTES: usize = 64 << 20;

impl Watch {
    /// Opens a watch on `job` (`None`: the running job, else the newest) at `endpoint`.
    /// Should the stream break, `next` reconnects for up to `reconnect_for` (zero: not at
    /// all).
    pub async fn open(
        endpoint: &EndpointConfig,
        job: Option<JobId>,
        max_rate: f64,
        reconnect_for: Duration,
    ) -> Result<Watch, ConnectError> {
        Self::open_frame(endpoint, job, None, max_rate, reconnect_for).await
    }

    /// As `open`, watching frame `frame` of a sequence (`None`: its first).
    pub async fn open_frame(
        endpoint: &EndpointConfig,
        job: Option<JobId>,
        frame: Option<u32>,
        max_rate: f64,
        reconnect_for: Duration,
    ) -> Result<Watch, ConnectError> {
        let endpoint = endpoint.clone().max_message_bytes(MAX_MESSAGE_BYTES);
        let stream = Self::stream(&endpoint, job, frame, max_rate).await?;
        Ok(Watch { stream, endpoint, job, frame, max_rate, reconnect_for })
    }

    async fn stream(
        endpoint: &EndpointConfig,
        job: Option<JobId>,
        frame: Option<u32>,
        max_rate: f64,
    ) -> Result<tonic::Streaming<pb::FramebufferUpdate>, ConnectError> {
        let mut client = tessera_proto::connect::client(endpoint).await?;
        let stream = client
            .watch(pb::WatchRequest {
                job_id: job_to_wire(job),
                max_rate,
                protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
                frame,
                // Display values while the job renders, the exact state at its end.
                previews: true,
            })
            .await
            .map_err(|s| ConnectError::Refused(s.message().to_string()))?
            .into_inner();
        Ok(stream)
    }

    /// The next update; `None` when the coordinator ended the stream. A broken stream is
    /// reopened on the same job with backoff; the first update after that has `reset` set.
    pub async fn next(&mut self) -> Result<Option<pb::FramebufferUpdate>, ConnectError> {
        let lost = match self.stream.message().await {
            Ok(Some(u)) => {
                // Reopen on the job being shown, not whichever is running by then.
                self.job = Some(JobId(u.job_id));
                return Ok(Some(u));
            }
            Ok(None) => return Ok(None),
            Err(s) => s.message().to_string(),
        };
        let deadline = tokio::time::Instant::now() + self.reconnect_for;
        let mut backoff = Backoff::new(Duration::from_millis(250), Duration::from_secs(5));
        loop {
            let now = tokio::time::Instant::now();
            if now >= deadline {
                return Err(ConnectError::Lost(if self.reconnect_for.is_zero() {
                    lost
                } else {
                    format!("{lost}; gave up reconnecting after {:?}", self.reconnect_for)
                }));
            }
            let delay = backoff.next_delay();
            warn!("lost the coordinator ({lost}); reconnecting in {delay:?}");
            tokio::time::sleep(delay.min(deadline - now)).await;
            match Self::stream(&self.endpoint, self.job, self.frame, self.max_rate).await {
                Ok(stream) => {
                    info!(job = job_to_wire(self.job), "reconnected to the coordinator");
                    self.stream = stream;
                    return Box::pin(self.next()).await;
                }
                // It answers but will not show this job (restarted without its data).
                Err(ConnectError::Refused(m)) => {
                    return Err(ConnectError::Lost(format!("{lost}; after reconnecting: {m}")))
                }
                Err(_) => {}
            }
        }
    }
}
