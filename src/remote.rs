//! The farm spread over machines: a standalone coordinator, and the clients that submit,
//! watch, fetch and cancel jobs over gRPC.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use tessera_coordinator::{Auth, CoordinatorService, Timing, Tokens};

use crate::report::report_recovery;
use crate::rpc::status_error;
use tessera_description::bundle::Bundle;
use tessera_description::ids::JobId;
use tessera_description::job::{JobProgress, JobSettings, JobState};
use tessera_proto::connect::{Backoff, Client, EndpointConfig};
use tessera_proto::convert::{bundle_to_wire, settings_to_wire, status_from_wire};
use tessera_proto::credentials::{ClientTls, ServerTls, Token};
use tessera_proto::v1 as pb;

/// How a client reaches the coordinator: its URL, what it trusts over `https://`, what it
/// proves. The token comes from a file or the `TESSERA_TOKEN` environment variable, never
/// from the command line (where `ps` shows it to every user).
#[derive(Debug, Clone, clap::Args)]
#[deny(missing_docs)]
pub struct ClientArgs {
    /// The coordinator's URL, e.g. https://render-host:7878 (TLS) or http://… (plain text).
    #[arg(long, env = "TESSERA_COORDINATOR")]
    pub coordinator: String,
    /// With https://: trust only certificates signed by this CA (PEM) [default: the
    /// system's roots].
    #[arg(long, value_name = "FILE")]
    pub ca: Option<PathBuf>,
    /// With https:// and a coordinator that asks for one: this client's certificate (PEM).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The key of --tls-cert (PEM, not readable by every user).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Read the bearer token from this file (one line, not readable by every user)
    /// [default: the TESSERA_TOKEN environment variable, if set].
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
}

impl ClientArgs {
    /// The endpoint these arguments describe, with its certificates and token read.
    pub fn endpoint(&self) -> Result<EndpointConfig> {
        let mut tls = ClientTls::new();
        if let Some(ca) = &self.ca {
            tls = tls.ca_file(ca)?;
        }
        if let (Some(cert), Some(key)) = (&self.tls_cert, &self.tls_key) {
            tls = tls.identity_files(cert, key)?;
        }
        let token = Token::from_file_or_env(self.token_file.as_deref())?;
        Ok(EndpointConfig::new(&self.coordinator)?.tls(tls)?.token(token))
    }
}

/// How the coordinator secures its port: TLS, who may call, what submitters may ask.
#[derive(Debug, Clone, clap::Args)]
#[deny(missing_docs)]
pub struct SecurityArgs {
    /// Speak TLS with this certificate (chain, PEM); clients then use https://.
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The key of --tls-cert (PEM, not readable by every user).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Mutual TLS: every client must show a certificate signed by this CA (PEM); one whose
    /// OU names a role (see `tessera certs client`) needs no token.
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_client_ca: Option<PathBuf>,
    /// Callers authenticate with a bearer token from this file: one `ROLE NAME TOKEN` a
    /// line (roles admin, submitter, worker, viewer; `#` comments), not readable by every
    /// user.
    #[arg(long, value_name = "FILE")]
    pub tokens: Option<PathBuf>,
    /// The highest priority a submitter may give a job; above it needs an admin.
    #[arg(long, default_value_t = tessera_coordinator::DEFAULT_MAX_PRIORITY, allow_negative_numbers = true)]
    pub max_priority: i32,
    /// Also serve the gRPC health service alone on this address, in plain text and without
    /// authentication, e.g. 0.0.0.0:7879: for probes that speak no TLS (Kubernetes' `grpc`
    /// probe). It tells only whether the coordinator serves; nothing else is served there.
    #[arg(long, value_name = "ADDR")]
    pub health_listen: Option<SocketAddr>,
    /// Listen beyond loopback with no authentication at all (no --tokens, no
    /// --tls-client-ca): anyone who reaches the port may do anything.
    #[arg(long)]
    pub insecure: bool,
}

