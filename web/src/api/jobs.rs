//! Jobs: list, one, submit, and their controls.

use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::Json;
use bytes::Bytes;
use serde::Deserialize;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;

use super::auth::parse_json;
use crate::caller::{job_id, request, status, the_job, Caller};
use crate::errors::ApiError;
use crate::json::{self, Job, Listing};
use crate::AppState;

/// `GET /api/jobs`.
pub(crate) async fn list(State(state): State<AppState>, caller: Caller) -> Result<Json<Listing>, ApiError> {
    Ok(Json(json::listing(status(&state, &caller, 0).await?)))
}

/// `GET /api/jobs/{id}`.
pub(crate) async fn one(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
) -> Result<Json<Job>, ApiError> {
    let id = job_id(&raw)?;
    Ok(Json(Job::from(the_job(&state, &caller, id).await?)))
}

/// Pauses or resumes a job through the Pause RPC (its role and owner checks); a job that
/// is over is left as it is there, which is 409 here.
async fn pause_or_resume(
    state: &AppState,
    caller: &Caller,
    raw: &str,
    paused: bool,
) -> Result<StatusCode, ApiError> {
    let id = job_id(raw)?;
    Coordinator::pause(&state.service, request(&caller.0, pb::PauseRequest { job_id: id, paused })).await?;
    let job = the_job(state, caller, id).await?;
    let name = json::state_name(job.state);
    if matches!(name, "done" | "cancelled" | "failed") {
        let what = if paused { "paused" } else { "resumed" };
        return Err(ApiError::new(StatusCode::CONFLICT, format!("job {id} is {name}: it cannot be {what}")));
    }
    Ok(StatusCode::NO_CONTENT)
}

/// `POST /api/jobs/{id}/pause`.
pub(crate) async fn pause(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
) -> Result<StatusCode, ApiError> {
    pause_or_resume(&state, &caller, &raw, true).await
}

/// `POST /api/jobs/{id}/resume`.
pub(crate) async fn resume(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
) -> Result<StatusCode, ApiError> {
    pause_or_resume(&state, &caller, &raw, false).await
}

/// `POST /api/jobs/{id}/cancel`.
pub(crate) async fn cancel(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
) -> Result<StatusCode, ApiError> {
    let id = job_id(&raw)?;
    Coordinator::cancel(&state.service, request(&caller.0, pb::CancelRequest { job_id: id })).await?;
    Ok(StatusCode::NO_CONTENT)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Priority {
    priority: i32,
}

/// `POST /api/jobs/{id}/priority {"priority": N}`.
pub(crate) async fn priority(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
    body: Bytes,
) -> Result<StatusCode, ApiError> {
    let id = job_id(&raw)?;
    let Priority { priority } = parse_json(&body, &format!("POST /api/jobs/{id}/priority"))?;
    Coordinator::set_priority(
        &state.service,
        request(&caller.0, pb::SetPriorityRequest { job_id: id, priority }),
    )
    .await?;
    Ok(StatusCode::NO_CONTENT)
}
