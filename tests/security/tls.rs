//! Farms over TLS: with tokens and with client certificates as identities, the in-process
//! harness too; `https://` never falls back to plain text; `tessera certs`' keys.

use std::time::Duration;

use tessera_proto::connect::EndpointConfig;
use tessera_proto::credentials::ClientTls;
use tessera_proto::v1 as pb;

use crate::common::*;
use crate::secrets::*;

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
