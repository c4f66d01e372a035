//! The pure core of a job's scheduling: cutting the walk into batches, leasing them to
//! workers, taking them back, and accepting each batch's result exactly once. No I/O, no
//! tokio, no prost: the time comes in as an argument, so tests drive it with a fake clock.

mod batch;
mod cut;
pub mod rounds;

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::{Duration, Instant};

use tessera_description::ids::{BatchId, WorkerId};
use tessera_film::quadtree::Quad;

pub use batch::{BatchSpec, CompleteError, Completed, Lease, LeaseToken, Pass, RestoreError};
use cut::{Cut, FixedSpp, InRounds};

/// Pixels in the first pass-one batch: small, so that the first mosaic shows at once.
pub const PASS_ONE_FIRST: usize = 16;
/// Pixels in a pass-one batch once the sizes have doubled up from `PASS_ONE_FIRST`:
/// ~4 ms of tracing for a simple scene, large enough that per-batch overhead vanishes.
pub const PASS_ONE_MAX: usize = 2048;
/// Samples in a pass-two batch for a worker whose speed is not measured yet; the pixel
/// count follows from the spp.
pub const PASS_TWO_SAMPLES: u64 = 32_768;
/// The most pixels in a pass-two batch (bounds message sizes at low spp).
pub const PASS_TWO_MAX_PIXELS: usize = 8192;
/// The fewest samples the end of pass two shrinks batches to (~2 ms of one thread on a
/// simple scene): below that a batch is mostly its round trip.
pub const PASS_TWO_FLOOR_SAMPLES: u64 = 4096;
/// What one pass-two batch should take a worker's thread once its speed is measured:
/// long enough that a batch's round trip and merge are ~1 % of it, short enough that a
/// pass ends within a fraction of a second of its last batch and previews refine often.
pub const PASS_TWO_BATCH_TIME: Duration = Duration::from_millis(100);

/// What sizes a pass-two batch cut for a worker: its speed and the farm's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pace {
    /// Samples the worker renders on one thread in `PASS_TWO_BATCH_TIME`, once measured;
    /// `None`: `PASS_TWO_SAMPLES`.
    pub samples: Option<u64>,
    /// Render threads of the workers sharing the job (0: unknown), for shrinking the
    /// batches at the end of the pass so that they finish together.
    pub threads: u32,
}

/// The batches of one job: those not cut yet (the rest of the walk), those waiting to be
/// leased again, those leased, and how many are done.
#[derive(Debug)]
pub struct PassQueue {
    width: u32,
    height: u32,
    spp: u32,
    /// Where new batches come from: one type per mode of pass two.
    cut: Cut,
    next_id: u64,
    /// Batches whose lease was taken back, waiting to be leased again, oldest first.
    retry: BTreeMap<BatchId, (BatchSpec, u32)>,
    leased: HashMap<BatchId, Lease>,
    /// Speculative second leases of batches in `leased` (stragglers near the end): the
    /// first result of either wins.
    spares: HashMap<BatchId, Lease>,
    /// Leases taken back from silent workers: should such a worker wake up, its result
    /// still counts (it holds the token), until the batch is merged.
    late: HashMap<BatchId, Vec<Lease>>,
    /// Pixels (y · width + x) whose pass-two batch is merged, in the paper's two passes:
    /// with the count it says which samples a pixel holds (`merged_samples`), which a
    /// repair must render again. Empty for jobs in rounds (their samples are a prefix).
    pass_two_merged: Vec<u64>,
    /// Merged batches: all ids below `done_below`, and these above it.
    done_below: u64,
    done_above: BTreeSet<u64>,
    /// Mean time from lease to merge, for judging which leases are stragglers.
    mean_batch_time: Option<Duration>,
    samples_done: u64,
    pass_one_pixels_done: u64,
    /// One frame's height (a still's whole height): a sequence's frames are stacked.
    frame_height: u32,
    /// Per frame: pass-one pixels and samples merged.
    per_frame: Vec<(u64, u64)>,
}

impl PassQueue {
    /// The batches of a `width × height` image at `spp` samples per pixel.
    pub fn new(width: u32, height: u32, spp: u32) -> Self {
        Self::sequence(width, height, 1, spp)
    }

    /// The batches of `frames` frames of `width × height` stacked (frame k in rows
    /// `k · height ..`), in the paper's two passes: every frame's pass one before any
    /// frame's pass two.
    pub fn sequence(width: u32, height: u32, frames: u32, spp: u32) -> Self {
        let spp = spp.max(1);
        let cut = Cut::Fixed(FixedSpp::new(width, height, spp, frames));
        let mut q = Self::with_cut(width, height.saturating_mul(frames), spp, cut);
        q.frame_height = height;
        q.per_frame = vec![(0, 0); frames as usize];
        q
    }

