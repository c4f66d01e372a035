//! Every conversion between the wire's types and the domain's (`tessera-description`), in
//! one place so that the coordinator and every client read and write the wire alike.
//!
//! On the wire, 0 means "none" for ids and "keep the scene's" for settings; here those are
//! `Option`s. A watch update's pixels travel as an encoded `PixelRuns`
//! ([`pixels_to_wire`], [`pixels_from_wire`]).

use std::time::Duration;

use bytes::Bytes;
use prost::Message;
use tessera_description::ids::{BatchId, JobId, WorkerId};
use tessera_description::job::{
    Aovs, FrameProgress, JobProgress, JobSettings, JobState, Noise, HALTED_BY_NOISE, HALTED_BY_TIME,
};
use tessera_description::Bundle;
use tessera_film::PixelState;

use crate::v1 as pb;

/// Why a wire message does not convert to its domain type.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    /// Render settings out of range; the message says which and why.
    #[error("{0}")]
    Settings(String),
    /// A job state this build does not know (or unspecified).
    #[error("unknown job state {0}")]
    UnknownState(i32),
}

/// Why a watch update's pixel payload is refused (a coordinator speaking nonsense).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PixelsError {
    /// The payload is not an encoded `PixelRuns` (e.g. cut short).
    #[error("the pixel payload does not decode: {0}")]
    Decode(#[from] prost::DecodeError),
    /// A run does not fit the image or its arrays disagree.
    #[error("malformed pixel run at {start}: {reason}")]
    Run {
        /// First pixel.
        start: u32,
        /// What is wrong.
        reason: &'static str,
    },
}

/// Pixels as a watch update carries them: consecutive indices grouped into runs, encoded
/// once, so that every viewer of the chunk shares this buffer. No pixels: an empty payload.
pub fn pixels_to_wire(pixels: &[PixelState]) -> Bytes {
    if pixels.is_empty() {
        return Bytes::new();
    }
    let mut runs: Vec<pb::PixelRun> = Vec::new();
    for p in pixels {
        match runs.last_mut() {
            Some(r) if r.start as usize + r.counts.len() == p.index as usize => {
                r.sums.extend_from_slice(&p.sums);
                r.counts.push(p.count);
            }
            _ => runs.push(pb::PixelRun { start: p.index, sums: p.sums.to_vec(), counts: vec![p.count] }),
        }
    }
    Bytes::from(pb::PixelRuns { runs }.encode_to_vec())
}

/// A watch update's pixels from the wire, for an image of `image_pixels` pixels. The
/// whole payload is decoded and every run checked before the first pixel is yielded, so a
/// replica that applies them either takes the whole chunk or nothing.
pub fn pixels_from_wire(
    payload: &[u8],
    image_pixels: u64,
) -> Result<impl Iterator<Item = PixelState>, PixelsError> {
    let runs = pb::PixelRuns::decode(payload)?.runs;
    for r in &runs {
        if r.sums.len() != r.counts.len() * 3 {
            return Err(PixelsError::Run { start: r.start, reason: "sums are not 3 per pixel" });
        }
        if u64::from(r.start) + r.counts.len() as u64 > image_pixels {
            return Err(PixelsError::Run { start: r.start, reason: "run extends past the image" });
        }
    }
    Ok(runs.into_iter().flat_map(|r| {
        (0..r.counts.len()).map(move |k| PixelState {
            index: r.start + k as u32,
            sums: [r.sums[3 * k], r.sums[3 * k + 1], r.sums[3 * k + 2]],
            count: r.counts[k],
        })
    }))
}

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

/// A bundle from the wire, its assets sorted by path (the order the content hash is taken in,
/// whatever order the sender used).
pub fn bundle_from_wire(b: pb::SceneBundle) -> Bundle {
    let mut assets: Vec<(String, Vec<u8>)> = b.assets.into_iter().map(|a| (a.path, a.data)).collect();
    assets.sort();
    Bundle { name: b.name, text: b.text, assets, refused: Vec::new() }
}

