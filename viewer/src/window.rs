//! The desktop viewer: a window that shows the refining image scaled to the window, with
//! the status in its title. Keys: S saves the current image (PNG and EXR), P pauses and
//! resumes the job, + and - change the exposure, Q or Escape quits. The network runs on
//! its own thread and only fills the replica; this loop only draws.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use minifb::{Key, KeyRepeat, Window, WindowOptions};
use tessera_description::ids::JobId;
use tessera_proto::connect::EndpointConfig;
use tessera_proto::v1 as pb;

use crate::conn::Watch;
use crate::state::Replica;

/// Why the window could not run.
#[derive(Debug, thiserror::Error)]
pub enum WindowError {
    /// No display, or the window system refused.
    #[error("cannot open a window ({0}); use --save OUT to write snapshots without a display")]
    Open(String),
    /// The network thread could not start.
    #[error("cannot start the network thread: {0}")]
    Runtime(String),
}

/// What the network thread reports.
#[derive(Debug, Default)]
struct Shared {
    replica: Replica,
    /// Set when the stream ended or failed.
    ended: Option<String>,
}

/// Opens the window on job `job` (`None`: the running one) of the coordinator at `endpoint`;
/// blocks until the window is closed.
pub fn run(
    endpoint: &EndpointConfig,
    job: Option<JobId>,
    reconnect_for: Duration,
) -> Result<(), WindowError> {
    run_frame(endpoint, job, None, reconnect_for)
}

/// As `run`, showing frame `frame` of a sequence (`None`: its first).
pub fn run_frame(
    endpoint: &EndpointConfig,
    job: Option<JobId>,
    frame: Option<u32>,
    reconnect_for: Duration,
) -> Result<(), WindowError> {
    let shared = Arc::new(Mutex::new(Shared::default()));
    let net = shared.clone();
    let net_endpoint = endpoint.clone();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| WindowError::Runtime(e.to_string()))?;
    let handle = runtime.handle().clone();
    std::thread::Builder::new()
        .name("viewer-net".into())
        .spawn(move || {
            runtime.block_on(async move {
                let ended = match Watch::open_frame(&net_endpoint, job, frame, 20.0, reconnect_for).await {
                    Err(e) => e.to_string(),
                    Ok(mut watch) => loop {
                        match watch.next().await {
                            Ok(Some(u)) => {
                                let mut s = net.lock().unwrap_or_else(|e| e.into_inner());
                                if let Err(e) = s.replica.apply(u) {
                                    break format!("the coordinator sent a malformed update: {e}");
                                }
                            }
                            Ok(None) => break "the job is over".into(),
                            Err(e) => break e.to_string(),
                        }
                    },
                };
                net.lock().unwrap_or_else(|e| e.into_inner()).ended = Some(ended);
            })
        })
        .map_err(|e| WindowError::Runtime(e.to_string()))?;

    let (mut w, mut h) = (640usize, 400usize);
    let mut window = Window::new("Tessera", w, h, WindowOptions { resize: true, ..WindowOptions::default() })
        .map_err(|e| WindowError::Open(e.to_string()))?;
    window.set_target_fps(30);
    let mut exposure = 0.0f32;
    let mut image: Option<(u32, u32, Vec<f32>)> = None;
    let mut seen_version = u64::MAX;
    let mut last_resolve = Instant::now() - Duration::from_secs(1);
    let mut buffer = vec![0u32; w * h];
    let mut note = String::new();
    while window.is_open() && !window.is_key_down(Key::Q) && !window.is_key_down(Key::Escape) {
        let (title, job_id, paused) = {
            let s = shared.lock().unwrap_or_else(|e| e.into_inner());
            // Resolving costs O(N log N): at most every 100 ms, and only on a new version.
            if s.replica.version != seen_version && last_resolve.elapsed() > Duration::from_millis(100) {
                image = s.replica.image();
                seen_version = s.replica.version;
                last_resolve = Instant::now();
            }
            let ended = s.ended.as_deref().map(|e| format!(" — {e}")).unwrap_or_default();
            let paused = s.replica.status.as_ref().is_some_and(|st| st.state == pb::JobState::Paused as i32);
            (format!("Tessera — {}{ended}{note}", s.replica.status_line()), s.replica.job, paused)
        };
        window.set_title(&title);
        for key in window.get_keys_pressed(KeyRepeat::No) {
            match key {
                Key::Equal | Key::NumPadPlus => exposure += 0.5,
                Key::Minus | Key::NumPadMinus => exposure -= 0.5,
                Key::S => note = save(image.as_ref(), job_id),
                Key::P => note = toggle_pause(&handle, endpoint, job_id, !paused),
                _ => {}
            }
        }
        let (nw, nh) = window.get_size();
        if (nw, nh) != (w, h) && nw > 0 && nh > 0 {
            (w, h) = (nw, nh);
            buffer = vec![0u32; w * h];
        }
        if let Some((iw, ih, rgb)) = &image {
            draw(&mut buffer, w, h, *iw as usize, *ih as usize, rgb, exposure);
        }
        window.update_with_buffer(&buffer, w, h).map_err(|e| WindowError::Open(e.to_string()))?;
    }
    Ok(())
}

