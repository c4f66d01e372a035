//! The live sockets: a snapshot, then deltas that end in the final image; sockets of one
//! job share one viewer slot, and a job takes at most 32.

use std::time::{Duration, Instant};

use serde_json::Value;

use crate::web::{client, small_form, submit_ok, Web};

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
