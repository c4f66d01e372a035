//! End-to-end: sequences. One job renders many frames of an animated scene; every frame is
//! byte-identical for one and two workers, alone or in a sequence, and after the
//! coordinator is killed and restarted mid-sequence; every frame's pass one comes before
//! any pass two; the files get their frame numbers; bad `--frames` input is one line.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tessera_harness::{FakeViewer, FakeWorker, Harness};
use tessera_proto::v1 as pb;

fn scene() -> PathBuf {
    root().join("tests/scenes/animated.toml")
}

/// `tessera render` of frames `frames` into `dir/shot_####.exr`; the files by frame.
fn render_frames(dir: &Path, frames: &str, workers: u32, extra: &[&str]) -> Vec<(u32, Vec<u8>)> {
    std::fs::create_dir_all(dir).unwrap();
    let out = dir.join("shot_####.exr");
    render_local(&scene(), &out, workers, &[&["--frames", frames], extra].concat());
    let mut files: Vec<(u32, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .map(|p| {
            let name = p.file_name().unwrap().to_str().unwrap().to_string();
            let n = name
                .strip_prefix("shot_")
                .and_then(|s| s.strip_suffix(".exr"))
                .unwrap_or_else(|| panic!("{name}"));
            assert_eq!(n.len(), 4, "{name}: the frame number is padded to the # run");
            (n.parse().unwrap(), read(&p))
        })
        .collect();
    files.sort();
    files
}

#[test]
fn every_frame_has_the_same_bytes_for_one_and_two_workers_and_alone() {
    let dir = tempfile::tempdir().unwrap();
    let one = render_frames(&dir.path().join("one"), "1-4", 1, &[]);
    let two = render_frames(&dir.path().join("two"), "1-4", 2, &[]);
    assert_eq!(one.iter().map(|f| f.0).collect::<Vec<_>>(), [1, 2, 3, 4], "one file per frame, named by it");
    for ((f, a), (_, b)) in one.iter().zip(&two) {
        assert!(a == b, "frame {f} differs between 1 and 2 workers");
    }
    // The animation moves: frames differ.
    assert!(one[0].1 != one[3].1, "frames 1 and 4 are the same image");
    // A frame rendered alone is the sequence's frame.
    let alone = render_frames(&dir.path().join("alone"), "3", 2, &[]);
    assert_eq!(alone.len(), 1);
    assert!(alone[0] == one[2], "frame 3 alone differs from frame 3 of the sequence");
}

/// Runs `tessera args` expecting failure; its stderr, which must be one line (logs at
/// `warn`, as a person runs it: the test helpers' `info` would add the coordinator's lines).
fn one_line_error(args: &[&str]) -> String {
    let o = tessera().env("RUST_LOG", "warn").args(args).output().unwrap();
    assert!(!o.status.success(), "{args:?} succeeded");
    let err = String::from_utf8_lossy(&o.stderr).trim().to_string();
    assert_eq!(err.lines().count(), 1, "{args:?}: not one line:\n{err}");
    err
}

#[test]
fn bad_frames_input_gets_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene();
    let s = s.to_str().unwrap();
    let pattern = dir.path().join("shot_####.png");
    let pattern = pattern.to_str().unwrap();
    let render = |frames: &str, out: &str| one_line_error(&["render", s, "-o", out, "--frames", frames]);
    assert_eq!(render("5-2", pattern), "error: --frames 5-2: the range is reversed");
    assert_eq!(
        render("1-20000", pattern),
        "error: --frames 1-20000: 20000 frames, more than the limit of 10000 in one job"
    );
    assert_eq!(
        render("one", pattern),
        "error: --frames one: expected a frame range such as 1-48 (or one frame, 12), got \"one\""
    );
    let single = dir.path().join("shot.png");
    let e = render("1-4", single.to_str().unwrap());
    assert!(e.ends_with("4 frames would all be written to this one name; put a run of # where the frame number goes, e.g. shot_####.exr"), "{e}");
    // Frames beyond the scene's animation, refused by the coordinator's validation.
    let e = render("2-9", pattern);
    assert!(e.contains("frames 2-9: the scene's animation has frames 1-4 ([animation] frames)"), "{e}");
    // Submit checks the same, before any network traffic.
    let e = one_line_error(&["submit", s, "--coordinator", "http://127.0.0.1:9", "--frames", "5-2"]);
    assert_eq!(e, "error: --frames 5-2: the range is reversed");
    assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none(), "a refused render wrote something");
}

