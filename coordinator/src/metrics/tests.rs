//! The exposition after known events of a pure, seeded farm: names, labels and values.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
use tessera_description::job::JobSettings;

use super::*;
use crate::farm::{AuditPolicy, Farm};
use crate::scheduler::BatchSpec;

fn bundle() -> Bundle {
    let text = include_str!("../../../tests/scenes/small.toml");
    Bundle { name: "small.toml".into(), text: text.into(), assets: vec![], refused: vec![] }
}

/// Honest sums: a function of the pixel and the sample count only (as the farm tests').
fn honest(spec: &BatchSpec) -> Vec<u64> {
    let n = u64::from(spec.samples.end - spec.samples.start);
    spec.quads.iter().flat_map(|q| [1, 2, 3].map(|c| u64::from((q.x * 7 + q.y * 3 + c) % 11) * n)).collect()
}

fn text(farm: &Farm, now: Instant) -> String {
    Metrics::default().exposition(farm.census(now), 0)
}

/// The value of the sample `name` (with its labels as written) in `text`.
fn sample(text: &str, name: &str) -> Option<f64> {
    text.lines().find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
}

/// Every family is there, typed, on an empty farm; the state families list every state
/// (zero included), so that a query of one state never finds nothing.
#[test]
fn every_family_is_typed_and_every_state_listed() {
    let t = text(&Farm::new(), Instant::now());
    let families: BTreeSet<(&str, &str)> =
        t.lines().filter_map(|l| l.strip_prefix("# TYPE ")?.split_once(' ')).collect();
    let expected = [
        ("tessera_audits_begun_total", "counter"),
        ("tessera_audits_total", "counter"),
        ("tessera_build_info", "gauge"),
        ("tessera_checkpoint_failures_total", "counter"),
        ("tessera_checkpoint_write_seconds", "histogram"),
        ("tessera_duplicate_results_total", "counter"),
        ("tessera_jobs", "gauge"),
        ("tessera_leases_outstanding", "gauge"),
        ("tessera_leases_taken_back_total", "counter"),
        ("tessera_merge_seconds", "histogram"),
        ("tessera_quarantines_total", "counter"),
        ("tessera_repaired_pixels_total", "counter"),
        ("tessera_samples_merged_total", "counter"),
        ("tessera_samples_per_second", "gauge"),
        ("tessera_samples_queued", "gauge"),
        ("tessera_scene_bytes_sent_total", "counter"),
        ("tessera_scenes_sent_total", "counter"),
        ("tessera_strikes_total", "counter"),
        ("tessera_viewers", "gauge"),
        ("tessera_workers", "gauge"),
    ];
    assert_eq!(families, expected.into_iter().collect(), "{t}");
    for state in JOB_STATES {
        assert_eq!(sample(&t, &format!("tessera_jobs{{state=\"{state}\"}}")), Some(0.0), "{t}");
    }
    for state in ["busy", "idle", "silent", "quarantined"] {
        assert_eq!(sample(&t, &format!("tessera_workers{{state=\"{state}\"}}")), Some(0.0), "{t}");
    }
    assert!(t.contains(&format!("tessera_build_info{{version=\"{}\"", env!("CARGO_PKG_VERSION"))), "{t}");
    assert_eq!(sample(&t, "tessera_merge_seconds_bucket{le=\"+Inf\"}"), Some(0.0), "{t}");
}

/// Scenes sent whole count their bytes; scenes sent by their hash count apart.
#[test]
fn scenes_sent_whole_and_by_hash_are_counted_apart() {
    let m = Metrics::default();
    m.observe_scene_sent(Some(36_000_000));
    m.observe_scene_sent(None);
    m.observe_scene_sent(None);
    m.observe_scene_sent(Some(1_000));
    let t = m.exposition(Farm::new().census(Instant::now()), 0);
    assert_eq!(sample(&t, "tessera_scenes_sent_total{how=\"whole\"}"), Some(2.0), "{t}");
    assert_eq!(sample(&t, "tessera_scenes_sent_total{how=\"by_hash\"}"), Some(2.0), "{t}");
    assert_eq!(sample(&t, "tessera_scene_bytes_sent_total"), Some(36_001_000.0), "{t}");
}