impl SecurityArgs {
    /// The TLS and the authentication these arguments ask for, checked against `listen`:
    /// a coordinator reachable beyond loopback refuses to start without authentication
    /// unless told `--insecure`.
    pub fn load(&self, listen: SocketAddr) -> Result<(Option<ServerTls>, Auth)> {
        let tls = match (&self.tls_cert, &self.tls_key) {
            (Some(cert), Some(key)) => Some(ServerTls::read(cert, key, self.tls_client_ca.as_deref())?),
            _ => None,
        };
        let tokens = self.tokens.as_deref().map(Tokens::read).transpose()?;
        if tokens.as_ref().is_some_and(Tokens::is_empty) {
            bail!(
                "the tokens file {} holds no tokens",
                self.tokens.as_deref().map_or(Path::new(""), |p| p).display()
            );
        }
        let auth =
            Auth::new(tokens, tls.as_ref().is_some_and(ServerTls::mutual)).max_priority(self.max_priority);
        self.check_exposure(listen, &auth, tls.is_some())?;
        Ok((tls, auth))
    }

    /// Refuses to listen on `listen` beyond loopback without authentication, or with
    /// tokens in plain text, unless `--insecure` (for the gRPC port and the --http one).
    pub fn check_exposure(&self, listen: SocketAddr, auth: &Auth, tls: bool) -> Result<()> {
        let beyond_loopback = !listen.ip().is_loopback();
        if beyond_loopback && !auth.required() && !self.insecure {
            bail!(
                "refusing to listen on {listen} with no authentication: anyone who reaches it could \
                 submit, cancel and read every job. Give --tokens FILE (or --tls-client-ca for mutual \
                 TLS), listen on 127.0.0.1, or say --insecure"
            );
        }
        if beyond_loopback && !auth.required() {
            tracing::warn!("--insecure: listening on {listen} with no authentication");
        }
        if beyond_loopback && auth.required() && !tls {
            if !self.insecure {
                bail!(
                    "refusing to take tokens in plain text on {listen}: anyone on the network could read                      them and act as their owners. Give --tls-cert and --tls-key, listen on 127.0.0.1, or                      say --insecure"
                );
            }
            tracing::warn!(
                "--insecure: tokens travel in plain text on {listen}: anyone on the network can read them"
            );
        }
        Ok(())
    }
}

/// Arguments of `tessera submit`.
#[derive(Debug, clap::Args)]
#[deny(missing_docs)]
pub struct SubmitArgs {
    /// The scene file (TOML).
    pub scene: PathBuf,
    /// Where the coordinator is and how to reach it.
    #[command(flatten)]
    pub conn: ClientArgs,
    /// Wait for the job and write its image here (.png or .exr); implies --wait. With
    /// --frames, a run of # in the name is replaced by each frame's number, zero-padded.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Render frames FIRST-LAST (inclusive) of the scene's animation as one job.
    #[arg(long, value_name = "FIRST-LAST", allow_hyphen_values = true)]
    pub frames: Option<String>,
    /// Samples per pixel [default: the scene's].
    #[arg(long)]
    pub spp: Option<u32>,
    /// Wait until the job is over, showing progress.
    #[arg(long)]
    pub wait: bool,
    /// Image size WIDTHxHEIGHT [default: the scene's].
    #[arg(long, value_parser = crate::parse_size)]
    pub size: Option<(u32, u32)>,
    #[command(flatten)]
    pub halt: crate::HaltArgs,
    /// Priority: jobs with a higher one are served first, equal ones oldest first (a
    /// submitter may ask at most the coordinator's --max-priority).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub priority: i32,
    /// AOV layers to accumulate and write beside the image (with -o FILE.exr).
    #[command(flatten)]
    pub layers: crate::layers::AovArgs,
}

