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
