//! `tessera bench`: benchmarks that print figures, compared as ratios measured in one run.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use glam::UVec2;
use rayon::prelude::*;
use tessera_worker::batch::render_batch;
use tessera_worker::bundle::Bundle;

use crate::local::{render_local, LocalOptions};

/// The benchmarks.
#[derive(Debug, clap::Subcommand)]
#[deny(missing_docs)]
pub enum BenchCommand {
    /// The farm's overhead: `tessera render` with local workers against the same image
    /// traced in one process on the same cores, as a ratio, and the time to the first
    /// full-frame preview.
    Overhead {
        /// The scene file.
        scene: PathBuf,
        /// Runs of each (the median is reported) [default: 3].
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Samples per pixel [default: the scene's].
        #[arg(long)]
        spp: Option<u32>,
        /// Local worker processes [default: one per core].
        #[arg(long)]
        workers: Option<usize>,
    },
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// Runs a benchmark.
pub async fn run(cmd: BenchCommand) -> Result<ExitCode> {
    match cmd {
        BenchCommand::Overhead { scene, runs, spp, workers } => {
            if runs == 0 {
                anyhow::bail!("--runs must be at least 1");
            }
            let cores = crate::cores();
            let workers = workers.unwrap_or(cores).max(1);
            let threads = (cores / workers).max(1);
            let bundle = Bundle::read(&scene)?;
            let mut parsed = bundle.parse()?;
            if let Some(s) = spp {
                parsed.spp = s;
            }
            let pool = rayon::ThreadPoolBuilder::new().num_threads(cores).build().map_err(|e| anyhow!(e))?;
            let (w, h, n) = (parsed.width, parsed.height, parsed.spp);
            println!(
                "scene {} ({w}x{h}, {n} spp), {cores} cores; farm: {workers} workers x {threads} threads",
                scene.display()
            );
            let (mut single, mut farm, mut preview) = (Vec::new(), Vec::new(), Vec::new());
            for run in 0..runs {
                // Alternate, so that drifting machine load hits both alike.
                let t = Instant::now();
                let rows: Vec<u64> = pool.install(|| {
                    (0..h)
                        .into_par_iter()
                        .map(|y| {
                            let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, y)).collect();
                            render_batch(&parsed, &pixels, 0..n).sums.iter().sum::<u64>()
                        })
                        .collect()
                });
                std::hint::black_box(rows);
                single.push(t.elapsed());
                let r = render_local(
                    &scene,
                    LocalOptions { workers, threads, spp, size: None, progress_bar: false },
                )
                .await?;
                farm.push(r.wall);
                preview.push(r.first_preview.unwrap_or(r.wall));
                println!(
                    "run {}: one process {:.3} s, farm {:.3} s, first preview {:.1} ms",
                    run + 1,
                    single[run].as_secs_f64(),
                    farm[run].as_secs_f64(),
                    preview[run].as_secs_f64() * 1e3
                );
            }
            // The minimum is the run least disturbed by other load on a shared machine; the
            // median shows what a typical run costs.
            let min_ratio =
                farm.iter().min().unwrap().as_secs_f64() / single.iter().min().unwrap().as_secs_f64();
            let (s, f, p) = (median(single), median(farm), median(preview));
            let samples = u64::from(w) * u64::from(h) * u64::from(n);
            println!(
                "median one process:   {:.3} s ({})",
                s.as_secs_f64(),
                crate::local::rate(samples as f64 / s.as_secs_f64())
            );
            println!(
                "median farm:          {:.3} s ({})",
                f.as_secs_f64(),
                crate::local::rate(samples as f64 / f.as_secs_f64())
            );
            println!(
                "farm overhead:        {:+.1} % (medians), {:+.1} % (fastest runs)",
                (f.as_secs_f64() / s.as_secs_f64() - 1.0) * 100.0,
                (min_ratio - 1.0) * 100.0
            );
            println!("first full-frame preview: {:.1} ms after start (workers spawned, scene sent, first batch back)", p.as_secs_f64() * 1e3);
            Ok(ExitCode::SUCCESS)
        }
    }
}
