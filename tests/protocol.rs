//! End-to-end: hostile or broken peers speaking gRPC to a real coordinator process. Each
//! is refused with a clear reason, and the coordinator keeps serving everyone else.

mod common;

use common::*;
use std::time::Duration;
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_client::CoordinatorClient;
use tessera_proto::v1::coordinator_message::Msg as In;
use tessera_proto::v1::worker_message::Msg as Out;
use tessera_proto::v1::workers_client::WorkersClient;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;

fn hello(protocol: i32, renderer: &str) -> pb::WorkerMessage {
    holding(protocol, renderer, vec![])
}

/// A Hello that says the worker holds the scenes of these content hashes.
fn holding(protocol: i32, renderer: &str, held_scenes: Vec<String>) -> pb::WorkerMessage {
    pb::WorkerMessage {
        msg: Some(Out::Hello(pb::Hello {
            protocol_version: protocol,
            renderer_version: renderer.into(),
            name: "hostile".into(),
            threads: 1,
            credit: 1,
            frames: true,
            held_scenes,
        })),
    }
}

/// Opens a worker stream, sends `first`, and returns the channel and the stream.
async fn open(
    url: &str,
    first: pb::WorkerMessage,
) -> (mpsc::Sender<pb::WorkerMessage>, tonic::Streaming<pb::CoordinatorMessage>) {
    let mut client = WorkersClient::connect(url.to_string()).await.unwrap();
    let (tx, rx) = mpsc::channel(8);
    tx.send(first).await.unwrap();
    let inbound = client.work(ReceiverStream::new(rx)).await.unwrap().into_inner();
    (tx, inbound)
}

async fn next(inbound: &mut tonic::Streaming<pb::CoordinatorMessage>) -> Option<In> {
    tokio::time::timeout(Duration::from_secs(20), inbound.message())
        .await
        .expect("coordinator answered")
        .ok()?
        .and_then(|m| m.msg)
}

fn refused(m: Option<In>) -> String {
    match m {
        Some(In::Refused(r)) => r.reason,
        other => panic!("expected Refused, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn handshake_mismatches_are_refused_with_reasons() {
    let coord = Coordinator::start(&[]);
    let current = pb::ProtocolVersion::Current as i32;
    let version = tessera_worker::RENDERER_VERSION;

    let (_tx, mut inbound) = open(&coord.url, hello(0, version)).await;
    assert!(refused(next(&mut inbound).await).contains("protocol version 0"));

    let (_tx, mut inbound) = open(&coord.url, hello(current, "0.0.0-other")).await;
    let reason = refused(next(&mut inbound).await);
    assert!(reason.contains("0.0.0-other") && reason.contains("bit-identical"), "{reason}");

    let (_tx, mut inbound) =
        open(&coord.url, pb::WorkerMessage { msg: Some(Out::Heartbeat(pb::Heartbeat {})) }).await;
    assert!(refused(next(&mut inbound).await).contains("must be Hello"));
}

/// A worker that says it holds a scene gets that scene's jobs by hash alone (no bundle);
/// one that does not gets the bundle; a Hello whose held scenes are too many or not content
/// hashes is refused, with the reason.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_held_scene_is_sent_by_its_hash_alone() {
    let coord = Coordinator::start(&[]);
    let (current, version) = (pb::ProtocolVersion::Current as i32, tessera_worker::RENDERER_VERSION);
    let (_tx, mut inbound) = open(&coord.url, holding(current, version, vec!["f".repeat(64); 17])).await;
    let reason = refused(next(&mut inbound).await);
    assert!(reason.contains("holds 17 scenes, more than the limit of 16"), "{reason}");
    for bad in ["F".repeat(64), "f".repeat(63), format!("{}g", "f".repeat(63))] {
        let held = vec!["0".repeat(64), bad.clone()];
        let (_tx, mut inbound) = open(&coord.url, holding(current, version, held)).await;
        let reason = refused(next(&mut inbound).await);
        assert!(reason.contains("held scene 1 is not a content hash"), "{bad}: {reason}");
    }

    let scene = small_scene();
    let hash = tessera_description::Bundle::read(&scene).unwrap().hash();
    let (_held_tx, mut held) = open(&coord.url, holding(current, version, vec![hash.clone()])).await;
    assert!(matches!(next(&mut held).await, Some(In::Welcome(_))));
    let (_other_tx, mut other) = open(&coord.url, holding(current, version, vec!["0".repeat(64)])).await;
    assert!(matches!(next(&mut other).await, Some(In::Welcome(_))));
    let url = coord.url.clone();
    let _submit =
        tokio::task::spawn_blocking(move || run(&["submit", scene.to_str().unwrap(), "--coordinator", &url]));
    for (inbound, holds) in [(&mut held, true), (&mut other, false)] {
        let Some(In::Scene(js)) = next(inbound).await else { panic!("expected the job's scene") };
        assert_eq!(js.scene_hash, hash);
        assert_eq!(js.bundle.is_none(), holds, "bundle sent: {}", js.bundle.is_some());
        assert!(js.settings.is_some());
        assert!(matches!(next(inbound).await, Some(In::Batch(_))));
    }
}

/// A worker that returns malformed sums is disconnected; its batch is re-leased, and the
/// job still ends byte-identical to a clean render.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_results_are_refused_and_the_job_survives() {
    let dir = tempfile::tempdir().unwrap();
    let coord = Coordinator::start(&[]);
    let current = pb::ProtocolVersion::Current as i32;
    let (tx, mut inbound) = open(&coord.url, hello(current, tessera_worker::RENDERER_VERSION)).await;
    assert!(matches!(next(&mut inbound).await, Some(In::Welcome(_))));

    let out = dir.path().join("out.png");
    let scene = small_scene();
    let url = coord.url.clone();
    let out_arg = out.clone();
    let submit = tokio::task::spawn_blocking(move || {
        run(&["submit", scene.to_str().unwrap(), "--coordinator", &url, "-o", out_arg.to_str().unwrap()])
    });
    // The hostile worker gets the scene, then a batch.
    assert!(matches!(next(&mut inbound).await, Some(In::Scene(_))));
    let Some(In::Batch(batch)) = next(&mut inbound).await else { panic!("expected a batch") };
    // A result for a job that does not exist is ignored, not fatal.
    let bogus = pb::BatchResult { job_id: 999, batch_id: 0, attempt: 1, sums: vec![], ..Default::default() };
    tx.send(pb::WorkerMessage { msg: Some(Out::Results(pb::Results { results: vec![bogus], credit: 0 })) })
        .await
        .unwrap();
    // Then a result with the wrong number of sums.
    let bad = pb::BatchResult {
        job_id: batch.job_id,
        batch_id: batch.batch_id,
        attempt: batch.attempt,
        // The lease's token: only its holder's results are checked (and then refused).
        lease: batch.lease.clone(),
        sums: vec![1, 2],
        ..Default::default()
    };
    tx.send(pb::WorkerMessage { msg: Some(Out::Results(pb::Results { results: vec![bad], credit: 1 })) })
        .await
        .unwrap();
    let reason = refused(next(&mut inbound).await);
    assert!(reason.contains("malformed result") && reason.contains("expected"), "{reason}");

    // A real worker finishes the job, with the hostile one's batch re-leased.
    let _worker = coord.worker(2);
    let o = submit.await.unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let reference = dir.path().join("reference.png");
    render_local(&small_scene(), &reference, 1, &[]);
    assert_eq!(read(&out), read(&reference));
}

