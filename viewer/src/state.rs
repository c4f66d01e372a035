//! The replica of a job's framebuffer: updates from the watch stream applied to the same
//! `Framebuffer` the coordinator keeps, so that it resolves to the same bits.

use tessera_description::ids::JobId;
use tessera_film::framebuffer::Framebuffer;
use tessera_film::preview::Overlay;
use tessera_proto::convert::{job_from_wire, pixels_from_wire, state_name, PixelsError};
use tessera_proto::preview::{preview_from_wire, PreviewError};
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
    /// The pixel payload does not decode, or a run in it does not fit the image.
    #[error(transparent)]
    Pixels(#[from] PixelsError),
    /// The preview payload does not decode, or a block in it does not fit the image.
    #[error(transparent)]
    Preview(#[from] PreviewError),
    /// The stream's first update names another protocol (one of version 1 names none).
    #[error("the coordinator speaks protocol version {0}, this viewer {current}", current = tessera_proto::PROTOCOL_VERSION as i32)]
    Protocol(i32),
}

/// A job as the viewer sees it.
#[derive(Debug, Default)]
pub struct Replica {
    fb: Option<Framebuffer>,
    /// Preview values painted over `fb`'s image where newer than its exact states.
    overlay: Option<Overlay>,
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
        if u.reset && u.protocol_version != tessera_proto::PROTOCOL_VERSION as i32 {
            return Err(UpdateError::Protocol(u.protocol_version));
        }
        // A reset drops the old image, so only a size it has not yet seen can disagree.
        let fb = if u.reset { None } else { self.fb.as_ref() };
        let size = (u.width, u.height);
        let n = u64::from(u.width) * u64::from(u.height);
        if n == 0 || fb.is_some_and(|fb| (fb.width(), fb.height()) != size) {
            let was = fb.map_or((0, 0), |fb| (fb.width(), fb.height()));
            return Err(UpdateError::Size { was, now: size });
        }
        let pixels = pixels_from_wire(&u.pixels, n)?;
        let preview = preview_from_wire(&u.preview, u.width, u.height)?;
        if u.reset {
            self.fb = None;
            self.overlay = None;
            self.version = 0;
            self.finished = false;
        }
        let fb = self.fb.get_or_insert_with(|| Framebuffer::new(u.width, u.height));
        let overlay = &mut self.overlay;
        for p in pixels {
            fb.set(&p);
            if let Some(o) = overlay.as_mut() {
                o.clear(p.index);
            }
        }
        if !preview.is_empty() {
            let o = overlay.get_or_insert_with(|| Overlay::new(u.width, u.height));
            for b in &preview {
                o.paint(b);
            }
        }
        if u.r#final {
            // The final update's exact states are every pixel's: nothing of a preview stays.
            *overlay = None;
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
    /// reached yet, preview values where they are newer than the exact states.
    pub fn image(&self) -> Option<(u32, u32, Vec<f32>)> {
        self.fb.as_ref().map(|fb| {
            let mut img = fb.resolve();
            if let Some(o) = &self.overlay {
                o.over(&mut img);
            }
            (fb.width(), fb.height(), img)
        })
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
    use prost::Message;
    use tessera_film::PixelState;
    use tessera_proto::convert::pixels_to_wire;

    fn update(pixels: impl Into<bytes::Bytes>) -> pb::FramebufferUpdate {
        pb::FramebufferUpdate {
            job_id: 1,
            width: 2,
            height: 2,
            version: 1,
            chunk_end: true,
            pixels: pixels.into(),
            ..Default::default()
        }
    }

    fn runs(runs: Vec<pb::PixelRun>) -> Vec<u8> {
        pb::PixelRuns { runs }.encode_to_vec()
    }

    #[test]
    fn hostile_updates_are_refused_untouched() {
        let mut r = Replica::new();
        let bad = pb::PixelRun { start: 3, sums: vec![1, 2, 3, 4, 5, 6], counts: vec![1, 1] };
        assert!(matches!(
            r.apply(update(runs(vec![bad]))),
            Err(UpdateError::Pixels(PixelsError::Run { .. }))
        ));
        let bad = pb::PixelRun { start: 0, sums: vec![1], counts: vec![1] };
        assert!(matches!(
            r.apply(update(runs(vec![bad]))),
            Err(UpdateError::Pixels(PixelsError::Run { .. }))
        ));
        let ok = pb::PixelRun { start: 0, sums: vec![1 << 24, 0, 0], counts: vec![1] };
        r.apply(update(runs(vec![ok]))).unwrap();
        let mut resized = update(Vec::new());
        resized.width = 3;
        assert!(matches!(r.apply(resized), Err(UpdateError::Size { .. })));
        // The root pixel paints the whole frame (mosaic).
        let (_, _, img) = r.image().unwrap();
        assert!(img.chunks(3).all(|p| p == [1.0, 0.0, 0.0]));
    }

    #[test]
    fn a_truncated_payload_is_refused_and_changes_nothing() {
        let mut r = Replica::new();
        let first = PixelState { index: 0, sums: [1 << 24, 0, 0], count: 1 };
        r.apply(update(pixels_to_wire(&[first]))).unwrap();
        let before = (r.image(), r.version, r.job, r.finished);
        let more = [1, 2, 3].map(|index| PixelState { index, sums: [0, 1 << 24, 0], count: 2 });
        let wire = pixels_to_wire(&more);
        let mut cut = update(wire.slice(..wire.len() - 2));
        cut.version = 2;
        cut.r#final = true;
        let err = r.apply(cut).unwrap_err();
        assert!(matches!(err, UpdateError::Pixels(PixelsError::Decode(_))), "{err:?}");
        assert!(err.to_string().contains("does not decode"), "{err}");
        assert_eq!((r.image(), r.version, r.job, r.finished), before);
    }

    /// Previews paint over the exact image; exact pixels that come later replace them; the
    /// final update leaves only exact states; a bad preview changes nothing.
    #[test]
    fn previews_paint_over_until_exact_states_replace_them() {
        use tessera_film::preview::Blocks;
        use tessera_proto::preview::preview_to_wire;
        let mut r = Replica::new();
        let mut u = update(Vec::new());
        // One 2x2 block (shift 1) covers the whole 2x2 image.
        u.preview = preview_to_wire(&[Blocks { shift: 1, runs: vec![(0, 1)], rgb: vec![[0.5, 0.25, 1.0]] }]);
        r.apply(u).unwrap();
        let (_, _, img) = r.image().unwrap();
        assert!(img.chunks(3).all(|p| p == [0.5, 0.25, 1.0]), "{img:?}");
        let exact = PixelState { index: 0, sums: [1 << 24, 0, 0], count: 1 };
        r.apply(update(pixels_to_wire(&[exact]))).unwrap();
        let (_, _, img) = r.image().unwrap();
        // Pixel 0 (bottom left) is exact; image rows are top first.
        assert_eq!(&img[6..9], &[1.0, 0.0, 0.0]);
        assert_eq!(&img[0..3], &[0.5, 0.25, 1.0]);
        let mut bad = update(Vec::new());
        bad.preview = preview_to_wire(&[Blocks { shift: 0, runs: vec![(3, 2)], rgb: vec![[1.0; 3]; 2] }]);
        assert!(matches!(r.apply(bad), Err(UpdateError::Preview(_))));
        let mut last = update(Vec::new());
        last.r#final = true;
        r.apply(last).unwrap();
        let (_, _, img) = r.image().unwrap();
        assert!(img.chunks(3).all(|p| p == [1.0, 0.0, 0.0]), "the mosaic of the exact pixel: {img:?}");
    }

    #[test]
    fn a_stream_of_another_protocol_is_refused_untouched() {
        let mut r = Replica::new();
        let mut first = update(Vec::new());
        first.reset = true;
        first.protocol_version = tessera_proto::PROTOCOL_VERSION as i32;
        r.apply(first.clone()).unwrap();
        assert_eq!(r.version, 1);
        // A version 1 coordinator names no version; its pixels would be lost silently.
        first.protocol_version = 0;
        first.version = 5;
        assert_eq!(r.apply(first), Err(UpdateError::Protocol(0)));
        assert_eq!(r.version, 1);
    }
}
