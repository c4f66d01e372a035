//! The coordinator service's behaviour, driven in one process by fake workers and viewers:
//! leases, failures, silence, pause, and what viewers see.

use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_coordinator::Timing;
use tessera_description::ids::JobId;
use tessera_description::job::JobState;
use tessera_film::framebuffer::Framebuffer;
use tessera_harness::{pixel_value, FakeViewer, FakeWorker, Harness, ServeStats};
use tokio::task::JoinHandle;

/// 32×32 at 4 spp: seven pass-one batches (16, 32, … 512, then 16 pixels) and one pass-two
/// batch, so that every test runs in a fraction of a second.
const W: u32 = 32;
const H: u32 = 32;
const SPP: u32 = 4;
const BATCHES: u64 = 8;

/// A worker that answers every batch at once, in the background.
async fn serving(h: &Harness, name: &str) -> (tessera_description::ids::WorkerId, JoinHandle<()>) {
    let w = FakeWorker::connect(&h.channel(), name, 2).await.unwrap();
    let id = w.id;
    let task = tokio::spawn(async move {
        let _ = w.serve(Duration::ZERO, Arc::new(ServeStats::new(false))).await;
    });
    (id, task)
}

/// Every pixel holds exactly `spp` samples of `pixel_value`: each batch merged exactly
/// once, in its place, whoever rendered it and however often it was leased.
fn assert_exact(fb: &Framebuffer, spp: u32) {
    let (sums, counts) = fb.accumulators();
    for y in 0..fb.height() {
        for x in 0..fb.width() {
            let i = (y * fb.width() + x) as usize;
            assert_eq!(counts[i], spp, "samples of pixel {x},{y}");
            assert_eq!(sums[i], pixel_value(x, y).map(|v| v * u64::from(spp)), "sums of pixel {x},{y}");
        }
    }
}

/// The viewer reads to the final update; its replica resolves to the coordinator's image
/// byte for byte and holds the exact accumulators.
async fn assert_converged(h: &Harness, viewer: &mut FakeViewer, job: JobId) {
    viewer.until_final().await.unwrap();
    let image = h.fetch_image(job).await.unwrap();
    assert_eq!((image.width, image.height), (W, H));
    assert!(viewer.image_bytes().unwrap() == image.bytes, "the replica differs from FetchImage");
    assert_exact(viewer.replica().unwrap(), SPP);
}

/// Invariant: fake workers drive a job to the end, and a viewer watching from the start
/// ends with a replica identical to the coordinator's image (exactly once, determinism,
/// viewers' deltas lose nothing).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_rendered_by_fake_workers_completes_and_the_replica_is_the_image() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    let (a, _ta) = serving(&h, "a").await;
    let (b, _tb) = serving(&h, "b").await;
    let done = h.wait_over(job).await.unwrap();
    assert_eq!(done.state, JobState::Done);
    assert_eq!(done.samples_done, done.samples_total);
    assert_converged(&h, &mut viewer, job).await;
    let status = h.status().await.unwrap();
    let merged: u64 = [a, b].iter().map(|&id| status.worker(id).unwrap().batches_done).sum();
    assert_eq!(merged, BATCHES);
}

/// Invariant: when a worker's stream ends, every batch leased to it is leased again at
/// once, and the job ends with the same accumulators as an undisturbed one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_that_disconnects_mid_batch_has_its_batches_re_leased() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    let mut a = FakeWorker::connect(&h.channel(), "crashes", 4).await.unwrap();
    let mut batches = Vec::new();
    for _ in 0..4 {
        batches.push(a.next_batch().await.unwrap());
    }
    assert_eq!(a.scenes, vec![job.0], "the scene comes once, before the first batch");
    a.answer(&batches[0]).await.unwrap();
    tessera_harness::wait_for(&h.channel(), job, Duration::from_secs(10), |j| j.samples_done > 0)
        .await
        .unwrap();
    let a_id = a.id;
    a.disconnect();
    let (b, _tb) = serving(&h, "b").await;
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    assert_converged(&h, &mut viewer, job).await;
    let status = h.status().await.unwrap();
    assert!(status.worker(a_id).is_none(), "the crashed worker is gone");
    assert_eq!(status.worker(b).unwrap().batches_done, BATCHES - 1, "b rendered all the rest");
}

