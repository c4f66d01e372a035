//! Jobs: list, one, submit, and their controls.

use axum::extract::{Path, State};
use axum::Json;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;

use super::auth::Caller;
use super::request;
use crate::errors::ApiError;
use crate::json::{self, Job, Listing};
use crate::AppState;

/// A job id from the path: a positive integer.
pub(crate) fn job_id(raw: &str) -> Result<u64, ApiError> {
    match raw.parse::<u64>() {
        Ok(id) if id > 0 => Ok(id),
        _ => Err(ApiError::bad_request(format!(
            "job id {:?} is not a positive integer",
            raw.chars().take(40).collect::<String>()
        ))),
    }
}

/// The status of every job `who` may see (`job` 0) or of one.
pub(crate) async fn status(
    state: &AppState,
    caller: &Caller,
    job: u64,
) -> Result<pb::StatusResponse, ApiError> {
    let response =
        Coordinator::status(&state.service, request(&caller.0, pb::StatusRequest { job_id: job })).await?;
    Ok(response.into_inner())
}

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
    let s = status(&state, &caller, id).await?;
    let job = s.jobs.into_iter().next().ok_or_else(|| ApiError::not_found(format!("no job {id}")))?;
    Ok(Json(Job::from(job)))
}