/// Queued samples are what queued and running jobs still need, not what paused or ended
/// ones do; jobs are counted by state.
#[test]
fn queued_samples_count_queued_and_running_jobs_only() {
    let mut farm = Farm::new();
    let now = Instant::now();
    let settings = JobSettings::sized(Some(3), Some((8, 8)));
    let running = farm.submit(bundle(), settings.clone(), 0).unwrap();
    let _queued = farm.submit(bundle(), settings.clone(), 0).unwrap();
    let paused = farm.submit(bundle(), settings.clone(), 0).unwrap();
    let cancelled = farm.submit(bundle(), settings, 0).unwrap();
    farm.set_paused(paused, true, now);
    farm.cancel(cancelled, now);
    let w = farm.add_worker("w".into(), 1, now);
    let a = farm.assign(w, now).unwrap();
    assert_eq!(a.job, running);
    farm.complete(w, &a.answer(&honest(&a.batch), None), now).unwrap();
    let t = text(&farm, now);
    let done = a.batch.sample_count();
    assert_eq!(sample(&t, "tessera_samples_queued"), Some((2 * 8 * 8 * 3 - done) as f64), "{t}");
    assert_eq!(sample(&t, "tessera_samples_merged_total"), Some(done as f64), "{t}");
    for (state, n) in [("queued", 1.0), ("running", 1.0), ("paused", 1.0), ("cancelled", 1.0), ("done", 0.0)]
    {
        assert_eq!(sample(&t, &format!("tessera_jobs{{state=\"{state}\"}}")), Some(n), "{state}: {t}");
    }
    assert_eq!(sample(&t, "tessera_workers{state=\"idle\"}"), Some(1.0), "{t}");
}

/// A silent worker's leases taken back are counted as re-leases for silence, and it shows
/// as silent until heard again; a worker that leaves gives its leases back as
/// "disconnected".
#[test]
fn leases_taken_back_from_silent_and_departed_workers_are_counted() {
    let mut farm = Farm::new();
    let t0 = Instant::now();
    farm.submit(bundle(), JobSettings::sized(Some(2), Some((16, 16))), 0).unwrap();
    let quiet = farm.add_worker("quiet".into(), 1, t0);
    let gone = farm.add_worker("gone".into(), 1, t0);
    farm.assign(quiet, t0).unwrap();
    farm.assign(gone, t0).unwrap();
    farm.assign(gone, t0).unwrap();
    let t = text(&farm, t0);
    assert_eq!(sample(&t, "tessera_leases_outstanding{kind=\"batch\"}"), Some(3.0), "{t}");
    assert_eq!(sample(&t, "tessera_workers{state=\"busy\"}"), Some(2.0), "{t}");

    let later = t0 + Duration::from_secs(11);
    farm.touch(gone, later);
    assert_eq!(farm.expire_silent(later, Duration::from_secs(10)).len(), 1);
    let t = text(&farm, later);
    assert_eq!(sample(&t, "tessera_leases_taken_back_total{reason=\"silent\"}"), Some(1.0), "{t}");
    assert_eq!(sample(&t, "tessera_workers{state=\"silent\"}"), Some(1.0), "{t}");
    assert_eq!(sample(&t, "tessera_leases_outstanding{kind=\"batch\"}"), Some(2.0), "{t}");

    farm.remove_worker(gone, later);
    let t = text(&farm, later);
    assert_eq!(sample(&t, "tessera_leases_taken_back_total{reason=\"disconnected\"}"), Some(2.0), "{t}");
    assert_eq!(sample(&t, "tessera_leases_outstanding{kind=\"batch\"}"), Some(0.0), "{t}");
    farm.touch(quiet, later);
    assert_eq!(sample(&text(&farm, later), "tessera_workers{state=\"idle\"}"), Some(1.0));
}

