//! `tessera bench convergence` and `tessera bench preview`: the trade of speed against
//! accuracy, measured. Renders run in this process on every core (the farm adds only its
//! small overhead, measured by `bench overhead`; the time-budget runs use a local worker
//! per core, one thread each, as `tessera render` did by default when they were measured),
//! and every error is against a
//! high-sample render of the same scene by the same renderer, so that the renderer's own
//! bias does not hide its convergence.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::UVec2;
use tessera_description::bundle::Bundle;
use tessera_film::fixed;
use tessera_film::quadtree::{fifo_walk_in, ChildOrder};
use tessera_worker::batch::{render_batch, Sums};
use tessera_worker::build::parse_bundle;
use tessera_worker::render::{SamplerKind, Scene};

use super::plot::{write_png, Plot, Series};
use super::rows::rows_in_parallel;
use crate::compare::errors;

/// Renders samples `samples` of every pixel; linear RGB, top row first.
pub fn render_image(scene: &Scene, samples: std::ops::Range<u32>) -> Vec<f32> {
    let (w, h) = (scene.width, scene.height);
    let n = samples.end - samples.start;
    let rows: Vec<Vec<f32>> = rows_in_parallel(h, |row| {
        let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, h - 1 - row)).collect();
        let r = render_batch(scene, &pixels, samples.clone(), Sums::Radiance);
        r.sums.iter().map(|&s| fixed::mean(s, n)).collect()
    });
    rows.concat()
}

fn load(scene: &Path, size: Option<(u32, u32)>) -> Result<Scene> {
    let mut s = parse_bundle(&Bundle::read(scene)?)?;
    s.apply(None, size);
    Ok(s)
}

/// The reference: from `file` (EXR, linear) if given, else rendered at `spp` with the
/// stratified sampler and a seed of its own, so that no run shares its noise.
fn reference(scene: &Scene, spp: u32, file: Option<&Path>) -> Result<Vec<f32>> {
    if let Some(f) = file {
        let (w, h, rgb) = crate::compare::read_linear(f)?;
        if (w, h) != (scene.width, scene.height) {
            bail!("reference {} is {w}x{h}, the render {}x{}", f.display(), scene.width, scene.height);
        }
        return Ok(rgb);
    }
    let mut r = scene.clone();
    r.spp = spp;
    r.sampler = SamplerKind::Stratified;
    r.seed = scene.seed ^ 0x0005_eed0_f4ef;
    let t = Instant::now();
    let rgb = render_image(&r, 0..spp);
    println!("reference: {spp} spp in {:.1} s", t.elapsed().as_secs_f64());
    Ok(rgb)
}

/// `tessera bench convergence`.
pub fn convergence(
    scene_path: &Path,
    size: Option<(u32, u32)>,
    max_spp: u32,
    reference_spp: u32,
    reference_file: Option<&Path>,
    out: &Path,
) -> Result<()> {
    let scene = load(scene_path, size)?;
    let (w, h) = (scene.width, scene.height);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    println!(
        "scene {} at {w}x{h}, {} threads; errors against a {reference_spp}-spp render",
        scene_path.display(),
        rayon::current_num_threads()
    );
    let reference = reference(&scene, reference_spp, reference_file)?;
    let ladder: Vec<u32> =
        std::iter::successors(Some(1u32), |s| s.checked_mul(4)).take_while(|&s| s <= max_spp).collect();
    let mut csv = String::from("sampler,spp,seconds,rmse,relmse,psnr\n");
    let mut table = String::from(
        "| sampler | spp | time (s) | RMSE | relMSE | PSNR (dB) |\n| --- | --- | --- | --- | --- | --- |\n",
    );
    let mut series = Vec::new();
    // Each sampler drawn whole (the pattern's size is the sample count), then two runs that
    // draw the first `spp` samples of a pattern of the most a pixel may take, as a job in
    // rounds stops: Cook's strata as such jobs drew them before, and the pattern they draw
    // now (`Scene::progressive`: Sobol's, in a nested order).
    // (label, sampler, a prefix of the largest pattern, drawn as a job in rounds)
    let runs = [
        (SamplerKind::Independent.name(), SamplerKind::Independent, false, false),
        (SamplerKind::Stratified.name(), SamplerKind::Stratified, false, false),
        (SamplerKind::Sobol.name(), SamplerKind::Sobol, false, false),
        ("stratified, a prefix", SamplerKind::Stratified, true, false),
        ("in rounds", SamplerKind::Stratified, true, true),
    ];
    for (label, kind, prefix, progressive) in runs {
        let mut points = Vec::new();
        for &spp in &ladder {
            let mut s = scene.clone();
            s.spp = if prefix { tessera_description::limits::MAX_SPP } else { spp };
            s.sampler = kind;
            s.progressive = progressive;
            let t = Instant::now();
            let rgb = render_image(&s, 0..spp);
            let seconds = t.elapsed().as_secs_f64();
            let e = errors(w, h, &rgb, &reference);
            println!(
                "{label:>20} {spp:>6} spp {seconds:>8.3} s  rmse {:.5}  relmse {:.5}  psnr {:.2} dB",
                e.rmse, e.relmse, e.psnr
            );
            csv.push_str(&format!(
                "{},{spp},{seconds:.4},{:.6},{:.6},{:.3}\n",
                label.replace(',', ""),
                e.rmse,
                e.relmse,
                e.psnr
            ));
            table.push_str(&format!(
                "| {label} | {spp} | {seconds:.3} | {:.5} | {:.5} | {:.2} |\n",
                e.rmse, e.relmse, e.psnr
            ));
            points.push((seconds, e.rmse));
        }
        series.push(Series { name: label.to_string(), points });
    }
    let name = scene_path.file_stem().map_or("scene".into(), |s| s.to_string_lossy().into_owned());
    std::fs::write(out.join("convergence.csv"), csv)?;
    std::fs::write(out.join("convergence.md"), &table)?;
    let plot = Plot {
        title: format!("{name} {w}x{h}: RMSE against time, 1 to {max_spp} spp"),
        x_label: "render time (s)".into(),
        y_label: "RMSE".into(),
        log_x: true,
        log_y: true,
        series,
    };
    write_png(&plot, &out.join("convergence.png"))?;
    println!("\n{table}\nwrote {}/convergence.{{png,csv,md}}", out.display());
    Ok(())
}

