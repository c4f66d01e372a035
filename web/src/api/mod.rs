//! The JSON API under `/api`.

pub(crate) mod auth;
mod jobs;
mod submit;

use axum::routing::{get, post};
use axum::Router;

use crate::AppState;

pub(crate) fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/login", post(auth::login))
        .route("/api/logout", post(auth::logout))
        .route("/api/whoami", get(auth::whoami))
        .route(
            "/api/jobs",
            get(jobs::list)
                .post(submit::submit)
                .layer(axum::extract::DefaultBodyLimit::max(submit::MAX_UPLOAD_BYTES as usize)),
        )
        .route("/api/jobs/{id}", get(jobs::one))
        .route("/api/jobs/{id}/pause", post(jobs::pause))
        .route("/api/jobs/{id}/resume", post(jobs::resume))
        .route("/api/jobs/{id}/cancel", post(jobs::cancel))
        .route("/api/jobs/{id}/priority", post(jobs::priority))
        .route("/api/jobs/{id}/image.png", get(crate::images::png))
        .route("/api/jobs/{id}/image.exr", get(crate::images::exr))
        .route("/api/jobs/{id}/live", get(crate::live::live))
        .route("/api/events", get(crate::events::events))
}
