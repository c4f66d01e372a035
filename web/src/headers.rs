//! The security headers of every answer: `nosniff` (a JSON error or an image is never
//! taken for a page or a script), no framing (no clickjacking of the control buttons),
//! and a Content-Security-Policy that lets the pages load only their own scripts, styles
//! and connections (the pages in `assets/` have no inline script, handler or style
//! attribute; the icon is a `data:` URL; the live canvas is drawn from WebSocket bytes with
//! `putImageData` and downloads are plain links, so no `blob:` source is needed).

use axum::extract::Request;
use axum::http::header::{CONTENT_SECURITY_POLICY, X_CONTENT_TYPE_OPTIONS, X_FRAME_OPTIONS};
use axum::http::HeaderValue;
use axum::middleware::Next;
use axum::response::Response;

/// The pages' policy.
pub(crate) const CSP: &str =
    "default-src 'self'; img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'";

/// The layer: adds the headers to whatever the routes answered.
pub(crate) async fn secure(request: Request, next: Next) -> Response {
    let mut response = next.run(request).await;
    let h = response.headers_mut();
    h.insert(X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(CONTENT_SECURITY_POLICY, HeaderValue::from_static(CSP));
    response
}
