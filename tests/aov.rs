//! AOV layers end to end: `--aov` on `tessera render` and `tessera submit`, one
//! multi-layer OpenEXR file read back by OpenEXR's own `exrheader` (scripts/openexr-tools.sh)
//! and by the `exr` crate, the same bytes for one and two workers and through a standalone
//! coordinator, plausible values, and a PNG output refused.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

const LAYERS: &str = "albedo,normal,depth";

fn wall() -> std::path::PathBuf {
    root().join("tests/scenes/aov_wall.toml")
}

/// The channels of an EXR file, by name, as the `exr` crate reads them.
fn channels(path: &Path) -> Vec<(String, Vec<f32>)> {
    let image = exr::prelude::read_all_flat_layers_from_file(path).unwrap();
    assert_eq!(image.layer_data.len(), 1, "one part");
    image.layer_data[0]
        .channel_data
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect()))
        .collect()
}

fn channel<'a>(all: &'a [(String, Vec<f32>)], name: &str) -> &'a [f32] {
    &all.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("no channel {name}")).1
}

#[test]
fn layers_are_plausible_and_the_same_bytes_for_one_and_two_workers() {
    let dir = tempfile::tempdir().unwrap();
    let (one, two) = (dir.path().join("one.exr"), dir.path().join("two.exr"));
    render_local(&small_scene(), &one, 1, &["--aov", LAYERS]);
    render_local(&small_scene(), &two, 2, &["--aov", LAYERS]);
    assert!(read(&one) == read(&two), "AOV files differ between 1 and 2 workers");

    let wall_exr = dir.path().join("wall.exr");
    render_local(&wall(), &wall_exr, 2, &["--aov", LAYERS]);
    let c = channels(&wall_exr);
    let names: Vec<&str> = c.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["B", "G", "R", "Z", "albedo.B", "albedo.G", "albedo.R", "normal.X", "normal.Y", "normal.Z"]
    );
    for name in ["albedo.R", "albedo.G", "albedo.B"] {
        assert!(channel(&c, name).iter().all(|&a| (a - 0.8).abs() < 1e-6), "{name}: {:?}", channel(&c, name));
    }
    assert!(channel(&c, "normal.X").iter().chain(channel(&c, "normal.Y")).all(|v| v.abs() < 1e-6));
    assert!(channel(&c, "normal.Z").iter().all(|&v| (v - 1.0).abs() < 1e-6));
    // The distance along each camera ray to the wall: 3 / cos θ, θ at most the half
    // diagonal of a 30° (vertical) × 44° view, about 26° (cos 0.90); 3 at the centre.
    let z = channel(&c, "Z");
    assert_eq!(z.len(), 24 * 16);
    assert!(z.iter().all(|&d| (3.0..3.0 / 0.89).contains(&d)), "{z:?}");
    let nearest = z.iter().copied().fold(f32::INFINITY, f32::min);
    assert!((nearest - 3.0).abs() < 0.01, "{nearest}");
    let corner = z[0];
    assert!((corner - 3.0 / 0.9).abs() < 0.05, "{corner}");
    // The radiance keeps its bits: the same render without layers has the same RGB.
    let plain = dir.path().join("plain.exr");
    render_local(&wall(), &plain, 1, &[]);
    let p = image::open(&plain).unwrap().to_rgb32f();
    let r: Vec<f32> = p.pixels().map(|px| px[0]).collect();
    assert_eq!(r, channel(&c, "R"));
}

#[test]
fn openexrs_own_tools_list_the_layers_and_channels() {
    let out = Command::new("bash")
        .arg(root().join("scripts/openexr-tools.sh"))
        .env("CARGO_TARGET_DIR", target_dir())
        .output()
        .unwrap();
    if !out.status.success() {
        eprintln!("SKIPPED: no exrheader: {}", String::from_utf8_lossy(&out.stderr).trim());
        return;
    }
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let mut lines = stdout.lines();
    let (bin, lib) = (lines.next().unwrap_or(""), lines.next().unwrap_or(""));
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("layers.exr");
    render_local(&wall(), &exr, 1, &["--aov", LAYERS]);
    let header = Command::new(Path::new(bin).join("exrheader"))
        .arg(&exr)
        .env("LD_LIBRARY_PATH", lib)
        .output()
        .unwrap();
    assert!(header.status.success(), "exrheader: {}", String::from_utf8_lossy(&header.stderr));
    let text = String::from_utf8_lossy(&header.stdout);
    eprintln!("{text}");
    // exrheader lists each channel on a line of its own with its pixel type.
    for name in ["R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "normal.X", "normal.Y", "normal.Z", "Z"] {
        let listed = text.lines().any(|l| {
            let l = l.trim();
            l.starts_with(&format!("{name},")) && l.contains("32-bit floating-point")
        });
        assert!(listed, "exrheader lists no 32-bit float channel {name}:\n{text}");
    }
    assert!(text.contains("zip"), "{text}");
}

