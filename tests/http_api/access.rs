//! Who may do what: roles and owners as over gRPC, the session cookie, HTTPS with the gRPC
//! certificate, and no unauthenticated web port beyond loopback.

use std::path::Path;
use std::time::Duration;

use reqwest::blocking::Client;

use crate::common::{read, run, write_secret, Proc};
use crate::web::{assert_error, client, job, json, post, small_form, submit, submit_ok, Web};

const ADMIN: &str = "admin-token-0123456789";
const ALICE: &str = "alice-token-0123456789";
const BOB: &str = "bob-token-0123456789ab";
const VIEWER: &str = "viewer-token-012345678";

fn write_tokens(dir: &Path) -> String {
    let path = dir.join("tokens");
    write_secret(
        &path,
        &format!("admin root {ADMIN}\nsubmitter alice {ALICE}\nsubmitter bob {BOB}\nviewer wall {VIEWER}\n"),
    );
    path.to_str().unwrap().to_string()
}

#[test]
fn roles_and_owners_are_checked_as_over_grpc() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = write_tokens(dir.path());
    let web = Web::start(&["--tokens", &tokens]);
    // No token, a bad one, a malformed header.
    assert_error(client().get(web.url("/api/jobs")).send().unwrap(), 401, "no token");
    assert_error(
        client().get(web.url("/api/jobs")).bearer_auth("nope-nope-nope-nope").send().unwrap(),
        401,
        "unknown token",
    );
    assert_error(
        client().get(web.url("/api/jobs")).header("authorization", ALICE).send().unwrap(),
        401,
        "Bearer TOKEN",
    );
    assert_error(submit(&web, None, small_form(8, 8, 1)), 401, "no token");
    // A viewer reads but may not submit or control.
    assert_error(submit(&web, Some(VIEWER), small_form(8, 8, 1)), 403, "may not submit");
    let alice_job = submit_ok(&web, Some(ALICE), small_form(8, 8, 1));
    assert_eq!(job(&web, Some(VIEWER), alice_job)["owner"], "alice");
    for action in ["pause", "resume", "cancel"] {
        assert_error(
            post(&web, Some(VIEWER), &format!("/api/jobs/{alice_job}/{action}"), None),
            403,
            "may not",
        );
    }
    assert_error(
        post(&web, Some(VIEWER), &format!("/api/jobs/{alice_job}/priority"), Some(r#"{"priority":0}"#)),
        403,
        "may not change priorities",
    );
    // Another submitter neither sees nor controls alice's job.
    assert_error(
        client().get(web.url(&format!("/api/jobs/{alice_job}"))).bearer_auth(BOB).send().unwrap(),
        403,
        "another submitter",
    );
    assert_error(
        post(&web, Some(BOB), &format!("/api/jobs/{alice_job}/cancel"), None),
        403,
        "another submitter",
    );
    assert_error(
        client().get(web.url(&format!("/api/jobs/{alice_job}/image.png"))).bearer_auth(BOB).send().unwrap(),
        403,
        "another submitter",
    );
    let bobs = json(client().get(web.url("/api/jobs")).bearer_auth(BOB).send().unwrap()).1;
    assert_eq!(bobs["jobs"].as_array().unwrap().len(), 0, "{bobs}");
    // A submitter's priority is capped by --max-priority (0), as in Submit.
    assert_error(
        post(&web, Some(ALICE), &format!("/api/jobs/{alice_job}/priority"), Some(r#"{"priority":5}"#)),
        403,
        "--max-priority",
    );
    assert_eq!(
        post(&web, Some(ADMIN), &format!("/api/jobs/{alice_job}/priority"), Some(r#"{"priority":5}"#))
            .status(),
        204
    );
    // The live socket: no token, no upgrade.
    let url = web.url(&format!("/api/jobs/{alice_job}/live")).replace("http://", "ws://");
    match tungstenite::connect(url.as_str()) {
        Err(tungstenite::Error::Http(r)) => assert_eq!(r.status().as_u16(), 401),
        other => panic!("expected 401, got {:?}", other.map(|(_, r)| r.status())),
    }
    // ?token= is not a way in.
    match tungstenite::connect(format!("{url}?token={ALICE}").as_str()) {
        Err(tungstenite::Error::Http(r)) => assert_eq!(r.status().as_u16(), 401),
        other => panic!("expected 401, got {:?}", other.map(|(_, r)| r.status())),
    }

    // The browser's way: a login sets the session cookie.
    let login = client()
        .post(web.url("/api/login"))
        .header("content-type", "application/json")
        .body(format!(r#"{{"token":"{ALICE}"}}"#))
        .send()
        .unwrap();
    assert_eq!(login.status(), 204);
    let cookie = login.headers()["set-cookie"].to_str().unwrap().to_string();
    for attribute in ["tessera_session=", "HttpOnly", "SameSite=Strict", "Max-Age=43200", "Path=/"] {
        assert!(cookie.contains(attribute), "{cookie}");
    }
    assert!(!cookie.contains("Secure"), "plain HTTP: no Secure flag: {cookie}");
    let session = cookie.split(';').next().unwrap().to_string();
    let who = json(client().get(web.url("/api/whoami")).header("cookie", &session).send().unwrap());
    assert_eq!(who, (200, serde_json::json!({"name": "alice", "role": "submitter"})));
    let (status, listing) =
        json(client().get(web.url("/api/jobs")).header("cookie", &session).send().unwrap());
    assert_eq!(status, 200);
    assert_eq!(listing["jobs"][0]["id"], alice_job);
    let r = client().post(web.url("/api/logout")).header("cookie", &session).send().unwrap();
    assert_eq!(r.status(), 204);
    assert_error(
        client().get(web.url("/api/whoami")).header("cookie", &session).send().unwrap(),
        401,
        "log in again",
    );
    assert_error(
        client()
            .post(web.url("/api/login"))
            .header("content-type", "application/json")
            .body(r#"{"token":"wrong-wrong-wrong-wrong"}"#)
            .send()
            .unwrap(),
        401,
        "unknown token",
    );
    assert_error(
        client()
            .post(web.url("/api/login"))
            .header("content-type", "application/json")
            .body("{token")
            .send()
            .unwrap(),
        400,
        "bad JSON",
    );
}

#[test]
fn https_serves_with_the_grpc_certificate_and_secure_cookies() {
    let dir = tempfile::tempdir().unwrap();
    let pki = dir.path().to_str().unwrap();
    for args in
        [vec!["certs", "ca", "--dir", pki], vec!["certs", "server", "--dir", pki, "--host", "127.0.0.1"]]
    {
        let o = run(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let tokens = write_tokens(dir.path());
    let (cert, key) = (dir.path().join("server.pem"), dir.path().join("server.key"));
    let web = Web::start(&[
        "--tls-cert",
        cert.to_str().unwrap(),
        "--tls-key",
        key.to_str().unwrap(),
        "--tokens",
        &tokens,
    ]);
    assert!(web.base.starts_with("https://"), "{}", web.base);
    let ca = reqwest::Certificate::from_pem(&read(&dir.path().join("ca.pem"))).unwrap();
    let c = Client::builder().add_root_certificate(ca).tls_built_in_root_certs(false).build().unwrap();
    assert_eq!(c.get(web.url("/healthz")).send().unwrap().text().unwrap(), "ok");
    let login = c
        .post(web.url("/api/login"))
        .header("content-type", "application/json")
        .body(format!(r#"{{"token":"{ADMIN}"}}"#))
        .send()
        .unwrap();
    assert_eq!(login.status(), 204);
    assert!(login.headers()["set-cookie"].to_str().unwrap().contains("; Secure"));
    // Plain HTTP to the HTTPS port is not served.
    assert!(client().get(web.url("/healthz").replace("https://", "http://")).send().is_err());
}

#[test]
fn a_web_port_beyond_loopback_without_authentication_is_refused() {
    let mut p = Proc::spawn(&["coordinator", "--listen", "127.0.0.1:0", "--http", "0.0.0.0:0"]);
    let status = p.wait(Duration::from_secs(30));
    assert!(!status.success());
    let err = p.stderr.lock().unwrap().clone();
    assert!(err.contains("--http: refusing to listen on 0.0.0.0:0 with no authentication"), "{err}");
}
