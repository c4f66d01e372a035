//! The client side's connection to a coordinator, shared by the worker, the viewer and the
//! CLI: where it is (`EndpointConfig`), opening a channel to it (`connect`, `client`), what
//! can go wrong (`ConnectError`) and how long to wait before trying again (`Backoff`).
//!
//! Only `http://` is spoken today. An `https://` URL is refused rather than silently sent
//! in plain text; TLS settings will be further fields of `EndpointConfig` with builder
//! methods, so callers that build one with `EndpointConfig::new` keep compiling.

use std::time::Duration;

use tonic::codegen::http::Uri;
use tonic::transport::{Channel, Endpoint};

use crate::v1::coordinator_client::CoordinatorClient;
use crate::v1::workers_client::WorkersClient;

/// The largest message a client sends or accepts by default: scene bundles with their
/// assets travel whole (`limits::MAX_BUNDLE_BYTES`, and a little for the rest).
pub const MAX_MESSAGE_BYTES: usize = (tessera_description::limits::MAX_BUNDLE_BYTES
    + tessera_description::limits::BUNDLE_MESSAGE_SLACK) as usize;

/// Why a client could not reach the coordinator, or lost it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConnectError {
    /// The URL is not usable.
    #[error("bad coordinator address {url:?}: {reason}")]
    BadAddress {
        /// The URL as given.
        url: String,
        /// Why.
        reason: String,
    },
    /// The URL asks for TLS, which this build cannot speak yet.
    #[error(
        "bad coordinator address {url:?}: TLS (https://) is not supported yet; use http:// on a \
         trusted network or through a tunnel"
    )]
    TlsUnsupported {
        /// The URL as given.
        url: String,
    },
    /// Nothing answers there.
    #[error("cannot reach coordinator at {url}: {reason}")]
    Unreachable {
        /// The URL.
        url: String,
        /// Why, with its causes.
        reason: String,
    },
    /// The coordinator answered but refused the request (no such job, a version mismatch, …).
    #[error("the coordinator refused: {0}")]
    Refused(String),
    /// The connection broke after it was made.
    #[error("lost the coordinator: {0}")]
    Lost(String),
}

/// HTTP/2 keep-alive pings, so that a silent peer is noticed on an idle connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KeepAlive {
    /// Time between pings.
    pub interval: Duration,
    /// How long a ping may go unanswered before the connection is dropped.
    pub timeout: Duration,
}

/// Where a coordinator is and how to connect to it. Built with [`EndpointConfig::new`] and
/// the builder methods; non-exhaustive so that TLS settings can join without changing callers.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct EndpointConfig {
    /// The coordinator's URL, e.g. `http://10.0.0.1:7878`.
    pub url: String,
    /// How long opening the connection may take.
    pub connect_timeout: Duration,
    /// Keep-alive pings, if any.
    pub keep_alive: Option<KeepAlive>,
    /// The largest message sent or accepted.
    pub max_message_bytes: usize,
}

impl EndpointConfig {
    /// Checks `url` (`http://HOST:PORT`) and gives it the default timeout (5 s), no
    /// keep-alive and [`MAX_MESSAGE_BYTES`].
    pub fn new(url: &str) -> Result<EndpointConfig, ConnectError> {
        let bad =
            |reason: &str| ConnectError::BadAddress { url: url.to_string(), reason: reason.to_string() };
        let uri: Uri = url.parse().map_err(|e: tonic::codegen::http::uri::InvalidUri| bad(&e.to_string()))?;
        match uri.scheme_str() {
            Some("http") => {}
            Some("https") => return Err(ConnectError::TlsUnsupported { url: url.to_string() }),
            Some(other) => return Err(bad(&format!("unknown scheme {other:?}; expected http://HOST:PORT"))),
            None => return Err(bad("no scheme; expected http://HOST:PORT")),
        }
        if uri.host().is_none_or(str::is_empty) {
            return Err(bad("no host; expected http://HOST:PORT"));
        }
        Ok(EndpointConfig {
            url: url.to_string(),
            connect_timeout: Duration::from_secs(5),
            keep_alive: None,
            max_message_bytes: MAX_MESSAGE_BYTES,
        })
    }

    /// With another connect timeout.
    pub fn connect_timeout(mut self, timeout: Duration) -> Self {
        self.connect_timeout = timeout;
        self
    }

    /// With keep-alive pings every `interval`, dropping the connection after `timeout`
    /// without an answer.
    pub fn keep_alive(mut self, interval: Duration, timeout: Duration) -> Self {
        self.keep_alive = Some(KeepAlive { interval, timeout });
        self
    }

    /// With another message size limit.
    pub fn max_message_bytes(mut self, bytes: usize) -> Self {
        self.max_message_bytes = bytes;
        self
    }

