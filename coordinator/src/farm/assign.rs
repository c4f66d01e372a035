//! Who renders what: leasing batches (and audits and repairs) to workers, merging their
//! results exactly once and only from the lease's holder, and batches that fail.

use std::time::Instant;

use tessera_description::ids::{BatchId, JobId, WorkerId};
use tessera_description::job::JobState;

use super::adaptive::converged;
use super::audit::{Answer, Audit, Verdict};
use super::MAX_BATCH_FAILURES;
use super::{Assignment, BatchResult, Farm, Job, ResultError, SPECULATE_MIN_AGE, SPECULATE_PATIENCE};
use crate::scheduler::{BatchSpec, CompleteError, Lease, LeaseToken};

/// A worker's report that it could not render a batch.
#[derive(Debug, Clone, Copy)]
pub struct BatchFailure<'a> {
    /// The job.
    pub job: JobId,
    /// The batch.
    pub batch: BatchId,
    /// The attempt number of the lease.
    pub attempt: u32,
    /// The lease's token as the worker sent it.
    pub lease: &'a [u8],
    /// The worker cannot take the job's scene at all (e.g. it exceeds its memory): the job
    /// is not sent to it again, and this does not count as the batch failing.
    pub scene_refused: bool,
    /// What went wrong, for messages.
    pub error: &'a str,
}

/// Which lease an answer belongs to.
enum Held {
    /// A batch of the job's queue.
    Queue(Lease),
    /// An audit's re-render (index in the job's audits).
    Audit(usize, Lease),
    /// A repair batch.
    Repair(Lease),
}

impl Held {
    fn lease(&self) -> &Lease {
        match self {
            Held::Queue(l) | Held::Audit(_, l) | Held::Repair(l) => l,
        }
    }
}

/// What a worker is given besides the queue's batches.
enum Extra {
    Repair,
    Audit,
}

impl Job {
    /// The lease `worker` holds on `batch` with `token`, whichever kind.
    fn held(&self, batch: BatchId, worker: WorkerId, token: &[u8]) -> Option<Held> {
        if let Some(l) = self.queue.held(batch, worker, token) {
            return Some(Held::Queue(l.clone()));
        }
        let audit = self.fence.audits.iter().enumerate().find_map(|(k, a)| {
            let l = a.lease.as_ref()?;
            let ok = l.token.matches(token);
            (ok && l.spec.id == batch && l.worker == worker).then(|| Held::Audit(k, l.clone()))
        });
        audit.or_else(|| self.fence.repairs.held(batch, worker, token).cloned().map(Held::Repair))
    }

    /// Gives a held lease back without its answer (malformed, or failed): the queue's goes
    /// to another worker, an audit is not asked of this identity again, a repair waits.
    fn give_back(&mut self, held: &Held, identity: &str) {
        let l = held.lease();
        match held {
            Held::Queue(_) => {
                self.queue.take_back_held(l.spec.id, l.worker, &l.token.0);
            }
            Held::Audit(k, _) => {
                let a = &mut self.fence.audits[*k];
                a.lease = None;
                a.declined.push(identity.to_owned());
            }
            Held::Repair(_) => {
                if let Some(l) = self.fence.repairs.finish(l.spec.id) {
                    self.fence.repairs.put_back(&l, self.framebuffer.width());
                }
            }
        }
    }

    /// A repair, else an audit `identity` may render, leased to `worker`.
    fn lease_extra(
        &mut self,
        worker: WorkerId,
        identity: &str,
        token: LeaseToken,
        now: Instant,
    ) -> Option<(Lease, Extra)> {
        let width = self.framebuffer.width();
        let frame_pixels = u64::from(width) * u64::from(self.queue.frame_height());
        if let Some(l) = self.fence.repairs.lease(worker, token, width, frame_pixels, now) {
            return Some((l, Extra::Repair));
        }
        let a = self.fence.audits.iter_mut().find(|a| a.open_to(identity))?;
        // The next attempt number, as a retry would have.
        let attempt = a.attempt + a.answers.len() as u32 + a.declined.len() as u32;
        let lease = Lease { spec: a.spec.clone(), worker, attempt, since: now, token };
        a.lease = Some(lease.clone());
        Some((lease, Extra::Audit))
    }

