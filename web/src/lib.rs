//! The coordinator's web face: the dashboard's pages (embedded from `assets/`), the HTTP
//! JSON API behind them, server-sent status events and the live image over a WebSocket.
//!
//! Every handler acts through the coordinator's own gRPC methods, called in-process with
//! the caller's `Principal` in the request's extensions exactly where the interceptor
//! puts it, so that the role and owner checks are those of gRPC, in one place. The
//! contract with the pages is `docs/http-api.md`.

mod api;
mod errors;
mod events;
mod images;
mod json;
mod live;
mod metrics;
mod pages;
mod serve;
mod sessions;

use std::sync::Arc;

use axum::Router;
use tessera_coordinator::CoordinatorService;

pub use errors::ApiError;
pub use serve::{serve, tls_acceptor, TlsError};

/// How the web face is served.
#[derive(Debug, Clone, Copy, Default)]
pub struct WebConfig {
    /// The session cookie is `Secure` (served over HTTPS).
    pub secure_cookies: bool,
}

/// What every handler shares.
#[derive(Clone)]
pub(crate) struct AppState {
    pub(crate) service: CoordinatorService,
    pub(crate) sessions: Arc<sessions::Sessions>,
    pub(crate) config: WebConfig,
    /// The jobs whose live image is being shared among sockets (`live.rs`).
    pub(crate) hubs: live::Hubs,
}

/// The whole web face of `service`: the API under `/api`, `/healthz`, the pages; unknown
/// routes are 404 with a JSON error.
pub fn router(service: CoordinatorService, config: WebConfig) -> Router {
    let state = AppState { service, sessions: Arc::default(), config, hubs: live::Hubs::default() };
    Router::new()
        .merge(api::routes())
        .merge(pages::routes())
        .route("/healthz", axum::routing::get(|| async { "ok" }))
        .route("/metrics", axum::routing::get(metrics::metrics))
        .fallback(errors::no_route)
        .with_state(state)
}

#[cfg(test)]
mod tests {
    use axum::body::Body;
    use axum::http::{Request, StatusCode};
    use tessera_coordinator::{Auth, Role, Timing, Tokens};
    use tower::ServiceExt;

    use super::*;

    const VIEWER: &str = "viewer-token-0123456789";

    fn app() -> Router {
        let tokens = Tokens::new().with(Role::Viewer, "wall", VIEWER);
        let service = CoordinatorService::new(Timing::default()).with_auth(Auth::new(Some(tokens), false));
        router(service, WebConfig::default())
    }

    async fn call(app: Router, method: &str, path: &str, auth: Option<&str>) -> (StatusCode, String) {
        let mut r = Request::builder().method(method).uri(path);
        if let Some(a) = auth {
            r = r.header("authorization", a);
        }
        let response = app.oneshot(r.body(Body::empty()).unwrap()).await.unwrap();
        let status = response.status();
        let body = axum::body::to_bytes(response.into_body(), 1 << 20).await.unwrap();
        (status, String::from_utf8(body.to_vec()).unwrap())
    }

    #[tokio::test]
    async fn tokens_are_checked_before_anything_else() {
        let (s, body) = call(app(), "GET", "/api/jobs", None).await;
        assert_eq!(s, StatusCode::UNAUTHORIZED, "{body}");
        assert!(body.starts_with(r#"{"error":"no token"#), "{body}");
        let (s, _) = call(app(), "GET", "/api/jobs", Some(VIEWER)).await;
        assert_eq!(s, StatusCode::UNAUTHORIZED);
        let (s, body) = call(app(), "GET", "/api/jobs", Some(&format!("Bearer {VIEWER}"))).await;
        assert_eq!((s, body.as_str()), (StatusCode::OK, r#"{"jobs":[],"workers":[]}"#));
        let (s, body) = call(app(), "POST", "/api/jobs/3/cancel", Some(&format!("Bearer {VIEWER}"))).await;
        assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
        let (s, body) = call(app(), "GET", "/api/whoami", Some(&format!("Bearer {VIEWER}"))).await;
        assert_eq!((s, body.as_str()), (StatusCode::OK, r#"{"name":"wall","role":"viewer"}"#));
        // Health needs no token; unknown routes are JSON 404s.
        assert_eq!(call(app(), "GET", "/healthz", None).await, (StatusCode::OK, "ok".into()));
        let (s, body) = call(app(), "GET", "/nope", None).await;
        assert_eq!((s, body.as_str()), (StatusCode::NOT_FOUND, r#"{"error":"no route /nope"}"#));
    }
}
