//! `tessera`: the one command-line tool of the render farm.
#![forbid(unsafe_code)]

mod bench;
mod certs;
mod compare;
mod frames;
mod layers;
mod local;
mod remote;
mod report;
mod rpc;
mod status;
mod worker;

use std::io::IsTerminal;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use tessera_description::ids::JobId;
use tracing_subscriber::EnvFilter;

/// Tessera: a render farm for distributed ray tracing with progressive refinement.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None, propagate_version = true)]
#[deny(missing_docs)]
struct Cli {
    /// How log lines are written on stderr: text, or json (one object a line with
    /// timestamp, level, target and fields, for log collectors).
    #[arg(long, global = true, value_enum, default_value_t = LogFormat::Text, env = "TESSERA_LOG_FORMAT")]
    log_format: LogFormat,
    #[command(subcommand)]
    command: Command,
}

/// How log lines are written (`--log-format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum LogFormat {
    /// Lines for people.
    Text,
    /// One JSON object a line.
    Json,
}

#[derive(Debug, Subcommand)]
#[deny(missing_docs)]
enum Command {
    /// Render a scene with local worker processes and write the image (.png or .exr).
    Render(local::RenderArgs),
    /// Run a coordinator that workers and clients connect to.
    Coordinator {
        /// Address to listen on, e.g. 0.0.0.0:7878 to accept workers from other machines.
        #[arg(long, default_value = "127.0.0.1:7878", env = "TESSERA_LISTEN")]
        listen: SocketAddr,
        /// Seconds of silence after which a worker's batches go to others [default: 10].
        #[arg(long, default_value_t = 10.0)]
        worker_timeout: f64,
        /// Seconds a pass-two batch should take one of a worker's threads, once the
        /// worker's speed on the job is measured: shorter refines previews more often and
        /// costs more round trips [default: 0.1; 0.005 to 60].
        #[arg(long, default_value_t = 0.1)]
        batch_time: f64,
        /// Keep jobs and their checkpoints in this directory, and take up every unfinished
        /// job found there at start. Without it, jobs live in memory only.
        #[arg(long, env = "TESSERA_DATA")]
        data: Option<PathBuf>,
        /// With --data: seconds between checkpoints of a running job (also at the end of
        /// pass one and when a job ends) [default: 30].
        #[arg(long, default_value_t = 30.0, requires = "data")]
        checkpoint_interval: f64,
        /// Memory the jobs may hold (framebuffers and scenes), e.g. 8G or 512M; a job that
        /// does not fit is refused (RESOURCE_EXHAUSTED) [default: half the machine's memory].
        #[arg(long, env = "TESSERA_MEMORY_BUDGET", value_parser = parse_bytes)]
        memory_budget: Option<u64>,
        /// Finished jobs kept (images fetchable, memory held); the oldest beyond are
        /// dropped from memory and the data directory.
        #[arg(long, default_value_t = tessera_coordinator::service::KEEP_FINISHED, value_parser = clap::value_parser!(usize))]
        keep_finished: usize,
        /// Share of each worker's batches rendered again on a worker of another identity
        /// and compared bit for bit (a worker's first 20 batches at 25 %); 0 turns audits
        /// off [default: 0.03].
        #[arg(long, default_value_t = tessera_coordinator::farm::DEFAULT_AUDIT_FRACTION)]
        audit_fraction: f64,
        /// Also serve the web dashboard and the HTTP API on this address, e.g.
        /// 127.0.0.1:8080 (HTTPS with the certificate of --tls-cert; see docs/http-api.md).
        #[arg(long, value_name = "ADDR", env = "TESSERA_HTTP")]
        http: Option<SocketAddr>,
        /// TLS and authentication.
        #[command(flatten)]
        security: remote::SecurityArgs,
    },
    /// Run a worker that renders batches for a coordinator.
    Worker(worker::WorkerArgs),
    /// Submit a scene to a coordinator; with -o, wait and write the image.
    Submit(remote::SubmitArgs),
    /// Show the jobs and workers of a coordinator.
    Status {
        /// Where the coordinator is and how to reach it.
        #[command(flatten)]
        conn: remote::ClientArgs,
        /// Also show each frame of a sequence on a line of its own.
        #[arg(long)]
        frames: bool,
    },
    /// Cancel a job; its current image stays fetchable.
    Cancel {
        /// The job id.
        job: u64,
        /// Where the coordinator is and how to reach it.
        #[command(flatten)]
        conn: remote::ClientArgs,
    },
    /// Watch a job refine in a window (S save, P pause/resume, +/- exposure, Q quit), or
    /// headless with --save.
    View(ViewArgs),
    /// Write a job's current image, finished or not (the mosaic where pass one has not
    /// reached yet).
    Fetch {
        /// The job id.
        job: u64,
        /// The image to write (.png or .exr).
        #[arg(short, long)]
        output: PathBuf,
        /// AOV layers of the job to write too (it must have been submitted with them).
        #[command(flatten)]
        layers: layers::AovArgs,
        /// The frame of a sequence [default: its first].
        #[arg(long)]
        frame: Option<u32>,
        /// Where the coordinator is and how to reach it.
        #[command(flatten)]
        conn: remote::ClientArgs,
    },
    /// Pause a job: no new batches until it is resumed.
    Pause {
        /// The job id.
        job: u64,
        /// Where the coordinator is and how to reach it.
        #[command(flatten)]
        conn: remote::ClientArgs,
    },
    /// Change a job's priority: jobs with a higher one are served first (a submitter may
    /// ask at most the coordinator's --max-priority).
    Priority {
        /// The job id.
        job: u64,
        /// The new priority.
        #[arg(allow_negative_numbers = true)]
        priority: i32,
        /// Where the coordinator is and how to reach it.
        #[command(flatten)]
        conn: remote::ClientArgs,
    },
    /// Resume a paused job.
    Resume {
        /// The job id.
        job: u64,
        /// Where the coordinator is and how to reach it.
        #[command(flatten)]
        conn: remote::ClientArgs,
    },
    /// Print the pass-one visit order of a WIDTH × HEIGHT image: one computed pixel per
    /// line as `x y w h` (origin at the lower-left corner, y upward; w × h is the block the
    /// pixel paints).
    Order {
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
    },
    /// Compare an image with a reference: RMSE, relative MSE and PSNR over all pixels and
    /// the three linear RGB channels (EXR is read as linear, PNG is decoded from sRGB).
    Compare {
        /// The image to judge.
        image: PathBuf,
        /// The reference image.
        reference: PathBuf,
        /// Also list the N pixels that differ most.
        #[arg(long, default_value_t = 0)]
        worst: usize,
        /// Clamp both images to [0, C] first, e.g. 1 for what a display shows.
        #[arg(long)]
        clamp: Option<f32>,
    },
    /// Benchmarks that print figures.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Make a private CA and certificates for a farm's TLS (see docs/security/connections.md).
    #[command(subcommand)]
    Certs(certs::CertsCommand),
}

