//! `tessera bench samples`: the tracer alone, as samples per second. The image is rendered
//! in this process by the worker's own batch function, a row per task, with no farm, no
//! image written and no process started, so that a change to the renderer is measured by
//! itself; and with `--threads 1` it runs the same instructions every time, which makes it
//! the run to give `valgrind --tool=callgrind` when the machine is too noisy for seconds.
//! A checksum of every pixel's fixed-point sums tells two builds' images apart: equal
//! checksums, the same bits (the determinism contract makes them comparable across builds,
//! thread counts and machines).

use std::path::Path;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use glam::UVec2;
use tessera_description::bundle::Bundle;
use tessera_worker::batch::{render_batch, Sums};
use tessera_worker::build::parse_bundle;
use tessera_worker::render::sampler::hash_words;

use super::rows::rows_in_parallel;

/// What to render and how often.
#[derive(Debug, Clone)]
pub struct SamplesOptions {
    pub spp: Option<u32>,
    pub size: Option<(u32, u32)>,
    pub threads: usize,
    pub runs: usize,
}

/// `--ab`: the scene's image a row at a time on this thread, each row with the switch off
/// and on, `rounds` times (`ab.rs`); a row's answer is the hash of its sums.
pub fn run_ab(scene_path: &Path, spp: Option<u32>, size: Option<(u32, u32)>, rounds: usize) -> Result<()> {
    let bundle = Bundle::read(scene_path)?;
    let mut scene = parse_bundle(&bundle).with_context(|| format!("building {}", scene_path.display()))?;
    scene.apply(spp, size);
    let (w, h, spp) = (scene.width, scene.height, scene.spp);
    println!("scene {} ({w}x{h}, {spp} spp), one thread, A against B a row at a time", scene_path.display());
    let r = super::ab::interleave_timed(h as usize, rounds, |y, _| {
        let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, y as u32)).collect();
        hash_words(&render_batch(&scene, &pixels, 0..spp, Sums::Radiance).sums)
    });
    println!("{}", r.line());
    Ok(())
}

/// Renders the scene `runs` times and prints each run's rate, the median and the checksum.
pub fn run(scene_path: &Path, opts: &SamplesOptions) -> Result<()> {
    let bundle = Bundle::read(scene_path)?;
    let mut scene = parse_bundle(&bundle).with_context(|| format!("building {}", scene_path.display()))?;
    scene.apply(opts.spp, opts.size);
    let (w, h, spp) = (scene.width, scene.height, scene.spp);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(opts.threads).build().map_err(|e| anyhow!(e))?;
    let threads = pool.current_num_threads();
    println!("scene {} ({w}x{h}, {spp} spp), {threads} threads, one process", scene_path.display());
    let samples = f64::from(w) * f64::from(h) * f64::from(spp);
    let mut times = Vec::new();
    let mut checksum = None;
    for run in 0..opts.runs {
        let start = Instant::now();
        let rows: Vec<(u64, u64)> = pool.install(|| {
            rows_in_parallel(h, |y| {
                let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, y)).collect();
                let b = render_batch(&scene, &pixels, 0..spp, Sums::Radiance);
                (hash_words(&b.sums), b.nonfinite)
            })
        });
        let elapsed = start.elapsed();
        // Rows in order: the same checksum on any number of threads.
        let sum = hash_words(&rows.iter().map(|r| r.0).collect::<Vec<_>>());
        let nonfinite: u64 = rows.iter().map(|r| r.1).sum();
        if checksum.is_some_and(|c| c != sum) {
            anyhow::bail!("run {} gave another image than run 1: the renderer is not deterministic", run + 1);
        }
        checksum = Some(sum);
        println!(
            "run {}: {:.3} s, {:.3} Msamples/s{}",
            run + 1,
            elapsed.as_secs_f64(),
            samples / elapsed.as_secs_f64() / 1e6,
            if nonfinite > 0 { format!(" ({nonfinite} non-finite samples dropped)") } else { String::new() }
        );
        times.push(elapsed);
    }
    let median = super::median(times);
    println!(
        "median {:.3} s, {:.3} Msamples/s, {:.3} Msamples/s per thread; image checksum {:016x}",
        median.as_secs_f64(),
        samples / median.as_secs_f64() / 1e6,
        samples / median.as_secs_f64() / 1e6 / threads as f64,
        checksum.unwrap_or_default()
    );
    Ok(())
}
