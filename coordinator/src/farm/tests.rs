//! The farm driven by fake workers: order of service, restore, adaptive sampling, time
//! budgets.

use std::time::{Duration, Instant};

use tessera_description::bundle::Bundle;
use tessera_description::ids::WorkerId;
use tessera_description::Noise;
use tessera_film::Quad;

use super::*;
use crate::persist::{JobRecord, LoadedJob};
use crate::scheduler::BatchSpec;

/// The result a fake worker sends for an assignment.
fn result<'a>(a: &'a Assignment, sums: &'a [u64], even: Option<&'a [u64]>) -> BatchResult<'a> {
    a.answer(sums, even)
}

const SCENE: &str = include_str!("../../../tests/scenes/small.toml");

fn bundle() -> Bundle {
    Bundle { name: "small.toml".into(), text: SCENE.into(), assets: vec![], refused: vec![] }
}

fn settings(w: u32, h: u32, spp: u32) -> JobSettings {
    JobSettings::sized(Some(spp), Some((w, h)))
}

/// What a worker would send: sums that depend on pixel and samples only.
fn fake_sums(spec: &BatchSpec) -> Vec<u64> {
    let n = u64::from(spec.samples.end - spec.samples.start);
    spec.quads.iter().flat_map(|q| [1, 2, 3].map(|c| u64::from((q.x * 7 + q.y * 3 + c) % 11) * n)).collect()
}

/// Leases and completes up to `limit` batches for one worker; returns how many.
fn work(farm: &mut Farm, worker: WorkerId, limit: usize) -> usize {
    let now = Instant::now();
    let mut n = 0;
    while n < limit {
        let Some(a) = farm.assign(worker, now) else { break };
        farm.complete(worker, &result(&a, &fake_sums(&a.batch), None), now).unwrap();
        n += 1;
    }
    n
}

#[test]
fn higher_priorities_are_served_first_then_the_oldest() {
    let mut farm = Farm::new();
    let low = farm.submit(bundle(), settings(16, 16, 2), -1).unwrap();
    let normal_old = farm.submit(bundle(), settings(16, 16, 2), 0).unwrap();
    let high = farm.submit(bundle(), settings(16, 16, 2), 5).unwrap();
    let normal_new = farm.submit(bundle(), settings(16, 16, 2), 0).unwrap();
    let w = farm.add_worker("w".into(), 1, Instant::now());
    let mut served = Vec::new();
    while let Some(a) = farm.assign(w, Instant::now()) {
        if served.last() != Some(&a.job) {
            served.push(a.job);
        }
        farm.complete(w, &result(&a, &fake_sums(&a.batch), None), Instant::now()).unwrap();
    }
    assert_eq!(served, vec![high, normal_old, normal_new, low]);
}

/// A job checkpointed mid-pass and restored into a new farm (a restarted coordinator)
/// ends with exactly the accumulators of a job never interrupted, whatever was leased
/// and lost at the moment of the checkpoint.
#[test]
fn a_restored_job_ends_with_the_uninterrupted_accumulators() {
    let (w, h, spp) = (37, 23, 5);
    let mut clean = Farm::new();
    let id = clean.submit(bundle(), settings(w, h, spp), 0).unwrap();
    let cw = clean.add_worker("clean".into(), 1, Instant::now());
    work(&mut clean, cw, usize::MAX);
    assert_eq!(clean.job(id).unwrap().state, JobState::Done);

    for stop_after in [0, 1, 3, 9, 20] {
        let mut farm = Farm::new();
        let id = farm.submit(bundle(), settings(w, h, spp), 0).unwrap();
        let a = farm.add_worker("a".into(), 1, Instant::now());
        work(&mut farm, a, stop_after);
        // Leases in flight at the checkpoint, one of them finished out of order.
        let now = Instant::now();
        let held: Vec<_> = (0..3).filter_map(|_| farm.assign(a, now)).collect();
        if let Some(x) = held.get(1) {
            farm.complete(a, &result(x, &fake_sums(&x.batch), None), now).unwrap();
        }
        let job = farm.job(id).unwrap();
        let stored = LoadedJob { record: job.record(), checkpoint: Some(job.snapshot(now).checkpoint()) };

        let mut restarted = Farm::new();
        assert_eq!(restarted.restore(stored, Instant::now()).unwrap(), id);
        let b = restarted.add_worker("b".into(), 1, Instant::now());
        work(&mut restarted, b, usize::MAX);
        let (got, want) = (restarted.job(id).unwrap(), clean.job(id).unwrap());
        assert_eq!(got.state, JobState::Done, "stopped after {stop_after}");
        assert_eq!(
            got.framebuffer().accumulators(),
            want.framebuffer().accumulators(),
            "stopped after {stop_after}"
        );
        assert_eq!(got.progress(now).samples_done, want.progress(now).samples_done);
        // New jobs never reuse the restored id.
        assert!(restarted.submit(bundle(), settings(4, 4, 1), 0).unwrap() > id);
    }
}

