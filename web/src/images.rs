//! `GET /api/jobs/{id}/image.png` and `image.exr`: the job's current image through the
//! FetchImage RPC, encoded in memory as `tessera fetch` would write it.

use std::io::Cursor;

use axum::extract::{Path, Query, State};
use axum::http::header::{CACHE_CONTROL, CONTENT_DISPOSITION, CONTENT_TYPE};
use axum::http::HeaderValue;
use axum::response::{IntoResponse, Response};
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;
use tokio_stream::StreamExt;

use crate::caller::{job_id, request, Caller};
use crate::errors::ApiError;
use crate::AppState;

/// An image format the API serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Png,
    Exr,
}

/// `?frame=N`: the frame of a sequence an image or live request names (absent: its first).
#[derive(Debug, Clone, Copy, Default, serde::Deserialize)]
pub(crate) struct FrameQuery {
    pub frame: Option<u32>,
}

/// A job's current image (of frame `frame` of a sequence, `None`: its first): width,
/// height, linear RGB top row first.
pub(crate) async fn fetch_frame(
    state: &AppState,
    caller: &Caller,
    id: u64,
    frame: Option<u32>,
) -> Result<(u32, u32, Vec<f32>), ApiError> {
    let mut stream = Coordinator::fetch_image(
        &state.service,
        request(&caller.0, pb::FetchImageRequest { job_id: id, frame, ..Default::default() }),
    )
    .await?
    .into_inner();
    let mut size = None;
    let mut rgb = Vec::new();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk?;
        let (w, h) = *size.get_or_insert((chunk.width, chunk.height));
        if (chunk.width, chunk.height) != (w, h) || chunk.rgb.len() % 4 != 0 {
            return Err(ApiError::new(
                axum::http::StatusCode::INTERNAL_SERVER_ERROR,
                format!("job {id}: the image came in inconsistent chunks"),
            ));
        }
        rgb.extend(chunk.rgb.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])));
    }
    let (w, h) = size.ok_or_else(|| ApiError::not_found(format!("job {id} has no image")))?;
    Ok((w, h, rgb))
}

/// `rgb` encoded: PNG sRGB 8-bit or EXR linear float, the bytes `tessera_film::output`
/// writes to a file.
pub(crate) fn encode(
    format: Format,
    width: u32,
    height: u32,
    rgb: Vec<f32>,
) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Cursor::new(Vec::new());
    match format {
        Format::Png => {
            let bytes: Vec<u8> = rgb.iter().map(|&v| tessera_film::output::srgb8(v)).collect();
            image::RgbImage::from_raw(width, height, bytes)
                .expect("the chunks filled the image")
                .write_to(&mut out, image::ImageFormat::Png)?;
        }
        Format::Exr => image::Rgb32FImage::from_raw(width, height, rgb)
            .expect("the chunks filled the image")
            .write_to(&mut out, image::ImageFormat::OpenExr)?,
    }
    Ok(out.into_inner())
}

async fn image(
    state: AppState,
    caller: Caller,
    raw: String,
    frame: Option<u32>,
    format: Format,
) -> Result<Response, ApiError> {
    let id = job_id(&raw)?;
    let (w, h, rgb) = fetch_frame(&state, &caller, id, frame).await?;
    if rgb.len() != w as usize * h as usize * 3 {
        return Err(ApiError::new(
            axum::http::StatusCode::INTERNAL_SERVER_ERROR,
            format!("job {id}: {} values for a {w}x{h} image", rgb.len()),
        ));
    }
    let bytes = tokio::task::spawn_blocking(move || encode(format, w, h, rgb))
        .await
        .map_err(|e| {
            ApiError::new(axum::http::StatusCode::INTERNAL_SERVER_ERROR, format!("encoding failed: {e}"))
        })?
        .map_err(|e| {
            ApiError::new(
                axum::http::StatusCode::INTERNAL_SERVER_ERROR,
                format!("job {id}: encoding failed: {e}"),
            )
        })?;
    let (mime, ext) = match format {
        Format::Png => ("image/png", "png"),
        Format::Exr => ("image/x-exr", "exr"),
    };
    let name = frame.map_or(format!("job-{id}"), |f| format!("job-{id}-frame-{f}"));
    let disposition = HeaderValue::from_str(&format!("inline; filename=\"{name}.{ext}\"")).expect("ASCII");
    Ok((
        [
            (CONTENT_TYPE, HeaderValue::from_static(mime)),
            (CONTENT_DISPOSITION, disposition),
            (CACHE_CONTROL, HeaderValue::from_static("no-store")),
        ],
        bytes,
    )
        .into_response())
}

/// `GET /api/jobs/{id}/image.png`.
pub(crate) async fn png(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
    Query(q): Query<FrameQuery>,
) -> Result<Response, ApiError> {
    image(state, caller, raw, q.frame, Format::Png).await
}

/// `GET /api/jobs/{id}/image.exr`.
pub(crate) async fn exr(
    State(state): State<AppState>,
    caller: Caller,
    Path(raw): Path<String>,
    Query(q): Query<FrameQuery>,
) -> Result<Response, ApiError> {
    image(state, caller, raw, q.frame, Format::Exr).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoded_png_is_the_file_output_writes() {
        let (w, h) = (5u32, 3u32);
        let rgb: Vec<f32> = (0..w * h * 3).map(|i| i as f32 / 45.0).collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        tessera_film::output::write_image(&path, w, h, &rgb).unwrap();
        assert_eq!(encode(Format::Png, w, h, rgb.clone()).unwrap(), std::fs::read(&path).unwrap());
        let path = dir.path().join("a.exr");
        tessera_film::output::write_image(&path, w, h, &rgb).unwrap();
        assert_eq!(encode(Format::Exr, w, h, rgb).unwrap(), std::fs::read(&path).unwrap());
    }
}