/// The preview after `k` computed pixels of `order`: each computed pixel paints the block
/// it stands for (finer blocks come later and paint over coarser ones); the rest is black.
fn mosaic_preview(
    w: u32,
    h: u32,
    order: &[tessera_film::quadtree::Quad],
    k: usize,
    first: &[f32],
) -> Vec<f32> {
    let mut img = vec![0.0f32; (w * h * 3) as usize];
    for q in &order[..k] {
        let src = (((h - 1 - q.y) * w + q.x) * 3) as usize;
        let c = [first[src], first[src + 1], first[src + 2]];
        for y in q.y..q.y + q.h {
            for x in q.x..q.x + q.w {
                let i = (((h - 1 - y) * w + x) * 3) as usize;
                img[i..i + 3].copy_from_slice(&c);
            }
        }
    }
    img
}

/// `tessera bench preview`.
pub fn preview(scene_path: &Path, size: Option<(u32, u32)>, out: &Path) -> Result<()> {
    let scene = load(scene_path, size)?;
    let (w, h) = (scene.width, scene.height);
    let n = (w * h) as usize;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    // Pass one computes sample 0 of every pixel's pattern; the final image has them all.
    // Errors of what a display shows: both images clamped to [0, 1], so that a few
    // fireflies of the one-sample image do not drown the preview's structure.
    let clamp = |v: Vec<f32>| -> Vec<f32> { v.into_iter().map(|x| x.clamp(0.0, 1.0)).collect() };
    let first = clamp(render_image(&scene, 0..1));
    let t = Instant::now();
    let last = clamp(render_image(&scene, 0..scene.spp));
    println!(
        "scene {} at {w}x{h}, final image {} spp ({:.1} s); errors of the preview against it",
        scene_path.display(),
        scene.spp,
        t.elapsed().as_secs_f64()
    );
    let paper = fifo_walk_in(w, h, ChildOrder::Paper).0;
    let sequential = fifo_walk_in(w, h, ChildOrder::Sequential).0;
    // Scanline: the top row first, left to right, one pixel each (its own 1×1 block).
    let scanline: Vec<_> = (0..h)
        .rev()
        .flat_map(|y| (0..w).map(move |x| tessera_film::quadtree::Quad { x, y, w: 1, h: 1 }))
        .collect();
    let orders = [("paper", &paper), ("sequential", &sequential), ("scanline", &scanline)];
    let fractions = [0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0];
    let mut table =
        String::from("| order | 1 % | 5 % | 25 % | 100 % of pass one |\n| --- | --- | --- | --- | --- |\n");
    let mut series = Vec::new();
    for (name, order) in orders {
        let mut points = Vec::new();
        let mut row = format!("| {name} |");
        for &f in &fractions {
            let k = ((n as f64 * f).round() as usize).clamp(1, n);
            let img = mosaic_preview(w, h, order, k, &first);
            let e = errors(w, h, &img, &last);
            points.push((f * 100.0, e.rmse));
            if [0.01, 0.05, 0.25, 1.0].contains(&f) {
                row.push_str(&format!(" {:.4} |", e.rmse));
                let file = out.join(format!("preview-{name}-{:03}.png", (f * 100.0) as u32));
                tessera_film::output::write_image(&file, w, h, &img)?;
            }
        }
        table.push_str(&row);
        table.push('\n');
        series.push(Series { name: name.to_string(), points });
    }
    let name = scene_path.file_stem().map_or("scene".into(), |s| s.to_string_lossy().into_owned());
    std::fs::write(out.join("preview.md"), &table)?;
    let plot = Plot {
        title: format!("{name} {w}x{h}: preview RMSE against the final image (clamped to 0..1)"),
        x_label: "% of pass one computed".into(),
        y_label: "RMSE".into(),
        log_x: true,
        log_y: true,
        series,
    };
    write_png(&plot, &out.join("preview.png"))?;
    println!("\n{table}\nwrote {}/preview.{{png,md}} and preview images", out.display());
    Ok(())
}

