//! End-to-end: bad input at every entry point gets a clear one-line error and a non-zero
//! exit, never a panic or a hang.

mod common;

use common::*;

fn stderr_of(args: &[&str]) -> String {
    let o = run(args);
    assert!(!o.status.success(), "tessera {args:?} should fail");
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(!err.contains("panicked"), "tessera {args:?} panicked: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "expected one error line from {args:?}, got: {err}");
    lines[0].to_string()
}

fn write_scene(dir: &std::path::Path, text: &str) -> String {
    let p = dir.join("bad.toml");
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn bad_scene_files_name_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.png");
    let out = out.to_str().unwrap();
    let good = std::fs::read_to_string(small_scene()).unwrap();

    let missing = dir.path().join("nope.toml");
    let e = stderr_of(&["render", missing.to_str().unwrap(), "-o", out]);
    assert!(e.contains("cannot read scene") && e.contains("nope.toml"), "{e}");

    let cases = [
        (good.replace("width = 64", "width = 6x4"), "bad.toml:4:"),
        (good.replace("radius = 0.4", "radius = -0.4"), "positive"),
        (good.replace("material = \"red\"", "material = \"blue\""), "unknown material \"blue\""),
        (good.replace("radius = 0.4", "radius = nan"), "positive"),
        (good.replace("center = [1.8, 0.4, -0.8]", "center = [1.8, nan, -0.8]"), "finite"),
        (good.replace("fov = 40", "fov = 40\nzoom = 2"), "zoom"),
        (good.replace("spp = 4", "spp = 4\nsampler = \"halton\""), "unknown sampler \"halton\""),
        (
            format!("{good}\n[[mesh]]\nfile = \"../../etc/passwd\"\nmaterial = \"red\"\n"),
            "escapes the scene's folder",
        ),
        (
            format!("{good}\n[[mesh]]\nfile = \"missing.obj\"\nmaterial = \"red\"\n"),
            "cannot read \"missing.obj\"",
        ),
        (
            good.replace("[materials.red]", "[materials.red]\ntype = \"velvet\""),
            "unknown material \"velvet\"",
        ),
    ];
    for (text, want) in cases {
        let scene = write_scene(dir.path(), &text);
        let e = stderr_of(&["render", &scene, "-o", out]);
        assert!(e.contains(want) && e.contains("bad.toml:"), "expected {want:?} in: {e}");
    }
    // An OBJ with broken indices: the error names the scene, the mesh and the OBJ line.
    std::fs::write(dir.path().join("broken.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n").unwrap();
    let scene =
        write_scene(dir.path(), &format!("{good}\n[[mesh]]\nfile = \"broken.obj\"\nmaterial = \"red\"\n"));
    let e = stderr_of(&["render", &scene, "-o", out]);
    assert!(e.contains("bad.toml:") && e.contains("broken.obj") && e.contains("line 4"), "{e}");
    // The checkpoint store is made before the coordinator validates the scene (its workers
    // start meanwhile): a refused scene's store is removed again.
    assert!(!dir.path().join("o.png.tessera").exists(), "a refused scene left its checkpoint folder");
    let e = stderr_of(&["render", &small_scene().to_string_lossy(), "-o", out, "--size", "0x5"]);
    assert!(e.contains("WIDTHxHEIGHT"), "{e}");
    assert!(!std::path::Path::new(out).exists(), "no image for a bad scene");
}

#[test]
fn bad_arguments_are_refused_before_work() {
    let scene = small_scene();
    let scene = scene.to_str().unwrap();
    let e = stderr_of(&["render", scene, "-o", "/tmp/x.jpg"]);
    assert!(e.contains("use .png or .exr"), "{e}");
    let e = stderr_of(&["render", scene, "-o", "/no/such/dir/x.png"]);
    assert!(e.contains("does not exist"), "{e}");
    // A private folder: a shared /tmp/x.png would meet other runs' leftovers.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.png");
    let out = out.to_str().unwrap();
    let e = stderr_of(&["render", scene, "-o", out, "--workers", "0"]);
    assert!(e.contains("--workers"), "{e}");
    let e = stderr_of(&["render", scene, "-o", out, "--spp", "0"]);
    assert!(e.contains("spp"), "{e}");
    // Bug this protects against: a refused job left its checkpoint folder behind.
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().flatten().map(|e| e.file_name()).collect();
    assert!(left.is_empty(), "a refused render left {left:?} behind");
    let o = run(&["render", scene]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--output"));
    for bad in ["0", "0.001", "61", "NaN"] {
        let e = stderr_of(&["coordinator", "--listen", "127.0.0.1:0", "--batch-time", bad]);
        assert!(e.contains("--batch-time must be between 0.005 and 60 seconds"), "{bad}: {e}");
    }
}

#[test]
fn bad_or_absent_coordinator_is_a_clear_error() {
    let scene = small_scene();
    let scene = scene.to_str().unwrap();
    let e = stderr_of(&["status", "--coordinator", "not a url"]);
    assert!(e.contains("bad coordinator address"), "{e}");
    let e = stderr_of(&["worker", "--coordinator", "not a url"]);
    assert!(e.contains("bad coordinator address"), "{e}");
    // A port nothing listens on: bind one, then free it.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let url = format!("http://127.0.0.1:{port}");
    for args in [
        vec!["status", "--coordinator", &url],
        vec!["worker", "--coordinator", &url],
        vec!["submit", scene, "--coordinator", &url],
        vec!["cancel", "3", "--coordinator", &url],
    ] {
        let e = stderr_of(&args);
        assert!(e.contains("cannot reach coordinator"), "{args:?}: {e}");
    }
    let e = stderr_of(&["coordinator", "--listen", "nonsense"]);
    assert!(e.contains("nonsense") || e.contains("invalid"), "{e}");
}

#[test]
fn submitting_a_bad_scene_or_asking_for_a_missing_job_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let coord = Coordinator::start(&[]);
    let scene = write_scene(dir.path(), "[render]\nwidth = 4\n");
    let e = stderr_of(&["submit", &scene, "--coordinator", &coord.url]);
    assert!(e.contains("bad.toml:") && e.contains("height"), "{e}");
    let small = small_scene();
    let small = small.to_str().unwrap();
    let e = stderr_of(&[
        "submit",
        small,
        "--coordinator",
        &coord.url,
        "--spp",
        "16",
        "--noise-abs",
        "0.1",
        "--noise-min",
        "32",
    ]);
    assert!(e.contains("minimum of 32 samples is more than the job's 16 samples per pixel"), "{e}");
    let e = stderr_of(&["cancel", "99", "--coordinator", &coord.url]);
    assert!(e.contains("no job 99"), "{e}");
    // The coordinator is still serving.
    assert!(coord.status().contains("no workers connected"));
}

/// Data directories and checkpoints: every misuse is one clear error line.
#[test]
fn bad_data_directories_and_checkpoints_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene();
    let scene = scene.to_str().unwrap();
    let listen = ["coordinator", "--listen", "127.0.0.1:0"];

    let file = dir.path().join("a-file");
    std::fs::write(&file, "x").unwrap();
    let e = stderr_of(&[&listen[..], &["--data", file.to_str().unwrap()]].concat());
    assert!(e.contains("data directory") && e.contains("a-file"), "{e}");

    let garbage = dir.path().join("garbage");
    std::fs::create_dir(&garbage).unwrap();
    std::fs::write(garbage.join("jobs.db"), vec![0x42u8; 4096]).unwrap();
    let e = stderr_of(&[&listen[..], &["--data", garbage.to_str().unwrap()]].concat());
    assert!(e.contains("damaged") && e.contains("move it aside"), "{e}");

    let data = dir.path().join("data");
    let e =
        stderr_of(&[&listen[..], &["--data", data.to_str().unwrap(), "--checkpoint-interval", "0"]].concat());
    assert!(e.contains("--checkpoint-interval must be a positive number"), "{e}");
    let o = run(&[&listen[..], &["--checkpoint-interval", "5"]].concat());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("required") && e.contains("--data"), "{e}");

    // One process per data directory.
    let _first = Coordinator::start(&["--data", data.to_str().unwrap()]);
    let e = stderr_of(&[&listen[..], &["--data", data.to_str().unwrap()]].concat());
    assert!(e.contains("in use by another coordinator"), "{e}");

    let out = dir.path().join("o.png");
    let e = stderr_of(&["render", scene, "-o", out.to_str().unwrap(), "--resume"]);
    assert!(e.contains("nothing to resume"), "{e}");
    // A coordinator's data directory is not a render's checkpoint.
    let e = stderr_of(&["render", scene, "-o", out.to_str().unwrap(), "--data", garbage.to_str().unwrap()]);
    assert!(e.contains("damaged"), "{e}");
    let e = stderr_of(&["submit", scene, "--coordinator", "http://127.0.0.1:1", "--priority", "high"]);
    assert!(e.contains("--priority"), "{e}");
}

