//! The coordinator's web face: the dashboard's pages (embedded from `assets/`), the HTTP
//! JSON API behind them, server-sent status events and the live image over a WebSocket.
//!
//! Every handler acts through the coordinator's own gRPC methods, called in-process with
//! the caller's `Principal` in the request's extensions exactly where the interceptor
//! puts it, so that the role and owner checks are those of gRPC, in one place. The
//! contract with the pages is `docs/http-api.md`.

mod api;
mod caller;
mod errors;
mod events;
mod headers;
mod images;
mod json;
mod live;
mod metrics;
mod origin;
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
/// routes are 404 with a JSON error. Every request passes the cross-site checks first
/// (`origin`), every answer gets the security headers (`headers`).
pub fn router(service: CoordinatorService, config: WebConfig) -> Router {
    let state = AppState { service, sessions: Arc::default(), config, hubs: live::Hubs::default() };
    Router::new()
        .merge(api::routes())
        .merge(pages::routes())
        .route("/healthz", axum::routing::get(|| async { "ok" }))
        .route("/metrics", axum::routing::get(metrics::metrics))
        .fallback(errors::no_route)
        .layer(axum::middleware::from_fn_with_state(state.clone(), origin::guard))
        .layer(axum::middleware::from_fn(headers::secure))
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
        let response =
            app.oneshot(r.header("host", "127.0.0.1:8080").body(Body::empty()).unwrap()).await.unwrap();
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

    /// A request to the router: method, path, headers; its status, headers and body.
    async fn send(
        app: &Router,
        method: &str,
        path: &str,
        headers: &[(&str, &str)],
        body: &str,
    ) -> (StatusCode, axum::http::HeaderMap, String) {
        let mut r = Request::builder().method(method).uri(path);
        for (k, v) in headers {
            r = r.header(*k, *v);
        }
        let response = app.clone().oneshot(r.body(Body::from(body.to_string())).unwrap()).await.unwrap();
        let (parts, body) = response.into_parts();
        let body = axum::body::to_bytes(body, 1 << 20).await.unwrap();
        (parts.status, parts.headers, String::from_utf8_lossy(&body).into_owned())
    }

    const HOST: (&str, &str) = ("host", "127.0.0.1:8080");

    /// Submits the small test scene to an open coordinator (no worker: it stays queued).
    async fn submit_small(app: &Router) -> u64 {
        let scene = include_str!("../../tests/scenes/small.toml");
        let body = format!(
            "--b\r\ncontent-disposition: form-data; name=\"scene\"; filename=\"small.toml\"\r\n\r\n{scene}\r\n--b--\r\n"
        );
        let length = body.len().to_string();
        let (s, _, answer) = send(
            app,
            "POST",
            "/api/jobs",
            &[HOST, ("content-type", "multipart/form-data; boundary=b"), ("content-length", &length)],
            &body,
        )
        .await;
        assert_eq!(s, StatusCode::CREATED, "{answer}");
        serde_json::from_str::<serde_json::Value>(&answer).unwrap()["id"].as_u64().unwrap()
    }

    async fn state_of(app: &Router, id: u64) -> String {
        let (s, _, body) = send(app, "GET", &format!("/api/jobs/{id}"), &[HOST], "").await;
        assert_eq!(s, StatusCode::OK, "{body}");
        serde_json::from_str::<serde_json::Value>(&body).unwrap()["state"].as_str().unwrap().to_string()
    }

    /// On an open coordinator (everyone admin), another site's page cannot cancel a job,
    /// change its priority, or open its live socket; the dashboard's own page can.
    #[tokio::test]
    async fn cross_site_requests_are_refused_and_same_origin_ones_served() {
        let app = router(CoordinatorService::new(Timing::default()), WebConfig::default());
        let id = submit_small(&app).await;
        assert_eq!(state_of(&app, id).await, "queued");
        let cancel = format!("/api/jobs/{id}/cancel");
        let priority = format!("/api/jobs/{id}/priority");
        for origin in ["http://evil.example", "http://127.0.0.1:9999", "https://127.0.0.1:8080", "null"] {
            let (s, _, body) = send(&app, "POST", &cancel, &[HOST, ("origin", origin)], "").await;
            assert_eq!(s, StatusCode::FORBIDDEN, "{origin}: {body}");
            assert!(
                body.starts_with(r#"{"error":"POST /api/jobs/1/cancel: refused from the origin"#),
                "{body}"
            );
        }
        let (s, _, body) = send(&app, "POST", &cancel, &[HOST, ("sec-fetch-site", "cross-site")], "").await;
        assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
        assert!(body.contains("Sec-Fetch-Site: cross-site"), "{body}");
        // A form's content types (no preflight) do not set a priority.
        for kind in [None, Some("text/plain"), Some("application/x-www-form-urlencoded")] {
            let mut headers = vec![HOST];
            headers.extend(kind.map(|k| ("content-type", k)));
            let (s, _, body) = send(&app, "POST", &priority, &headers, r#"{"priority": 7}"#).await;
            assert_eq!(s, StatusCode::UNSUPPORTED_MEDIA_TYPE, "{kind:?}: {body}");
            assert!(body.contains("Content-Type: application/json"), "{body}");
        }
        assert_eq!(state_of(&app, id).await, "queued");
        let live = format!("/api/jobs/{id}/live");
        let upgrade = [
            HOST,
            ("origin", "http://evil.example"),
            ("connection", "upgrade"),
            ("upgrade", "websocket"),
            ("sec-websocket-version", "13"),
            ("sec-websocket-key", "dGhlIHNhbXBsZSBub25jZQ=="),
        ];
        let (s, _, body) = send(&app, "GET", &live, &upgrade, "").await;
        assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
        assert!(body.contains("GET /api/jobs/1/live: refused from the origin"), "{body}");
        // Reads without an Origin pass (an in-process request cannot upgrade: 426, after
        // the checks).
        let (s, _, body) = send(&app, "GET", &live, &[HOST], "").await;
        assert_ne!(s, StatusCode::FORBIDDEN, "{body}");

        // The page's own origin (any case) is served.
        let same =
            [HOST, ("origin", "http://127.0.0.1:8080"), ("content-type", "application/json; charset=utf-8")];
        let (s, _, body) = send(&app, "POST", &priority, &same, r#"{"priority": 7}"#).await;
        assert_eq!(s, StatusCode::NO_CONTENT, "{body}");
        let (s, _, body) = send(
            &app,
            "POST",
            &cancel,
            &[HOST, ("origin", "HTTP://127.0.0.1:8080"), ("sec-fetch-site", "same-origin")],
            "",
        )
        .await;
        assert_eq!(s, StatusCode::NO_CONTENT, "{body}");
        assert_eq!(state_of(&app, id).await, "cancelled");
    }

    /// An open coordinator answers only at loopback names: a rebound foreign name reads
    /// neither the jobs nor the metrics. With tokens the name is not checked.
    #[tokio::test]
    async fn an_open_coordinator_answers_only_at_loopback_names() {
        let app = router(CoordinatorService::new(Timing::default()), WebConfig::default());
        for path in ["/api/jobs", "/metrics", "/", "/healthz"] {
            for host in ["evil.example", "evil.example:8080", "127.0.0.1.evil.example:8080"] {
                let (s, _, body) = send(&app, "GET", path, &[("host", host)], "").await;
                assert_eq!(s, StatusCode::FORBIDDEN, "{path} at {host}: {body}");
                assert!(body.contains("answers only at a loopback address"), "{body}");
            }
            let (s, _, body) = send(&app, "GET", path, &[], "").await;
            assert_eq!(
                (s, body.as_str()),
                (StatusCode::FORBIDDEN, r#"{"error":"no Host header"}"#),
                "{path}"
            );
            for host in ["127.0.0.1:8080", "[::1]:8080", "localhost", "localhost:1234"] {
                let (s, _, body) = send(&app, "GET", path, &[("host", host)], "").await;
                assert_eq!(s, StatusCode::OK, "{path} at {host}: {body}");
            }
        }
        let (s, _, body) = send(
            &self::app(),
            "GET",
            "/api/jobs",
            &[("host", "farm.example:8080"), ("authorization", &format!("Bearer {VIEWER}"))],
            "",
        )
        .await;
        assert_eq!(s, StatusCode::OK, "{body}");
    }

    /// Logins need a JSON body and refuse workers' tokens; each principal holds at most
    /// `MAX_PER_PRINCIPAL` sessions, its oldest dropped first.
    #[tokio::test]
    async fn logins_refuse_workers_and_forms_and_cap_sessions_per_principal() {
        const WORKER: &str = "worker-token-0123456789";
        let tokens = Tokens::new().with(Role::Viewer, "wall", VIEWER).with(Role::Worker, "node-1", WORKER);
        let service = CoordinatorService::new(Timing::default()).with_auth(Auth::new(Some(tokens), false));
        let app = router(service, WebConfig::default());
        let json = ("content-type", "application/json");
        let login = |token: &str| format!(r#"{{"token":"{token}"}}"#);
        let (s, _, body) = send(&app, "POST", "/api/login", &[HOST, json], &login(WORKER)).await;
        assert_eq!(s, StatusCode::FORBIDDEN, "{body}");
        assert!(body.contains("node-1 holds a worker token; workers have nothing to do here"), "{body}");
        let form = ("content-type", "application/x-www-form-urlencoded");
        let (s, _, body) = send(&app, "POST", "/api/login", &[HOST, form], &login(VIEWER)).await;
        assert_eq!(s, StatusCode::UNSUPPORTED_MEDIA_TYPE, "{body}");
        let mut cookies = Vec::new();
        for _ in 0..=crate::sessions::MAX_PER_PRINCIPAL {
            let (s, headers, body) = send(&app, "POST", "/api/login", &[HOST, json], &login(VIEWER)).await;
            assert_eq!(s, StatusCode::NO_CONTENT, "{body}");
            let cookie = headers["set-cookie"].to_str().unwrap();
            cookies.push(cookie.split(';').next().unwrap().to_string());
        }
        let whoami = |cookie: String| {
            let app = app.clone();
            async move { send(&app, "GET", "/api/whoami", &[HOST, ("cookie", &cookie)], "").await.0 }
        };
        assert_eq!(whoami(cookies[0].clone()).await, StatusCode::UNAUTHORIZED);
        for c in &cookies[1..] {
            assert_eq!(whoami(c.clone()).await, StatusCode::OK);
        }
    }

    /// Pages and API answers alike say nosniff, no framing, and the pages' policy.
    #[tokio::test]
    async fn answers_carry_the_security_headers() {
        let app = router(CoordinatorService::new(Timing::default()), WebConfig::default());
        for path in ["/", "/assets/job.js", "/api/jobs", "/nope"] {
            let (_, h, _) = send(&app, "GET", path, &[HOST], "").await;
            assert_eq!(h["x-content-type-options"], "nosniff", "{path}");
            assert_eq!(h["x-frame-options"], "DENY", "{path}");
            assert_eq!(h["content-security-policy"], crate::headers::CSP, "{path}");
        }
        // Refusals too.
        let (s, h, _) = send(&app, "GET", "/", &[("host", "evil.example")], "").await;
        assert_eq!((s, &h["x-content-type-options"]), (StatusCode::FORBIDDEN, &"nosniff".parse().unwrap()));
    }
}
