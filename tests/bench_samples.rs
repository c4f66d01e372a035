//! End-to-end: `tessera bench samples` prints a row per run and the median, and its image
//! checksum tells images apart: the same for one and two threads (rows rendered in another
//! interleaving, gathered in order) and another for another seed. Bad arguments get a one-line refusal. (The figures are not
//! checked: a benchmark is not a test, but it must keep working.)

mod common;

use common::*;
use std::time::Duration;

/// The checksum the median line ends with.
fn checksum(stdout: &str) -> String {
    let line =
        stdout.lines().find(|l| l.starts_with("median")).unwrap_or_else(|| panic!("no median:\n{stdout}"));
    line.rsplit("checksum ").next().unwrap().trim().to_string()
}

fn bench(scene: &str, threads: &str) -> String {
    let args =
        ["bench", "samples", scene, "--size", "40x30", "--spp", "5", "--threads", threads, "--runs", "2"];
    let out = run_with_timeout(&args, Duration::from_secs(60));
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

#[test]
fn the_samples_benchmark_reports_runs_and_one_checksum_for_any_thread_count() {
    let scene = root().join("scenes/spheres.toml");
    let scene = scene.to_str().expect("a UTF-8 path");
    let one = bench(scene, "1");
    assert_eq!(one.lines().filter(|l| l.starts_with("run ") && l.contains("Msamples/s")).count(), 2, "{one}");
    let two = bench(scene, "2");
    assert_eq!(checksum(&one), checksum(&two), "one thread:\n{one}\ntwo threads:\n{two}");
    assert_eq!(checksum(&one).len(), 16, "{one}");

    // Another seed is another image: the checksum tells images apart.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("scenes/spheres.toml")).unwrap();
    let seeded = dir.path().join("seeded.toml");
    std::fs::write(&seeded, text.replacen("[render]\n", "[render]\nseed = 7\n", 1)).unwrap();
    let other = bench(seeded.to_str().unwrap(), "1");
    assert_ne!(checksum(&one), checksum(&other), "{other}");

    for (args, says) in [
        (vec!["bench", "samples", scene, "--spp", "0"], "--spp"),
        (vec!["bench", "samples", scene, "--threads", "0"], "--threads"),
        (vec!["bench", "samples", scene, "--runs", "18446744073709551615"], "--runs at most 1000"),
        (vec!["bench", "samples", scene, "--threads", "1000000"], "--threads at most 1024"),
        (vec!["bench", "samples", scene, "--spp", "99999999"], "--spp 99999999"),
        (vec!["bench", "samples", scene, "--size", "100000x100000"], "--size 100000x100000"),
        (vec!["bench", "samples", "no/such/scene.toml"], "no/such/scene.toml"),
        // The tests' build has no `ab` switch: both sides would be the same code.
        (vec!["bench", "samples", scene, "--ab"], "--ab needs a build with the switch"),
    ] {
        let out = run_with_timeout(&args, Duration::from_secs(30));
        assert!(!out.status.success(), "{args:?} was accepted");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    }
}