    /// As `restore`, for a sequence made by `sequence`.
    pub fn restore_sequence(
        width: u32,
        height: u32,
        frames: u32,
        spp: u32,
        completed: &Completed,
    ) -> Result<Self, RestoreError> {
        Self::restore_with(PassQueue::sequence(width, height, frames, spp), completed)
    }

    /// Per frame (one for a still): pass-one pixels and samples merged.
    pub fn frames_done(&self) -> &[(u64, u64)] {
        &self.per_frame
    }

    /// One frame's height.
    pub fn frame_height(&self) -> u32 {
        self.frame_height
    }

    /// The batches of a job whose pass two runs in rounds over tiles (see `rounds.rs`).
    pub fn with_rounds(width: u32, height: u32, spp: u32) -> Self {
        let spp = spp.max(1);
        Self::with_cut(width, height, spp, Cut::Rounds(InRounds::new(width, height, spp)))
    }

    fn with_cut(width: u32, height: u32, spp: u32, cut: Cut) -> Self {
        PassQueue {
            width,
            height,
            spp,
            cut,
            next_id: 0,
            retry: BTreeMap::new(),
            leased: HashMap::new(),
            spares: HashMap::new(),
            late: HashMap::new(),
            pass_two_merged: Vec::new(),
            done_below: 0,
            done_above: BTreeSet::new(),
            mean_batch_time: None,
            samples_done: 0,
            pass_one_pixels_done: 0,
            frame_height: height,
            per_frame: vec![(0, 0)],
        }
    }

    /// The (round, tile) of a pass-two batch of a job in rounds.
    pub fn round_of(&self, batch: BatchId) -> Option<(u32, u32)> {
        self.cut.rounds()?.round_of(batch)
    }

