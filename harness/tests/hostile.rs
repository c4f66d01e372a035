//! Hostile workers against the coordinator's fences and audits: forged lease tokens,
//! answers for other workers' leases, scenes never sent, impossible attempt numbers and
//! non-finite counts, failures by one worker or many, scene refusals, and workers whose
//! sums are in range but wrong (zeroed, doubled, wrong once in fifty batches). Each is
//! refused or caught, the liar quarantined and refused at reconnection, and the final
//! image byte-identical to a clean run with honest fakes only.

use std::sync::Arc;
use std::time::Duration;

use tessera_coordinator::farm::AuditPolicy;
use tessera_description::ids::JobId;
use tessera_description::job::JobState;
use tessera_harness::{client, FakeWorker, Harness, HarnessError, ServeStats};
use tessera_proto::v1 as pb;
use tokio::task::JoinHandle;

/// 32×32 at 4 spp: eight batches, so each test runs in a fraction of a second.
const W: u32 = 32;
const H: u32 = 32;
const SPP: u32 = 4;

/// A harness whose coordinator audits as `policy` says.
async fn harness(policy: AuditPolicy) -> Harness {
    let h = Harness::start().await.unwrap();
    h.service().set_audit_policy(policy);
    h
}

/// The image bytes of a `w`×`h`@`spp` job rendered by honest fakes only: the oracle.
async fn clean_image(w: u32, h: u32, spp: u32) -> Vec<u8> {
    let harness = harness(AuditPolicy::off()).await;
    let job = harness.submit_small(w, h, spp).await.unwrap();
    let _a = serving(&harness, "clean-a", |_, _| {}).await;
    let _b = serving(&harness, "clean-b", |_, _| {}).await;
    assert_eq!(harness.wait_over(job).await.unwrap().state, JobState::Done);
    harness.fetch_image(job).await.unwrap().bytes
}

/// A worker serving every batch at once in the background, its results passed through
/// `edit` (honest: leave them).
async fn serving(
    h: &Harness,
    name: &str,
    edit: impl FnMut(&pb::Batch, &mut pb::BatchResult) + Send + 'static,
) -> JoinHandle<()> {
    let w = FakeWorker::connect(&h.channel(), name, 2).await.unwrap();
    tokio::spawn(async move {
        let _ = w.serve_with(Duration::ZERO, Arc::new(ServeStats::new(false)), edit).await;
    })
}

/// The raw Status entries of workers (with strikes and quarantine).
async fn workers(h: &Harness) -> Vec<pb::WorkerStatus> {
    client(&h.channel()).status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner().workers
}

async fn strikes(h: &Harness, name: &str) -> u32 {
    workers(h)
        .await
        .iter()
        .find(|w| w.name == name || w.name.ends_with(&format!("/{name}")))
        .map_or(0, |w| w.strikes)
}

/// Whether Status lists the identity of `name` as quarantined.
async fn quarantined(h: &Harness, name: &str) -> bool {
    workers(h).await.iter().any(|w| w.quarantined && w.name.ends_with(&format!("/{name}")))
}

/// A reconnection under `name` is refused because it is quarantined.
async fn refused_at_reconnect(h: &Harness, name: &str) {
    match FakeWorker::connect(&h.new_channel().await.unwrap(), name, 1).await {
        Err(HarnessError::Refused(reason)) => assert!(reason.contains("quarantined"), "{reason}"),
        Err(e) => panic!("reconnecting {name}: {e}"),
        Ok(_) => panic!("{name} was let in again after its quarantine"),
    }
}

