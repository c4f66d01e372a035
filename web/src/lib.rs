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
}

/// The whole web face of `service`: the API under `/api`, `/healthz`, the pages; unknown
/// routes are 404 with a JSON error.
pub fn router(service: CoordinatorService, config: WebConfig) -> Router {
    let state = AppState { service, sessions: Arc::default(), config };
    Router::new()
        .merge(api::routes())
        .merge(pages::routes())
        .route("/healthz", axum::routing::get(|| async { "ok" }))
        .fallback(errors::no_route)
        .with_state(state)
}
