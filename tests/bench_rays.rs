//! End-to-end: `tessera bench rays DIR` reads the ray files and `rays.json` that
//! `bench/peers/embree_rays.py` writes, casts each set as its query says, and holds its hit
//! fractions to the file's. Embree is not needed: the test writes the files itself, for a
//! mesh whose hits it knows (a square of two triangles), with made-up Embree rates. A
//! wrong hit fraction fails the run; bad files get a one-line error. (The rates are not
//! checked: a benchmark is not a test, but it must keep working.)

mod common;

use common::*;
use std::path::Path;
use std::time::Duration;

/// The square [-1, 1]² at z = 0, as two triangles.
const SQUARE: &str = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n";

/// Rays as embree_rays.py writes them: origin, direction, t_max, little-endian f32.
fn write_rays(path: &Path, rays: &[[f32; 7]]) {
    let bytes: Vec<u8> = rays.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

/// A folder with the square, a closest-hit set (rays down onto a 4×4 area, a quarter of
/// them over the square) and an any-hit set (rays down from z = 1 whose t_max stops half
/// of them short of it), and a rays.json that gives each set `fractions`.
fn rays_dir(fractions: (f64, f64)) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("square.obj"), SQUARE).unwrap();
    let mut down = Vec::new();
    for i in 0..20 {
        for j in 0..20 {
            // Cell centres, so that no ray runs along an edge of the square.
            let (x, y) = (-2.0 + 0.2 * (i as f32 + 0.5), -2.0 + 0.2 * (j as f32 + 0.5));
            down.push([x, y, 2.0, 0.0, 0.0, -1.0, f32::INFINITY]);
        }
    }
    write_rays(&dir.path().join("down.rays"), &down);
    let shadow: Vec<[f32; 7]> = (0..100)
        .map(|k| [0.01 * k as f32 - 0.5, 0.25, 1.0, 0.0, 0.0, -1.0, if k % 2 == 0 { 0.5 } else { 2.0 }])
        .collect();
    write_rays(&dir.path().join("shadow.rays"), &shadow);
    let json = format!(
        r#"{{"mesh": {mesh:?}, "triangles": 2, "camera": "-", "sets": {{
  "camera": {{"file": "down.rays", "query": "closest", "rays": 400, "hit_fraction": {},
              "mrays_per_s_1t": 1.5, "mrays_per_s_2t": 3.0}},
  "random": {{"file": "down.rays", "query": "closest", "rays": 400, "hit_fraction": {},
              "mrays_per_s_1t": 1.5, "mrays_per_s_2t": 3.0}},
  "shadow": {{"file": "shadow.rays", "query": "any", "rays": 100, "hit_fraction": {},
              "mrays_per_s_1t": 2.5, "mrays_per_s_2t": 5.0}}}}}}"#,
        fractions.0,
        fractions.0,
        fractions.1,
        mesh = dir.path().join("square.obj").to_str().unwrap(),
    );
    std::fs::write(dir.path().join("rays.json"), json).unwrap();
    dir
}