/// Runs a coordinator until Ctrl-C or SIGTERM; with a data directory, its jobs survive.
#[allow(clippy::too_many_arguments)]
pub async fn serve_coordinator(
    listen: SocketAddr,
    http: Option<SocketAddr>,
    timing: Timing,
    data: Option<(PathBuf, Duration)>,
    memory_budget: u64,
    keep_finished: usize,
    security: &SecurityArgs,
    audit: tessera_coordinator::farm::AuditPolicy,
) -> Result<()> {
    // Before the data directory is opened: a refused start touches nothing.
    let (tls, auth) = security.load(listen)?;
    if let Some(http) = http {
        security.check_exposure(http, &auth, tls.is_some()).context("--http")?;
    }
    tracing::info!(bytes = memory_budget, "memory budget of the jobs");
    let service = match &data {
        Some((dir, interval)) => {
            let (service, recovery) = CoordinatorService::open_within(timing, dir, *interval, memory_budget)
                .with_context(|| format!("data directory {}", dir.display()))?;
            report_recovery(dir, &recovery);
            service
        }
        None => CoordinatorService::with_memory_budget(timing, memory_budget),
    };
    let service = service.keeping_finished(keep_finished).with_auth(auth);
    service.set_audit_policy(audit);
    let listener =
        tokio::net::TcpListener::bind(listen).await.with_context(|| format!("cannot listen on {listen}"))?;
    tracing::info!(
        "coordinator listening on {}{}",
        listener.local_addr()?,
        if tls.is_some() { " (TLS)" } else { "" }
    );
    if let Some(addr) = security.health_listen {
        let health = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr} (--health-listen)"))?;
        tracing::info!("health service listening on {} (plain text)", health.local_addr()?);
        // Until the process ends: while the coordinator drains it answers NOT_SERVING.
        let routes = service.health_routes();
        tokio::spawn(async move {
            let served = tessera_coordinator::service::server()
                .add_routes(routes)
                .serve_with_incoming(tessera_coordinator::service::incoming(health))
                .await;
            if let Err(e) = served {
                tracing::error!("the health listener failed: {e}");
            }
        });
    }
    let _reaper = service.spawn_reaper();
    let _checkpointer = service.spawn_checkpointer();
    // One signal stops both servers.
    let (stop, stopped) = tokio::sync::watch::channel(false);
    let until_stopped = |mut rx: tokio::sync::watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };
    let web = http.map(|addr| {
        tokio::spawn(serve_web(addr, service.clone(), tls.clone(), until_stopped(stopped.clone())))
    });
    let mut server = tessera_coordinator::service::server();
    if let Some(tls) = &tls {
        server = server.tls_config(tls.config()).context("the TLS certificate or key cannot be used")?;
    }
    let stop = std::sync::Arc::new(stop);
    let stop_all = {
        let (service, stop) = (service.clone(), stop.clone());
        move || {
            // Health turns NOT_SERVING, and the worker and viewer streams end, so that the
            // graceful shutdown does not wait for them (a service manager's stop timeout).
            service.shutdown();
            stop.send_replace(true);
        }
    };
    {
        let stop_all = stop_all.clone();
        tokio::spawn(async move {
            crate::shutdown_signal().await;
            stop_all();
        });
    }
    let grpc = server.add_routes(service.clone().into_server()).serve_with_incoming_shutdown(
        tessera_coordinator::service::incoming(listener),
        until_stopped(stopped.clone()),
    );
    // Both servers are awaited to the end: the web side drops its connections at once,
    // and returning then would cut gRPC's graceful drain (a submission acknowledged in it
    // lost) short. A web server that fails stops the coordinator too, rather than leave it
    // running without the dashboard it was asked for.
    let (grpc, web) = match web {
        Some(web) => {
            let web = async move {
                let r = web.await;
                stop_all();
                r
            };
            let (g, w) = tokio::join!(grpc, web);
            (g, Some(w))
        }
        None => (grpc.await, None),
    };
    tracing::info!("shutting down");
    let n = service.checkpoint(true).await.context("writing the last checkpoints")?;
    if n > 0 {
        tracing::info!(jobs = n, "checkpointed");
    }
    grpc.context("coordinator server failed")?;
    if let Some(web) = web {
        web.context("the web server panicked")??;
    }
    Ok(())
}

