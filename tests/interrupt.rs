//! End-to-end: Ctrl-C on `tessera render` still writes the unfinished image and leaves no
//! process behind.

mod common;

use common::*;
use std::time::Duration;

/// The processes (other than ourselves) whose environment carries `tag`.
fn processes_with_tag(tag: &str) -> Vec<u32> {
    let needle = format!("TESSERA_TEST_TAG={tag}");
    let mut pids = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else { continue };
        if pid == std::process::id() {
            continue;
        }
        if let Ok(env) = std::fs::read(entry.path().join("environ")) {
            if env.split(|b| *b == 0).any(|kv| kv == needle.as_bytes()) {
                // A zombie still has no environ to read; a live one does.
                pids.push(pid);
            }
        }
    }
    pids
}

#[test]
fn sigint_writes_unfinished_image_and_leaves_no_process() {
    if !std::path::Path::new("/proc/self/environ").exists() {
        eprintln!("skipped: needs /proc to find child processes");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("partial.png");
    let tag = format!("interrupt-{}", std::process::id());
    let mut child = tessera()
        .env("TESSERA_TEST_TAG", &tag)
        .args([
            "render",
            small_scene().to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--workers",
            "2",
            "--spp",
            "8192",
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until the local workers run (the render's children carry the tag).
    let start = std::time::Instant::now();
    while processes_with_tag(&tag).len() < 3 {
        assert!(start.elapsed() < Duration::from_secs(30), "workers never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(700));
    std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(start.elapsed() < Duration::from_secs(30), "render did not stop after SIGINT");
        std::thread::sleep(Duration::from_millis(20));
    };
    let stderr = std::io::read_to_string(child.stderr.take().unwrap()).unwrap();
    assert_eq!(status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("interrupted at"), "{stderr}");
    let img = image::open(&out).expect("the unfinished image was written").to_rgb8();
    assert_eq!(img.dimensions(), (64, 48));
    // The mosaic covers the frame: no pixel is left black (the scene has no black).
    assert!(img.pixels().all(|p| p.0 != [0, 0, 0]), "unfinished image has unpainted pixels");
    let start = std::time::Instant::now();
    while !processes_with_tag(&tag).is_empty() {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "processes left behind: {:?}",
            processes_with_tag(&tag)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Ctrl-C, then `--resume`: the render continues from its checkpoint and ends in the bytes
/// of an uninterrupted render. Without `--resume` the checkpoint is not silently discarded,
/// and a checkpoint of other settings is refused.
#[test]
fn sigint_then_resume_gives_the_uninterrupted_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let scene = root().join("scenes/showcase.toml");
    // Long enough (several seconds on one thread) that the interrupt below, 1.5 s in,
    // comes while it renders on any machine this runs on: the showcase got faster twice
    // (its motion blur, then its moving mesh as one instance: 16 spp took 3.6 s, 32 take 6.9).
    let settings = ["--size", "640x480", "--spp", "32"];
    let reference = dir.path().join("reference.png");
    render_local(&scene, &reference, 2, &settings);

    let out = dir.path().join("out.png");
    let checkpoint = dir.path().join("out.png.tessera");
    let mut args = vec!["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--workers", "1"];
    args.extend_from_slice(&["--threads", "1", "--checkpoint-interval", "0.3"]);
    args.extend_from_slice(&settings);
    let mut first = Proc::spawn(&args);
    // Interrupt once the checkpointer has had time to write: rendering is under way.
    std::thread::sleep(Duration::from_millis(1500));
    assert!(checkpoint.join("jobs.db").exists(), "no checkpoint while rendering");
    first.signal(2);
    let status = first.wait(Duration::from_secs(30));
    let stderr = first.stderr.lock().unwrap().clone();
    assert_eq!(status.code(), Some(130), "the render finished before the interrupt: {stderr}");
    assert!(stderr.contains("--resume"), "{stderr}");

    let again = run(&args);
    assert!(!again.status.success());
    let msg = String::from_utf8_lossy(&again.stderr);
    assert!(msg.contains("holds an interrupted render") && msg.contains("--resume"), "{msg}");

    let mut other: Vec<&str> = args.iter().map(|a| if *a == "32" { "16" } else { a }).collect();
    other.push("--resume");
    let refused = run(&other);
    assert!(!refused.status.success());
    let msg = String::from_utf8_lossy(&refused.stderr);
    assert!(msg.contains("different scene or settings"), "{msg}");

    let mut resume = args.clone();
    resume.push("--resume");
    let o = run(&resume);
    let msg = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{msg}");
    assert!(msg.contains("resumed job 1"), "{msg}");
    assert_eq!(read(&out), read(&reference), "resumed render differs from the uninterrupted one");
    assert!(!checkpoint.exists(), "the checkpoint outlived the finished render");
}

/// The same with a noise target, relative or absolute: an adaptive render interrupted and
/// resumed ends in the bytes of an uninterrupted one (its decisions depend on merged
/// samples only, and the checkpoint keeps the even-sample sums they are made from; the
/// store keeps which kind of target it was, and its minimum: a resume without it is
/// refused).
#[test]
fn adaptive_render_resumes_to_the_same_bytes() {
    // As above: at most 32 samples a pixel the render ended (1.8 s) before the interrupt,
    // and at 240x135 it took 2.3 s once the showcase's knot became an instance (320x180:
    // 4.0 s). The absolute target takes at least 64 samples a pixel, so it runs longer, and
    // with a minimum of 96 (its round ends at 128) longer still.
    adaptive_resume_case(&["--size", "320x180", "--spp", "128", "--noise", "0.02"]);
    adaptive_resume_case(&["--size", "320x180", "--spp", "128", "--noise-abs", "0.01"]);
    adaptive_resume_case(&["--size", "240x135", "--spp", "256", "--noise-abs", "0.01", "--noise-min", "96"]);
}

fn adaptive_resume_case(settings: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let scene = root().join("scenes/showcase.toml");
    let reference = dir.path().join("reference.png");
    render_local(&scene, &reference, 2, settings);

    let out = dir.path().join("out.png");
    let mut args = vec!["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--workers", "1"];
    args.extend_from_slice(&["--threads", "1", "--checkpoint-interval", "0.3"]);
    args.extend_from_slice(settings);
    let mut first = Proc::spawn(&args);
    std::thread::sleep(Duration::from_millis(1500));
    first.signal(2);
    let status = first.wait(Duration::from_secs(30));
    assert_eq!(status.code(), Some(130), "finished before the interrupt: {}", first.stderr.lock().unwrap());
    let mut resume = args.clone();
    resume.push("--resume");
    if let Some(at) = resume.iter().position(|a| *a == "--noise-min") {
        let mut other = resume.clone();
        other.drain(at..at + 2);
        let refused = run(&other);
        let msg = String::from_utf8_lossy(&refused.stderr);
        assert!(!refused.status.success() && msg.contains("different scene or settings"), "{msg}");
    }
    let o = run(&resume);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(read(&out), read(&reference), "resumed adaptive render differs: {settings:?}");
}