    /// Ends the job in failure: every lease released.
    pub(super) fn fail(&mut self, message: String, now: Instant) {
        self.abandon_all();
        self.state = JobState::Failed(message);
        self.finished = Some(now);
    }
}

/// Audits of one job that may wait, holding their sums, for a worker of another identity
/// to join; a lone worker's further audits are skipped.
const MAX_WAITING_AUDITS: usize = 256;

impl Farm {
    /// The next batch for `worker`: a repair or an audit it may render first, then from
    /// the first job in service order that has a new or taken-back batch; failing that, a
    /// speculative duplicate of a straggler at the end of a job, so that one slow or stuck
    /// worker does not hold the last of a job up. Jobs whose scene its identity refused
    /// are skipped; a quarantined worker gets nothing.
    pub fn assign(&mut self, worker: WorkerId, now: Instant) -> Option<Assignment> {
        let identity = self.workers.get(&worker)?.identity.clone();
        let renders_frames = self.workers.get(&worker)?.renders_frames;
        if self.standing.get(&identity).is_some_and(|s| s.quarantined.is_some()) {
            return None;
        }
        self.enforce_deadlines(now);
        let order: Vec<JobId> = self
            .service_order()
            .into_iter()
            .filter(|id| !self.jobs[id].fence.refused_by.contains(&identity))
            // Frames and AOV layers came in one release: a worker that does not announce
            // frames (`Hello.frames`) returns no AOV sums either, and gets neither kind of job.
            .filter(|id| {
                renders_frames
                    || (self.jobs[id].settings.frames.is_none() && self.jobs[id].aov.layout().is_empty())
            })
            .collect();
        let token = self.entropy.token();
        let extra = order.iter().find_map(|id| {
            let job = self.jobs.get_mut(id).expect("ordered ids exist");
            job.lease_extra(worker, &identity, token, now).map(|(l, kind)| (*id, l, kind))
        });
        let (id, batch, attempt, speculative) = match extra {
            Some((id, l, kind)) => {
                match kind {
                    Extra::Repair => self.counters.repair_batches += 1,
                    Extra::Audit => self.counters.audit_batches += 1,
                }
                (id, l.spec, l.attempt, false)
            }
            None => {
                let threads = self.render_threads();
                let batch_time = self.batch_time();
                let pick = |job: &mut Job, speculate: bool| {
                    let lease = if speculate {
                        job.queue.lease_speculative(worker, token, now, SPECULATE_PATIENCE, SPECULATE_MIN_AGE)
                    } else {
                        let pace = job.speeds.pace(worker, threads, batch_time);
                        job.queue.lease_paced(worker, token, now, pace)
                    };
                    lease.map(|l| (l.spec.clone(), l.attempt))
                };
                [false, true].into_iter().find_map(|speculate| {
                    order.iter().find_map(|id| {
                        let job = self.jobs.get_mut(id).expect("ordered ids exist");
                        pick(job, speculate).map(|(b, a)| (*id, b, a, speculate))
                    })
                })?
            }
        };
        let job = self.jobs.get_mut(&id).expect("picked above");
        let info = self.workers.get_mut(&worker).expect("checked above");
        if job.state == JobState::Queued {
            job.state = JobState::Running;
            job.started = Some(now);
            job.rate.push_back((now, job.queue.samples_done()));
        }
        let scene = info
            .scenes
            .insert(job.id)
            .then(|| (job.bundle.clone(), job.scene_hash.clone(), job.settings.clone()));
        let even_sums = job.framebuffer.has_even();
        let aovs = job.aov.layout().bits();
        let index = batch.quads.first().map_or(0, |q| q.y / job.queue.frame_height().max(1));
        let frame = job.settings.frames.map_or(0, |(first, _)| first + index);
        let frame_row = index * job.queue.frame_height();
        Some(Assignment {
            frame,
            frame_row,
            job: job.id,
            scene,
            scene_hash: job.scene_hash.clone(),
            batch,
            attempt,
            speculative,
            even_sums,
            aovs,
            token,
        })
    }