#[test]
fn restored_states_are_kept_and_a_mismatched_checkpoint_is_refused() {
    let mut farm = Farm::new();
    let id = farm.submit(bundle(), settings(8, 8, 2), 0).unwrap();
    let job = farm.job(id).unwrap();
    for (state, want) in [
        (JobState::Paused, JobState::Paused),
        (JobState::Cancelled, JobState::Cancelled),
        (JobState::Running, JobState::Queued),
    ] {
        let mut record = job.record();
        record.state = state;
        let mut f = Farm::new();
        f.restore(
            LoadedJob { record, checkpoint: Some(job.snapshot(Instant::now()).checkpoint()) },
            Instant::now(),
        )
        .unwrap();
        assert_eq!(f.job(id).unwrap().state, want);
        let w = f.add_worker("w".into(), 1, Instant::now());
        assert_eq!(f.assign(w, Instant::now()).is_some(), want == JobState::Queued);
    }
    let mut wrong = job.snapshot(Instant::now()).checkpoint();
    wrong.spp = 3;
    let e = Farm::new().restore(LoadedJob { record: job.record(), checkpoint: Some(wrong) }, Instant::now());
    assert!(matches!(e, Err(RestoreJobError::Mismatch { .. })), "{e:?}");
    // Another renderer's checkpoint is not resumed from, nor one that does not say.
    let mut other = job.snapshot(Instant::now()).checkpoint();
    other.renderer = "0.1.0+images.1".into();
    let e = Farm::new()
        .restore(LoadedJob { record: job.record(), checkpoint: Some(other.clone()) }, Instant::now());
    let e = e.err().map(|e| e.to_string()).unwrap_or_default();
    assert!(
        e.contains("from renderer 0.1.0+images.1") && e.contains(tessera_description::RENDERER_VERSION),
        "{e}"
    );
    // A job that renders nothing more keeps its image whatever made it.
    for state in [JobState::Cancelled, JobState::Failed("stopped".into())] {
        let record = JobRecord { state: state.clone(), ..job.record() };
        let mut f = Farm::new();
        f.restore(LoadedJob { record, checkpoint: Some(other.clone()) }, Instant::now()).unwrap();
        assert_eq!(f.job(id).unwrap().state, state);
    }
    // A checkpoint that does not name its renderer (format 3 and older) is not resumed
    // from either, whatever the job: a scene drawn whole by Cook's pattern, one in rounds,
    // one of Sobol's pattern, one with triangles. A finished job keeps its image.
    other.renderer.clear();
    let e = Farm::new()
        .restore(LoadedJob { record: job.record(), checkpoint: Some(other.clone()) }, Instant::now());
    assert!(e.err().is_some_and(|e| e.to_string().contains("did not name itself")));
    let record = JobRecord { state: JobState::Cancelled, ..job.record() };
    Farm::new().restore(LoadedJob { record, checkpoint: Some(other) }, Instant::now()).unwrap();
    let timed = JobSettings { time_limit: Some(Duration::from_secs(60)), ..settings(8, 8, 2) };
    let sobol = SCENE.replacen("[render]", "[render]\nsampler = \"sobol\"", 1);
    let triangle = format!(
        "{SCENE}\n[[triangle]]\nvertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nmaterial = \"floor\"\n"
    );
    let whole = settings(8, 8, 2);
    let jobs = [
        ("rounds.toml", SCENE.to_owned(), timed),
        ("sobol.toml", sobol, whole.clone()),
        ("triangle.toml", triangle, whole),
    ];
    for (name, text, how) in jobs {
        let scene = Bundle { name: name.into(), text, assets: vec![], refused: vec![] };
        let id = farm.submit(scene, how, 0).unwrap();
        let job = farm.job(id).unwrap();
        let mut old = job.snapshot(Instant::now()).checkpoint();
        Farm::new()
            .restore(LoadedJob { record: job.record(), checkpoint: Some(old.clone()) }, Instant::now())
            .unwrap();
        old.renderer.clear();
        let e =
            Farm::new().restore(LoadedJob { record: job.record(), checkpoint: Some(old) }, Instant::now());
        assert!(matches!(e, Err(RestoreJobError::Mismatch { .. })), "{name}: {e:?}");
    }
}

