//! The farm against hostile workers, pure and seeded: fenced leases, strikes, quarantine,
//! failures by identity, audits and exact repair.

use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
use tessera_description::ids::WorkerId;

use super::*;
use crate::scheduler::BatchSpec;

const SCENE: &str = include_str!("../../../tests/scenes/small.toml");

fn bundle() -> Bundle {
    Bundle { name: "small.toml".into(), text: SCENE.into(), assets: vec![], refused: vec![] }
}

/// Honest sums: every sample of a pixel is the same function of the pixel, so sums add up
/// however samples are batched.
fn honest(spec: &BatchSpec) -> Vec<u64> {
    let n = u64::from(spec.samples.end - spec.samples.start);
    spec.quads.iter().flat_map(|q| [1, 2, 3].map(|c| u64::from((q.x * 7 + q.y * 3 + c) % 11) * n)).collect()
}

fn result<'a>(a: &'a Assignment, sums: &'a [u64]) -> BatchResult<'a> {
    a.answer(sums, None)
}

fn failure<'a>(a: &'a Assignment, scene_refused: bool) -> BatchFailure<'a> {
    BatchFailure {
        job: a.job,
        batch: a.batch.id,
        attempt: a.attempt,
        lease: &a.token.0,
        scene_refused,
        error: "no",
    }
}

fn farm(policy: AuditPolicy) -> Farm {
    let mut f = Farm::with_seed([3; 32]);
    f.set_audit_policy(policy);
    f
}

/// Invariant: only the holder of a lease, with its token and attempt, is heard. Anything
/// else is refused with the lease untouched and a strike; three strikes quarantine the
/// identity, which is refused at registration.
#[test]
fn answers_count_only_from_the_holder_with_its_token() {
    let mut f = farm(AuditPolicy::off());
    let now = Instant::now();
    let job = f.submit(bundle(), JobSettings::sized(Some(2), Some((16, 16))), 0).unwrap();
    let a = f.add_worker_as("host/a".into(), "a".into(), 1, now).unwrap();
    let b = f.add_worker_as("host/b".into(), "b".into(), 1, now).unwrap();
    let la = f.assign(a, now).unwrap();
    let lb = f.assign(b, now).unwrap();
    assert_ne!(la.token, lb.token);
    let sums = honest(&la.batch);
    // b with a's batch and a's token.
    let stolen = BatchResult { lease: &la.token.0, ..result(&la, &sums) };
    assert!(matches!(f.complete(b, &stolen, now), Err(ResultError::Forged { .. })));
    // b with its own batch and a made-up token.
    let sb = honest(&lb.batch);
    let forged = BatchResult { lease: &[0; 16], ..result(&lb, &sb) };
    assert!(matches!(f.complete(b, &forged, now), Err(ResultError::Forged { .. })));
    assert_eq!(f.strikes(b), 2);
    assert_eq!(f.job(job).unwrap().progress(now).samples_done, 0);
    // a's lease is untouched.
    f.complete(a, &result(&la, &sums), now).unwrap();
    // a, with its next lease at the wrong attempt: refused, the batch back in the queue.
    let la2 = f.assign(a, now).unwrap();
    let s2 = honest(&la2.batch);
    let odd = BatchResult { attempt: 999, ..result(&la2, &s2) };
    assert!(matches!(f.complete(a, &odd, now), Err(ResultError::Invalid { .. })));
    let toomany = BatchResult { nonfinite: u64::MAX, ..result(&lb, &sb) };
    assert!(matches!(f.complete(b, &toomany, now), Err(ResultError::Invalid { .. })));
    assert_eq!(f.strikes(a), 1);
    assert!(f.quarantined(b).is_some(), "three strikes quarantine");
    assert!(f.assign(b, now).is_none());
    assert!(f.add_worker_as("host/b".into(), "b".into(), 1, now).unwrap_err().contains("quarantined"));
    // A failure for someone else's lease is no failure, but a strike.
    let la3 = f.assign(a, now).unwrap();
    let c = f.add_worker_as("host/c".into(), "c".into(), 1, now).unwrap();
    let lc = f.assign(c, now).unwrap();
    let foreign = BatchFailure { lease: &la3.token.0, ..failure(&lc, false) };
    let foreign = BatchFailure { batch: la3.batch.id, ..foreign };
    assert!(f.fail_batch(c, &foreign, now).is_err());
    assert_eq!(f.strikes(c), 1);
    let s3 = honest(&la3.batch);
    f.complete(a, &result(&la3, &s3), now).unwrap();
}