/// Halt conditions out of range are one clear error line each.
#[test]
fn bad_halt_conditions_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.png");
    let (scene, out) = (small_scene(), out.to_str().unwrap().to_string());
    let render = |extra: &[&str]| {
        let mut args = vec!["render", scene.to_str().unwrap(), "-o", &out];
        args.extend_from_slice(extra);
        stderr_of(&args)
    };
    for noise in ["2", "0", "-0.1", "nan"] {
        let e = render(&["--noise", noise]);
        assert!(
            e.contains("noise target must be a relative error in (0, 1)") || e.contains("--noise"),
            "{noise}: {e}"
        );
    }
    for noise in ["0", "-0.1", "nan", "inf"] {
        let e = render(&["--noise-abs", noise]);
        assert!(
            e.contains("absolute noise target must be a positive number") || e.contains("--noise-abs"),
            "{noise}: {e}"
        );
    }
    let both = render(&["--noise", "0.1", "--noise-abs", "0.1"]);
    assert!(both.contains("cannot be used with"), "{both}");
    let alone = render(&["--noise-min", "32"]);
    assert!(alone.contains("--noise-min 32: a minimum of samples needs a noise target"), "{alone}");
    for min in ["1", "0", "-3", "many"] {
        let e = render(&["--noise", "0.1", "--noise-min", min]);
        assert!(e.contains("--noise-min"), "{min}: {e}");
    }
    let over = render(&["--noise-abs", "0.1", "--spp", "16", "--noise-min", "32"]);
    assert!(over.contains("minimum of 32 samples is more than the job's 16 samples per pixel"), "{over}");
    for time in ["0", "soon", "5x", "-1s"] {
        let e = render(&["--time", time]);
        assert!(e.contains("--time") && e.contains("duration"), "{time}: {e}");
    }
}

