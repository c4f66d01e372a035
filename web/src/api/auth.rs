//! The login, logout and whoami endpoints (who is calling is `crate::caller`'s).

use axum::extract::State;
use axum::http::header::{COOKIE, SET_COOKIE};
use axum::http::{HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use bytes::Bytes;
use serde::Deserialize;
use tessera_coordinator::Role;

use crate::caller::Caller;
use crate::errors::ApiError;
use crate::sessions::{self, COOKIE as SESSION_COOKIE, LIFETIME};
use crate::AppState;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Login {
    token: String,
}

/// A JSON body of type `T`, or a 400 saying what is wrong with it.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(body: &[u8], what: &str) -> Result<T, ApiError> {
    serde_json::from_slice(body).map_err(|e| ApiError::bad_request(format!("{what}: bad JSON body: {e}")))
}

/// `POST /api/login {"token": ...}`: 204 and the session cookie; 403 for a worker's token.
pub(crate) async fn login(State(state): State<AppState>, body: Bytes) -> Result<Response, ApiError> {
    let login: Login = parse_json(&body, "POST /api/login")?;
    let who = state.service.auth().authenticate_token(Some(login.token.as_bytes()))?;
    // A worker's token does nothing a browser could use; refusing it also keeps the many
    // hosts holding worker tokens from filling the session map.
    if who.role == Role::Worker {
        return Err(ApiError::new(
            StatusCode::FORBIDDEN,
            format!("POST /api/login: {} holds a worker token; workers have nothing to do here", who.name),
        ));
    }
    tracing::info!(principal = %who.name, role = %who.role, "web login");
    let id = state
        .sessions
        .open(who)
        .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let cookie = format!(
        "{SESSION_COOKIE}={id}; Path=/; HttpOnly; SameSite=Strict; Max-Age={}{}",
        LIFETIME.as_secs(),
        if state.config.secure_cookies { "; Secure" } else { "" }
    );
    let cookie = HeaderValue::from_str(&cookie).expect("a cookie of hex digits and ASCII");
    Ok((StatusCode::NO_CONTENT, [(SET_COOKIE, cookie)]).into_response())
}

/// `POST /api/logout`: drops the session, clears the cookie.
pub(crate) async fn logout(State(state): State<AppState>, headers: HeaderMap) -> Response {
    for id in headers
        .get_all(COOKIE)
        .iter()
        .filter_map(|h| h.to_str().ok())
        .filter_map(sessions::from_cookie_header)
    {
        state.sessions.close(id);
    }
    let clear = HeaderValue::from_static("tessera_session=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0");
    (StatusCode::NO_CONTENT, [(SET_COOKIE, clear)]).into_response()
}

/// `GET /api/whoami`: `{"name", "role"}`.
pub(crate) async fn whoami(Caller(who): Caller) -> Json<serde_json::Value> {
    Json(serde_json::json!({ "name": who.name, "role": who.role.name() }))
}