/// Job settings as they travel.
pub fn settings_to_wire(s: &JobSettings) -> pb::RenderSettings {
    let (width, height) = s.size.unwrap_or((0, 0));
    pb::RenderSettings {
        spp: s.spp.unwrap_or(0),
        width,
        height,
        time_limit_seconds: s.time_limit.map_or(0.0, |t| t.as_secs_f64()),
        noise: match s.noise {
            Some(Noise::Relative(v)) => f64::from(v),
            _ => 0.0,
        },
        noise_absolute: match s.noise {
            Some(Noise::Absolute(v)) => f64::from(v),
            _ => 0.0,
        },
        noise_min_samples: s.noise_min.unwrap_or(0),
        aovs: aovs_to_wire(s.aovs),
        frames: s.frames.map(|(first, last)| pb::FrameRange { first, last }),
    }
}

/// AOV layers as wire bits (`Batch.aovs`, `RenderSettings.aovs`).
pub fn aovs_to_wire(a: Aovs) -> u32 {
    layout_of(a).bits()
}

/// AOV layers from wire bits; `None` if a bit names no layer.
pub fn aovs_from_wire(bits: u32) -> Option<Aovs> {
    tessera_film::aov::Layout::from_bits(bits).map(|l| Aovs {
        albedo: l.albedo,
        normal: l.normal,
        depth: l.depth,
    })
}

/// The film's layout of a job's AOV layers.
pub fn layout_of(a: Aovs) -> tessera_film::aov::Layout {
    tessera_film::aov::Layout { albedo: a.albedo, normal: a.normal, depth: a.depth }
}

/// Job settings from the wire, checked; 0 means "keep the scene's".
pub fn settings_from_wire(s: pb::RenderSettings) -> Result<JobSettings, WireError> {
    let bad = |m: String| Err(WireError::Settings(m));
    let size = match (s.width, s.height) {
        (0, 0) => None,
        (0, _) | (_, 0) => return bad(format!("give both width and height, got {}x{}", s.width, s.height)),
        (w, h) => Some((w, h)),
    };
    let time_limit = match s.time_limit_seconds {
        0.0 => None,
        t if t.is_finite() && t > 0.0 && t < 1e9 => Some(Duration::from_secs_f64(t)),
        t => return bad(format!("time_limit_seconds must be a positive number of seconds, got {t}")),
    };
    // The ranges are `Noise::checked`'s, applied to the f32 the job keeps (an f64 beyond
    // f32's range becomes infinite there, and is refused); the messages name the wire's fields.
    let noise = match (s.noise, s.noise_absolute) {
        (0.0, 0.0) => None,
        (n, 0.0) => match Noise::Relative(n as f32).checked() {
            Ok(t) => Some(t),
            Err(_) => return bad(format!("noise must be a relative error in (0, 1), got {n}")),
        },
        (0.0, n) => match Noise::Absolute(n as f32).checked() {
            Ok(t) => Some(t),
            Err(_) => return bad(format!("noise_absolute must be a positive number, got {n}")),
        },
        (r, a) => return bad(format!("give noise or noise_absolute, not both (got {r} and {a})")),
    };
    let noise_min = (s.noise_min_samples != 0).then_some(s.noise_min_samples);
    let adaptive = JobSettings { noise, noise_min, ..JobSettings::default() };
    if let Err(e) = adaptive.checked_noise() {
        return bad(format!("{e} (noise_min_samples {})", s.noise_min_samples));
    }
    let Some(aovs) = aovs_from_wire(s.aovs) else {
        return bad(format!("aovs: unknown layer bits in {:#x} (1 albedo, 2 normal, 4 depth)", s.aovs));
    };
    let frames = match s.frames {
        None => None,
        Some(f) => {
            tessera_description::job::check_frames(f.first, f.last)
                .map_err(|e| WireError::Settings(format!("frames {}-{}: {e}", f.first, f.last)))?;
            Some((f.first, f.last))
        }
    };
    Ok(JobSettings { spp: (s.spp != 0).then_some(s.spp), size, time_limit, noise, noise_min, aovs, frames })
}

/// A job state as it travels (a failure's reason travels apart, in `JobStatus::error`).
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