/// Where a scene's figures go by default: `docs/accuracy/NAME`.
pub fn default_out(scene: &Path) -> PathBuf {
    let name = scene.file_stem().map_or("scene".into(), |s| s.to_string_lossy().into_owned());
    PathBuf::from("docs/accuracy").join(name)
}

/// `tessera bench halt`: for each time budget, the error reached by the farm with pass two
/// in even rounds, with adaptive sampling to each noise target within the same budget, and by
/// the paper's single pass two given the same number of samples (its walk-ordered pass two
/// stopped where those samples run out: the first pixels finished, the rest at 1 spp).
pub async fn halt(
    scene_path: &Path,
    size: Option<(u32, u32)>,
    budgets: &[f64],
    targets: &[tessera_description::Noise],
    paper_spp: u32,
    reference_spp: u32,
) -> Result<()> {
    use crate::local::{render_local, LocalOptions};
    let scene = load(scene_path, size)?;
    let (w, h) = (scene.width, scene.height);
    let n = f64::from(w) * f64::from(h);
    let cores = crate::cores();
    println!(
        "scene {} at {w}x{h}, {cores} cores, farm of {cores} local workers; errors against a {reference_spp}-spp render",
        scene_path.display()
    );
    let reference = reference(&scene, reference_spp, None)?;
    // The paper's pass two at `paper_spp`: each pixel either finished or at its first sample.
    let mut paper = scene.clone();
    paper.spp = paper_spp;
    let full = render_image(&paper, 0..paper_spp);
    let first = render_image(&paper, 0..1);
    let walk = fifo_walk_in(w, h, ChildOrder::Paper).0;
    let dir = std::env::temp_dir().join(format!("tessera-bench-halt-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut table = String::from(
        "| budget | method | samples per pixel | RMSE | relMSE |\n| --- | --- | --- | --- | --- |\n",
    );
    for &budget in budgets {
        let mut uniform_spp = 0.0;
        let runs = std::iter::once(("rounds, uniform", None))
            .chain(targets.iter().map(|&t| ("rounds, adaptive", Some(t))));
        for (name, adaptive) in runs {
            let out = dir.join("halt.exr");
            let r = render_local(
                scene_path,
                LocalOptions {
                    workers: cores,
                    threads: 1,
                    spp: Some(1 << 20),
                    size,
                    time_limit: Some(std::time::Duration::from_secs_f64(budget)),
                    noise: adaptive,
                    noise_min: None,
                    layers: Default::default(),
                    frames: None,
                    progress_bar: false,
                    view: false,
                    output: Some(out.clone()),
                    checkpoints: None,
                },
            )
            .await?;
            let (_, _, rgb) = crate::compare::read_linear(&out)?;
            let e = errors(w, h, &rgb, &reference);
            let spp = r.progress.samples_done as f64 / n;
            if adaptive.is_none() {
                uniform_spp = spp;
            }
            let ended = match r.progress.halted {
                Some(why) => format!("{why}, {:.1} s", r.progress.elapsed.as_secs_f64()),
                None => format!("spp cap, {:.1} s", r.progress.elapsed.as_secs_f64()),
            };
            let label = match adaptive {
                Some(t) => format!("{name} (noise {t}; ended by {ended})"),
                None => format!("{name} (ended by {ended})"),
            };
            println!("{budget:>6} s  {label:<58} {spp:>8.1} spp  rmse {:.5}  relmse {:.5}", e.rmse, e.relmse);
            table.push_str(&format!(
                "| {budget} s | {label} | {spp:.1} | {:.5} | {:.5} |\n",
                e.rmse, e.relmse
            ));
        }
        // The paper's single pass two with the uniform run's samples.
        let finished = (((uniform_spp - 1.0) * n) / f64::from(paper_spp - 1)).clamp(0.0, n) as usize;
        let mut img = first.clone();
        for q in &walk[..finished.min(walk.len())] {
            let i = (((h - 1 - q.y) * w + q.x) * 3) as usize;
            img[i..i + 3].copy_from_slice(&full[i..i + 3]);
        }
        let e = errors(w, h, &img, &reference);
        let label = format!("paper's pass two at {paper_spp} spp, same samples");
        println!(
            "{budget:>6} s  {label:<30} {uniform_spp:>8.1} spp  rmse {:.5}  relmse {:.5}  ({finished} of {} pixels finished)",
            e.rmse,
            e.relmse,
            walk.len()
        );
        table.push_str(&format!(
            "| {budget} s | {label} | {uniform_spp:.1} | {:.5} | {:.5} |\n",
            e.rmse, e.relmse
        ));
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!("\n{table}");
    Ok(())
}
