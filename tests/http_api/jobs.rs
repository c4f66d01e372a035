//! Jobs over HTTP: a submitted job's images are a local render's bytes, the controls act
//! on it, and the event stream follows the listing.

use std::io::Read;

use crate::common::{read, render_local, run, small_scene};
use crate::web::{assert_error, client, job, json, post, small_form, submit_ok, wait_state, Web};

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

/// How a job may end before its spp travels with its status: the API's job, and the line
/// `tessera status` prints under it. No worker: the job stays queued.
#[test]
fn a_jobs_noise_target_and_time_budget_show_in_the_api_and_the_status() {
    let web = Web::start(&[]);
    let form =
        small_form(16, 16, 64).text("noise_absolute", "0.05").text("noise_min", "32").text("time", "90s");
    let id = submit_ok(&web, None, form);
    let j = job(&web, None, id);
    assert_eq!(j["noise"]["kind"], "absolute", "{j}");
    assert_eq!(j["noise"]["target"], 0.05, "{j}");
    assert_eq!(j["noise"]["min_samples"], 32, "{j}");
    assert_eq!(j["time_limit_seconds"], 90.0, "{j}");
    let plain = submit_ok(&web, None, small_form(16, 16, 2));
    let j = job(&web, None, plain);
    assert!(j.get("noise").is_none() && j.get("time_limit_seconds").is_none(), "{j}");
    let status = web.coord.status();
    assert!(
        status.contains(
            "ends at an absolute noise of 0.05, each pixel after at least 32 samples, or when its time budget of 90s is spent"
        ),
        "{status}"
    );
    assert_eq!(status.matches("ends ").count(), 1, "only the job with a target says how it ends: {status}");
    // A target every pixel meets at its minimum: done at 4 of 64 samples, and said so.
    for queued in [id, plain] {
        assert_eq!(post(&web, None, &format!("/api/jobs/{queued}/cancel"), None).status(), 204);
    }
    let _worker = web.coord.worker(1);
    let met =
        submit_ok(&web, None, small_form(16, 16, 64).text("noise_absolute", "1000").text("noise_min", "4"));
    let done = wait_state(&web, None, met, "done");
    assert_eq!(
        (done["progress"].as_f64(), done["ended_by"].as_str()),
        (Some(1.0), Some("noise target")),
        "{done}"
    );
    assert_eq!(done["samples_done"], 16 * 16 * 4, "{done}");
    let status = web.coord.status();
    assert!(
        status.contains("ended by its noise target at 4.0 samples a pixel on average, of at most 64"),
        "{status}"
    );
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
