//! Re-rendering what a liar delivered. Sums are additive integers and a pixel's sum is the
//! sum over its sample indices of a pure function, however the samples were batched; so a
//! pixel the liar touched is reset to zero and its merged samples (the coordinator's own
//! count, which no worker reports) are rendered again by others, in repair batches whose
//! results merge like any other. No result is kept for this: only which pixels each
//! worker delivered, a bit per pixel.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::ops::Range;
use std::time::Instant;

use tessera_description::ids::{BatchId, WorkerId};
use tessera_film::{Framebuffer, Quad};

use crate::scheduler::{
    BatchSpec, Lease, LeaseToken, Pass, PassQueue, PASS_TWO_MAX_PIXELS, PASS_TWO_SAMPLES,
};

/// Repair batch ids start here, far above any batch a walk is cut into (a 2^28-pixel
/// image at 2^16 spp has fewer than 2^40 batches), so they never collide.
pub const REPAIR_IDS: u64 = 1 << 48;

/// A set of pixels, one bit each (index y · width + x).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PixelSet(Vec<u64>);

impl PixelSet {
    /// Adds pixel `i`.
    pub fn insert(&mut self, i: u64) {
        let w = (i / 64) as usize;
        if self.0.len() <= w {
            self.0.resize(w + 1, 0);
        }
        self.0[w] |= 1 << (i % 64);
    }

    /// The pixels, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u64> + '_ {
        self.0.iter().enumerate().flat_map(|(w, &bits)| {
            (0..64).filter(move |b| bits & (1 << b) != 0).map(move |b| w as u64 * 64 + b)
        })
    }
}

/// A job's repairs: pixels reset and waiting for their samples again, grouped by the
/// sample range each needs, and repair batches leased.
#[derive(Debug, Default)]
pub(super) struct Repairs {
    /// Sample range → pixels waiting for it.
    pending: BTreeMap<(u32, u32), BTreeSet<u64>>,
    /// Pixel → its range in `pending`.
    range_of: HashMap<u64, (u32, u32)>,
    pub(super) leased: Vec<Lease>,
    next: u64,
    /// Repair batches handed out, for the figures.
    pub(super) batches: u64,
    /// Pixels reset, for the figures.
    pub(super) pixels: u64,
}

impl Repairs {
    /// Whether nothing is waiting or leased.
    pub(super) fn is_idle(&self) -> bool {
        self.pending.is_empty() && self.leased.is_empty()
    }

    fn add(&mut self, i: u64, r: Range<u32>) {
        self.pending.entry((r.start, r.end)).or_default().insert(i);
        self.range_of.insert(i, (r.start, r.end));
    }

    fn remove(&mut self, i: u64) -> Option<Range<u32>> {
        let key = self.range_of.remove(&i)?;
        if let Some(set) = self.pending.get_mut(&key) {
            set.remove(&i);
            if set.is_empty() {
                self.pending.remove(&key);
            }
        }
        Some(key.0..key.1)
    }

    /// Resets every pixel of `pixels` and queues its samples again: those merged (the
    /// framebuffer's count), plus those already waiting in a repair. Leased repair batches
    /// that hold such a pixel are called back whole (returned, to be released), their
    /// pixels waiting again. Returns the pixels reset.
    pub(super) fn reset(
        &mut self,
        pixels: &PixelSet,
        fb: &mut Framebuffer,
        queue: &PassQueue,
    ) -> (u64, Vec<Lease>) {
        let width = u64::from(fb.width());
        let hit: BTreeSet<u64> = pixels.iter().collect();
        let (recalled, kept): (Vec<Lease>, Vec<Lease>) =
            std::mem::take(&mut self.leased).into_iter().partition(|l| {
                l.spec.quads.iter().any(|q| hit.contains(&(u64::from(q.y) * width + u64::from(q.x))))
            });
        self.leased = kept;
        for l in &recalled {
            for q in &l.spec.quads {
                self.add(u64::from(q.y) * width + u64::from(q.x), l.spec.samples.clone());
            }
        }
        let mut n = 0;
        for &i in &hit {
            let (x, y) = ((i % width) as u32, (i / width) as u32);
            let waiting = self.remove(i).map_or(0, |r| r.end - r.start);
            let full = queue.merged_samples(x, y, fb.count(x, y) + waiting);
            fb.reset(x, y);
            if !full.is_empty() {
                self.add(i, full);
            }
            n += 1;
        }
        self.pixels += n;
        (n, recalled)
    }

