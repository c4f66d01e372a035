//! `tessera render`: a coordinator in this process, local worker processes on loopback,
//! a progress bar, and the image written at the end (or at Ctrl-C, unfinished).
//!
//! The loopback port is reachable by every user of the machine, so the coordinator takes
//! only callers with a secret made fresh for this render: its workers get theirs in the
//! environment (readable by this user alone, unlike the command line), the viewer window
//! holds its own in memory.

use std::path::{Path, PathBuf};
use std::process::{ExitCode, Stdio};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use tessera_coordinator::{Auth, CoordinatorService, Role, Tokens};
use tessera_description::bundle::Bundle;
use tessera_description::ids::JobId;
use tessera_description::job::{JobProgress, JobSettings, JobState};
use tokio::net::TcpListener;
use tokio::process::{Child, Command};

use crate::report::rate;

mod opening;

pub use opening::Checkpoints;
use opening::{open_job, submit_job};

/// Arguments of `tessera render`.
#[derive(Debug, clap::Args)]
#[deny(missing_docs)]
pub struct RenderArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,
    /// The image to write: .png (8-bit sRGB) or .exr (linear float). With --frames, a
    /// run of # in the name is replaced by each frame's number, zero-padded
    /// (shot_####.exr: shot_0001.exr, …).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Render frames FIRST-LAST (inclusive) of the scene's animation as one job: every
    /// frame's first pass before any frame's second, so the whole sequence previews early.
    #[arg(long, value_name = "FIRST-LAST", allow_hyphen_values = true)]
    pub frames: Option<String>,
    /// Local worker processes [default: 1, with a render thread per core: one process
    /// reads and builds the scene once, where a process per core would each do it].
    #[arg(long)]
    pub workers: Option<usize>,
    /// Samples per pixel [default: the scene's].
    #[arg(long)]
    pub spp: Option<u32>,
    /// Render threads per worker [default: cores / workers, at least 1].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Image size WIDTHxHEIGHT [default: the scene's], e.g. a quick 160x90 preview; the
    /// field of view is kept along the camera's axis.
    #[arg(long, value_parser = crate::parse_size)]
    pub size: Option<(u32, u32)>,
    /// Open the viewer window on the render (it stays open until closed).
    #[arg(long)]
    pub view: bool,
    #[command(flatten)]
    pub halt: crate::HaltArgs,
    /// Continue an interrupted render of the same scene and settings from its checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Where checkpoints are kept while rendering [default: the output path + ".tessera"];
    /// removed once the image is written.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Seconds between checkpoints [default: 30]; also at the end of pass one and at Ctrl-C.
    #[arg(long, default_value_t = 30.0)]
    pub checkpoint_interval: f64,
    /// AOV layers to accumulate and write beside the image (an .exr output).
    #[command(flatten)]
    pub layers: crate::layers::AovArgs,
}

/// How a local render ended.
#[derive(Debug)]
pub enum Ending {
    /// Every sample is in.
    Done,
    /// Ctrl-C.
    Interrupted,
}

/// A finished (or interrupted) local render.
pub struct LocalRender {
    /// How it ended.
    pub ending: Ending,
    /// Final progress figures.
    pub progress: JobProgress,
    /// From start (before workers were spawned) to the end.
    pub wall: Duration,
    /// From start to the first pass-one result: the first full-frame mosaic.
    pub first_preview: Option<Duration>,
    /// Image size.
    pub width: u32,
    /// Height.
    pub height: u32,
}

/// Options of a local render.
pub struct LocalOptions {
    /// Worker processes.
    pub workers: usize,
    /// Threads per worker.
    pub threads: usize,
    /// spp override.
    pub spp: Option<u32>,
    /// Size override.
    pub size: Option<(u32, u32)>,
    /// Time budget.
    pub time_limit: Option<Duration>,
    /// Noise target.
    pub noise: Option<tessera_description::Noise>,
    /// Samples a pixel takes before the noise target may stop it (`None`: the target's own).
    pub noise_min: Option<u32>,
    /// AOV layers to accumulate and write, and denoising.
    pub layers: crate::layers::AovArgs,
    /// The frames of a sequence (`None`: a still); `output` is then a pattern.
    pub frames: Option<(u32, u32)>,
    /// Show a progress bar.
    pub progress_bar: bool,
    /// Open the viewer window.
    pub view: bool,
    /// Write the image here at the end (before waiting for the viewer window).
    pub output: Option<PathBuf>,
    /// Keep checkpoints in this directory; removed when the image is written.
    pub checkpoints: Option<Checkpoints>,
}

