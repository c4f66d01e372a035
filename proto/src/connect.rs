//! The client side's connection to a coordinator, shared by the worker, the viewer and the
//! CLI: where it is and how to reach it (`EndpointConfig`: the URL, TLS, the token),
//! opening a channel to it (`connect`, `client`), what can go wrong (`ConnectError`) and
//! how long to wait before trying again (`Backoff`).
//!
//! `http://` is plain text; `https://` is TLS (rustls), verified against a CA file or the
//! system's roots, and never falls back to plain text. A token, if any, travels as
//! `authorization: Bearer …` on every call of the channel (`Channel`), so that no caller
//! can forget it.

use std::task::{Context, Poll};
use std::time::Duration;

use tonic::codegen::http::{self, HeaderValue, Uri};
use tonic::codegen::Service;
use tonic::transport::Endpoint;

use crate::credentials::{ClientTls, CredentialError, Token};
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
    /// A certificate, key or token cannot be used.
    #[error(transparent)]
    Credentials(#[from] CredentialError),
    /// TLS settings given for an `http://` URL, which would not use them.
    #[error("TLS settings (a CA or a client certificate) given for {url}: use https:// to connect with TLS")]
    TlsForPlainText {
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

impl ConnectError {
    /// A call that failed at `url`: refused credentials (`UNAUTHENTICATED`,
    /// `PERMISSION_DENIED`) are `Refused`, which retrying does not change; anything else is
    /// `Unreachable`.
    pub fn from_call(url: &str, status: &tonic::Status) -> ConnectError {
        match status.code() {
            tonic::Code::Unauthenticated | tonic::Code::PermissionDenied => {
                ConnectError::Refused(status.message().to_string())
            }
            _ => ConnectError::Unreachable { url: url.to_string(), reason: status.message().to_string() },
        }
    }
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
/// the builder methods; non-exhaustive so that settings can join without changing callers.
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
    /// TLS, exactly when the URL is `https://`.
    pub tls: Option<ClientTls>,
    /// The bearer token sent with every call, if any.
    pub token: Option<Token>,
}

impl EndpointConfig {
    /// Checks `url` (`http://HOST:PORT`, or `https://HOST:PORT` for TLS verified against
    /// the system's roots until [`EndpointConfig::tls`] says otherwise) and gives it the
    /// default timeout (5 s), no keep-alive, [`MAX_MESSAGE_BYTES`] and no token.
    pub fn new(url: &str) -> Result<EndpointConfig, ConnectError> {
        let bad =
            |reason: &str| ConnectError::BadAddress { url: url.to_string(), reason: reason.to_string() };
        let uri: Uri = url.parse().map_err(|e: tonic::codegen::http::uri::InvalidUri| bad(&e.to_string()))?;
        let tls = match uri.scheme_str() {
            Some("http") => None,
            Some("https") => Some(ClientTls::new()),
            Some(other) => {
                return Err(bad(&format!(
                    "unknown scheme {other:?}; expected http://HOST:PORT or https://HOST:PORT"
                )))
            }
            None => return Err(bad("no scheme; expected http://HOST:PORT or https://HOST:PORT")),
        };
        if uri.host().is_none_or(str::is_empty) {
            return Err(bad("no host; expected http://HOST:PORT"));
        }
        Ok(EndpointConfig {
            url: url.to_string(),
            connect_timeout: Duration::from_secs(5),
            keep_alive: None,
            max_message_bytes: MAX_MESSAGE_BYTES,
            tls,
            token: None,
        })
    }

    /// With these TLS settings; refused for an `http://` URL unless they are the
    /// defaults, so that a CA given to a plain-text URL is not silently ignored.
    pub fn tls(mut self, tls: ClientTls) -> Result<Self, ConnectError> {
        match &mut self.tls {
            Some(t) => *t = tls,
            None if tls.is_default() => {}
            None => return Err(ConnectError::TlsForPlainText { url: self.url.clone() }),
        }
        Ok(self)
    }

    /// Sending `token` with every call.
    pub fn token(mut self, token: Option<Token>) -> Self {
        self.token = token;
        self
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
        let endpoint = match &self.tls {
            // The handshake verifies the coordinator; a failure is an error, never a
            // fallback to plain text.
            Some(tls) => endpoint.tls_config(tls.config()).map_err(|e| ConnectError::BadAddress {
                url: self.url.clone(),
                reason: format!(
                    "its TLS settings (the CA or the client certificate) cannot be used: {}",
                    error_chain(&e)
                ),
            })?,
            None => endpoint,
        };
        Ok(match self.keep_alive {
            Some(k) => endpoint.http2_keep_alive_interval(k.interval).keep_alive_timeout(k.timeout),
            None => endpoint,
        })
    }
}

/// A channel to the coordinator that sends the configured token with every call.
#[derive(Debug, Clone)]
pub struct Channel {
    inner: tonic::transport::Channel,
    authorization: Option<HeaderValue>,
}

impl Service<http::Request<tonic::body::Body>> for Channel {
    type Response = <tonic::transport::Channel as Service<http::Request<tonic::body::Body>>>::Response;
    type Error = <tonic::transport::Channel as Service<http::Request<tonic::body::Body>>>::Error;
    type Future = <tonic::transport::Channel as Service<http::Request<tonic::body::Body>>>::Future;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut request: http::Request<tonic::body::Body>) -> Self::Future {
        if let Some(value) = &self.authorization {
            request.headers_mut().insert(http::header::AUTHORIZATION, value.clone());
        }
        self.inner.call(request)
    }
}

/// The `authorization` header for `token`, marked sensitive so that HTTP/2 never puts it
/// in its compression table.
fn authorization(token: &Token) -> Result<HeaderValue, ConnectError> {
    let mut value = HeaderValue::from_str(&format!("Bearer {}", token.secret())).map_err(|_| {
        CredentialError::BadToken {
            from: "the configuration".into(),
            reason: "cannot travel in a header".into(),
        }
    })?;
    value.set_sensitive(true);
    Ok(value)
}

/// Opens a channel to the coordinator.
pub async fn connect(config: &EndpointConfig) -> Result<Channel, ConnectError> {
    let authorization = config.token.as_ref().map(authorization).transpose()?;
    let inner = config
        .endpoint()?
        .connect()
        .await
        .map_err(|e| ConnectError::Unreachable { url: config.url.clone(), reason: error_chain(&e) })?;
    Ok(Channel { inner, authorization })
}

/// A coordinator client.
pub type Client = CoordinatorClient<Channel>;

/// A coordinator client over a new channel, with the configured message size limit both ways.
pub async fn client(config: &EndpointConfig) -> Result<Client, ConnectError> {
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
    fn https_is_tls_and_tls_settings_need_https() {
        let c = EndpointConfig::new("https://render-host:7878").unwrap();
        assert_eq!(c.tls, Some(ClientTls::new()));
        assert_eq!(EndpointConfig::new("http://render-host:7878").unwrap().tls, None);
        // A CA given with a plain-text URL is a mistake to say, not a setting to drop.
        let dir = std::env::temp_dir().join(format!("tessera-connect-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ca = dir.join("ca.pem");
        std::fs::write(&ca, "-----BEGIN CERTIFICATE-----\nAA==\n-----END CERTIFICATE-----\n").unwrap();
        let tls = ClientTls::new().ca_file(&ca).unwrap();
        let e = EndpointConfig::new("http://render-host:7878").unwrap().tls(tls.clone()).unwrap_err();
        assert!(matches!(e, ConnectError::TlsForPlainText { .. }), "{e:?}");
        assert!(e.to_string().contains("use https://"), "{e}");
        assert!(EndpointConfig::new("https://render-host:7878").unwrap().tls(tls).is_ok());
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn the_token_is_hidden_and_sensitive() {
        let token = Token::new("abc123", "test").unwrap();
        let c = EndpointConfig::new("http://10.0.0.1:7878").unwrap().token(Some(token.clone()));
        assert!(!format!("{c:?}").contains("abc123"), "{c:?}");
        let header = authorization(&token).unwrap();
        assert!(header.is_sensitive());
        assert_eq!(header.to_str().unwrap(), "Bearer abc123");
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