/// A sequence's status over gRPC: (state, samples done, total, each frame's (done, total)).
type Sequence = (String, u64, u64, Vec<(u64, u64)>);

fn frames_status(url: &str) -> Option<Sequence> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let channel = tonic::transport::Endpoint::from_shared(url.to_string()).ok()?.connect().await.ok()?;
        let mut client = pb::coordinator_client::CoordinatorClient::new(channel);
        let s = client.status(pb::StatusRequest { job_id: 1 }).await.ok()?.into_inner();
        let j = s.jobs.into_iter().next()?;
        let frames = j.frame_status.iter().map(|f| (f.samples_done, f.samples_total)).collect();
        let state = tessera_proto::convert::state_name(j.state).to_string();
        Some((state, j.samples_done, j.samples_total, frames))
    })
}

fn wait_status(url: &str, what: &str, done: impl Fn(&Sequence) -> bool) -> Sequence {
    let start = std::time::Instant::now();
    loop {
        if let Some(s) = frames_status(url).filter(&done) {
            return s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "{what}: not within 120 s: {:?}",
            frames_status(url)
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A standalone farm renders the sequence to `tessera render`'s bytes; a finished frame is
/// fetchable, final, while later frames render; the coordinator SIGKILLed mid-sequence and
/// restarted on its data directory takes the job up from its checkpoint, and every frame
/// still ends with the same bytes.
#[test]
fn a_coordinator_killed_mid_sequence_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    // Large enough that the job outlives a few checkpoints on one thread.
    let size = ["--size", "256x176", "--spp", "16"];
    let reference = render_frames(&dir.path().join("reference"), "1-4", 2, &size);
    let data = dir.path().join("data");
    let addr = free_loopback_addr();
    let args = ["--data", data.to_str().unwrap(), "--checkpoint-interval", "0.2"];
    let coord = Coordinator::start_at(&addr, &args, &[]);
    let o = run(&[
        &["submit", scene().to_str().unwrap(), "--coordinator", &coord.url, "--frames", "1-4"][..],
        &size,
    ]
    .concat());
    assert!(o.status.success(), "submit: {}", String::from_utf8_lossy(&o.stderr));
    let worker = coord.worker(1);
    // Frame 1 done while frame 4's samples are not all in: fetch it now.
    let s = wait_status(&coord.url, "frame 1 done", |s| s.3.first().is_some_and(|f| f.0 == f.1));
    assert!(s.3[3].0 < s.3[3].1, "frame 4 was done as soon as frame 1: {s:?}");
    let early = dir.path().join("early.exr");
    let o = run(&["fetch", "1", "--frame", "1", "-o", early.to_str().unwrap(), "--coordinator", &coord.url]);
    assert!(o.status.success(), "fetch: {}", String::from_utf8_lossy(&o.stderr));
    assert!(read(&early) == reference[0].1, "frame 1 fetched early is not its final image");
    let status = coord.status();
    assert!(status.contains("frames 1-4: "), "{status}");
    // Kill in the middle of the sequence, after a checkpoint had time to be written.
    let before = wait_status(&coord.url, "mid-sequence", |s| s.1 * 10 > s.2 * 4);
    assert_eq!(before.0, "running", "{before:?}");
    coord.proc.signal(9);
    drop(coord);
    drop(worker);
    let coord = Coordinator::start_at(&addr, &args, &[]);
    let line = coord.proc.wait_for("resumed job 1 ", Duration::from_secs(30));
    let kept: u64 = line.split(" of ").next().unwrap().rsplit(' ').next().unwrap().parse().unwrap();
    assert!(kept > 0, "nothing kept across the restart: {line}");
    eprintln!(
        "killed at {} of {} samples (frames {:?}); the restart kept {kept}",
        before.1, before.2, before.3
    );
    let _w = coord.worker(1);
    wait_status(&coord.url, "job done", |s| s.0 == "done");
    let pattern = dir.path().join("after_#.exr");
    for (frame, want) in &reference {
        let out = Path::new(&pattern).with_file_name(format!("after_{frame}.exr"));
        let f = frame.to_string();
        let o =
            run(&["fetch", "1", "--frame", &f, "-o", pattern.to_str().unwrap(), "--coordinator", &coord.url]);
        assert!(o.status.success(), "fetch: {}", String::from_utf8_lossy(&o.stderr));
        assert!(read(&out) == *want, "frame {frame} differs after the restart");
    }
    // A frame the job does not have.
    let o =
        run(&["fetch", "1", "--frame", "9", "-o", pattern.to_str().unwrap(), "--coordinator", &coord.url]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("job 1 has frames 1-4, not frame 9"), "{err}");
}

/// Through the service: a fake worker taking one batch at a time sees every frame's pass
/// one before any pass two, frames in order, each batch naming its frame with pixels
/// inside one frame; a viewer of frame 3 ends with exactly frame 3's image.
#[tokio::test]
async fn every_frame_s_pass_one_comes_before_any_pass_two() {
    let h = Harness::start().await.unwrap();
    let (width, height) = (20, 12);
    let settings = pb::RenderSettings {
        spp: 3,
        width,
        height,
        frames: Some(pb::FrameRange { first: 1, last: 4 }),
        ..Default::default()
    };
    let text = std::fs::read_to_string(scene()).unwrap();
    let job = tessera_harness::submit(&h.channel(), "animated.toml", &text, settings).await.unwrap();
    let mut viewer = FakeViewer::watch_frame(&h.channel(), job.0, Some(3), 0.0, true).await.unwrap();
    let mut w = FakeWorker::connect(&h.channel(), "fake", 1).await.unwrap();
    let mut order: Vec<(u32, u32)> = Vec::new();
    loop {
        let Some(m) = w.next_within(Duration::from_millis(500)).await.unwrap() else { break };
        let tessera_proto::v1::coordinator_message::Msg::Batch(b) = m else { continue };
        assert!(b.pixels.chunks(2).all(|p| p[0] < width && p[1] < height), "pixels outside a frame");
        if order.last() != Some(&(b.pass, b.frame)) {
            order.push((b.pass, b.frame));
        }
        w.answer(&b).await.unwrap();
    }
    let progress = h.wait_over(job).await.unwrap();
    assert_eq!(progress.state.name(), "done");
    let want: Vec<(u32, u32)> = [1, 2].iter().flat_map(|&p| (1..=4).map(move |f| (p, f))).collect();
    assert_eq!(order, want, "batches by (pass, frame) as they came");
    assert_eq!(progress.frames, Some((1, 4)));
    assert!(progress.frame_progress.iter().all(|f| f.samples_done == f.samples_total && f.samples_total > 0));
    viewer.until_final().await.unwrap();
    let frame3 = tessera_harness::fetch_frame_image(&h.channel(), job, Some(3)).await.unwrap();
    assert_eq!((frame3.width, frame3.height), (width, height));
    assert_eq!(viewer.image_bytes().unwrap(), frame3.bytes, "the viewer's frame 3 is not frame 3");
    let frame1 = tessera_harness::fetch_frame_image(&h.channel(), job, Some(1)).await.unwrap();
    // The fake worker's values depend on the pixel in its frame only: a batch's pixels are
    // in-frame coordinates, so every frame is the same image.
    assert_eq!(frame1.bytes, frame3.bytes, "the batches' pixels were not frame coordinates");
}
