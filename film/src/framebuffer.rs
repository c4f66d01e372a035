//! A job's framebuffer: per-pixel fixed-point sums and sample counts (store sums, not
//! averages), resolved into an image on demand, with the pass-one mosaic for pixels that
//! have no sample yet.

use crate::fixed;

use crate::quadtree::{mosaic_source, Quad};

/// Why a batch's sums could not be merged.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MergeError {
    /// The result does not have three sums per pixel.
    #[error("expected {expected} sums (3 per pixel), got {got}")]
    WrongLength {
        /// 3 × pixels.
        expected: usize,
        /// What came.
        got: usize,
    },
    /// The result does not have one even-sample sum per pixel.
    #[error("expected {expected} even-sample sums (1 per pixel), got {got}")]
    EvenLength {
        /// Pixels.
        expected: usize,
        /// What came.
        got: usize,
    },
    /// A sum is larger than its samples can produce.
    #[error("sum {value} of pixel {x},{y} exceeds the largest possible for {samples} samples")]
    OutOfRange {
        /// Column.
        x: u32,
        /// Row from the bottom.
        y: u32,
        /// The sum.
        value: u64,
        /// Samples it claims to hold.
        samples: u32,
    },
}

/// Accumulated samples of a `width × height` image, in the paper's coordinates.
#[derive(Debug, Clone)]
pub struct Framebuffer {
    width: u32,
    height: u32,
    sums: Vec<[u64; 3]>,
    counts: Vec<u32>,
    /// Per pixel, the sum of the luminance of its even-numbered samples, for jobs with a
    /// noise target: with the full sums it gives two independent half estimates, whose
    /// difference estimates the error of the mean. Empty otherwise.
    even: Vec<u64>,
    /// Per pixel, the version of the merge that last changed it (for viewers' deltas).
    versions: Vec<u64>,
    /// Merges so far.
    version: u64,
}

/// The state of one pixel as it travels to viewers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelState {
    /// Pixel index, y · width + x.
    pub index: u32,
    /// Fixed-point sums.
    pub sums: [u64; 3],
    /// Samples.
    pub count: u32,
}

