//! End-to-end: `tessera bench load` on a small mesh scene prints a row per run and the
//! medians, with every phase (the figures are not checked: a benchmark is not a test, but
//! it must keep working).

mod common;

use common::*;
use std::time::Duration;

#[test]
fn the_load_benchmark_prints_every_phase_per_run() {
    let scene = root().join("scenes/mesh.toml");
    let scene = scene.to_str().expect("a UTF-8 path");
    let out =
        run_with_timeout(&["bench", "load", scene, "--runs", "2", "--threads", "1"], Duration::from_secs(60));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    for phase in ["read+parse OBJ", "validation", "primitives", "BVH build", "slots", "total"] {
        assert!(stdout.contains(phase), "{phase}:\n{stdout}");
    }
    // Six phases and the total, wall and CPU each: 14 figures a row.
    let figures = |l: &&str| l.split('|').skip(1).flat_map(|c| c.split_whitespace()).count();
    let rows: Vec<&str> = (stdout.lines())
        .filter(|l| l.contains('|'))
        .filter(|l| l.split_whitespace().next().is_some_and(|w| w == "median" || w.parse::<u32>().is_ok()))
        .collect();
    assert_eq!(rows.len(), 3, "two runs and the medians:\n{stdout}");
    assert!(rows.iter().all(|l| figures(l) == 14), "{stdout}");
    assert!(stdout.contains("load average"), "{stdout}");
    assert!(stdout.lines().any(|l| l.contains("primitives; load average")), "{stdout}");

    let missing = run_with_timeout(&["bench", "load", "no/such/scene.toml"], Duration::from_secs(30));
    assert!(!missing.status.success());
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(stderr.contains("no/such/scene.toml"), "{stderr}");
}
