//! `tessera bench farm`: the coordinator under load. A real coordinator process on
//! loopback, simulated workers (the harness's `FakeWorker`: valid sums without rendering,
//! each batch answered after a simulated render time) and viewers (`FakeViewer`, counting
//! only). For each image size, worker count and viewer count it prints commits per
//! second, the coordinator's CPU per batch and per viewer update, lease-grant and merge
//! latencies, and what each viewer receives; then the ratios the targets are stated in.

use std::process::Stdio;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use tessera_harness::{FakeViewer, FakeWorker, ServeStats, REFERENCE_BATCH_SAMPLES, SMALL_SCENE};
use tessera_proto::v1 as pb;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tokio::task::JoinHandle;

/// The longest pass one is waited for before a case is measured anyway.
const WARM_UP_LIMIT: Duration = Duration::from_secs(15);

/// What to measure: `tessera bench farm`'s options.
#[derive(Debug, Clone, clap::Args)]
#[deny(missing_docs)]
pub struct FarmOptions {
    /// Image sizes WIDTHxHEIGHT, comma-separated [default: 1920x1080,3840x2160].
    #[arg(long, value_delimiter = ',', value_parser = crate::parse_size, default_value = "1920x1080,3840x2160")]
    pub sizes: Vec<(u32, u32)>,
    /// Worker counts, comma-separated [default: 16,64,256].
    #[arg(long, value_delimiter = ',', default_value = "16,64,256")]
    pub workers: Vec<usize>,
    /// Viewer counts, comma-separated; a 0 among them gives the others their baseline
    /// [default: 0,10,100].
    #[arg(long, value_delimiter = ',', default_value = "0,10,100")]
    pub viewers: Vec<usize>,
    /// Seconds measured per case, after pass one [default: 2].
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// Simulated render times of a pass-two batch (32768 samples) in ms, comma-separated;
    /// 0 answers at once and finds the coordinator's ceiling [default: 20,0].
    #[arg(long, value_delimiter = ',', default_value = "20,0")]
    pub batch_ms: Vec<f64>,
    /// The coordinator's `--batch-time` in ms, the time it paces pass-two batches to at
    /// each worker's measured speed; without it each case uses its --batch-ms (at least 5),
    /// so that fake workers get batches of 32768 samples, as with fixed sizes.
    #[arg(long)]
    pub batch_time: Option<f64>,
    /// Samples per pixel of the job: pass two's batches are 32768 / (spp - 1) pixels
    /// at the default batch time [default: 1024].
    #[arg(long, default_value_t = 1024)]
    pub spp: u32,
    /// Credit each fake worker keeps (a real worker keeps 2 per thread) [default: 2].
    #[arg(long, default_value_t = 2)]
    pub credit: u32,
    /// Updates per second each viewer asks for [default: 10, the coordinator's].
    #[arg(long, default_value_t = 10.0)]
    pub viewer_rate: f64,
    /// Viewers keep exact replicas (the web dashboard's kind) instead of reading
    /// previews while the job renders (`tessera view`'s kind).
    #[arg(long)]
    pub exact_viewers: bool,
    /// Rounds of each size and worker count: every round measures all the viewer counts
    /// (in reverse order every other round, so that drift falls on both sides), and the
    /// ratios to the 0-viewer row are taken within a round, then summarised by their
    /// median [default: 1].
    #[arg(long, default_value_t = 1)]
    pub rounds: usize,
}

/// One case's figures.
#[derive(Debug, Clone, Default)]
struct Figures {
    commits_per_s: f64,
    /// Coordinator CPU seconds over the window.
    cpu: f64,
    commits: u64,
    /// Complete viewer updates (versions) over the window, all viewers.
    updates: u64,
    lease_ms: Option<(f64, f64)>,
    merge_ms: Option<(f64, f64)>,
    updates_per_viewer_s: (f64, f64),
    bytes_per_viewer_s: f64,
    simulated_worker_cpu: f64,
    bench_cpu: f64,
    window: f64,
    /// Seconds from the submission (workers connecting) to the end of pass one.
    warm: f64,
    note: &'static str,
}

