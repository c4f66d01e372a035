//! Helpers for end-to-end tests: real `tessera` processes on loopback.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub mod builds;

/// Writes a token or key file readable by its owner only (tessera refuses others).
pub fn write_secret(path: &Path, text: &str) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::write(path, text).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600)).unwrap();
}

/// The `tessera` binary under test.
pub fn tessera() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_tessera"));
    cmd.env("RUST_LOG", "info").stdin(Stdio::null());
    cmd
}

/// Runs `tessera args…` to completion, with a time limit so that a hang fails the test.
pub fn run(args: &[&str]) -> Output {
    run_with_timeout(args, Duration::from_secs(120))
}

/// Runs `tessera args…`; panics if it takes longer than `limit`.
pub fn run_with_timeout(args: &[&str], limit: Duration) -> Output {
    let mut child = tessera().args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let start = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!("tessera {args:?} hung for {limit:?}; stderr:\n{}", String::from_utf8_lossy(&out.stderr));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The repository's root (where `scenes/` lives).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The small end-to-end test scene.
pub fn small_scene() -> PathBuf {
    root().join("tests/scenes/small.toml")
}

/// A process killed (and reaped) when dropped, with its stderr collected.
pub struct Proc {
    pub child: Child,
    pub stderr: Arc<Mutex<String>>,
    /// The thread copying stderr; `wait` lets it drain the pipe, since the process can exit
    /// before its last line has been read (a test that read stderr right after the exit once
    /// saw it empty).
    reader: Option<std::thread::JoinHandle<()>>,
}

impl Proc {
    pub fn spawn(args: &[&str]) -> Proc {
        Self::spawn_with_env(args, &[])
    }

    pub fn spawn_with_env(args: &[&str], env: &[(&str, &str)]) -> Proc {
        Self::spawn_command(tessera().args(args).envs(env.iter().copied()))
    }

    /// Spawns a prepared command (e.g. `ip netns exec … tessera …`).
    pub fn spawn_command(cmd: &mut Command) -> Proc {
        let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        let stderr = Arc::new(Mutex::new(String::new()));
        let pipe = child.stderr.take().unwrap();
        let sink = stderr.clone();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(pipe).lines().map_while(Result::ok) {
                let mut s = sink.lock().unwrap_or_else(|e| e.into_inner());
                s.push_str(&line);
                s.push('\n');
            }
        });
        Proc { child, stderr, reader: Some(reader) }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Waits until stderr contains `needle`; returns the line that holds it.
    pub fn wait_for(&self, needle: &str, limit: Duration) -> String {
        let start = Instant::now();
        loop {
            if let Some(line) = self.stderr.lock().unwrap().lines().find(|l| l.contains(needle)) {
                return line.to_string();
            }
            if start.elapsed() > limit {
                panic!("no {needle:?} within {limit:?}; stderr:\n{}", self.stderr.lock().unwrap());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Sends a signal (by number) to the process.
    pub fn signal(&self, sig: i32) {
        let status =
            Command::new("kill").arg(format!("-{sig}")).arg(self.pid().to_string()).status().unwrap();
        assert!(status.success());
    }

    pub fn wait(&mut self, limit: Duration) -> std::process::ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                self.drain_stderr(Duration::from_secs(10));
                return s;
            }
            if start.elapsed() > limit {
                panic!("process did not exit within {limit:?}; stderr:\n{}", self.stderr.lock().unwrap());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Proc {
    /// Lets the stderr thread reach the pipe's end. Bounded: a child the process started
    /// may still hold the pipe open (`ip netns exec`, a shell), and then what arrived is
    /// what the test gets.
    fn drain_stderr(&mut self, limit: Duration) {
        let start = Instant::now();
        while self.reader.as_ref().is_some_and(|r| !r.is_finished()) && start.elapsed() < limit {
            std::thread::sleep(Duration::from_millis(5));
        }
        if self.reader.as_ref().is_some_and(|r| r.is_finished()) {
            let _ = self.reader.take().map(|r| r.join());
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A standalone coordinator on a free loopback port.
pub struct Coordinator {
    pub proc: Proc,
    pub url: String,
}

impl Coordinator {
    pub fn start(extra: &[&str]) -> Coordinator {
        Self::start_at("127.0.0.1:0", extra, &[])
    }

    /// A coordinator listening on `addr`, with extra arguments and environment.
    pub fn start_at(addr: &str, extra: &[&str], env: &[(&str, &str)]) -> Coordinator {
        let mut args = vec!["coordinator", "--listen", addr];
        args.extend_from_slice(extra);
        let proc = Proc::spawn_with_env(&args, env);
        let line = proc.wait_for("coordinator listening on ", Duration::from_secs(30));
        let addr = line.rsplit("listening on ").next().unwrap().trim().to_string();
        Coordinator { proc, url: format!("http://{addr}") }
    }

    /// The job's status over gRPC; `None` while the coordinator does not answer.
    pub fn job(&self, id: u64) -> Option<JobStatus> {
        job_status(&self.url, id)
    }

    /// Polls the job until `done` holds of it; panics after `limit`.
    pub fn wait_until(
        &self,
        id: u64,
        limit: Duration,
        what: &str,
        done: impl Fn(&JobStatus) -> bool,
    ) -> JobStatus {
        let start = Instant::now();
        loop {
            if let Some(s) = self.job(id) {
                if done(&s) {
                    return s;
                }
                assert!(start.elapsed() < limit, "{what}: not within {limit:?}; last status {s:?}");
            }
            assert!(start.elapsed() < limit, "{what}: coordinator not answering within {limit:?}");
            std::thread::sleep(Duration::from_millis(25));
        }
    }

    /// A worker connected to this coordinator.
    pub fn worker(&self, threads: u32) -> Proc {
        let w = Proc::spawn(&["worker", "--coordinator", &self.url, "--threads", &threads.to_string()]);
        w.wait_for("connected to", Duration::from_secs(30));
        w
    }

    /// `tessera status` output.
    pub fn status(&self) -> String {
        let out = run(&["status", "--coordinator", &self.url]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    }
}

/// The bytes of a file.
pub fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

/// Renders the small scene locally with `workers` workers into `out`.
pub fn render_local(scene: &Path, out: &Path, workers: u32, extra: &[&str]) {
    let mut args = vec!["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--workers"];
    let w = workers.to_string();
    args.push(&w);
    args.extend_from_slice(extra);
    let o = run(&args);
    assert!(o.status.success(), "render failed: {}", String::from_utf8_lossy(&o.stderr));
}

/// Percent done of job `id` in `tessera status` output (0 when not listed yet).
pub fn job_percent(status: &str, id: u64) -> f64 {
    status
        .lines()
        .find(|l| l.split_whitespace().next() == Some(&id.to_string()))
        .and_then(|l| l.split_whitespace().find(|w| w.ends_with('%')))
        .map_or(0.0, |w| w.trim_end_matches('%').parse().unwrap())
}

/// The state word of job `id` in `tessera status` output ("" when not listed).
pub fn job_state(status: &str, id: u64) -> String {
    status
        .lines()
        .find(|l| l.split_whitespace().next() == Some(&id.to_string()))
        .and_then(|l| l.split_whitespace().nth(1))
        .unwrap_or("")
        .to_string()
}

/// A job's figures, read over gRPC.
#[derive(Debug, Clone)]
pub struct JobStatus {
    pub state: String,
    pub pass: u32,
    pub samples_done: u64,
    pub samples_total: u64,
    pub samples_per_second: f64,
}

impl JobStatus {
    pub fn fraction(&self) -> f64 {
        self.samples_done as f64 / self.samples_total.max(1) as f64
    }
}

/// Job `id`'s status at `url`; `None` if the coordinator does not answer.
pub fn job_status(url: &str, id: u64) -> Option<JobStatus> {
    use tessera_proto::v1 as pb;
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    rt.block_on(async {
        let endpoint = tonic::transport::Endpoint::from_shared(url.to_string())
            .ok()?
            .connect_timeout(Duration::from_secs(2));
        let channel = endpoint.connect().await.ok()?;
        let mut client = pb::coordinator_client::CoordinatorClient::new(channel);
        let r = tokio::time::timeout(Duration::from_secs(5), client.status(pb::StatusRequest { job_id: id }))
            .await
            .ok()?
            .ok()?
            .into_inner();
        let j = r.jobs.into_iter().next()?;
        Some(JobStatus {
            state: tessera_proto::convert::state_name(j.state).to_string(),
            pass: j.pass,
            samples_done: j.samples_done,
            samples_total: j.samples_total,
            samples_per_second: j.samples_per_second,
        })
    })
}

/// A loopback address with a port free a moment ago, for a coordinator that restarts on
/// the same address.
pub fn free_loopback_addr() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().to_string()
}

/// The target directory this test binary was built in (`target/` or `$CARGO_TARGET_DIR`).
pub fn target_dir() -> PathBuf {
    // .../target/debug/tessera
    PathBuf::from(env!("CARGO_BIN_EXE_tessera")).parent().and_then(Path::parent).unwrap().to_path_buf()
}

/// A Python venv `name` with `requirements` (a file under the repository) installed by
/// `scripts/python-venv.sh`, under the target directory; its `bin/python`. `None`, after
/// printing `SKIPPED: <why>`, when Python, venv or the package index cannot be had.
pub fn python_venv(name: &str, requirements: &str) -> Option<PathBuf> {
    let out = Command::new("bash")
        .arg(root().join("scripts/python-venv.sh"))
        .arg(name)
        .arg(root().join(requirements))
        .env("CARGO_TARGET_DIR", target_dir())
        .stdin(Stdio::null())
        .output();
    match out {
        Ok(o) if o.status.success() => {
            let venv = String::from_utf8_lossy(&o.stdout).trim().lines().last().unwrap_or("").to_string();
            Some(PathBuf::from(venv).join("bin/python"))
        }
        Ok(o) => {
            let why = String::from_utf8_lossy(&o.stderr);
            eprintln!(
                "SKIPPED: no Python venv {name}: {}",
                why.trim().lines().last().unwrap_or("(no message)")
            );
            None
        }
        Err(e) => {
            eprintln!("SKIPPED: cannot run bash for scripts/python-venv.sh: {e}");
            None
        }
    }
}
