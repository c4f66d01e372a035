//! `POST /api/jobs`: a scene and its assets as multipart/form-data, admitted like a gRPC
//! Submit (the role, a turn, a memory reservation) before a byte of it is read, its size
//! and part count bounded, then submitted through the Submit RPC.

use axum::extract::multipart::{Field, MultipartRejection};
use axum::extract::{FromRequest, Multipart, Request, State};
use axum::http::header::CONTENT_LENGTH;
use axum::http::StatusCode;
use axum::Json;
use tessera_description::bundle::check_asset_path;
use tessera_description::limits::{MAX_ASSETS, MAX_NAME_BYTES};
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;

use crate::caller::{request, Caller};
use crate::errors::ApiError;
use crate::AppState;

/// The largest upload: the largest Submit message (a bundle and its framing). Multipart
/// framing adds ~200 bytes a part, well within its slack.
pub(crate) const MAX_UPLOAD_BYTES: u64 = tessera_proto::connect::MAX_MESSAGE_BYTES as u64;
/// The most parts: a scene, every asset it may carry, and the eight settings.
pub(crate) const MAX_PARTS: usize = MAX_ASSETS + 1 + 8;
/// The longest setting value, in bytes.
const MAX_SETTING_BYTES: usize = 64;

#[derive(Debug, serde::Serialize)]
pub(crate) struct Submitted {
    id: u64,
    width: u32,
    height: u32,
    spp: u32,
}

/// What the form carried.
#[derive(Default)]
struct Form {
    scene: Option<(String, String)>,
    assets: Vec<pb::Asset>,
    settings: pb::RenderSettings,
    priority: i32,
}

/// A refused upload this small is read (and dropped) before the answer: a client still
/// sending when the connection closes would get a reset instead of the answer.
const DRAIN_BYTES: u64 = 1 << 20;

/// `e`, once what is left of a small upload was read.
async fn drained(e: ApiError, request: Request, length: u64) -> ApiError {
    if length <= DRAIN_BYTES {
        let _ = axum::body::to_bytes(request.into_body(), DRAIN_BYTES as usize).await;
    }
    e
}

/// `POST /api/jobs`.
pub(crate) async fn submit(
    State(state): State<AppState>,
    caller: Result<Caller, ApiError>,
    http: Request,
) -> Result<(StatusCode, Json<Submitted>), ApiError> {
    // Bounded before it is read: the declared length is checked and reserved first.
    let length =
        http.headers().get(CONTENT_LENGTH).and_then(|v| v.to_str().ok()?.parse::<u64>().ok()).ok_or_else(
            || {
                ApiError::new(
                    StatusCode::LENGTH_REQUIRED,
                    "POST /api/jobs: the upload must declare its Content-Length",
                )
            },
        )?;
    let who = match caller {
        Ok(Caller(who)) => who,
        Err(e) => return Err(drained(e, http, length).await),
    };
    if length > MAX_UPLOAD_BYTES {
        return Err(ApiError::too_large(format!(
            "POST /api/jobs: an upload of {length} bytes; a scene bundle may take at most {MAX_UPLOAD_BYTES}"
        )));
    }
    let _admission = match state.service.admit_submission(&who, length).await {
        Ok(a) => a,
        Err(e) => return Err(drained(e.into(), http, length).await),
    };
    // The turn and the reservation are held while the body arrives: a sender that
    // trickles it must not hold them (and every other submission) for ever.
    let deadline = upload_deadline(length);
    let form = tokio::time::timeout(deadline, async {
        let mut multipart =
            Multipart::from_request(http, &state).await.map_err(|e: MultipartRejection| {
                ApiError::bad_request(format!("POST /api/jobs: {}", e.body_text()))
            })?;
        read_form(&mut multipart).await
    })
    .await
    .map_err(|_| {
        ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "POST /api/jobs: the upload of {length} bytes did not arrive within {} s",
                deadline.as_secs()
            ),
        )
    })??;
    let (name, text) = form.scene.ok_or_else(|| ApiError::bad_request("POST /api/jobs: no `scene` part"))?;
    let message = pb::SubmitRequest {
        protocol_version: pb::ProtocolVersion::Current as i32,
        bundle: Some(pb::SceneBundle { name, text, assets: form.assets }),
        settings: Some(form.settings),
        priority: form.priority,
    };
    let r = Coordinator::submit(&state.service, request(&who, message)).await?.into_inner();
    Ok((StatusCode::CREATED, Json(Submitted { id: r.job_id, width: r.width, height: r.height, spp: r.spp })))
}

