//! The viewer's connection: one watch stream, turned into updates; the errors a person can
//! act on.

use std::time::Duration;

use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_client::CoordinatorClient;
use tonic::transport::{Channel, Endpoint};
use tracing::{info, warn};

/// Why the viewer could not (or can no longer) watch.
#[derive(Debug, thiserror::Error)]
pub enum ConnError {
    /// The URL is not usable.
    #[error("bad coordinator address {url:?}: {reason}")]
    BadAddress {
        /// The URL.
        url: String,
        /// Why.
        reason: String,
    },
    /// Nothing answers there.
    #[error("cannot reach coordinator at {url}: {reason}")]
    Unreachable {
        /// The URL.
        url: String,
        /// Why.
        reason: String,
    },
    /// The coordinator refused (no such job, …).
    #[error("{0}")]
    Refused(String),
    /// The stream broke mid-job.
    #[error("lost the coordinator: {0}")]
    Lost(String),
}

/// How long a viewer keeps trying to reconnect to a lost coordinator by default: long
/// enough for a coordinator to be restarted on its data directory.
pub const RECONNECT_FOR: Duration = Duration::from_secs(60);

/// An open watch stream, reopened with backoff when the coordinator goes away.
pub struct Watch {
    stream: tonic::Streaming<pb::FramebufferUpdate>,
    url: String,
    job: u64,
    max_rate: f64,
    reconnect_for: Duration,
}

/// The largest update message accepted.
const MAX_MESSAGE_BYTES: usize = 64 << 20;

impl Watch {
    /// Opens a watch on `job` (0: the running job, else the newest) at `url`. Should the
    /// stream break, `next` reconnects for up to `reconnect_for` (zero: not at all).
    pub async fn open(
        url: &str,
        job: u64,
        max_rate: f64,
        reconnect_for: Duration,
    ) -> Result<Watch, ConnError> {
        let stream = Self::stream(url, job, max_rate).await?;
        Ok(Watch { stream, url: url.to_string(), job, max_rate, reconnect_for })
    }

    async fn stream(
        url: &str,
        job: u64,
        max_rate: f64,
    ) -> Result<tonic::Streaming<pb::FramebufferUpdate>, ConnError> {
        let endpoint = Endpoint::from_shared(url.to_string())
            .map_err(|e| ConnError::BadAddress { url: url.into(), reason: e.to_string() })?
            .connect_timeout(Duration::from_secs(5));
        let channel: Channel = endpoint.connect().await.map_err(|e| ConnError::Unreachable {
            url: url.into(),
            reason: tessera_worker::client::error_chain(&e),
        })?;
        let mut client = CoordinatorClient::new(channel).max_decoding_message_size(MAX_MESSAGE_BYTES);
        let stream = client
            .watch(pb::WatchRequest { job_id: job, max_rate })
            .await
            .map_err(|s| ConnError::Refused(s.message().to_string()))?
            .into_inner();
        Ok(stream)
    }

    /// The next update; `None` when the coordinator ended the stream. A broken stream is
    /// reopened on the same job with backoff; the first update after that has `reset` set.
    pub async fn next(&mut self) -> Result<Option<pb::FramebufferUpdate>, ConnError> {
        let lost = match self.stream.message().await {
            Ok(Some(u)) => {
                self.job = u.job_id;
                return Ok(Some(u));
            }
            Ok(None) => return Ok(None),
            Err(s) => s.message().to_string(),
        };
        let deadline = tokio::time::Instant::now() + self.reconnect_for;
        let mut delay = Duration::from_millis(250);
        loop {
            let now = tokio::time::Instant::now();
            if now >= deadline {
                return Err(ConnError::Lost(if self.reconnect_for.is_zero() {
                    lost
                } else {
                    format!("{lost}; gave up reconnecting after {:?}", self.reconnect_for)
                }));
            }
            warn!("lost the coordinator ({lost}); reconnecting in {delay:?}");
            tokio::time::sleep(delay.min(deadline - now)).await;
            match Self::stream(&self.url, self.job, self.max_rate).await {
                Ok(stream) => {
                    info!(job = self.job, "reconnected to the coordinator");
                    self.stream = stream;
                    return Box::pin(self.next()).await;
                }
                // It answers but will not show this job (restarted without its data).
                Err(ConnError::Refused(m)) => {
                    return Err(ConnError::Lost(format!("{lost}; after reconnecting: {m}")))
                }
                Err(_) => delay = (delay * 2).min(Duration::from_secs(5)),
            }
        }
    }
}