/// Invariant: an honest worker whose lease ended without its answer (a speculative
/// duplicate won, the job was cancelled, it fell silent) is no liar: its late answer is a
/// harmless duplicate, or still counts, but never a strike.
#[test]
fn late_answers_of_honest_workers_are_no_strike() {
    let mut f = farm(AuditPolicy::off());
    let t0 = Instant::now();
    let job = f.submit(bundle(), JobSettings::sized(Some(1), Some((4, 4))), 0).unwrap();
    let a = f.add_worker("a".into(), 1, t0);
    let b = f.add_worker("b".into(), 1, t0);
    let la = f.assign(a, t0).unwrap();
    // The straggler's duplicate for b, after the patience.
    let lb = f.assign(b, t0 + Duration::from_secs(5)).unwrap();
    assert!(lb.speculative && lb.batch.id == la.batch.id);
    let sums = honest(&la.batch);
    f.complete(b, &result(&lb, &sums), t0).unwrap();
    assert!(matches!(f.complete(a, &result(&la, &sums), t0), Err(ResultError::Duplicate(_))));
    assert_eq!((f.strikes(a), f.strikes(b)), (0, 0));
    assert_eq!(f.job(job).unwrap().state, JobState::Done);

    let job = f.submit(bundle(), JobSettings::sized(Some(1), Some((4, 4))), 0).unwrap();
    let la = f.assign(a, t0).unwrap();
    f.cancel(job, t0);
    assert!(matches!(f.complete(a, &result(&la, &sums), t0), Err(ResultError::Duplicate(_))));
    assert_eq!(f.strikes(a), 0);

    let job = f.submit(bundle(), JobSettings::sized(Some(1), Some((4, 4))), 0).unwrap();
    let la = f.assign(a, t0).unwrap();
    assert_eq!(f.expire_silent(t0 + Duration::from_secs(60), Duration::from_secs(10)).len(), 1);
    f.complete(a, &result(&la, &sums), t0).unwrap();
    assert_eq!(f.job(job).unwrap().state, JobState::Done);
    assert_eq!(f.strikes(a), 0);
}

/// Invariant: failures count per identity (three distinct fail a batch's job, one
/// identity failing thrice does not while another is connected); scene refusals send the
/// job elsewhere and fail it only when every connected worker refused it.
#[test]
fn failures_count_per_identity_and_refusals_move_the_job() {
    let mut f = farm(AuditPolicy::off());
    let now = Instant::now();
    let job = f.submit(bundle(), JobSettings::sized(Some(1), Some((4, 4))), 0).unwrap();
    let ws: Vec<WorkerId> = ["a", "b", "c"].iter().map(|n| f.add_worker((*n).into(), 1, now)).collect();
    for _ in 0..3 {
        let l = f.assign(ws[0], now).unwrap();
        f.fail_batch(ws[0], &failure(&l, false), now).unwrap();
    }
    assert!(!f.job(job).unwrap().is_over());
    for &w in &ws[1..] {
        let l = f.assign(w, now).unwrap();
        f.fail_batch(w, &failure(&l, false), now).unwrap();
    }
    assert!(matches!(&f.job(job).unwrap().state, JobState::Failed(m) if m.contains("3 workers")));

    let job = f.submit(bundle(), JobSettings::sized(Some(1), Some((4, 4))), 0).unwrap();
    let l = f.assign(ws[0], now).unwrap();
    f.fail_batch(ws[0], &failure(&l, true), now).unwrap();
    assert!(f.assign(ws[0], now).is_none(), "a refusing worker is not sent the job again");
    let l = f.assign(ws[1], now).unwrap();
    f.fail_batch(ws[1], &failure(&l, true), now).unwrap();
    assert!(!f.job(job).unwrap().is_over());
    let l = f.assign(ws[2], now).unwrap();
    f.fail_batch(ws[2], &failure(&l, true), now).unwrap();
    assert!(
        matches!(&f.job(job).unwrap().state, JobState::Failed(m) if m.contains("every connected worker refused"))
    );
}