/// Per-sample values of a fake scene: a flat left part (it reaches any noise target)
/// and a noisy right part (it does not), as fixed-point r = g = b.
fn fake_sample(q: &Quad, i: u32) -> u64 {
    if q.x < 20 {
        5 << 22
    } else {
        (u64::from(i).wrapping_mul(2_654_435_761) % 1000) << 14
    }
}

/// A worker's result with even-sample sums.
fn fake_split(spec: &BatchSpec) -> (Vec<u64>, Vec<u64>) {
    let mut sums = Vec::new();
    let mut even = Vec::new();
    for q in &spec.quads {
        let vals: Vec<u64> = spec.samples.clone().map(|i| fake_sample(q, i)).collect();
        let total: u64 = vals.iter().sum();
        sums.extend([total; 3]);
        even.push(spec.samples.clone().zip(&vals).filter(|(i, _)| i % 2 == 0).map(|(_, v)| *v).sum());
    }
    (sums, even)
}

/// Runs a job to its end, merging each window of `window` leases in reverse order.
fn run_adaptive(farm: &mut Farm, limit: usize, window: usize) -> usize {
    let w = farm.add_worker("w".into(), 1, Instant::now());
    let now = Instant::now();
    let mut merged = 0;
    while merged < limit {
        let held: Vec<Assignment> = (0..window).map_while(|_| farm.assign(w, now)).collect();
        if held.is_empty() {
            break;
        }
        for a in held.iter().rev() {
            let (sums, even) = fake_split(&a.batch);
            farm.complete(w, &result(a, &sums, Some(&even)), now).unwrap();
            merged += 1;
        }
    }
    merged
}

/// With a noise target, relative or absolute, flat pixels stop early and noisy ones go
/// on; the result is the same bits whatever the merge order, and after a restore from a
/// mid-run checkpoint.
#[test]
fn adaptive_sampling_is_deterministic_and_resumable() {
    // The noisy part's samples are spread over [0, 1) with a mean about 0.49: after 256 a
    // pixel's standard error is about 0.018, 0.036 of its mean, above both targets.
    // Flat pixels stop at the end of the first round at or past the minimum: the target's
    // own (16 and 64), or the job's (2; 100, whose round ends at 128).
    for (target, noise_min, stop) in [
        (Noise::Relative(0.02), None, 16),
        (Noise::Absolute(0.01), None, 64),
        (Noise::Relative(0.02), Some(2), 2),
        (Noise::Absolute(0.01), Some(100), 128),
    ] {
        adaptive_run_checks(JobSettings { noise: Some(target), noise_min, ..settings(40, 36, 256) }, stop);
    }
}

