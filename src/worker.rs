//! `tessera worker`: a worker process's arguments and start.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};

use crate::{cores, parse_bytes, remote, shutdown_signal};

/// Arguments of `tessera worker`.
#[derive(Debug, clap::Args)]
#[deny(missing_docs)]
pub struct WorkerArgs {
    /// Where the coordinator is and how to reach it.
    #[command(flatten)]
    conn: remote::ClientArgs,
    /// Render threads [default: one per core].
    #[arg(long)]
    threads: Option<usize>,
    /// Name shown in status [default: host name and process id].
    #[arg(long)]
    name: Option<String>,
    /// Exit when the coordinator goes away instead of reconnecting.
    #[arg(long)]
    exit_on_disconnect: bool,
    /// Memory one scene may take here, e.g. 16G; a larger scene is refused and its job goes
    /// to other workers [default: the memory available at start].
    #[arg(long, env = "TESSERA_WORKER_MEMORY", value_parser = parse_bytes)]
    memory: Option<u64>,
    /// A scene to build at start, while the worker connects: a job of the same scene (the
    /// same content) then starts without building it, and the coordinator sends it by its
    /// hash alone instead of the scene and its assets.
    #[arg(long, value_name = "SCENE", env = "TESSERA_PRELOAD")]
    preload: Option<PathBuf>,
}

/// Runs a worker until it is told to stop or its coordinator refuses it.
pub async fn run(args: WorkerArgs) -> Result<ExitCode> {
    let threads = args.threads.unwrap_or_else(cores);
    if threads == 0 {
        anyhow::bail!("--threads must be at least 1");
    }
    let preload = match &args.preload {
        Some(path) => Some(std::sync::Arc::new(
            tessera_description::Bundle::read(path)
                .with_context(|| format!("--preload {}", path.display()))?,
        )),
        None => None,
    };
    let config = tessera_worker::client::WorkerConfig {
        coordinator: args.conn.endpoint()?,
        preload,
        threads,
        name: args.name.unwrap_or_else(|| format!("{}:{}", host_name(), std::process::id())),
        exit_on_disconnect: args.exit_on_disconnect,
        memory: args.memory.or_else(tessera_description::machine::available_memory).unwrap_or(4 << 30),
    };
    // SIGTERM (scancel, systemd, kubelet) or Ctrl-C: leave at once, leases handed back.
    tessera_worker::client::run(config, shutdown_signal()).await?;
    Ok(ExitCode::SUCCESS)
}

/// The machine's name, for a worker's default name in status.
fn host_name() -> String {
    std::env::var("HOSTNAME")
        .ok()
        .or_else(|| std::fs::read_to_string("/etc/hostname").ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "worker".into())
}