    fn endpoint(&self) -> Result<Endpoint, ConnectError> {
        let endpoint = Endpoint::from_shared(self.url.clone())
            .map_err(|e| ConnectError::BadAddress { url: self.url.clone(), reason: error_chain(&e) })?
            .connect_timeout(self.connect_timeout)
            .tcp_nodelay(true);
        Ok(match self.keep_alive {
            Some(k) => endpoint.http2_keep_alive_interval(k.interval).keep_alive_timeout(k.timeout),
            None => endpoint,
        })
    }
}

/// Opens a channel to the coordinator.
pub async fn connect(config: &EndpointConfig) -> Result<Channel, ConnectError> {
    config
        .endpoint()?
        .connect()
        .await
        .map_err(|e| ConnectError::Unreachable { url: config.url.clone(), reason: error_chain(&e) })
}

/// A coordinator client over a new channel, with the configured message size limit both ways.
pub async fn client(config: &EndpointConfig) -> Result<CoordinatorClient<Channel>, ConnectError> {
    Ok(CoordinatorClient::new(connect(config).await?)
        .max_decoding_message_size(config.max_message_bytes)
        .max_encoding_message_size(config.max_message_bytes))
}

/// A worker's client of the coordinator over a new channel: the `Workers` service, whose
/// scenes arrive with the configured message size limit (the coordinator decodes worker
/// messages only up to the largest legal one).
pub async fn worker_client(config: &EndpointConfig) -> Result<WorkersClient<Channel>, ConnectError> {
    Ok(WorkersClient::new(connect(config).await?)
        .max_decoding_message_size(config.max_message_bytes)
        .max_encoding_message_size(config.max_message_bytes))
}

/// An error with its causes on one line, each said once (transport errors repeat their
/// sources in their own messages).
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        let text = cause.to_string();
        if !s.contains(&text) {
            s.push_str(": ");
            s.push_str(&text);
        }
        source = cause.source();
    }
    s
}

/// A capped exponential backoff for reconnecting: deterministic steps, doubling from the
/// first wait up to the cap.
#[derive(Debug, Clone)]
pub struct Backoff {
    first: Duration,
    next: Duration,
    max: Duration,
}

impl Backoff {
    /// Starts at `first`, doubles up to `max`.
    pub fn new(first: Duration, max: Duration) -> Self {
        Backoff { first, next: first.min(max), max }
    }

    /// The next wait.
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }

    /// Back to the first wait, after a connection that worked.
    pub fn reset(&mut self) {
        self.next = self.first.min(self.max);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_up_to_its_cap_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(250), Duration::from_secs(1));
        let waits: Vec<u64> = (0..5).map(|_| b.next_delay().as_millis() as u64).collect();
        assert_eq!(waits, [250, 500, 1000, 1000, 1000]);
        b.reset();
        assert_eq!(b.next_delay(), Duration::from_millis(250));
    }

    #[test]
    fn urls_are_checked() {
        let c = EndpointConfig::new("http://10.0.0.1:7878").unwrap();
        assert_eq!(
            (c.url.as_str(), c.connect_timeout, c.keep_alive),
            ("http://10.0.0.1:7878", Duration::from_secs(5), None)
        );
        for bad in ["not a url", "10.0.0.1:7878", "ftp://host:1", "http://", ""] {
            let e = EndpointConfig::new(bad).unwrap_err();
            assert!(matches!(e, ConnectError::BadAddress { .. }), "{bad}: {e:?}");
            assert!(e.to_string().contains("bad coordinator address"), "{e}");
        }
    }

    #[test]
    fn https_is_refused_not_sent_in_plain_text() {
        let e = EndpointConfig::new("https://render-host:7878").unwrap_err();
        assert_eq!(e, ConnectError::TlsUnsupported { url: "https://render-host:7878".into() });
        assert!(e.to_string().contains("TLS (https://) is not supported yet"), "{e}");
    }

    #[tokio::test]
    async fn nothing_listening_is_unreachable() {
        // A port nothing listens on: bind one, then free it.
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let c = EndpointConfig::new(&format!("http://127.0.0.1:{port}")).unwrap();
        let e = connect(&c).await.unwrap_err();
        assert!(matches!(e, ConnectError::Unreachable { .. }), "{e:?}");
        assert!(e.to_string().starts_with("cannot reach coordinator at http://127.0.0.1:"), "{e}");
    }

    #[test]
    fn error_chains_say_each_cause_once() {
        #[derive(Debug, thiserror::Error)]
        #[error("outer: inner")]
        struct Outer(#[source] Inner);
        #[derive(Debug, thiserror::Error)]
        #[error("inner")]
        struct Inner;
        #[derive(Debug, thiserror::Error)]
        #[error("wrapper")]
        struct Wrapper(#[source] Outer);
        assert_eq!(error_chain(&Outer(Inner)), "outer: inner");
        assert_eq!(error_chain(&Wrapper(Outer(Inner))), "wrapper: outer: inner");
    }
}