fn bench(dir: &Path, extra: &[&str]) -> (bool, String, String) {
    let mut args = vec!["bench", "rays", dir.to_str().unwrap()];
    if !extra.contains(&"--repeats") {
        args.extend(["--repeats", "1"]);
    }
    args.extend_from_slice(extra);
    let out = run_with_timeout(&args, Duration::from_secs(60));
    let text = |b: &[u8]| String::from_utf8_lossy(b).to_string();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

#[test]
fn the_rays_benchmark_casts_each_set_and_checks_its_hit_fraction() {
    let dir = rays_dir((0.25, 0.5));
    let (ok, stdout, stderr) = bench(dir.path(), &[]);
    assert!(ok, "{stdout}\n{stderr}");
    let row = |set: &str| {
        stdout
            .lines()
            .find(|l| l.starts_with(set))
            .unwrap_or_else(|| panic!("no {set} row:\n{stdout}"))
            .to_string()
    };
    // The camera set takes the camera rays' walk, the others the other one: the same hits.
    for set in ["camera", "random"] {
        let row = row(set);
        let cells: Vec<&str> = row.split_whitespace().collect();
        // set, query, rays, hits, Embree's, 1t, Embree's, 2t, Embree's, 1t completed.
        assert_eq!(&cells[..5], [set, "closest", "400", "0.2500", "0.2500"], "{stdout}");
        assert_eq!(cells[6], "1.50", "{stdout}");
        assert!(cells[9].parse::<f64>().is_ok_and(|r| r > 0.0), "a completed-hit rate: {stdout}");
    }
    let shadow: Vec<String> = row("shadow").split_whitespace().map(str::to_string).collect();
    assert_eq!(&shadow[..6], ["shadow", "any", "hit", "100", "0.5000", "0.5000"], "{stdout}");
    assert_eq!(shadow.last().map(String::as_str), Some("-"), "no completed rate for any-hit rays: {stdout}");

    // --mesh names another mesh: the same rays miss a square moved away, and the
    // fractions no longer match Embree's.
    let moved = dir.path().join("moved.obj");
    std::fs::write(&moved, SQUARE.replace(" 0\n", " 5\n")).unwrap();
    let (ok, stdout, stderr) = bench(dir.path(), &["--mesh", moved.to_str().unwrap()]);
    assert!(!ok, "{stdout}");
    assert!(stdout.contains("<- hit fraction differs"), "{stdout}");
    assert!(stderr.contains("hit fractions differ from Embree's"), "{stderr}");
}

#[test]
fn the_rays_benchmark_refuses_bad_files_in_one_line() {
    let check = |dir: &Path, extra: &[&str], needle: &str| {
        let (ok, stdout, stderr) = bench(dir, extra);
        assert!(!ok, "{stdout}");
        assert!(stderr.contains(needle), "wanted {needle:?}:\n{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    };
    let dir = rays_dir((0.25, 0.5));
    // A ray file cut short.
    let bytes = std::fs::read(dir.path().join("down.rays")).unwrap();
    std::fs::write(dir.path().join("down.rays"), &bytes[..bytes.len() - 3]).unwrap();
    check(dir.path(), &[], "not a whole number of 28-byte rays");
    // Fewer rays than rays.json says.
    std::fs::write(dir.path().join("down.rays"), &bytes[..28 * 399]).unwrap();
    check(dir.path(), &[], "399 rays, rays.json says 400");
    // More rays than rays.json says: refused before it is read.
    std::fs::write(dir.path().join("down.rays"), [&bytes[..], &bytes[..28]].concat()).unwrap();
    check(dir.path(), &[], "11228 bytes, more than the 400 rays rays.json says");
    // A direction that is not of unit length.
    let mut long = bytes.clone();
    long[5 * 4..6 * 4].copy_from_slice(&(-3.0f32).to_le_bytes());
    std::fs::write(dir.path().join("down.rays"), &long).unwrap();
    check(dir.path(), &[], "ray 0 has a non-finite origin or a direction not of unit length");
    std::fs::write(dir.path().join("down.rays"), &bytes).unwrap();
    // Another mesh than the rays were made for.
    let three = dir.path().join("three.obj");
    std::fs::write(&three, format!("{SQUARE}v 0 0 1\nf 1 2 5\n")).unwrap();
    check(dir.path(), &["--mesh", three.to_str().unwrap()], "3 triangles, rays.json says 2");
    // Not the script's rays.json, and none at all.
    std::fs::write(dir.path().join("rays.json"), "{\"sets\": 3}").unwrap();
    check(dir.path(), &[], "not the rays.json of embree_rays.py");
    let empty = tempfile::tempdir().unwrap();
    check(empty.path(), &[], "reading");
    // A query the script does not write, and more repeats than a benchmark needs.
    let dir = rays_dir((0.25, 0.5));
    let json = std::fs::read_to_string(dir.path().join("rays.json")).unwrap();
    std::fs::write(dir.path().join("rays.json"), json.replace("\"any\"", "\"all\"")).unwrap();
    check(dir.path(), &[], "has query \"all\"");
    check(dir.path(), &["--repeats", "1000000000"], "--repeats");
    // The tests' build has no `ab` switch (worker/src/ab.rs): both sides would be A.
    check(dir.path(), &["--ab"], "--ab needs a build with the switch");
}
