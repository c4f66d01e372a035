//! The headless viewer: follows a job and writes snapshots, for servers, scripts and tests.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use tessera_description::ids::JobId;
use tessera_proto::connect::{ConnectError, EndpointConfig};
use tracing::info;

use crate::conn::Watch;
use crate::state::{Replica, UpdateError};

/// When to write the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum When {
    /// Every so often while the job runs, and at its end.
    Every(Duration),
    /// Once, when this percent of the samples is done (then exit).
    At(f64),
    /// Once, at the end of the job.
    End,
}

/// What the headless viewer does.
#[derive(Debug, Clone)]
pub struct Headless {
    /// Where the coordinator is.
    pub coordinator: EndpointConfig,
    /// The job (`None`: the running one, else the newest).
    pub job: Option<JobId>,
    /// The frame of a sequence (`None`: its first).
    pub frame: Option<u32>,
    /// Where to write (.png or .exr), replaced atomically at each snapshot.
    pub save: PathBuf,
    /// When.
    pub when: When,
    /// How long to keep reconnecting to a lost coordinator.
    pub reconnect_for: std::time::Duration,
}

/// How a headless run failed.
#[derive(Debug, thiserror::Error)]
pub enum HeadlessError {
    /// The connection.
    #[error(transparent)]
    Conn(#[from] ConnectError),
    /// A malformed update.
    #[error("the coordinator sent a malformed update: {0}")]
    Update(#[from] UpdateError),
    /// Writing the image.
    #[error(transparent)]
    Output(#[from] tessera_film::output::OutputError),
    /// The stream ended before anything arrived.
    #[error("the coordinator closed the stream before sending an image")]
    Empty,
    /// The tev bridge failed.
    #[error("{0}")]
    Tev(String),
}

/// What a headless run ended with.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Snapshots written.
    pub snapshots: u32,
    /// Percent done at the last one.
    pub percent: f64,
    /// Whether the job had ended.
    pub finished: bool,
}

fn write(r: &Replica, save: &std::path::Path) -> Result<(), HeadlessError> {
    let (w, h, rgb) = r.image().ok_or(HeadlessError::Empty)?;
    tessera_film::output::write_image(save, w, h, &rgb)?;
    info!("{}: wrote {}", r.status_line(), save.display());
    Ok(())
}

/// Runs until the job ends (or the `At` percentage is reached). A coordinator that goes
/// away mid-stream is an error, after the last complete image has been written.
pub async fn run(h: Headless) -> Result<Outcome, HeadlessError> {
    // A snapshot at a given percentage wants fine-grained updates to land close to it.
    let rate = if matches!(h.when, When::At(_)) { 50.0 } else { 10.0 };
    let mut watch = Watch::open_frame(&h.coordinator, h.job, h.frame, rate, h.reconnect_for).await?;
    let mut replica = Replica::new();
    let mut snapshots = 0;
    let mut last = Instant::now();
    loop {
        let update = match watch.next().await {
            Ok(Some(u)) => u,
            Ok(None) => break,
            Err(e) => {
                if replica.size().is_some() && snapshots == 0 {
                    write(&replica, &h.save)?;
                }
                return Err(e.into());
            }
        };
        let chunk_end = update.chunk_end;
        replica.apply(update)?;
        if !chunk_end {
            continue;
        }
        match h.when {
            When::At(p) if replica.percent() >= p || replica.finished => {
                write(&replica, &h.save)?;
                return Ok(Outcome { snapshots: 1, percent: replica.percent(), finished: replica.finished });
            }
            When::Every(d) if last.elapsed() >= d && !replica.finished => {
                write(&replica, &h.save)?;
                snapshots += 1;
                last = Instant::now();
            }
            _ => {}
        }
        if replica.finished {
            break;
        }
    }
    if replica.size().is_none() {
        return Err(HeadlessError::Empty);
    }
    write(&replica, &h.save)?;
    Ok(Outcome { snapshots: snapshots + 1, percent: replica.percent(), finished: replica.finished })
}