/// Clock ticks per second of /proc's CPU times: asked of `getconf CLK_TCK`, else the
/// Linux default of 100 (this crate forbids the `unsafe` a `sysconf` call needs).
fn clock_ticks() -> f64 {
    std::process::Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.trim().parse::<f64>().ok())
        .filter(|&t| t > 0.0)
        .unwrap_or(100.0)
}

/// utime + stime of a process, in clock ticks (fields 14 and 15 of /proc/PID/stat,
/// counted after the command name, which may itself hold spaces and parentheses).
fn cpu_ticks(pid: &str) -> Result<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).context("reading /proc/PID/stat")?;
    let rest = stat.rsplit_once(')').ok_or_else(|| anyhow!("unexpected /proc/{pid}/stat"))?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let get = |i: usize| fields.get(i).and_then(|f| f.parse::<u64>().ok()).ok_or_else(|| anyhow!("bad stat"));
    Ok(get(11)? + get(12)?)
}

fn percentiles(mut v: Vec<u64>) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    v.sort_unstable();
    let at = |q: usize| v[(v.len() * q / 100).min(v.len() - 1)] as f64 / 1e3;
    Some((at(50), at(99)))
}

/// A coordinator process on a free loopback port, its log drained; killed when dropped.
pub(super) async fn start_coordinator(args: &[String]) -> Result<(Child, String)> {
    let mut child = Command::new(std::env::current_exe()?)
        .args(["coordinator", "--listen", "127.0.0.1:0"])
        .args(args)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .context("starting the coordinator")?;
    let mut lines = BufReader::new(child.stderr.take().expect("piped")).lines();
    let url = tokio::time::timeout(Duration::from_secs(20), async {
        loop {
            let line = lines.next_line().await?.ok_or_else(|| anyhow!("the coordinator exited"))?;
            if let Some(addr) = line.split("listening on ").nth(1) {
                return Ok::<_, anyhow::Error>(format!("http://{}", addr.trim()));
            }
        }
    })
    .await
    .map_err(|_| anyhow!("the coordinator did not start listening"))??;
    // Drained, so that its log never blocks it.
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    Ok((child, url))
}

/// Per viewer: complete updates and bytes received while measuring.
#[derive(Default)]
struct ViewerCount {
    updates: AtomicU64,
    bytes: AtomicU64,
}

