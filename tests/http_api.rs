//! The HTTP API end to end: a real `tessera coordinator --http` with real workers, driven
//! by an HTTP client and a WebSocket client as a browser or a script would.

mod common;

use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use common::{read, render_local, run, small_scene, write_secret, Coordinator, Proc};
use reqwest::blocking::{multipart, Client, Response};
use serde_json::Value;

const ADMIN: &str = "admin-token-0123456789";
const ALICE: &str = "alice-token-0123456789";
const BOB: &str = "bob-token-0123456789ab";
const VIEWER: &str = "viewer-token-012345678";

/// A coordinator serving the web face too, and its web address.
struct Web {
    coord: Coordinator,
    base: String,
}

impl Web {
    fn start(extra: &[&str]) -> Web {
        let mut args = vec!["--http", "127.0.0.1:0"];
        args.extend_from_slice(extra);
        let coord = Coordinator::start(&args);
        let line = coord.proc.wait_for("web dashboard on ", Duration::from_secs(30));
        let base = line.rsplit("web dashboard on ").next().unwrap().trim().to_string();
        Web { coord, base }
    }

    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }
}

fn client() -> Client {
    Client::builder().timeout(Duration::from_secs(60)).build().unwrap()
}

/// The status and JSON body of a response that must be JSON.
fn json(r: Response) -> (u16, Value) {
    let status = r.status().as_u16();
    let text = r.text().unwrap();
    let value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{status}: not JSON ({e}): {text}"));
    (status, value)
}

/// Asserts a 4xx JSON error with `status` whose message contains `says`.
fn assert_error(r: Response, status: u16, says: &str) {
    let (got, body) = json(r);
    let message = body["error"].as_str().unwrap_or_else(|| panic!("no error field: {body}"));
    assert_eq!(got, status, "{message}");
    assert!(message.contains(says), "{status}: {message:?} does not say {says:?}");
}

/// The multipart form of the small scene at `size`, `spp`.
fn small_form(width: u32, height: u32, spp: u32) -> multipart::Form {
    let text = std::fs::read_to_string(small_scene()).unwrap();
    multipart::Form::new()
        .part("scene", multipart::Part::text(text).file_name("small.toml"))
        .text("width", width.to_string())
        .text("height", height.to_string())
        .text("spp", spp.to_string())
}

fn submit(web: &Web, token: Option<&str>, form: multipart::Form) -> Response {
    let mut r = client().post(web.url("/api/jobs")).multipart(form);
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    r.send().unwrap()
}

fn submit_ok(web: &Web, token: Option<&str>, form: multipart::Form) -> u64 {
    let (status, body) = json(submit(web, token, form));
    assert_eq!(status, 201, "{body}");
    body["id"].as_u64().unwrap()
}

fn job(web: &Web, token: Option<&str>, id: u64) -> Value {
    let mut r = client().get(web.url(&format!("/api/jobs/{id}")));
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    let (status, body) = json(r.send().unwrap());
    assert_eq!(status, 200, "{body}");
    body
}

