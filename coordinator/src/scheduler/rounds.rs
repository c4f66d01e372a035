//! Pass two in rounds, for jobs with a time budget or a noise target: the image is cut
//! into 32×32 tiles, visited in the paper's quadrant order, and each round adds samples to
//! every pixel still active, so that stopping at any moment leaves an image converged
//! evenly to within one round. Round r of a tile is handed out only after round r − 1 of
//! the same tile is merged, which is what lets the adaptive decision (which pixels go on)
//! depend only on merged samples: the same for any worker count or arrival order.
//! Pure: the decisions come in from the farm.

use std::collections::BTreeMap;
use std::ops::Range;

use tessera_film::quadtree::{Quad, Walk};

/// Tile side in pixels.
pub const TILE: u32 = 32;
/// The most samples one round adds to a pixel: rounds double from 1 up to this, so that
/// early rounds are quick and late ones never leave the image uneven by more than this.
pub const ROUND_MAX_SAMPLES: u32 = 64;

/// One past the last sample index taken after `round` rounds (round 0 is pass one):
/// 2^round while rounds double (up to `ROUND_MAX_SAMPLES`), then `ROUND_MAX_SAMPLES` more
/// a round; never past `spp`. O(1): budgets come with caps of a million samples.
pub fn round_end(round: u32, spp: u32) -> u32 {
    let doubling = ROUND_MAX_SAMPLES.trailing_zeros() + 1;
    let end = if round <= doubling {
        1u64 << round
    } else {
        (1u64 << doubling) + u64::from(round - doubling) * u64::from(ROUND_MAX_SAMPLES)
    };
    end.min(u64::from(spp)) as u32
}

/// The sample indices round `round` (≥ 1) takes.
pub fn round_samples(round: u32, spp: u32) -> Range<u32> {
    round_end(round - 1, spp)..round_end(round, spp)
}

/// The round after which a pixel holds `count` samples, if some round ends there.
pub fn round_reaching(count: u32, spp: u32) -> Option<u32> {
    if count == spp {
        return Some(last_round(spp));
    }
    let doubling = ROUND_MAX_SAMPLES.trailing_zeros() + 1;
    let r = if count.is_power_of_two() && count <= 1 << doubling {
        count.trailing_zeros()
    } else if count > 1 << doubling && (count - (1 << doubling)).is_multiple_of(ROUND_MAX_SAMPLES) {
        doubling + (count - (1 << doubling)) / ROUND_MAX_SAMPLES
    } else {
        return None;
    };
    (round_end(r, spp) == count).then_some(r)
}

/// The number of rounds after pass one that reach `spp`.
pub fn last_round(spp: u32) -> u32 {
    let doubling = ROUND_MAX_SAMPLES.trailing_zeros() + 1;
    if spp <= 1 << doubling {
        spp.next_power_of_two().trailing_zeros()
    } else {
        doubling + (spp - (1 << doubling)).div_ceil(ROUND_MAX_SAMPLES)
    }
}

/// The tiles and which of them have a round ready to hand out.
#[derive(Debug)]
pub struct Rounds {
    width: u32,
    height: u32,
    spp: u32,
    /// Tile origins (lower-left, paper coordinates) in the paper's order over the grid.
    tiles: Vec<(u32, u32)>,
    /// Ready rounds: (round, tile) → the pixels to sample (`None`: all of the tile).
    ready: BTreeMap<(u32, u32), Option<Vec<Quad>>>,
    /// Tiles with rounds still to come.
    open: u32,
    /// Whether round 1 has been released (pass one is merged).
    started: bool,
}

impl Rounds {
    /// The tiles of a `width × height` image at `spp`.
    pub fn new(width: u32, height: u32, spp: u32) -> Self {
        let (tx, ty) = (width.div_ceil(TILE), height.div_ceil(TILE));
        let tiles: Vec<(u32, u32)> = Walk::new(tx, ty).map(|q| (q.x * TILE, q.y * TILE)).collect();
        let open = if spp > 1 { tiles.len() as u32 } else { 0 };
        Rounds { width, height, spp, tiles, ready: BTreeMap::new(), open, started: false }
    }

    /// Tiles in the image.
    pub fn tile_count(&self) -> u32 {
        self.tiles.len() as u32
    }

    /// The pixels of tile `t` in the paper's order within the tile.
    pub fn tile_pixels(&self, t: u32) -> Vec<Quad> {
        let (x0, y0) = self.tiles[t as usize];
        let (w, h) = (TILE.min(self.width - x0), TILE.min(self.height - y0));
        Walk::new(w, h).map(|q| Quad { x: x0 + q.x, y: y0 + q.y, w: 1, h: 1 }).collect()
    }

    /// Releases round 1 of every tile (once pass one is merged).
    pub fn start(&mut self) {
        if !self.started && self.spp > 1 {
            for t in 0..self.tile_count() {
                self.ready.insert((1, t), None);
            }
        }
        self.started = true;
    }

    /// Whether round 1 was released.
    pub fn started(&self) -> bool {
        self.started
    }

    /// Marks round 1 as released without releasing it: a restored queue schedules each
    /// tile's next round itself.
    pub fn start_restored(&mut self) {
        self.started = true;
    }

    /// Whether nothing is ready to hand out now.
    pub fn idle(&self) -> bool {
        self.ready.is_empty()
    }

    /// Schedules round `round` of tile `t` for `active` pixels (`None`: all); a round past
    /// the last, or no active pixel, closes the tile.
    pub fn schedule(&mut self, t: u32, round: u32, active: Option<Vec<Quad>>) {
        if round > last_round(self.spp) || active.as_ref().is_some_and(|a| a.is_empty()) {
            self.open = self.open.saturating_sub(1);
        } else {
            self.ready.insert((round, t), active);
        }
    }