/// Invariant: nothing half-merged — a result with the wrong number of sums disconnects
/// its worker with a reason, its batch goes back to the queue, and the job completes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_malformed_result_disconnects_its_worker_and_the_batch_is_redone() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    let mut a = FakeWorker::connect(&h.channel(), "hostile", 1).await.unwrap();
    let batch = a.next_batch().await.unwrap();
    let mut bad = tessera_harness::valid_result(&batch);
    bad.sums.pop();
    a.send_results(vec![bad], 1).await.unwrap();
    let reason = a.refusal().await.unwrap();
    assert!(reason.contains("malformed result"), "{reason}");
    assert_eq!(h.job(job).await.unwrap().samples_done, 0, "nothing of it was merged");
    let (b, _tb) = serving(&h, "b").await;
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    assert_converged(&h, &mut viewer, job).await;
    assert_eq!(h.status().await.unwrap().worker(b).unwrap().batches_done, BATCHES);
}

/// Invariant: a batch that workers cannot render fails the job after three failures, with
/// a message that carries the workers' error, instead of being retried for ever.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_batch_failed_three_times_fails_the_job_with_a_message() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut a = FakeWorker::connect(&h.channel(), "broken", 1).await.unwrap();
    let mut failures = 0;
    // Bounded: the job must fail within the first few failures.
    while failures < 10 && !h.job(job).await.unwrap().state.is_over() {
        let Ok(Some(tessera_proto::v1::coordinator_message::Msg::Batch(batch))) =
            a.next_within(Duration::from_millis(500)).await
        else {
            continue;
        };
        a.fail(&batch, "the scene failed to load here").await.unwrap();
        failures += 1;
    }
    let over = h.wait_over(job).await.unwrap();
    let JobState::Failed(message) = over.state else { panic!("expected a failed job, got {:?}", over.state) };
    assert!(message.contains("failed 3 times"), "{message}");
    assert!(message.contains("the scene failed to load here"), "{message}");
    assert_eq!(failures, 3, "the third failure of the first batch ends the job");
}

/// Invariant: a silent worker's leases are taken back after the silence timeout, so that
/// a frozen machine does not hold a job up; the job then completes exactly.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_workers_leases_are_taken_back_after_the_timeout() {
    let timing = Timing {
        heartbeat: Duration::from_millis(100),
        silence_timeout: Duration::from_millis(300),
        ..Default::default()
    };
    let h = Harness::start_with(timing).await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    // Held, never driven again: its stream stays open, it sends nothing.
    let mut silent = FakeWorker::connect(&h.channel(), "frozen", 2).await.unwrap();
    silent.next_batch().await.unwrap();
    silent.next_batch().await.unwrap();
    let leased_at = Instant::now();
    assert_eq!(h.status().await.unwrap().worker(silent.id).unwrap().in_flight, 2);
    let start = Instant::now();
    loop {
        let status = h.status().await.unwrap();
        if status.worker(silent.id).map_or(0, |w| w.in_flight) == 0 {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(5), "leases not taken back: {status:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(leased_at.elapsed() >= timing.silence_timeout, "taken back before the timeout");
    let _b = serving(&h, "b").await;
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    assert_converged(&h, &mut viewer, job).await;
    drop(silent);
}

/// Invariant: a paused job leases nothing new (the batch out still merges), and resuming
/// it continues where it was.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pause_stops_new_leases_and_resume_continues() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    let mut a = FakeWorker::connect(&h.channel(), "a", 1).await.unwrap();
    let first = a.next_batch().await.unwrap();
    h.pause(job, true).await.unwrap();
    assert_eq!(h.job(job).await.unwrap().state, JobState::Paused);
    a.answer(&first).await.unwrap();
    let next = a.next_within(Duration::from_millis(500)).await.unwrap();
    assert!(next.is_none(), "a paused job leased {next:?}");
    let paused = h.job(job).await.unwrap();
    assert_eq!(
        paused.samples_done,
        u64::from(first.sample_end - first.sample_start) * 16,
        "the batch out merged"
    );
    assert_eq!(paused.state, JobState::Paused);
    h.pause(job, false).await.unwrap();
    let second = a.next_batch().await.unwrap();
    assert_eq!(second.batch_id, first.batch_id + 1, "it continues with the next batch");
    a.answer(&second).await.unwrap();
    tokio::spawn(a.serve(Duration::ZERO, Arc::new(ServeStats::new(false))));
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    assert_converged(&h, &mut viewer, job).await;
}

