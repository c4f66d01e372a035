//! End-to-end: TLS and authentication with real `tessera` processes on loopback. Certificates
//! come from `tessera certs`, tokens from a tokens file. A TLS farm renders the bytes of a
//! local render; every refused call is refused with the right code and changes nothing
//! (the job list, the images and the database are compared before and after).

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::*;
use tessera_proto::connect::{ConnectError, EndpointConfig};
use tessera_proto::credentials::{ClientTls, Token};
use tessera_proto::v1 as pb;
use tonic::Code;

const ADMIN: &str = "admin-token-0123456789abcdef";
const ALICE: &str = "alice-token-0123456789abcdef";
const BOB: &str = "bob-token-0123456789abcdef01";
const WORKER: &str = "worker-token-0123456789abcdef";
const VIEWER: &str = "viewer-token-0123456789abcdef";

/// The tiny render every test uses.
const SIZE: &str = "16x12";
const SPP: &str = "2";

/// `tessera certs …`, which must succeed.
fn certs(args: &[&str]) {
    let mut all = vec!["certs"];
    all.extend_from_slice(args);
    let o = run(&all);
    assert!(o.status.success(), "tessera {all:?}: {}", String::from_utf8_lossy(&o.stderr));
}

/// A farm's certificates and tokens in a temporary directory.
struct Secrets {
    dir: tempfile::TempDir,
}