/// Waits until Status has quarantined `name`.
async fn until_quarantined(h: &Harness, name: &str) {
    for _ in 0..2000 {
        if quarantined(h, name).await {
            return;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("{name} was never quarantined");
}

/// Drives the job to the end with one honest worker; returns the final image bytes.
async fn finish_honestly(h: &Harness, job: JobId) -> Vec<u8> {
    let _honest = serving(h, "finisher", |_, _| {}).await;
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    h.fetch_image(job).await.unwrap().bytes
}

/// Bug this protects against: a result was accepted for a batch leased to another
/// worker, a forged token counted, and a failure for another's lease took it back.
/// Each is refused, leaves the lease to its holder, and is a strike; the third
/// quarantines the sender, which is refused at reconnection and listed in Status.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn forged_tokens_and_answers_for_others_leases_are_refused_and_struck() {
    let h = harness(AuditPolicy::off()).await;
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut honest = FakeWorker::connect(&h.channel(), "honest", 1).await.unwrap();
    let mut thief = FakeWorker::connect(&h.channel(), "thief", 1).await.unwrap();
    let theirs = honest.next_batch().await.unwrap();
    let mine = thief.next_batch().await.unwrap();
    assert_ne!(theirs.lease, mine.lease, "every lease has its own token");
    assert!(theirs.lease.len() >= 16);

    // The honest worker's batch, with its real token, from the thief.
    thief.forge(&theirs, theirs.lease.clone()).await.unwrap();
    // Its own batch with a made-up token.
    thief.forge(&mine, vec![0; 16]).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(strikes(&h, "thief").await, 2);
    assert_eq!(h.job(job).await.unwrap().samples_done, 0, "nothing forged merged");

    // The lease stayed the honest worker's: its answer merges.
    honest.answer(&theirs).await.unwrap();
    let after = h.job(job).await.unwrap().samples_done;
    tessera_harness::wait_for(&h.channel(), job, Duration::from_secs(5), |j| j.samples_done > 0)
        .await
        .unwrap();
    let _ = after;

    // A failure for the honest worker's next lease: the third strike.
    let next = honest.next_batch().await.unwrap();
    thief.fail_with(&next, "sabotage", |_| {}).await.unwrap();
    let reason = thief.refusal().await.unwrap();
    assert!(reason.contains("quarantined"), "{reason}");
    assert!(quarantined(&h, "thief").await);
    refused_at_reconnect(&h, "thief").await;

    // The failure did not take the lease: the honest answer merges, and the job ends as
    // a clean one does.
    honest.answer(&next).await.unwrap();
    drop(honest);
    let image = finish_honestly(&h, job).await;
    assert!(image == clean_image(W, H, SPP).await, "the image differs from a clean render");
}

/// Bug this protects against: a worker that never received a job's scene could deliver
/// its batches. Refused and struck; the lease is untouched.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn results_for_a_scene_never_sent_are_refused() {
    let h = harness(AuditPolicy::off()).await;
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut honest = FakeWorker::connect(&h.channel(), "honest", 1).await.unwrap();
    let batch = honest.next_batch().await.unwrap();
    // No credit: it is never sent the scene.
    let mut stranger = FakeWorker::connect(&h.channel(), "stranger", 0).await.unwrap();
    stranger.forge(&batch, batch.lease.clone()).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(strikes(&h, "stranger").await, 1);
    assert_eq!(h.job(job).await.unwrap().samples_done, 0);
    assert!(stranger.scenes.is_empty());
    honest.answer(&batch).await.unwrap();
    tessera_harness::wait_for(&h.channel(), job, Duration::from_secs(5), |j| j.samples_done > 0)
        .await
        .unwrap();
}

/// Bug this protects against: attempt numbers 0 or 999 and `nonfinite_samples =
/// u64::MAX` were accepted. Each is refused (the worker disconnected, the batch given to
/// others) and struck; three quarantine the identity across reconnections.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn impossible_attempts_and_nonfinite_counts_are_refused() {
    let h = harness(AuditPolicy::off()).await;
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let edits: [fn(&mut pb::BatchResult); 3] =
        [|r| r.attempt = 0, |r| r.attempt = 999, |r| r.nonfinite_samples = u64::MAX];
    for (k, edit) in edits.into_iter().enumerate() {
        let mut w = FakeWorker::connect(&h.new_channel().await.unwrap(), "odd", 1).await.unwrap();
        let b = w.next_batch().await.unwrap();
        w.answer_with(&b, edit).await.unwrap();
        let reason = w.refusal().await.unwrap();
        assert!(
            reason.contains("attempt") || reason.contains("non-finite") || reason.contains("quarantined"),
            "{reason}"
        );
        assert_eq!(h.job(job).await.unwrap().samples_done, 0, "edit {k} merged");
    }
    until_quarantined(&h, "odd").await;
    refused_at_reconnect(&h, "odd").await;
    let image = finish_honestly(&h, job).await;
    assert!(image == clean_image(W, H, SPP).await);
}