/// Arguments of `tessera view`.
#[derive(Debug, clap::Args)]
#[deny(missing_docs)]
pub struct ViewArgs {
    /// Where the coordinator is and how to reach it.
    #[command(flatten)]
    conn: remote::ClientArgs,
    /// The job [default: the running job, else the newest].
    #[arg(long)]
    job: Option<u64>,
    /// The frame of a sequence to watch [default: its first].
    #[arg(long)]
    frame: Option<u32>,
    /// Write the image here (.png or .exr) instead of opening a window.
    #[arg(long)]
    save: Option<PathBuf>,
    /// With --save: write a snapshot every SECONDS while the job runs, and at its end.
    #[arg(long, requires = "save", conflicts_with = "at")]
    every: Option<f64>,
    /// With --save: write one snapshot once PERCENT of the samples are done, then exit.
    #[arg(long, requires = "save")]
    at: Option<f64>,
    /// Forward the image, as HDR float tiles, to a running tev viewer at HOST:PORT (tev
    /// listens on 127.0.0.1:14158 by default).
    #[arg(long, conflicts_with = "save")]
    tev: Option<String>,
    /// Seconds to keep reconnecting to a lost coordinator (one restarting on its data
    /// directory) before giving up; 0 gives up at once.
    #[arg(long, default_value_t = 60.0)]
    reconnect_for: f64,
}