/// Invariant: a viewer that joins mid-job starts from a reset snapshot of exactly the
/// pixels merged so far, then converges to the final image.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_joining_mid_job_gets_a_reset_snapshot_then_converges() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut a = FakeWorker::connect(&h.channel(), "a", 1).await.unwrap();
    // Four pass-one batches: 16 + 32 + 64 + 128 pixels.
    for _ in 0..4 {
        let b = a.next_batch().await.unwrap();
        a.answer(&b).await.unwrap();
    }
    let merged = 16 + 32 + 64 + 128;
    tessera_harness::wait_for(&h.channel(), job, Duration::from_secs(10), |j| j.samples_done == merged)
        .await
        .unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    let first = viewer.next_within(Duration::from_secs(10)).await.unwrap();
    assert!(first.reset, "the first update of a stream is a reset");
    while viewer.versions_seen == 0 {
        viewer.next_within(Duration::from_secs(10)).await.unwrap();
    }
    assert_eq!(viewer.version, 4, "the snapshot is of the four merges");
    let (_, counts) = viewer.replica().unwrap().accumulators();
    assert_eq!(counts.iter().filter(|&&c| c > 0).count() as u64, merged, "the snapshot holds what is merged");
    assert!(counts.iter().all(|&c| c <= 1), "pass one only");
    tokio::spawn(a.serve(Duration::ZERO, Arc::new(ServeStats::new(false))));
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    assert_converged(&h, &mut viewer, job).await;
    assert_eq!(viewer.resets, 1);
}

/// Invariant (proto `FramebufferUpdate.reset`): only the first update of a stream is a
/// reset, also for a viewer that joins before the first merge (the old feeder derived it
/// from "nothing sent yet" and repeated it until something was merged).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_first_update_of_a_stream_is_a_reset() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let mut viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap();
    // Let the viewer see the empty job before any batch is merged.
    viewer.next_within(Duration::from_secs(10)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let _a = serving(&h, "a").await;
    assert_converged(&h, &mut viewer, job).await;
    assert_eq!(viewer.resets, 1, "resets in one stream");
}

/// Invariant (ARCHITECTURE, viewers never slow rendering): viewers in step are fed the
/// delta one publisher computed for the job, not a scan of their own per tick; a viewer
/// makes its own updates only to join (and to catch up, should it fall behind).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewers_in_step_share_the_publishers_deltas() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(160, 120, 256).await.unwrap();
    let mut viewers = Vec::new();
    for _ in 0..3 {
        viewers.push(FakeViewer::watch(&h.channel(), job.0, 0.0, true).await.unwrap());
    }
    // Slow enough that the job spans many publisher ticks.
    let w = FakeWorker::connect(&h.channel(), "slow", 2).await.unwrap();
    tokio::spawn(w.serve(Duration::from_millis(10), Arc::new(ServeStats::new(false))));
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    let image = h.fetch_image(job).await.unwrap();
    for v in &mut viewers {
        v.until_final().await.unwrap();
        assert!(v.image_bytes().unwrap() == image.bytes, "a replica differs from FetchImage");
    }
    let fed = h.service().viewer_updates();
    eprintln!("viewer updates: {fed:?}");
    assert!(fed.shared > 3 * fed.own, "most updates come from shared deltas: {fed:?}");
}

