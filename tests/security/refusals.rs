//! Refused calls are refused with the right code and change nothing; a coordinator that
//! would listen beyond loopback unauthenticated, and a worker with a refused token, stop.

use std::path::Path;
use std::time::Duration;

use tessera_proto::connect::ConnectError;
use tessera_proto::v1 as pb;
use tonic::Code;

use crate::common::*;
use crate::secrets::*;

/// What must not change when a call is refused: every job as the admin sees it, every
/// job's image bytes, and the database file.
#[derive(Debug, PartialEq)]
struct Snapshot {
    jobs: Vec<(u64, i32, u64, i32)>,
    images: Vec<Vec<u8>>,
    database: Vec<u8>,
}

async fn snapshot(url: &str, ca: &str, data: &Path) -> Snapshot {
    let mut admin = client(url, Some(ca), Some(ADMIN)).await.unwrap();
    let status = admin.status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner();
    let jobs: Vec<_> = status.jobs.iter().map(|j| (j.job_id, j.state, j.samples_done, j.priority)).collect();
    let mut images = Vec::new();
    for j in &status.jobs {
        let mut stream = admin
            .fetch_image(pb::FetchImageRequest { job_id: j.job_id, ..Default::default() })
            .await
            .unwrap()
            .into_inner();
        let mut bytes = Vec::new();
        while let Some(chunk) = stream.message().await.unwrap() {
            bytes.extend_from_slice(&chunk.rgb);
        }
        images.push(bytes);
    }
    let database = std::fs::read(data.join("jobs.db")).unwrap();
    Snapshot { jobs, images, database }
}

/// Plain text, a wrong CA, no token, a wrong token and wrong roles are each refused with
/// the right code, and none changes the job list, the images or the database; ownership
/// survives a restart.
#[test]
fn refused_calls_are_refused_with_no_side_effect() {
    let s = Secrets::new();
    let data = s.path("data");
    let (mut coord, url) = tls_coordinator(&s, &data, &["--max-priority", "2"]);
    let ca = s.ca();
    let rt = runtime();
    // Alice's job, queued (no worker): every refused call below would change it.
    let alice_job = rt.block_on(async {
        let mut alice = client(&url, Some(&ca), Some(ALICE)).await.unwrap();
        alice.submit(submit_request(1)).await.unwrap().into_inner().job_id
    });
    // Let the checkpointer write the new job's first checkpoint.
    std::thread::sleep(Duration::from_millis(1500));
    let before = rt.block_on(snapshot(&url, &ca, &data));
    assert_eq!(before.jobs.len(), 1);

    rt.block_on(async {
        // Plain text against the TLS port.
        let plain = url.replace("https://", "http://");
        match client(&plain, None, Some(ADMIN)).await {
            Err(_) => {}
            Ok(mut c) => {
                assert!(c.status(pb::StatusRequest { job_id: 0 }).await.is_err(), "plain text was answered");
                assert!(c.submit(submit_request(0)).await.is_err());
            }
        }
        // Another farm's CA: the handshake fails, nothing is sent.
        let e = client(&url, Some(&s.arg("other/ca.pem")), Some(ADMIN)).await.unwrap_err();
        assert!(matches!(e, ConnectError::Unreachable { .. }), "{e:?}");
        assert!(e.to_string().to_lowercase().contains("certificate"), "{e}");
        // The system's roots do not know the farm's CA either.
        assert!(client(&url, None, Some(ADMIN)).await.is_err());

        // No token, a wrong token.
        for token in [None, Some("not-a-token-of-this-farm-at-all")] {
            let mut c = client(&url, Some(&ca), token).await.unwrap();
            let (code, _) = status_code(c.status(pb::StatusRequest { job_id: 0 }).await);
            assert_eq!(code, Code::Unauthenticated, "{token:?}");
            let (code, _) = status_code(c.submit(submit_request(0)).await);
            assert_eq!(code, Code::Unauthenticated, "{token:?}");
            let (code, _) = status_code(c.cancel(pb::CancelRequest { job_id: alice_job }).await);
            assert_eq!(code, Code::Unauthenticated, "{token:?}");
        }

        // The viewer may read, not submit, pause or cancel.
        let mut viewer = client(&url, Some(&ca), Some(VIEWER)).await.unwrap();
        let (code, msg) = status_code(viewer.submit(submit_request(0)).await);
        assert_eq!(
            (code, msg.as_str()),
            (Code::PermissionDenied, "viewer `wall` may not submit: that needs the admin or submitter role")
        );
        let (code, _) = status_code(viewer.cancel(pb::CancelRequest { job_id: alice_job }).await);
        assert_eq!(code, Code::PermissionDenied);
        let (code, _) = status_code(viewer.pause(pb::PauseRequest { job_id: alice_job, paused: true }).await);
        assert_eq!(code, Code::PermissionDenied);
        assert_eq!(viewer.status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner().jobs.len(), 1);

        // Bob may not touch or see Alice's job.
        let mut bob = client(&url, Some(&ca), Some(BOB)).await.unwrap();
        let (code, msg) = status_code(bob.cancel(pb::CancelRequest { job_id: alice_job }).await);
        assert_eq!(code, Code::PermissionDenied);
        assert!(msg.contains("belongs to another submitter"), "{msg}");
        let (code, _) = status_code(bob.pause(pb::PauseRequest { job_id: alice_job, paused: true }).await);
        assert_eq!(code, Code::PermissionDenied);
        let (code, _) = status_code(
            bob.fetch_image(pb::FetchImageRequest { job_id: alice_job, ..Default::default() }).await,
        );
        assert_eq!(code, Code::PermissionDenied);
        let (code, _) = status_code(bob.status(pb::StatusRequest { job_id: alice_job }).await);
        assert_eq!(code, Code::PermissionDenied);
        let watch = pb::WatchRequest {
            job_id: alice_job,
            max_rate: 0.0,
            protocol_version: pb::ProtocolVersion::Current as i32,
            frame: None,
            previews: false,
        };
        let (code, _) = status_code(bob.watch(watch).await);
        assert_eq!(code, Code::PermissionDenied);
        assert!(bob.status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner().jobs.is_empty());

        // A worker's token works, and only works.
        let mut worker = client(&url, Some(&ca), Some(WORKER)).await.unwrap();
        let (code, msg) = status_code(worker.status(pb::StatusRequest { job_id: 0 }).await);
        assert_eq!(
            (code, msg.as_str()),
            (
                Code::PermissionDenied,
                "worker `node-1` may not read the status: that needs the admin or submitter or viewer role"
            )
        );
        let (code, _) = status_code(worker.submit(submit_request(0)).await);
        assert_eq!(code, Code::PermissionDenied);

        // Alice above the ceiling of 2.
        let mut alice = client(&url, Some(&ca), Some(ALICE)).await.unwrap();
        let (code, msg) = status_code(alice.submit(submit_request(3)).await);
        assert_eq!(code, Code::PermissionDenied);
        assert!(msg.contains("priority 3 is above 2"), "{msg}");
    });
    let after = rt.block_on(snapshot(&url, &ca, &data));
    assert!(
        after == before,
        "a refused call changed something:\nbefore {:?}\nafter  {:?}",
        before.jobs,
        after.jobs
    );

    // The owner is stored with the job: after a restart, Bob still may not cancel it and
    // Alice still sees it. The runtime goes first, with its connections, so that the
    // coordinator's graceful shutdown has none to wait for.
    drop(rt);
    coord.signal(15);
    assert!(coord.wait(Duration::from_secs(30)).success());
    let (_again, url) = tls_coordinator(&s, &data, &[]);
    runtime().block_on(async {
        let mut bob = client(&url, Some(&ca), Some(BOB)).await.unwrap();
        let (code, _) = status_code(bob.cancel(pb::CancelRequest { job_id: alice_job }).await);
        assert_eq!(code, Code::PermissionDenied);
        let mut alice = client(&url, Some(&ca), Some(ALICE)).await.unwrap();
        let jobs = alice.status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner().jobs;
        assert_eq!(jobs.iter().map(|j| j.job_id).collect::<Vec<_>>(), [alice_job]);
        alice.cancel(pb::CancelRequest { job_id: alice_job }).await.unwrap();
    });
}

