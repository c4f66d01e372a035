//! The pure core of a job's scheduling: cutting the walk into batches, leasing them to
//! workers, taking them back, and accepting each batch's result exactly once. No I/O, no
//! tokio, no prost: the time comes in as an argument, so tests drive it with a fake clock.

use std::collections::{BTreeMap, HashMap};
use std::ops::Range;
use std::time::{Duration, Instant};

use crate::ids::{BatchId, WorkerId};
use crate::quadtree::{Quad, Walk};

/// Pixels in the first pass-one batch: small, so that the first mosaic shows at once.
pub const PASS_ONE_FIRST: usize = 16;
/// Pixels in a pass-one batch once the sizes have doubled up from `PASS_ONE_FIRST`:
/// ~4 ms of tracing for a simple scene, large enough that per-batch overhead vanishes.
pub const PASS_ONE_MAX: usize = 2048;
/// Samples aimed at per pass-two batch; the pixel count follows from the spp.
pub const PASS_TWO_SAMPLES: u64 = 32_768;
/// The most pixels in a pass-two batch (bounds message sizes at low spp).
pub const PASS_TWO_MAX_PIXELS: usize = 8192;

/// Which pass a batch belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Pass {
    /// The first sample of every pixel, painted as mosaic blocks.
    One,
    /// The remaining samples of every pixel.
    Two,
}

impl Pass {
    /// 1 or 2, as on the wire and in status.
    pub fn number(self) -> u32 {
        match self {
            Pass::One => 1,
            Pass::Two => 2,
        }
    }
}

/// A run of consecutive pixels of the walk, with the samples to take of each.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BatchSpec {
    /// The batch's id, its position among the job's batches.
    pub id: BatchId,
    /// The pass.
    pub pass: Pass,
    /// The pixels in walk order; in pass one each with the block it paints.
    pub quads: Vec<Quad>,
    /// Sample indices taken of every pixel.
    pub samples: Range<u32>,
}

impl BatchSpec {
    /// Samples in the batch.
    pub fn sample_count(&self) -> u64 {
        self.quads.len() as u64 * u64::from(self.samples.end - self.samples.start)
    }
}

/// A batch leased to a worker.
#[derive(Debug, Clone)]
pub struct Lease {
    /// What to render.
    pub spec: BatchSpec,
    /// Who renders it.
    pub worker: WorkerId,
    /// 1 for the first lease of the batch, 2 for the next, and so on.
    pub attempt: u32,
    /// When it was leased.
    pub since: Instant,
}

/// Why a result was not accepted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CompleteError {
    /// The batch's result was merged already (a retry or a late lease finished second), or
    /// the batch never existed.
    #[error("{batch} is not outstanding (already merged, or never cut)")]
    NotOutstanding {
        /// The batch.
        batch: BatchId,
    },
}

/// The batches of one job: those not cut yet (the rest of the walk), those waiting to be
/// leased again, those leased, and how many are done.
#[derive(Debug)]
pub struct PassQueue {
    width: u32,
    height: u32,
    spp: u32,
    pass: Pass,
    walk: std::iter::Peekable<Walk>,
    /// Whether the walk of the last pass is exhausted. Known as soon as the last batch is
    /// cut (the walk is peeked), so that the merge of the last result finishes the job
    /// whether or not anyone asks for more work afterwards.
    cut_all: bool,
    next_id: u64,
    next_pass_one_size: usize,
    /// Batches whose lease was taken back, waiting to be leased again, oldest first.
    retry: BTreeMap<BatchId, (BatchSpec, u32)>,
    leased: HashMap<BatchId, Lease>,
    samples_done: u64,
    pass_one_pixels_done: u64,
}

impl PassQueue {
    /// The batches of a `width × height` image at `spp` samples per pixel.
    pub fn new(width: u32, height: u32, spp: u32) -> Self {
        PassQueue {
            width,
            height,
            spp: spp.max(1),
            pass: Pass::One,
            walk: Walk::new(width, height).peekable(),
            cut_all: width == 0 || height == 0,
            next_id: 0,
            next_pass_one_size: PASS_ONE_FIRST,
            retry: BTreeMap::new(),
            leased: HashMap::new(),
            samples_done: 0,
            pass_one_pixels_done: 0,
        }
    }

    /// The pass whose batches are being cut now.
    pub fn pass(&self) -> Pass {
        self.pass
    }