/// Invariant: failures count per identity. One worker failing a batch three times (with
/// another connected) does not fail the job; three distinct workers failing it do.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_batch_fails_its_job_only_on_three_distinct_workers() {
    let h = harness(AuditPolicy::off()).await;
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let _idle = FakeWorker::connect(&h.channel(), "idle", 0).await.unwrap();
    let mut flaky = FakeWorker::connect(&h.channel(), "flaky", 1).await.unwrap();
    let first = flaky.next_batch().await.unwrap();
    let mut b = first.clone();
    for _ in 0..3 {
        assert_eq!(b.batch_id, first.batch_id, "a failed batch is leased again first");
        flaky.fail(&b, "out of luck").await.unwrap();
        b = flaky.next_batch().await.unwrap();
    }
    assert!(!h.job(job).await.unwrap().state.is_over(), "one worker's failures failed the job");
    assert_eq!(strikes(&h, "flaky").await, 0, "failing its own lease is no strike");
    drop(flaky);

    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut batch_id = None;
    for name in ["x", "y", "z"] {
        let mut w = FakeWorker::connect(&h.new_channel().await.unwrap(), name, 1).await.unwrap();
        // The first job's batches come first for a new worker: fail only the second's.
        let b = loop {
            let b = w.next_batch().await.unwrap();
            if b.job_id == job.0 {
                break b;
            }
            w.answer(&b).await.unwrap();
        };
        assert_eq!(*batch_id.get_or_insert(b.batch_id), b.batch_id);
        // No credit back, so the batch goes to the next worker.
        w.fail_with(&b, "cannot", |f| f.credit = 0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        std::mem::forget(w);
    }
    let p = h.wait_over(job).await.unwrap();
    match p.state {
        JobState::Failed(m) => assert!(m.contains("3 workers"), "{m}"),
        other => panic!("job ended {other:?}"),
    }
}

/// Scene refusals send the job to others and do not count as failures; a job every
/// connected worker refused fails with a message saying so.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refused_scenes_go_to_other_workers_and_fail_only_when_all_refuse() {
    let h = harness(AuditPolicy::off()).await;
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut small = FakeWorker::connect(&h.channel(), "small", 1).await.unwrap();
    // Another worker connected (idle): not every connected worker refused the job.
    let _idle = FakeWorker::connect(&h.channel(), "idle", 0).await.unwrap();
    let b = small.next_batch().await.unwrap();
    small.fail_with(&b, "the scene needs 9 GB; this worker has 4", |f| f.scene_refused = true).await.unwrap();
    assert!(small.next_within(Duration::from_millis(200)).await.unwrap().is_none(), "sent the job again");
    let image = finish_honestly(&h, job).await;
    assert!(image == clean_image(W, H, SPP).await);

    let h = harness(AuditPolicy::off()).await;
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut a = FakeWorker::connect(&h.channel(), "a", 1).await.unwrap();
    let mut b = FakeWorker::connect(&h.channel(), "b", 1).await.unwrap();
    for w in [&mut a, &mut b] {
        let batch = w.next_batch().await.unwrap();
        w.fail_with(&batch, "too big", |f| f.scene_refused = true).await.unwrap();
    }
    match h.wait_over(job).await.unwrap().state {
        JobState::Failed(m) => assert!(m.contains("every connected worker refused"), "{m}"),
        other => panic!("job ended {other:?}"),
    }
}

/// A job of many small batches (64×64 at 257 spp: 128-pixel pass-two batches), so that a
/// liar delivers dozens of them.
const MANY: (u32, u32, u32) = (64, 64, 257);

/// The liar's time for a batch of `REFERENCE_BATCH_SAMPLES` samples.
const LIAR_BATCH_TIME: Duration = Duration::from_millis(20);

/// Runs MANY with three honest workers and one liar editing its results; returns the
/// final image and whether the liar was quarantined.
async fn with_liar(
    policy: AuditPolicy,
    lie: impl FnMut(&pb::Batch, &mut pb::BatchResult) + Send + 'static,
) -> (Harness, Vec<u8>) {
    let h = harness(policy).await;
    let (w, ht, spp) = MANY;
    let job = h.submit_small(w, ht, spp).await.unwrap();
    // The liar first, so that its batches are merged before anyone can audit them (caught
    // first as another's auditor, it would have delivered nothing to repair). It renders
    // at a realistic pace, so that the others join while it works: a liar answering at
    // once could deliver the whole job before they connect on a loaded machine, and
    // audits that no other worker answers in time are skipped (a CI run: 20 audits, all
    // skipped, the liar not caught).
    let liar = FakeWorker::connect(&h.channel(), "liar", 2).await.unwrap();
    let _liar = tokio::spawn(async move {
        let _ = liar.serve_with(LIAR_BATCH_TIME, Arc::new(ServeStats::new(false)), lie).await;
    });
    let _a = serving(&h, "a", |_, _| {}).await;
    let _b = serving(&h, "b", |_, _| {}).await;
    let _c = serving(&h, "c", |_, _| {}).await;
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    let image = h.fetch_image(job).await.unwrap().bytes;
    (h, image)
}