    /// Which lease of `job` an answer from `worker` belongs to. `Err` refuses it: a
    /// harmless duplicate (a released lease, a job gone), or a strike (no such lease).
    fn holder(
        &mut self,
        worker: WorkerId,
        job_id: JobId,
        batch: BatchId,
        token: &[u8],
    ) -> Result<(String, Held), ResultError> {
        let info = self.workers.get(&worker).ok_or(ResultError::NotConnected)?;
        let identity = info.identity.clone();
        let sent = info.scenes.contains(&job_id);
        let forged = |why: &str| ResultError::Forged { job: job_id, batch, why: why.to_owned() };
        let Some(job) = self.jobs.get(&job_id) else {
            if job_id.0 > self.next_job || job_id.0 == 0 {
                self.strike(worker, "an answer for a job that never existed");
                return Err(forged("no such job ever existed"));
            }
            return Err(ResultError::UnknownJob(job_id));
        };
        if !sent {
            self.strike(worker, "an answer for a job whose scene it was never sent");
            return Err(forged("its scene was never sent to this worker"));
        }
        if let Some(h) = job.held(batch, worker, token) {
            return Ok((identity, h));
        }
        if job.fence.was_released(batch, worker, token) {
            return Err(CompleteError::NotOutstanding { batch }.into());
        }
        self.strike(worker, "an answer without a lease of its batch with that token");
        Err(forged("this worker holds no lease of the batch with that token"))
    }

