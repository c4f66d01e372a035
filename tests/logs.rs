//! `--log-format json`: every line a coordinator and a worker write on stderr is one JSON
//! object with a timestamp, a level, a target and the event's fields.

mod common;

use std::time::Duration;

use common::Proc;

/// Checks each line of `stderr` is a JSON object of the log format; returns them.
fn parse_lines(who: &str, stderr: &str) -> Vec<serde_json::Value> {
    stderr
        .lines()
        .map(|line| {
            let v: serde_json::Value = serde_json::from_str(line)
                .unwrap_or_else(|e| panic!("{who}: a line that is not JSON ({e}): {line:?}\n{stderr}"));
            let timestamp = v["timestamp"].as_str().unwrap_or_else(|| panic!("{who}: no timestamp: {line}"));
            // RFC 3339 with the date first, e.g. 2026-12-01T14:41:08.123456Z.
            assert!(timestamp.len() >= 20 && timestamp.as_bytes()[10] == b'T', "{who}: {timestamp}");
            let level = v["level"].as_str().unwrap_or_else(|| panic!("{who}: no level: {line}"));
            assert!(["TRACE", "DEBUG", "INFO", "WARN", "ERROR"].contains(&level), "{who}: {line}");
            assert!(v["target"].as_str().is_some_and(|t| t.starts_with("tessera")), "{who}: {line}");
            assert!(v["fields"]["message"].is_string(), "{who}: no message: {line}");
            v
        })
        .collect()
}

#[test]
fn json_logs_are_one_object_a_line_with_their_fields() {
    let coordinator = Proc::spawn(&["--log-format", "json", "coordinator", "--listen", "127.0.0.1:0"]);
    let line = coordinator.wait_for("coordinator listening on ", Duration::from_secs(30));
    let v: serde_json::Value = serde_json::from_str(&line).unwrap();
    let message = v["fields"]["message"].as_str().unwrap();
    let addr = message.rsplit("listening on ").next().unwrap();
    // The option is global: it may come after the command too.
    let worker = Proc::spawn(&[
        "worker",
        "--coordinator",
        &format!("http://{addr}"),
        "--threads",
        "1",
        "--name",
        "json-worker",
        "--log-format",
        "json",
    ]);
    worker.wait_for("connected to", Duration::from_secs(30));
    let joined = coordinator.wait_for("worker joined", Duration::from_secs(30));
    let joined: serde_json::Value = serde_json::from_str(&joined).unwrap();
    // The event's own fields travel as JSON fields, not inside the message.
    assert_eq!(joined["fields"]["name"], "json-worker", "{joined}");
    assert_eq!(joined["fields"]["threads"], 1, "{joined}");
    assert_eq!(joined["level"], "INFO", "{joined}");
    let worker_log = worker.stderr.lock().unwrap().clone();
    drop(worker);
    coordinator.wait_for("worker left", Duration::from_secs(30));
    let lines = parse_lines("coordinator", &coordinator.stderr.lock().unwrap());
    assert!(lines.len() >= 3, "{lines:?}");
    assert!(!parse_lines("worker", &worker_log).is_empty());
}

/// The text format stays the default: a line of it is not JSON, and has no colour codes
/// when stderr is not a terminal.
#[test]
fn text_logs_stay_the_default() {
    let coordinator = Proc::spawn(&["coordinator", "--listen", "127.0.0.1:0"]);
    let line = coordinator.wait_for("coordinator listening on ", Duration::from_secs(30));
    assert!(serde_json::from_str::<serde_json::Value>(&line).is_err(), "{line}");
    assert!(line.contains(" INFO ") && !line.contains('\u{1b}'), "{line:?}");
}

/// `render --log-format json` starts its local workers with it too: their lines are JSON.
#[test]
fn a_render_passes_the_json_format_to_its_workers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("small.png");
    let scene = common::small_scene();
    let args = ["--log-format", "json", "render", scene.to_str().unwrap(), "-o", out.to_str().unwrap()];
    let run = common::run(&[&args[..], &["--workers", "1", "--size", "16x16", "--spp", "2"]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stderr = String::from_utf8_lossy(&run.stderr);
    // The render's own summary ("wrote …") is output, not a log line.
    let logs: String =
        stderr.lines().filter(|l| !l.starts_with("wrote ")).map(|l| format!("{l}\n")).collect();
    let lines = parse_lines("render", &logs);
    assert!(lines.iter().any(|v| v["target"] == "tessera_worker::client"), "no worker line: {stderr}");
}
