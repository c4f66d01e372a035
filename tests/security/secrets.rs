//! A farm's certificates and tokens in a temporary directory, and the coordinators and
//! clients that use them.

use std::path::{Path, PathBuf};
use std::time::Duration;

use tessera_proto::connect::{ConnectError, EndpointConfig};
use tessera_proto::credentials::{ClientTls, Token};
use tessera_proto::v1 as pb;
use tonic::Code;

use crate::common::*;

pub(crate) const ADMIN: &str = "admin-token-0123456789abcdef";
pub(crate) const ALICE: &str = "alice-token-0123456789abcdef";
pub(crate) const BOB: &str = "bob-token-0123456789abcdef01";
pub(crate) const WORKER: &str = "worker-token-0123456789abcdef";
pub(crate) const VIEWER: &str = "viewer-token-0123456789abcdef";

/// The tiny render every test uses.
pub(crate) const SIZE: &str = "16x12";
pub(crate) const SPP: &str = "2";

/// `tessera certs …`, which must succeed.
pub(crate) fn certs(args: &[&str]) {
    let mut all = vec!["certs"];
    all.extend_from_slice(args);
    let o = run(&all);
    assert!(o.status.success(), "tessera {all:?}: {}", String::from_utf8_lossy(&o.stderr));
}

/// A farm's certificates and tokens in a temporary directory.
pub(crate) struct Secrets {
    dir: tempfile::TempDir,
}

impl Secrets {
    pub(crate) fn new() -> Secrets {
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

    pub(crate) fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    pub(crate) fn arg(&self, name: &str) -> String {
        self.path(name).to_str().unwrap().to_string()
    }

    pub(crate) fn ca(&self) -> String {
        self.arg("pki/ca.pem")
    }
}

/// A coordinator process, with the URL from its "listening on" line.
pub(crate) fn coordinator(args: &[&str], host: &str) -> (Proc, String) {
    let mut all = vec!["coordinator", "--listen", "127.0.0.1:0"];
    all.extend_from_slice(args);
    let proc = Proc::spawn(&all);
    let line = proc.wait_for("coordinator listening on ", Duration::from_secs(30));
    let addr = line.rsplit("listening on ").next().unwrap().split_whitespace().next().unwrap().to_string();
    let port = addr.rsplit(':').next().unwrap();
    let scheme = if line.contains("(TLS)") { "https" } else { "http" };
    (proc, format!("{scheme}://{host}:{port}"))
}

pub(crate) fn tls_coordinator(s: &Secrets, data: &Path, extra: &[&str]) -> (Proc, String) {
    let (cert, key, tokens) = (s.arg("pki/server.pem"), s.arg("pki/server.key"), s.arg("tokens"));
    let mut args =
        vec!["--tls-cert", &cert, "--tls-key", &key, "--tokens", &tokens, "--data", data.to_str().unwrap()];
    args.extend_from_slice(extra);
    coordinator(&args, "localhost")
}

pub(crate) fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

/// A client of `url` trusting `ca`, sending `token`.
pub(crate) async fn client(
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

pub(crate) fn submit_request(priority: i32) -> pb::SubmitRequest {
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

/// The code and message of a call that must have been refused.
pub(crate) fn status_code<T: std::fmt::Debug>(r: Result<T, tonic::Status>) -> (Code, String) {
    let s = r.expect_err("the call was accepted");
    (s.code(), s.message().to_string())
}