/// Serves the web dashboard and the HTTP API of `service` on `addr` until `shutdown`.
async fn serve_web(
    addr: SocketAddr,
    service: CoordinatorService,
    tls: Option<ServerTls>,
    shutdown: impl std::future::Future<Output = ()>,
) -> Result<()> {
    let acceptor = match &tls {
        Some(tls) => {
            let (cert, key) = tls.pem();
            Some(tessera_web::tls_acceptor(cert, key).context("--http with --tls-cert")?)
        }
        None => None,
    };
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("--http: cannot listen on {addr}"))?;
    tracing::info!(
        "web dashboard on {}://{}",
        if acceptor.is_some() { "https" } else { "http" },
        listener.local_addr()?
    );
    let router = tessera_web::router(service, tessera_web::WebConfig { secure_cookies: acceptor.is_some() });
    tessera_web::serve(listener, router, acceptor, shutdown).await.context("the web server failed")
}

/// A client of the coordinator.
pub async fn connect(conn: &ClientArgs) -> Result<Client> {
    Ok(tessera_proto::connect::client(&conn.endpoint()?).await?)
}

/// `tessera submit`.
pub async fn submit(args: SubmitArgs) -> Result<ExitCode> {
    let frames = crate::frames::parse(args.frames.as_deref())?;
    let (noise, noise_min) = args.halt.noise_target()?;
    if let Some(out) = &args.output {
        crate::check_output(out)?;
        args.layers.check(Some(out))?;
        crate::frames::check_pattern(out, frames)?;
    }
    let bundle = Bundle::read(&args.scene)?;
    // Refuse a bad scene here, with its location, before any network traffic; nothing is
    // built for that.
    tessera_description::Description::parse(&bundle)?;
    let mut client = connect(&args.conn).await?;
    let response = client
        .submit(pb::SubmitRequest {
            protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
            bundle: Some(bundle_to_wire(&bundle)),
            settings: Some(settings_to_wire(&JobSettings {
                spp: args.spp,
                size: args.size,
                time_limit: args.halt.time,
                noise,
                noise_min,
                aovs: args.layers.aovs(),
                frames,
            })),
            priority: args.priority,
        })
        .await
        .map_err(status_error)?
        .into_inner();
    let job = JobId(response.job_id);
    eprintln!("submitted {job}: {}x{}, {} spp", response.width, response.height, response.spp);
    println!("{}", job.0);
    if args.output.is_none() && !args.wait {
        return Ok(ExitCode::SUCCESS);
    }
    let state = wait(&mut client, job).await?.state;
    if let JobState::Failed(e) = &state {
        bail!("{job} failed: {e}");
    }
    if let (Some(out), Some((first, last))) = (&args.output, frames) {
        for frame in first..=last {
            let path = crate::frames::frame_path(out, frame);
            let (w, h, rgb, layers) =
                crate::layers::fetch(&mut client, job, Some(frame), &args.layers).await?;
            crate::layers::write(&path, w, h, &rgb, layers, &args.layers)?;
        }
        let (a, b) = (crate::frames::frame_path(out, first), crate::frames::frame_path(out, last));
        eprintln!("wrote frames {first}-{last} ({} .. {}), {job} {}", a.display(), b.display(), state.name());
    } else if let Some(out) = &args.output {
        let (w, h, rgb, layers) = crate::layers::fetch(&mut client, job, None, &args.layers).await?;
        crate::layers::write(out, w, h, &rgb, layers, &args.layers)?;
        eprintln!("wrote {} ({w}x{h}), {job} {}", out.display(), state.name());
    }
    Ok(if state == JobState::Done { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// How long `submit --wait` keeps trying a lost coordinator.
const RECONNECT_FOR: Duration = Duration::from_secs(60);

/// Polls a job until it is over, with a progress bar; rides out a coordinator restart.
async fn wait(client: &mut Client, job: JobId) -> Result<JobProgress> {
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("pass {prefix} [{bar:32}] {percent:>3}% {msg} ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let mut said_waiting = false;
    let mut lost_since: Option<std::time::Instant> = None;
    let mut backoff = Backoff::new(Duration::from_millis(250), Duration::from_secs(2));
    loop {
        let response = match client.status(pb::StatusRequest { job_id: job.0 }).await {
            Ok(r) => {
                backoff.reset();
                if lost_since.take().is_some() {
                    bar.suspend(|| eprintln!("{job}: reconnected to the coordinator"));
                }
                r.into_inner()
            }
            // A coordinator restarting on its data directory comes back with the job. A
            // connection cut in the middle of a call surfaces as Unknown or Cancelled
            // ("transport error"), not only as Unavailable: all three mean "lost".
            Err(s)
                if matches!(
                    s.code(),
                    tonic::Code::Unavailable | tonic::Code::Unknown | tonic::Code::Cancelled
                ) =>
            {
                let since = *lost_since.get_or_insert_with(|| {
                    bar.suspend(|| eprintln!("{job}: lost the coordinator ({}); reconnecting", s.message()));
                    std::time::Instant::now()
                });
                if since.elapsed() > RECONNECT_FOR {
                    bail!("lost the coordinator for {RECONNECT_FOR:?}: {}", s.message());
                }
                tokio::time::sleep(backoff.next_delay()).await;
                continue;
            }
            Err(s) => return Err(status_error(s)),
        };
        // Say it once, also where the bar is hidden (no terminal): a job with no worker
        // otherwise looks like a hang.
        if response.workers.is_empty() && !said_waiting {
            bar.suspend(|| eprintln!("{job}: no workers connected; waiting for a worker to join"));
            said_waiting = true;
        } else if !response.workers.is_empty() {
            said_waiting = false;
        }
        let s = response.jobs.into_iter().next().ok_or_else(|| anyhow!("{job} vanished"))?;
        let s = status_from_wire(s).with_context(|| format!("the coordinator's status of {job}"))?;
        let total = s.samples_total.max(1) as f64;
        bar.set_prefix(s.pass.to_string());
        bar.set_position((s.samples_done as f64 / total * 1000.0) as u64);
        let waiting = if response.workers.is_empty() { ", waiting for workers" } else { "" };
        bar.set_message(format!("{}{waiting}", crate::report::rate(s.samples_per_second)));
        if s.state.is_over() {
            bar.finish_and_clear();
            return Ok(s);
        }
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
}

/// `tessera status`.
pub async fn status(conn: &ClientArgs, each_frame: bool) -> Result<ExitCode> {
    let mut client = connect(conn).await?;
    let s = client.status(pb::StatusRequest { job_id: 0 }).await.map_err(status_error)?.into_inner();
    let out = crate::status::table(&s, each_frame);
    // A reader that stops early (`| head`, `grep -q`) is not an error.
    use std::io::Write as _;
    match std::io::stdout().lock().write_all(out.as_bytes()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e).context("writing the status"),
        _ => Ok(ExitCode::SUCCESS),
    }
}

/// `tessera pause` and `tessera resume`.
pub async fn pause(conn: &ClientArgs, job: JobId, paused: bool) -> Result<ExitCode> {
    let mut client = connect(conn).await?;
    client.pause(pb::PauseRequest { job_id: job.0, paused }).await.map_err(status_error)?;
    eprintln!("{} {job}", if paused { "paused" } else { "resumed" });
    Ok(ExitCode::SUCCESS)
}

/// `tessera priority`.
pub async fn set_priority(conn: &ClientArgs, job: JobId, priority: i32) -> Result<ExitCode> {
    let mut client = connect(conn).await?;
    client.set_priority(pb::SetPriorityRequest { job_id: job.0, priority }).await.map_err(status_error)?;
    eprintln!("{job} has priority {priority}");
    Ok(ExitCode::SUCCESS)
}

/// `tessera cancel`.
pub async fn cancel(conn: &ClientArgs, job: JobId) -> Result<ExitCode> {
    let mut client = connect(conn).await?;
    client.cancel(pb::CancelRequest { job_id: job.0 }).await.map_err(status_error)?;
    eprintln!("cancelled {job}");
    Ok(ExitCode::SUCCESS)
}
