//! The replica of a job's framebuffer: updates from the watch stream applied to the same
//! `Framebuffer` the coordinator keeps, so that it resolves to the same bits.

use tessera_description::ids::JobId;
use tessera_film::framebuffer::{Framebuffer, PixelState};
use tessera_proto::convert::{job_from_wire, state_name};
use tessera_proto::v1 as pb;

/// Why an update could not be applied (a coordinator speaking nonsense).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UpdateError {
    /// The image size changed mid-stream, or is empty.
    #[error("the coordinator changed the image size from {was:?} to {now:?}")]
    Size {
        /// Before.
        was: (u32, u32),
        /// Now.
        now: (u32, u32),
    },
    /// A run does not fit the image or its arrays disagree.
    #[error("malformed pixel run at {start}: {reason}")]
    Run {
        /// First pixel.
        start: u32,
        /// What is wrong.
        reason: &'static str,
    },
}

/// A job as the viewer sees it.
#[derive(Debug, Default)]
pub struct Replica {
    fb: Option<Framebuffer>,
    /// The job, once an update named it.
    pub job: Option<JobId>,
    /// The version of the last complete update.
    pub version: u64,
    /// The job's status from the last update.
    pub status: Option<pb::JobStatus>,
    /// Workers connected.
    pub workers: u32,
    /// The job is over and the replica holds its final image.
    pub finished: bool,
}

impl Replica {
    /// An empty replica.
    pub fn new() -> Self {
        Replica::default()
    }

    /// Applies one update; checks it all before changing anything. The first update of a
    /// stream starts the replica afresh.
    pub fn apply(&mut self, u: pb::FramebufferUpdate) -> Result<(), UpdateError> {
        if u.reset {
            self.fb = None;
            self.version = 0;
            self.finished = false;
        }
        let size = (u.width, u.height);
        let n = u64::from(u.width) * u64::from(u.height);
        if n == 0 || self.fb.as_ref().is_some_and(|fb| (fb.width(), fb.height()) != size) {
            let was = self.fb.as_ref().map_or((0, 0), |fb| (fb.width(), fb.height()));
            return Err(UpdateError::Size { was, now: size });
        }
        for r in &u.runs {
            if r.sums.len() != r.counts.len() * 3 {
                return Err(UpdateError::Run { start: r.start, reason: "sums are not 3 per pixel" });
            }
            if u64::from(r.start) + r.counts.len() as u64 > n {
                return Err(UpdateError::Run { start: r.start, reason: "run extends past the image" });
            }
        }
        let fb = self.fb.get_or_insert_with(|| Framebuffer::new(u.width, u.height));
        for r in &u.runs {
            for (k, (s, &count)) in r.sums.chunks_exact(3).zip(&r.counts).enumerate() {
                fb.set(&PixelState { index: r.start + k as u32, sums: [s[0], s[1], s[2]], count });
            }
        }
        self.job = job_from_wire(u.job_id);
        if u.chunk_end {
            self.version = u.version;
        }
        self.status = u.status.or(self.status.take());
        self.workers = u.workers;
        self.finished |= u.r#final;
        Ok(())
    }

    /// Width and height, once known.
    pub fn size(&self) -> Option<(u32, u32)> {
        self.fb.as_ref().map(|fb| (fb.width(), fb.height()))
    }

    /// The current image: linear RGB, top row first, the mosaic where pass one has not
    /// reached yet.
    pub fn image(&self) -> Option<(u32, u32, Vec<f32>)> {
        self.fb.as_ref().map(|fb| (fb.width(), fb.height(), fb.resolve()))
    }

    /// Percent of the job's samples done.
    pub fn percent(&self) -> f64 {
        self.status.as_ref().map_or(0.0, |s| s.samples_done as f64 / s.samples_total.max(1) as f64 * 100.0)
    }

    /// A one-line status: job, pass, percent, samples/s, ETA, workers.
    pub fn status_line(&self) -> String {
        let Some(s) = &self.status else { return "waiting for the first update".into() };
        let eta = if s.samples_per_second > 0.0 {
            let left = s.samples_total.saturating_sub(s.samples_done) as f64 / s.samples_per_second;
            format!("ETA {left:.0} s")
        } else {
            "ETA -".into()
        };
        format!(
            "job {} {} pass {} {:.1}% {:.2} Msamples/s {} workers {}",
            s.job_id,
            state_name(s.state),
            s.pass,
            self.percent(),
            s.samples_per_second / 1e6,
            eta,
            self.workers
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn update(runs: Vec<pb::PixelRun>) -> pb::FramebufferUpdate {
        pb::FramebufferUpdate {
            job_id: 1,
            width: 2,
            height: 2,
            version: 1,
            chunk_end: true,
            runs,
            ..Default::default()
        }
    }

    #[test]
    fn hostile_updates_are_refused_untouched() {
        let mut r = Replica::new();
        let bad = pb::PixelRun { start: 3, sums: vec![1, 2, 3, 4, 5, 6], counts: vec![1, 1] };
        assert!(matches!(r.apply(update(vec![bad])), Err(UpdateError::Run { .. })));
        let bad = pb::PixelRun { start: 0, sums: vec![1], counts: vec![1] };
        assert!(matches!(r.apply(update(vec![bad])), Err(UpdateError::Run { .. })));
        let ok = pb::PixelRun { start: 0, sums: vec![1 << 24, 0, 0], counts: vec![1] };
        r.apply(update(vec![ok])).unwrap();
        let mut resized = update(vec![]);
        resized.width = 3;
        assert!(matches!(r.apply(resized), Err(UpdateError::Size { .. })));
        // The root pixel paints the whole frame (mosaic).
        let (_, _, img) = r.image().unwrap();
        assert!(img.chunks(3).all(|p| p == [1.0, 0.0, 0.0]));
    }
}
