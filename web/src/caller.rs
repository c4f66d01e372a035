//! Who is calling and how handlers call the coordinator for them: the `Caller` of a
//! request (a bearer token in `Authorization`, or the session cookie a login set), the
//! gRPC request carrying its principal, and the job lookups the handlers share. It sits
//! below `api` and the handlers it routes to (`images`, `live`, `events`), so that they
//! all depend on it rather than on each other.

use axum::extract::FromRequestParts;
use axum::http::header::{AUTHORIZATION, COOKIE};
use axum::http::request::Parts;
use axum::http::HeaderMap;
use tessera_coordinator::Principal;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;

use crate::errors::ApiError;
use crate::sessions;
use crate::AppState;

/// The authenticated caller of a request.
pub(crate) struct Caller(pub(crate) Principal);

impl FromRequestParts<AppState> for Caller {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, Self::Rejection> {
        authenticate(&parts.headers, state).map(Caller)
    }
}

/// The principal of a request's bearer token, else of its session cookie; the admin
/// `anonymous` on a coordinator without authentication.
pub(crate) fn authenticate(headers: &HeaderMap, state: &AppState) -> Result<Principal, ApiError> {
    let auth = state.service.auth();
    if !auth.required() {
        return Ok(auth.authenticate_token(None)?);
    }
    if let Some(h) = headers.get(AUTHORIZATION) {
        let token = h
            .as_bytes()
            .strip_prefix(b"Bearer ")
            .ok_or_else(|| ApiError::unauthorized("the Authorization header is not `Bearer TOKEN`"))?;
        return Ok(auth.authenticate_token(Some(token))?);
    }
    let session =
        headers.get_all(COOKIE).iter().filter_map(|h| h.to_str().ok()).find_map(sessions::from_cookie_header);
    match session {
        Some(id) => state
            .sessions
            .get(id)
            .ok_or_else(|| ApiError::unauthorized("the session expired or was closed; log in again")),
        None => Err(ApiError::unauthorized(
            "no token: send `Authorization: Bearer TOKEN`, or log in with POST /api/login",
        )),
    }
}

/// A gRPC request of `who`, as the coordinator's interceptor would hand it to the RPC: the
/// principal in its extensions.
pub(crate) fn request<T>(who: &Principal, message: T) -> tonic::Request<T> {
    let mut r = tonic::Request::new(message);
    r.extensions_mut().insert(who.clone());
    r
}

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

/// The one job `id` as `caller` may see it, or why not (401, 403, 404, as Status says).
pub(crate) async fn the_job(state: &AppState, caller: &Caller, id: u64) -> Result<pb::JobStatus, ApiError> {
    let s = status(state, caller, id).await?;
    s.jobs.into_iter().next().ok_or_else(|| ApiError::not_found(format!("no job {id}")))
}
