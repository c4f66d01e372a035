//! The cross-site defences, one layer in front of every route (`docs/http-api.md`,
//! "Cross-site requests"):
//!
//! - a request that changes something (any method but GET and HEAD) or opens a WebSocket
//!   is refused when its `Origin` is not the address it was sent to, or when the browser
//!   says `Sec-Fetch-Site: cross-site`: another site's page cannot drive the farm with the
//!   operator's cookie, or at all on an open coordinator, where everyone is admin;
//! - the JSON endpoints (`/api/login`, `/api/jobs/{id}/priority`) need
//!   `Content-Type: application/json`, which a cross-site form cannot send without a
//!   preflight;
//! - an open coordinator (no authentication) answers only requests addressed to a
//!   loopback name, so that a foreign name rebound to 127.0.0.1 (DNS rebinding) reads
//!   nothing.
//!
//! curl and scripts send no `Origin` and address the host they reach: they pass.

use axum::extract::{Request, State};
use axum::http::header::{CONTENT_TYPE, HOST, ORIGIN, UPGRADE};
use axum::http::{Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::errors::ApiError;
use crate::AppState;

/// The refusal of a request that the checks stop, or None to serve it.
fn refusal(request: &Request, https: bool, open: bool) -> Option<ApiError> {
    let forbidden = |m: String| Some(ApiError::new(StatusCode::FORBIDDEN, m));
    let headers = request.headers();
    let host = headers
        .get(HOST)
        .and_then(|h| h.to_str().ok())
        .map(str::to_string)
        .or_else(|| request.uri().authority().map(|a| a.as_str().to_string()));
    if open {
        match host.as_deref() {
            Some(h) if is_loopback(h) => {}
            Some(h) => {
                let shown: String = h.chars().take(80).collect();
                return forbidden(format!(
                    "this coordinator has no authentication and answers only at a loopback address \
                     (127.0.0.1, [::1], localhost), not at {shown:?}"
                ));
            }
            None => return forbidden("no Host header".into()),
        }
    }
    let upgrade = headers.get(UPGRADE).is_some_and(|v| v.as_bytes().eq_ignore_ascii_case(b"websocket"));
    let changes = !matches!(*request.method(), Method::GET | Method::HEAD);
    if !(changes || upgrade) {
        return None;
    }
    let what = format!("{} {}", request.method(), request.uri().path().chars().take(200).collect::<String>());
    if headers.get("sec-fetch-site").is_some_and(|v| v.as_bytes().eq_ignore_ascii_case(b"cross-site")) {
        return forbidden(format!("{what}: refused from another site's page (Sec-Fetch-Site: cross-site)"));
    }
    if let Some(origin) = headers.get(ORIGIN) {
        let origin = origin.to_str().unwrap_or("");
        let scheme = if https { "https" } else { "http" };
        let ours = host.as_deref().map(|h| format!("{scheme}://{h}"));
        if !ours.is_some_and(|o| o.eq_ignore_ascii_case(origin)) {
            let shown: String = origin.chars().take(80).collect();
            return forbidden(format!("{what}: refused from the origin {shown:?}, not this coordinator's"));
        }
    }
    let path = request.uri().path();
    let json_only = path == "/api/login" || (path.starts_with("/api/jobs/") && path.ends_with("/priority"));
    if changes && json_only {
        let kind = headers.get(CONTENT_TYPE).and_then(|v| v.to_str().ok()).unwrap_or("");
        let media = kind.split(';').next().unwrap_or("").trim();
        if !media.eq_ignore_ascii_case("application/json") {
            let shown: String = kind.chars().take(80).collect();
            return Some(ApiError::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                format!("{what}: the body must be sent with Content-Type: application/json, not {shown:?}"),
            ));
        }
    }
    None
}

/// Whether a `Host` value (name and optional port) is a loopback name.
fn is_loopback(host: &str) -> bool {
    let name = if let Some(rest) = host.strip_prefix('[') {
        match rest.split_once(']') {
            Some((inside, port)) if port.is_empty() || port.starts_with(':') => return inside == "::1",
            _ => return false,
        }
    } else {
        host.split_once(':').map_or(host, |(name, _)| name)
    };
    name == "127.0.0.1" || name.eq_ignore_ascii_case("localhost")
}

/// The layer: refuses what the checks stop, serves the rest.
pub(crate) async fn guard(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let open = !state.service.auth().required();
    match refusal(&request, state.config.secure_cookies, open) {
        Some(e) => {
            tracing::debug!("web request refused: {}", e.message);
            e.into_response()
        }
        None => next.run(request).await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_names_with_any_port() {
        for h in ["127.0.0.1", "127.0.0.1:8080", "[::1]", "[::1]:80", "localhost", "LOCALHOST:9"] {
            assert!(is_loopback(h), "{h}");
        }
        for h in
            ["evil.example", "evil.example:8080", "127.0.0.1.evil.example", "[::2]:80", "[::1]x", "10.0.0.1"]
        {
            assert!(!is_loopback(h), "{h}");
        }
    }
}
