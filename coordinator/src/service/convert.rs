//! Wire ↔ farm conversions used by the service (public until every client uses the
//! proto crate's own).

use std::time::Duration;

use tessera_description::bundle::Bundle;
use tessera_description::job::{JobProgress, JobSettings, JobState};
use tessera_proto::v1 as pb;

/// A bundle as it travels.
pub fn bundle_to_wire(b: &Bundle) -> pb::SceneBundle {
    pb::SceneBundle {
        name: b.name.clone(),
        text: b.text.clone(),
        assets: b
            .assets
            .iter()
            .map(|(path, data)| pb::Asset { path: path.clone(), data: data.clone() })
            .collect(),
    }
}

/// A bundle from the wire.
pub fn bundle_from_wire(b: pb::SceneBundle) -> Bundle {
    let mut assets: Vec<(String, Vec<u8>)> = b.assets.into_iter().map(|a| (a.path, a.data)).collect();
    assets.sort();
    Bundle { name: b.name, text: b.text, assets }
}

/// Job settings as they travel.
pub fn settings_to_wire(s: &JobSettings) -> pb::RenderSettings {
    let (width, height) = s.size.unwrap_or((0, 0));
    pb::RenderSettings {
        spp: s.spp.unwrap_or(0),
        width,
        height,
        time_limit_seconds: s.time_limit.map_or(0.0, |t| t.as_secs_f64()),
        noise: s.noise.map_or(0.0, f64::from),
    }
}

/// Job settings from the wire; 0 means "keep the scene's".
pub fn settings_from_wire(s: pb::RenderSettings) -> Result<JobSettings, String> {
    let size = match (s.width, s.height) {
        (0, 0) => None,
        (0, _) | (_, 0) => return Err(format!("give both width and height, got {}x{}", s.width, s.height)),
        (w, h) => Some((w, h)),
    };
    let time_limit = match s.time_limit_seconds {
        0.0 => None,
        t if t.is_finite() && t > 0.0 && t < 1e9 => Some(Duration::from_secs_f64(t)),
        t => return Err(format!("time_limit_seconds must be a positive number of seconds, got {t}")),
    };
    let noise = match s.noise {
        0.0 => None,
        n if n.is_finite() && n > 0.0 && n < 1.0 => Some(n as f32),
        n => return Err(format!("noise must be a relative error in (0, 1), got {n}")),
    };
    Ok(JobSettings { spp: (s.spp != 0).then_some(s.spp), size, time_limit, noise })
}

/// A job's state as it travels.
pub fn state_to_wire(s: &JobState) -> pb::JobState {
    match s {
        JobState::Queued => pb::JobState::Queued,
        JobState::Running => pb::JobState::Running,
        JobState::Done => pb::JobState::Done,
        JobState::Cancelled => pb::JobState::Cancelled,
        JobState::Failed(_) => pb::JobState::Failed,
        JobState::Paused => pb::JobState::Paused,
    }
}

/// A job's progress as it travels.
pub fn status_to_wire(p: &JobProgress) -> pb::JobStatus {
    pb::JobStatus {
        job_id: p.id.0,
        scene: p.scene.clone(),
        state: state_to_wire(&p.state) as i32,
        width: p.width,
        height: p.height,
        spp: p.spp,
        pass: p.pass,
        samples_done: p.samples_done,
        samples_total: p.samples_total,
        samples_per_second: p.samples_per_second,
        elapsed_seconds: p.elapsed.as_secs_f64(),
        error: match &p.state {
            JobState::Failed(e) => e.clone(),
            _ => String::new(),
        },
        pass_one_done: p.pass_one_done,
        priority: p.priority,
    }
}

/// Consecutive pixels grouped into runs.
pub fn runs(pixels: &[tessera_film::PixelState]) -> Vec<pb::PixelRun> {
    let mut out: Vec<pb::PixelRun> = Vec::new();
    for p in pixels {
        match out.last_mut() {
            Some(r) if r.start as usize + r.counts.len() == p.index as usize => {
                r.sums.extend_from_slice(&p.sums);
                r.counts.push(p.count);
            }
            _ => out.push(pb::PixelRun { start: p.index, sums: p.sums.to_vec(), counts: vec![p.count] }),
        }
    }
    out
}