fn init_tracing(default: &str, format: LogFormat) {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
    let logs = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr);
    match format {
        // Colours only for a terminal: a log file or a collector gets plain text.
        LogFormat::Text => logs.with_target(false).with_ansi(std::io::stderr().is_terminal()).init(),
        // Spans carry nothing the events do not: one flat object per event.
        LogFormat::Json => logs.json().with_ansi(false).with_current_span(false).with_span_list(false).init(),
    }
}

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let quiet = matches!(
        cli.command,
        Command::Render(_)
            | Command::Submit(_)
            | Command::Order { .. }
            | Command::Bench(_)
            | Command::Certs(_)
    );
    init_tracing(if quiet { "warn" } else { "info" }, cli.log_format);
    if cli.log_format == LogFormat::Json {
        // Worker processes this one starts (`render`) log the same way. Still one thread.
        std::env::set_var("TESSERA_LOG_FORMAT", "json");
    }
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(cli.command)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes on one line.
fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain().map(|c| c.to_string()) {
        // Many errors already print their source; say each thing once.
        if !line.contains(&cause) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&cause);
        }
    }
    line
}

async fn run(command: Command) -> Result<ExitCode> {
    match command {
        Command::Render(args) => local::render(args).await,
        Command::Coordinator {
            listen,
            worker_timeout,
            batch_time,
            data,
            checkpoint_interval,
            memory_budget,
            keep_finished,
            audit_fraction,
            http,
            security,
        } => {
            let audit = tessera_coordinator::farm::AuditPolicy::with_fraction(audit_fraction)
                .map_err(|e| anyhow::anyhow!("--audit-fraction: {e}"))?;
            let timing = tessera_coordinator::Timing {
                silence_timeout: seconds("--worker-timeout", worker_timeout)?,
                batch_time: batch_time_arg(batch_time)?,
                ..Default::default()
            };
            let data = match data {
                Some(dir) => Some((dir, seconds("--checkpoint-interval", checkpoint_interval)?)),
                None => None,
            };
            let budget = memory_budget.unwrap_or_else(tessera_coordinator::service::default_budget);
            if keep_finished == 0 {
                anyhow::bail!("--keep-finished must be at least 1");
            }
            remote::serve_coordinator(listen, http, timing, data, budget, keep_finished, &security, audit)
                .await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Worker(args) => worker::run(args).await,
        Command::Submit(args) => remote::submit(args).await,
        Command::Status { conn, frames } => remote::status(&conn, frames).await,
        Command::Cancel { job, conn } => remote::cancel(&conn, JobId(job)).await,
        Command::Fetch { job, output, layers, frame, conn } => {
            check_output(&output)?;
            layers.check(Some(&output))?;
            let mut client = remote::connect(&conn).await?;
            let (w, h, rgb, aov) = layers::fetch(&mut client, JobId(job), frame, &layers).await?;
            let output = frame.map_or(output.clone(), |f| frames::frame_path(&output, f));
            layers::write(&output, w, h, &rgb, aov, &layers)?;
            eprintln!("wrote {} ({w}x{h}) of job {job}", output.display());
            Ok(ExitCode::SUCCESS)
        }
        Command::Pause { job, conn } => remote::pause(&conn, JobId(job), true).await,
        Command::Resume { job, conn } => remote::pause(&conn, JobId(job), false).await,
        Command::Priority { job, priority, conn } => remote::set_priority(&conn, JobId(job), priority).await,
        Command::Order { width, height } => {
            use std::io::Write;
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::new(stdout.lock());
            for q in tessera_film::quadtree::Walk::new(width, height) {
                if let Err(e) = writeln!(out, "{} {} {} {}", q.x, q.y, q.w, q.h) {
                    // A closed pipe (`| head`) is a normal way to stop reading.
                    if e.kind() == std::io::ErrorKind::BrokenPipe {
                        return Ok(ExitCode::SUCCESS);
                    }
                    return Err(e).context("writing the order");
                }
            }
            match out.flush() {
                Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e).context("writing the order"),
                _ => Ok(ExitCode::SUCCESS),
            }
        }
        Command::Bench(cmd) => bench::run(cmd).await,
        Command::Certs(cmd) => certs::run(cmd),
        Command::View(args) => view(args).await,
        Command::Compare { image, reference, worst, clamp } => {
            if clamp.is_some_and(|c| !(c.is_finite() && c > 0.0)) {
                anyhow::bail!("--clamp must be a positive number");
            }
            let (w, h, a, b) = compare::load_pair(&image, &reference, clamp)?;
            let e = compare::errors(w, h, &a, &b);
            println!(
                "rmse {:.6}  relmse {:.6}  psnr {:.2} dB  ({} x {})",
                e.rmse, e.relmse, e.psnr, e.width, e.height
            );
            for (x, y, got, want) in compare::worst_pixels(w, &a, &b, worst) {
                println!("  pixel {x},{y} (from top-left): {got:?} vs reference {want:?}");
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

async fn view(args: ViewArgs) -> Result<ExitCode> {
    use tessera_viewer::headless::{run, Headless, When};
    let reconnect_for = match args.reconnect_for {
        0.0 => std::time::Duration::ZERO,
        s => seconds("--reconnect-for", s)?,
    };
    let coordinator = args.conn.endpoint()?;
    let job = args.job.map(JobId);
    if let Some(tev) = &args.tev {
        tessera_viewer::tev::run_frame(&coordinator, job, args.frame, tev, reconnect_for).await?;
        eprintln!("forwarded the job to tev at {tev}");
        return Ok(ExitCode::SUCCESS);
    }
    let Some(save) = args.save else {
        let frame = args.frame;
        tokio::task::spawn_blocking(move || {
            tessera_viewer::window::run_frame(&coordinator, job, frame, reconnect_for)
        })
        .await??;
        return Ok(ExitCode::SUCCESS);
    };
    check_output(&save)?;
    let when = match (args.every, args.at) {
        (Some(s), _) if !(s.is_finite() && s > 0.0) => {
            anyhow::bail!("--every must be a positive number of seconds")
        }
        (Some(s), _) => When::Every(std::time::Duration::from_secs_f64(s)),
        (_, Some(p)) if !(p.is_finite() && (0.0..=100.0).contains(&p)) => {
            anyhow::bail!("--at must be a percentage in 0..=100")
        }
        (_, Some(p)) => When::At(p),
        (None, None) => When::End,
    };
    let frame = args.frame;
    let outcome = run(Headless { coordinator, job, frame, save: save.clone(), when, reconnect_for }).await?;
    eprintln!(
        "wrote {} at {:.1}%{}",
        save.display(),
        outcome.percent,
        if outcome.finished { " (job over)" } else { "" }
    );
    Ok(ExitCode::SUCCESS)
}

/// Checks an output path before any work is done: a known extension and a directory
/// that exists.
pub fn check_output(path: &std::path::Path) -> Result<()> {
    tessera_film::output::Format::from_path(path)?;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    if !dir.is_dir() {
        anyhow::bail!("cannot write {}: directory {} does not exist", path.display(), dir.display());
    }
    Ok(())
}

/// A positive number of seconds from the command line.
pub fn seconds(flag: &str, value: f64) -> Result<std::time::Duration> {
    if !(value.is_finite() && value > 0.0 && value < 1e9) {
        anyhow::bail!("{flag} must be a positive number of seconds, got {value}");
    }
    Ok(std::time::Duration::from_secs_f64(value))
}

/// `--batch-time`: below 5 ms a batch would be mostly its round trip; above a minute a
/// job's last batches, and its previews, would wait that long on one worker.
fn batch_time_arg(value: f64) -> Result<std::time::Duration> {
    if !(0.005..=60.0).contains(&value) {
        anyhow::bail!("--batch-time must be between 0.005 and 60 seconds, got {value}");
    }
    seconds("--batch-time", value)
}

/// Waits for Ctrl-C or SIGTERM (what `kill` and service managers send).
pub async fn shutdown_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    let _ = tokio::signal::ctrl_c().await;
}

/// How a job may end before its spp: the flags `tessera render` and `tessera submit` share.
#[derive(clap::Args, Debug, Clone)]
pub struct HaltArgs {
    /// Stop after this much rendering time, e.g. 90s, 2m, 1h30m (spp is then the most a
    /// pixel takes): pass two runs in rounds over the whole image, so the image is evenly
    /// converged whenever it stops.
    #[arg(long, value_parser = crate::parse_duration, allow_hyphen_values = true)]
    pub time: Option<std::time::Duration>,
    /// Stop sampling each pixel once its estimated relative error is below this, e.g.
    /// 0.01 (adaptive sampling, in rounds as with --time; spp is the most a pixel takes).
    #[arg(long, allow_negative_numbers = true)]
    pub noise: Option<f32>,
    /// As --noise, but the error in the image's linear units, e.g. 0.02: every pixel to
    /// the same absolute error (what an RMSE counts), so the samples go to the bright,
    /// noisy highlights and dark pixels stop early.
    #[arg(long, allow_negative_numbers = true, conflicts_with = "noise")]
    pub noise_abs: Option<f32>,
    /// Samples every pixel takes before --noise or --noise-abs may stop it [default: 16
    /// with --noise, 64 with --noise-abs]; at most --spp. More cuts the low bias of pixels
    /// whose first samples missed a rare bright path, at the cost of time (docs/accuracy.md).
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..), allow_negative_numbers = true)]
    pub noise_min: Option<u32>,
}