/// A noise target's minimum is refused without a target, below two samples and above the
/// job's sample count, with the reason.
#[test]
fn a_noise_minimum_out_of_range_is_refused() {
    let abs = Some(Noise::Absolute(0.01));
    for (noise, noise_min, says) in [
        (None, Some(32), "without a noise target"),
        (abs, Some(1), "at least 2 samples"),
        (abs, Some(257), "minimum of 257 samples is more than the job's 256"),
    ] {
        let err = Farm::new()
            .submit(bundle(), JobSettings { noise, noise_min, ..settings(8, 8, 256) }, 0)
            .unwrap_err();
        assert!(err.to_string().contains(says), "{err}");
    }
    // A stored job whose minimum is above its samples (a store edited by hand) is refused
    // when taken up again, with the same reason.
    let mut farm = Farm::new();
    let id = farm.submit(bundle(), JobSettings { noise: abs, ..settings(8, 8, 256) }, 0).unwrap();
    let mut record = farm.job(id).unwrap().record();
    record.settings.noise_min = Some(300);
    let err = Farm::new().restore(LoadedJob { record, checkpoint: None }, Instant::now()).unwrap_err();
    assert!(err.to_string().contains("minimum of 300 samples is more than the job's 256"), "{err}");
}

fn adaptive_run_checks(adaptive: JobSettings, flat_stop: u32) {
    let mut reference = Farm::new();
    let id = reference.submit(bundle(), adaptive.clone(), 0).unwrap();
    run_adaptive(&mut reference, usize::MAX, 1);
    let done = reference.job(id).unwrap();
    assert_eq!(done.state, JobState::Done);
    assert_eq!(done.progress(Instant::now()).halted, Some("noise target"));
    let counts = done.framebuffer().accumulators().1;
    // Flat pixels stop at the minimum, but for those whose window reaches the noise.
    let flat = counts.iter().enumerate().filter(|(i, _)| i % 40 < 18).map(|(_, &c)| c);
    assert!(
        flat.clone().all(|c| c == flat_stop),
        "flat pixels stop at the minimum: {:?}",
        adaptive.adaptive()
    );
    let noisy = counts.iter().enumerate().filter(|(i, _)| i % 40 >= 20).map(|(_, &c)| c);
    assert!(noisy.clone().all(|c| c == 256), "noisy pixels take every sample: {:?}", adaptive.noise);

    let mut shuffled = Farm::new();
    shuffled.submit(bundle(), adaptive.clone(), 0).unwrap();
    run_adaptive(&mut shuffled, usize::MAX, 7);
    let got = shuffled.job(id).unwrap().framebuffer();
    assert_eq!(got.accumulators(), done.framebuffer().accumulators());
    assert_eq!(got.even(), done.framebuffer().even());

    for stop in [3, 40, 90] {
        let mut first = Farm::new();
        first.submit(bundle(), adaptive.clone(), 0).unwrap();
        run_adaptive(&mut first, stop, 3);
        let job = first.job(id).unwrap();
        let stored =
            LoadedJob { record: job.record(), checkpoint: Some(job.snapshot(Instant::now()).checkpoint()) };
        let mut restarted = Farm::new();
        restarted.restore(stored, Instant::now()).unwrap();
        run_adaptive(&mut restarted, usize::MAX, 2);
        let got = restarted.job(id).unwrap();
        assert_eq!(got.state, JobState::Done, "stop {stop}");
        assert_eq!(got.framebuffer().accumulators(), done.framebuffer().accumulators(), "stop {stop}");
    }
}

/// A time budget ends the job wherever it is, even mid-round, and says so.
#[test]
fn a_spent_time_budget_ends_the_job() {
    let mut farm = Farm::new();
    let timed = JobSettings { time_limit: Some(Duration::from_secs(5)), ..settings(16, 16, 1000) };
    let id = farm.submit(bundle(), timed, 0).unwrap();
    let w = farm.add_worker("w".into(), 1, Instant::now());
    let t0 = Instant::now();
    let a = farm.assign(w, t0).unwrap();
    farm.complete(w, &result(&a, &fake_sums(&a.batch), None), t0).unwrap();
    assert!(farm.enforce_deadlines(t0 + Duration::from_secs(4)).is_empty());
    assert!(farm.assign(w, t0 + Duration::from_secs(6)).is_none());
    let job = farm.job(id).unwrap();
    assert_eq!((job.state.clone(), job.progress(t0).halted), (JobState::Done, Some("time budget")));
}