/// A job state from the wire (the raw enum field), with a failure's reason `error`.
pub fn state_from_wire(state: i32, error: &str) -> Result<JobState, WireError> {
    Ok(match pb::JobState::try_from(state) {
        Ok(pb::JobState::Queued) => JobState::Queued,
        Ok(pb::JobState::Running) => JobState::Running,
        Ok(pb::JobState::Done) => JobState::Done,
        Ok(pb::JobState::Cancelled) => JobState::Cancelled,
        Ok(pb::JobState::Failed) => JobState::Failed(error.to_string()),
        Ok(pb::JobState::Paused) => JobState::Paused,
        Ok(pb::JobState::Unspecified) | Err(_) => return Err(WireError::UnknownState(state)),
    })
}

/// A wire job state's name as people read it (`queued`, `running`, …; [`JobState::name`]),
/// `?` for one this build does not know.
pub fn state_name(state: i32) -> &'static str {
    state_from_wire(state, "").map_or("?", |s| s.name())
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
        // Not part of a job's progress: the service fills them in.
        owner: String::new(),
        workers: 0,
        frames: p.frames.map(|(first, last)| pb::FrameRange { first, last }),
        settings: Some(settings_to_wire(&p.settings)),
        halted: p.halted.unwrap_or_default().to_string(),
        frame_status: p
            .frame_progress
            .iter()
            .map(|f| pb::FrameStatus {
                frame: f.frame,
                pass_one_done: f.pass_one_done,
                samples_done: f.samples_done,
                samples_total: f.samples_total,
            })
            .collect(),
    }
}

/// A job's progress from the wire. A nonsensical elapsed time reads as zero. The settings
/// and why the job halted are only shown to people, and a status is not refused for them:
/// settings out of range, or none (an older coordinator), read as none overridden, and a
/// reason to halt this build does not know as none.
pub fn status_from_wire(s: pb::JobStatus) -> Result<JobProgress, WireError> {
    let state = state_from_wire(s.state, &s.error)?;
    let settings = s.settings.and_then(|w| settings_from_wire(w).ok()).unwrap_or_default();
    let halted = halted_from_wire(&s.halted);
    Ok(JobProgress {
        id: JobId(s.job_id),
        scene: s.scene,
        state,
        width: s.width,
        height: s.height,
        spp: s.spp,
        pass: s.pass,
        samples_done: s.samples_done,
        samples_total: s.samples_total,
        samples_per_second: s.samples_per_second,
        elapsed: Duration::try_from_secs_f64(s.elapsed_seconds).unwrap_or_default(),
        pass_one_done: s.pass_one_done,
        nonfinite_samples: 0,
        priority: s.priority,
        halted,
        settings,
        frames: s.frames.map(|f| (f.first, f.last)),
        frame_progress: s
            .frame_status
            .iter()
            .map(|f| FrameProgress {
                frame: f.frame,
                pass_one_done: f.pass_one_done,
                samples_done: f.samples_done,
                samples_total: f.samples_total,
            })
            .collect(),
    })
}

/// Why a done job stopped short of its spp (`JobStatus.halted`), if it is a reason this
/// build knows: what a coordinator sends is shown to people, and only as one of these.
pub fn halted_from_wire(halted: &str) -> Option<&'static str> {
    [HALTED_BY_TIME, HALTED_BY_NOISE].into_iter().find(|h| *h == halted)
}

/// A job id field of a request: 0 when none is named (the coordinator then picks, e.g. the
/// running job).
pub fn job_to_wire(id: Option<JobId>) -> u64 {
    id.map_or(0, |j| j.0)
}

/// A job id field from the wire; 0 names no job.
pub fn job_from_wire(id: u64) -> Option<JobId> {
    (id != 0).then_some(JobId(id))
}

/// A batch id from the wire (batches are numbered from 0, so every value names one).
pub fn batch_from_wire(id: u64) -> BatchId {
    BatchId(id)
}

