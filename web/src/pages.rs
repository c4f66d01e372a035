//! The dashboard's pages and their scripts and styles, embedded in the binary from
//! `web/assets/` (also in debug builds: nothing is read from disk at run time).

use axum::extract::Path;
use axum::http::header::{CACHE_CONTROL, CONTENT_TYPE};
use axum::http::HeaderValue;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

use crate::errors::ApiError;
use crate::AppState;

#[derive(rust_embed::Embed)]
#[folder = "assets/"]
struct Assets;

pub(crate) fn routes() -> Router<AppState> {
    Router::new()
        .route("/", get(|| async { page("index.html") }))
        .route("/jobs/{id}", get(job_page))
        .route("/assets/{*path}", get(asset))
}

/// An embedded file with its content type, or 404.
fn page(path: &str) -> Result<Response, ApiError> {
    let file = Assets::get(path).ok_or_else(|| ApiError::not_found(format!("no page {path}")))?;
    let mime = file.metadata.mimetype();
    let mime = HeaderValue::from_str(mime).unwrap_or(HeaderValue::from_static("application/octet-stream"));
    Ok((
        [(CONTENT_TYPE, mime), (CACHE_CONTROL, HeaderValue::from_static("no-cache"))],
        file.data.into_owned(),
    )
        .into_response())
}

/// `/jobs/{id}`: the job page (which reads its id from the address).
async fn job_page(Path(raw): Path<String>) -> Result<Response, ApiError> {
    crate::caller::job_id(&raw)?;
    page("job.html")
}

/// `/assets/{path}`: a file of the folder; no path leaves it.
async fn asset(Path(path): Path<String>) -> Result<Response, ApiError> {
    if path.split(['/', '\\']).any(|part| part == ".." || part.is_empty()) || path.contains('\0') {
        let shown: String = path.chars().take(80).collect();
        return Err(ApiError::bad_request(format!("asset path {shown:?} is not a plain relative path")));
    }
    page(&path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_index_page_is_embedded() {
        let r = page("index.html").unwrap();
        assert_eq!(r.headers()[CONTENT_TYPE], "text/html");
        assert!(page("nothing-here.js").is_err());
    }
}
