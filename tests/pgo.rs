//! The profile-guided build (`scripts/pgo-build.sh`, docs/speed.md's twentieth part) is the
//! same renderer: it renders every scene of `scenes/` to this run's checksums, and a worker
//! of it in a farm with one of this run's passes every audit bit for bit. PGO moves and
//! inlines code by measured counts; it must not change one bit of an image, whichever
//! profile this run was built with.
//!
//! The script takes two release builds (about nine minutes on two cores, into
//! `<target>/pgo`); where the toolchain cannot do PGO (no rustup to add llvm-tools) the
//! tests print SKIPPED with its reason.

mod common;

use common::builds::*;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Duration;

const SIZE: &str = "48x36";
const SPP: &str = "4";

/// How the script ended, kept for every test that asks (a failure is reported by each,
/// not by running the script again).
enum Built {
    Binary(PathBuf),
    Skipped(String),
    Failed(String),
}

/// The PGO build of `tessera`, made on first use; `None` (after saying why, in every test
/// that asks) where this toolchain cannot make one.
fn pgo_build() -> Option<&'static Path> {
    static BUILT: OnceLock<Built> = OnceLock::new();
    let built = BUILT.get_or_init(|| {
        // Under `timeout`, which signals its whole process group: the cargo and tessera
        // processes the script starts go with it if it overruns, not just bash.
        let mut script = Command::new("timeout");
        script.args(["--kill-after=30", "3600", "bash"]);
        script.arg(root().join("scripts/pgo-build.sh")).arg(target_dir().join("pgo"));
        without_cargos_env(&mut script);
        // Two release builds and the training; rustup's download is bounded inside.
        let out = output_within(&mut script, Duration::from_secs(3700));
        let log = String::from_utf8_lossy(&out.stderr);
        match out.status.code() {
            Some(0) => {}
            Some(2) => return Built::Skipped(log.trim().to_string()),
            _ => {
                let tail: Vec<&str> = log.lines().rev().take(40).collect();
                let tail: Vec<&str> = tail.into_iter().rev().collect();
                return Built::Failed(format!(
                    "scripts/pgo-build.sh failed ({}):\n{}",
                    out.status,
                    tail.join("\n")
                ));
            }
        }
        let stdout = String::from_utf8_lossy(&out.stdout);
        let bin = PathBuf::from(stdout.lines().last().unwrap_or_default().trim());
        if bin.is_file() {
            Built::Binary(bin)
        } else {
            Built::Failed(format!("the script printed {stdout:?}, whose last line is not a file"))
        }
    });
    match built {
        Built::Binary(bin) => Some(bin),
        Built::Skipped(why) => {
            eprintln!("SKIPPED: scripts/pgo-build.sh: {why}");
            None
        }
        Built::Failed(why) => panic!("{why}"),
    }
}

/// Every scene: the PGO build's checksum of the fixed-point sums is this run's.
#[test]
fn the_pgo_build_renders_every_scene_to_the_same_sums() {
    let Some(bin) = pgo_build() else { return };
    let mut failures = Vec::new();
    for scene in scene_files() {
        let want = checksum(tessera(), &scene, SIZE, SPP);
        let got = checksum(Command::new(bin), &scene, SIZE, SPP);
        if got != want {
            failures.push(format!("{}: {got} against {want}", scene.display()));
        }
    }
    assert!(failures.is_empty(), "the PGO build renders other bits:\n{}", failures.join("\n"));
}

/// A PGO worker beside one of this run's, every batch audited: every audit agrees and the
/// images are the local render's bytes.
#[test]
fn a_farm_with_a_pgo_worker_agrees_bit_for_bit() {
    let Some(bin) = pgo_build() else { return };
    let (_coord, url, http) = auditing_coordinator();
    let mut pgo = Command::new(bin);
    pgo.env("RUST_LOG", "info");
    let _workers = two_workers(&url, "ours", &mut pgo, "pgo", Duration::from_secs(30));
    let picked = ["showcase.toml", "environment.toml", "motion_blur.toml", "gltf_quad/quad_gltf.toml"];
    farm_agrees_with_local("pgo", &url, &http, &picked, SIZE, SPP);
}
