//! Where a job's batches come from: the walk cut into ordered runs, and one type per mode
//! of pass two. `FixedSpp` is the paper's two passes (pass two walks the order again,
//! every pixel to the job's spp); `InRounds` cuts pass one off the walk and then hands out
//! rounds over tiles (jobs with a time budget or noise target). The lease machinery in
//! `PassQueue` is the same for both.

use std::collections::VecDeque;
use std::iter::Peekable;

use tessera_description::ids::BatchId;
use tessera_film::quadtree::{Quad, Walk};

use super::rounds::Rounds;
use super::{
    BatchSpec, Pace, Pass, PASS_ONE_FIRST, PASS_ONE_MAX, PASS_TWO_FLOOR_SAMPLES, PASS_TWO_MAX_PIXELS,
    PASS_TWO_SAMPLES,
};

/// A walk of the image cut into batches whose size doubles from `PASS_ONE_FIRST` to
/// `PASS_ONE_MAX` (pass one) or is given by the caller (pass two).
#[derive(Debug)]
struct WalkCut {
    walk: Peekable<Walk>,
    next_pass_one_size: usize,
}

impl WalkCut {
    fn new(width: u32, height: u32) -> Self {
        WalkCut { walk: Walk::new(width, height).peekable(), next_pass_one_size: PASS_ONE_FIRST }
    }

    /// The next run of the walk for `pass` (`pixels` of it in pass two), and whether the
    /// walk is exhausted after it (known at once, the walk is peeked, so that the last
    /// merge can finish the job).
    fn take(&mut self, pass: Pass, pixels: usize) -> (Vec<Quad>, bool) {
        let size = match pass {
            Pass::One => {
                let size = self.next_pass_one_size;
                self.next_pass_one_size = (size * 2).min(PASS_ONE_MAX);
                size
            }
            Pass::Two => pixels,
        };
        let quads: Vec<Quad> = self.walk.by_ref().take(size).collect();
        let exhausted = self.walk.peek().is_none();
        (quads, exhausted)
    }
}

/// The paper's two passes: pass one off the walk, then pass two off the walk again. A
/// sequence's frames are stacked, frame k in rows `k · height ..`: pass one walks every
/// frame in turn, in frame order, before pass two walks them again, so the whole sequence
/// previews before any frame refines. A batch never spans two frames.
///
/// Pass one's sizes are fixed; pass two's follow the speed of the worker each batch is cut
/// for (`Pace`), so they are not a function of the image alone: every pass-two size is
/// logged in id order, a checkpoint keeps the log, and a restore replays it to cut the
/// same batches again.
#[derive(Debug)]
pub(super) struct FixedSpp {
    width: u32,
    /// One frame's height.
    height: u32,
    spp: u32,
    pass: Pass,
    walk: WalkCut,
    cut_all: bool,
    /// Frames stacked, and the one being walked.
    frames: u32,
    frame: u32,
    /// Pixels of each pass-two batch cut so far, in id order.
    log: Vec<u32>,
    /// Sizes a restore cuts pass-two batches to before any pace counts.
    replay: VecDeque<u32>,
    /// Pass-two pixels cut so far (every frame).
    pass_two_cut: u64,
}

impl FixedSpp {
    pub(super) fn new(width: u32, height: u32, spp: u32, frames: u32) -> Self {
        FixedSpp {
            width,
            height,
            spp,
            pass: Pass::One,
            walk: WalkCut::new(width, height),
            cut_all: width == 0 || height == 0 || frames == 0,
            frames,
            frame: 0,
            log: Vec::new(),
            replay: VecDeque::new(),
            pass_two_cut: 0,
        }
    }