/// Trust 6: a mesh that is a symlink out of the scene's folder is refused by `render` and
/// `submit` alike, saying why, with no image, no job and nothing of the outside file quoted;
/// a mesh that is a FIFO is refused at once rather than hanging the client.
#[test]
fn assets_that_leave_the_scene_folder_or_are_no_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let outside = tempfile::tempdir().unwrap();
    let secret = outside.path().join("passwd");
    std::fs::write(&secret, "root:x:0:0:root:/root:/bin/bash\n").unwrap();
    std::os::unix::fs::symlink(&secret, dir.path().join("m.obj")).unwrap();
    let good = std::fs::read_to_string(small_scene()).unwrap();
    let scene = write_scene(dir.path(), &format!("{good}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n"));
    let out = dir.path().join("o.png");
    let want = "mesh.file: cannot read \"m.obj\": it leads outside the scene's folder (through a symlink); \
                assets must lie beneath it";
    let e = stderr_of(&["render", &scene, "-o", out.to_str().unwrap()]);
    assert!(e.contains("bad.toml:") && e.ends_with(want) && !e.contains("root:x"), "{e}");
    assert!(!out.exists(), "no image for a refused scene");
    let coord = Coordinator::start(&[]);
    let e = stderr_of(&["submit", &scene, "--coordinator", &coord.url]);
    assert!(e.contains("bad.toml:") && e.ends_with(want) && !e.contains("root:x"), "{e}");
    assert!(coord.job(1).is_none(), "the scene never reached the coordinator");
    assert!(coord.status().contains("no workers connected"), "the coordinator still serves");

    std::fs::remove_file(dir.path().join("m.obj")).unwrap();
    if std::process::Command::new("mkfifo").arg(dir.path().join("m.obj")).status().is_ok_and(|s| s.success())
    {
        let o = run_with_timeout(
            &["render", &scene, "-o", out.to_str().unwrap()],
            std::time::Duration::from_secs(60),
        );
        let e = String::from_utf8(o.stderr).unwrap();
        assert!(!o.status.success() && e.contains("it is a FIFO, not a regular file"), "{e}");
        assert!(!out.exists());
    } else {
        eprintln!("skipped the FIFO case: mkfifo is not available");
    }
}