/// Time paused is not spent: a job with a 5 s budget, paused for an hour after 2 s of
/// rendering, still has 3 s when resumed, and its elapsed time stands still meanwhile; a
/// pause before the first lease counts nothing, and a job cancelled while paused keeps
/// the time it had.
#[test]
fn a_paused_job_does_not_spend_its_time_budget() {
    let s = Duration::from_secs;
    let mut farm = Farm::new();
    let timed = JobSettings { time_limit: Some(s(5)), ..settings(16, 16, 1000) };
    let id = farm.submit(bundle(), timed.clone(), 0).unwrap();
    let w = farm.add_worker("w".into(), 1, Instant::now());
    let t0 = Instant::now();
    // Paused and resumed before it starts: nothing to count yet.
    assert!(farm.set_paused(id, true, t0));
    assert!(farm.set_paused(id, false, t0 + s(100)));
    assert_eq!(farm.job(id).unwrap().state, JobState::Queued);
    let a = farm.assign(w, t0).unwrap();
    farm.complete(w, &result(&a, &fake_sums(&a.batch), None), t0).unwrap();
    farm.set_paused(id, true, t0 + s(2));
    let elapsed = |farm: &Farm, at| farm.job(id).unwrap().progress(at).elapsed;
    assert_eq!(elapsed(&farm, t0 + s(3600)), s(2));
    assert!(farm.enforce_deadlines(t0 + s(3600)).is_empty());
    farm.set_paused(id, false, t0 + s(3602));
    assert_eq!(farm.job(id).unwrap().state, JobState::Running);
    assert_eq!(elapsed(&farm, t0 + s(3604)), s(4));
    assert!(farm.enforce_deadlines(t0 + s(3604)).is_empty());
    assert_eq!(farm.enforce_deadlines(t0 + s(3605)), vec![id]);
    assert_eq!(farm.job(id).unwrap().progress(t0).halted, Some("time budget"));

    // Cancelled while paused: its time stops where the pause began.
    let other = farm.submit(bundle(), timed, 0).unwrap();
    let a = farm.assign(w, t0).unwrap();
    assert_eq!(a.job, other);
    farm.set_paused(other, true, t0 + s(1));
    farm.cancel(other, t0 + s(50));
    assert_eq!(farm.job(other).unwrap().progress(t0 + s(99)).elapsed, s(1));
}

/// A paused job reports no rate, and once resumed its rate counts only the time since:
/// a window spanning the pause would spread the first samples back over it.
#[test]
fn a_resumed_jobs_rate_leaves_out_its_pause() {
    let (s, ms) = (Duration::from_secs, Duration::from_millis);
    let mut farm = Farm::new();
    let id = farm.submit(bundle(), settings(16, 16, 1000), 0).unwrap();
    let w = farm.add_worker("w".into(), 1, Instant::now());
    let t0 = Instant::now();
    let rate = |farm: &Farm, at| farm.job(id).unwrap().progress(at).samples_per_second;
    let samples =
        |a: &Assignment| u64::from(a.batch.samples.end - a.batch.samples.start) * a.batch.quads.len() as u64;
    let a = farm.assign(w, t0).unwrap();
    let first = samples(&a);
    farm.complete(w, &result(&a, &fake_sums(&a.batch), None), t0 + s(1)).unwrap();
    assert_eq!(rate(&farm, t0 + s(1)), first as f64);
    let a = farm.assign(w, t0 + s(1)).unwrap();
    farm.set_paused(id, true, t0 + s(1));
    assert_eq!(rate(&farm, t0 + s(2)), 0.0);
    // The batch out at the pause merges during it.
    farm.complete(w, &result(&a, &fake_sums(&a.batch), None), t0 + s(2)).unwrap();
    assert_eq!(rate(&farm, t0 + s(2)), 0.0);
    farm.set_paused(id, false, t0 + s(100));
    let a = farm.assign(w, t0 + s(100)).unwrap();
    let n = samples(&a);
    farm.complete(w, &result(&a, &fake_sums(&a.batch), None), t0 + s(100) + ms(500)).unwrap();
    assert_eq!(rate(&farm, t0 + s(101)), n as f64 / 0.5);
}

