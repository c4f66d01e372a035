//! `tessera bench`: benchmarks that print figures, compared as ratios measured in one run.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use glam::UVec2;
use tessera_description::bundle::Bundle;
use tessera_worker::batch::{render_batch, Sums};
use tessera_worker::build::parse_bundle;
use tessera_worker::render::sampler::MOST_PLANNED;

mod ab;
mod audit;
mod checkpoint;
mod convergence;
mod farm;
mod font;
mod load;
mod overhead;
mod plot;
mod rays;
mod reference;
mod rows;
mod samples;
mod submit;
mod viewers;

/// The benchmarks.
#[derive(Debug, clap::Subcommand)]
#[deny(missing_docs)]
pub enum BenchCommand {
    /// Pay for what you use: a scene with none of Cook's effects (classic spheres, planes,
    /// point lights) through the full renderer against a minimal Whitted tracer, one
    /// thread each, same rays; prints the throughput ratio and the images' difference.
    Whitted {
        /// A Whitted scene [default: scenes/whitted.toml].
        #[arg(default_value = "scenes/whitted.toml")]
        scene: PathBuf,
        /// Runs of each, alternating (the fastest is reported) [default: 3].
        #[arg(long, default_value_t = 3)]
        runs: usize,
    },
    /// What viewers cost: wall time with 0, 8, and 8 viewers of which one never reads, as
    /// ratios, and the coordinator's peak memory in each case.
    Viewers {
        /// The scene [default: scenes/whitted.toml].
        #[arg(default_value = "scenes/whitted.toml")]
        scene: PathBuf,
        /// Samples per pixel [default: the scene's].
        #[arg(long)]
        spp: Option<u32>,
        /// Runs of each case (the fastest is reported) [default: 2].
        #[arg(long, default_value_t = 2)]
        runs: usize,
    },
    /// What durability costs: snapshot, write and take-up times of a half-done job's
    /// checkpoint at 640x480, 1920x1080 and 3840x2160.
    Checkpoint {
        /// The scene [default: scenes/whitted.toml].
        #[arg(default_value = "scenes/whitted.toml")]
        scene: PathBuf,
        /// Samples per pixel [default: 16].
        #[arg(long, default_value_t = 16)]
        spp: u32,
        /// Runs of each (the fastest is reported) [default: 3].
        #[arg(long, default_value_t = 3)]
        runs: usize,
    },
    /// The trade of speed against accuracy: the scene at 1, 4, 16, … spp with each sampler
    /// (independent, stratified, Sobol) and as a job in rounds stops (the first samples of
    /// the largest pattern: Cook's, and the one rounds draw), each run's time and error
    /// (RMSE, relative MSE, PSNR) against a high-sample render; writes a table, a CSV and a
    /// log-log plot.
    Convergence {
        /// The scene file.
        scene: PathBuf,
        /// Image size WIDTHxHEIGHT [default: the scene's].
        #[arg(long, value_parser = crate::parse_size)]
        size: Option<(u32, u32)>,
        /// The top of the ladder 1, 4, 16, … [default: 256].
        #[arg(long, default_value_t = 256)]
        max_spp: u32,
        /// Samples per pixel of the reference [default: 16 × --max-spp].
        #[arg(long)]
        reference_spp: Option<u32>,
        /// A reference image (EXR, linear) instead of rendering one.
        #[arg(long)]
        reference: Option<PathBuf>,
        /// Where to write the figures [default: docs/accuracy/SCENE].
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// The preview, measured: its error against the final image after 1 %, 5 %, 25 % and
    /// 100 % of pass one, for the paper's order, the sequential quadrant order it rejects,
    /// and scanline order; writes a table, a plot and the preview images.
    Preview {
        /// The scene file.
        scene: PathBuf,
        /// Image size WIDTHxHEIGHT [default: the scene's].
        #[arg(long, value_parser = crate::parse_size)]
        size: Option<(u32, u32)>,
        /// Where to write the figures [default: docs/accuracy/SCENE].
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Halt conditions, measured: for each time budget, the error reached with pass two in
    /// even rounds, with adaptive sampling to a noise target in the same budget, and by the
    /// paper's single pass two given the same samples.
    Halt {
        /// The scene file.
        scene: PathBuf,
        /// Image size WIDTHxHEIGHT [default: the scene's].
        #[arg(long, value_parser = crate::parse_size)]
        size: Option<(u32, u32)>,
        /// Time budgets in seconds, comma-separated [default: 2,8].
        #[arg(long, value_delimiter = ',', default_value = "2,8")]
        budgets: Vec<f64>,
        /// The adaptive runs' noise target [default: 0.01].
        #[arg(long, default_value_t = 0.01)]
        noise: f32,
        /// Also runs adaptive sampling to this absolute noise target (`tessera render
        /// --noise-abs`) in each budget.
        #[arg(long)]
        noise_abs: Option<f32>,
        /// The paper's pass two: samples per pixel of a finished pixel, the quality a
        /// final render would ask for [default: 1024].
        #[arg(long, default_value_t = 1024)]
        paper_spp: u32,
        /// Samples per pixel of the reference [default: 1024].
        #[arg(long, default_value_t = 1024)]
        reference_spp: u32,
    },
    /// The coordinator under load: simulated workers (valid sums without rendering, a set
    /// batch time) and viewers against a coordinator process on loopback; prints commits
    /// per second, the coordinator's CPU per batch and per viewer update, lease-grant and
    /// merge latencies and bytes per viewer, for each size × workers × viewers.
    Farm(farm::FarmOptions),
    /// A huge scene submitted while another client polls Status: submit time, Status
    /// latency during it, client-side validation time and the coordinator's peak memory.
    Submit {
        /// Triangles of the one OBJ mesh [default: 500000].
        #[arg(long, default_value_t = 500_000)]
        triangles: usize,
        /// `[[mesh]]` entries using it, each placed differently [default: 24].
        #[arg(long, default_value_t = 24)]
        meshes: usize,
    },
    /// Auditing workers bit for bit, on the pure farm: batches a lying worker (doubling
    /// its sums, or zeroing one batch in fifty) delivers before quarantine, the extra
    /// batches audits render, and the repaired image against a clean one.
    Audit {
        /// Seeded trials per liar [default: 200].
        #[arg(long, default_value_t = 200)]
        trials: usize,
        /// Share of batches audited [default: 0.03].
        #[arg(long, default_value_t = tessera_coordinator::farm::DEFAULT_AUDIT_FRACTION)]
        audit_fraction: f64,
    },
    /// The BVH at scale: build time and traversal speed for meshes of 10k to 1M triangles.
    Bvh {
        /// The largest triangle count [default: 1000000].
        #[arg(long, default_value_t = 1_000_000)]
        triangles: usize,
    },
    /// Ray casting against Embree's on the same rays: reads the ray files and rays.json that
    /// `bench/peers/embree_rays.py --out DIR` writes, casts each set (closest
    /// or any hit as the file says), checks the hit fractions match Embree's within 1e-3
    /// and prints Mrays/s with 1 and 2 threads beside Embree's.
    Rays {
        /// The folder the script wrote.
        dir: PathBuf,
        /// The mesh [default: the one rays.json names].
        #[arg(long)]
        mesh: Option<PathBuf>,
        /// Runs of each set and thread count (the median is reported) [default: 3].
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Time a change against the code it replaces instead, in this process: each set on
        /// one thread in chunks of 20 000 rays, each chunk with the switch off (A) and on
        /// (B), `repeats` rounds. Needs a build with `--features ab` (worker/src/ab.rs).
        #[arg(long)]
        ab: bool,
    },
    /// A worker's load of a scene, step by step (OBJ read and parsed, validation,
    /// primitives, BVH build, slots), in wall and CPU seconds per run, and the medians.
    Load {
        /// The scene file.
        scene: PathBuf,
        /// Runs [default: 5].
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Threads [default: one per core].
        #[arg(long)]
        threads: Option<usize>,
    },
    /// The tracer alone: the scene rendered in this process (no farm, no image written),
    /// samples per second per run and their median, and a checksum of the image's sums that
    /// differs when two builds' images do. `--threads 1` runs the same instructions every
    /// time (for callgrind).
    Samples {
        /// The scene file.
        scene: PathBuf,
        /// Samples per pixel [default: the scene's].
        #[arg(long)]
        spp: Option<u32>,
        /// Image size WIDTHxHEIGHT [default: the scene's].
        #[arg(long, value_parser = crate::parse_size)]
        size: Option<(u32, u32)>,
        /// Threads [default: one per core].
        #[arg(long)]
        threads: Option<usize>,
        /// Runs (the median is reported) [default: 3].
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Time a change against the code it replaces instead, in this process: the image
        /// a row at a time on one thread, each row with the switch off (A) and on (B), `runs`
        /// rounds. Needs a build with `--features ab` (worker/src/ab.rs).
        #[arg(long)]
        ab: bool,
    },
    /// The farm's overhead: `tessera render` with local workers against the same image
    /// loaded and traced in one process on the same cores, as a ratio (and against the
    /// one process's render alone), and the time to the first full-frame preview.
    Overhead {
        /// The scene file.
        scene: PathBuf,
        /// Runs of each (the median is reported) [default: 3].
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Samples per pixel [default: the scene's].
        #[arg(long)]
        spp: Option<u32>,
        /// Image size WIDTHxHEIGHT [default: the scene's].
        #[arg(long, value_parser = crate::parse_size)]
        size: Option<(u32, u32)>,
        /// Local worker processes [default: 1, as `tessera render`].
        #[arg(long)]
        workers: Option<usize>,
    },
}

/// The scene limits a render would refuse past, refused before a benchmark starts (the
/// one-process side of `bench overhead` would otherwise trace them before the farm side
/// got to say no).
fn check_spp_and_size(spp: Option<u32>, size: Option<(u32, u32)>) -> Result<()> {
    use tessera_description::limits::{MAX_PIXELS, MAX_SIDE, MAX_SPP};
    if let Some(s) = spp.filter(|&s| s == 0 || s > MAX_SPP) {
        anyhow::bail!("--spp {s}: 1 to {MAX_SPP}");
    }
    if let Some((w, h)) =
        size.filter(|&(w, h)| w.max(h) > MAX_SIDE || u64::from(w) * u64::from(h) > MAX_PIXELS)
    {
        anyhow::bail!("--size {w}x{h}: at most {MAX_SIDE} a side and {MAX_PIXELS} pixels");
    }
    Ok(())
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// Runs a benchmark.
pub async fn run(cmd: BenchCommand) -> Result<ExitCode> {
    match cmd {
        BenchCommand::Whitted { scene, runs } => whitted(&scene, runs.max(1)),
        BenchCommand::Bvh { triangles } => bvh(triangles),
        BenchCommand::Audit { trials, audit_fraction } => {
            audit::run(trials, audit_fraction)?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Rays { dir, mesh, repeats, ab } => {
            if repeats > 1000 {
                anyhow::bail!("--repeats {repeats}: at most 1000");
            }
            if ab {
                ab::require_switch()?;
            }
            rays::run(&dir, mesh.as_deref(), repeats.max(1), ab)
        }
        BenchCommand::Load { scene, runs, threads } => load::run(&scene, runs.max(1), threads),
        BenchCommand::Samples { scene, spp, size, threads, runs, ab } => {
            if spp == Some(0) || threads == Some(0) || runs == 0 {
                anyhow::bail!("--spp, --threads and --runs must be at least 1");
            }
            // A benchmark's runs and threads, not a stress test: bounded so that a typo
            // cannot ask for a billion threads or runs.
            if runs > 1000 || threads.is_some_and(|t| t > 1024) {
                anyhow::bail!("--runs at most 1000 and --threads at most 1024");
            }
            check_spp_and_size(spp, size)?;
            let threads = threads.unwrap_or_else(crate::cores);
            if ab {
                ab::require_switch()?;
                samples::run_ab(&scene, spp, size, runs)?;
                return Ok(ExitCode::SUCCESS);
            }
            samples::run(&scene, &samples::SamplesOptions { spp, size, threads, runs })?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Farm(opts) => {
            if opts.spp < 2 || opts.credit == 0 || opts.workers.contains(&0) {
                anyhow::bail!("--spp must be at least 2, --credit and every --workers at least 1");
            }
            farm::run(opts).await?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Submit { triangles, meshes } => {
            if triangles == 0 || meshes == 0 {
                anyhow::bail!("--triangles and --meshes must be at least 1");
            }
            submit::run(submit::SubmitOptions { triangles, meshes }).await?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Convergence { scene, size, max_spp, reference_spp, reference, out } => {
            if max_spp == 0 {
                anyhow::bail!("--max-spp must be at least 1");
            }
            let reference_spp = reference_spp.unwrap_or(max_spp.saturating_mul(16)).clamp(1, 1 << 20);
            let out = out.unwrap_or_else(|| convergence::default_out(&scene));
            convergence::convergence(&scene, size, max_spp, reference_spp, reference.as_deref(), &out)?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Halt { scene, size, budgets, noise, noise_abs, paper_spp, reference_spp } => {
            if budgets.iter().any(|b| !(b.is_finite() && *b > 0.0)) || budgets.is_empty() {
                anyhow::bail!("--budgets must be positive numbers of seconds");
            }
            if paper_spp < 2 || reference_spp == 0 {
                anyhow::bail!("--paper-spp must be at least 2 and --reference-spp at least 1");
            }
            use tessera_description::Noise;
            let mut targets = vec![Noise::Relative(noise)];
            targets.extend(noise_abs.map(Noise::Absolute));
            for t in &targets {
                t.checked().map_err(|e| anyhow::anyhow!("--noise/--noise-abs: {e}"))?;
            }
            convergence::halt(&scene, size, &budgets, &targets, paper_spp, reference_spp).await?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Preview { scene, size, out } => {
            let out = out.unwrap_or_else(|| convergence::default_out(&scene));
            convergence::preview(&scene, size, &out)?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Checkpoint { scene, spp, runs } => {
            checkpoint::run(&scene, spp.max(2), runs.max(1))?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Viewers { scene, spp, runs } => {
            viewers::run(&scene, spp, runs.max(1)).await?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Overhead { scene, runs, spp, size, workers } => {
            overhead::run(&scene, runs, spp, size, workers).await?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn whitted(path: &std::path::Path, runs: usize) -> Result<ExitCode> {
    let scene = parse_bundle(&Bundle::read(path)?)?;
    let reference = reference::Whitted::new(&scene).ok_or_else(|| {
        anyhow!(
            "{} is not a plain Whitted scene (classic spheres and planes, point lights only)",
            path.display()
        )
    })?;
    let (w, h, n) = (scene.width, scene.height, scene.spp);
    let pixels: Vec<UVec2> = (0..h).flat_map(|y| (0..w).map(move |x| UVec2::new(x, y))).collect();
    let (mut full, mut plain) = (Duration::MAX, Duration::MAX);
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for _ in 0..runs {
        let t = Instant::now();
        a = render_batch(&scene, &pixels, 0..n, Sums::Radiance).sums;
        full = full.min(t.elapsed());
        let t = Instant::now();
        let mut sampler = scene.sampler();
        b = pixels
            .iter()
            .flat_map(|&p| {
                let mut acc = [0u64; 3];
                for i in 0..n {
                    // Planned as `render_batch` plans, so that the two differ by their
                    // integrators only.
                    if i % MOST_PLANNED == 0 {
                        sampler.plan_pixel(p, i..n.min(i.saturating_add(MOST_PLANNED)));
                    }
                    let l = reference.sample(&mut sampler, p, i);
                    for (c, v) in acc.iter_mut().zip([l.x, l.y, l.z]) {
                        *c += tessera_film::fixed::to_fixed(v).unwrap_or(0);
                    }
                }
                acc
            })
            .collect();
        plain = plain.min(t.elapsed());
    }
    let samples = (pixels.len() as u64 * u64::from(n)) as f64;
    let max_diff = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (tessera_film::fixed::mean(*x, n) - tessera_film::fixed::mean(*y, n)).abs())
        .fold(0.0f32, f32::max);
    println!("scene {} ({w}x{h}, {n} spp), one thread, fastest of {runs}", path.display());
    println!(
        "full renderer (BVH, Cook's integrator): {:.3} s ({})",
        full.as_secs_f64(),
        crate::report::rate(samples / full.as_secs_f64())
    );
    println!(
        "minimal Whitted tracer:                 {:.3} s ({})",
        plain.as_secs_f64(),
        crate::report::rate(samples / plain.as_secs_f64())
    );
    println!("time ratio full / minimal: {:.3}", full.as_secs_f64() / plain.as_secs_f64());
    println!("largest pixel difference: {max_diff:.2e} (same rays, same shading)");
    Ok(ExitCode::SUCCESS)
}

fn bvh(max: usize) -> Result<ExitCode> {
    use tessera_worker::render::bvh::Bvh;
    use tessera_worker::render::geometry::Ray;
    use tessera_worker::render::shape::Mesh;
    println!("{:>10} {:>10} {:>12} {:>14}", "triangles", "build s", "Mrays/s", "tris/ray");
    let mut n = 10_000usize;
    loop {
        let n_now = n.min(max);
        // A bumpy sphere: triangles of every orientation and size, like a scanned model.
        let rings = ((n_now / 2) as f64).sqrt().ceil() as u32;
        let mut mesh = Mesh::default();
        for i in 0..=rings {
            for j in 0..=rings {
                let (th, ph) = (
                    std::f32::consts::PI * i as f32 / rings as f32,
                    2.0 * std::f32::consts::PI * j as f32 / rings as f32,
                );
                // libm's, as the renderer's: the benchmark mesh is the same on every machine.
                use tessera_description::math::{cos, sin};
                let r = 1.0 + 0.05 * sin(7.0 * th) * cos(5.0 * ph);
                mesh.p.push(glam::Vec3::new(sin(th) * cos(ph), cos(th), sin(th) * sin(ph)) * r);
            }
        }
        let idx = |i: u32, j: u32| [i * (rings + 1) + j, u32::MAX, u32::MAX];
        for i in 0..rings {
            for j in 0..rings {
                mesh.tris.push([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)]);
                mesh.tris.push([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]);
            }
        }
        let bounds: Vec<_> = (0..mesh.tris.len() as u32)
            .map(|t| {
                let c = mesh.tris[t as usize];
                tessera_worker::render::bvh::Aabb::from_points(c.iter().map(|k| mesh.p[k[0] as usize]))
            })
            .collect();
        let t = Instant::now();
        let bvh = Bvh::build(&bounds);
        let build = t.elapsed();
        let rays = 200_000u32;
        let t = Instant::now();
        let mut hits = 0u32;
        let mut visits = 0u64;
        for k in 0..rays {
            let h = tessera_worker::render::sampler::hash_words(&[u64::from(k)]);
            let (a, b) = ((h >> 40) as f32 / 16_777_216.0, ((h >> 16) & 0xff_ffff) as f32 / 16_777_216.0);
            let dir = glam::Vec3::new(a - 0.5, b - 0.5, -1.0).normalize();
            let ray = Ray::new(glam::Vec3::new(0.0, 0.0, 3.0), dir);
            let t_hit = bvh.traverse(&ray, f32::INFINITY, |i, t_max| {
                visits += 1;
                mesh.intersect(i, &ray, t_max).map(|h| h.t)
            });
            hits += u32::from(t_hit.is_finite());
        }
        let secs = t.elapsed().as_secs_f64();
        println!(
            "{:>10} {:>10.3} {:>12.2} {:>14.1}",
            mesh.tris.len(),
            build.as_secs_f64(),
            f64::from(rays) / secs / 1e6,
            visits as f64 / f64::from(rays)
        );
        std::hint::black_box(hits);
        if n_now >= max {
            break;
        }
        n *= 10;
    }
    println!("(tris/ray counts triangle tests per ray: it stays flat as N grows, as a BVH's should)");
    Ok(ExitCode::SUCCESS)
}
