//! `GET /metrics`: the coordinator's Prometheus text (`docs/metrics.md`). Any caller the
//! coordinator knows may read it, whatever its role: a Prometheus scrape carries a bearer
//! token (`authorization` in its scrape config; give it a viewer's), a logged-in browser
//! its session. An open coordinator (no tokens) serves it to everyone, as everything else.

use axum::extract::State;
use axum::http::header::CONTENT_TYPE;
use axum::response::{IntoResponse, Response};

use crate::caller::Caller;
use crate::AppState;

/// The exposition text; the farm's lock is held for one census (no pixel is read).
pub(crate) async fn metrics(State(state): State<AppState>, _: Caller) -> Response {
    let text = state.service.metrics_text();
    ([(CONTENT_TYPE, tessera_coordinator::metrics::CONTENT_TYPE)], text).into_response()
}

#[cfg(test)]
mod tests {
    use axum::body::Body;
    use axum::http::{Request, StatusCode};
    use tessera_coordinator::{Auth, CoordinatorService, Role, Timing, Tokens};
    use tower::ServiceExt;

    use crate::{router, WebConfig};

    const VIEWER: &str = "viewer-token-0123456789abcdef";
    const WORKER: &str = "worker-token-0123456789abcdef";

    async fn get(service: &CoordinatorService, token: Option<&str>) -> (StatusCode, Option<String>, String) {
        let mut request = Request::get("/metrics").header("host", "127.0.0.1:8080");
        if let Some(t) = token {
            request = request.header("authorization", format!("Bearer {t}"));
        }
        let response = router(service.clone(), WebConfig::default())
            .oneshot(request.body(Body::empty()).unwrap())
            .await
            .unwrap();
        let status = response.status();
        let kind = response.headers().get("content-type").map(|v| v.to_str().unwrap().to_string());
        let body = axum::body::to_bytes(response.into_body(), 1 << 20).await.unwrap();
        (status, kind, String::from_utf8(body.to_vec()).unwrap())
    }

    /// With tokens, any role's token reads the metrics and no token or an unknown one is
    /// a 401 with a JSON error; an open coordinator needs none.
    #[tokio::test]
    async fn any_known_token_reads_the_metrics() {
        let tokens = Tokens::new().with(Role::Viewer, "wall", VIEWER).with(Role::Worker, "node-1", WORKER);
        let secured = CoordinatorService::new(Timing::default()).with_auth(Auth::new(Some(tokens), false));
        for token in [VIEWER, WORKER] {
            let (status, kind, body) = get(&secured, Some(token)).await;
            assert_eq!(status, StatusCode::OK, "{body}");
            assert_eq!(kind.as_deref(), Some("text/plain; version=0.0.4; charset=utf-8"));
            assert!(body.contains("\ntessera_jobs{state=\"queued\"} 0\n"), "{body}");
        }
        for token in [None, Some("an-unknown-token-0123456789")] {
            let (status, _, body) = get(&secured, token).await;
            assert_eq!(status, StatusCode::UNAUTHORIZED, "{token:?}: {body}");
            assert!(body.starts_with("{\"error\":"), "{body}");
        }
        let open = CoordinatorService::new(Timing::default());
        let (status, _, body) = get(&open, None).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        assert!(body.contains("tessera_samples_queued 0"), "{body}");
    }
}