/// A viewer of protocol version 1 sends no version and could not read the pixels: its
/// watch is refused with a reason, not answered with updates it would show as blank.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_of_another_protocol_is_refused_with_a_reason() {
    let h = Harness::start().await.unwrap();
    let job = h.submit_small(W, H, SPP).await.unwrap();
    let old = tessera_proto::v1::WatchRequest { job_id: job.0, ..Default::default() };
    let status = tessera_harness::client(&h.channel()).watch(old).await.unwrap_err();
    assert_eq!(status.code(), tonic::Code::FailedPrecondition);
    assert!(status.message().contains("protocol version 0"), "{}", status.message());
}

/// Bug this protects against: a bundle of millions of empty assets (2 bytes each on the
/// wire, ~50 decoded, again when converted) cost gigabytes before validation could refuse
/// it. The submit gate counts assets on the wire first; nothing is queued.
#[tokio::test]
async fn a_bundle_of_too_many_assets_is_refused_before_it_is_decoded() {
    use tessera_proto::v1 as pb;
    let h = Harness::start().await.unwrap();
    let n = tessera_description::limits::MAX_ASSETS + 1;
    let request = pb::SubmitRequest {
        protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
        bundle: Some(pb::SceneBundle {
            name: "many.toml".into(),
            text: tessera_harness::SMALL_SCENE.into(),
            assets: vec![pb::Asset::default(); n],
        }),
        settings: None,
        priority: 0,
    };
    let e = tessera_harness::client(&h.channel()).submit(request).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    // From the gate (validation would name the scene file first).
    assert!(
        e.message().starts_with(&format!("the bundle carries {n} assets, more than the limit")),
        "{}",
        e.message()
    );
    assert!(h.status().await.unwrap().jobs.is_empty());
}

/// Bug this protects against: every call of the client service decoded up to Submit's
/// 257 MiB limit, so a viewer's token could make the coordinator buffer that much per
/// Status request. Requests of other calls are refused beyond 64 KiB from their prefix.
#[tokio::test]
async fn an_oversized_request_of_another_call_is_refused_from_its_prefix() {
    use tessera_proto::v1 as pb;
    /// A StatusRequest with an unknown field to pad it (prost skips unknown fields).
    #[derive(Clone, PartialEq, prost::Message)]
    struct Padded {
        #[prost(bytes = "vec", tag = "100")]
        pad: Vec<u8>,
    }
    let h = Harness::start().await.unwrap();
    let mut grpc = tonic::client::Grpc::new(h.channel());
    let path = tonic::codegen::http::uri::PathAndQuery::from_static("/tessera.v1.Coordinator/Status");
    for (size, refused) in [(1000, false), (1 << 20, true)] {
        grpc.ready().await.unwrap();
        let codec = tonic_prost::ProstCodec::<Padded, pb::StatusResponse>::default();
        let r = grpc.unary(tonic::Request::new(Padded { pad: vec![7; size] }), path.clone(), codec).await;
        match (r, refused) {
            (Ok(_), false) => {}
            (Err(e), true) => {
                assert_eq!(e.code(), tonic::Code::OutOfRange, "{e:?}");
                assert!(e.message().contains("this call takes at most 65536"), "{}", e.message());
            }
            (r, _) => panic!("a padded Status request of {size} bytes: {r:?}"),
        }
    }
}

