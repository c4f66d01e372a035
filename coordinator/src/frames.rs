//! A sequence's frames as clients see them. A job of many frames keeps them stacked in one
//! framebuffer (frame `first + k` in rows `k · height ..`, see `scheduler::FixedSpp`), so
//! that merging, checkpoints, audits and repairs are those of a still; this module cuts
//! one frame out again: its image (with its own mosaic) and its pixels for viewers.

use tessera_film::quadtree::mosaic_source;
use tessera_film::{Framebuffer, PixelState};

/// One frame of a stacked framebuffer: rows `row .. row + height`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameRows {
    /// The frame's first row in the stacked framebuffer.
    pub row: u32,
    /// The frame's height.
    pub height: u32,
}

impl FrameRows {
    /// A still's only frame: the whole framebuffer.
    pub fn whole(fb: &Framebuffer) -> FrameRows {
        FrameRows { row: 0, height: fb.height() }
    }

    /// The frame's image as linear RGB, top row first: exactly what `Framebuffer::resolve`
    /// gives for a framebuffer holding only this frame (its mosaic is the frame's own).
    pub fn resolve(&self, fb: &Framebuffer) -> Vec<f32> {
        let (w, h, row0) = (fb.width(), self.height, self.row);
        let mut out = Vec::with_capacity(w as usize * h as usize * 3);
        for row in 0..h {
            let y = h - 1 - row;
            for x in 0..w {
                let rgb = fb.mean(x, row0 + y).or_else(|| {
                    mosaic_source(w, h, x, y, |sx, sy| fb.count(sx, row0 + sy) > 0)
                        .and_then(|(sx, sy)| fb.mean(sx, row0 + sy))
                });
                out.extend_from_slice(&rgb.unwrap_or([0.0; 3]));
            }
        }
        out
    }

    /// The pixels of `pixels` (stacked indices) that lie in this frame, re-indexed to it.
    pub fn select(&self, width: u32, pixels: Vec<PixelState>) -> Vec<PixelState> {
        if self.row == 0 && pixels.iter().all(|p| p.index / width.max(1) < self.height) {
            return pixels;
        }
        let (start, end) = (self.row * width, (self.row + self.height) * width);
        pixels
            .into_iter()
            .filter(|p| (start..end).contains(&p.index))
            .map(|p| PixelState { index: p.index - start, ..p })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_film::Quad;

    /// A frame cut out of a stack resolves as that frame rendered alone, mosaic included.
    #[test]
    fn a_stacked_frame_resolves_as_the_frame_alone() {
        let (w, h) = (9, 7);
        let mut alone = Framebuffer::new(w, h);
        let mut stacked = Framebuffer::new(w, h * 3);
        let quads = [Quad { x: 0, y: 0, w: 8, h: 8 }, Quad { x: 4, y: 4, w: 4, h: 4 }];
        let sums = [1 << 24, 2 << 24, 3 << 24, 5 << 23, 1 << 22, 7 << 20];
        alone.merge(&quads, 1, &sums, None).unwrap();
        let shifted: Vec<Quad> = quads.iter().map(|q| Quad { y: q.y + h, ..*q }).collect();
        stacked.merge(&shifted, 1, &sums, None).unwrap();
        let frame = FrameRows { row: h, height: h };
        assert_eq!(frame.resolve(&stacked), alone.resolve());
        assert_eq!(FrameRows::whole(&alone).resolve(&alone), alone.resolve());
        let changed = stacked.changes(0, usize::MAX).flatten().collect();
        let picked = frame.select(w, changed);
        let want: Vec<PixelState> = alone.changes(0, usize::MAX).flatten().collect();
        assert_eq!(picked, want);
        assert!(FrameRows { row: 2 * h, height: h }
            .select(w, stacked.changes(0, 99).flatten().collect())
            .is_empty());
    }
}