/// Runs a job to the end with honest workers `a`, `b`, `c` and `liar` (whose sums pass
/// through `lie`), round robin; returns the farm and the job.
fn run(policy: AuditPolicy, settings: JobSettings, lie: impl Fn(u64, &mut Vec<u64>)) -> (Farm, JobId) {
    let mut f = farm(policy);
    let now = Instant::now();
    let job = f.submit(bundle(), settings, 0).unwrap();
    let liar = f.add_worker("liar".into(), 1, now);
    let ws = [
        liar,
        f.add_worker("a".into(), 1, now),
        f.add_worker("b".into(), 1, now),
        f.add_worker("c".into(), 1, now),
    ];
    let mut lies = 0;
    for _ in 0..100_000 {
        if f.job(job).unwrap().is_over() {
            break;
        }
        for &w in &ws {
            let Some(l) = f.assign(w, now) else { continue };
            let mut sums = honest(&l.batch);
            if w == liar {
                lie(lies, &mut sums);
                lies += 1;
            }
            let _ = f.complete(w, &result(&l, &sums), now);
        }
    }
    (f, job)
}

/// Invariant: a liar caught by an audit is quarantined, and every pixel it delivered is
/// reset and rendered again, so the accumulators end bit for bit as a clean run's.
#[test]
fn a_caught_liar_is_repaired_to_the_clean_accumulators() {
    // 8-pixel pass-two batches: the liar delivers some thirty.
    let settings = JobSettings::sized(Some(4097), Some((32, 32)));
    let (clean, cj) = run(AuditPolicy::off(), settings.clone(), |_, _| {});
    let policy = AuditPolicy { fraction: 0.5, probation_batches: 0, probation_fraction: 0.0 };
    for lie in [
        |_: u64, s: &mut Vec<u64>| s.iter_mut().for_each(|v| *v *= 2),
        |n: u64, s: &mut Vec<u64>| {
            if n % 5 == 3 {
                s.iter_mut().for_each(|v| *v = 0)
            }
        },
    ] {
        let (f, j) = run(policy, settings.clone(), lie);
        assert_eq!(f.job(j).unwrap().state, JobState::Done);
        let c = f.fence_counters();
        assert!(f.standing("liar").unwrap().quarantined.is_some(), "{c:?}");
        assert!(c.repaired_pixels > 0 && c.repair_batches > 0, "{c:?}");
        assert!(f.job(j).unwrap().framebuffer() == clean.job(cj).unwrap().framebuffer(), "{c:?}");
        assert_eq!(f.job(j).unwrap().progress(Instant::now()).samples_done, 32 * 32 * 4097);
    }
}

/// Audits of honest workers agree, and an audit with no other identity to render it waits
/// only until the rest of its job is done: then it is skipped (counted) rather than
/// holding the job open.
#[test]
fn honest_audits_pass_and_a_lone_worker_is_not_held_up() {
    let settings = JobSettings::sized(Some(65), Some((32, 32)));
    let (f, j) = run(AuditPolicy::default(), settings.clone(), |_, _| {});
    let c = f.fence_counters();
    assert!(c.audits_passed > 0 && c.audits_mismatched == 0 && c.strikes == 0, "{c:?}");
    assert_eq!(f.job(j).unwrap().state, JobState::Done);

    let mut f = farm(AuditPolicy { fraction: 1.0, probation_batches: 0, probation_fraction: 0.0 });
    let now = Instant::now();
    let j = f.submit(bundle(), settings, 0).unwrap();
    let w = f.add_worker("alone".into(), 1, now);
    while let Some(l) = f.assign(w, now) {
        let s = honest(&l.batch);
        f.complete(w, &result(&l, &s), now).unwrap();
    }
    assert_eq!(f.job(j).unwrap().state, JobState::Done);
    assert!(f.fence_counters().audits_skipped > 0);
}

/// A per-sample value: flat on the left (reaches any noise target), noisy on the right.
fn sample(q: &tessera_film::Quad, i: u32) -> u64 {
    if q.x < 20 {
        5 << 22
    } else {
        (u64::from(i).wrapping_mul(2_654_435_761) % 1000) << 14
    }
}

