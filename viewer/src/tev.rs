//! The tev bridge: forwards a job's refining image to a running tev viewer over its TCP
//! protocol, as HDR float tiles, for people who already look at pbrt's or Mitsuba's output
//! in tev. Packets (little-endian): a u32 total length, a type byte, then the fields;
//! strings end with a NUL. `CreateImage` (type 4) once, then `UpdateImage` v3 (type 6)
//! tiles of interleaved RGB floats.

use std::time::{Duration, Instant};

use tessera_description::ids::JobId;
use tessera_proto::connect::EndpointConfig;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

use crate::conn::Watch;
use crate::headless::HeadlessError;
use crate::state::Replica;

/// Rows per tile: about 1.5 MB of floats at 2048 pixels wide.
const TILE_ROWS: u32 = 64;
/// Most full-image refreshes a second sent to tev.
const MAX_REFRESH_PER_SECOND: f64 = 2.0;

fn push_str(p: &mut Vec<u8>, s: &str) {
    p.extend_from_slice(s.as_bytes());
    p.push(0);
}

fn finish(mut p: Vec<u8>) -> Vec<u8> {
    let len = p.len() as u32;
    p[..4].copy_from_slice(&len.to_le_bytes());
    p
}

/// The `CreateImage` packet for an RGB image.
pub fn create_image(name: &str, width: u32, height: u32) -> Vec<u8> {
    let mut p = vec![0, 0, 0, 0, 4, 1];
    push_str(&mut p, name);
    for v in [width as i32, height as i32, 3] {
        p.extend_from_slice(&v.to_le_bytes());
    }
    for c in ["R", "G", "B"] {
        push_str(&mut p, c);
    }
    finish(p)
}

/// An `UpdateImage` (v3) packet: rows `y..y + rows` of `rgb` (interleaved, top row first).
pub fn update_tile(name: &str, width: u32, y: u32, rows: u32, rgb: &[f32]) -> Vec<u8> {
    let mut p = vec![0, 0, 0, 0, 6, 0];
    push_str(&mut p, name);
    p.extend_from_slice(&3i32.to_le_bytes());
    for c in ["R", "G", "B"] {
        push_str(&mut p, c);
    }
    for v in [0, y as i32, width as i32, rows as i32] {
        p.extend_from_slice(&v.to_le_bytes());
    }
    for offset in [0i64, 1, 2] {
        p.extend_from_slice(&offset.to_le_bytes());
    }
    for _ in 0..3 {
        p.extend_from_slice(&3i64.to_le_bytes());
    }
    let start = (y * width * 3) as usize;
    let end = ((y + rows) * width * 3) as usize;
    for v in &rgb[start..end] {
        p.extend_from_slice(&v.to_le_bytes());
    }
    finish(p)
}

/// Follows job `job` at `coordinator` and mirrors it into tev at `tev` (HOST:PORT) until
/// the job ends.
pub async fn run(
    coordinator: &EndpointConfig,
    job: Option<JobId>,
    tev: &str,
    reconnect_for: Duration,
) -> Result<(), HeadlessError> {
    run_frame(coordinator, job, None, tev, reconnect_for).await
}

/// As `run`, forwarding frame `frame` of a sequence (`None`: its first).
pub async fn run_frame(
    coordinator: &EndpointConfig,
    job: Option<JobId>,
    frame: Option<u32>,
    tev: &str,
    reconnect_for: Duration,
) -> Result<(), HeadlessError> {
    let mut socket = TcpStream::connect(tev)
        .await
        .map_err(|e| HeadlessError::Tev(format!("cannot reach tev at {tev}: {e} (is tev running?)")))?;
    let mut watch = Watch::open_frame(coordinator, job, frame, 10.0, reconnect_for).await?;
    let mut replica = Replica::new();
    let mut created = false;
    let mut last = Instant::now() - Duration::from_secs(1);
    loop {
        let update = watch.next().await?;
        let done = update.is_none();
        if let Some(u) = update {
            let chunk_end = u.chunk_end;
            replica.apply(u)?;
            if !chunk_end
                || (!replica.finished && last.elapsed().as_secs_f64() < 1.0 / MAX_REFRESH_PER_SECOND)
            {
                continue;
            }
        }
        let Some((w, h, rgb)) = replica.image() else { return Err(HeadlessError::Empty) };
        let name = format!("tessera job {}", replica.job.map_or(0, |j| j.0));
        let send = |e: std::io::Error| HeadlessError::Tev(format!("lost tev at {tev}: {e}"));
        if !created {
            socket.write_all(&create_image(&name, w, h)).await.map_err(send)?;
            created = true;
        }
        let mut y = 0;
        while y < h {
            let rows = TILE_ROWS.min(h - y);
            socket.write_all(&update_tile(&name, w, y, rows, &rgb)).await.map_err(send)?;
            y += rows;
        }
        last = Instant::now();
        if done || replica.finished {
            return Ok(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_have_their_length_and_layout() {
        let c = create_image("a", 2, 1);
        assert_eq!(u32::from_le_bytes(c[..4].try_into().unwrap()) as usize, c.len());
        assert_eq!(&c[4..8], &[4, 1, b'a', 0]);
        let rgb: Vec<f32> = (0..12).map(|i| i as f32).collect();
        let u = update_tile("a", 2, 1, 1, &rgb);
        assert_eq!(u32::from_le_bytes(u[..4].try_into().unwrap()) as usize, u.len());
        // Header, 3 channel names, x y w h, 3 offsets, 3 strides, then 2 pixels × 3 floats.
        let header = 4 + 2 + 2 + 4 + 6 + 16 + 24 + 24;
        assert_eq!(u.len(), header + 6 * 4);
        assert_eq!(f32::from_le_bytes(u[header..header + 4].try_into().unwrap()), 6.0);
    }
}
