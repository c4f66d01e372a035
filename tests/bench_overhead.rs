//! End-to-end: `tessera bench overhead` renders the image it says on both sides (the scene's
//! or the one `--size` and `--spp` ask for), prints each run and the overhead, and refuses
//! sizes, sample counts and run counts a render would refuse before it starts tracing. (The
//! figures are not checked: a benchmark is not a test, but it must keep working.)

mod common;

use common::*;
use std::time::Duration;

#[test]
fn the_overhead_benchmark_renders_the_size_asked_for_and_refuses_what_a_render_would() {
    let scene = root().join("scenes/cornell.toml");
    let scene = scene.to_str().expect("a UTF-8 path");
    let args = ["bench", "overhead", scene, "--runs", "1", "--spp", "2", "--size", "32x24"];
    let out = run_with_timeout(&args, Duration::from_secs(120));
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("(32x24, 2 spp)"), "{stdout}");
    assert!(stdout.lines().any(|l| l.starts_with("run 1: one process")), "{stdout}");
    assert!(stdout.contains("farm overhead:"), "{stdout}");
    // The one process loads the scene inside its clock, and says how long that took.
    assert!(stdout.contains("(its load ") && stdout.contains("against the render alone"), "{stdout}");

    for (args, says) in [
        (vec!["bench", "overhead", scene, "--size", "100000x100000"], "--size 100000x100000"),
        (vec!["bench", "overhead", scene, "--spp", "0"], "--spp 0"),
        (vec!["bench", "overhead", scene, "--spp", "99999999"], "--spp 99999999"),
        (vec!["bench", "overhead", scene, "--runs", "0"], "--runs"),
        (vec!["bench", "overhead", scene, "--workers", "100000"], "--workers"),
        (vec!["bench", "overhead", scene, "--size", "0x10"], "WIDTHxHEIGHT"),
    ] {
        let out = run_with_timeout(&args, Duration::from_secs(30));
        assert!(!out.status.success(), "{args:?} was accepted");
        // One line says what (clap adds a line pointing at --help to its own refusals).
        let stderr = String::from_utf8_lossy(&out.stderr);
        let first = stderr.lines().next().unwrap_or_default();
        assert!(first.starts_with("error") && first.contains(says), "{args:?}: {stderr}");
    }
}