/// Invariant: a viewer of previews is sent display values while the job renders (the
/// shared deltas), no exact pixel state until the job is over, then the exact state of
/// every pixel: it ends with the coordinator's bytes. One that joins mid-render starts
/// from an exact snapshot of its own and ends the same.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn preview_viewers_see_previews_while_rendering_and_end_with_the_exact_image() {
    let h = Harness::start().await.unwrap();
    let (w, hgt, spp) = (64, 64, 64);
    let job = h.submit_small(w, hgt, spp).await.unwrap();
    let mut early = FakeViewer::watch_previews(&h.channel(), job.0, 0.0, true).await.unwrap();
    let first = early.next_within(Duration::from_secs(10)).await.unwrap();
    assert!(first.reset && first.pixels.is_empty() && first.preview.is_empty(), "an empty snapshot first");
    let mut workers = Vec::new();
    for name in ["a", "b"] {
        let fw = FakeWorker::connect(&h.channel(), name, 2).await.unwrap();
        workers.push(tokio::spawn(fw.serve(Duration::from_millis(100), Arc::new(ServeStats::new(false)))));
    }
    // A delta painted with pass two's first results, then a viewer joins.
    let mut deltas = 0;
    while deltas == 0 {
        let u = early.next_within(Duration::from_secs(20)).await.unwrap();
        assert!(u.pixels.is_empty() || u.r#final || early.finished, "exact states before the end");
        deltas += u64::from(!u.reset && !u.preview.is_empty());
    }
    let mut late = FakeViewer::watch_previews(&h.channel(), job.0, 0.0, true).await.unwrap();
    let joined = late.next_within(Duration::from_secs(10)).await.unwrap();
    assert!(
        joined.reset && !joined.pixels.is_empty(),
        "a viewer that joins starts from a snapshot of its own"
    );
    h.wait_over(job).await.unwrap();
    let image = h.fetch_image(job).await.unwrap();
    for v in [&mut early, &mut late] {
        v.until_final().await.unwrap();
        assert_eq!(v.resets, 1);
        assert!(v.image_bytes().unwrap() == image.bytes, "the final replica differs from FetchImage");
        let shown: Vec<u8> = v.shown().unwrap().iter().flat_map(|f| f.to_le_bytes()).collect();
        assert!(shown == image.bytes, "the final picture still shows a preview");
    }
    assert_eq!(early.exact, 1, "exact states come once, in the final update (4096 pixels, one chunk)");
    assert!(late.exact >= 2, "its snapshot, then the final update");
    assert!(early.previews >= 2, "{} previews", early.previews);
}

/// Invariant: a viewer of previews in step is sent the refinement of coarse blocks also
/// while nothing is merged (a paused job), until it shows the image at pixel detail.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn preview_viewers_are_refined_while_the_job_is_paused() {
    let h = Harness::start().await.unwrap();
    // 65 536 pixels: more than one tick's blocks for one viewer, so pass one is painted
    // in coarse blocks first.
    let (w, hgt) = (256, 256);
    let job = h.submit_small(w, hgt, 64).await.unwrap();
    let mut v = FakeViewer::watch_previews(&h.channel(), job.0, 0.0, true).await.unwrap();
    v.next_within(Duration::from_secs(10)).await.unwrap();
    let fw = FakeWorker::connect(&h.channel(), "a", 2).await.unwrap();
    let _serving = tokio::spawn(fw.serve(Duration::from_millis(400), Arc::new(ServeStats::new(false))));
    let pixels = u64::from(w) * u64::from(hgt);
    tessera_harness::wait_for(&h.channel(), job, Duration::from_secs(30), |j| j.pass_one_done >= pixels)
        .await
        .unwrap();
    h.pause(job, true).await.unwrap();
    // Leases out when it was paused are still answered and merged.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let image = h.fetch_image(job).await.unwrap();
    let exact: Vec<f32> =
        image.bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    let start = std::time::Instant::now();
    loop {
        v.next_within(Duration::from_secs(10)).await.unwrap();
        let shown = v.shown().unwrap();
        // Half floats: within their precision of the exact value.
        let off =
            shown.iter().zip(&exact).filter(|(s, e)| (*s - *e).abs() > 1e-3 * e.abs().max(1e-3)).count();
        if off == 0 {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(20), "{off} pixels still coarse after 20 s paused");
    }
}