    /// Merges a batch's result, exactly once, and only from the worker holding the lease
    /// with its token, at its attempt number. The one merge path: the even-sample sums
    /// ride along when the job keeps them. A result for an audit is compared instead; a
    /// repair's merges into the pixels it reset.
    pub fn complete(
        &mut self,
        worker: WorkerId,
        r: &BatchResult<'_>,
        now: Instant,
    ) -> Result<(), ResultError> {
        let (job_id, batch) = (r.job, r.batch);
        let (identity, held) = match self.holder(worker, job_id, batch, r.lease) {
            Err(e @ ResultError::Duplicate(_)) => {
                self.lease_counters.duplicates += 1;
                return Err(e);
            }
            other => other?,
        };
        let job = self.jobs.get_mut(&job_id).expect("holder checked it");
        let spec = held.lease().spec.clone();
        let samples = spec.samples.end - spec.samples.start;
        // Check everything before accepting the batch, so that a malformed result neither
        // merges nor marks the batch done.
        let invalid = if r.attempt != held.lease().attempt {
            Some(format!("attempt {} for a lease of attempt {}", r.attempt, held.lease().attempt))
        } else if r.nonfinite > spec.sample_count() {
            Some(format!("{} non-finite samples in a batch of {}", r.nonfinite, spec.sample_count()))
        } else {
            None
        };
        // AOV sums are checked like the radiance sums: a lying worker's layers never merge.
        let invalid =
            invalid.or_else(|| job.aov.check(&spec.quads, samples, r.aov).err().map(|e| e.to_string()));
        let error = match invalid {
            Some(why) => Some(ResultError::Invalid { job: job_id, batch, why }),
            None => job
                .framebuffer
                .check(&spec.quads, samples, r.sums, r.even)
                .err()
                .map(|source| ResultError::Malformed { job: job_id, batch, source }),
        };
        if let Some(e) = error {
            job.give_back(&held, &identity);
            self.strike(worker, &e.to_string());
            self.settle(now);
            return Err(e);
        }
        match held {
            Held::Queue(lease) => {
                let others = job.queue.leases_of(batch).into_iter().filter(|l| l.token != lease.token);
                job.fence.release_all(others.collect::<Vec<_>>());
                job.queue.complete(batch, now)?;
                job.framebuffer.merge(&spec.quads, samples, r.sums, r.even).expect("sums were checked above");
                job.aov.merge(&spec.quads, samples, r.aov).expect("AOV sums were checked above");
                if let Some((round, tile)) = job.queue.round_of(batch) {
                    // The tile's next round: every pixel, or those still above the noise
                    // target (decided on merged samples only, so the same whatever the
                    // arrival order).
                    let next = job.settings.adaptive().map(|adaptive| {
                        spec.quads
                            .iter()
                            .copied()
                            .filter(|q| !converged(&job.framebuffer, *q, Some(adaptive)))
                            .collect()
                    });
                    job.queue.schedule_round(tile, round + 1, next);
                }
                job.after_merge(r.nonfinite, now);
                let turnaround = now.saturating_duration_since(lease.since);
                job.speeds.book(worker, spec.sample_count(), r.render, turnaround);
                self.lease_counters.samples_merged += spec.sample_count();
                self.delivered(worker, &identity, job_id, &spec, lease.attempt, r);
                self.book_rate(worker, spec.sample_count(), now);
            }
            Held::Repair(lease) => {
                job.fence.repairs.finish(batch);
                let turnaround = now.saturating_duration_since(lease.since);
                job.speeds.book(worker, spec.sample_count(), r.render, turnaround);
                job.framebuffer.merge(&spec.quads, samples, r.sums, r.even).expect("sums were checked above");
                job.aov.merge(&spec.quads, samples, r.aov).expect("AOV sums were checked above");
                self.lease_counters.samples_merged += spec.sample_count();
                self.delivered(worker, &identity, job_id, &spec, lease.attempt, r);
                self.book_rate(worker, spec.sample_count(), now);
            }
            Held::Audit(k, _) => {
                let answer = Answer::new(&identity, r.sums, r.even, &job.framebuffer).with_aov(r.aov);
                let audit = &mut job.fence.audits[k];
                audit.lease = None;
                let first_check = audit.answers.len() == 1;
                match audit.answer(answer) {
                    Verdict::Agreed => {
                        job.fence.audits.remove(k);
                        self.counters.audits_passed += 1;
                    }
                    Verdict::Undecided => {
                        if first_check {
                            self.counters.audits_mismatched += 1;
                        }
                    }
                    Verdict::Liars(liars) => {
                        if first_check {
                            self.counters.audits_mismatched += 1;
                        }
                        self.counters.audits_decided += 1;
                        let a: Audit = job.fence.audits.remove(k);
                        for liar in liars {
                            let detail = format!(
                                "its sums for {job_id} {} (samples {:?} of {} pixels) differ from two other workers'",
                                a.spec.id,
                                a.spec.samples,
                                a.spec.quads.len()
                            );
                            self.catch_liar(&liar, detail);
                        }
                    }
                }
            }
        }
        self.settle(now);
        Ok(())
    }

    /// Books `samples` merged from `worker` at `now`, for its rate.
    fn book_rate(&mut self, worker: WorkerId, samples: u64, now: Instant) {
        if let Some(w) = self.workers.get_mut(&worker) {
            w.book(samples, now);
        }
    }

