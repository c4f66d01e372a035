//! `tessera bench submit`: a huge scene submitted to a coordinator process on loopback
//! while another client polls `Status`. The coordinator validates the scene outside the
//! farm's lock, so Status should keep answering throughout; its peak memory shows that it
//! holds the bundle and never builds the geometry.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use tessera_description::bundle::Bundle;
use tessera_description::{limits, Description};
use tessera_proto::connect::EndpointConfig;
use tessera_proto::v1 as pb;

/// How often the second client asks for Status, as a watching `tessera status` loop would.
const STATUS_EVERY: Duration = Duration::from_millis(10);
/// How long Status is still polled after the submit returned: the unloaded baseline.
const AFTER: Duration = Duration::from_secs(1);

/// What to measure.
#[derive(Debug, Clone)]
pub struct SubmitOptions {
    /// Triangles of the one OBJ mesh.
    pub triangles: usize,
    /// `[[mesh]]` entries that use it.
    pub meshes: usize,
}

/// A temporary directory removed when dropped, also on an error.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Writes a regular grid of exactly `triangles` triangles (two per cell, the last cell
/// possibly half) on the unit square, gently waved so that it is not a plane.
fn write_grid(path: &Path, triangles: usize) -> Result<()> {
    let cells = triangles.div_ceil(2);
    let cols = (cells as f64).sqrt().ceil().max(1.0) as usize;
    let rows = cells.div_ceil(cols);
    let mut out = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(path)?);
    writeln!(out, "# {triangles} triangles: a {cols}x{rows} grid, written by tessera bench submit")?;
    for j in 0..=rows {
        for i in 0..=cols {
            let (x, z) = (i as f64 / cols as f64, j as f64 / rows as f64);
            let y = 0.02 * (x * 25.0).sin() * (z * 25.0).cos();
            writeln!(out, "v {x:.5} {y:.5} {z:.5}")?;
        }
    }
    let vertex = |i: usize, j: usize| 1 + j * (cols + 1) + i;
    let mut left = triangles;
    'cells: for j in 0..rows {
        for i in 0..cols {
            let (a, b, c, d) = (vertex(i, j), vertex(i + 1, j), vertex(i + 1, j + 1), vertex(i, j + 1));
            for [p, q, r] in [[a, b, c], [a, c, d]] {
                if left == 0 {
                    break 'cells;
                }
                writeln!(out, "f {p} {q} {r}")?;
                left -= 1;
            }
        }
    }
    out.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    Ok(())
}

/// The scene: `meshes` uses of grid.obj, each placed and turned differently, a camera
/// and a light.
fn scene_text(meshes: usize) -> String {
    let mut s = String::from(
        "# Written by tessera bench submit: one OBJ grid used by many meshes.\n\
         [render]\nwidth = 640\nheight = 480\nspp = 16\n\n\
         [camera]\nposition = [0, 8, 14]\nlook_at = [0, 0, -3]\n\n\
         [materials.grey]\ntype = \"lambert\"\nalbedo = 0.7\n\n",
    );
    for k in 0..meshes {
        let (x, z) = ((k % 6) as f64 * 2.2 - 5.5, (k / 6) as f64 * -2.2);
        let (tilt, turn) = ((k % 5) as f64 * 6.0, k as f64 * 15.0);
        s.push_str(&format!(
            "[[mesh]]\nfile = \"grid.obj\"\nmaterial = \"grey\"\n\
             transform = {{ translate = [{x:.2}, 0, {z:.2}], rotate = [{tilt}, {turn}, 0], scale = 1.8 }}\n\n"
        ));
    }
    s.push_str("[[point_light]]\nposition = [3, 10, 6]\nintensity = 150\n");
    s
}

/// Peak (`VmHWM`) or current (`VmRSS`) resident memory of a process, in MB.
fn memory_mb(pid: u32, field: &str) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// p50, p99 and max of latencies, in ms (nearest rank).
fn latency_ms(mut v: Vec<Duration>) -> Option<(f64, f64, f64)> {
    if v.is_empty() {
        return None;
    }
    v.sort_unstable();
    let at = |q: f64| v[((v.len() as f64 * q).ceil() as usize).clamp(1, v.len()) - 1].as_secs_f64() * 1e3;
    Some((at(0.5), at(0.99), at(1.0)))
}

fn row(what: &str, time: Option<Duration>, calls: usize, lat: Option<(f64, f64, f64)>) {
    let time = time.map_or("-".into(), |t| format!("{:.3} s", t.as_secs_f64()));
    let lat = lat.map_or(format!("{:>8} {:>8} {:>8}", "-", "-", "-"), |(a, b, c)| {
        format!("{a:>8.2} {b:>8.2} {c:>8.2}")
    });
    println!("{what:<34} {time:>9} {calls:>7} {lat}");
}

