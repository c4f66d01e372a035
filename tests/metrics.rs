//! `/metrics` as an operator meets it: a real coordinator with `--http` and tokens, a real
//! worker rendering a small job, the text checked by `promtool check metrics`, and a real
//! Prometheus scraping it every second with a bearer token, queried over its HTTP API.
//! promtool and Prometheus come from Debian's `prometheus` package, unpacked by
//! `scripts/prometheus.sh`; without them those parts print `SKIPPED: <why>`.

mod common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{free_loopback_addr, small_scene, tessera, write_secret, Proc};

const ADMIN: &str = "admin-token-0123456789abcdef";
const WORKER: &str = "worker-token-0123456789abcdef";
const VIEWER: &str = "viewer-token-0123456789abcdef";

/// One HTTP/1.1 GET; returns the status code and the body (chunked bodies decoded).
fn get(addr: &str, path: &str, token: Option<&str>) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connecting to {addr}: {e}"));
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let auth = token.map(|t| format!("Authorization: Bearer {t}\r\n")).unwrap_or_default();
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\n{auth}Connection: close\r\n\r\n").unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let raw = String::from_utf8(raw).expect("a UTF-8 response");
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or_else(|| panic!("no header end: {raw:?}"));
    let code = head.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap_or_else(|| panic!("{head}"));
    if !head.to_ascii_lowercase().contains("transfer-encoding: chunked") {
        return (code, body.to_string());
    }
    let (mut rest, mut out) = (body, String::new());
    loop {
        let (size, after) = rest.split_once("\r\n").expect("a chunk size line");
        let size = usize::from_str_radix(size.trim(), 16).expect("a hex chunk size");
        if size == 0 {
            return (code, out);
        }
        out.push_str(&after[..size]);
        rest = &after[size + 2..];
    }
}

/// Where promtool and prometheus are, or why not.
fn tools() -> Result<PathBuf, String> {
    let out = Command::new(common::root().join("scripts/prometheus.sh"))
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run scripts/prometheus.sh: {e}"))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
    }
    Ok(PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()))
}

/// The value of the sample `name` (with its labels as written) in `text`.
fn sample(text: &str, name: &str) -> Option<f64> {
    text.lines().find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
}

