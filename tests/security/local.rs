//! `tessera render`'s loopback coordinator takes only its own secret.

use std::time::Duration;

use tessera_proto::connect::EndpointConfig;
use tessera_proto::credentials::Token;
use tessera_proto::v1 as pb;
use tonic::Code;

use crate::common::*;
use crate::secrets::*;

/// The children of process `pid`.
fn children(pid: u32) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(child) = entry.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else { continue };
        // After the command name in parentheses: state, then the parent's pid.
        let ppid = stat.rsplit(')').next().and_then(|rest| rest.split_whitespace().nth(1));
        if ppid == Some(pid.to_string().as_str()) {
            found.push(child);
        }
    }
    found
}

/// `tessera render`'s loopback coordinator takes only its own secret: a client without it
/// (another user of the machine) can neither read nor join; the workers get the secret in
/// their environment, not on their command line, and it lets them work and nothing else.
#[test]
fn a_local_render_takes_only_its_own_secret() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("slow.png");
    let scene = small_scene();
    let mut render = Proc::spawn(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--workers",
        "1",
        "--threads",
        "1",
        "--spp",
        "100000",
    ]);
    let line = render.wait_for("local coordinator on ", Duration::from_secs(30));
    let addr = line.rsplit("coordinator on ").next().unwrap().split(',').next().unwrap().to_string();
    let url = format!("http://{addr}");
    let rt = runtime();
    rt.block_on(async {
        for token in [None, Some("a-guess-at-the-secret-0123456789")] {
            let mut c = client(&url, None, token).await.unwrap();
            let (code, _) = status_code(c.status(pb::StatusRequest { job_id: 0 }).await);
            assert_eq!(code, Code::Unauthenticated);
            let hello = pb::WorkerMessage {
                msg: Some(pb::worker_message::Msg::Hello(pb::Hello {
                    protocol_version: pb::ProtocolVersion::Current as i32,
                    renderer_version: tessera_description::RENDERER_VERSION.into(),
                    name: "intruder".into(),
                    threads: 1,
                    credit: 2,
                    frames: true,
                    held_scenes: vec![],
                })),
            };
            let mut w = tessera_proto::connect::worker_client(
                &EndpointConfig::new(&url).unwrap().token(token.map(|t| Token::new(t, "test").unwrap())),
            )
            .await
            .unwrap();
            let (code, _) = status_code(w.work(tokio_stream::iter([hello])).await);
            assert_eq!(code, Code::Unauthenticated);
        }
    });
    // The worker's secret: in its environment, not its command line; good for work only.
    let start = std::time::Instant::now();
    let worker = loop {
        if let Some(&w) = children(render.pid()).first() {
            break w;
        }
        assert!(start.elapsed() < Duration::from_secs(10), "no worker process");
        std::thread::sleep(Duration::from_millis(20));
    };
    let environ = std::fs::read(format!("/proc/{worker}/environ")).unwrap();
    let secret = environ
        .split(|b| *b == 0)
        .find_map(|kv| kv.strip_prefix(b"TESSERA_TOKEN="))
        .map(|v| String::from_utf8(v.to_vec()).unwrap())
        .expect("the worker has its secret in its environment");
    assert_eq!(secret.len(), 64, "256 bits as hex");
    let cmdline = std::fs::read(format!("/proc/{worker}/cmdline")).unwrap();
    assert!(!String::from_utf8_lossy(&cmdline).contains(&secret), "the secret is on a command line");
    rt.block_on(async {
        let mut c = client(&url, None, Some(&secret)).await.unwrap();
        let (code, _) = status_code(c.status(pb::StatusRequest { job_id: 0 }).await);
        assert_eq!(code, Code::PermissionDenied);
    });
    drop(rt);
    render.signal(2);
    render.wait(Duration::from_secs(30));
}
