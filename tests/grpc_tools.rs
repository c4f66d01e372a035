//! A third-party gRPC client against a real coordinator: Python's grpcio with the health
//! and reflection packages (tests/tools/grpc_reflect.py) checks health without a token,
//! lists the services through reflection, and calls `Status` from reflected descriptors
//! alone, with a bearer token. Skips, saying why, where Python or PyPI cannot be had.

mod common;

use std::process::Command;
use std::time::Duration;

use common::{python_venv, root, run, write_secret, Proc};

const ADMIN: &str = "a-very-secret-admin-token-0123";
const WORKER: &str = "a-very-secret-worker-token-456";

/// The address a `... listening on ADDR` line names.
fn address(line: &str) -> String {
    line.rsplit("listening on ").next().unwrap().split_whitespace().next().unwrap().to_string()
}

fn script(python: &std::path::Path, args: &[&str]) -> String {
    let out =
        Command::new(python).arg(root().join("tests/tools/grpc_reflect.py")).args(args).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "grpc_reflect.py {args:?} failed\nstdout:\n{stdout}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

#[test]
fn grpcio_lists_and_calls_the_coordinator_through_health_and_reflection() {
    let Some(python) = python_venv("grpc", "tests/tools/grpc-requirements.txt") else { return };
    let dir = tempfile::tempdir().unwrap();
    let tokens = dir.path().join("tokens");
    write_secret(&tokens, &format!("admin root {ADMIN}\nworker node-1 {WORKER}\n"));
    let (admin, worker) = (dir.path().join("admin.token"), dir.path().join("worker.token"));
    write_secret(&admin, ADMIN);
    write_secret(&worker, WORKER);

    let mut coord = Proc::spawn(&[
        "coordinator",
        "--listen",
        "127.0.0.1:0",
        "--health-listen",
        "127.0.0.1:0",
        "--tokens",
        tokens.to_str().unwrap(),
    ]);
    let grpc = address(&coord.wait_for("coordinator listening on ", Duration::from_secs(30)));
    let health = address(&coord.wait_for("health service listening on ", Duration::from_secs(30)));
    let url = format!("http://{grpc}");
    let _worker = Proc::spawn(&[
        "worker",
        "--coordinator",
        &url,
        "--token-file",
        worker.to_str().unwrap(),
        "--threads",
        "2",
    ]);
    let scene = root().join("tests/scenes/small.toml");
    let o = run(&[
        "submit",
        scene.to_str().unwrap(),
        "--coordinator",
        &url,
        "--token-file",
        admin.to_str().unwrap(),
        "--size",
        "24x16",
        "--spp",
        "4",
        "--wait",
    ]);
    assert!(o.status.success(), "submit: {}", String::from_utf8_lossy(&o.stderr));

    let out = script(&python, &[&grpc, admin.to_str().unwrap()]);
    eprintln!("{out}");
    for want in [
        "health (server): SERVING",
        "health tessera.v1.Coordinator: SERVING",
        "health tessera.v1.Workers: SERVING",
        "service grpc.health.v1.Health",
        "service grpc.reflection.v1.ServerReflection",
        "service grpc.reflection.v1alpha.ServerReflection",
        "service tessera.v1.Coordinator",
        "service tessera.v1.Workers",
        "status without token: UNAUTHENTICATED",
        "status: 1 jobs, 1 workers",
    ] {
        assert!(out.lines().any(|l| l == want), "no line {want:?} in:\n{out}");
    }
    let job = out.lines().find(|l| l.starts_with("job ")).unwrap();
    for want in ["job_id=1", "state=JOB_STATE_DONE", "width=24", "height=16", "spp=4", "samples_done=1536"] {
        assert!(job.split_whitespace().any(|w| w == want), "no {want} in {job:?}");
    }
    let worker_line = out.lines().find(|l| l.starts_with("worker ")).unwrap();
    assert!(worker_line.contains("threads=2"), "{worker_line}");

    // The plain-text health listener (Kubernetes' grpc probe) answers health, and only it.
    let out = script(&python, &["--health-only", &health]);
    assert!(out.contains("health tessera.v1.Coordinator: SERVING"), "{out}");
    assert!(out.contains("reflection: UNIMPLEMENTED"), "{out}");

    // SIGTERM with a worker still connected: its stream ends, so the graceful shutdown does
    // not wait for it.
    coord.signal(15);
    assert!(coord.wait(Duration::from_secs(20)).success(), "{}", coord.stderr.lock().unwrap());
}