/// The secrets of one render: its workers', and its viewer window's.
struct Secrets {
    worker: String,
    viewer: String,
}

impl Secrets {
    /// Fresh from the system's random source: 256 bits each, as hex.
    fn new() -> Result<Secrets> {
        let one = || -> Result<String> {
            let mut bytes = [0u8; 32];
            getrandom::fill(&mut bytes).map_err(|e| anyhow!("the system's random source failed: {e}"))?;
            Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
        };
        Ok(Secrets { worker: one()?, viewer: one()? })
    }

    /// Who the coordinator lets in: the local workers and the window (an admin: it pauses
    /// and resumes), nobody else.
    fn auth(&self) -> Auth {
        Auth::new(
            Some(Tokens::new().with(Role::Worker, "local", &self.worker).with(
                Role::Admin,
                "window",
                &self.viewer,
            )),
            false,
        )
    }
}

/// Kills the local workers when dropped, so that no process outlives the render, whatever
/// path the render leaves by.
struct Workers(Vec<Child>);

impl Workers {
    fn spawn(url: &str, n: usize, threads: usize, secret: &str, preload: &Path) -> Result<Workers> {
        let exe = std::env::current_exe().context("locating the tessera executable")?;
        let mut children = Vec::with_capacity(n);
        for i in 0..n {
            let mut cmd = Command::new(&exe);
            cmd.args(["worker", "--coordinator", url, "--exit-on-disconnect"])
                .args(["--threads", &threads.to_string(), "--name", &format!("local-{i}")])
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .env(tessera_proto::credentials::TOKEN_ENV, secret)
                .kill_on_drop(true);
            // One argument, so that a path starting with '-' is not taken for an option.
            let mut preload_arg = std::ffi::OsString::from("--preload=");
            preload_arg.push(preload);
            cmd.arg(preload_arg);
            if std::env::var_os("RUST_LOG").is_none() {
                cmd.env("RUST_LOG", "warn");
            }
            children.push(cmd.spawn().with_context(|| format!("starting local worker {i}"))?);
        }
        Ok(Workers(children))
    }

    /// Whether every worker has exited.
    fn all_exited(&mut self) -> bool {
        self.0.iter_mut().all(|c| matches!(c.try_wait(), Ok(Some(_))))
    }

    async fn shutdown(mut self) {
        for c in &mut self.0 {
            let _ = c.start_kill();
        }
        for c in &mut self.0 {
            let _ = c.wait().await;
        }
    }
}