    /// Samples in the whole job.
    pub fn samples_total(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height) * u64::from(self.spp)
    }

    /// Samples merged so far.
    pub fn samples_done(&self) -> u64 {
        self.samples_done
    }

    /// Pixels of pass one merged so far.
    pub fn pass_one_pixels_done(&self) -> u64 {
        self.pass_one_pixels_done
    }

    /// Batches leased right now.
    pub fn leased(&self) -> usize {
        self.leased.len()
    }

    /// Whether every batch has been merged.
    pub fn is_finished(&self) -> bool {
        self.cut_all && self.retry.is_empty() && self.leased.is_empty()
    }

    /// Cuts the next batch off the walk, moving on to pass two when pass one is cut.
    fn cut(&mut self) -> Option<BatchSpec> {
        loop {
            if self.cut_all {
                return None;
            }
            let pass = self.pass;
            let (size, samples) = match self.pass {
                Pass::One => {
                    let size = self.next_pass_one_size;
                    self.next_pass_one_size = (size * 2).min(PASS_ONE_MAX);
                    (size, 0..1)
                }
                Pass::Two => {
                    let per_pixel = u64::from(self.spp - 1);
                    let size = (PASS_TWO_SAMPLES / per_pixel).clamp(1, PASS_TWO_MAX_PIXELS as u64);
                    (size as usize, 1..self.spp)
                }
            };
            let quads: Vec<Quad> = self.walk.by_ref().take(size).collect();
            if self.walk.peek().is_none() {
                if self.pass == Pass::One && self.spp > 1 {
                    self.pass = Pass::Two;
                    self.walk = Walk::new(self.width, self.height).peekable();
                } else {
                    self.cut_all = true;
                }
            }
            if quads.is_empty() {
                continue;
            }
            let id = BatchId(self.next_id);
            self.next_id += 1;
            return Some(BatchSpec { id, pass, quads, samples });
        }
    }

    /// Leases the next batch to `worker`: a batch taken back from another worker first
    /// (oldest first), else a new one off the walk.
    pub fn lease_next(&mut self, worker: WorkerId, now: Instant) -> Option<&Lease> {
        let (spec, attempt) = match self.retry.pop_first() {
            Some((_, (spec, attempts))) => (spec, attempts + 1),
            None => (self.cut()?, 1),
        };
        let id = spec.id;
        self.leased.insert(id, Lease { spec, worker, attempt, since: now });
        self.leased.get(&id)
    }

    /// Batches leased to `worker` now.
    pub fn leased_by(&self, worker: WorkerId) -> usize {
        self.leased.values().filter(|l| l.worker == worker).count()
    }

    /// The spec of `batch` if its result is still wanted: leased, or taken back and
    /// waiting to be leased again.
    pub fn outstanding(&self, batch: BatchId) -> Option<&BatchSpec> {
        self.leased.get(&batch).map(|l| &l.spec).or_else(|| self.retry.get(&batch).map(|(s, _)| s))
    }

    /// The lease of `batch`, if it is leased.
    pub fn lease(&self, batch: BatchId) -> Option<&Lease> {
        self.leased.get(&batch)
    }

    /// Accepts the result of `batch` (from any attempt: all compute the same samples) and
    /// returns its spec for merging. A second result for the same batch is refused, which
    /// is what makes merging exactly-once.
    pub fn complete(&mut self, batch: BatchId) -> Result<BatchSpec, CompleteError> {
        let spec = match self.leased.remove(&batch) {
            Some(lease) => lease.spec,
            None => match self.retry.remove(&batch) {
                Some((spec, _)) => spec,
                None => return Err(CompleteError::NotOutstanding { batch }),
            },
        };
        self.samples_done += spec.sample_count();
        if spec.pass == Pass::One {
            self.pass_one_pixels_done += spec.quads.len() as u64;
        }
        Ok(spec)
    }

    /// Takes back the lease of `batch` so that another worker gets it.
    pub fn take_back(&mut self, batch: BatchId) -> bool {
        match self.leased.remove(&batch) {
            Some(lease) => {
                self.retry.insert(batch, (lease.spec, lease.attempt));
                true
            }
            None => false,
        }
    }

    /// Takes back every lease held by `worker` (it left, or fell silent); returns them.
    pub fn take_back_worker(&mut self, worker: WorkerId) -> Vec<BatchId> {
        let mut ids: Vec<BatchId> =
            self.leased.values().filter(|l| l.worker == worker).map(|l| l.spec.id).collect();
        ids.sort();
        for id in &ids {
            self.take_back(*id);
        }
        ids
    }

    /// Takes back every lease older than `max_age`, for callers that bound batch time.
    pub fn take_back_older_than(&mut self, now: Instant, max_age: Duration) -> Vec<BatchId> {
        let mut ids: Vec<BatchId> = self
            .leased
            .values()
            .filter(|l| now.saturating_duration_since(l.since) > max_age)
            .map(|l| l.spec.id)
            .collect();
        ids.sort();
        for id in &ids {
            self.take_back(*id);
        }
        ids
    }

    /// Drops every outstanding lease and everything not yet cut (the job was cancelled).
    pub fn abandon(&mut self) {
        self.leased.clear();
        self.retry.clear();
        self.cut_all = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drain(q: &mut PassQueue, now: Instant) -> Vec<BatchSpec> {
        let mut out = Vec::new();
        while let Some(l) = q.lease_next(WorkerId(1), now) {
            out.push(l.spec.clone());
        }
        out
    }

    #[test]
    fn batches_cover_both_passes_exactly_once() {
        let now = Instant::now();
        for (w, h, spp) in [(1, 1, 1), (7, 5, 1), (33, 17, 4), (100, 80, 16), (1, 300, 3)] {
            let mut q = PassQueue::new(w, h, spp);
            let batches = drain(&mut q, now);
            let mut samples = vec![0u32; (w * h) as usize];
            for b in &batches {
                for quad in &b.quads {
                    samples[(quad.y * w + quad.x) as usize] += b.samples.end - b.samples.start;
                }
                q.complete(b.id).unwrap();
            }
            assert!(samples.iter().all(|&s| s == spp), "{w}x{h}@{spp}");
            assert!(q.is_finished());
            assert_eq!(q.samples_done(), q.samples_total());
            // Pass two never starts before pass one is fully cut, and ids follow the walk.
            let passes: Vec<Pass> = batches.iter().map(|b| b.pass).collect();
            assert!(passes.windows(2).all(|p| p[0] <= p[1]));
            assert!(batches.windows(2).all(|b| b[0].id < b[1].id));
        }
    }

    /// The merge of the last batch finishes the job even when nobody asks for more work
    /// after the last lease (a hang found with one worker on a tiny image).
    #[test]
    fn last_result_finishes_without_another_lease() {
        let now = Instant::now();
        for (w, h, spp) in [(1, 1, 1), (48, 30, 4), (7, 5, 1), (16, 16, 2)] {
            let mut counting = PassQueue::new(w, h, spp);
            let n = drain(&mut counting, now).len();
            let mut q = PassQueue::new(w, h, spp);
            let ids: Vec<BatchId> = (0..n).map(|_| q.lease_next(WorkerId(1), now).unwrap().spec.id).collect();
            for id in ids {
                assert!(!q.is_finished());
                q.complete(id).unwrap();
            }
            assert!(q.is_finished(), "{w}x{h}@{spp}: all batches merged but not finished");
        }
    }

    #[test]
    fn pass_one_batches_grow_from_small_to_max() {
        let mut q = PassQueue::new(256, 256, 1);
        let sizes: Vec<usize> = drain(&mut q, Instant::now()).iter().map(|b| b.quads.len()).collect();
        assert_eq!(sizes[0], PASS_ONE_FIRST);
        assert_eq!(sizes[1], PASS_ONE_FIRST * 2);
        assert!(sizes.iter().all(|&s| s <= PASS_ONE_MAX));
        assert!(sizes.contains(&PASS_ONE_MAX));
    }

    /// Exactly-once: a batch computed twice (a retry after its worker went silent) is
    /// merged once; the second result is refused.
    #[test]
    fn duplicate_results_are_refused() {
        let now = Instant::now();
        let mut q = PassQueue::new(16, 16, 1);
        let first = q.lease_next(WorkerId(1), now).unwrap().spec.id;
        assert_eq!(q.take_back_worker(WorkerId(1)), vec![first]);
        let again = q.lease_next(WorkerId(2), now).unwrap();
        assert_eq!((again.spec.id, again.attempt), (first, 2));
        // The silent worker's late result arrives first and wins...
        assert!(q.complete(first).is_ok());
        // ...and the retry's result is a duplicate.
        assert_eq!(q.complete(first), Err(CompleteError::NotOutstanding { batch: first }));
    }

    #[test]
    fn taken_back_batches_are_leased_again_oldest_first() {
        let now = Instant::now();
        let mut q = PassQueue::new(64, 64, 1);
        let a = q.lease_next(WorkerId(1), now).unwrap().spec.id;
        let b = q.lease_next(WorkerId(2), now).unwrap().spec.id;
        let c = q.lease_next(WorkerId(1), now).unwrap().spec.id;
        q.take_back_worker(WorkerId(1));
        assert_eq!(q.lease_next(WorkerId(3), now).unwrap().spec.id, a);
        assert_eq!(q.lease_next(WorkerId(3), now).unwrap().spec.id, c);
        assert!(q.lease(b).is_some());
        // A result for a batch waiting in the retry queue is still accepted once.
        let d = q.lease_next(WorkerId(4), now).unwrap().spec.id;
        q.take_back(d);
        assert!(q.complete(d).is_ok());
        assert_ne!(q.lease_next(WorkerId(4), now).unwrap().spec.id, d);
    }

    #[test]
    fn old_leases_expire_with_a_fake_clock() {
        let t0 = Instant::now();
        let mut q = PassQueue::new(64, 64, 1);
        let a = q.lease_next(WorkerId(1), t0).unwrap().spec.id;
        assert!(q.take_back_older_than(t0 + Duration::from_secs(5), Duration::from_secs(10)).is_empty());
        assert_eq!(q.take_back_older_than(t0 + Duration::from_secs(11), Duration::from_secs(10)), vec![a]);
    }
}
