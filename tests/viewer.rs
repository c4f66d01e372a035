//! End-to-end: viewers attached at any moment end with the coordinator's bytes, and an
//! early snapshot shows the mosaic.

mod common;

use common::*;
use std::time::Duration;

/// A viewer attached at about 30 % and one attached after the end both end with an image
/// byte-identical to the one `submit` fetches from the coordinator.
#[test]
fn viewers_end_byte_identical_to_the_coordinators_image() {
    let dir = tempfile::tempdir().unwrap();
    let coord = Coordinator::start(&[]);
    let _worker = coord.worker(1);
    let out = dir.path().join("farm.png");
    let mut submit = Proc::spawn(&[
        "submit",
        small_scene().to_str().unwrap(),
        "--coordinator",
        &coord.url,
        "-o",
        out.to_str().unwrap(),
        "--spp",
        "2048",
    ]);
    let start = std::time::Instant::now();
    let mut at = 0.0;
    while at < 25.0 {
        assert!(start.elapsed() < Duration::from_secs(60), "no progress");
        std::thread::sleep(Duration::from_millis(20));
        at = job_percent(&coord.status(), 1);
    }
    assert!(at < 90.0, "the render went too fast to attach mid-way ({at}%)");
    let during = dir.path().join("during.png");
    let viewer = run(&["view", "--coordinator", &coord.url, "--save", during.to_str().unwrap()]);
    assert!(viewer.status.success(), "{}", String::from_utf8_lossy(&viewer.stderr));
    assert!(submit.wait(Duration::from_secs(120)).success(), "{}", submit.stderr.lock().unwrap());
    assert_eq!(read(&during), read(&out), "viewer attached at {at:.0}% differs from the coordinator's image");

    // A second job exists now; the viewer asks for the first by id, after its end.
    let o = run(&[
        "submit",
        small_scene().to_str().unwrap(),
        "--coordinator",
        &coord.url,
        "--spp",
        "2",
        "--wait",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let after_png = dir.path().join("after.png");
    let o = run(&["view", "--coordinator", &coord.url, "--job", "1", "--save", after_png.to_str().unwrap()]);
    assert!(o.status.success());
    assert_eq!(read(&after_png), read(&out), "viewer attached after the end differs");
}

/// An early snapshot (a fraction of pass one) is the mosaic: every pixel painted by the
/// block of the finest computed pixel, not a black image with a few dots.
#[test]
fn early_snapshot_shows_the_mosaic() {
    let dir = tempfile::tempdir().unwrap();
    let coord = Coordinator::start(&[]);
    // Queue the job with no worker yet, so that the viewer sees it from its first pixel.
    // Large enough that pass one takes a while on one thread.
    let scene = small_scene();
    let args =
        ["submit", scene.to_str().unwrap(), "--coordinator", &coord.url, "--spp", "64", "--size", "320x240"];
    let o = run(&args);
    assert!(o.status.success());
    let early = dir.path().join("early.png");
    let mut viewer = Proc::spawn(&[
        "view",
        "--coordinator",
        &coord.url,
        "--save",
        early.to_str().unwrap(),
        "--at",
        "0.02",
    ]);
    std::thread::sleep(Duration::from_millis(300));
    let _worker = coord.worker(1);
    assert!(viewer.wait(Duration::from_secs(60)).success(), "{}", viewer.stderr.lock().unwrap());
    let img = image::open(&early).unwrap().to_rgb8();
    assert!(img.pixels().all(|p| p.0 != [0, 0, 0]), "the early snapshot has unpainted (black) pixels");
    let distinct: std::collections::HashSet<_> = img.pixels().map(|p| p.0).collect();
    let n = (img.width() * img.height()) as usize;
    assert!(distinct.len() < n / 4, "{} distinct colours in {n} pixels: not a mosaic", distinct.len());
    assert!(distinct.len() > 4, "only {} colours: not refined at all", distinct.len());
}

/// Bad requests: a job that does not exist, a coordinator that is not there.
#[test]
fn viewing_a_missing_job_or_coordinator_is_a_clear_error() {
    let coord = Coordinator::start(&[]);
    let o = run(&["view", "--coordinator", &coord.url, "--job", "7", "--save", "/tmp/never.png"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("no job 7"), "{err}");
    let o = run(&["view", "--coordinator", &coord.url, "--save", "/tmp/never.png"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("no jobs yet"), "{err}");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let o = run(&["view", "--coordinator", &format!("http://127.0.0.1:{port}"), "--save", "/tmp/never.png"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("cannot reach coordinator"), "{err}");
    // No display: the window cannot open, and the message says how to go headless.
    let o = tessera()
        .args(["view", "--coordinator", &coord.url])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("cannot open a window") && err.contains("--save"), "{err}");
}

/// The tev bridge speaks tev's protocol: a fake tev on loopback parses `CreateImage` and
/// `UpdateImage` v3 packets and ends with the coordinator's exact floats.
#[test]
fn tev_bridge_sends_the_exact_image() {
    use std::io::Read;
    let dir = tempfile::tempdir().unwrap();
    let coord = Coordinator::start(&[]);
    let _worker = coord.worker(2);
    let exr = dir.path().join("out.exr");
    let o = run(&[
        "submit",
        small_scene().to_str().unwrap(),
        "--coordinator",
        &coord.url,
        "-o",
        exr.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let fake_tev = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let mut bytes = Vec::new();
        s.read_to_end(&mut bytes).unwrap();
        let (mut size, mut image, mut creates) = ((0usize, 0usize), Vec::<f32>::new(), 0);
        let mut at = 0;
        while at < bytes.len() {
            let len = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
            let p = &bytes[at + 4..at + len];
            at += len;
            let mut i = 2; // type, grab focus
            let string = |i: &mut usize| {
                let end = p[*i..].iter().position(|&b| b == 0).unwrap();
                let s = String::from_utf8(p[*i..*i + end].to_vec()).unwrap();
                *i += end + 1;
                s
            };
            let int = |i: &mut usize| {
                *i += 4;
                i32::from_le_bytes(p[*i - 4..*i].try_into().unwrap()) as usize
            };
            assert!(string(&mut i).starts_with("tessera job 1"));
            match p[0] {
                4 => {
                    size = (int(&mut i), int(&mut i));
                    assert_eq!(int(&mut i), 3);
                    image = vec![f32::NAN; size.0 * size.1 * 3];
                    creates += 1;
                }
                6 => {
                    assert_eq!(int(&mut i), 3);
                    let names: Vec<String> = (0..3).map(|_| string(&mut i)).collect();
                    assert_eq!(names, ["R", "G", "B"]);
                    let (x, y, w, h) = (int(&mut i), int(&mut i), int(&mut i), int(&mut i));
                    assert_eq!((x, w), (0, size.0));
                    i += 48; // offsets 0, 1, 2 and strides 3, 3, 3 (i64)
                    let floats = &p[i..];
                    assert_eq!(floats.len(), w * h * 3 * 4);
                    for (k, v) in floats.chunks_exact(4).enumerate() {
                        image[y * w * 3 + k] = f32::from_le_bytes(v.try_into().unwrap());
                    }
                }
                t => panic!("unexpected packet type {t}"),
            }
        }
        assert_eq!(creates, 1);
        (size, image)
    });
    let o = run(&["view", "--coordinator", &coord.url, "--job", "1", "--tev", &addr]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ((w, h), got) = fake_tev.join().unwrap();
    let want = image::open(&exr).unwrap().to_rgb32f();
    assert_eq!((w as u32, h as u32), want.dimensions());
    assert_eq!(got, want.into_raw(), "tev received other floats than the coordinator's image");
}

/// With no job running, a viewer without --job lists the jobs to choose from; a
/// coordinator that goes away mid-stream and stays away past --reconnect-for is a clear
/// error, after the last image is saved.
#[test]
fn viewer_lists_jobs_and_survives_a_lost_coordinator() {
    let dir = tempfile::tempdir().unwrap();
    let coord = Coordinator::start(&[]);
    let _worker = coord.worker(1);
    for _ in 0..2 {
        let o = run(&[
            "submit",
            small_scene().to_str().unwrap(),
            "--coordinator",
            &coord.url,
            "--spp",
            "2",
            "--wait",
        ]);
        assert!(o.status.success());
    }
    let o = run(&["view", "--coordinator", &coord.url, "--save", "/tmp/never.png"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("choose one with --job: 1 (done"), "{err}");

    let o = run(&["submit", small_scene().to_str().unwrap(), "--coordinator", &coord.url, "--spp", "8192"]);
    assert!(o.status.success());
    let out = dir.path().join("last.png");
    let mut viewer = Proc::spawn(&[
        "view",
        "--coordinator",
        &coord.url,
        "--save",
        out.to_str().unwrap(),
        "--reconnect-for",
        "1",
    ]);
    std::thread::sleep(Duration::from_millis(800));
    coord.proc.signal(9);
    let status = viewer.wait(Duration::from_secs(30));
    let err = viewer.stderr.lock().unwrap().clone();
    assert!(!status.success() && err.contains("gave up reconnecting after 1s"), "{err}");
    assert!(out.exists(), "the last image was not saved: {err}");
}
