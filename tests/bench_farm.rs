//! End-to-end: a tiny `tessera bench farm` runs and prints its table (the figures are not
//! checked: a benchmark is not a test, but it must keep working). The image is large enough
//! that its job outlasts the warm-up and both rounds (a case whose job ended is left out of
//! the summary).

mod common;

use common::*;
use std::time::Duration;

#[test]
fn a_tiny_farm_benchmark_prints_its_table() {
    let out = run_with_timeout(
        &[
            "bench",
            "farm",
            "--sizes",
            "96x96",
            "--workers",
            "2",
            "--viewers",
            "0,1",
            "--seconds",
            "0.5",
            "--batch-ms",
            "20",
            "--rounds",
            "2",
        ],
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("commit/s") && stdout.contains("lease p50/99"), "{stdout}");
    let rows: Vec<&str> = stdout
        .lines()
        .filter(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            // A row: size, then the worker count (the summary's lines say "2w").
            f.len() >= 15 && f[0] == "96x96" && f[1].parse::<u32>().is_ok()
        })
        .collect();
    assert_eq!(rows.len(), 4, "one row per case and round:\n{stdout}");
    assert!(stdout.contains("targets:"), "{stdout}");
    // The viewer case's ratio, taken within each round, summarised over both.
    assert!(stdout.contains("96x96 2w 1v 20 ms:") && stdout.contains("median of 2 rounds"), "{stdout}");
}
