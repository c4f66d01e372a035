//! The same bits on other machines (docs/determinism.md): `tessera` built for aarch64 (run
//! here by qemu's user-mode emulator, which computes IEEE arithmetic as an aarch64 CPU
//! does) and for x86-64 against musl's C library instead of glibc renders every scene of
//! `scenes/` to this run's checksums, and a worker of each, in a farm with one of this
//! run's, passes every audit bit for bit.
//!
//! `scripts/cross-target.sh` makes each target ready (the standard library through rustup,
//! Debian's cross compiler or musl-gcc, qemu-user); where it cannot, the tests print
//! SKIPPED with its reason. The builds go to their own target directory
//! (`<target>/other-targets`), in this run's profile: minutes each, the first time.

mod common;

use common::builds::*;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

/// Small and few samples: every code path of a scene, in seconds even under emulation.
const SIZE: &str = "40x30";
const SPP: &str = "4";

/// A target this file builds for, and how its binaries run here.
#[derive(Clone, Copy, Debug)]
enum Target {
    /// aarch64 Linux with glibc, under `qemu-aarch64`.
    Aarch64,
    /// x86-64 Linux with musl, statically linked: it runs as it is.
    Musl,
}

impl Target {
    const ALL: [Target; 2] = [Target::Aarch64, Target::Musl];

    fn triple(self) -> &'static str {
        match self {
            Target::Aarch64 => "aarch64-unknown-linux-gnu",
            Target::Musl => "x86_64-unknown-linux-musl",
        }
    }

    /// The C compiler (and linker) cargo and the `cc` crate use for the target.
    fn env(self) -> Vec<(String, &'static str)> {
        let under = self.triple().replace('-', "_");
        match self {
            Target::Aarch64 => vec![
                (format!("CARGO_TARGET_{}_LINKER", under.to_uppercase()), "aarch64-linux-gnu-gcc"),
                (format!("CC_{under}"), "aarch64-linux-gnu-gcc"),
                (format!("AR_{under}"), "aarch64-linux-gnu-ar"),
            ],
            Target::Musl => vec![(format!("CC_{under}"), "musl-gcc")],
        }
    }

    /// A command that runs `bin` here.
    fn command(self, bin: &Path) -> Command {
        let mut cmd = match self {
            Target::Aarch64 => {
                let mut c = Command::new("qemu-aarch64");
                // Where Debian's cross packages put aarch64's dynamic loader and glibc.
                c.args(["-L", "/usr/aarch64-linux-gnu"]).arg(bin);
                c
            }
            Target::Musl => Command::new(bin),
        };
        cmd.env("RUST_LOG", "info").stdin(Stdio::null());
        cmd
    }

    /// This target's `tessera`, built on first use; `None` (after saying why, in every
    /// test that asks) where the target cannot be made ready here.
    fn build(self) -> Option<&'static Path> {
        static BUILT: [OnceLock<Result<PathBuf, String>>; 2] = [OnceLock::new(), OnceLock::new()];
        let built = BUILT[self as usize].get_or_init(|| {
            let mut script = Command::new("bash");
            script.arg(root().join("scripts/cross-target.sh")).arg(self.triple()).stdin(Stdio::null());
            // The script's own waits (apt, rustup) are bounded by `timeout` inside it.
            let ready = output_within(&mut script, Duration::from_secs(40 * 60));
            if !ready.status.success() {
                let why = String::from_utf8_lossy(&ready.stderr).trim().to_string();
                return Err(if why.is_empty() {
                    format!("scripts/cross-target.sh: {}", ready.status)
                } else {
                    why
                });
            }
            let dir = target_dir().join("other-targets");
            let mut cargo = nested_cargo(&["build", "--bin", "tessera", "--target", self.triple()]);
            cargo.env("CARGO_TARGET_DIR", &dir).envs(self.env());
            // About six minutes on two cores; a download that stalls fails here.
            let out = output_within(&mut cargo, Duration::from_secs(45 * 60));
            let log = String::from_utf8_lossy(&out.stderr);
            assert!(out.status.success(), "building tessera for {} failed:\n{log}", self.triple());
            // `debug` or `release`, as this run's.
            let ours = PathBuf::from(env!("CARGO_BIN_EXE_tessera"));
            let profile = ours.parent().and_then(Path::file_name).expect("a profile directory");
            let bin = dir.join(self.triple()).join(profile).join("tessera");
            assert!(bin.is_file(), "no {}", bin.display());
            Ok(bin)
        });
        match built {
            Ok(bin) => Some(bin),
            Err(why) => {
                eprintln!("SKIPPED: {}: {why}", self.triple());
                None
            }
        }
    }
}

/// Every scene renders to the fixed-point sums of this run's build on aarch64 and with musl
/// (the checksum of every pixel's sums, which decide the image's bytes).
#[test]
fn other_targets_render_every_scene_to_the_same_sums() {
    let scenes = scene_files();
    let ours: Vec<String> = scenes.iter().map(|s| checksum(tessera(), s, SIZE, SPP)).collect();
    for target in Target::ALL {
        let Some(bin) = target.build() else { continue };
        let mut failures = Vec::new();
        for (scene, want) in scenes.iter().zip(&ours) {
            let got = checksum(target.command(bin), scene, SIZE, SPP);
            if &got != want {
                failures.push(format!("{}: {got} against {want}", scene.display()));
            }
        }
        assert!(failures.is_empty(), "{:?} renders other bits:\n{}", target, failures.join("\n"));
    }
}

/// A worker of each other target in a farm with one of this run's, every batch audited
/// (rendered again on the other worker and compared bit for bit): every audit agrees,
/// nobody is struck, and the images are the local render's bytes.
#[test]
fn a_farm_with_an_aarch64_and_a_musl_worker_agrees_bit_for_bit() {
    for target in Target::ALL {
        let Some(bin) = target.build() else { continue };
        let (_coord, url, http) = auditing_coordinator();
        let name = format!("{target:?}");
        // Emulated, the worker starts in seconds rather than milliseconds.
        let _workers = two_workers(&url, "ours", &mut target.command(bin), &name, Duration::from_secs(120));

        // Motion, textures, an environment map, glTF nodes, many BSDFs, a mesh.
        let picked = ["showcase.toml", "environment.toml", "motion_blur.toml", "gltf_quad/quad_gltf.toml"];
        farm_agrees_with_local(&name, &url, &http, &picked, SIZE, SPP);
    }
}
