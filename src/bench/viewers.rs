//! `tessera bench viewers`: what viewers cost a render. A standalone coordinator process
//! and local workers render the same job with 0 viewers, 8 viewers, and 8 viewers of which
//! one never reads; prints the wall times as ratios to 0 viewers and the coordinator's
//! peak memory (VmHWM) in each case.

use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use tessera_description::ids::JobId;
use tessera_description::job::JobState;
use tessera_proto::connect::EndpointConfig;
use tessera_proto::convert::state_from_wire;
use tessera_proto::v1 as pb;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

async fn spawn(args: &[&str]) -> Result<Child> {
    let exe = std::env::current_exe()?;
    Command::new(exe)
        .args(args)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .context("starting a tessera process")
}

fn peak_rss_mb(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// One case: returns wall time from submission to the end, and the coordinator's peak RSS.
async fn case(
    scene: &Path,
    spp: Option<u32>,
    viewers: usize,
    stalled: usize,
) -> Result<(Duration, Option<f64>, f64)> {
    let mut coord = spawn(&["coordinator", "--listen", "127.0.0.1:0"]).await?;
    let mut lines = BufReader::new(coord.stderr.take().expect("piped")).lines();
    let url = loop {
        let line = lines.next_line().await?.ok_or_else(|| anyhow!("the coordinator exited"))?;
        if let Some(addr) = line.split("listening on ").nth(1) {
            break format!("http://{}", addr.trim());
        }
    };
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    let cores = crate::cores();
    let mut workers = Vec::new();
    for _ in 0..cores {
        workers
            .push(spawn(&["worker", "--coordinator", &url, "--threads", "1", "--exit-on-disconnect"]).await?);
    }
    let endpoint = EndpointConfig::new(&url)?;
    let mut client = tessera_proto::connect::client(&endpoint).await?;
    // Wait for the workers, so that every case starts alike.
    let t = Instant::now();
    while client.status(pb::StatusRequest { job_id: 0 }).await?.into_inner().workers.len() < cores {
        if t.elapsed() > Duration::from_secs(30) {
            bail!("workers did not connect");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let bundle = tessera_description::bundle::Bundle::read(scene)?;
    let start = Instant::now();
    let job = client
        .submit(pb::SubmitRequest {
            protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
            bundle: Some(tessera_proto::convert::bundle_to_wire(&bundle)),
            settings: Some(pb::RenderSettings { spp: spp.unwrap_or(0), ..Default::default() }),
            priority: 0,
        })
        .await?
        .into_inner()
        .job_id;
    let mut tasks = Vec::new();
    let mut held = Vec::new();
    for v in 0..viewers {
        let mut watch =
            tessera_viewer::conn::Watch::open(&endpoint, Some(JobId(job)), 10.0, Duration::ZERO).await?;
        if v < stalled {
            // Opened and never read.
            held.push(watch);
            continue;
        }
        tasks.push(tokio::spawn(async move {
            let mut replica = tessera_viewer::state::Replica::new();
            let mut bytes = 0usize;
            while let Ok(Some(u)) = watch.next().await {
                bytes += prost::Message::encoded_len(&u);
                if replica.apply(u).is_err() || replica.finished {
                    break;
                }
            }
            (replica.finished, bytes)
        }));
    }
    loop {
        let s = client.status(pb::StatusRequest { job_id: job }).await?.into_inner();
        if s.jobs.first().is_some_and(|j| state_from_wire(j.state, &j.error) == Ok(JobState::Done)) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let wall = start.elapsed();
    let mut bytes = Vec::new();
    for t in tasks {
        match t.await {
            Ok((true, b)) => bytes.push(b as f64),
            _ => bail!("a reading viewer did not receive the final image"),
        }
    }
    let per_viewer = if bytes.is_empty() {
        0.0
    } else {
        bytes.iter().sum::<f64>() / bytes.len() as f64 / wall.as_secs_f64()
    };
    let peak = coord.id().and_then(peak_rss_mb);
    drop(held);
    let _ = coord.kill().await;
    for mut w in workers {
        let _ = w.kill().await;
    }
    Ok((wall, peak, per_viewer))
}

/// Runs the benchmark.
pub async fn run(scene: &Path, spp: Option<u32>, runs: usize) -> Result<()> {
    println!("scene {}, {} local workers; each case's fastest of {runs}", scene.display(), crate::cores());
    let cases = [("0 viewers", 0, 0), ("8 viewers", 8, 0), ("8 viewers, 1 stalled", 8, 1)];
    let mut best = [Duration::MAX; 3];
    let mut peaks = [0.0f64; 3];
    let mut rates = [0.0f64; 3];
    for _ in 0..runs {
        for (i, (_, viewers, stalled)) in cases.iter().enumerate() {
            let (wall, peak, rate) = case(scene, spp, *viewers, *stalled).await?;
            best[i] = best[i].min(wall);
            peaks[i] = peaks[i].max(peak.unwrap_or(0.0));
            rates[i] = rates[i].max(rate);
        }
    }
    println!(
        "{:<22} {:>9} {:>9} {:>14} {:>16}",
        "case", "wall s", "ratio", "coord peak MB", "MB/s per viewer"
    );
    for (i, (name, _, _)) in cases.iter().enumerate() {
        println!(
            "{name:<22} {:>9.3} {:>9.3} {:>14.1} {:>16.2}",
            best[i].as_secs_f64(),
            best[i].as_secs_f64() / best[0].as_secs_f64(),
            peaks[i],
            rates[i] / 1e6
        );
    }
    Ok(())
}