/// Honest sums and even-sample sums of a batch of `sample`.
fn split(spec: &BatchSpec) -> (Vec<u64>, Vec<u64>) {
    let (mut sums, mut even) = (Vec::new(), Vec::new());
    for q in &spec.quads {
        let total: u64 = spec.samples.clone().map(|i| sample(q, i)).sum();
        sums.extend([total; 3]);
        even.push(spec.samples.clone().filter(|i| i % 2 == 0).map(|i| sample(q, i)).sum());
    }
    (sums, even)
}

/// What differs, precisely, when a liar is repaired in a noise-target job: which pixels
/// took another round was decided with its samples in, so sample counts may differ from
/// a clean render; but every pixel's sums and even sums are exactly those of its samples
/// 0..count, and with equal counts the accumulators are bit for bit a clean run's.
#[test]
fn a_repaired_noise_target_job_is_exact_for_its_sample_counts() {
    let settings = JobSettings {
        noise: Some(tessera_description::Noise::Relative(0.02)),
        ..JobSettings::sized(Some(256), Some((40, 36)))
    };
    let go = |policy: AuditPolicy, lie: bool| {
        let mut f = farm(policy);
        let now = Instant::now();
        let job = f.submit(bundle(), settings.clone(), 0).unwrap();
        let ws: Vec<WorkerId> =
            ["liar", "a", "b", "c"].iter().map(|n| f.add_worker((*n).into(), 1, now)).collect();
        for _ in 0..100_000 {
            if f.job(job).unwrap().is_over() {
                break;
            }
            for &w in &ws {
                let Some(l) = f.assign(w, now) else { continue };
                let (mut sums, mut even) = split(&l.batch);
                if lie && w == ws[0] {
                    sums.iter_mut().for_each(|s| *s = 0);
                    even.iter_mut().for_each(|s| *s = 0);
                }
                let r = BatchResult { even: Some(&even), ..result(&l, &sums) };
                let _ = f.complete(w, &r, now);
            }
        }
        (f, job)
    };
    let (clean, cj) = go(AuditPolicy::off(), false);
    let (f, j) = go(AuditPolicy { fraction: 0.5, probation_batches: 0, probation_fraction: 0.0 }, true);
    assert_eq!(f.job(j).unwrap().state, JobState::Done);
    assert!(f.fence_counters().liars == 1 && f.fence_counters().repaired_pixels > 0);
    let fb = f.job(j).unwrap().framebuffer();
    let (sums, counts) = fb.accumulators();
    let even = fb.even();
    for y in 0..36 {
        for x in 0..40 {
            let i = (y * 40 + x) as usize;
            let q = tessera_film::Quad { x, y, w: 1, h: 1 };
            let spec = BatchSpec {
                id: BatchId(0),
                pass: crate::scheduler::Pass::Two,
                quads: vec![q],
                samples: 0..counts[i],
            };
            let (s, e) = split(&spec);
            assert_eq!((sums[i].to_vec(), even[i]), (s, e[0]), "pixel {x},{y} with {} samples", counts[i]);
        }
    }
    let (_, clean_counts) = clean.job(cj).unwrap().framebuffer().accumulators();
    eprintln!(
        "pixels whose count differs from a clean render: {}",
        counts.iter().zip(&clean_counts).filter(|(a, b)| a != b).count()
    );
    if counts == clean_counts {
        assert!(fb == clean.job(cj).unwrap().framebuffer(), "equal counts, different bits");
    }
}

/// Bug this protects against: one identity could open work streams without end, each
/// holding copies of the scenes sent to it.
#[test]
fn an_identity_holds_a_bounded_number_of_connections() {
    let mut f = farm(AuditPolicy::default());
    let now = Instant::now();
    for i in 0..super::MAX_CONNECTIONS_PER_IDENTITY {
        f.add_worker_as("principal node-1".into(), format!("w{i}"), 1, now).unwrap();
    }
    let e = f.add_worker_as("principal node-1".into(), "one more".into(), 1, now).unwrap_err();
    assert!(e.contains("the most one identity may hold"), "{e}");
    f.add_worker_as("principal node-2".into(), "other".into(), 1, now).unwrap();
}