    /// Pixels of the next pass-two batch: a replayed size, else what the worker renders
    /// in a batch's time (`Pace::samples`, the old fixed `PASS_TWO_SAMPLES` until it is
    /// measured), shrunk near the end of the pass so that the farm's threads finish
    /// together (guided self-scheduling: at most half of a thread's share of what is left,
    /// but not below `PASS_TWO_FLOOR_SAMPLES`, where batches would be all overhead).
    fn pass_two_pixels(&mut self, pace: Pace) -> usize {
        if let Some(p) = self.replay.pop_front() {
            return p as usize;
        }
        let per_pixel = u64::from(self.spp - 1);
        let want = pace.samples.unwrap_or(PASS_TWO_SAMPLES) / per_pixel;
        let total = u64::from(self.width) * u64::from(self.height) * u64::from(self.frames);
        let left = total.saturating_sub(self.pass_two_cut);
        let share = match pace.threads {
            0 => u64::MAX,
            t => left.div_ceil(2 * u64::from(t)).max(PASS_TWO_FLOOR_SAMPLES / per_pixel),
        };
        want.min(share).clamp(1, PASS_TWO_MAX_PIXELS as u64) as usize
    }

    /// Sizes for the next pass-two batches, from a checkpoint's log (`sizes`), checked.
    pub(super) fn replay(&mut self, sizes: &[u32]) -> Result<(), u32> {
        if let Some(&bad) = sizes.iter().find(|&&p| p == 0 || p as usize > PASS_TWO_MAX_PIXELS) {
            return Err(bad);
        }
        self.replay = sizes.iter().copied().collect();
        Ok(())
    }

    /// Pixels of each pass-two batch cut so far, in id order.
    pub(super) fn log(&self) -> &[u32] {
        &self.log
    }

    /// Cuts the next batch, moving on to pass two when pass one is cut.
    pub(super) fn cut(&mut self, next_id: &mut u64, pace: Pace) -> Option<BatchSpec> {
        loop {
            if self.cut_all {
                return None;
            }
            let pass = self.pass;
            let (samples, pixels) = match pass {
                Pass::One => (0..1, 0),
                Pass::Two => (1..self.spp, self.pass_two_pixels(pace)),
            };
            let (mut quads, exhausted) = self.walk.take(pass, pixels);
            let offset = self.frame * self.height;
            if offset > 0 {
                quads.iter_mut().for_each(|q| q.y += offset);
            }
            if exhausted {
                if self.frame + 1 < self.frames {
                    self.frame += 1;
                    self.walk = WalkCut::new(self.width, self.height);
                } else if self.pass == Pass::One && self.spp > 1 {
                    self.pass = Pass::Two;
                    self.frame = 0;
                    self.walk = WalkCut::new(self.width, self.height);
                } else {
                    self.cut_all = true;
                }
            }
            if quads.is_empty() {
                if pass == Pass::Two {
                    // No batch came of the size: it stands for the next one, replayed or not.
                    self.replay.push_front(pixels as u32);
                }
                continue;
            }
            if pass == Pass::Two {
                self.log.push(pixels as u32);
                self.pass_two_cut += quads.len() as u64;
            }
            let id = BatchId(*next_id);
            *next_id += 1;
            return Some(BatchSpec { id, pass, quads, samples });
        }
    }

    pub(super) fn cut_all(&self) -> bool {
        self.cut_all
    }

    pub(super) fn pass(&self) -> Pass {
        self.pass
    }

    pub(super) fn abandon(&mut self) {
        self.cut_all = true;
    }
}

/// Pass one off the walk, then pass two in rounds over tiles (see `rounds.rs`).
#[derive(Debug)]
pub(super) struct InRounds {
    walk: WalkCut,
    /// Whether pass one is cut whole.
    cut_all: bool,
    /// The number of pass-one batches, once pass one is cut: pass-two batch ids follow
    /// them, derived from (round, tile).
    pass_one_batches: Option<u64>,
    pub(super) rounds: Rounds,
}

impl InRounds {
    pub(super) fn new(width: u32, height: u32, spp: u32) -> Self {
        InRounds {
            walk: WalkCut::new(width, height),
            cut_all: width == 0 || height == 0,
            pass_one_batches: None,
            rounds: Rounds::new(width, height, spp),
        }
    }