    /// A repair batch for `worker`: pixels waiting for the same samples, in index order,
    /// about a pass-two batch's worth, all of one frame (`frame_pixels` a frame: a batch
    /// renders one frame's scene).
    pub(super) fn lease(
        &mut self,
        worker: WorkerId,
        token: LeaseToken,
        width: u32,
        frame_pixels: u64,
        now: Instant,
    ) -> Option<Lease> {
        let (&(start, end), _) = self.pending.iter().next()?;
        let per = u64::from(end - start).max(1);
        let most = (PASS_TWO_SAMPLES / per).clamp(1, PASS_TWO_MAX_PIXELS as u64) as usize;
        let set = self.pending.get_mut(&(start, end)).expect("first key");
        let frame_of = |i: u64| i / frame_pixels.max(1);
        let first = set.iter().next().map_or(0, |&i| frame_of(i));
        let take: Vec<u64> = set.iter().copied().take_while(|&i| frame_of(i) == first).take(most).collect();
        for i in &take {
            set.remove(i);
            self.range_of.remove(i);
        }
        if set.is_empty() {
            self.pending.remove(&(start, end));
        }
        let w = u64::from(width);
        let quads = take.iter().map(|&i| Quad { x: (i % w) as u32, y: (i / w) as u32, w: 1, h: 1 }).collect();
        let id = BatchId(REPAIR_IDS + self.next);
        self.next += 1;
        self.batches += 1;
        let pass = if start == 0 { Pass::One } else { Pass::Two };
        let spec = BatchSpec { id, pass, quads, samples: start..end };
        let lease = Lease { spec, worker, attempt: 1, since: now, token };
        self.leased.push(lease.clone());
        Some(lease)
    }

    /// The repair lease `worker` holds on `batch` with `token`.
    pub(super) fn held(&self, batch: BatchId, worker: WorkerId, token: &[u8]) -> Option<&Lease> {
        self.leased.iter().find(|l| {
            let ok = l.token.matches(token);
            ok && l.spec.id == batch && l.worker == worker
        })
    }

    /// Removes the lease of `batch` (merged, or to be given to another worker).
    pub(super) fn finish(&mut self, batch: BatchId) -> Option<Lease> {
        let k = self.leased.iter().position(|l| l.spec.id == batch)?;
        Some(self.leased.remove(k))
    }

    /// Puts a repair lease's pixels back to wait (it failed, or its worker left).
    pub(super) fn put_back(&mut self, lease: &Lease, width: u32) {
        for q in &lease.spec.quads {
            self.add(u64::from(q.y) * u64::from(width) + u64::from(q.x), lease.spec.samples.clone());
        }
    }

    /// Takes back every repair lease of `worker`; returns them.
    pub(super) fn take_back_worker(&mut self, worker: WorkerId, width: u32) -> Vec<Lease> {
        let (gone, kept): (Vec<Lease>, Vec<Lease>) =
            std::mem::take(&mut self.leased).into_iter().partition(|l| l.worker == worker);
        self.leased = kept;
        for l in &gone {
            self.put_back(l, width);
        }
        gone
    }

    /// Drops everything (the job is over).
    pub(super) fn abandon(&mut self) -> Vec<Lease> {
        self.pending.clear();
        self.range_of.clear();
        std::mem::take(&mut self.leased)
    }
}
