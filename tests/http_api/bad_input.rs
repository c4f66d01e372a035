//! Bad input gets a clear 4xx JSON error, and the coordinator stays well.

use std::io::{Read, Write};
use std::time::Duration;

use reqwest::blocking::multipart;

use crate::web::{assert_error, client, post, small_form, submit, Web};

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
    assert_error(
        submit(&web, None, small_form(8, 8, 1).text("noise_absolute", "-1")),
        400,
        "noise_absolute must be a positive number",
    );
    assert_error(
        submit(&web, None, small_form(8, 8, 1).text("noise", "0.1").text("noise_absolute", "0.1")),
        400,
        "not both",
    );
    assert_error(
        submit(&web, None, small_form(8, 8, 16).text("noise_min", "4")),
        400,
        "without a noise target",
    );
    assert_error(
        submit(&web, None, small_form(8, 8, 16).text("noise", "0.1").text("noise_min", "some")),
        400,
        "`noise_min` \"some\" is not a whole number",
    );
    assert_error(
        submit(&web, None, small_form(8, 8, 16).text("noise", "0.1").text("noise_min", "0")),
        400,
        "`noise_min` \"0\" is not a whole number of at least 2 samples",
    );
    assert_error(
        submit(&web, None, small_form(8, 8, 16).text("noise_absolute", "0.1").text("noise_min", "32")),
        400,
        "minimum of 32 samples is more than the job's 16 samples per pixel",
    );
    let traversal = small_form(8, 8, 1)
        .part("asset", multipart::Part::bytes(b"x".to_vec()).file_name("../../etc/passwd"));
    assert_error(submit(&web, None, traversal), 400, "escapes the scene's folder");
    let scene_error = multipart::Form::new()
        .part("scene", multipart::Part::text("[render]\nwidth = -1\n").file_name("bad.toml"));
    assert_error(submit(&web, None, scene_error), 400, "bad.toml:2");
    // Too many parts: refused once counted past the limit (the form written out by hand:
    // reqwest takes tens of seconds to build one of 65 546 parts).
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
    assert_error(r, 400, "more than 65545 parts");
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
