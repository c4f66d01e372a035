//! The viewer's connection: one watch stream, turned into updates; the errors a person can
//! act on.

use std::time::Duration;

use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_client::CoordinatorClient;
use tonic::transport::{Channel, Endpoint};

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

/// An open watch stream.
pub struct Watch {
    stream: tonic::Streaming<pb::FramebufferUpdate>,
}

/// The largest update message accepted.
const MAX_MESSAGE_BYTES: usize = 64 << 20;

impl Watch {
    /// Opens a watch on `job` (0: the running job, else the newest) at `url`.
    pub async fn open(url: &str, job: u64, max_rate: f64) -> Result<Watch, ConnError> {
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
        Ok(Watch { stream })
    }

    /// The next update; `None` when the coordinator ended the stream.
    pub async fn next(&mut self) -> Result<Option<pb::FramebufferUpdate>, ConnError> {
        self.stream.message().await.map_err(|s| ConnError::Lost(s.message().to_string()))
    }
}