/// Runs the benchmark and prints its table.
pub async fn run(opts: SubmitOptions) -> Result<()> {
    let total = opts.triangles.checked_mul(opts.meshes).filter(|&t| t <= limits::MAX_TRIANGLES);
    let Some(total) = total else {
        bail!("--triangles x --meshes must be at most {} (the scene limit)", limits::MAX_TRIANGLES);
    };
    let dir = TempDir(std::env::temp_dir().join(format!("tessera-bench-submit-{}", std::process::id())));
    std::fs::create_dir_all(&dir.0).with_context(|| format!("creating {}", dir.0.display()))?;
    let scene = dir.0.join("scene.toml");
    write_grid(&dir.0.join("grid.obj"), opts.triangles).context("writing the mesh")?;
    std::fs::write(&scene, scene_text(opts.meshes)).context("writing the scene")?;
    let bundle = Bundle::read(&scene)?;
    let bytes: usize = bundle.text.len() + bundle.assets.iter().map(|(_, a)| a.len()).sum::<usize>();
    let mb = bytes as f64 / 1e6;

    // What `tessera submit` does before any network traffic, timed in this process.
    let (bundle, parsed, client_time) = tokio::task::spawn_blocking(move || {
        let t = Instant::now();
        let parsed = Description::parse(&bundle);
        (bundle, parsed, t.elapsed())
    })
    .await?;
    let summary = parsed.context("the generated scene")?.summary(false);
    if summary.triangles != total as u64 {
        bail!("the scene counts {} triangles, expected {total}", summary.triangles);
    }

    let (mut coord, url) = super::farm::start_coordinator(&[]).await?;
    let pid = coord.id().ok_or_else(|| anyhow!("the coordinator has no pid"))?;
    let config = EndpointConfig::new(&url)?;
    let mut submitter = tessera_proto::connect::client(&config).await?;
    // Its own connection, as a separate `tessera status` process has.
    let mut poller = tessera_proto::connect::client(&config).await?;
    poller.status(pb::StatusRequest { job_id: 0 }).await?;
    let rss_before = memory_mb(pid, "VmRSS:");

    let stop = Arc::new(AtomicBool::new(false));
    let polling = tokio::spawn({
        let (stop, mut poller) = (stop.clone(), poller.clone());
        async move {
            let mut samples: Vec<(Instant, Duration)> = Vec::new();
            let mut tick = tokio::time::interval(STATUS_EVERY);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            while !stop.load(Ordering::Relaxed) {
                tick.tick().await;
                let sent = Instant::now();
                poller.status(pb::StatusRequest { job_id: 0 }).await?;
                samples.push((sent, sent.elapsed()));
            }
            Ok::<_, tonic::Status>(samples)
        }
    });
    let request = pb::SubmitRequest {
        protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
        bundle: Some(tessera_proto::convert::bundle_to_wire(&bundle)),
        settings: Some(pb::RenderSettings::default()),
        priority: 0,
    };
    drop(bundle);
    let start = Instant::now();
    let response = submitter.submit(request).await;
    let end = Instant::now();
    tokio::time::sleep(AFTER).await;
    stop.store(true, Ordering::Relaxed);
    let samples = polling.await?.context("Status failed")?;
    let response = response.context("Submit failed")?.into_inner();
    let listed = poller.status(pb::StatusRequest { job_id: response.job_id }).await?.into_inner();
    let peak = memory_mb(pid, "VmHWM:");
    let _ = coord.kill().await;
    let job = listed.jobs.first().ok_or_else(|| anyhow!("job {} is not listed", response.job_id))?;
    if job.spp != summary.spp || (job.width, job.height) != (summary.width, summary.height) {
        bail!("job {} is listed with other figures than its scene's", response.job_id);
    }

    let during: Vec<Duration> =
        samples.iter().filter(|(s, _)| (start..end).contains(s)).map(|&(_, l)| l).collect();
    let after: Vec<Duration> = samples.iter().filter(|(s, _)| *s >= end).map(|&(_, l)| l).collect();
    println!(
        "scene: one OBJ grid of {} triangles used by {} [[mesh]] entries: {total} triangles; bundle {mb:.1} MB; \
         {} cores",
        opts.triangles,
        opts.meshes,
        crate::cores()
    );
    println!("{:<34} {:>9} {:>7} {:>8} {:>8} {:>8}", "", "time", "Status", "p50 ms", "p99 ms", "max ms");
    row("Submit over gRPC, while polled", Some(end - start), during.len(), latency_ms(during));
    row(&format!("the {:.0} s after it returned", AFTER.as_secs_f64()), None, after.len(), latency_ms(after));
    row("client-side validation (in-process)", Some(client_time), 0, None);
    let mem = |m: Option<f64>| m.map_or("?".into(), |m| format!("{m:.0} MB"));
    println!(
        "coordinator memory: {} resident before the submit, peak (VmHWM) {}; the bundle is {mb:.1} MB, a \
         worker's built scene an estimated {:.0} MB",
        mem(rss_before),
        mem(peak),
        summary.worker_bytes as f64 / 1e6
    );
    println!(
        "columns: time = Submit sent to answered (upload, the coordinator's validation, queueing), or \
         Description::parse of the bundle as `tessera submit` runs it before sending; Status = calls sent \
         every {} ms on a second connection while the submit was in flight, then after it; p50/p99/max = \
         their latency",
        STATUS_EVERY.as_millis()
    );
    Ok(())
}