/// Listening beyond loopback needs authentication, or `--insecure` said in so many words.
#[test]
fn listening_beyond_loopback_needs_authentication_or_insecure() {
    let o = run_with_timeout(&["coordinator", "--listen", "0.0.0.0:0"], Duration::from_secs(30));
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("refusing to listen on 0.0.0.0:0 with no authentication"), "{err}");
    let open = Proc::spawn(&["coordinator", "--listen", "0.0.0.0:0", "--insecure"]);
    open.wait_for("coordinator listening on ", Duration::from_secs(30));
    let s = Secrets::new();
    let tokens = s.arg("tokens");
    // Tokens in plain text beyond loopback: refused, unless --insecure.
    let o = run_with_timeout(
        &["coordinator", "--listen", "0.0.0.0:0", "--tokens", &tokens],
        Duration::from_secs(30),
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("refusing to take tokens in plain text"), "{o:?}");
    let with_tokens =
        Proc::spawn(&["coordinator", "--listen", "0.0.0.0:0", "--tokens", &tokens, "--insecure"]);
    with_tokens.wait_for("coordinator listening on ", Duration::from_secs(30));
    // A tokens file every user can read is refused.
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(s.path("tokens"), std::fs::Permissions::from_mode(0o644)).unwrap();
    }
    let o = run_with_timeout(
        &["coordinator", "--listen", "127.0.0.1:0", "--tokens", &tokens],
        Duration::from_secs(30),
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("can be read by every user (mode 644)"), "{o:?}");
}

/// A worker with a wrong token or role is told so once and exits, rather than retrying
/// forever.
#[test]
fn a_worker_with_a_refused_token_says_so_and_exits() {
    let s = Secrets::new();
    let data = s.path("data");
    let (_coord, url) = tls_coordinator(&s, &data, &[]);
    let ca = s.ca();
    for (token, says) in
        [("not-a-token-of-this-farm-at-all", "unknown token"), (VIEWER, "viewer `wall` may not work")]
    {
        let mut w = Proc::spawn_with_env(
            &["worker", "--coordinator", &url, "--ca", &ca, "--threads", "1"],
            &[("TESSERA_TOKEN", token)],
        );
        assert!(!w.wait(Duration::from_secs(30)).success());
        let err = w.stderr.lock().unwrap().clone();
        assert!(err.contains("the coordinator refused") && err.contains(says), "{err}");
    }
}