/// Fake AOV sums: per pixel, within the bounds of its samples, depending on pixel and
/// samples only.
fn fake_aov(spec: &BatchSpec, per_pixel: usize) -> Vec<u64> {
    let n = u64::from(spec.samples.end - spec.samples.start);
    spec.quads
        .iter()
        .flat_map(|q| {
            (0..per_pixel as u64).map(move |k| if k == 6 { n } else { u64::from(q.x + q.y + k as u32) * n })
        })
        .collect()
}

/// A job with AOV layers: its batches carry their sums, a result with impossible or
/// missing ones is refused (and merges nothing), and a checkpointed, restored job ends
/// with exactly the layers of one never interrupted.
#[test]
fn aov_layers_are_checked_merged_and_restored_bit_for_bit() {
    use tessera_description::job::Aovs;
    let (w, h, spp) = (19, 13, 3);
    let all = JobSettings { aovs: Aovs { albedo: true, normal: true, depth: true }, ..settings(w, h, spp) };
    let run = |farm: &mut Farm, worker: WorkerId, limit: usize| {
        let now = Instant::now();
        for _ in 0..limit {
            let Some(a) = farm.assign(worker, now) else { break };
            assert_eq!(a.aovs, 7);
            let (sums, aov) = (fake_sums(&a.batch), fake_aov(&a.batch, 8));
            farm.complete(worker, &BatchResult { aov: &aov, ..result(&a, &sums, None) }, now).unwrap();
        }
    };
    let mut clean = Farm::new();
    let id = clean.submit(bundle(), all.clone(), 0).unwrap();
    let cw = clean.add_worker("clean".into(), 1, Instant::now());
    run(&mut clean, cw, usize::MAX);
    let done = clean.job(id).unwrap();
    assert_eq!(done.state, JobState::Done);
    assert!(done.aov().sums().iter().any(|&v| v > 0));

    let mut farm = Farm::new();
    let id = farm.submit(bundle(), all, 0).unwrap();
    let a = farm.add_worker("a".into(), 1, Instant::now());
    run(&mut farm, a, 4);
    // A liar's layers: missing, then out of range; neither merges.
    let before = farm.job(id).unwrap().aov().clone();
    let l = farm.assign(a, Instant::now()).unwrap();
    let sums = fake_sums(&l.batch);
    assert!(farm.complete(a, &result(&l, &sums, None), Instant::now()).is_err());
    let b = farm.add_worker("b".into(), 1, Instant::now());
    let l = farm.assign(b, Instant::now()).unwrap();
    let (sums, mut aov) = (fake_sums(&l.batch), fake_aov(&l.batch, 8));
    aov[0] = u64::MAX;
    assert!(farm.complete(b, &BatchResult { aov: &aov, ..result(&l, &sums, None) }, Instant::now()).is_err());
    assert_eq!(farm.job(id).unwrap().aov(), &before);

    let now = Instant::now();
    let job = farm.job(id).unwrap();
    let checkpoint = job.snapshot(now).checkpoint();
    let parts = checkpoint.encode();
    let stored = LoadedJob {
        record: job.record(),
        checkpoint: Some(crate::checkpoint::Checkpoint::decode(&parts).unwrap()),
    };
    let mut restarted = Farm::new();
    restarted.restore(stored, now).unwrap();
    let c = restarted.add_worker("c".into(), 1, Instant::now());
    run(&mut restarted, c, usize::MAX);
    assert_eq!(restarted.job(id).unwrap().aov(), clean.job(id).unwrap().aov());
    assert_eq!(restarted.job(id).unwrap().framebuffer(), clean.job(id).unwrap().framebuffer());
}