    /// Books a merged delivery: the identity's pixels, its count, and perhaps an audit of
    /// it (chosen now, after delivery, so the worker could not know).
    fn delivered(
        &mut self,
        worker: WorkerId,
        identity: &str,
        job_id: JobId,
        spec: &BatchSpec,
        attempt: u32,
        r: &BatchResult<'_>,
    ) {
        if let Some(w) = self.workers.get_mut(&worker) {
            w.batches_done += 1;
        }
        // With no other identity to render it yet, an audit waits for one (a farm's first
        // worker is often alone for a moment, and a liar that joins first must not pass
        // unchecked), holding the sums, up to `MAX_WAITING_AUDITS` per job; beyond that it
        // is skipped and counted. At the job's end, `settle` skips what no one can render.
        let waiting = self.jobs.get(&job_id).map_or(0, |j| j.fence.audits.len());
        let standing = self.standing.entry(identity.to_owned()).or_default();
        let rate = self.audit.rate(standing.delivered);
        standing.delivered += 1;
        let chosen = rate > 0.0 && self.entropy.chance(rate);
        // Asked only of the batches chosen, without listing identities: this runs for every
        // merge, and listing (cloning and sorting every worker's name) cost more than the
        // merge itself with 256 workers (`tessera bench farm`).
        let audit = chosen && (waiting < MAX_WAITING_AUDITS || self.able_other_than(job_id, identity));
        if chosen && !audit {
            self.counters.audits_skipped += 1;
        }
        let Some(job) = self.jobs.get_mut(&job_id) else { return };
        let width = u64::from(job.framebuffer.width());
        let set = job.fence.delivered.entry(identity.to_owned()).or_default();
        for q in &spec.quads {
            set.insert(u64::from(q.y) * width + u64::from(q.x));
        }
        if audit && !job.is_over() {
            let answer = Answer::new(identity, r.sums, r.even, &job.framebuffer).with_aov(r.aov);
            job.fence.audits.push(Audit {
                spec: spec.clone(),
                attempt,
                answers: vec![answer],
                declined: Vec::new(),
                lease: None,
            });
            self.counters.audits += 1;
        }
    }

    /// `identity` was caught lying: quarantined, its answers in other audits void, and
    /// every pixel it delivered in a running job reset and rendered again by others.
    fn catch_liar(&mut self, identity: &str, detail: String) {
        self.counters.liars += 1;
        self.quarantine(identity, format!("caught lying by an audit: {detail}"));
        let mut pixels = 0;
        for job in self.jobs.values_mut().filter(|j| !j.is_over()) {
            let mut released = Vec::new();
            job.fence.audits.retain_mut(|a| {
                if a.answers[0].identity == identity {
                    // Its delivery is repaired below: nothing left to audit.
                    released.extend(a.lease.take());
                    return false;
                }
                a.answers.retain(|x| x.identity != identity);
                true
            });
            job.fence.release_all(released);
            if let Some(set) = job.fence.delivered.remove(identity) {
                let (n, recalled) = job.fence.repairs.reset(&set, &mut job.framebuffer, &job.queue);
                let width = u64::from(job.framebuffer.width());
                for i in set.iter() {
                    job.aov.reset((i % width) as u32, (i / width) as u32);
                }
                job.fence.release_all(recalled);
                pixels += n;
            }
        }
        self.counters.repaired_pixels += pixels;
    }