/// Bug this protects against: in-range but wrong sums (all zero, doubled) merged
/// silently. Audits catch the liar, it is quarantined, every pixel it delivered is
/// rendered again, and the image is byte-identical to a clean render.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn zeroed_and_doubled_sums_are_caught_and_repaired() {
    let (w, ht, spp) = MANY;
    let clean = clean_image(w, ht, spp).await;
    // Every batch audited: which batches are audited is the OS's random choice, and a test
    // must not depend on the liar being drawn (`tessera bench audit` measures the odds).
    let policy = AuditPolicy { fraction: 1.0, probation_batches: 0, probation_fraction: 0.0 };
    let lies: [fn(&pb::Batch, &mut pb::BatchResult); 2] =
        [|_, r| r.sums.iter_mut().for_each(|s| *s = 0), |_, r| r.sums.iter_mut().for_each(|s| *s *= 2)];
    for lie in lies {
        let (h, image) = with_liar(policy, lie).await;
        let c = h.service().fence_counters();
        assert!(quarantined(&h, "liar").await, "the liar was not caught ({c:?})");
        refused_at_reconnect(&h, "liar").await;
        let c = h.service().fence_counters();
        assert!(c.liars == 1 && c.repaired_pixels > 0, "{c:?}");
        assert!(image == clean, "the repaired image differs from a clean render ({c:?})");
    }
}

/// A worker that zeroes one batch in fifty and is honest otherwise is caught at that
/// batch when it is audited (here every batch is), quarantined, and repaired. Its first
/// lie is its second answer: how many batches a worker gets depends on the machine's
/// load, and a lie it never gets to tell cannot be caught.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_lying_once_in_fifty_batches_is_caught() {
    let (w, ht, spp) = MANY;
    let clean = clean_image(w, ht, spp).await;
    let policy = AuditPolicy { fraction: 1.0, probation_batches: 0, probation_fraction: 0.0 };
    let answers = Arc::new(std::sync::atomic::AtomicU32::new(0));
    let counted = answers.clone();
    let (h, image) = with_liar(policy, move |b, r| {
        let n = counted.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        if n % 50 == 2 {
            eprintln!(
                "liar zeroes answer {n}: job {} batch {} attempt {} pass {}",
                b.job_id, b.batch_id, b.attempt, b.pass
            );
            r.sums.iter_mut().for_each(|s| *s = 0);
        }
    })
    .await;
    let c = h.service().fence_counters();
    assert!(
        quarantined(&h, "liar").await,
        "the liar was not caught ({} answers; {c:?})",
        answers.load(std::sync::atomic::Ordering::Relaxed)
    );
    let c = h.service().fence_counters();
    assert!(c.audits_passed > 10 && c.liars == 1, "{c:?}");
    assert!(image == clean, "the repaired image differs from a clean render ({c:?})");
}

/// Honest workers are never struck or quarantined, with audits on at their default and
/// speculative duplicates and all.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn honest_workers_pass_every_audit() {
    let (w, ht, spp) = MANY;
    let clean = clean_image(w, ht, spp).await;
    let (h, image) = with_liar(AuditPolicy::default(), |_, _| {}).await;
    let c = h.service().fence_counters();
    assert_eq!((c.strikes, c.quarantines, c.audits_mismatched), (0, 0, 0), "{c:?}");
    assert!(c.audits_passed > 0, "{c:?}");
    assert!(image == clean);
}

/// Bug this protects against: a results message with millions of (empty) entries was
/// walked entry by entry under the farm's lock, a strike and a log line each. More results
/// than the protocol allows in one message are refused whole and the worker disconnected.
#[tokio::test]
async fn more_results_than_leases_in_one_message_are_refused_whole() {
    let h = harness(AuditPolicy::default()).await;
    let _job = h.submit_small(8, 8, 2).await.unwrap();
    let mut w = FakeWorker::connect(&h.channel(), "flood", 1).await.unwrap();
    let b = w.next_batch().await.unwrap();
    let one = tessera_harness::valid_result(&b);
    let flood = vec![one; tessera_proto::MAX_RESULTS_PER_MESSAGE + 1];
    w.send_results(flood, 0).await.unwrap();
    let reason = w.refusal().await.unwrap();
    assert!(reason.contains("more than the 8 the protocol allows"), "{reason}");
}