/// How long an upload of `length` bytes may take to arrive: half a minute, plus a second
/// a megabyte (a slow link, not a stalled one).
fn upload_deadline(length: u64) -> std::time::Duration {
    std::time::Duration::from_secs(30 + length / 1_000_000)
}

fn bad(what: String) -> ApiError {
    ApiError::bad_request(format!("POST /api/jobs: {what}"))
}

/// A multipart error: 413 where the body went past its limit, else 400.
fn multipart_error(e: axum::extract::multipart::MultipartError) -> ApiError {
    ApiError::new(e.status(), format!("POST /api/jobs: malformed multipart body: {}", e.body_text()))
}

async fn read_form(multipart: &mut Multipart) -> Result<Form, ApiError> {
    let mut form = Form::default();
    let mut parts = 0usize;
    let mut size = None;
    while let Some(field) = multipart.next_field().await.map_err(multipart_error)? {
        parts += 1;
        if parts > MAX_PARTS {
            return Err(bad(format!(
                "more than {MAX_PARTS} parts (a scene, at most {MAX_ASSETS} assets, settings)"
            )));
        }
        let name = field.name().unwrap_or("").to_string();
        match name.as_str() {
            "scene" => {
                if form.scene.is_some() {
                    return Err(bad("more than one `scene` part".into()));
                }
                let file = file_name(&field, "scene")?;
                let bytes = field.bytes().await.map_err(multipart_error)?;
                let text = String::from_utf8(bytes.to_vec()).map_err(|e| {
                    bad(format!("the scene {file:?} is not UTF-8 (byte {})", e.utf8_error().valid_up_to()))
                })?;
                form.scene = Some((file, text));
            }
            "asset" => {
                let path = file_name(&field, "asset")?;
                let path = check_asset_path(&path).map_err(bad)?;
                let data = field.bytes().await.map_err(multipart_error)?;
                form.assets.push(pb::Asset { path, data: data.to_vec() });
            }
            "spp" | "width" | "height" | "priority" | "time" | "noise" | "noise_absolute" | "noise_min" => {
                let value = setting(field, &name).await?;
                let value = value.trim();
                let number = |what: &str| bad(format!("`{name}` {value:?} is not {what}"));
                match name.as_str() {
                    "spp" => form.settings.spp = value.parse().map_err(|_| number("a whole number"))?,
                    "width" => {
                        size = Some((
                            value.parse().map_err(|_| number("a whole number"))?,
                            size.map_or(0, |s: (u32, u32)| s.1),
                        ))
                    }
                    "height" => {
                        size = Some((
                            size.map_or(0, |s: (u32, u32)| s.0),
                            value.parse().map_err(|_| number("a whole number"))?,
                        ))
                    }
                    "priority" => form.priority = value.parse().map_err(|_| number("an integer"))?,
                    "time" => {
                        let d = tessera_description::job::parse_duration(value)
                            .map_err(|e| bad(format!("`time`: {e}")))?;
                        form.settings.time_limit_seconds = d.as_secs_f64();
                    }
                    "noise" => form.settings.noise = value.parse().map_err(|_| number("a number"))?,
                    "noise_absolute" => {
                        form.settings.noise_absolute = value.parse().map_err(|_| number("a number"))?
                    }
                    _ => {
                        // 0 is the wire's "unset": refused here rather than taken as the
                        // target's own minimum.
                        let least = tessera_description::job::NOISE_MIN_SAMPLES_LEAST;
                        form.settings.noise_min_samples =
                            value.parse().ok().filter(|&m| m >= least).ok_or_else(|| {
                                number(&format!("a whole number of at least {least} samples"))
                            })?
                    }
                }
            }
            other => {
                let shown: String = other.chars().take(40).collect();
                return Err(bad(format!(
                    "unknown part {shown:?}; expected scene, asset, spp, width, height, priority, time, noise, noise_absolute or noise_min"
                )));
            }
        }
    }
    if let Some((w, h)) = size {
        if w == 0 || h == 0 {
            return Err(bad("give both `width` and `height`, each above 0".into()));
        }
        (form.settings.width, form.settings.height) = (w, h);
    }
    Ok(form)
}