#[allow(clippy::too_many_arguments)]
async fn case(
    opts: &FarmOptions,
    (width, height): (u32, u32),
    workers: usize,
    viewers: usize,
    batch_ms: f64,
    ticks: f64,
) -> Result<Figures> {
    // The batch time the coordinator paces to (seconds; it refuses below 5 ms).
    let pace_ms = opts.batch_time.unwrap_or(batch_ms).max(5.0);
    let (mut coord, url) = start_coordinator(&["--batch-time".into(), (pace_ms / 1e3).to_string()]).await?;
    let pid = coord.id().ok_or_else(|| anyhow!("the coordinator has no pid"))?.to_string();
    let channel = tessera_harness::connect(&url).await?;
    let settings = pb::RenderSettings { spp: opts.spp, width, height, ..Default::default() };
    let job = tessera_harness::submit(&channel, "small.toml", SMALL_SCENE, settings).await?;
    let stats = Arc::new(ServeStats::new(viewers > 0));
    let mut tasks: Vec<JoinHandle<()>> = Vec::new();
    // Viewers watch from the submission on, as a viewer of a render does: they receive
    // pass one as it comes, not one snapshot of it.
    let merge_micros = Arc::new(Mutex::new(Vec::new()));
    let mut counts = Vec::new();
    for v in 0..viewers {
        let ch = tessera_harness::connect(&url).await?;
        let mut viewer = if opts.exact_viewers {
            FakeViewer::watch(&ch, job.0, opts.viewer_rate, false).await?
        } else {
            FakeViewer::watch_previews(&ch, job.0, opts.viewer_rate, false).await?
        };
        let count = Arc::new(ViewerCount::default());
        counts.push(count.clone());
        let (stats, merge_micros) = (stats.clone(), merge_micros.clone());
        tasks.push(tokio::spawn(async move {
            let _ch = ch;
            loop {
                let before = viewer.bytes;
                let Ok(Some(u)) = viewer.next().await else { return };
                if !stats.measuring() {
                    continue;
                }
                count.updates.fetch_add(u64::from(u.chunk_end), Ordering::Relaxed);
                count.bytes.fetch_add(viewer.bytes - before, Ordering::Relaxed);
                // The first viewer times merges: when it first sees the first pixel of a
                // pass-two batch with more than its pass-one sample, or a preview block
                // painted over it.
                if v == 0 {
                    let now = Instant::now();
                    let mut sent = stats.sent.lock().unwrap_or_else(|e| e.into_inner());
                    let mut lat = merge_micros.lock().unwrap_or_else(|e| e.into_inner());
                    let n = u64::from(u.width) * u64::from(u.height);
                    let Ok(pixels) = tessera_proto::convert::pixels_from_wire(&u.pixels, n) else { return };
                    for p in pixels.filter(|p| p.count > 1) {
                        if let Some(t) = sent.remove(&(job.0, p.index % width, p.index / width)) {
                            lat.push(now.duration_since(t).as_micros() as u64);
                        }
                    }
                    if !u.reset {
                        let Ok(blocks) =
                            tessera_proto::preview::preview_from_wire(&u.preview, u.width, u.height)
                        else {
                            return;
                        };
                        for b in &blocks {
                            let painted = painted_blocks(b);
                            let (gw, _) = tessera_film::preview::grid(u.width, u.height, b.shift);
                            sent.retain(|&(j, x, y), t| {
                                let hit =
                                    j == job.0 && painted.contains(&((y >> b.shift) * gw + (x >> b.shift)));
                                if hit {
                                    lat.push(now.duration_since(*t).as_micros() as u64);
                                }
                                !hit
                            });
                        }
                    }
                }
            }
        }));
    }
    let batch_time = Duration::from_secs_f64(batch_ms / 1e3);
    for i in 0..workers {
        // A connection each, as separate worker processes have; all at once, so that a
        // coordinator slow to welcome them (many viewers) delays the case once, not once
        // per worker. One that cannot connect in time is missing from the count below.
        let (url, stats, credit) = (url.clone(), stats.clone(), opts.credit);
        tasks.push(tokio::spawn(async move {
            let Ok(ch) = tessera_harness::connect(&url).await else { return };
            let Ok(w) = FakeWorker::connect(&ch, &format!("fake-{i}"), credit).await else { return };
            let _ = w.serve(batch_time, stats).await;
        }));
    }
    // Warm-up: every worker connected and pass one done (its batches are cut small, then
    // doubling, and say little about a running job), then half a second of pass two.
    let mut note = "";
    let warm = Instant::now();
    loop {
        let s = tessera_harness::status(&channel).await?;
        let j = s.jobs.iter().find(|j| j.id == job).ok_or_else(|| anyhow!("{job} missing from Status"))?;
        if s.workers.len() >= workers && j.pass_one_done >= u64::from(width) * u64::from(height) {
            break;
        }
        if j.state.is_over() {
            bail!("the job ended during the warm-up: {:?}", j.state);
        }
        // Bounded, so that a case the coordinator cannot keep up with (many viewers of a
        // large image) still ends: it is then measured in pass one, and says so.
        if warm.elapsed() > WARM_UP_LIMIT {
            note = if s.workers.len() < workers { " (not all connected)" } else { " (in pass 1)" };
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let warm = warm.elapsed().as_secs_f64();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let done = |s: &tessera_harness::FarmStatus| s.workers.iter().map(|w| w.batches_done).sum::<u64>();
    // Commits and CPU are taken between the two Status answers (a loaded coordinator may
    // answer late), the viewers' and workers' counts while `measuring` is set.
    let d0 = done(&tessera_harness::status(&channel).await?);
    let (c0, b0, t0) = (cpu_ticks(&pid)?, cpu_ticks("self")?, Instant::now());
    stats.set_measuring(true);
    tokio::time::sleep(Duration::from_secs_f64(opts.seconds)).await;
    stats.set_measuring(false);
    let window = t0.elapsed().as_secs_f64();
    let status = tessera_harness::status(&channel).await?;
    let (c1, b1, d1) = (cpu_ticks(&pid)?, cpu_ticks("self")?, done(&status));
    let span = t0.elapsed().as_secs_f64();
    if status.jobs.iter().any(|j| j.id == job && j.state.is_over()) {
        note = " (job ended)";
    }
    for t in &tasks {
        t.abort();
    }
    let _ = coord.kill().await;
    let commits = d1.saturating_sub(d0);
    let per_viewer: Vec<(f64, f64)> = counts
        .iter()
        .map(|c| {
            (
                c.updates.load(Ordering::Relaxed) as f64 / window,
                c.bytes.load(Ordering::Relaxed) as f64 / window,
            )
        })
        .collect();
    let n = per_viewer.len().max(1) as f64;
    let lease = std::mem::take(&mut *stats.lease_micros.lock().unwrap_or_else(|e| e.into_inner()));
    let merge = std::mem::take(&mut *merge_micros.lock().unwrap_or_else(|e| e.into_inner()));
    Ok(Figures {
        commits_per_s: commits as f64 / span,
        cpu: c1.saturating_sub(c0) as f64 / ticks,
        commits,
        updates: counts.iter().map(|c| c.updates.load(Ordering::Relaxed)).sum(),
        lease_ms: percentiles(lease),
        merge_ms: percentiles(merge),
        updates_per_viewer_s: (
            per_viewer.iter().map(|p| p.0).sum::<f64>() / n,
            per_viewer.iter().map(|p| p.0).fold(f64::INFINITY, f64::min),
        ),
        bytes_per_viewer_s: per_viewer.iter().map(|p| p.1).sum::<f64>() / n,
        simulated_worker_cpu: stats.simulated_micros.load(Ordering::Relaxed) as f64 / 1e6,
        bench_cpu: b1.saturating_sub(b0) as f64 / ticks,
        window: span,
        warm,
        note,
    })
}

/// One real pass-two batch of the benchmark scene rendered on one thread: what a batch
/// of `REFERENCE_BATCH_SAMPLES` samples costs a worker with this (trivial) scene.
fn real_batch_time(spp: u32) -> Result<Duration> {
    let bundle = tessera_description::bundle::Bundle {
        name: "small.toml".into(),
        text: SMALL_SCENE.into(),
        assets: vec![],
        refused: vec![],
    };
    let scene = tessera_worker::build::parse_bundle(&bundle)?;
    let per_pixel = u64::from(spp.max(2) - 1);
    let pixels = (REFERENCE_BATCH_SAMPLES / per_pixel).max(1) as u32;
    let pixels: Vec<glam::UVec2> =
        (0..pixels).map(|i| glam::UVec2::new(i % scene.width, i / scene.width)).collect();
    let t = Instant::now();
    std::hint::black_box(tessera_worker::batch::render_batch(
        &scene,
        &pixels,
        1..spp.max(2),
        tessera_worker::batch::Sums::Radiance,
    ));
    Ok(t.elapsed())
}

/// The block indices a preview group paints.
fn painted_blocks(b: &tessera_film::preview::Blocks) -> std::collections::HashSet<u32> {
    b.runs.iter().flat_map(|&(first, count)| first..first + count).collect()
}

fn ms(v: Option<(f64, f64)>) -> String {
    v.map_or("-".into(), |(a, b)| format!("{a:.2}/{b:.2}"))
}

/// Runs the benchmark and prints its table.
pub async fn run(opts: FarmOptions) -> Result<()> {
    if opts.seconds <= 0.0 || !opts.seconds.is_finite() {
        bail!("--seconds must be positive");
    }
    if opts.rounds == 0 {
        bail!("--rounds must be at least 1");
    }
    if opts.batch_ms.iter().any(|b| !(b.is_finite() && *b >= 0.0)) {
        bail!("--batch-ms must be non-negative milliseconds");
    }
    if opts.batch_time.is_some_and(|b| !(5.0..=60_000.0).contains(&b)) {
        bail!("--batch-time must be between 5 and 60000 ms");
    }
    let ticks = clock_ticks();
    let real = real_batch_time(opts.spp)?;
    println!(
        "coordinator: a child process on loopback, pacing pass-two batches to {}; fake workers: 1 thread, credit \
         {}, a pass-two batch of {} samples answered after --batch-ms (other sizes in proportion); {} spp; {:.1} s \
         measured per case after pass one; viewers ask for {} updates/s and read {}",
        match opts.batch_time {
            Some(ms) => format!("{ms} ms"),
            None => "each case's --batch-ms (at least 5 ms)".into(),
        },
        opts.credit,
        REFERENCE_BATCH_SAMPLES,
        opts.spp,
        opts.seconds,
        opts.viewer_rate,
        if opts.exact_viewers { "exact pixel states (--exact-viewers)" } else { "previews" }
    );
    println!(
        "for scale: one real pass-two batch ({} samples) of the trivial test scene takes {:.2} ms on one thread \
         here; {} cores; CPU from /proc/PID/stat at {ticks} ticks/s",
        REFERENCE_BATCH_SAMPLES,
        real.as_secs_f64() * 1e3,
        crate::cores()
    );
    println!(
        "{:>9} {:>4} {:>4} {:>5} {:>9} {:>6} {:>8} {:>8} {:>11} {:>13} {:>11} {:>9} {:>7} {:>7} {:>6} {:>6}",
        "size",
        "wrk",
        "view",
        "b.ms",
        "commit/s",
        "crd%",
        "us/batch",
        "us/upd",
        "lease p50/99",
        "merge p50/99",
        "upd/s avg/mn",
        "KB/s/view",
        "crd/wrk",
        "vs 0 v.",
        "bench%",
        "pass1s"
    );
    let mut worst_ratio: f64 = 0.0;
    let mut peak: f64 = 0.0;
    let mut viewer_drop: Vec<ViewerCost> = Vec::new();
    for &batch_ms in &opts.batch_ms {
        for &size in &opts.sizes {
            for &workers in &opts.workers {
                for round in 0..opts.rounds {
                    // Measured first, printed in the given order: a row's baseline is the
                    // 0-viewer case of the same round, whenever it ran.
                    let mut order: Vec<usize> = (0..opts.viewers.len()).collect();
                    if round % 2 == 1 {
                        order.reverse();
                    }
                    let mut measured: Vec<Option<Figures>> = vec![None; opts.viewers.len()];
                    for i in order {
                        measured[i] =
                            Some(case(&opts, size, workers, opts.viewers[i], batch_ms, ticks).await?);
                    }
                    let round_baseline =
                        opts.viewers.iter().position(|&v| v == 0).and_then(|i| measured[i].clone());
                    for (i, (&viewers, f)) in opts.viewers.iter().zip(measured).enumerate() {
                        let f = f.expect("every viewer count was measured");
                        let baseline = round_baseline.as_ref().filter(|_| viewers > 0);
                        let per_batch = f.cpu / f.commits.max(1) as f64;
                        // What viewers add: the CPU beyond the same commits at the 0-viewer
                        // row's cost per batch, shared over the updates sent.
                        let per_update = baseline.filter(|_| f.updates > 0).map(|b| {
                            let base = b.cpu / b.commits.max(1) as f64;
                            (f.cpu - base * f.commits as f64).max(0.0) / f.updates as f64
                        });
                        let ratio = (f.simulated_worker_cpu > 0.0).then(|| f.cpu / f.simulated_worker_cpu);
                        let vs0 = baseline.map(|b| f.commits_per_s / b.commits_per_s.max(1e-9));
                        // Rows whose job ended, or that never left pass one, measure something else.
                        if f.note.is_empty() {
                            if let Some(r) = ratio {
                                worst_ratio = worst_ratio.max(r);
                            }
                            if f.cpu > 0.0 {
                                peak = peak.max(f.commits_per_s / (f.cpu / f.window));
                            }
                        }
                        // A case whose job ended, or that never left pass one, (or whose
                        // baseline did) measures something else: it stays out of the summary.
                        let comparable = f.note.is_empty() && baseline.is_some_and(|b| b.note.is_empty());
                        if viewers > 0 && comparable {
                            if let Some(v) = vs0 {
                                // A viewer count given twice is two cases.
                                let twice = opts.viewers.iter().filter(|&&n| n == viewers).count() > 1;
                                let key = format!(
                                    "{}x{} {workers}w {viewers}v{} {batch_ms} ms",
                                    size.0,
                                    size.1,
                                    if twice { format!(" (#{})", i + 1) } else { String::new() }
                                );
                                match viewer_drop.iter_mut().find(|d| d.key == key) {
                                    Some(d) => d.push(v, f.updates_per_viewer_s.1),
                                    None => {
                                        viewer_drop.push(ViewerCost::new(key, v, f.updates_per_viewer_s.1))
                                    }
                                }
                            }
                        }
                        println!(
                        "{:>9} {:>4} {:>4} {:>5} {:>9.0} {:>6.1} {:>8.1} {:>8} {:>11} {:>13} {:>11} {:>9} {:>7} {:>7} {:>6.1} {:>6.1}{}",
                        format!("{}x{}", size.0, size.1),
                        workers,
                        viewers,
                        batch_ms,
                        f.commits_per_s,
                        f.cpu / f.window * 100.0,
                        per_batch * 1e6,
                        per_update.map_or("-".into(), |u| format!("{:.1}", u * 1e6)),
                        ms(f.lease_ms),
                        ms(f.merge_ms),
                        if viewers > 0 {
                            format!("{:.1}/{:.1}", f.updates_per_viewer_s.0, f.updates_per_viewer_s.1)
                        } else {
                            "-".into()
                        },
                        if viewers > 0 { format!("{:.0}", f.bytes_per_viewer_s / 1e3) } else { "-".into() },
                        ratio.map_or("-".into(), |r| format!("{:.2}%", r * 100.0)),
                        vs0.map_or("-".into(), |v| format!("{:.3}", v)),
                        f.bench_cpu / f.window * 100.0,
                        f.warm,
                        f.note
                    );
                    }
                }
            }
        }
    }
    println!(
        "columns: commit/s = batches merged (Status batches_done) per second; crd% = coordinator CPU over the \
         window (100 % = one core); us/batch = coordinator CPU / commits (viewers' cost included); us/upd = \
         the CPU beyond the 0-viewer row's cost per batch, per complete viewer update; lease = ms from \
         sending a result with credit to receiving the batch it bought (includes the merge, which comes \
         first); merge = ms from sending a pass-two result to the first viewer seeing it (includes the \
         viewer's coalescing interval); crd/wrk = coordinator CPU / simulated worker CPU; vs 0 v. = commits/s \
         over the 0-viewer row's; bench% = this process's CPU (fake workers and viewers share the cores); pass1s = seconds \
         from the workers connecting to the end of pass one (the warm-up, at most 15 s)"
    );
    println!(
        "targets: >= 5000 commits per coordinator core-second: best {peak:.0}; coordinator CPU <= 2 % of the \
         workers': worst {:.2} %; 100 viewers at >= 5 upd/s with <= 5 % fewer commits:",
        worst_ratio * 100.0
    );
    for d in viewer_drop {
        println!("  {d}");
    }
    Ok(())
}

/// One case's commits against its round's 0-viewer row, over the rounds.
struct ViewerCost {
    key: String,
    ratios: Vec<f64>,
    min_updates: f64,
}

impl ViewerCost {
    fn new(key: String, ratio: f64, min_updates: f64) -> Self {
        ViewerCost { key, ratios: vec![ratio], min_updates }
    }

    fn push(&mut self, ratio: f64, min_updates: f64) {
        self.ratios.push(ratio);
        self.min_updates = self.min_updates.min(min_updates);
    }

    /// The median ratio (of the middle two, their mean).
    fn median(&self) -> f64 {
        let mut r = self.ratios.clone();
        r.sort_by(f64::total_cmp);
        let n = r.len();
        if n % 2 == 1 {
            r[n / 2]
        } else {
            (r[n / 2 - 1] + r[n / 2]) / 2.0
        }
    }
}

impl std::fmt::Display for ViewerCost {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = |v: f64| format!("{:+.1} %", (v - 1.0) * 100.0);
        write!(f, "{}: {} commits", self.key, pct(self.median()))?;
        if self.ratios.len() > 1 {
            let each: Vec<String> = self.ratios.iter().map(|&v| pct(v)).collect();
            write!(f, " (median of {} rounds: {})", self.ratios.len(), each.join(", "))?;
        }
        write!(f, ", {:.1} upd/s min", self.min_updates)
    }
}