/// Out-of-range sums (more light than the samples can carry) are refused too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn impossible_sums_are_refused() {
    let coord = Coordinator::start(&[]);
    let current = pb::ProtocolVersion::Current as i32;
    let (tx, mut inbound) = open(&coord.url, hello(current, tessera_worker::RENDERER_VERSION)).await;
    assert!(matches!(next(&mut inbound).await, Some(In::Welcome(_))));
    let scene = small_scene();
    let url = coord.url.clone();
    tokio::task::spawn_blocking(move || run(&["submit", scene.to_str().unwrap(), "--coordinator", &url]))
        .await
        .unwrap();
    assert!(matches!(next(&mut inbound).await, Some(In::Scene(_))));
    let Some(In::Batch(batch)) = next(&mut inbound).await else { panic!("expected a batch") };
    let n = batch.pixels.len() / 2 * 3;
    let bad = pb::BatchResult {
        job_id: batch.job_id,
        batch_id: batch.batch_id,
        attempt: batch.attempt,
        // The lease's token: only its holder's results are checked (and then refused).
        lease: batch.lease.clone(),
        sums: vec![u64::MAX; n],
        ..Default::default()
    };
    tx.send(pb::WorkerMessage { msg: Some(Out::Results(pb::Results { results: vec![bad], credit: 1 })) })
        .await
        .unwrap();
    assert!(refused(next(&mut inbound).await).contains("exceeds"));
    let status = coord.status();
    assert!(status.contains("running") || status.contains("queued"), "{status}");
}

/// Clients: an old protocol, or a scene that fails validation on the coordinator.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_submissions_are_refused_by_the_coordinator() {
    let coord = Coordinator::start(&[]);
    let mut client = CoordinatorClient::connect(coord.url.clone()).await.unwrap();
    let bundle =
        pb::SceneBundle { name: "remote.toml".into(), text: "[render]\nwidth = -3\n".into(), assets: vec![] };
    let err = client
        .submit(pb::SubmitRequest {
            protocol_version: 0,
            bundle: Some(bundle.clone()),
            settings: None,
            priority: 0,
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::FailedPrecondition);
    let current = pb::ProtocolVersion::Current as i32;
    let err = client
        .submit(pb::SubmitRequest {
            protocol_version: current,
            bundle: Some(bundle),
            settings: None,
            priority: 0,
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    assert!(err.message().starts_with("remote.toml:2:"), "{}", err.message());
    let err = client
        .submit(pb::SubmitRequest { protocol_version: current, bundle: None, settings: None, priority: 0 })
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    let err = client.status(pb::StatusRequest { job_id: 42 }).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::NotFound);
}