/// Scales the image into the window (nearest pixel, aspect kept), exposure in stops.
fn draw(buffer: &mut [u32], w: usize, h: usize, iw: usize, ih: usize, rgb: &[f32], exposure: f32) {
    let scale = (w as f32 / iw as f32).min(h as f32 / ih as f32);
    let (dw, dh) = ((iw as f32 * scale) as usize, (ih as f32 * scale) as usize);
    let (ox, oy) = ((w - dw.min(w)) / 2, (h - dh.min(h)) / 2);
    let gain = 2f32.powf(exposure);
    buffer.fill(0x0020_2020);
    for y in 0..dh.min(h) {
        let sy = ((y as f32 / scale) as usize).min(ih - 1);
        for x in 0..dw.min(w) {
            let sx = ((x as f32 / scale) as usize).min(iw - 1);
            let p = &rgb[(sy * iw + sx) * 3..][..3];
            let c = |v: f32| u32::from(tessera_film::output::srgb8(v * gain));
            buffer[(oy + y) * w + ox + x] = (c(p[0]) << 16) | (c(p[1]) << 8) | c(p[2]);
        }
    }
}

fn save(image: Option<&(u32, u32, Vec<f32>)>, job: Option<JobId>) -> String {
    let (Some((w, h, rgb)), Some(JobId(job))) = (image, job) else {
        return " — nothing to save yet".into();
    };
    let mut saved = Vec::new();
    for ext in ["png", "exr"] {
        let path = PathBuf::from(format!("tessera-job{job}.{ext}"));
        match tessera_film::output::write_image(&path, *w, *h, rgb) {
            Ok(()) => saved.push(path.display().to_string()),
            Err(e) => return format!(" — {e}"),
        }
    }
    format!(" — saved {}", saved.join(" and "))
}

fn toggle_pause(
    handle: &tokio::runtime::Handle,
    endpoint: &EndpointConfig,
    job: Option<JobId>,
    pause: bool,
) -> String {
    let Some(JobId(job)) = job else { return " — no job to pause yet".into() };
    let result = std::thread::scope(|s| {
        s.spawn(|| {
            handle.block_on(async move {
                let mut client = tessera_proto::connect::client(endpoint).await.map_err(|e| e.to_string())?;
                client
                    .pause(pb::PauseRequest { job_id: job, paused: pause })
                    .await
                    .map_err(|s| s.message().to_string())
            })
        })
        .join()
    });
    match result {
        Ok(Ok(_)) => (if pause { " — paused" } else { " — resumed" }).into(),
        Ok(Err(e)) => format!(" — {e}"),
        Err(_) => " — pause failed".into(),
    }
}