impl Framebuffer {
    /// An empty framebuffer.
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Framebuffer {
            width,
            height,
            sums: vec![[0; 3]; n],
            counts: vec![0; n],
            even: Vec::new(),
            versions: vec![0; n],
            version: 0,
        }
    }

    /// An empty framebuffer that also keeps even-sample luminance sums (noise targets).
    pub fn with_even(width: u32, height: u32) -> Self {
        let mut fb = Framebuffer::new(width, height);
        fb.even = vec![0; fb.counts.len()];
        fb
    }

    /// Whether it keeps even-sample sums.
    pub fn has_even(&self) -> bool {
        !self.even.is_empty()
    }

    /// The even-sample luminance sums (empty unless `with_even`).
    pub fn even(&self) -> &[u64] {
        &self.even
    }

    /// The estimated relative standard error of pixel `(x, y)`'s mean luminance: half the
    /// difference of the means of its even and odd samples (each half an independent
    /// estimate, so that their difference has twice the mean's standard deviation),
    /// relative to the mean, which is floored at `floor` so that black pixels converge too.
    /// `None` before two samples, or without even sums.
    pub fn noise(&self, x: u32, y: u32, floor: f64) -> Option<f64> {
        let i = self.index(x, y);
        let n = self.counts[i];
        if n < 2 || self.even.is_empty() {
            return None;
        }
        let total = self.sums[i].iter().map(|&s| s as f64).sum::<f64>() / 3.0;
        let even = self.even[i] as f64;
        let (n_even, n_odd) = (f64::from(n.div_ceil(2)), f64::from(n / 2));
        let (m_even, m_odd) = (even / n_even, (total - even).max(0.0) / n_odd);
        let mean = total / f64::from(n);
        let scale = fixed::SCALE;
        Some((m_even - m_odd).abs() / 2.0 / (mean / scale).max(floor) / scale)
    }

    /// A framebuffer holding these accumulators (a checkpoint read back), or `None` if
    /// their lengths do not fit the size. Every pixel with samples is new to viewers.
    pub fn from_accumulators(
        width: u32,
        height: u32,
        sums: Vec<[u64; 3]>,
        counts: Vec<u32>,
        even: Vec<u64>,
    ) -> Option<Self> {
        let n = width as usize * height as usize;
        if sums.len() != n || counts.len() != n || !(even.is_empty() || even.len() == n) {
            return None;
        }
        let versions = counts.iter().map(|&c| u64::from(c > 0)).collect();
        Some(Framebuffer { width, height, sums, counts, even, versions, version: 1 })
    }

    /// The per-pixel sums and sample counts, pixel index y · width + x.
    pub fn accumulators(&self) -> (&[[u64; 3]], &[u32]) {
        (&self.sums, &self.counts)
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    fn index(&self, x: u32, y: u32) -> usize {
        y as usize * self.width as usize + x as usize
    }

    /// Adds `samples` samples to each of `quads`' pixels. Checks everything before
    /// changing anything, so a refused result leaves the framebuffer as it was. Integer
    /// addition makes the result independent of merge order (DESIGN contract 1).
    pub fn merge(&mut self, quads: &[Quad], samples: u32, sums: &[u64]) -> Result<(), MergeError> {
        self.merge_split(quads, samples, sums, &[])
    }

    /// `merge`, with the batch's even-sample luminance sums `even` (one per pixel) when the
    /// framebuffer keeps them; ignored otherwise.
    pub fn merge_split(
        &mut self,
        quads: &[Quad],
        samples: u32,
        sums: &[u64],
        even: &[u64],
    ) -> Result<(), MergeError> {
        Self::check(quads, samples, sums)?;
        if self.has_even() {
            Self::check_even(quads, samples, even)?;
            for (q, e) in quads.iter().zip(even) {
                let i = self.index(q.x, q.y);
                self.even[i] = self.even[i].saturating_add(*e);
            }
        }
        self.version += 1;
        for (q, s) in quads.iter().zip(sums.chunks_exact(3)) {
            let i = self.index(q.x, q.y);
            self.versions[i] = self.version;
            for (acc, v) in self.sums[i].iter_mut().zip(s) {
                // Saturating: only a scene far beyond the documented limits can get here.
                *acc = acc.saturating_add(*v);
            }
            self.counts[i] = self.counts[i].saturating_add(samples);
        }
        Ok(())
    }

    /// Checks that `sums` can be the result of `samples` samples of each of `quads`.
    pub fn check(quads: &[Quad], samples: u32, sums: &[u64]) -> Result<(), MergeError> {
        if sums.len() != quads.len() * 3 {
            return Err(MergeError::WrongLength { expected: quads.len() * 3, got: sums.len() });
        }
        let max = fixed::max_sum(samples);
        for (q, s) in quads.iter().zip(sums.chunks_exact(3)) {
            if let Some(&value) = s.iter().find(|&&v| v > max) {
                return Err(MergeError::OutOfRange { x: q.x, y: q.y, value, samples });
            }
        }
        Ok(())
    }

    /// Checks even-sample sums: one per pixel, each within what the batch's even samples
    /// (at most half of them, rounded up) can produce.
    pub fn check_even(quads: &[Quad], samples: u32, even: &[u64]) -> Result<(), MergeError> {
        if even.len() != quads.len() {
            return Err(MergeError::EvenLength { expected: quads.len(), got: even.len() });
        }
        let max = fixed::max_sum(samples.div_ceil(2));
        match quads.iter().zip(even).find(|(_, &v)| v > max) {
            Some((q, &value)) => Err(MergeError::OutOfRange { x: q.x, y: q.y, value, samples }),
            None => Ok(()),
        }
    }

    /// Merges so far: the framebuffer's version.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Up to `limit` pixels changed after version `since` and not after `until`, from
    /// pixel index `from` on; returns them and the index to continue from (`None` at the
    /// end). Bounded, so that a viewer's update never holds more than `limit` pixels.
    pub fn changes(
        &self,
        since: u64,
        until: u64,
        from: usize,
        limit: usize,
    ) -> (Vec<PixelState>, Option<usize>) {
        let mut out = Vec::new();
        for i in from..self.versions.len() {
            let v = self.versions[i];
            if v > since && v <= until {
                if out.len() == limit {
                    return (out, Some(i));
                }
                out.push(PixelState { index: i as u32, sums: self.sums[i], count: self.counts[i] });
            }
        }
        (out, None)
    }

    /// Sets a pixel's state (a viewer's replica applying an update).
    pub fn set(&mut self, p: &PixelState) -> bool {
        let i = p.index as usize;
        if i >= self.counts.len() {
            return false;
        }
        self.sums[i] = p.sums;
        self.counts[i] = p.count;
        true
    }

    /// The mean radiance of pixel `(x, y)`, or `None` before its first sample.
    pub fn mean(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        let i = self.index(x, y);
        let n = self.counts[i];
        (n > 0).then(|| self.sums[i].map(|s| fixed::mean(s, n)))
    }

    /// The image as linear RGB, top row first (image order, ready to encode). A pixel
    /// without samples shows the mosaic: the mean of the finest computed block covering it.
    pub fn resolve(&self) -> Vec<f32> {
        let (w, h) = (self.width, self.height);
        let mut out = Vec::with_capacity(w as usize * h as usize * 3);
        for row in 0..h {
            let y = h - 1 - row;
            for x in 0..w {
                let rgb = self.mean(x, y).or_else(|| {
                    mosaic_source(w, h, x, y, |sx, sy| self.counts[self.index(sx, sy)] > 0)
                        .and_then(|(sx, sy)| self.mean(sx, sy))
                });
                out.extend_from_slice(&rgb.unwrap_or([0.0; 3]));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadtree::Walk;

    fn one(v: f32) -> u64 {
        fixed::to_fixed(v).unwrap()
    }

    #[test]
    fn merge_order_does_not_change_the_bits() {
        let quads: Vec<Quad> = Walk::new(4, 4).collect();
        let sums_a: Vec<u64> = (0..48).map(|i| one(0.1 * i as f32 + 0.013)).collect();
        let sums_b: Vec<u64> = (0..48).map(|i| one(1.7 / (i as f32 + 1.0))).collect();
        let mut ab = Framebuffer::new(4, 4);
        ab.merge(&quads, 1, &sums_a).unwrap();
        ab.merge(&quads, 1, &sums_b).unwrap();
        let mut ba = Framebuffer::new(4, 4);
        ba.merge(&quads, 1, &sums_b).unwrap();
        ba.merge(&quads, 1, &sums_a).unwrap();
        let bits = |f: &Framebuffer| f.resolve().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&ab), bits(&ba));
    }

    /// A replica fed the changes of every version resolves to the same bits.
    #[test]
    fn replica_from_changes_resolves_identically() {
        let quads: Vec<Quad> = Walk::new(9, 7).collect();
        let mut fb = Framebuffer::new(9, 7);
        let mut replica = Framebuffer::new(9, 7);
        let mut sent = 0;
        for (k, chunk) in quads.chunks(5).enumerate() {
            let sums: Vec<u64> = (0..chunk.len() * 3).map(|i| one((i + k) as f32 * 0.01)).collect();
            fb.merge(chunk, 1, &sums).unwrap();
            if k % 3 == 0 {
                let until = fb.version();
                let mut from = Some(0);
                while let Some(f) = from {
                    let (px, next) = fb.changes(sent, until, f, 4);
                    px.iter().for_each(|p| assert!(replica.set(p)));
                    from = next;
                }
                sent = until;
                let bits = |f: &Framebuffer| f.resolve().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&replica), bits(&fb));
            }
        }
    }

    #[test]
    fn bad_results_are_refused_without_change() {
        let quads: Vec<Quad> = Walk::new(2, 2).collect();
        let mut fb = Framebuffer::new(2, 2);
        assert!(matches!(fb.merge(&quads, 1, &[0; 5]), Err(MergeError::WrongLength { .. })));
        let mut sums = vec![0; 12];
        sums[4] = u64::MAX;
        assert!(matches!(fb.merge(&quads, 1, &sums), Err(MergeError::OutOfRange { .. })));
        assert!(fb.mean(0, 0).is_none());
    }

    /// An early image shows the mosaic, not black with a few dots.
    #[test]
    fn mosaic_fills_the_frame_from_the_first_pixel() {
        let mut fb = Framebuffer::new(8, 8);
        let root = Walk::new(8, 8).next().unwrap();
        fb.merge(&[root], 1, &[one(0.5), one(0.25), one(1.0)]).unwrap();
        let img = fb.resolve();
        assert!(img.chunks(3).all(|p| p == [0.5, 0.25, 1.0]));
    }
}