impl Secrets {
    fn new() -> Secrets {
        let dir = tempfile::tempdir().unwrap();
        let pki = dir.path().join("pki");
        let p = pki.to_str().unwrap();
        certs(&["ca", "--dir", p]);
        certs(&["server", "--dir", p, "--host", "localhost", "--host", "127.0.0.1"]);
        certs(&["client", "--dir", p, "--name", "node-1", "--role", "worker"]);
        certs(&["client", "--dir", p, "--name", "root", "--role", "admin"]);
        // Another farm's CA, which must not be trusted.
        certs(&["ca", "--dir", dir.path().join("other").to_str().unwrap()]);
        write_secret(
            &dir.path().join("tokens"),
            &format!(
                "# role name token\nadmin root {ADMIN}\nsubmitter alice {ALICE}\nsubmitter bob {BOB}\n\
                 worker node-1 {WORKER}\nviewer wall {VIEWER}\n"
            ),
        );
        for (name, token) in
            [("admin", ADMIN), ("alice", ALICE), ("bob", BOB), ("worker", WORKER), ("viewer", VIEWER)]
        {
            write_secret(&dir.path().join(format!("{name}.token")), &format!("{token}\n"));
        }
        Secrets { dir }
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    fn arg(&self, name: &str) -> String {
        self.path(name).to_str().unwrap().to_string()
    }

    fn ca(&self) -> String {
        self.arg("pki/ca.pem")
    }
}

/// A coordinator process, with the URL from its "listening on" line.
fn coordinator(args: &[&str], host: &str) -> (Proc, String) {
    let mut all = vec!["coordinator", "--listen", "127.0.0.1:0"];
    all.extend_from_slice(args);
    let proc = Proc::spawn(&all);
    let line = proc.wait_for("coordinator listening on ", Duration::from_secs(30));
    let addr = line.rsplit("listening on ").next().unwrap().split_whitespace().next().unwrap().to_string();
    let port = addr.rsplit(':').next().unwrap();
    let scheme = if line.contains("(TLS)") { "https" } else { "http" };
    (proc, format!("{scheme}://{host}:{port}"))
}

fn tls_coordinator(s: &Secrets, data: &Path, extra: &[&str]) -> (Proc, String) {
    let (cert, key, tokens) = (s.arg("pki/server.pem"), s.arg("pki/server.key"), s.arg("tokens"));
    let mut args =
        vec!["--tls-cert", &cert, "--tls-key", &key, "--tokens", &tokens, "--data", data.to_str().unwrap()];
    args.extend_from_slice(extra);
    coordinator(&args, "localhost")
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

/// A client of `url` trusting `ca`, sending `token`.
async fn client(
    url: &str,
    ca: Option<&str>,
    token: Option<&str>,
) -> Result<tessera_proto::connect::Client, ConnectError> {
    let mut tls = ClientTls::new();
    if let Some(ca) = ca {
        tls = tls.ca_file(Path::new(ca))?;
    }
    let token = token.map(|t| Token::new(t, "test").unwrap());
    tessera_proto::connect::client(&EndpointConfig::new(url)?.tls(tls)?.token(token)).await
}

fn submit_request(priority: i32) -> pb::SubmitRequest {
    pb::SubmitRequest {
        protocol_version: pb::ProtocolVersion::Current as i32,
        bundle: Some(pb::SceneBundle {
            name: "small.toml".into(),
            text: std::fs::read_to_string(small_scene()).unwrap(),
            assets: vec![],
        }),
        settings: Some(pb::RenderSettings { spp: 2, width: 16, height: 12, ..Default::default() }),
        priority,
    }
}

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

fn status_code<T: std::fmt::Debug>(r: Result<T, tonic::Status>) -> (Code, String) {
    let s = r.expect_err("the call was accepted");
    (s.code(), s.message().to_string())
}

/// A TLS farm with tokens (coordinator, `tessera worker` verifying against the farm's CA
/// with a worker token, `tessera submit` with a submitter's token file) renders the bytes
/// of a local render.
#[test]
fn a_tls_farm_with_tokens_renders_the_bytes_of_a_local_render() {
    let s = Secrets::new();
    let local = s.path("local.png");
    render_local(&small_scene(), &local, 1, &["--size", SIZE, "--spp", SPP]);
    let data = s.path("data");
    let (_coord, url) = tls_coordinator(&s, &data, &[]);
    assert!(url.starts_with("https://localhost:"), "{url}");
    let ca = s.ca();
    let _worker = {
        let w = Proc::spawn_with_env(
            &["worker", "--coordinator", &url, "--ca", &ca, "--threads", "1", "--name", "node-1"],
            &[("TESSERA_TOKEN", WORKER)],
        );
        w.wait_for("connected to", Duration::from_secs(30));
        w
    };
    let farm = s.path("farm.png");
    let (scene, out, token) = (small_scene(), farm.to_str().unwrap().to_string(), s.arg("alice.token"));
    let o = run(&[
        "submit",
        scene.to_str().unwrap(),
        "--coordinator",
        &url,
        "--ca",
        &ca,
        "--token-file",
        &token,
        "--size",
        SIZE,
        "--spp",
        SPP,
        "-o",
        &out,
    ]);
    assert!(o.status.success(), "submit: {}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(read(&farm), read(&local), "the TLS farm's image differs from the local render");
    // `tessera status` over TLS as the viewer lists the job and the worker by name.
    let o = run(&["status", "--coordinator", &url, "--ca", &ca, "--token-file", &s.arg("viewer.token")]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && job_state(&out, 1) == "done" && out.contains("node-1"), "{out}");
}

/// Mutual TLS with no tokens: a worker's certificate (CN node-1, OU worker) is its identity
/// and its role; a client without a certificate does not get through the handshake.
#[test]
fn mutual_tls_certificates_are_identities() {
    let s = Secrets::new();
    let (cert, key, ca) = (s.arg("pki/server.pem"), s.arg("pki/server.key"), s.ca());
    let (_coord, url) =
        coordinator(&["--tls-cert", &cert, "--tls-key", &key, "--tls-client-ca", &ca], "localhost");
    let (wcert, wkey) = (s.arg("pki/node-1.pem"), s.arg("pki/node-1.key"));
    let w = Proc::spawn(&[
        "worker",
        "--coordinator",
        &url,
        "--ca",
        &ca,
        "--tls-cert",
        &wcert,
        "--tls-key",
        &wkey,
        "--threads",
        "1",
    ]);
    w.wait_for("connected to", Duration::from_secs(30));
    let (acert, akey) = (s.arg("pki/root.pem"), s.arg("pki/root.key"));
    let out = s.path("mtls.png");
    let o = run(&[
        "submit",
        small_scene().to_str().unwrap(),
        "--coordinator",
        &url,
        "--ca",
        &ca,
        "--tls-cert",
        &acert,
        "--tls-key",
        &akey,
        "--size",
        SIZE,
        "--spp",
        SPP,
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "submit: {}", String::from_utf8_lossy(&o.stderr));
    // The worker's certificate gives the worker role only.
    let o = run(&["status", "--coordinator", &url, "--ca", &ca, "--tls-cert", &wcert, "--tls-key", &wkey]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("worker `node-1` may not read the status"), "{o:?}");
    // No certificate: refused, whatever token.
    let o = run(&["status", "--coordinator", &url, "--ca", &ca]);
    assert!(!o.status.success(), "{o:?}");
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

/// `https://` against a plain-text coordinator is an error, never a plain-text call.
#[test]
fn https_against_a_plain_text_coordinator_is_an_error() {
    let (_coord, url) = coordinator(&[], "127.0.0.1");
    let https = url.replace("http://", "https://");
    let o = run_with_timeout(&["status", "--coordinator", &https], Duration::from_secs(30));
    assert!(!o.status.success(), "answered over https://: {}", String::from_utf8_lossy(&o.stdout));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cannot reach coordinator at https://"), "{err}");
    // The same coordinator answers over http://.
    let o = run(&["status", "--coordinator", &url]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
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

/// `tessera certs` writes keys only the owner can read and never overwrites a file.
#[test]
fn certs_keys_are_private_and_never_overwritten() {
    use std::os::unix::fs::PermissionsExt;
    let s = Secrets::new();
    for key in ["pki/ca.key", "pki/server.key", "pki/node-1.key"] {
        let mode = std::fs::metadata(s.path(key)).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode & 0o077, 0, "{key} has mode {mode:o}");
    }
    let ca = std::fs::read(s.path("pki/ca.pem")).unwrap();
    let o = run(&["certs", "ca", "--dir", &s.arg("pki")]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("exists; remove it first"), "{o:?}");
    assert_eq!(std::fs::read(s.path("pki/ca.pem")).unwrap(), ca);
    let o = run(&["certs", "client", "--dir", &s.arg("pki"), "--name", "x", "--role", "boss"]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("expected admin, submitter, worker or viewer"),
        "{o:?}"
    );
}

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

/// The in-process harness serves TLS with mutual certificates too: a fake worker with a
/// worker certificate renders a job submitted with an admin certificate.
#[test]
fn the_harness_serves_mutual_tls() {
    use tessera_harness::{FakeWorker, Harness, Security, ServeStats};
    use tessera_proto::credentials::ServerTls;
    let s = Secrets::new();
    let server =
        ServerTls::read(&s.path("pki/server.pem"), &s.path("pki/server.key"), Some(&s.path("pki/ca.pem")))
            .unwrap();
    let ca = s.path("pki/ca.pem");
    let identity = |name: &str| {
        ClientTls::new()
            .ca_file(&ca)
            .unwrap()
            .identity_files(&s.path(&format!("pki/{name}.pem")), &s.path(&format!("pki/{name}.key")))
            .unwrap()
    };
    runtime().block_on(async {
        let security = Security {
            auth: tessera_coordinator::Auth::new(None, true),
            tls: Some(server),
            client_tls: identity("root"),
            host: Some("localhost".into()),
            ..Security::default()
        };
        let h = Harness::start_secured(tessera_coordinator::Timing::default(), security).await.unwrap();
        assert!(h.url.starts_with("https://localhost:"), "{}", h.url);
        let worker = EndpointConfig::new(&h.url).unwrap().tls(identity("node-1")).unwrap();
        let ch = tessera_harness::connect_with(&worker).await.unwrap();
        let w = FakeWorker::connect(&ch, "node-1", 2).await.unwrap();
        let task = tokio::spawn(async move {
            let _ = w.serve(Duration::ZERO, std::sync::Arc::new(ServeStats::new(false))).await;
        });
        let job = h.submit_small(16, 16, 2).await.unwrap();
        assert!(h.wait_over(job).await.unwrap().state == tessera_description::job::JobState::Done);
        // The worker's certificate may not submit.
        let settings = pb::RenderSettings { spp: 1, width: 8, height: 8, ..Default::default() };
        let e = tessera_harness::submit(&ch, "small.toml", tessera_harness::SMALL_SCENE, settings)
            .await
            .unwrap_err();
        assert!(e.to_string().contains("worker `node-1` may not submit"), "{e}");
        task.abort();
    });
}