/// Renders `scene` with local worker processes.
pub async fn render_local(scene: &Path, opts: LocalOptions) -> Result<LocalRender> {
    let start = Instant::now();
    let bundle = Bundle::read(scene)?;
    let settings = JobSettings {
        spp: opts.spp,
        size: opts.size,
        time_limit: opts.time_limit,
        noise: opts.noise,
        noise_min: opts.noise_min,
        aovs: opts.layers.aovs(),
        frames: opts.frames,
    };
    let (service, opening) = open_job(&bundle, &settings, opts.checkpoints.as_ref())?;
    let secrets = Secrets::new()?;
    let service = service.with_auth(secrets.auth());
    let listener =
        TcpListener::bind("127.0.0.1:0").await.context("binding a loopback port for the coordinator")?;
    let addr = listener.local_addr()?;
    let server = tokio::spawn(
        tessera_coordinator::service::server()
            .add_routes(service.clone().into_server())
            .serve_with_incoming(tessera_coordinator::service::incoming(listener)),
    );
    let reaper = service.spawn_reaper();
    let url = format!("http://{addr}");
    tracing::info!("local coordinator on {addr}, for this render's secret holders only");
    // The coordinator serves before it has a job, and its workers start with `--preload`:
    // they connect and build the scene while the coordinator validates it — on the
    // 1M-triangle terrain, half a second of the first sample's wait (docs/speed.md, "Ninth
    // part").
    let mut workers = Workers::spawn(&url, opts.workers, opts.threads, &secrets.worker, scene)?;
    let job = match submit_job(&service, bundle, settings, opening).await {
        Ok(job) => job,
        Err(e) => {
            server.abort();
            reaper.abort();
            return Err(e);
        }
    };
    let checkpointer = service.spawn_checkpointer();
    let viewer = tessera_proto::credentials::Token::new(&secrets.viewer, "the render's secret")?;
    let endpoint = tessera_proto::connect::EndpointConfig::new(&url)?.token(Some(viewer));
    let window = opts.view.then(|| {
        std::thread::spawn(move || {
            if let Err(e) = tessera_viewer::window::run(&endpoint, Some(job), std::time::Duration::ZERO) {
                eprintln!("warning: {e}");
            }
        })
    });

    let bar = opts.progress_bar.then(progress_bar);
    let mut changed = service.subscribe();
    let mut first_preview = None;
    let mut workers_gone_since: Option<Instant> = None;
    // A sequence's frames are written as each finishes, while later ones render.
    let mut written: std::collections::BTreeSet<u32> = std::collections::BTreeSet::new();
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    let ending = loop {
        tokio::select! {
            _ = changed.changed() => {}
            _ = tokio::time::sleep(Duration::from_millis(200)) => {}
            _ = &mut ctrl_c => break Ending::Interrupted,
        }
        let p = progress(&service, job);
        if first_preview.is_none() && p.pass_one_done > 0 {
            first_preview = Some(start.elapsed());
        }
        if let Some(bar) = &bar {
            update_bar(bar, &p);
        }
        if let Some(out) = &opts.output {
            for f in p.frame_progress.iter().filter(|f| f.samples_done == f.samples_total) {
                if written.insert(f.frame) {
                    write_frame(&service, job, out, f.frame, &opts.layers)?;
                }
            }
        }
        match &p.state {
            JobState::Done => break Ending::Done,
            JobState::Failed(e) => {
                workers.shutdown().await;
                return Err(anyhow!("the render failed: {e}"));
            }
            _ => {}
        }
        // Local workers exit only when something is wrong (they crashed, or were killed):
        // give a moment for a last result, then stop rather than wait forever.
        if workers.all_exited() {
            let since = *workers_gone_since.get_or_insert_with(Instant::now);
            if since.elapsed() > Duration::from_secs(1) {
                workers.shutdown().await;
                return Err(anyhow!(
                    "every local worker exited before the render finished (see their messages above)"
                ));
            }
        }
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    let progress = progress(&service, job);
    let image = service.image(job).expect("job exists");
    let (width, height, rgb, layers) = (image.width, image.height, image.rgb, image.layers);
    workers.shutdown().await;
    if let Some(c) = checkpointer {
        c.abort();
    }
    if matches!(ending, Ending::Interrupted) {
        service.checkpoint(true).await.context("writing the checkpoint")?;
    }
    if let Some(out) = &opts.output {
        match opts.frames {
            None => crate::layers::write(out, width, height, &rgb, layers, &opts.layers)?,
            Some((first, last)) => {
                for frame in (first..=last).filter(|f| !written.contains(f)) {
                    write_frame(&service, job, out, frame, &opts.layers)?;
                }
            }
        }
    }
    if let (Ending::Done, Some(c)) = (&ending, &opts.checkpoints) {
        // The image is written: the checkpoint has served its purpose.
        std::fs::remove_dir_all(&c.dir).with_context(|| format!("removing {}", c.dir.display()))?;
    }
    if let Some(window) = window {
        // The window needs the coordinator to show the final image: keep serving until the
        // person closes it.
        if !window.is_finished() {
            eprintln!("render over; close the viewer window to exit");
        }
        let _ = tokio::task::spawn_blocking(move || window.join()).await;
    }
    server.abort();
    reaper.abort();
    Ok(LocalRender { ending, progress, wall: start.elapsed(), first_preview, width, height })
}

/// Writes frame `frame` of sequence `job` to its file of output pattern `out`.
fn write_frame(
    service: &CoordinatorService,
    job: JobId,
    out: &Path,
    frame: u32,
    layers: &crate::layers::AovArgs,
) -> Result<()> {
    let image =
        service.frame_image(job, Some(frame), true).ok_or_else(|| anyhow!("{job} has no frame {frame}"))?;
    let path = crate::frames::frame_path(out, frame);
    crate::layers::write(&path, image.width, image.height, &image.rgb, image.layers, layers)?;
    Ok(())
}

fn progress(service: &CoordinatorService, job: JobId) -> JobProgress {
    service.progress(job).expect("job exists")
}

fn progress_bar() -> ProgressBar {
    let bar = ProgressBar::new(1000);
    bar.set_style(
        ProgressStyle::with_template("{spinner} pass {prefix} [{bar:32}] {percent:>3}% {msg} ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar
}

fn update_bar(bar: &ProgressBar, p: &JobProgress) {
    bar.set_prefix(p.pass.to_string());
    bar.set_position((p.fraction() * 1000.0) as u64);
    bar.set_message(rate(p.samples_per_second));
}

/// The local worker processes `--workers` asks for (one by default), bounded: each is a
/// process.
pub fn local_workers(asked: Option<usize>) -> Result<usize> {
    let workers = asked.unwrap_or(1);
    if workers == 0 || workers > 256 {
        anyhow::bail!("--workers must be 1..=256, got {workers}");
    }
    Ok(workers)
}

/// `tessera render`.
pub async fn render(args: RenderArgs) -> Result<ExitCode> {
    crate::check_output(&args.output)?;
    args.layers.check(Some(&args.output))?;
    let frames = crate::frames::parse(args.frames.as_deref())?;
    crate::frames::check_pattern(&args.output, frames)?;
    let cores = crate::cores();
    let workers = local_workers(args.workers)?;
    let threads = args.threads.unwrap_or((cores / workers).max(1));
    if threads == 0 {
        anyhow::bail!("--threads must be at least 1");
    }
    let dir = args.data.clone().unwrap_or_else(|| {
        let mut name = args.output.as_os_str().to_owned();
        name.push(".tessera");
        PathBuf::from(name)
    });
    let checkpoints = Checkpoints {
        dir: dir.clone(),
        interval: crate::seconds("--checkpoint-interval", args.checkpoint_interval)?,
        resume: args.resume,
    };
    let (noise, noise_min) = args.halt.noise_target()?;
    let opts = LocalOptions {
        workers,
        threads,
        spp: args.spp,
        size: args.size,
        time_limit: args.halt.time,
        noise,
        noise_min,
        layers: args.layers.clone(),
        frames,
        progress_bar: true,
        view: args.view,
        output: Some(args.output.clone()),
        checkpoints: Some(checkpoints),
    };
    let r = render_local(&args.scene, opts).await?;
    let p = &r.progress;
    if p.nonfinite_samples > 0 {
        eprintln!("warning: {} samples were NaN or infinite and counted as black", p.nonfinite_samples);
    }
    match r.ending {
        Ending::Done => {
            let samples = match p.halted {
                Some(why) => format!(
                    "stopped by the {why} at {:.1} samples per pixel on average, of at most {}",
                    p.samples_done as f64 / (f64::from(r.width) * f64::from(r.height)),
                    p.spp
                ),
                None => format!("{} spp", p.spp),
            };
            let written = match frames {
                Some((first, last)) if last > first => format!(
                    "{} frames {} .. {}",
                    last - first + 1,
                    crate::frames::frame_path(&args.output, first).display(),
                    crate::frames::frame_path(&args.output, last).display()
                ),
                Some((first, _)) => crate::frames::frame_path(&args.output, first).display().to_string(),
                None => args.output.display().to_string(),
            };
            eprintln!(
                "wrote {written} ({}x{}, {samples}) in {:.2} s, {}",
                r.width,
                r.height,
                r.wall.as_secs_f64(),
                rate(p.samples_done as f64 / p.elapsed.as_secs_f64().max(1e-9))
            );
            Ok(ExitCode::SUCCESS)
        }
        Ending::Interrupted => {
            eprintln!(
                "interrupted at {:.1}% (pass {}): wrote the unfinished image to {} and a checkpoint to {}",
                p.fraction() * 100.0,
                p.pass,
                args.output.display(),
                dir.display()
            );
            eprintln!(
                "continue with: tessera render {} -o {} --resume",
                args.scene.display(),
                args.output.display()
            );
            Ok(ExitCode::from(130))
        }
    }
}