/// A liar's audited batch: the first re-render disagrees, a third identity decides, the
/// liar is quarantined and its pixels repaired; the counters say so, and its connection is
/// no longer counted as connected.
#[test]
fn an_audit_disagreement_quarantines_and_is_counted() {
    let mut farm = Farm::with_seed([5; 32]);
    farm.set_audit_policy(AuditPolicy { fraction: 1.0, probation_batches: 0, probation_fraction: 0.0 });
    let now = Instant::now();
    farm.submit(bundle(), JobSettings::sized(Some(2), Some((16, 16))), 0).unwrap();
    let liar = farm.add_worker("liar".into(), 1, now);
    let a = farm.add_worker("a".into(), 1, now);
    let b = farm.add_worker("b".into(), 1, now);
    let lie = farm.assign(liar, now).unwrap();
    let doubled: Vec<u64> = honest(&lie.batch).iter().map(|v| v * 2 + 1).collect();
    farm.complete(liar, &lie.answer(&doubled, None), now).unwrap();
    let t = text(&farm, now);
    assert_eq!(sample(&t, "tessera_audits_begun_total"), Some(1.0), "{t}");
    for (w, outcome) in [(a, "disagreed"), (b, "decided")] {
        let check = farm.assign(w, now).unwrap();
        assert_eq!(check.batch.id, lie.batch.id, "the audit is handed out first");
        let t = text(&farm, now);
        assert_eq!(sample(&t, "tessera_leases_outstanding{kind=\"audit\"}"), Some(1.0), "{t}");
        farm.complete(w, &check.answer(&honest(&check.batch), None), now).unwrap();
        let t = text(&farm, now);
        assert_eq!(sample(&t, &format!("tessera_audits_total{{outcome=\"{outcome}\"}}")), Some(1.0), "{t}");
    }
    let t = text(&farm, now);
    assert_eq!(sample(&t, "tessera_audits_total{outcome=\"agreed\"}"), Some(0.0), "{t}");
    assert_eq!(sample(&t, "tessera_quarantines_total"), Some(1.0), "{t}");
    assert_eq!(sample(&t, "tessera_workers{state=\"quarantined\"}"), Some(1.0), "{t}");
    assert_eq!(sample(&t, "tessera_workers{state=\"idle\"}"), Some(2.0), "{t}");
    assert!(sample(&t, "tessera_repaired_pixels_total").is_some_and(|n| n > 0.0), "{t}");
    assert_eq!(sample(&t, "tessera_strikes_total"), Some(0.0), "an audit quarantines without strikes: {t}");
}

/// A forged answer is a strike, counted.
#[test]
fn strikes_are_counted() {
    let mut farm = Farm::new();
    let now = Instant::now();
    farm.submit(bundle(), JobSettings::sized(Some(2), Some((16, 16))), 0).unwrap();
    let w = farm.add_worker("w".into(), 1, now);
    let a = farm.assign(w, now).unwrap();
    let sums = honest(&a.batch);
    let forged = crate::farm::BatchResult { lease: &[0; 16], ..a.answer(&sums, None) };
    assert!(farm.complete(w, &forged, now).is_err());
    assert_eq!(sample(&text(&farm, now), "tessera_strikes_total"), Some(1.0));
}

/// `promtool check metrics` (Debian's prometheus package, unpacked by
/// `scripts/prometheus.sh`) accepts the text of a farm with leases out, a silent worker,
/// a merge timed and a failed checkpoint: its format and its lint (names, suffixes, help).
#[test]
fn promtool_accepts_the_text() {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/../scripts/prometheus.sh");
    let bin = match Command::new(script).stdin(Stdio::null()).output() {
        Ok(o) if o.status.success() => std::path::PathBuf::from(String::from_utf8_lossy(&o.stdout).trim()),
        Ok(o) => return eprintln!("SKIPPED: no promtool: {}", String::from_utf8_lossy(&o.stderr).trim()),
        Err(e) => return eprintln!("SKIPPED: cannot run {script}: {e}"),
    };
    let mut farm = Farm::new();
    let t0 = Instant::now();
    farm.submit(bundle(), JobSettings::sized(Some(2), Some((16, 16))), 0).unwrap();
    let (a, b) = (farm.add_worker("a".into(), 1, t0), farm.add_worker("b".into(), 1, t0));
    let l = farm.assign(a, t0).unwrap();
    farm.complete(a, &l.answer(&honest(&l.batch), None), t0).unwrap();
    farm.assign(b, t0).unwrap();
    farm.assign(a, t0).unwrap();
    let later = t0 + Duration::from_secs(11);
    farm.touch(a, later);
    farm.expire_silent(later, Duration::from_secs(10));
    let metrics = Metrics::default();
    metrics.observe_merge(Duration::from_micros(40));
    metrics.observe_checkpoint(Duration::from_millis(3), true);
    metrics.observe_checkpoint(Duration::from_millis(3), false);
    let text = metrics.exposition(farm.census(later), 2);
    let mut check = Command::new(bin.join("promtool"))
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    check.stdin.take().unwrap().write_all(text.as_bytes()).unwrap();
    let out = check.wait_with_output().unwrap();
    let said = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success() && said.trim().is_empty(), "promtool: {said}\n{text}");
    assert_eq!(sample(&text, "tessera_checkpoint_failures_total"), Some(1.0), "{text}");
    assert_eq!(sample(&text, "tessera_checkpoint_write_seconds_count"), Some(1.0), "{text}");
    assert_eq!(sample(&text, "tessera_merge_seconds_bucket{le=\"3.2e-05\"}"), Some(0.0), "{text}");
    assert_eq!(sample(&text, "tessera_merge_seconds_bucket{le=\"0.000128\"}"), Some(1.0), "{text}");
    assert_eq!(sample(&text, "tessera_viewers"), Some(2.0), "{text}");
}
