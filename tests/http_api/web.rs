//! A coordinator serving the web face, and the requests the tests make of it.

use std::time::{Duration, Instant};

use reqwest::blocking::{multipart, Client, Response};
use serde_json::Value;

use crate::common::{small_scene, Coordinator};

/// A coordinator serving the web face too, and its web address.
pub(crate) struct Web {
    pub(crate) coord: Coordinator,
    pub(crate) base: String,
}

impl Web {
    pub(crate) fn start(extra: &[&str]) -> Web {
        let mut args = vec!["--http", "127.0.0.1:0"];
        args.extend_from_slice(extra);
        let coord = Coordinator::start(&args);
        let line = coord.proc.wait_for("web dashboard on ", Duration::from_secs(30));
        let base = line.rsplit("web dashboard on ").next().unwrap().trim().to_string();
        Web { coord, base }
    }

    pub(crate) fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }
}

pub(crate) fn client() -> Client {
    Client::builder().timeout(Duration::from_secs(60)).build().unwrap()
}

/// The status and JSON body of a response that must be JSON.
pub(crate) fn json(r: Response) -> (u16, Value) {
    let status = r.status().as_u16();
    let text = r.text().unwrap();
    let value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{status}: not JSON ({e}): {text}"));
    (status, value)
}

/// Asserts a 4xx JSON error with `status` whose message contains `says`.
pub(crate) fn assert_error(r: Response, status: u16, says: &str) {
    let (got, body) = json(r);
    let message = body["error"].as_str().unwrap_or_else(|| panic!("no error field: {body}"));
    assert_eq!(got, status, "{message}");
    assert!(message.contains(says), "{status}: {message:?} does not say {says:?}");
}

/// The multipart form of the small scene at `size`, `spp`.
pub(crate) fn small_form(width: u32, height: u32, spp: u32) -> multipart::Form {
    let text = std::fs::read_to_string(small_scene()).unwrap();
    multipart::Form::new()
        .part("scene", multipart::Part::text(text).file_name("small.toml"))
        .text("width", width.to_string())
        .text("height", height.to_string())
        .text("spp", spp.to_string())
}

pub(crate) fn submit(web: &Web, token: Option<&str>, form: multipart::Form) -> Response {
    let mut r = client().post(web.url("/api/jobs")).multipart(form);
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    r.send().unwrap()
}

pub(crate) fn submit_ok(web: &Web, token: Option<&str>, form: multipart::Form) -> u64 {
    let (status, body) = json(submit(web, token, form));
    assert_eq!(status, 201, "{body}");
    body["id"].as_u64().unwrap()
}

pub(crate) fn job(web: &Web, token: Option<&str>, id: u64) -> Value {
    let mut r = client().get(web.url(&format!("/api/jobs/{id}")));
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    let (status, body) = json(r.send().unwrap());
    assert_eq!(status, 200, "{body}");
    body
}

pub(crate) fn wait_state(web: &Web, token: Option<&str>, id: u64, state: &str) -> Value {
    let start = Instant::now();
    loop {
        let j = job(web, token, id);
        if j["state"] == state {
            return j;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "job {id} never {state}: {j}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

pub(crate) fn post(web: &Web, token: Option<&str>, path: &str, body: Option<&str>) -> Response {
    let mut r = client().post(web.url(path));
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    if let Some(b) = body {
        r = r.header("content-type", "application/json").body(b.to_string());
    }
    r.send().unwrap()
}
