//! `tessera bench overhead`: the farm's cost, as `tessera render` with local workers against
//! the same image rendered in one process on the same cores. Both sides read and build the
//! scene inside their clocks (a one-process renderer loads it too); the figure against the
//! render alone, the one process's load left out, is printed beside it.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use glam::UVec2;
use tessera_description::bundle::Bundle;
use tessera_worker::batch::{render_batch, Sums};
use tessera_worker::build::parse_bundle;
use tessera_worker::render::Scene;

use super::rows::rows_in_parallel;
use super::{check_spp_and_size, median};
use crate::local::{render_local, LocalOptions};

/// Runs the benchmark: `runs` of each side, alternating.
pub async fn run(
    scene: &Path,
    runs: usize,
    spp: Option<u32>,
    size: Option<(u32, u32)>,
    workers: Option<usize>,
) -> Result<()> {
    if runs == 0 || runs > 1000 {
        anyhow::bail!("--runs must be 1 to 1000");
    }
    check_spp_and_size(spp, size)?;
    let cores = crate::cores();
    let workers = crate::local::local_workers(workers)?;
    let threads = (cores / workers).max(1);
    // The scene as a one-process renderer reads it: from the file, on the same cores.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(cores).build().map_err(|e| anyhow!(e))?;
    let load = || -> Result<Scene> {
        let bundle = Bundle::read(scene)?;
        let mut parsed = pool.install(|| parse_bundle(&bundle))?;
        // As the farm side applies them: the same image on both sides.
        parsed.apply(spp, size);
        Ok(parsed)
    };
    let (mut loads, mut single, mut farm, mut preview) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    // Every run loads the same image; its sample count, for the rates.
    let mut samples = 0;
    for run in 0..runs {
        // Alternate, so that drifting machine load hits both alike. The one process
        // loads the scene inside its clock, as the farm's worker does: the load is
        // the renderer's cost, not the farm's (it is also shown apart).
        let t = Instant::now();
        let parsed = load()?;
        loads.push(t.elapsed());
        let (w, h, n) = (parsed.width, parsed.height, parsed.spp);
        if run == 0 {
            println!(
                "scene {} ({w}x{h}, {n} spp), {cores} cores; farm: {workers} workers x {threads} threads",
                scene.display()
            );
        }
        samples = u64::from(w) * u64::from(h) * u64::from(n);
        let rows: Vec<u64> = pool.install(|| {
            rows_in_parallel(h, |y| {
                let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, y)).collect();
                render_batch(&parsed, &pixels, 0..n, Sums::Radiance).sums.iter().sum::<u64>()
            })
        });
        std::hint::black_box(rows);
        single.push(t.elapsed());
        drop(parsed);
        let r = render_local(
            scene,
            LocalOptions {
                workers,
                threads,
                spp,
                size,
                time_limit: None,
                noise: None,
                noise_min: None,
                layers: Default::default(),
                frames: None,
                progress_bar: false,
                view: false,
                output: None,
                // Measure the farm as `tessera render` runs it, checkpoints included.
                checkpoints: Some(crate::local::Checkpoints {
                    dir: std::env::temp_dir().join(format!("tessera-bench-{}-{run}", std::process::id())),
                    interval: Duration::from_secs(30),
                    resume: false,
                }),
            },
        )
        .await?;
        farm.push(r.wall);
        preview.push(r.first_preview.unwrap_or(r.wall));
        println!(
            "run {}: one process {:.3} s (its load {:.3} s), farm {:.3} s, first preview {:.1} ms",
            run + 1,
            single[run].as_secs_f64(),
            loads[run].as_secs_f64(),
            farm[run].as_secs_f64(),
            preview[run].as_secs_f64() * 1e3
        );
    }
    let secs = |d: Duration| d.as_secs_f64();
    let rendering: Vec<Duration> = single.iter().zip(&loads).map(|(s, l)| *s - *l).collect();
    // The minimum is the run least disturbed by other load on a shared machine; the
    // median shows what a typical run costs.
    let fastest = |v: &[Duration]| *v.iter().min().unwrap();
    let min_ratio = secs(fastest(&farm)) / secs(fastest(&single));
    let min_render_ratio = secs(fastest(&farm)) / secs(fastest(&rendering));
    let (s, l, r, f, p) = (median(single), median(loads), median(rendering), median(farm), median(preview));
    println!(
        "median one process:   {:.3} s ({}), of which the load {:.3} s",
        secs(s),
        crate::report::rate(samples as f64 / secs(s)),
        secs(l)
    );
    println!("median farm:          {:.3} s ({})", secs(f), crate::report::rate(samples as f64 / secs(f)));
    println!(
        "farm overhead:        {:+.1} % (medians), {:+.1} % (fastest runs)",
        (secs(f) / secs(s) - 1.0) * 100.0,
        (min_ratio - 1.0) * 100.0
    );
    println!(
        "  against the render alone (the load left out of the one process, not of the farm): {:+.1} % (medians), {:+.1} % (fastest)",
        (secs(f) / secs(r) - 1.0) * 100.0,
        (min_render_ratio - 1.0) * 100.0
    );
    println!(
        "first full-frame preview: {:.1} ms after start (workers spawned, scene sent, first batch back)",
        p.as_secs_f64() * 1e3
    );
    Ok(())
}
