//! The HTTP API end to end: a real `tessera coordinator --http` with real workers, driven
//! by an HTTP client and a WebSocket client as a browser or a script would.
//!
//! The parts: `web` (the coordinator under test and the requests made to it), `jobs`
//! (submit, images, control, the event stream), `live` (the live sockets), `access` (roles,
//! owners, sessions, HTTPS, the loopback rule) and `bad_input` (clear 4xx errors). One test
//! binary (each file in `tests/` costs a link), its parts in `tests/http_api/`.

mod common;

#[path = "http_api/access.rs"]
mod access;
#[path = "http_api/bad_input.rs"]
mod bad_input;
#[path = "http_api/jobs.rs"]
mod jobs;
#[path = "http_api/live.rs"]
mod live;
#[path = "http_api/web.rs"]
mod web;