    /// The lowest ready round, lowest tile first: (round, tile, pixels, samples).
    pub fn take(&mut self) -> Option<(u32, u32, Vec<Quad>, Range<u32>)> {
        let ((round, t), active) = self.ready.pop_first()?;
        let pixels = active.unwrap_or_else(|| self.tile_pixels(t));
        Some((round, t, pixels, round_samples(round, self.spp)))
    }

    /// Whether every tile is closed.
    pub fn finished(&self) -> bool {
        self.started && self.open == 0 && self.ready.is_empty()
    }

    /// Drops everything not handed out (the job stopped).
    pub fn abandon(&mut self) {
        self.ready.clear();
        self.open = 0;
        self.started = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounds_double_then_stay_at_their_cap_and_end_at_spp() {
        let ends: Vec<u32> = (0..10).map(|r| round_end(r, 1000)).collect();
        assert_eq!(ends, [1, 2, 4, 8, 16, 32, 64, 128, 192, 256]);
        assert_eq!(round_end(last_round(1000), 1000), 1000);
        assert_eq!(last_round(1), 0);
        assert_eq!(last_round(2), 1);
        assert_eq!(round_samples(3, 5), 4..5);
        assert_eq!(last_round(5), 3);
        // Every round ends where the next begins, and the last one at spp, for every spp.
        for spp in (1..700).chain([1 << 20, u32::MAX]) {
            let last = last_round(spp);
            assert_eq!(round_end(last, spp), spp, "spp {spp}");
            assert!(last == 0 || round_end(last - 1, spp) < spp, "spp {spp}");
            for r in (0..=last.min(40)).chain([last]) {
                assert_eq!(round_reaching(round_end(r, spp), spp), Some(r), "spp {spp}, round {r}");
            }
        }
        assert_eq!(round_reaching(3, 100), None);
        assert_eq!(round_reaching(150, 1000), None);
    }

    #[test]
    fn tiles_cover_every_pixel_once() {
        for (w, h) in [(1, 1), (33, 70), (64, 64), (100, 5)] {
            let r = Rounds::new(w, h, 4);
            let mut seen = vec![0u32; (w * h) as usize];
            for t in 0..r.tile_count() {
                for q in r.tile_pixels(t) {
                    seen[(q.y * w + q.x) as usize] += 1;
                }
            }
            assert!(seen.iter().all(|&n| n == 1), "{w}x{h}");
        }
    }
}

#[cfg(test)]
mod queue_tests {
    use std::time::Instant;

    use crate::scheduler::{BatchSpec, LeaseToken, PassQueue};
    use tessera_description::ids::WorkerId;

    /// Any token: these tests are about rounds, not fencing.
    const TOKEN: LeaseToken = LeaseToken([7; 16]);

    /// Leases and completes up to `limit` batches of a queue in rounds on one worker,
    /// scheduling every tile's next round for all its pixels; adds each batch's samples to
    /// `counts` (row-major, `width` wide) and returns the batches in order.
    fn run(q: &mut PassQueue, width: u32, counts: &mut [u32], limit: usize) -> Vec<BatchSpec> {
        let now = Instant::now();
        let mut out = Vec::new();
        while out.len() < limit {
            let Some(l) = q.lease_next(WorkerId(1), TOKEN, now) else { break };
            let b = l.spec.clone();
            for p in &b.quads {
                counts[(p.y * width + p.x) as usize] += b.samples.end - b.samples.start;
            }
            q.complete(b.id, now).unwrap();
            if let Some((round, tile)) = q.round_of(b.id) {
                q.schedule_round(tile, round + 1, None);
            }
            out.push(b);
        }
        out
    }

    /// Without a noise target, rounds give every pixel exactly spp samples, in rounds that
    /// each cover the whole image before the next begins for the same tile.
    #[test]
    fn rounds_cover_every_pixel_with_spp_samples() {
        for (w, h, spp) in [(1, 1, 1), (40, 33, 5), (64, 64, 130), (7, 70, 2)] {
            let mut q = PassQueue::with_rounds(w, h, spp);
            let mut samples = vec![0u32; (w * h) as usize];
            run(&mut q, w, &mut samples, usize::MAX);
            assert!(samples.iter().all(|&s| s == spp), "{w}x{h}@{spp}");
            assert!(q.is_finished(), "{w}x{h}@{spp}");
            assert_eq!(q.samples_done(), q.samples_total());
        }
    }

    /// A queue in rounds rebuilt from counts mid-way hands out exactly the batches that
    /// were left, with the same ids.
    #[test]
    fn restored_rounds_continue_with_the_same_batches() {
        let (w, h, spp) = (70, 40, 20);
        let mut whole = PassQueue::with_rounds(w, h, spp);
        let mut c = vec![0; (w * h) as usize];
        let all = run(&mut whole, w, &mut c, usize::MAX);
        for stop in [1, 5, 17, 30] {
            let mut q = PassQueue::with_rounds(w, h, spp);
            let mut counts = vec![0; (w * h) as usize];
            run(&mut q, w, &mut counts, stop);
            let mut r = PassQueue::restore_rounds(w, h, spp, &q.completed(), &counts, None).unwrap();
            assert_eq!(r.samples_done(), q.samples_done(), "stop {stop}");
            let rest = run(&mut r, w, &mut counts, usize::MAX);
            let mut got: Vec<_> = rest.iter().map(|b| b.id).collect();
            got.sort();
            let mut want: Vec<_> = all[stop..].iter().map(|b| b.id).collect();
            want.sort();
            assert_eq!(got, want, "stop {stop}");
            assert!(counts.iter().all(|&n| n == spp));
        }
    }
}
