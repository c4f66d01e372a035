//! Authentication and roles in one process: a coordinator with tokens, fake workers and
//! clients with different tokens. Each refused call is refused with its code and leaves
//! no trace (no worker registered, no job, no state changed).

use std::sync::Arc;
use std::time::Duration;

use tessera_coordinator::{Auth, Role, Timing, Tokens};
use tessera_description::job::JobState;
use tessera_harness::{FakeWorker, Harness, HarnessError, Security, ServeStats};
use tessera_proto::credentials::Token;
use tessera_proto::v1 as pb;
use tonic::Code;

const ADMIN: &str = "admin-0123456789abcdef";
const ALICE: &str = "alice-0123456789abcdef";
const BOB: &str = "bob-0123456789abcdef01";
const WORKER: &str = "worker-0123456789abcdef";
const VIEWER: &str = "viewer-0123456789abcdef";

fn token(t: &str) -> Option<Token> {
    Some(Token::new(t, "test").unwrap())
}

/// A harness whose own channel is the admin's.
async fn secured() -> Harness {
    let tokens = Tokens::new()
        .with(Role::Admin, "root", ADMIN)
        .with(Role::Submitter, "alice", ALICE)
        .with(Role::Submitter, "bob", BOB)
        .with(Role::Worker, "node-1", WORKER)
        .with(Role::Viewer, "wall", VIEWER);
    let security =
        Security { auth: Auth::new(Some(tokens), false), token: token(ADMIN), ..Security::default() };
    Harness::start_secured(Timing::default(), security).await.unwrap()
}

fn code(e: HarnessError) -> Code {
    match e {
        HarnessError::Status(s) => s.code(),
        other => panic!("expected a refusal, got {other:?}"),
    }
}

/// Only a worker (or admin) token may open a work stream; a refused one is never a worker.
#[tokio::test]
async fn only_workers_work() {
    let h = secured().await;
    for (t, expected) in [
        (None, Code::Unauthenticated),
        (token(VIEWER), Code::PermissionDenied),
        (token(ALICE), Code::PermissionDenied),
    ] {
        let ch = h.channel_with(t).await.unwrap();
        let e = FakeWorker::connect(&ch, "intruder", 2).await.err().expect("refused");
        assert_eq!(code(e), expected);
    }
    assert!(h.status().await.unwrap().workers.is_empty(), "a refused worker was registered");
    let ch = h.channel_with(token(WORKER)).await.unwrap();
    let w = FakeWorker::connect(&ch, "node-1", 2).await.unwrap();
    assert_eq!(h.status().await.unwrap().workers.len(), 1);
    // The worker renders Alice's job to its end; Alice fetches it, Bob may not.
    let task = tokio::spawn(async move {
        let _ = w.serve(Duration::ZERO, Arc::new(ServeStats::new(false))).await;
    });
    let alice = h.channel_with(token(ALICE)).await.unwrap();
    let settings = pb::RenderSettings { spp: 2, width: 16, height: 16, ..Default::default() };
    let job =
        tessera_harness::submit(&alice, "small.toml", tessera_harness::SMALL_SCENE, settings).await.unwrap();
    assert_eq!(h.wait_over(job).await.unwrap().state, JobState::Done);
    let image = tessera_harness::fetch_image(&alice, job).await.unwrap();
    assert_eq!(image, h.fetch_image(job).await.unwrap());
    let bob = h.channel_with(token(BOB)).await.unwrap();
    assert_eq!(code(tessera_harness::fetch_image(&bob, job).await.unwrap_err()), Code::PermissionDenied);
    // Bob's Status has no jobs and shows workers without their names.
    let status = tessera_harness::status(&bob).await.unwrap();
    assert!(status.jobs.is_empty());
    assert_eq!(status.workers.iter().map(|w| w.name.as_str()).collect::<Vec<_>>(), [""]);
    task.abort();
}

/// A submitter's priority ceiling (0 by default) and the admin above it; a submitter's
/// pause of another's job changes nothing.
#[tokio::test]
async fn priorities_above_the_ceiling_need_an_admin() {
    let h = secured().await;
    let alice = tessera_harness::client(&h.channel_with(token(ALICE)).await.unwrap());
    let request = |priority| pb::SubmitRequest {
        protocol_version: pb::ProtocolVersion::Current as i32,
        bundle: Some(pb::SceneBundle {
            name: "small.toml".into(),
            text: tessera_harness::SMALL_SCENE.into(),
            assets: vec![],
        }),
        settings: Some(pb::RenderSettings { spp: 1, width: 8, height: 8, ..Default::default() }),
        priority,
    };
    let e = alice.clone().submit(request(1)).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied);
    assert!(h.status().await.unwrap().jobs.is_empty(), "a refused submission was queued");
    let job = alice.clone().submit(request(0)).await.unwrap().into_inner().job_id;
    let admin = tessera_harness::client(&h.channel());
    admin.clone().submit(request(100)).await.unwrap();
    let bob = tessera_harness::client(&h.channel_with(token(BOB)).await.unwrap());
    let e = bob.clone().pause(pb::PauseRequest { job_id: job, paused: true }).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied);
    let states: Vec<JobState> = h.status().await.unwrap().jobs.into_iter().map(|j| j.state).collect();
    assert_eq!(states, [JobState::Queued, JobState::Queued]);
    alice.clone().pause(pb::PauseRequest { job_id: job, paused: true }).await.unwrap();
    assert_eq!(h.job(tessera_description::ids::JobId(job)).await.unwrap().state, JobState::Paused);
}

/// Bugs this protects against: a submitter's Watch without a job id listed every job's
/// scene name, and a submitter's Cancel of an id not yet used passed the ownership check,
/// so a guess of the next id could cancel another's job as it was inserted.
#[tokio::test]
async fn a_submitter_sees_and_touches_only_its_own_jobs_even_by_guessing() {
    let h = secured().await;
    let alice = h.channel_with(token(ALICE)).await.unwrap();
    let bob = h.channel_with(token(BOB)).await.unwrap();
    let settings = pb::RenderSettings { spp: 2, width: 16, height: 16, ..Default::default() };
    let job = tessera_harness::submit(&alice, "secret-project.toml", tessera_harness::SMALL_SCENE, settings)
        .await
        .unwrap();
    // Bob's Watch with no job finds none of his and names nothing of Alice's.
    let watch = pb::WatchRequest {
        job_id: 0,
        protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
        ..Default::default()
    };
    let Err(refused) = tessera_harness::client(&bob).watch(watch).await else {
        panic!("Bob was given a job to watch")
    };
    assert_eq!(refused.code(), Code::NotFound, "{refused:?}");
    assert!(!refused.message().contains("secret"), "{}", refused.message());
    // An id that does not exist yet is not found for a submitter, not let through.
    let next = job.0 + 1;
    let e = tessera_harness::client(&bob).cancel(pb::CancelRequest { job_id: next }).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    let e = tessera_harness::client(&bob).cancel(pb::CancelRequest { job_id: job.0 }).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied);
    assert_eq!(h.job(job).await.unwrap().state, JobState::Queued);
}
