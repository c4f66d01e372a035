//! Helpers for the tests that compare other builds of `tessera` with this run's
//! (`simd_levels.rs`, `other_targets.rs`): a nested cargo, the scenes they render, and the
//! coordinator's metrics that say whether every audit agreed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use super::{read, render_local, root, run_with_timeout, Proc};

/// `cargo` for a build inside a test, on this repository's manifest. What cargo set for
/// this test process (the package's name, manifest, out dir) is not the nested cargo's
/// business, and build scripts that watch such variables (ring's) would run again and
/// take everything above them along.
pub fn nested_cargo(args: &[&str]) -> Command {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(args).arg("--manifest-path").arg(root().join("Cargo.toml"));
    if this_profile_is_release() {
        cmd.arg("--release");
    }
    without_cargos_env(&mut cmd);
    cmd
}

/// Takes out of `cmd`'s environment what cargo set for this test process, for a command
/// that runs cargo itself (see `nested_cargo`), and gives it stdin from nowhere.
pub fn without_cargos_env(cmd: &mut Command) {
    for (key, _) in std::env::vars_os() {
        let k = key.to_string_lossy();
        let set_by_cargo = ["CARGO_PKG_", "CARGO_MANIFEST_", "CARGO_CFG_", "CARGO_BIN_", "CARGO_CRATE_"]
            .iter()
            .any(|p| k.starts_with(p))
            || ["CARGO_PRIMARY_PACKAGE", "CARGO_TARGET_TMPDIR", "OUT_DIR"].contains(&k.as_ref());
        if set_by_cargo {
            cmd.env_remove(&key);
        }
    }
    cmd.stdin(Stdio::null());
}

/// Runs `cmd` to completion, its output captured; panics, with what it printed, if it
/// takes longer than `limit` (a stuck emulator or a network that drops packets must fail
/// the test, not hang the suite).
pub fn output_within(cmd: &mut Command, limit: Duration) -> Output {
    let mut child =
        cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    // Drained on threads, so that a chatty child does not block on a full pipe.
    let drain = |mut r: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    };
    let out = drain(Box::new(child.stdout.take().unwrap()));
    let err = drain(Box::new(child.stderr.take().unwrap()));
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let (stdout, stderr) = (out.join().unwrap(), err.join().unwrap());
    match status {
        Some(status) => Output { status, stdout, stderr },
        None => panic!("{cmd:?} ran over {limit:?}; stderr:\n{}", String::from_utf8_lossy(&stderr)),
    }
}

/// Whether this run's `tessera` was built with the release profile.
fn this_profile_is_release() -> bool {
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_tessera"));
    bin.parent().and_then(Path::file_name).is_some_and(|p| p == "release")
}

/// The checksum of the fixed-point sums `tessera bench samples` prints for `scene` at
/// `size` and `spp` on one thread: equal checksums, the same image bits. In-process, so it
/// also serves binaries run under an emulator (a `render` would start a worker process,
/// which the emulator does not follow into).
pub fn checksum(mut cmd: Command, scene: &Path, size: &str, spp: &str) -> String {
    let args = ["bench", "samples", "--threads", "1", "--runs", "1", "--size", size, "--spp", spp];
    // Emulated, a scene takes a second or two.
    let out = output_within(cmd.args(args).arg(scene), Duration::from_secs(300));
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "bench samples {}: {text}", scene.display());
    let found = text.lines().find_map(|l| l.split("image checksum ").nth(1)).map(str::trim);
    found.unwrap_or_else(|| panic!("no checksum from bench samples {}: {text}", scene.display())).to_string()
}

/// Every scene file under `scenes/` whose assets are all there (the terrain's mesh is
/// generated, not kept in git), sorted.
pub fn scene_files() -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|e| e == "toml")
                && !p.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.'))
            {
                out.push(p);
            }
        }
    }
    let mut all = Vec::new();
    walk(&root().join("scenes"), &mut all);
    all.sort();
    all.retain(|p| {
        let bundle = tessera_description::Bundle::read(p);
        let present = bundle.is_ok_and(|b| tessera_description::Description::parse(&b).is_ok());
        if !present {
            eprintln!(
                "note: {} left out: it does not validate here (the terrain's mesh is generated, not in git)",
                p.display()
            );
        }
        present
    });
    assert!(all.len() >= 15, "expected the scenes of scenes/, found {all:?}");
    all
}

/// A sample of `/metrics` (a counter without labels, or with the labels given).
pub fn metric(text: &str, name: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.trim().parse().ok())
        .unwrap_or_else(|| panic!("no {name} in the metrics:\n{text}"))
}