    /// A worker could not render a batch. Counts only from the lease's holder with its
    /// token (anything else is a strike). The batch is rendered elsewhere; it fails its
    /// job only once it failed on `MAX_BATCH_FAILURES` distinct identities, or on every
    /// identity connected that many times each (a farm of one worker still ends). A scene
    /// refusal does not count: that identity is not sent the job again, and the job fails
    /// only when every connected worker refused it.
    pub fn fail_batch(
        &mut self,
        worker: WorkerId,
        f: &BatchFailure<'_>,
        now: Instant,
    ) -> Result<(), ResultError> {
        let (job_id, batch) = (f.job, f.batch);
        let (identity, held) = match self.holder(worker, job_id, batch, f.lease) {
            Err(ResultError::Duplicate(_) | ResultError::UnknownJob(_)) => return Ok(()),
            other => other?,
        };
        let job = self.jobs.get_mut(&job_id).expect("holder checked it");
        job.give_back(&held, &identity);
        if f.attempt != held.lease().attempt {
            let why =
                format!("a failure of attempt {} for a lease of attempt {}", f.attempt, held.lease().attempt);
            self.strike(worker, &why);
            self.settle(now);
            return Err(ResultError::Invalid { job: job_id, batch, why });
        }
        if f.scene_refused {
            job.fence.refused_by.insert(identity.clone());
            // It will render none of this job: the rest of its leases here go to others.
            let rest = job.queue.leases_of_worker(worker);
            job.queue.take_back_worker(worker, false);
            job.fence.release_all(rest);
            let width = job.framebuffer.width();
            let repairs = job.fence.repairs.take_back_worker(worker, width);
            job.fence.release_all(repairs);
            if self.able_identities(job_id).is_empty() {
                let job = self.jobs.get_mut(&job_id).expect("still there");
                let names = job.fence.refused_by.iter().cloned().collect::<Vec<_>>().join(", ");
                job.fence.refused_by.clear();
                job.fail(
                    format!("every connected worker refused its scene ({names}); the last said: {}", f.error),
                    now,
                );
            }
        } else if matches!(held, Held::Queue(_)) {
            let counts = job.fence.failures.entry(batch).or_default();
            *counts.entry(identity).or_default() += 1;
            let distinct = counts.len() as u32;
            let counts = counts.clone();
            let able = self.able_identities(job_id);
            let everywhere = !able.is_empty()
                && able.iter().all(|i| counts.get(i).is_some_and(|&n| n >= MAX_BATCH_FAILURES));
            if distinct >= MAX_BATCH_FAILURES || everywhere {
                let who = counts.iter().map(|(i, n)| format!("{i} ×{n}")).collect::<Vec<_>>().join(", ");
                let job = self.jobs.get_mut(&job_id).expect("still there");
                let times: u32 = counts.values().sum();
                job.fail(
                    format!(
                        "{batch} failed {times} times on {distinct} workers ({who}); last error: {}",
                        f.error
                    ),
                    now,
                );
            }
        }
        self.settle(now);
        Ok(())
    }

    /// Ends the jobs that are complete: every batch merged, no repair left, and their
    /// audits resolved. Once nothing else holds a job open, an audit that no connected
    /// worker of another identity can render is skipped (counted) at once, and one not
    /// answered within the straggler patience (`SPECULATE_PATIENCE` mean batch times, at
    /// least `SPECULATE_MIN_AGE`: its only possible auditor may be frozen) is skipped then;
    /// a mismatch waits for a third identity to decide. Called after every answer and by
    /// the reaper (through `expire_silent`) every second.
    pub(super) fn settle(&mut self, now: Instant) {
        let ready: Vec<JobId> =
            self.jobs.values().filter(|j| !j.is_over() && j.queue.is_finished()).map(|j| j.id).collect();
        for id in ready {
            let able = self.able_identities(id);
            let job = self.jobs.get_mut(&id).expect("listed above");
            if job.fence.repairs.is_idle() {
                let since = *job.audits_since.get_or_insert(now);
                let patience = job
                    .queue
                    .mean_batch_time()
                    .map_or(SPECULATE_MIN_AGE, |m| (m * SPECULATE_PATIENCE).max(SPECULATE_MIN_AGE));
                let waited = now.saturating_duration_since(since) >= patience;
                let before = job.fence.audits.len();
                let mut released = Vec::new();
                job.fence.audits.retain_mut(|a| {
                    let keep = a.answers.len() > 1
                        || (!waited && (a.lease.is_some() || able.iter().any(|i| a.open_to(i))));
                    if !keep {
                        released.extend(a.lease.take());
                    }
                    keep
                });
                self.counters.audits_skipped += (before - job.fence.audits.len()) as u64;
                job.fence.release_all(released);
            }
            job.finish_if_done(now);
        }
    }
}