/// Two workers, one rendering a sample in 1 µs and one in 4 µs and saying so, work on
/// `farm`'s job until each has had three pass-two batches cut for it; returns the clock
/// and the pixels of each one's last such batch. (A worker is also handed copies of the
/// other's batches, cut at the other's pace: audits, frequent while both are on
/// probation, and speculative duplicates. They carry an id already seen.)
fn race(farm: &mut Farm, mut clock: Instant) -> (Instant, [usize; 2]) {
    use crate::scheduler::Pass;
    let fast = farm.add_worker("fast".into(), 1, clock);
    let slow = farm.add_worker("slow".into(), 1, clock);
    let mut last = [0usize; 2];
    let mut pass_two = [0usize; 2];
    let mut seen = HashSet::new();
    while pass_two.iter().any(|&n| n < 3) {
        for (k, (worker, micros)) in [(fast, 1), (slow, 4)].into_iter().enumerate() {
            let a = farm.assign(worker, clock).unwrap();
            let took = Duration::from_micros(a.batch.sample_count() * micros);
            clock += took;
            let sums = fake_sums(&a.batch);
            let r = BatchResult { render: took, ..result(&a, &sums, None) };
            farm.complete(worker, &r, clock).unwrap();
            if seen.insert(a.batch.id) && a.batch.pass == Pass::Two {
                pass_two[k] += 1;
                last[k] = a.batch.quads.len();
            }
        }
    }
    (clock, last)
}

/// Each worker's pass-two batches take about `PASS_TWO_BATCH_TIME` at its own measured
/// speed (a worker four times faster gets batches four times larger), and a job restored
/// from a checkpoint of such a cut ends with the accumulators of a job cut at the fixed
/// sizes.
#[test]
fn pass_two_batches_follow_each_worker_s_speed() {
    use crate::scheduler::PASS_TWO_BATCH_TIME;
    let (w, h, spp) = (256, 256, 33);
    let mut clean = Farm::new();
    let id = clean.submit(bundle(), settings(w, h, spp), 0).unwrap();
    let cw = clean.add_worker("clean".into(), 1, Instant::now());
    work(&mut clean, cw, usize::MAX);

    let mut farm = Farm::new();
    assert_eq!(farm.submit(bundle(), settings(w, h, spp), 0).unwrap(), id);
    let (clock, last) = race(&mut farm, Instant::now());
    let per_pixel = u64::from(spp - 1);
    let batch_secs = PASS_TWO_BATCH_TIME.as_secs_f64();
    assert_eq!(last[0] as u64, (1e6 * batch_secs) as u64 / per_pixel);
    assert_eq!(last[1] as u64, (0.25e6 * batch_secs) as u64 / per_pixel);

    let job = farm.job(id).unwrap();
    let stored = LoadedJob { record: job.record(), checkpoint: Some(job.snapshot(clock).checkpoint()) };
    let mut restarted = Farm::new();
    restarted.restore(stored, clock).unwrap();
    let b = restarted.add_worker("b".into(), 1, clock);
    work(&mut restarted, b, usize::MAX);
    let (got, want) = (restarted.job(id).unwrap(), clean.job(id).unwrap());
    assert_eq!(got.state, JobState::Done);
    assert_eq!(got.framebuffer().accumulators(), want.framebuffer().accumulators());
}

/// A farm set to shorter batches (`--batch-time`) cuts each worker's batches to that time
/// at its speed.
#[test]
fn the_farm_s_batch_time_sets_the_paced_size() {
    let mut farm = Farm::new();
    farm.set_batch_time(Duration::from_millis(25));
    assert_eq!(farm.batch_time(), Duration::from_millis(25));
    farm.submit(bundle(), settings(256, 256, 33), 0).unwrap();
    let (_, last) = race(&mut farm, Instant::now());
    // 25 ms at a million and at a quarter million samples a second, 32 samples a pixel.
    assert_eq!(last, [25_000 / 32, 6_250 / 32]);
}

/// The farm's count of render threads follows workers joining and leaving (it sizes the
/// end of pass two's batches).
#[test]
fn render_threads_follow_the_workers() {
    let mut farm = Farm::new();
    let now = Instant::now();
    let a = farm.add_worker("a".into(), 8, now);
    let b = farm.add_worker("b".into(), 3, now);
    assert_eq!(farm.render_threads(), 11);
    farm.remove_worker(a, now);
    assert_eq!(farm.render_threads(), 3);
    // Removing twice, or a worker never seen, changes nothing.
    farm.remove_worker(a, now);
    farm.remove_worker(WorkerId(999), now);
    assert_eq!(farm.render_threads(), 3);
    farm.remove_worker(b, now);
    assert_eq!(farm.render_threads(), 0);
}