/// A worker id field from the wire; 0 names no worker.
pub fn worker_from_wire(id: u64) -> Option<WorkerId> {
    (id != 0).then_some(WorkerId(id))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundles_round_trip_and_assets_come_in_sorted() {
        let b = Bundle {
            name: "s.toml".into(),
            text: "x = 1".into(),
            assets: vec![("a.obj".into(), vec![1, 2]), ("b.png".into(), vec![3])],
            refused: vec![],
        };
        assert_eq!(bundle_from_wire(bundle_to_wire(&b)), b);
        let mut wire = bundle_to_wire(&b);
        wire.assets.reverse();
        assert_eq!(bundle_from_wire(wire), b);
    }

    #[test]
    fn settings_round_trip() {
        for s in [
            JobSettings::default(),
            JobSettings::sized(Some(64), Some((320, 200))),
            JobSettings {
                spp: Some(1024),
                size: None,
                time_limit: Some(Duration::from_secs(90)),
                noise: Some(Noise::Relative(0.01)),
                noise_min: None,
                aovs: Aovs { albedo: true, normal: false, depth: true },
                frames: None,
            },
            JobSettings { noise: Some(Noise::Absolute(0.02)), ..JobSettings::sized(Some(4096), None) },
            JobSettings {
                noise: Some(Noise::Absolute(0.02)),
                noise_min: Some(256),
                ..JobSettings::sized(Some(4096), None)
            },
            JobSettings { frames: Some((1, 48)), ..JobSettings::sized(Some(4), None) },
        ] {
            assert_eq!(settings_from_wire(settings_to_wire(&s)), Ok(s));
        }
    }

    #[test]
    fn bad_settings_are_refused_with_reasons() {
        let wire = |f: fn(&mut pb::RenderSettings)| {
            let mut s = pb::RenderSettings::default();
            f(&mut s);
            settings_from_wire(s).unwrap_err().to_string()
        };
        assert!(wire(|s| s.width = 10).contains("both width and height"));
        assert!(wire(|s| s.time_limit_seconds = -1.0).contains("time_limit_seconds"));
        assert!(wire(|s| s.time_limit_seconds = f64::NAN).contains("time_limit_seconds"));
        assert!(wire(|s| s.noise = 1.0).contains("noise"));
        assert!(wire(|s| s.noise_absolute = -0.5).contains("noise_absolute must be a positive number"));
        assert!(wire(|s| s.noise_absolute = f64::INFINITY).contains("noise_absolute"));
        assert!(wire(|s| s.noise_absolute = 1e300).contains("noise_absolute"));
        let both = wire(|s| {
            s.noise = 0.1;
            s.noise_absolute = 0.1;
        });
        assert!(both.contains("not both"), "{both}");
        let alone = wire(|s| s.noise_min_samples = 32);
        assert!(alone.contains("noise_min_samples") && alone.contains("without a noise target"), "{alone}");
        let one = wire(|s| {
            s.noise_absolute = 0.1;
            s.noise_min_samples = 1;
        });
        assert!(one.contains("noise_min_samples") && one.contains("at least 2"), "{one}");
        assert!(wire(|s| s.aovs = 8).contains("aovs: unknown layer bits"));
        let reversed = wire(|s| s.frames = Some(pb::FrameRange { first: 5, last: 2 }));
        assert!(reversed.contains("frames 5-2: the range is reversed"), "{reversed}");
    }

    #[test]
    fn states_round_trip_and_have_names() {
        for s in [
            JobState::Queued,
            JobState::Running,
            JobState::Done,
            JobState::Cancelled,
            JobState::Failed("bad scene".into()),
            JobState::Paused,
        ] {
            let error = if let JobState::Failed(e) = &s { e.as_str() } else { "" };
            assert_eq!(state_from_wire(state_to_wire(&s) as i32, error), Ok(s.clone()));
            assert_eq!(state_name(state_to_wire(&s) as i32), s.name());
        }
        assert_eq!(state_name(pb::JobState::Unspecified as i32), "?");
        assert_eq!(state_name(99), "?");
        assert_eq!(state_from_wire(99, ""), Err(WireError::UnknownState(99)));
    }

    #[test]
    fn progress_round_trips_but_for_what_does_not_travel() {
        let p = JobProgress {
            id: JobId(3),
            scene: "cornell".into(),
            state: JobState::Failed("out of memory".into()),
            width: 64,
            height: 48,
            spp: 16,
            pass: 2,
            samples_done: 1000,
            samples_total: 64 * 48 * 16,
            samples_per_second: 1.5e6,
            elapsed: Duration::from_millis(2500),
            pass_one_done: 64 * 48,
            nonfinite_samples: 0,
            priority: -1,
            halted: Some(HALTED_BY_NOISE),
            settings: JobSettings {
                noise: Some(Noise::Absolute(0.05)),
                noise_min: Some(128),
                time_limit: Some(Duration::from_secs(30)),
                ..JobSettings::sized(Some(16), Some((64, 96)))
            },
            frames: Some((7, 8)),
            frame_progress: vec![
                FrameProgress { frame: 7, pass_one_done: 64 * 48, samples_done: 900, samples_total: 49152 },
                FrameProgress { frame: 8, pass_one_done: 0, samples_done: 100, samples_total: 49152 },
            ],
        };
        let wire = status_to_wire(&p);
        assert_eq!(wire.error, "out of memory");
        assert_eq!(status_from_wire(wire.clone()), Ok(p.clone()));
        // An older coordinator's status has no settings: none overridden.
        let old = status_from_wire(pb::JobStatus { settings: None, ..wire.clone() }).unwrap();
        assert_eq!(old.settings, JobSettings::default());
        // Settings a submission could not have had, and a reason to halt this build does
        // not know, read as none: the status itself is still taken.
        let mut lying = wire;
        lying.settings.as_mut().unwrap().noise = 0.2;
        lying.halted = "the moon".into();
        let taken = status_from_wire(lying).unwrap();
        assert_eq!((taken.settings, taken.halted), (JobSettings::default(), None));
    }

    fn pixel(index: u32, count: u32) -> PixelState {
        PixelState { index, sums: [u64::from(index), 1 << 40, 3], count }
    }

    #[test]
    fn pixels_round_trip_in_runs() {
        let pixels = vec![pixel(4, 1), pixel(5, 2), pixel(6, 1), pixel(0, 9), pixel(9, 1)];
        let wire = pixels_to_wire(&pixels);
        let runs = pb::PixelRuns::decode(wire.clone()).unwrap().runs;
        assert_eq!(
            runs.iter().map(|r| (r.start, r.counts.len())).collect::<Vec<_>>(),
            [(4, 3), (0, 1), (9, 1)]
        );
        assert_eq!(pixels_from_wire(&wire, 10).unwrap().collect::<Vec<_>>(), pixels);
        assert!(pixels_to_wire(&[]).is_empty());
        assert_eq!(pixels_from_wire(&[], 10).unwrap().count(), 0);
    }

    /// Version 1 sent the runs inline as field 6: exactly the payload's bytes. Wrapping
    /// them in one bytes field costs its tag and length prefix, 2 to 4 bytes an update.
    #[test]
    fn the_payload_costs_one_length_prefix_over_inline_runs() {
        let pixels: Vec<_> = (0..65536).map(|i| pixel(i * 2, 7)).collect();
        let payload = pixels_to_wire(&pixels);
        let bare = pb::FramebufferUpdate { job_id: 1, width: 512, height: 256, ..Default::default() };
        let full = pb::FramebufferUpdate { pixels: payload.clone(), ..bare.clone() };
        let over = full.encoded_len() - bare.encoded_len() - payload.len();
        assert_eq!(over, 1 + prost::length_delimiter_len(payload.len()));
        assert!(over <= 4);
    }

    #[test]
    fn bad_pixel_payloads_are_refused_with_reasons() {
        let wire = pixels_to_wire(&[pixel(4, 1), pixel(5, 2)]);
        assert!(matches!(pixels_from_wire(&wire[..wire.len() - 1], 10), Err(PixelsError::Decode(_))));
        let err = pixels_from_wire(&wire, 5).err().unwrap();
        assert_eq!(err, PixelsError::Run { start: 4, reason: "run extends past the image" });
        let odd = pb::PixelRuns { runs: vec![pb::PixelRun { start: 0, sums: vec![1], counts: vec![1] }] };
        let err = pixels_from_wire(&odd.encode_to_vec(), 10).err().unwrap();
        assert!(err.to_string().contains("3 per pixel"), "{err}");
    }

    #[test]
    fn ids_map_zero_to_none() {
        assert_eq!(job_to_wire(None), 0);
        assert_eq!(job_from_wire(job_to_wire(Some(JobId(7)))), Some(JobId(7)));
        assert_eq!(job_from_wire(0), None);
        assert_eq!(worker_from_wire(0), None);
        assert_eq!(batch_from_wire(0), BatchId(0));
    }
}