/// A file part's file name (the scene's name, an asset's path).
fn file_name(field: &Field<'_>, part: &str) -> Result<String, ApiError> {
    let name = field.file_name().filter(|n| !n.is_empty()).ok_or_else(|| {
        bad(format!(
            "the `{part}` part has no filename (the {})",
            if part == "scene" { "scene's name" } else { "path the scene uses" }
        ))
    })?;
    if name.len() > MAX_NAME_BYTES {
        return Err(bad(format!("a `{part}` filename of {} bytes; at most {MAX_NAME_BYTES}", name.len())));
    }
    Ok(name.to_string())
}

/// A short text part.
async fn setting(mut field: Field<'_>, name: &str) -> Result<String, ApiError> {
    let mut value = Vec::new();
    while let Some(chunk) = field.chunk().await.map_err(multipart_error)? {
        value.extend_from_slice(&chunk);
        if value.len() > MAX_SETTING_BYTES {
            return Err(bad(format!("`{name}` is longer than {MAX_SETTING_BYTES} bytes")));
        }
    }
    String::from_utf8(value).map_err(|_| bad(format!("`{name}` is not UTF-8")))
}

#[cfg(test)]
mod tests {
    use axum::body::Body;
    use axum::http::{Request, StatusCode};
    use tessera_coordinator::{CoordinatorService, Timing};
    use tokio_stream::StreamExt;
    use tower::ServiceExt;

    use crate::{router, WebConfig};

    /// A sender that declares a small upload, sends its first bytes and then nothing more
    /// is answered 408 once its time is up, and gives its submit turn back: the next
    /// submission is served (time is paused, so the wait costs the test nothing).
    #[tokio::test(start_paused = true)]
    async fn a_trickled_upload_times_out_and_frees_its_turn() {
        let app = router(CoordinatorService::new(Timing::default()), WebConfig::default());
        let stalled = |app: axum::Router| async move {
            let first = tokio_stream::once(Ok::<_, std::io::Error>(bytes::Bytes::from_static(
                b"--x\r\ncontent-disposition: form-data; name=\"scene\"; filename=\"a.toml\"\r\n\r\n",
            )));
            let body = Body::from_stream(first.chain(tokio_stream::pending()));
            let request = Request::builder()
                .method("POST")
                .uri("/api/jobs")
                .header("host", "127.0.0.1")
                .header("content-type", "multipart/form-data; boundary=x")
                .header("content-length", "1000")
                .body(body)
                .unwrap();
            let response = app.oneshot(request).await.unwrap();
            let status = response.status();
            let body = axum::body::to_bytes(response.into_body(), 1 << 20).await.unwrap();
            (status, String::from_utf8(body.to_vec()).unwrap())
        };
        // More stalled senders than there are submit turns: each must give its turn back.
        for _ in 0..tessera_coordinator::service::SUBMITS_AT_ONCE + 1 {
            // Without a deadline the request would never end: bound the test itself.
            let (status, body) =
                tokio::time::timeout(std::time::Duration::from_secs(3600), stalled(app.clone()))
                    .await
                    .expect("a stalled upload was never answered");
            assert_eq!(status, StatusCode::REQUEST_TIMEOUT, "{body}");
            assert!(body.contains("did not arrive within 30 s"), "{body}");
        }
    }
}