#[test]
fn submit_and_fetch_write_the_same_layers_as_a_local_render() {
    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("local.exr");
    render_local(&wall(), &local, 1, &["--aov", LAYERS]);
    let coord = Coordinator::start(&[]);
    let _worker = coord.worker(2);
    let submitted = dir.path().join("submitted.exr");
    let o = run(&[
        "submit",
        wall().to_str().unwrap(),
        "--coordinator",
        &coord.url,
        "--aov",
        LAYERS,
        "-o",
        submitted.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "submit: {}", String::from_utf8_lossy(&o.stderr));
    assert!(read(&local) == read(&submitted), "submit -o differs from the local render");
    let job = String::from_utf8_lossy(&o.stdout).trim().to_string();
    let fetched = dir.path().join("fetched.exr");
    let o =
        run(&["fetch", &job, "--coordinator", &coord.url, "--aov", "depth", "-o", fetched.to_str().unwrap()]);
    assert!(o.status.success(), "fetch: {}", String::from_utf8_lossy(&o.stderr));
    let c = channels(&fetched);
    assert_eq!(c.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>(), ["B", "G", "R", "Z"]);
    assert_eq!(channel(&c, "Z"), channel(&channels(&local), "Z"));
}

#[test]
fn a_png_output_with_layers_is_refused_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("out.png");
    let o = run(&["render", wall().to_str().unwrap(), "-o", png.to_str().unwrap(), "--aov", "albedo"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("AOV layers need an OpenEXR output (.exr), not PNG"), "{err}");
    assert!(!png.exists());
    let o = run(&["render", wall().to_str().unwrap(), "-o", "x.exr", "--aov", "albedo,shadow"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown AOV layer \"shadow\""));
}

#[test]
fn denoise_runs_where_open_image_denoise_is_found_and_says_why_not_otherwise() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("denoised.exr");
    let o = run(&[
        "render",
        wall().to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--denoise",
        "--oidn-lib",
        "/nonexistent",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--denoise: no libOpenImageDenoise at /nonexistent"), "{err}");
    assert!(!out.exists());

    let Some(python) = python_venv("oidn", "tests/tools/oidn-requirements.txt") else { return };
    let lib = python.parent().and_then(Path::parent).unwrap().join("lib");
    let noisy = dir.path().join("noisy.exr");
    render_local(&small_scene(), &noisy, 1, &["--spp", "2", "--aov", "albedo,normal"]);
    let o = run(&[
        "render",
        small_scene().to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--workers",
        "1",
        "--spp",
        "2",
        "--aov",
        "albedo,normal",
        "--denoise",
        "--oidn-lib",
        lib.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    if err.contains("cannot load Open Image Denoise") {
        eprintln!("SKIPPED: the pyoidn wheel's library does not load here: {}", err.trim());
        return;
    }
    assert!(o.status.success(), "{err}");
    let (n, d) = (channels(&noisy), channels(&out));
    // The guides are the same; the image is changed, and stays finite and near the original.
    assert_eq!(channel(&n, "albedo.R"), channel(&d, "albedo.R"));
    let (nr, dr) = (channel(&n, "R"), channel(&d, "R"));
    assert_ne!(nr, dr);
    assert!(dr.iter().all(|v| v.is_finite()));
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!((mean(nr) - mean(dr)).abs() < 0.1 * mean(nr).max(0.05), "{} vs {}", mean(nr), mean(dr));
}

/// A sequence's layers are cut per frame: frame 2 of a two-frame job has the same bytes,
/// layers included, as frame 2 rendered as a job of its own.
#[test]
fn each_frame_of_a_sequence_gets_its_own_layers() {
    let dir = tempfile::tempdir().unwrap();
    let scene = root().join("scenes/bouncing_ball.toml");
    let small = ["--aov", LAYERS, "--size", "32x20", "--spp", "2"];
    let both = dir.path().join("both_#.exr");
    render_local(&scene, &both, 2, &[&small[..], &["--frames", "1-2"]].concat());
    let alone = dir.path().join("alone_#.exr");
    render_local(&scene, &alone, 1, &[&small[..], &["--frames", "2-2"]].concat());
    let (a, b) = (dir.path().join("both_2.exr"), dir.path().join("alone_2.exr"));
    assert!(read(&a) == read(&b), "frame 2's file differs between the sequence and the frame alone");
    let z = channels(&a);
    assert!(channel(&z, "Z").iter().any(|d| d.is_finite()), "frame 2 has depth");
    assert!(read(&dir.path().join("both_1.exr")) != read(&a), "frames 1 and 2 differ");
}
