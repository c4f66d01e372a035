//! The pure core of a job's scheduling: cutting the walk into batches, leasing them to
//! workers, taking them back, and accepting each batch's result exactly once. No I/O, no
//! tokio, no prost: the time comes in as an argument, so tests drive it with a fake clock.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::ops::Range;
use std::time::{Duration, Instant};

use crate::rounds::Rounds;
use tessera_description::ids::{BatchId, WorkerId};
use tessera_film::quadtree::{Quad, Walk};

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

/// Which batches of a job are merged: every id below `below`, and the ids in `above`. This
/// is all a checkpoint needs besides the framebuffer, because the cut of the walk into
/// batches is deterministic: the same image and spp give the same batches with the same ids.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Completed {
    /// Every batch id below this one is merged.
    pub below: u64,
    /// Merged ids above `below`, ascending (those finished out of order).
    pub above: Vec<u64>,
}

impl Completed {
    fn contains(&self, id: u64) -> bool {
        id < self.below || self.above.binary_search(&id).is_ok()
    }

    /// One past the highest merged id.
    pub fn end(&self) -> u64 {
        self.above.last().map_or(self.below, |&a| a + 1).max(self.below)
    }
}

/// Why a queue could not be rebuilt from a checkpoint.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RestoreError {
    /// The checkpoint names batches this job does not have.
    #[error("the checkpoint names batch {id}, but a {width}x{height} image at {spp} spp has only {batches} batches")]
    NoSuchBatch {
        /// The id named.
        id: u64,
        /// Batches the job has.
        batches: u64,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
        /// Samples per pixel.
        spp: u32,
    },
    /// The sample counts of a tile fit no round (a checkpoint of another job).
    #[error("tile {tile} holds {count} samples in a pixel, which no round ends at")]
    Rounds {
        /// The tile.
        tile: u32,
        /// The count found.
        count: u32,
    },
    /// The merged ids are not ascending, or repeat one below `below`.
    #[error("the checkpoint's list of merged batches is not ascending above {below}")]
    Unordered {
        /// The watermark.
        below: u64,
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
    /// Speculative second leases of batches in `leased` (stragglers near the end): the
    /// first result of either wins.
    spares: HashMap<BatchId, Lease>,
    /// Merged batches: all ids below `done_below`, and these above it.
    done_below: u64,
    done_above: BTreeSet<u64>,
    /// Mean time from lease to merge, for judging which leases are stragglers.
    mean_batch_time: Option<Duration>,
    /// Pass two in rounds over tiles (jobs with a time budget or noise target).
    rounds: Option<Rounds>,
    /// In rounds mode, the number of pass-one batches, once pass one is cut: pass-two
    /// batch ids follow them, derived from (round, tile).
    pass_one_batches: Option<u64>,
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
            spares: HashMap::new(),
            done_below: 0,
            done_above: BTreeSet::new(),
            mean_batch_time: None,
            rounds: None,
            pass_one_batches: None,
            samples_done: 0,
            pass_one_pixels_done: 0,
        }
    }

    /// The batches of a job whose pass two runs in rounds over tiles (see `rounds.rs`).
    pub fn with_rounds(width: u32, height: u32, spp: u32) -> Self {
        let mut q = PassQueue::new(width, height, spp);
        q.rounds = Some(Rounds::new(width, height, q.spp));
        q
    }

    /// The (round, tile) of a pass-two batch of a job in rounds.
    pub fn round_of(&self, batch: BatchId) -> Option<(u32, u32)> {
        let (rounds, first) = (self.rounds.as_ref()?, self.pass_one_batches?);
        let k = batch.0.checked_sub(first)?;
        let tiles = u64::from(rounds.tile_count().max(1));
        Some(((k / tiles) as u32 + 1, (k % tiles) as u32))
    }

    /// Schedules round `round` of tile `tile` for `active` pixels (`None`: all of the
    /// tile); an empty list or a round past the last closes the tile.
    pub fn schedule_round(&mut self, tile: u32, round: u32, active: Option<Vec<Quad>>) {
        if let Some(r) = self.rounds.as_mut() {
            r.schedule(tile, round, active);
        }
    }

    /// A queue in rounds rebuilt from a checkpoint: pass one from its merged batches, and
    /// each tile's next round from its pixels' sample counts (a tile's active pixels all
    /// hold the samples of the last round merged; the others stopped earlier). `active`
    /// says whether a pixel that finished a round goes on (the adaptive decision), `None`
    /// if every pixel does.
    pub fn restore_rounds(
        width: u32,
        height: u32,
        spp: u32,
        completed: &Completed,
        counts: &[u32],
        active: Option<&dyn Fn(Quad) -> bool>,
    ) -> Result<Self, RestoreError> {
        let mut q = Self::restore_with(PassQueue::with_rounds(width, height, spp), completed)?;
        let pixels = u64::from(width) * u64::from(height);
        if !(q.cut_all && q.retry.is_empty() && q.pass_one_pixels_done == pixels) {
            return Ok(q);
        }
        let spp = q.spp;
        let rounds = q.rounds.as_mut().expect("made with rounds");
        rounds.start_restored();
        let mut extra = 0u64;
        for t in 0..rounds.tile_count() {
            let tile = rounds.tile_pixels(t);
            let count = |p: &Quad| counts[(p.y * width + p.x) as usize];
            let most = tile.iter().map(count).max().unwrap_or(1);
            let round = crate::rounds::round_reaching(most, spp)
                .ok_or(RestoreError::Rounds { tile: t, count: most })?;
            extra += tile.iter().map(|p| u64::from(count(p) - 1)).sum::<u64>();
            let next = match (round, active) {
                (0, _) | (_, None) => None,
                (_, Some(keep)) => Some(tile.into_iter().filter(|p| count(p) == most && keep(*p)).collect()),
            };
            rounds.schedule(t, round + 1, next);
        }
        q.samples_done += extra;
        Ok(q)
    }

    /// The queue of a job of which the batches in `completed` are merged: the walk is cut
    /// again up to the last merged batch, and the batches in between that are not merged
    /// wait to be leased first. Costs one walk of the image per pass cut, no rendering.
    pub fn restore(width: u32, height: u32, spp: u32, completed: &Completed) -> Result<Self, RestoreError> {
        Self::restore_with(PassQueue::new(width, height, spp), completed)
    }

    fn restore_with(mut q: PassQueue, completed: &Completed) -> Result<Self, RestoreError> {
        let (width, height) = (q.width, q.height);
        if completed.above.windows(2).any(|w| w[0] >= w[1])
            || completed.above.first().is_some_and(|&a| a < completed.below)
        {
            return Err(RestoreError::Unordered { below: completed.below });
        }
        let end = completed.end();
        while q.next_id < end {
            let Some(spec) = q.cut() else {
                let id = completed.above.last().copied().unwrap_or(end - 1);
                return Err(RestoreError::NoSuchBatch { id, batches: q.next_id, width, height, spp: q.spp });
            };
            if completed.contains(spec.id.0) {
                q.account(&spec);
            } else {
                q.retry.insert(spec.id, (spec, 0));
            }
        }
        q.done_below = completed.below;
        q.done_above = completed.above.iter().copied().collect();
        Ok(q)
    }

    /// In rounds mode, releases round 1 once pass one is merged: the adaptive decisions
    /// that follow may then rely on every pixel's first sample.
    fn maybe_start_rounds(&mut self) {
        let pixels = u64::from(self.width) * u64::from(self.height);
        let pass_one_over = self.cut_all && self.retry.is_empty() && self.pass_one_pixels_done == pixels;
        if let Some(r) = self.rounds.as_mut() {
            if pass_one_over && !r.started() {
                r.start();
            }
        }
    }

    /// The merged batches, for a checkpoint.
    pub fn completed(&self) -> Completed {
        Completed { below: self.done_below, above: self.done_above.iter().copied().collect() }
    }

    fn mark_done(&mut self, id: BatchId) {
        if id.0 == self.done_below {
            self.done_below += 1;
            while self.done_above.remove(&self.done_below) {
                self.done_below += 1;
            }
        } else {
            self.done_above.insert(id.0);
        }
    }

    fn account(&mut self, spec: &BatchSpec) {
        self.samples_done += spec.sample_count();
        if spec.pass == Pass::One {
            self.pass_one_pixels_done += spec.quads.len() as u64;
        }
    }

    /// The pass whose batches are being cut now.
    pub fn pass(&self) -> Pass {
        match &self.rounds {
            Some(r) if r.started() => Pass::Two,
            _ => self.pass,
        }
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
        self.cut_all
            && self.retry.is_empty()
            && self.leased.is_empty()
            && self.rounds.as_ref().is_none_or(|r| r.finished())
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
                if self.rounds.is_some() {
                    // Pass two comes in rounds over tiles, not off the walk.
                    self.cut_all = true;
                    self.pass_one_batches = Some(self.next_id + u64::from(!quads.is_empty()));
                } else if self.pass == Pass::One && self.spp > 1 {
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
            None => match self.cut() {
                Some(spec) => (spec, 1),
                None => (self.next_round()?, 1),
            },
        };
        let id = spec.id;
        self.leased.insert(id, Lease { spec, worker, attempt, since: now });
        self.leased.get(&id)
    }

    /// The next ready round of a tile, as a batch.
    fn next_round(&mut self) -> Option<BatchSpec> {
        let first = self.pass_one_batches?;
        let rounds = self.rounds.as_mut()?;
        let tiles = u64::from(rounds.tile_count());
        let (round, tile, quads, samples) = rounds.take()?;
        let id = BatchId(first + u64::from(round - 1) * tiles + u64::from(tile));
        Some(BatchSpec { id, pass: Pass::Two, quads, samples })
    }

    /// Whether every batch is cut and leased: the end of the last pass, where an idle
    /// worker has nothing to do but duplicate a straggler.
    pub fn all_leased(&self) -> bool {
        self.cut_all && self.retry.is_empty() && self.rounds.as_ref().is_none_or(|r| r.idle())
    }

    /// A speculative duplicate for `worker` of the oldest lease that has run for longer
    /// than `patience` times the mean batch time (at least `min_age`), held by another
    /// worker and not duplicated yet. Only at the end of the last pass: before that, idle
    /// workers have new batches. The first result of the two wins; the other is refused as
    /// a duplicate, so merging stays exactly-once.
    pub fn lease_speculative(
        &mut self,
        worker: WorkerId,
        now: Instant,
        patience: u32,
        min_age: Duration,
    ) -> Option<&Lease> {
        if !self.all_leased() {
            return None;
        }
        let wait = self.mean_batch_time.map_or(min_age, |m| (m * patience).max(min_age));
        let oldest = self
            .leased
            .values()
            .filter(|l| l.worker != worker && !self.spares.contains_key(&l.spec.id))
            .filter(|l| now.saturating_duration_since(l.since) >= wait)
            .min_by_key(|l| (l.since, l.spec.id))?;
        let spare = Lease { spec: oldest.spec.clone(), worker, attempt: oldest.attempt + 1, since: now };
        let id = spare.spec.id;
        self.spares.insert(id, spare);
        self.spares.get(&id)
    }

    /// Batches leased to `worker` now, speculative duplicates included.
    pub fn leased_by(&self, worker: WorkerId) -> usize {
        self.leased.values().chain(self.spares.values()).filter(|l| l.worker == worker).count()
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
    pub fn complete(&mut self, batch: BatchId, now: Instant) -> Result<BatchSpec, CompleteError> {
        let spare = self.spares.remove(&batch);
        let spec = match self.leased.remove(&batch) {
            Some(lease) => {
                // The time of whichever lease delivered first: the spare's, if it won.
                let since = spare.map_or(lease.since, |s| s.since.max(lease.since));
                let took = now.saturating_duration_since(since);
                self.mean_batch_time = Some(match self.mean_batch_time {
                    Some(m) => (m * 7 + took) / 8,
                    None => took,
                });
                lease.spec
            }
            None => match self.retry.remove(&batch) {
                Some((spec, _)) => spec,
                None => return Err(CompleteError::NotOutstanding { batch }),
            },
        };
        self.account(&spec);
        // In rounds, pass-two batches are known from the sample counts; only pass one's
        // ids need remembering.
        if self.round_of(spec.id).is_none() {
            self.mark_done(spec.id);
        }
        self.maybe_start_rounds();
        Ok(spec)
    }

    /// Takes back the lease of `batch` so that another worker gets it. If a speculative
    /// duplicate is out, that one becomes the lease instead.
    pub fn take_back(&mut self, batch: BatchId) -> bool {
        let Some(lease) = self.leased.remove(&batch) else { return false };
        match self.spares.remove(&batch) {
            Some(spare) => {
                self.leased.insert(batch, spare);
            }
            None => {
                self.retry.insert(batch, (lease.spec, lease.attempt));
            }
        }
        true
    }

    /// Takes back every lease held by `worker` (it left, or fell silent); returns them.
    pub fn take_back_worker(&mut self, worker: WorkerId) -> Vec<BatchId> {
        self.spares.retain(|_, l| l.worker != worker);
        let mut ids: Vec<BatchId> =
            self.leased.values().filter(|l| l.worker == worker).map(|l| l.spec.id).collect();
        ids.sort();
        for id in &ids {
            self.take_back(*id);
        }
        ids
    }

    /// Drops every outstanding lease and everything not yet cut (the job was cancelled).
    pub fn abandon(&mut self) {
        self.leased.clear();
        self.spares.clear();
        self.retry.clear();
        self.cut_all = true;
        if let Some(r) = self.rounds.as_mut() {
            r.abandon();
        }
    }
}

#[cfg(test)]
mod tests;