    /// Schedules round `round` of tile `tile` for `active` pixels (`None`: all of the
    /// tile); an empty list or a round past the last closes the tile.
    pub fn schedule_round(&mut self, tile: u32, round: u32, active: Option<Vec<Quad>>) {
        if let Some(r) = self.cut.rounds_mut() {
            r.rounds.schedule(tile, round, active);
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
        if !(q.cut.cut_all() && q.retry.is_empty() && q.pass_one_pixels_done == pixels) {
            return Ok(q);
        }
        let spp = q.spp;
        let rounds = &mut q.cut.rounds_mut().expect("made with rounds").rounds;
        rounds.start_restored();
        let mut extra = 0u64;
        for t in 0..rounds.tile_count() {
            let tile = rounds.tile_pixels(t);
            let count = |p: &Quad| counts[(p.y * width + p.x) as usize];
            let most = tile.iter().map(count).max().unwrap_or(1);
            let round =
                rounds::round_reaching(most, spp).ok_or(RestoreError::Rounds { tile: t, count: most })?;
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
        if let Some(f) = q.cut.fixed_mut() {
            f.replay(&completed.sizes).map_err(|pixels| RestoreError::BatchSize { pixels })?;
        }
        let end = completed.end();
        while q.next_id < end {
            let Some(spec) = q.cut.cut(&mut q.next_id, Pace::default()) else {
                let id = completed.above.last().copied().unwrap_or(end - 1);
                return Err(RestoreError::NoSuchBatch { id, batches: q.next_id, width, height, spp: q.spp });
            };
            if completed.contains(spec.id.0) {
                q.account(&spec);
            } else {
                q.retry.insert(spec.id, (spec, 0));
            }
        }
        if let Some(f) = q.cut.fixed_mut() {
            // Sizes logged past the last merged batch were cut but not merged: the next
            // cuts are paced afresh.
            f.replay(&[]).expect("no sizes are valid");
        }
        q.done_below = completed.below;
        q.done_above = completed.above.iter().copied().collect();
        Ok(q)
    }

    /// In rounds mode, releases round 1 once pass one is merged: the adaptive decisions
    /// that follow may then rely on every pixel's first sample.
    fn maybe_start_rounds(&mut self) {
        let pixels = u64::from(self.width) * u64::from(self.height);
        let pass_one_over =
            self.cut.cut_all() && self.retry.is_empty() && self.pass_one_pixels_done == pixels;
        if let Some(r) = self.cut.rounds_mut() {
            if pass_one_over && !r.rounds.started() {
                r.rounds.start();
            }
        }
    }

    /// The merged batches and the pass-two sizes cut, for a checkpoint.
    pub fn completed(&self) -> Completed {
        Completed {
            below: self.done_below,
            above: self.done_above.iter().copied().collect(),
            sizes: self.cut.fixed().map_or_else(Vec::new, |f| f.log().to_vec()),
        }
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
        // A batch lies in one frame (`FixedSpp` cuts each frame's walk apart).
        let frame = spec.quads.first().map_or(0, |q| (q.y / self.frame_height.max(1)) as usize);
        if let Some(f) = self.per_frame.get_mut(frame) {
            f.1 += spec.sample_count();
            if spec.pass == Pass::One {
                f.0 += spec.quads.len() as u64;
            }
        }
        if spec.pass == Pass::One {
            self.pass_one_pixels_done += spec.quads.len() as u64;
        } else if self.cut.rounds().is_none() {
            let words = (u64::from(self.width) * u64::from(self.height)).div_ceil(64) as usize;
            self.pass_two_merged.resize(words, 0);
            for q in &spec.quads {
                let i = u64::from(q.y) * u64::from(self.width) + u64::from(q.x);
                self.pass_two_merged[(i / 64) as usize] |= 1 << (i % 64);
            }
        }
    }

    /// The sample indices pixel `(x, y)` holds when its framebuffer count is `count`: what
    /// a repair renders again after resetting the pixel. Jobs in rounds hold a prefix
    /// (pass one is merged before round 1, each round after the one before); in the two
    /// passes, pass two may be merged before pass one, which `pass_two_merged` tells.
    pub fn merged_samples(&self, x: u32, y: u32, count: u32) -> std::ops::Range<u32> {
        if self.cut.rounds().is_some() || count == 0 {
            return 0..count;
        }
        let i = u64::from(y) * u64::from(self.width) + u64::from(x);
        let two = self.pass_two_merged.get((i / 64) as usize).is_some_and(|w| w & (1 << (i % 64)) != 0);
        match (two, count == self.spp) {
            (true, false) => 1..self.spp,
            _ => 0..count,
        }
    }

    /// The pass whose batches are being cut now.
    pub fn pass(&self) -> Pass {
        self.cut.pass()
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

    /// The mean time from lease to merge so far, if a batch merged.
    pub fn mean_batch_time(&self) -> Option<Duration> {
        self.mean_batch_time
    }

    /// Batches leased right now.
    pub fn leased(&self) -> usize {
        self.leased.len()
    }

    /// Whether every batch has been merged.
    pub fn is_finished(&self) -> bool {
        self.cut.cut_all()
            && self.retry.is_empty()
            && self.leased.is_empty()
            && self.cut.rounds().is_none_or(|r| r.rounds.finished())
    }

    /// Leases the next batch to `worker`, a new one cut at the fixed sizes (`lease_paced`
    /// with no pace).
    pub fn lease_next(&mut self, worker: WorkerId, token: LeaseToken, now: Instant) -> Option<&Lease> {
        self.lease_paced(worker, token, now, Pace::default())
    }

    /// Leases the next batch to `worker`: a batch taken back from another worker first
    /// (oldest first), else a new one off the walk, of pass two's sized by `pace`.
    pub fn lease_paced(
        &mut self,
        worker: WorkerId,
        token: LeaseToken,
        now: Instant,
        pace: Pace,
    ) -> Option<&Lease> {
        let (spec, attempt) = match self.retry.pop_first() {
            Some((_, (spec, attempts))) => (spec, attempts + 1),
            None => match self.cut.cut(&mut self.next_id, pace) {
                Some(spec) => (spec, 1),
                None => (self.cut.rounds_mut()?.next_round()?, 1),
            },
        };
        let id = spec.id;
        self.leased.insert(id, Lease { spec, worker, attempt, since: now, token });
        self.leased.get(&id)
    }

    /// Whether every batch is cut and leased: the end of the last pass, where an idle
    /// worker has nothing to do but duplicate a straggler.
    pub fn all_leased(&self) -> bool {
        self.cut.cut_all() && self.retry.is_empty() && self.cut.rounds().is_none_or(|r| r.rounds.idle())
    }

    /// A speculative duplicate for `worker` of the oldest lease that has run for longer
    /// than `patience` times the mean batch time (at least `min_age`), held by another
    /// worker and not duplicated yet. Only at the end of the last pass: before that, idle
    /// workers have new batches. The first result of the two wins; the other is refused as
    /// a duplicate, so merging stays exactly-once.
    pub fn lease_speculative(
        &mut self,
        worker: WorkerId,
        token: LeaseToken,
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
        let spare =
            Lease { spec: oldest.spec.clone(), worker, attempt: oldest.attempt + 1, since: now, token };
        let id = spare.spec.id;
        self.spares.insert(id, spare);
        self.spares.get(&id)
    }

    /// Every lease out now, with whether it is a speculative duplicate (leases taken back
    /// from silent workers are not out: their batches wait for, or went to, others).
    pub fn outstanding_leases(&self) -> impl Iterator<Item = (&Lease, bool)> + '_ {
        self.leased.values().map(|l| (l, false)).chain(self.spares.values().map(|l| (l, true)))
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

    /// The lease of `batch` that `worker` holds with `token` (the lease, its speculative
    /// duplicate, or one taken back while the worker was silent), compared in constant
    /// time; `None` if it holds none.
    pub fn held(&self, batch: BatchId, worker: WorkerId, token: &[u8]) -> Option<&Lease> {
        let late = self.late.get(&batch).into_iter().flatten();
        self.leased.get(&batch).into_iter().chain(self.spares.get(&batch)).chain(late).find(|l| {
            // Every candidate compared, so the time does not say which one matched.
            let ok = l.token.matches(token);
            ok && l.worker == worker
        })
    }

    /// Every lease `worker` holds (leases, duplicates, late ones).
    pub fn leases_of_worker(&self, worker: WorkerId) -> Vec<Lease> {
        let late = self.late.values().flatten();
        self.leased
            .values()
            .chain(self.spares.values())
            .chain(late)
            .filter(|l| l.worker == worker)
            .cloned()
            .collect()
    }

    /// Every lease of `batch` (the lease, its duplicate, late ones), e.g. those about to be
    /// released by a merge.
    pub fn leases_of(&self, batch: BatchId) -> Vec<Lease> {
        let late = self.late.get(&batch).into_iter().flatten();
        self.leased.get(&batch).into_iter().chain(self.spares.get(&batch)).chain(late).cloned().collect()
    }

    /// Accepts the result of `batch` (from any attempt: all compute the same samples) and
    /// returns its spec for merging. A second result for the same batch is refused, which
    /// is what makes merging exactly-once.
    pub fn complete(&mut self, batch: BatchId, now: Instant) -> Result<BatchSpec, CompleteError> {
        let spare = self.spares.remove(&batch);
        self.late.remove(&batch);
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

    /// Takes back the one lease `worker` holds on `batch` with `token` (it failed it): a
    /// speculative duplicate is just dropped, the lease goes back to the queue (or its
    /// duplicate takes over). `false` if it holds no such lease.
    pub fn take_back_held(&mut self, batch: BatchId, worker: WorkerId, token: &[u8]) -> bool {
        if self.spares.get(&batch).is_some_and(|l| l.worker == worker && l.token.matches(token)) {
            self.spares.remove(&batch);
            return true;
        }
        if self.leased.get(&batch).is_some_and(|l| l.worker == worker && l.token.matches(token)) {
            return self.take_back(batch);
        }
        if let Some(late) = self.late.get_mut(&batch) {
            let before = late.len();
            late.retain(|l| !(l.worker == worker && l.token.matches(token)));
            return late.len() < before;
        }
        false
    }

    /// Takes back every lease held by `worker` (it left, or fell silent); returns them.
    /// With `keep_late` (silence), its tokens stay valid until the batches merge.
    pub fn take_back_worker(&mut self, worker: WorkerId, keep_late: bool) -> Vec<BatchId> {
        let mut late: Vec<Lease> = Vec::new();
        self.spares.retain(|_, l| {
            let mine = l.worker == worker;
            if mine {
                late.push(l.clone());
            }
            !mine
        });
        let mut ids: Vec<BatchId> =
            self.leased.values().filter(|l| l.worker == worker).map(|l| l.spec.id).collect();
        ids.sort();
        for id in &ids {
            late.extend(self.leased.get(id).cloned());
            self.take_back(*id);
        }
        if keep_late {
            for l in late {
                self.late.entry(l.spec.id).or_default().push(l);
            }
        } else {
            for v in self.late.values_mut() {
                v.retain(|l| l.worker != worker);
            }
            self.late.retain(|_, v| !v.is_empty());
        }
        ids
    }

    /// Drops every outstanding lease and everything not yet cut (the job was cancelled);
    /// returns the leases dropped, whose holders may still answer harmlessly.
    pub fn abandon(&mut self) -> Vec<Lease> {
        let mut dropped: Vec<Lease> = self.leased.drain().map(|(_, l)| l).collect();
        dropped.extend(self.spares.drain().map(|(_, l)| l));
        dropped.extend(self.late.drain().flat_map(|(_, v)| v));
        self.retry.clear();
        self.cut.abandon();
        dropped
    }
}

#[cfg(test)]
mod tests;