#[test]
fn prometheus_scrapes_the_coordinator_with_a_token() {
    let dir = tempfile::tempdir().unwrap();
    let tokens = dir.path().join("tokens");
    write_secret(&tokens, &format!("admin root {ADMIN}\nworker node-1 {WORKER}\nviewer wall {VIEWER}\n"));
    let coordinator = Proc::spawn(&[
        "coordinator",
        "--listen",
        "127.0.0.1:0",
        "--http",
        "127.0.0.1:0",
        "--tokens",
        tokens.to_str().unwrap(),
        "--data",
        dir.path().join("data").to_str().unwrap(),
    ]);
    let line = coordinator.wait_for("coordinator listening on ", Duration::from_secs(30));
    let url = format!("http://{}", line.rsplit("listening on ").next().unwrap().trim());
    let line = coordinator.wait_for("web dashboard on http://", Duration::from_secs(30));
    let http = line.rsplit("http://").next().unwrap().trim().to_string();
    let token = tessera_proto::credentials::TOKEN_ENV;
    let worker =
        Proc::spawn_with_env(&["worker", "--coordinator", &url, "--threads", "1"], &[(token, WORKER)]);
    worker.wait_for("connected to", Duration::from_secs(30));
    let image = dir.path().join("small.png");
    let (w, h, spp) = (24u64, 16u64, 4u64);
    let out = tessera()
        .args(["submit", "--coordinator", &url, "--spp", "4", "--size", "24x16", "-o"])
        .arg(&image)
        .arg(small_scene())
        .env(token, ADMIN)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    // Any role's token reads the metrics; no token, or a wrong one, does not.
    let deadline = Instant::now() + Duration::from_secs(30);
    let (code, text) = loop {
        let (code, text) = get(&http, "/metrics", Some(VIEWER));
        // The job's last checkpoint is written on the checkpointer's next tick.
        let written = sample(&text, "tessera_checkpoint_write_seconds_count").is_some_and(|n| n >= 1.0);
        let done = sample(&text, "tessera_jobs{state=\"done\"}") == Some(1.0);
        if code != 200 || (done && written) || Instant::now() > deadline {
            break (code, text);
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(code, 200, "{text}");
    assert_eq!(sample(&text, "tessera_jobs{state=\"done\"}"), Some(1.0), "{text}");
    assert_eq!(sample(&text, "tessera_samples_merged_total"), Some((w * h * spp) as f64), "{text}");
    assert_eq!(sample(&text, "tessera_samples_queued"), Some(0.0), "{text}");
    assert_eq!(sample(&text, "tessera_workers{state=\"idle\"}"), Some(1.0), "{text}");
    assert!(sample(&text, "tessera_merge_seconds_count").is_some_and(|n| n >= 1.0), "{text}");
    assert!(sample(&text, "tessera_checkpoint_write_seconds_count").is_some_and(|n| n >= 1.0), "{text}");
    assert_eq!(sample(&text, "tessera_checkpoint_failures_total"), Some(0.0), "{text}");
    // The one worker got the job's scene once, whole (it preloaded nothing).
    assert_eq!(sample(&text, "tessera_scenes_sent_total{how=\"whole\"}"), Some(1.0), "{text}");
    assert_eq!(sample(&text, "tessera_scenes_sent_total{how=\"by_hash\"}"), Some(0.0), "{text}");
    assert!(sample(&text, "tessera_scene_bytes_sent_total").is_some_and(|b| b > 100.0), "{text}");
    for bad in [None, Some("not-a-token-of-this-farm-at-all")] {
        let (code, body) = get(&http, "/metrics", bad);
        assert_eq!(code, 401, "{bad:?}: {body}");
        assert!(body.contains("\"error\""), "{body}");
    }
    eprintln!("scraped:\n{text}");

    let bin = match tools() {
        Ok(bin) => bin,
        Err(why) => {
            eprintln!("SKIPPED: promtool and prometheus: {why}");
            return;
        }
    };
    // promtool reads the exposition from stdin: format errors fail, lint problems too.
    let mut check = Command::new(bin.join("promtool"))
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    check.stdin.take().unwrap().write_all(text.as_bytes()).unwrap();
    let checked = check.wait_with_output().unwrap();
    assert!(
        checked.status.success(),
        "promtool check metrics: {}{}",
        String::from_utf8_lossy(&checked.stdout),
        String::from_utf8_lossy(&checked.stderr)
    );

    // A real Prometheus scraping every second with the viewer's token.
    let credentials = dir.path().join("scrape.token");
    write_secret(&credentials, VIEWER);
    let config = dir.path().join("prometheus.yml");
    std::fs::write(
        &config,
        format!(
            "global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\nscrape_configs:\n  - job_name: tessera\n    \
             authorization:\n      type: Bearer\n      credentials_file: {}\n    static_configs:\n      - targets: ['{http}']\n",
            credentials.display()
        ),
    )
    .unwrap();
    let web = free_loopback_addr();
    let mut prometheus = Proc::spawn_command(
        Command::new(bin.join("prometheus"))
            .arg(format!("--config.file={}", config.display()))
            .arg(format!("--storage.tsdb.path={}", dir.path().join("tsdb").display()))
            .arg(format!("--web.listen-address={web}"))
            .stdin(Stdio::null()),
    );
    let deadline = Instant::now() + Duration::from_secs(90);
    let result = loop {
        assert!(
            prometheus.child.try_wait().unwrap().is_none(),
            "prometheus exited:\n{}",
            prometheus.stderr.lock().unwrap()
        );
        // Up once its port answers.
        if TcpStream::connect(&web).is_ok() {
            let (code, body) = get(&web, "/api/v1/query?query=tessera_jobs", None);
            if code == 200 && body.contains("\"state\":\"done\"") {
                break body;
            }
        }
        assert!(
            Instant::now() < deadline,
            "Prometheus did not show tessera_jobs within 90 s; its log:\n{}",
            prometheus.stderr.lock().unwrap()
        );
        std::thread::sleep(Duration::from_millis(250));
    };
    let v: serde_json::Value = serde_json::from_str(&result).unwrap();
    let series = v["data"]["result"].as_array().unwrap();
    let done = series.iter().find(|s| s["metric"]["state"] == "done").unwrap();
    assert_eq!(done["value"][1], "1", "{result}");
    assert_eq!(done["metric"]["job"], "tessera", "{result}");
    assert_eq!(series.len(), 6, "every state is a series: {result}");
    // The scrape's health, as Prometheus saw it, and the autoscaler's figure.
    let (_, up) = get(&web, "/api/v1/query?query=up", None);
    assert!(up.contains("\"value\":[") && up.contains(",\"1\"]"), "{up}");
    let (_, queued) = get(&web, "/api/v1/query?query=tessera_samples_queued", None);
    assert!(queued.contains(",\"0\"]"), "{queued}");
    prometheus.signal(15);
    prometheus.wait(Duration::from_secs(30));
}