fn wait_state(web: &Web, token: Option<&str>, id: u64, state: &str) -> Value {
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

fn post(web: &Web, token: Option<&str>, path: &str, body: Option<&str>) -> Response {
    let mut r = client().post(web.url(path));
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    if let Some(b) = body {
        r = r.header("content-type", "application/json").body(b.to_string());
    }
    r.send().unwrap()
}

#[test]
fn a_job_submitted_over_http_gives_the_bytes_of_a_local_render() {
    let web = Web::start(&[]);
    let _worker = web.coord.worker(2);
    let id = submit_ok(&web, None, small_form(40, 30, 3));
    let done = wait_state(&web, None, id, "done");
    assert_eq!(
        (done["width"].as_u64(), done["height"].as_u64(), done["spp"].as_u64()),
        (Some(40), Some(30), Some(3))
    );
    assert_eq!(done["progress"], 1.0);
    assert_eq!(done["owner"], "anonymous");
    assert_eq!(done["scene"], "small.toml");
    let listing = json(client().get(web.url("/api/jobs")).send().unwrap()).1;
    assert_eq!(listing["jobs"][0]["id"], id);
    let worker = &listing["workers"][0];
    assert_eq!(worker["threads"], 2);
    assert!(worker["batches_done"].as_u64().unwrap() > 0, "{worker}");
    assert!(worker["last_heard_seconds"].as_f64().unwrap() < 10.0, "{worker}");

    let png = client().get(web.url(&format!("/api/jobs/{id}/image.png"))).send().unwrap();
    assert_eq!(png.status(), 200);
    assert_eq!(png.headers()["content-type"], "image/png");
    let png = png.bytes().unwrap().to_vec();
    let dir = tempfile::tempdir().unwrap();
    // FetchImage of the same job, written by `tessera fetch`.
    let fetched = dir.path().join("fetched.png");
    let o =
        run(&["fetch", &id.to_string(), "-o", fetched.to_str().unwrap(), "--coordinator", &web.coord.url]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png, read(&fetched), "image.png differs from tessera fetch's file");
    // And a local render of the same scene and settings: the determinism contract.
    let local = dir.path().join("local.png");
    render_local(&small_scene(), &local, 1, &["--size", "40x30", "--spp", "3"]);
    assert_eq!(png, read(&local), "image.png differs from tessera render's file");
    let exr = client().get(web.url(&format!("/api/jobs/{id}/image.exr"))).send().unwrap();
    assert_eq!(exr.status(), 200);
    let fetched = dir.path().join("fetched.exr");
    let o =
        run(&["fetch", &id.to_string(), "-o", fetched.to_str().unwrap(), "--coordinator", &web.coord.url]);
    assert!(o.status.success());
    assert_eq!(exr.bytes().unwrap().to_vec(), read(&fetched));
}

#[test]
fn pause_resume_priority_and_cancel_act_on_the_job() {
    // No worker: the job stays queued, so every transition is the control's doing.
    let web = Web::start(&[]);
    let id = submit_ok(&web, None, small_form(16, 16, 2));
    assert_eq!(job(&web, None, id)["state"], "queued");
    assert_eq!(post(&web, None, &format!("/api/jobs/{id}/pause"), None).status(), 204);
    assert_eq!(job(&web, None, id)["state"], "paused");
    assert_eq!(post(&web, None, &format!("/api/jobs/{id}/resume"), None).status(), 204);
    assert_eq!(job(&web, None, id)["state"], "queued");
    let r = post(&web, None, &format!("/api/jobs/{id}/priority"), Some(r#"{"priority": 7}"#));
    assert_eq!(r.status(), 204);
    assert_eq!(job(&web, None, id)["priority"], 7);
    // The CLI's priority goes through the same RPC.
    let o = run(&["priority", &id.to_string(), "-3", "--coordinator", &web.coord.url]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(job(&web, None, id)["priority"], -3);
    assert_eq!(post(&web, None, &format!("/api/jobs/{id}/cancel"), None).status(), 204);
    assert_eq!(job(&web, None, id)["state"], "cancelled");
    assert_error(post(&web, None, &format!("/api/jobs/{id}/resume"), None), 409, "is cancelled");
    // A cancelled job's image is still there (black: nothing rendered).
    assert_eq!(client().get(web.url(&format!("/api/jobs/{id}/image.png"))).send().unwrap().status(), 200);
}

/// A canvas the binary live messages are drawn on, as the job page draws them.
struct Canvas {
    rgba: Vec<u8>,
    resets: usize,
    deltas: usize,
    final_seen: bool,
}

impl Canvas {
    fn apply(&mut self, m: &[u8]) {
        let u32_at = |i: usize| u32::from_le_bytes(m[i..i + 4].try_into().unwrap());
        assert_eq!(u32_at(0), 0x5453_5231, "magic");
        let flags = u32_at(12);
        let runs = u32_at(16) as usize;
        if flags & 1 != 0 {
            self.rgba.iter_mut().for_each(|b| *b = 0);
            self.resets += 1;
        } else {
            self.deltas += 1;
        }
        self.final_seen |= flags & 2 != 0;
        let mut at = 20;
        for _ in 0..runs {
            let (start, len) = (u32_at(at) as usize, u32_at(at + 4) as usize);
            at += 8;
            self.rgba[start * 4..(start + len) * 4].copy_from_slice(&m[at..at + len * 4]);
            at += len * 4;
        }
        assert_eq!(at, m.len(), "trailing bytes");
    }
}

#[test]
fn the_live_socket_sends_a_snapshot_then_deltas_that_end_in_the_final_image() {
    let web = Web::start(&[]);
    let id = submit_ok(&web, None, small_form(48, 36, 400));
    let url = web.url(&format!("/api/jobs/{id}/live")).replace("http://", "ws://");
    let (mut socket, _) = tungstenite::connect(url.as_str()).expect("the live socket opens");
    let hello: Value = serde_json::from_str(socket.read().unwrap().to_text().unwrap()).unwrap();
    assert_eq!(hello["type"], "hello");
    assert_eq!((hello["width"].as_u64(), hello["height"].as_u64()), (Some(48), Some(36)));
    // The worker joins once the browser watches, so the image refines under its eyes.
    let _worker = web.coord.worker(1);
    let mut canvas = Canvas { rgba: vec![0; 48 * 36 * 4], resets: 0, deltas: 0, final_seen: false };
    let mut statuses = 0;
    let start = Instant::now();
    while !canvas.final_seen {
        assert!(start.elapsed() < Duration::from_secs(60), "no final update");
        match socket.read().expect("the socket stays open until the final update") {
            tungstenite::Message::Binary(m) => canvas.apply(&m),
            tungstenite::Message::Text(t) => {
                let v: Value = serde_json::from_str(&t).unwrap();
                assert_eq!(v["type"], "status");
                assert_eq!(v["job"]["id"], id);
                statuses += 1;
            }
            other => panic!("unexpected message {other:?}"),
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    let images = canvas.resets + canvas.deltas;
    eprintln!("live: {images} image messages, {statuses} status messages in {elapsed:.2} s");
    assert!(
        images as f64 <= elapsed * 10.0 + 2.0,
        "more than 10 image messages a second: {images} in {elapsed} s"
    );
    assert_eq!(canvas.resets, 1, "one snapshot at the start");
    assert!(canvas.deltas >= 1, "deltas after the snapshot");
    assert!(statuses >= 1);
    // Closed by the server after the final update.
    match socket.read() {
        Ok(tungstenite::Message::Close(_)) | Err(_) => {}
        Ok(other) => panic!("expected the close after the final update, got {other:?}"),
    }
    let png = client().get(web.url(&format!("/api/jobs/{id}/image.png"))).send().unwrap().bytes().unwrap();
    let image = image::load_from_memory(&png).unwrap().to_rgba8();
    assert_eq!(canvas.rgba, image.into_raw(), "the canvas ends as the final image");
}

#[test]
fn two_live_sockets_of_one_job_share_one_viewer_slot_and_both_end_in_the_final_image() {
    let web = Web::start(&[]);
    let id = submit_ok(&web, None, small_form(40, 30, 300));
    let url = web.url(&format!("/api/jobs/{id}/live")).replace("http://", "ws://");
    let mut sockets: Vec<_> = (0..2)
        .map(|_| {
            let (mut s, _) = tungstenite::connect(url.as_str()).expect("the live socket opens");
            let hello: Value = serde_json::from_str(s.read().unwrap().to_text().unwrap()).unwrap();
            assert_eq!(hello["type"], "hello");
            s
        })
        .collect();
    let viewers = || -> f64 {
        let text = client().get(web.url("/metrics")).send().unwrap().text().unwrap();
        text.lines()
            .find_map(|l| l.strip_prefix("tessera_viewers ").map(|v| v.trim().parse().unwrap()))
            .unwrap_or_else(|| panic!("no tessera_viewers in {text}"))
    };
    assert_eq!(viewers(), 1.0, "two sockets of one job hold one Watch viewer slot");
    let _worker = web.coord.worker(1);
    let start = Instant::now();
    let mut canvases = Vec::new();
    for socket in &mut sockets {
        let mut canvas = Canvas { rgba: vec![0; 40 * 30 * 4], resets: 0, deltas: 0, final_seen: false };
        while !canvas.final_seen {
            assert!(start.elapsed() < Duration::from_secs(60), "no final update");
            match socket.read().expect("the socket stays open until the final update") {
                tungstenite::Message::Binary(m) => canvas.apply(&m),
                tungstenite::Message::Text(t) => {
                    assert_eq!(serde_json::from_str::<Value>(&t).unwrap()["type"], "status");
                }
                other => panic!("unexpected message {other:?}"),
            }
        }
        assert_eq!(canvas.resets, 1, "one snapshot at the start");
        canvases.push(canvas.rgba);
    }
    let png = client().get(web.url(&format!("/api/jobs/{id}/image.png"))).send().unwrap().bytes().unwrap();
    let image = image::load_from_memory(&png).unwrap().to_rgba8().into_raw();
    for (i, c) in canvases.iter().enumerate() {
        assert!(c == &image, "socket {i}'s canvas differs from the final image");
    }
    // Both gone and the job over: the shared task has left its slot.
    drop(sockets);
    let gone = Instant::now();
    while viewers() != 0.0 {
        assert!(gone.elapsed() < Duration::from_secs(10), "the viewer slot is still held");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_job_takes_at_most_32_live_sockets_and_a_closed_one_frees_its_place() {
    // No worker: the job stays queued, so the sockets stay open.
    let web = Web::start(&[]);
    let id = submit_ok(&web, None, small_form(8, 8, 1));
    let url = web.url(&format!("/api/jobs/{id}/live")).replace("http://", "ws://");
    let open = || tungstenite::connect(url.as_str());
    let mut sockets: Vec<_> = (0..32).map(|_| open().expect("the live socket opens").0).collect();
    match open() {
        Err(tungstenite::Error::Http(r)) => {
            assert_eq!(r.status(), 503);
            let body = String::from_utf8_lossy(r.body().as_deref().unwrap_or_default()).to_string();
            assert!(body.contains("already has 32 live sockets"), "{body}");
        }
        other => panic!("expected a 503 for the 33rd socket, got {:?}", other.map(|_| ())),
    }
    sockets.pop().unwrap().close(None).unwrap();
    let start = Instant::now();
    loop {
        match open() {
            Ok((s, _)) => break sockets.push(s),
            Err(tungstenite::Error::Http(r)) if r.status() == 503 => {
                assert!(start.elapsed() < Duration::from_secs(10), "the closed socket's place stays taken");
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => panic!("{e}"),
        }
    }
}

fn write_tokens(dir: &Path) -> String {
    let path = dir.join("tokens");
    write_secret(
        &path,
        &format!("admin root {ADMIN}\nsubmitter alice {ALICE}\nsubmitter bob {BOB}\nviewer wall {VIEWER}\n"),
    );
    path.to_str().unwrap().to_string()
}

#[test]
fn roles_and_owners_are_checked_as_over_grpc() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let web = Web::start(&["--tokens", &tokens]);
    // No token, a bad one, a malformed header.
    assert_error(client().get(web.url("/api/jobs")).send().unwrap(), 401, "no token");
    assert_error(
        client().get(web.url("/api/jobs")).bearer_auth("nope-nope-nope-nope").send().unwrap(),
        401,
        "unknown token",
    );
    assert_error(
        client().get(web.url("/api/jobs")).header("authorization", ALICE).send().unwrap(),
        401,
        "Bearer TOKEN",
    );
    assert_error(submit(&web, None, small_form(8, 8, 1)), 401, "no token");
    // A viewer reads but may not submit or control.
    assert_error(submit(&web, Some(VIEWER), small_form(8, 8, 1)), 403, "may not submit");
    let alice_job = submit_ok(&web, Some(ALICE), small_form(8, 8, 1));
    assert_eq!(job(&web, Some(VIEWER), alice_job)["owner"], "alice");
    for action in ["pause", "resume", "cancel"] {
        assert_error(
            post(&web, Some(VIEWER), &format!("/api/jobs/{alice_job}/{action}"), None),
            403,
            "may not",
        );
    }
    assert_error(
        post(&web, Some(VIEWER), &format!("/api/jobs/{alice_job}/priority"), Some(r#"{"priority":0}"#)),
        403,
        "may not change priorities",
    );
    // Another submitter neither sees nor controls alice's job.
    assert_error(
        client().get(web.url(&format!("/api/jobs/{alice_job}"))).bearer_auth(BOB).send().unwrap(),
        403,
        "another submitter",
    );
    assert_error(
        post(&web, Some(BOB), &format!("/api/jobs/{alice_job}/cancel"), None),
        403,
        "another submitter",
    );
    assert_error(
        client().get(web.url(&format!("/api/jobs/{alice_job}/image.png"))).bearer_auth(BOB).send().unwrap(),
        403,
        "another submitter",
    );
    let bobs = json(client().get(web.url("/api/jobs")).bearer_auth(BOB).send().unwrap()).1;
    assert_eq!(bobs["jobs"].as_array().unwrap().len(), 0, "{bobs}");
    // A submitter's priority is capped by --max-priority (0), as in Submit.
    assert_error(
        post(&web, Some(ALICE), &format!("/api/jobs/{alice_job}/priority"), Some(r#"{"priority":5}"#)),
        403,
        "--max-priority",
    );
    assert_eq!(
        post(&web, Some(ADMIN), &format!("/api/jobs/{alice_job}/priority"), Some(r#"{"priority":5}"#))
            .status(),
        204
    );
    // The live socket: no token, no upgrade.
    let url = web.url(&format!("/api/jobs/{alice_job}/live")).replace("http://", "ws://");
    match tungstenite::connect(url.as_str()) {
        Err(tungstenite::Error::Http(r)) => assert_eq!(r.status().as_u16(), 401),
        other => panic!("expected 401, got {:?}", other.map(|(_, r)| r.status())),
    }
    // ?token= is not a way in.
    match tungstenite::connect(format!("{url}?token={ALICE}").as_str()) {
        Err(tungstenite::Error::Http(r)) => assert_eq!(r.status().as_u16(), 401),
        other => panic!("expected 401, got {:?}", other.map(|(_, r)| r.status())),
    }

    // The browser's way: a login sets the session cookie.
    let login = client()
        .post(web.url("/api/login"))
        .header("content-type", "application/json")
        .body(format!(r#"{{"token":"{ALICE}"}}"#))
        .send()
        .unwrap();
    assert_eq!(login.status(), 204);
    let cookie = login.headers()["set-cookie"].to_str().unwrap().to_string();
    for attribute in ["tessera_session=", "HttpOnly", "SameSite=Strict", "Max-Age=43200", "Path=/"] {
        assert!(cookie.contains(attribute), "{cookie}");
    }
    assert!(!cookie.contains("Secure"), "plain HTTP: no Secure flag: {cookie}");
    let session = cookie.split(';').next().unwrap().to_string();
    let who = json(client().get(web.url("/api/whoami")).header("cookie", &session).send().unwrap());
    assert_eq!(who, (200, serde_json::json!({"name": "alice", "role": "submitter"})));
    let (status, listing) =
        json(client().get(web.url("/api/jobs")).header("cookie", &session).send().unwrap());
    assert_eq!(status, 200);
    assert_eq!(listing["jobs"][0]["id"], alice_job);
    let r = client().post(web.url("/api/logout")).header("cookie", &session).send().unwrap();
    assert_eq!(r.status(), 204);
    assert_error(
        client().get(web.url("/api/whoami")).header("cookie", &session).send().unwrap(),
        401,
        "log in again",
    );
    assert_error(
        client()
            .post(web.url("/api/login"))
            .header("content-type", "application/json")
            .body(r#"{"token":"wrong-wrong-wrong-wrong"}"#)
            .send()
            .unwrap(),
        401,
        "unknown token",
    );
    assert_error(
        client()
            .post(web.url("/api/login"))
            .header("content-type", "application/json")
            .body("{token")
            .send()
            .unwrap(),
        400,
        "bad JSON",
    );
}

/// Sends raw bytes to `addr` and returns the response head and body read within 10 s.
fn raw_request(addr: &str, request: &[u8]) -> String {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(request).unwrap();
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    while let Ok(n) = s.read(&mut buf) {
        if n == 0 {
            break;
        }
        out.extend_from_slice(&buf[..n]);
        if String::from_utf8_lossy(&out).contains("}") {
            break;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

#[test]
fn bad_input_gets_a_clear_4xx_json_error() {
    let web = Web::start(&[]);
    let addr = web.base.trim_start_matches("http://").to_string();
    // An upload declared too large is refused from its headers, before any of it is sent.
    let response = raw_request(
        &addr,
        b"POST /api/jobs HTTP/1.1\r\nhost: 127.0.0.1\r\ncontent-type: multipart/form-data; boundary=b\r\ncontent-length: 300000000\r\n\r\n",
    );
    assert!(response.starts_with("HTTP/1.1 413"), "{response}");
    assert!(response.contains(r#"{"error":"POST /api/jobs: an upload of 300000000 bytes"#), "{response}");
    // No declared length (chunked): refused, not read without bound.
    let response = raw_request(
        &addr,
        b"POST /api/jobs HTTP/1.1\r\nhost: 127.0.0.1\r\ncontent-type: multipart/form-data; boundary=b\r\ntransfer-encoding: chunked\r\n\r\n",
    );
    assert!(response.starts_with("HTTP/1.1 411"), "{response}");
    let c = client();
    let malformed = c
        .post(web.url("/api/jobs"))
        .header("content-type", "multipart/form-data; boundary=xyz")
        .body("--xyz\r\ncontent-disposition: form-data; name=\"scene\"; filename=\"s.toml\"\r\n\r\nno end")
        .send()
        .unwrap();
    assert_error(malformed, 400, "malformed multipart");
    assert_error(c.post(web.url("/api/jobs")).body("plain").send().unwrap(), 400, "multipart");
    assert_error(submit(&web, None, multipart::Form::new().text("spp", "4")), 400, "no `scene` part");
    assert_error(submit(&web, None, small_form(8, 8, 1).text("bogus", "1")), 400, "unknown part \"bogus\"");
    assert_error(
        submit(&web, None, small_form(8, 8, 1).text("spp", "many")),
        400,
        "`spp` \"many\" is not a whole number",
    );
    let traversal = small_form(8, 8, 1)
        .part("asset", multipart::Part::bytes(b"x".to_vec()).file_name("../../etc/passwd"));
    assert_error(submit(&web, None, traversal), 400, "escapes the scene's folder");
    let scene_error = multipart::Form::new()
        .part("scene", multipart::Part::text("[render]\nwidth = -1\n").file_name("bad.toml"));
    assert_error(submit(&web, None, scene_error), 400, "bad.toml:2");
    // Too many parts: refused once counted past the limit (the form written out by hand:
    // reqwest takes tens of seconds to build one of 65 545 parts).
    let mut many =
        b"--b\r\ncontent-disposition: form-data; name=\"scene\"; filename=\"s.toml\"\r\n\r\n[render]\r\n"
            .to_vec();
    for _ in 0..65_545 {
        many.extend_from_slice(b"--b\r\ncontent-disposition: form-data; name=\"spp\"\r\n\r\n1\r\n");
    }
    many.extend_from_slice(b"--b--\r\n");
    let r = c
        .post(web.url("/api/jobs"))
        .header("content-type", "multipart/form-data; boundary=b")
        .body(many)
        .send()
        .unwrap();
    assert_error(r, 400, "more than 65543 parts");
    // Bad JSON, unknown jobs, non-numeric ids, unknown routes.
    assert_error(post(&web, None, "/api/jobs/1/priority", Some("{\"priority\":")), 400, "bad JSON");
    assert_error(
        post(&web, None, "/api/jobs/1/priority", Some(r#"{"priority":1,"x":2}"#)),
        400,
        "unknown field",
    );
    assert_error(c.get(web.url("/api/jobs/99")).send().unwrap(), 404, "no job 99");
    assert_error(post(&web, None, "/api/jobs/99/cancel", None), 404, "no job 99");
    assert_error(c.get(web.url("/api/jobs/99/image.png")).send().unwrap(), 404, "no job 99");
    assert_error(c.get(web.url("/api/jobs/abc")).send().unwrap(), 400, "\"abc\" is not a positive integer");
    assert_error(c.get(web.url("/api/jobs/0")).send().unwrap(), 400, "not a positive integer");
    assert_error(post(&web, None, "/api/jobs/-1/pause", None), 400, "not a positive integer");
    assert_error(c.get(web.url("/api/nothing")).send().unwrap(), 404, "no route /api/nothing");
    assert_error(
        c.get(web.url("/assets/..%2F..%2FCargo.toml")).send().unwrap(),
        400,
        "not a plain relative path",
    );
    assert_error(c.get(web.url("/assets/missing.js")).send().unwrap(), 404, "no page");
    assert_error(c.get(web.url("/api/jobs/1/live")).send().unwrap(), 404, "no job 1");
    // The coordinator is still well.
    assert_eq!(c.get(web.url("/healthz")).send().unwrap().text().unwrap(), "ok");
}

#[test]
fn events_stream_the_listing_when_it_changes() {
    let web = Web::start(&[]);
    let mut events = client().get(web.url("/api/events")).send().unwrap();
    assert_eq!(events.headers()["content-type"], "text/event-stream");
    let mut seen = String::new();
    let mut buf = [0u8; 4096];
    let first = |s: &str| s.contains("event: status") && s.contains(r#"data: {"jobs":[],"workers":[]}"#);
    while !first(&seen) {
        let n = events.read(&mut buf).unwrap();
        assert!(n > 0, "{seen}");
        seen.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    let id = submit_ok(&web, None, small_form(8, 8, 1));
    while !seen.contains(&format!(r#""id":{id},"scene":"small.toml","state":"queued""#)) {
        let n = events.read(&mut buf).unwrap();
        assert!(n > 0, "{seen}");
        seen.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
}

#[test]
fn https_serves_with_the_grpc_certificate_and_secure_cookies() {
    let dir = tempfile::tempdir().unwrap();
    let pki = dir.path().to_str().unwrap();
    for args in
        [vec!["certs", "ca", "--dir", pki], vec!["certs", "server", "--dir", pki, "--host", "127.0.0.1"]]
    {
        let o = run(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let tokens = write_tokens(dir.path());
    let (cert, key) = (dir.path().join("server.pem"), dir.path().join("server.key"));
    let web = Web::start(&[
        "--tls-cert",
        cert.to_str().unwrap(),
        "--tls-key",
        key.to_str().unwrap(),
        "--tokens",
        &tokens,
    ]);
    assert!(web.base.starts_with("https://"), "{}", web.base);
    let ca = reqwest::Certificate::from_pem(&read(&dir.path().join("ca.pem"))).unwrap();
    let c = Client::builder().add_root_certificate(ca).tls_built_in_root_certs(false).build().unwrap();
    assert_eq!(c.get(web.url("/healthz")).send().unwrap().text().unwrap(), "ok");
    let login = c
        .post(web.url("/api/login"))
        .header("content-type", "application/json")
        .body(format!(r#"{{"token":"{ADMIN}"}}"#))
        .send()
        .unwrap();
    assert_eq!(login.status(), 204);
    assert!(login.headers()["set-cookie"].to_str().unwrap().contains("; Secure"));
    // Plain HTTP to the HTTPS port is not served.
    assert!(client().get(web.url("/healthz").replace("https://", "http://")).send().is_err());
}

#[test]
fn a_web_port_beyond_loopback_without_authentication_is_refused() {
    let mut p = Proc::spawn(&["coordinator", "--listen", "127.0.0.1:0", "--http", "0.0.0.0:0"]);
    let status = p.wait(Duration::from_secs(30));
    assert!(!status.success());
    let err = p.stderr.lock().unwrap().clone();
    assert!(err.contains("--http: refusing to listen on 0.0.0.0:0 with no authentication"), "{err}");
}
