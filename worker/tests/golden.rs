//! Golden-image regression tests: every scene in `scenes/`, rendered tiny, against a stored
//! PNG with a tolerance. Regenerate with `UPDATE_GOLDEN=1 cargo test -p tessera-worker
//! --test golden` and review the diff of the images before committing them.

use std::path::{Path, PathBuf};

use glam::UVec2;
use tessera_description::bundle::Bundle;
use tessera_description::math;
use tessera_film::fixed;
use tessera_worker::batch::{render_batch, Sums};
use tessera_worker::render::sampler::hash_words;
use tessera_worker::render::{SamplerKind, Scene};

const SIZE: (u32, u32) = (64, 40);
const SPP: u32 = 8;

fn srgb8(v: f32) -> u8 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * math::powf(v, 1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}

fn render_tiny(path: &Path) -> Vec<u8> {
    render_tiny_as(path, |_| {})
}

/// [`render_tiny`], the scene changed by `adjust` after the job's settings.
fn render_tiny_as(path: &Path, adjust: impl Fn(&mut Scene)) -> Vec<u8> {
    let bundle = Bundle::read(path).unwrap();
    let mut scene = tessera_worker::build::parse_bundle(&bundle).unwrap_or_else(|e| panic!("{e}"));
    scene.apply(Some(SPP), Some(SIZE));
    adjust(&mut scene);
    let (w, h) = SIZE;
    let mut out = Vec::with_capacity((w * h * 3) as usize);
    for row in 0..h {
        let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, h - 1 - row)).collect();
        let sums = render_batch(&scene, &pixels, 0..SPP, Sums::Radiance);
        out.extend(sums.sums.iter().map(|&s| srgb8(fixed::mean(s, SPP))));
    }
    out
}

fn scenes() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        // Not a seeded copy another tool renders beside a scene (bench/peers, scripts/).
        .filter(|p| !p.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')))
        .collect();
    v.sort();
    v
}

#[test]
fn every_scene_matches_its_golden_image() {
    let update = std::env::var_os("UPDATE_GOLDEN").is_some();
    let golden_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    let mut failures = Vec::new();
    let all = scenes();
    assert!(all.len() >= 10, "expected the scenes of scenes/, found {all:?}");
    for scene in all {
        let name = scene.file_stem().unwrap().to_string_lossy().to_string();
        let got = render_tiny(&scene);
        let golden = golden_dir.join(format!("{name}.png"));
        if update {
            image::RgbImage::from_raw(SIZE.0, SIZE.1, got).unwrap().save(&golden).unwrap();
            continue;
        }
        let want = image::open(&golden)
            .unwrap_or_else(|e| panic!("{}: {e} (run with UPDATE_GOLDEN=1 to create it)", golden.display()))
            .to_rgb8()
            .into_raw();
        // Tolerance for floating-point differences between machines: the mean error stays
        // under half a level, and few values move by more than 8 levels.
        let diffs: Vec<i32> =
            got.iter().zip(&want).map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs()).collect();
        let mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
        let large = diffs.iter().filter(|&&d| d > 8).count() as f64 / diffs.len() as f64;
        if mean > 0.5 || large > 0.01 {
            failures.push(format!(
                "{name}: mean error {mean:.3} levels, {:.2}% values off by > 8",
                large * 100.0
            ));
        }
    }
    assert!(failures.is_empty(), "golden images differ:\n{}", failures.join("\n"));
}

/// The renderer version and the images it makes, recorded together: the hash of the tiny
/// renders of every scene (their 8-bit values, in the scenes' order), and of the Cornell
/// box's drawn from the other patterns: the first samples of a job in rounds (a pattern
/// of 2^20 drawn in prefixes), Sobol's and independent samples. When they change,
/// `RENDERER_VERSION`'s image count must rise with them (workers of the two builds would
/// otherwise join one farm and mix their images), and both are recorded here anew. A
/// change may also raise the count where these tiny renders stay the same and larger ones
/// do not (`images.6` and `images.7`: the hash was `images.5`'s). A scene added to
/// `scenes/` changes the hash and no image of the renderer's (`sky.toml`, with
/// `images.7`): the count stays.
const IMAGES: (&str, u64) = ("0.1.0+images.8", 0xaeef_36b3_025c_e653);

#[test]
fn the_renderer_version_names_its_images() {
    let mut h = 0u64;
    let cornell = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell.toml");
    type Adjust = fn(&mut Scene);
    let patterns: [(&str, Adjust); 3] = [
        ("cornell in rounds", |s| (s.spp, s.progressive) = (1 << 20, true)),
        ("cornell sobol", |s| s.sampler = SamplerKind::Sobol),
        ("cornell independent", |s| s.sampler = SamplerKind::Independent),
    ];
    let renders = scenes()
        .into_iter()
        .map(|scene| (scene.file_stem().unwrap().to_string_lossy().to_string(), render_tiny(&scene)))
        .chain(patterns.map(|(name, adjust)| (name.to_string(), render_tiny_as(&cornell, adjust))));
    for (name, image) in renders {
        h = hash_words(&[h, name.len() as u64]);
        for chunk in name.as_bytes().chunks(8).chain(image.chunks(8)) {
            h = hash_words(&[h, chunk.iter().fold(0u64, |w, &b| (w << 8) | u64::from(b))]);
        }
    }
    assert_eq!(
        (tessera_worker::RENDERER_VERSION, h),
        IMAGES,
        "the renders and the version no longer match: if the images changed, raise the \
         +images.N of RENDERER_VERSION (description/src/lib.rs) and record both here"
    );
}
