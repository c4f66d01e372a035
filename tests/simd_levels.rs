//! The same bits on every machine (docs/determinism.md): a `tessera` built with the
//! renderer on glam's scalar code (`--features scalar`) renders every scene of `scenes/` to
//! the bytes of the default build (glam's SSE2 paths), and the two builds' workers in one
//! farm pass every audit, bit for bit.
//!
//! The other build shares this run's target directory, so only the crates above glam are
//! compiled again (minutes, not a second full build); cargo puts its binary where this
//! run's `tessera` is, so it is copied to `<target>/scalar/tessera` and this run's binary
//! is linked back in place (built again: nothing to compile) before any test
//! renders. The window in between is inside this file's first test: cargo runs test
//! files one after another, so no other test sees the other build.

mod common;

use common::builds::*;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

/// Small and few samples: every code path of a scene, in seconds.
const SIZE: &str = "40x30";
const SPP: &str = "4";

/// Builds this test file's `tessera` in this run's target directory and profile, with the
/// scalar renderer or without: `cargo test --no-run --test simd_levels`, so that the
/// dependencies' features are this run's (a plain `cargo build` leaves out those of the
/// dev-dependencies, and would compile them again).
fn cargo_build(scalar: bool) -> std::io::Result<std::process::ExitStatus> {
    let mut cmd = nested_cargo(&["test", "--no-run", "--test", "simd_levels"]);
    if scalar {
        cmd.args(["--features", "scalar"]);
    }
    cmd.env("CARGO_TARGET_DIR", target_dir()).status()
}

/// The other build's `tessera` (scalar if this run's is not, and the other way round),
/// built on first use; `None` (after saying why) when there is no cargo to build it with.
fn other_build() -> Option<&'static Path> {
    static BUILT: OnceLock<Option<PathBuf>> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            let ours = PathBuf::from(env!("CARGO_BIN_EXE_tessera"));
            let other = !cfg!(feature = "scalar");
            let built = match cargo_build(other) {
                Ok(s) => s.success(),
                Err(e) => {
                    eprintln!("SKIPPED: cannot run cargo to build the other variant: {e}");
                    return None;
                }
            };
            let copy = target_dir().join("scalar/tessera");
            if built {
                std::fs::create_dir_all(copy.parent().unwrap()).unwrap();
                let _ = std::fs::remove_file(&copy);
                std::fs::copy(&ours, &copy).unwrap();
            }
            // This run's binary back in place, whatever happened.
            let restored = cargo_build(!other).map(|s| s.success()).unwrap_or(false);
            assert!(restored, "could not link this run's tessera back into {}", ours.display());
            assert!(built, "building the other variant (scalar: {other}) failed");
            Some(copy)
        })
        .as_deref()
}

/// Runs `bin args…` to completion within two minutes; panics with its stderr on failure.
fn run_bin(bin: &Path, args: &[&str]) {
    let mut child = Command::new(bin)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{}: {e}", bin.display()));
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{} {args:?}: {}", bin.display(), String::from_utf8_lossy(&out.stderr));
}

/// The render arguments of `scene` into `out`: the scene as a still, or, for one with an
/// animation, two frames mid-sequence (keys evaluated at a later time).
fn render_args(scene: &Path, out: &Path) -> Vec<String> {
    let mut args = vec!["render".to_string(), scene.display().to_string(), "-o".into()];
    let animated = std::fs::read_to_string(scene).unwrap().contains("[animation]");
    if animated {
        args.extend([
            out.with_extension("").display().to_string() + "_####.exr",
            "--frames".into(),
            "4-5".into(),
        ]);
    } else {
        args.push(out.display().to_string());
    }
    args.extend(["--workers", "1", "--threads", "2", "--spp", SPP, "--size", SIZE].map(String::from));
    args
}

/// The image files a render of `render_args(scene, out)` wrote.
fn outputs(scene: &Path, out: &Path) -> Vec<PathBuf> {
    if std::fs::read_to_string(scene).unwrap().contains("[animation]") {
        let stem = out.with_extension("").display().to_string();
        ["0004", "0005"].iter().map(|f| PathBuf::from(format!("{stem}_{f}.exr"))).collect()
    } else {
        vec![out.to_path_buf()]
    }
}

/// The renderer on glam's SSE2 paths and on its scalar code gives the same bytes, scene by
/// scene: the SIMD code's results equal the scalar path's.
#[test]
fn simd_and_scalar_builds_render_every_scene_to_the_same_bytes() {
    let Some(scalar) = other_build() else { return };
    let default = PathBuf::from(env!("CARGO_BIN_EXE_tessera"));
    assert!(read(&default) != read(scalar), "the two builds are the same binary: nothing would be tested");
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for scene in scene_files() {
        let name = scene.strip_prefix(root().join("scenes")).unwrap().display().to_string().replace('/', "_");
        let simd_out = dir.path().join(format!("{name}.simd.exr"));
        let scalar_out = dir.path().join(format!("{name}.scalar.exr"));
        run_bin(&default, &render_args(&scene, &simd_out).iter().map(String::as_str).collect::<Vec<_>>());
        run_bin(scalar, &render_args(&scene, &scalar_out).iter().map(String::as_str).collect::<Vec<_>>());
        for (a, b) in outputs(&scene, &simd_out).iter().zip(outputs(&scene, &scalar_out)) {
            if read(a) != read(&b) {
                failures.push(format!("{}: {}", a.display(), difference(a, &b)));
            }
        }
    }
    assert!(failures.is_empty(), "the scalar build renders other bits:\n{}", failures.join("\n"));
}

/// A worker built for another SIMD level in the farm: a default worker and a scalar one,
/// every batch audited (rendered again on the other and compared bit for bit). Every
/// audit agrees, nobody is struck, and the images are the local render's bytes.
#[test]
fn a_farm_of_a_simd_and_a_scalar_worker_agrees_bit_for_bit() {
    let Some(scalar) = other_build() else { return };
    let (_coord, url, http) = auditing_coordinator();
    let _workers = two_workers(&url, "simd", &mut Command::new(scalar), "scalar", Duration::from_secs(30));

    // Scenes with motion, textures, an environment map, glTF nodes and many BSDFs.
    let picked =
        ["showcase.toml", "environment.toml", "motion_blur.toml", "gltf_quad/quad_gltf.toml", "gloss.toml"];
    farm_agrees_with_local("simd and scalar", &url, &http, &picked, SIZE, SPP);
}