/// The coordinator's `/metrics` over plain HTTP on loopback (an open coordinator).
pub fn scrape_metrics(http: &str) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(http).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(s, "GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n").unwrap();
    let mut raw = String::new();
    s.read_to_string(&mut raw).unwrap();
    let (head, body) = raw.split_once("\r\n\r\n").unwrap();
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    assert!(!head.to_ascii_lowercase().contains("chunked"), "{head}");
    body.to_string()
}

/// A coordinator on loopback that audits every batch (`--audit-fraction 1`: each batch
/// rendered again on another worker and compared bit for bit), its gRPC URL and its HTTP
/// address.
pub fn auditing_coordinator() -> (Proc, String, String) {
    let coord = Proc::spawn(&[
        "coordinator",
        "--listen",
        "127.0.0.1:0",
        "--http",
        "127.0.0.1:0",
        "--audit-fraction",
        "1",
    ]);
    let line = coord.wait_for("coordinator listening on ", Duration::from_secs(30));
    let url = format!("http://{}", line.rsplit("listening on ").next().unwrap().trim());
    let line = coord.wait_for("web dashboard on http://", Duration::from_secs(30));
    let http = line.rsplit("http://").next().unwrap().trim().to_string();
    (coord, url, http)
}

/// Two workers of one thread each on the farm at `url`, connected: one of this run's build
/// named `ours`, and one run by `other` (a command the worker's arguments are added to)
/// named `theirs`, whose connection is waited for up to `connect`.
pub fn two_workers(
    url: &str,
    ours: &str,
    other: &mut Command,
    theirs: &str,
    connect: Duration,
) -> (Proc, Proc) {
    let args = |name| ["worker", "--coordinator", url, "--threads", "1", "--name", name];
    let (ours, theirs) = (Proc::spawn(&args(ours)), Proc::spawn_command(other.args(args(theirs))));
    ours.wait_for("connected to", Duration::from_secs(30));
    theirs.wait_for("connected to", connect);
    (ours, theirs)
}

/// Each of `scenes` (paths under `scenes/`) submitted to the farm at `url` at `size` and
/// `spp` gives the bytes of a local render of this run's build; then the coordinator at
/// `http` shows audits agreed and none disagreed, no strike and no quarantine. `who` names
/// the farm in failures.
pub fn farm_agrees_with_local(who: &str, url: &str, http: &str, scenes: &[&str], size: &str, spp: &str) {
    let dir = tempfile::tempdir().unwrap();
    for name in scenes {
        let scene = root().join("scenes").join(name);
        let stem = name.replace('/', "_");
        let local = dir.path().join(format!("{stem}.local.exr"));
        render_local(&scene, &local, 1, &["--spp", spp, "--size", size]);
        let farm = dir.path().join(format!("{stem}.farm.exr"));
        let args =
            ["submit", scene.to_str().unwrap(), "--coordinator", url, "--spp", spp, "--size", size, "-o"];
        // Emulated workers are slow.
        let o = run_with_timeout(&[&args[..], &[farm.to_str().unwrap()]].concat(), Duration::from_secs(300));
        assert!(o.status.success(), "{who}, submit {name}: {}", String::from_utf8_lossy(&o.stderr));
        assert!(
            read(&farm) == read(&local),
            "{who}, {name}: the farm's image is not the local render's: {}",
            difference(&farm, &local)
        );
    }
    let m = scrape_metrics(http);
    let agreed = metric(&m, "tessera_audits_total{outcome=\"agreed\"}");
    let disagreed = metric(&m, "tessera_audits_total{outcome=\"disagreed\"}");
    assert!(agreed > 0.0 && disagreed == 0.0, "{who}: audits: {agreed} agreed, {disagreed} disagreed\n{m}");
    assert_eq!(metric(&m, "tessera_strikes_total"), 0.0, "{who}: {m}");
    assert_eq!(metric(&m, "tessera_quarantines_total"), 0.0, "{who}: {m}");
}

/// How two EXR images differ, for a failure message.
pub fn difference(a: &Path, b: &Path) -> String {
    let (Ok(x), Ok(y)) = (image::open(a), image::open(b)) else {
        return "the files differ and do not both decode".into();
    };
    let (x, y) = (x.into_rgb32f().into_raw(), y.into_rgb32f().into_raw());
    if x.len() != y.len() {
        return format!("{} against {} values", x.len(), y.len());
    }
    let off = x.iter().zip(&y).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
    let max = x.iter().zip(&y).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    format!("{off} of {} values differ, by up to {max:e}", x.len())
}