    /// Cuts the next pass-one batch; `None` once pass one is cut (rounds come from
    /// `next_round`).
    pub(super) fn cut(&mut self, next_id: &mut u64) -> Option<BatchSpec> {
        loop {
            if self.cut_all {
                return None;
            }
            let (quads, exhausted) = self.walk.take(Pass::One, 0);
            if exhausted {
                self.cut_all = true;
                self.pass_one_batches = Some(*next_id + u64::from(!quads.is_empty()));
            }
            if quads.is_empty() {
                continue;
            }
            let id = BatchId(*next_id);
            *next_id += 1;
            return Some(BatchSpec { id, pass: Pass::One, quads, samples: 0..1 });
        }
    }

    pub(super) fn cut_all(&self) -> bool {
        self.cut_all
    }

    /// The next ready round of a tile, as a batch.
    pub(super) fn next_round(&mut self) -> Option<BatchSpec> {
        let first = self.pass_one_batches?;
        let tiles = u64::from(self.rounds.tile_count());
        let (round, tile, quads, samples) = self.rounds.take()?;
        let id = BatchId(first + u64::from(round - 1) * tiles + u64::from(tile));
        Some(BatchSpec { id, pass: Pass::Two, quads, samples })
    }

    /// The (round, tile) of a pass-two batch.
    pub(super) fn round_of(&self, batch: BatchId) -> Option<(u32, u32)> {
        let k = batch.0.checked_sub(self.pass_one_batches?)?;
        let tiles = u64::from(self.rounds.tile_count().max(1));
        Some(((k / tiles) as u32 + 1, (k % tiles) as u32))
    }

    pub(super) fn pass(&self) -> Pass {
        if self.rounds.started() {
            Pass::Two
        } else {
            Pass::One
        }
    }

    pub(super) fn abandon(&mut self) {
        self.cut_all = true;
        self.rounds.abandon();
    }
}

/// A job's batches by the mode of its pass two.
#[derive(Debug)]
pub(super) enum Cut {
    /// The paper's two passes.
    Fixed(FixedSpp),
    /// Pass two in rounds.
    Rounds(InRounds),
}

impl Cut {
    pub(super) fn cut(&mut self, next_id: &mut u64, pace: Pace) -> Option<BatchSpec> {
        match self {
            Cut::Fixed(f) => f.cut(next_id, pace),
            Cut::Rounds(r) => r.cut(next_id),
        }
    }

    /// Whether the walk (of the last pass cut off it) is exhausted.
    pub(super) fn cut_all(&self) -> bool {
        match self {
            Cut::Fixed(f) => f.cut_all(),
            Cut::Rounds(r) => r.cut_all(),
        }
    }

    pub(super) fn pass(&self) -> Pass {
        match self {
            Cut::Fixed(f) => f.pass(),
            Cut::Rounds(r) => r.pass(),
        }
    }

    /// The two passes' cut, if this is one.
    pub(super) fn fixed(&self) -> Option<&FixedSpp> {
        match self {
            Cut::Fixed(f) => Some(f),
            Cut::Rounds(_) => None,
        }
    }

    pub(super) fn fixed_mut(&mut self) -> Option<&mut FixedSpp> {
        match self {
            Cut::Fixed(f) => Some(f),
            Cut::Rounds(_) => None,
        }
    }

    pub(super) fn rounds(&self) -> Option<&InRounds> {
        match self {
            Cut::Fixed(_) => None,
            Cut::Rounds(r) => Some(r),
        }
    }

    pub(super) fn rounds_mut(&mut self) -> Option<&mut InRounds> {
        match self {
            Cut::Fixed(_) => None,
            Cut::Rounds(r) => Some(r),
        }
    }

    pub(super) fn abandon(&mut self) {
        match self {
            Cut::Fixed(f) => f.abandon(),
            Cut::Rounds(r) => r.abandon(),
        }
    }
}