impl HaltArgs {
    /// The noise target of `--noise` (relative) or `--noise-abs` (absolute), which clap
    /// keeps apart, and `--noise-min`, which needs one of them; the coordinator checks
    /// their ranges.
    pub fn noise_target(&self) -> anyhow::Result<(Option<tessera_description::Noise>, Option<u32>)> {
        use tessera_description::Noise;
        let target = self.noise.map(Noise::Relative).or(self.noise_abs.map(Noise::Absolute));
        if let (None, Some(m)) = (target, self.noise_min) {
            anyhow::bail!(
                "--noise-min {m}: a minimum of samples needs a noise target, --noise or --noise-abs"
            );
        }
        Ok((target, self.noise_min))
    }
}

/// A duration such as `90`, `90s`, `2m`, `1h30m` or `1.5h` (also the web API's `time`).
pub fn parse_duration(s: &str) -> Result<std::time::Duration, String> {
    tessera_description::job::parse_duration(s)
}

/// Parses `WIDTHxHEIGHT`.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let parse = |v: &str| v.trim().parse::<u32>().ok().filter(|&n| n > 0);
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("expected WIDTHxHEIGHT with positive whole numbers, got {s:?}")),
    }
}

/// A size in bytes as given on the command line: a number with an optional unit (K, M, G,
/// T: powers of 1024; KB, MB, GB, TB: powers of 1000; KiB… as K…).
fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let scale: f64 = match unit.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 1.0,
        "K" | "KIB" => 1024.0,
        "M" | "MIB" => 1024f64.powi(2),
        "G" | "GIB" => 1024f64.powi(3),
        "T" | "TIB" => 1024f64.powi(4),
        "KB" => 1e3,
        "MB" => 1e6,
        "GB" => 1e9,
        "TB" => 1e12,
        other => return Err(format!("unknown unit {other:?} in {s:?}; e.g. 512M or 8G")),
    };
    let n: f64 = number.parse().map_err(|_| format!("expected a size such as 512M or 8G, got {s:?}"))?;
    let bytes = n * scale;
    if !(bytes >= 1.0 && bytes < 2f64.powi(63)) {
        return Err(format!("{s:?} is not a usable size"));
    }
    Ok(bytes as u64)
}

/// A path given on the command line.
pub type PathArg = PathBuf;

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn durations_parse_with_units() {
        let secs = |s: &str| parse_duration(s).map(|d| d.as_secs_f64());
        assert_eq!(secs("90"), Ok(90.0));
        assert_eq!(secs("90s"), Ok(90.0));
        assert_eq!(secs("2m"), Ok(120.0));
        assert_eq!(secs("1h30m"), Ok(5400.0));
        assert_eq!(secs("1.5h"), Ok(5400.0));
        for bad in ["", "0", "-5s", "2x", "m", "1e99"] {
            assert!(parse_duration(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn sizes_parse_with_units() {
        assert_eq!(parse_bytes("1000"), Ok(1000));
        assert_eq!(parse_bytes("512M"), Ok(512 << 20));
        assert_eq!(parse_bytes("8G"), Ok(8 << 30));
        assert_eq!(parse_bytes("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_bytes("2 GB"), Ok(2_000_000_000));
        for bad in ["", "0", "-5M", "2X", "M", "1e99"] {
            assert!(parse_bytes(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn cli_is_well_formed() {
        Cli::command().debug_assert();
    }
}
