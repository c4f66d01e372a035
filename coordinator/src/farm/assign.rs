//! Who renders what: leasing batches to workers, merging their results exactly once, and
//! batches that fail.

use std::time::Instant;

use tessera_description::ids::{BatchId, JobId, WorkerId};
use tessera_description::job::JobState;

use super::adaptive::converged;
use super::MAX_BATCH_FAILURES;
use super::{Assignment, BatchResult, Farm, Job, ResultError, SPECULATE_MIN_AGE, SPECULATE_PATIENCE};
use crate::scheduler::CompleteError;

impl Farm {
    /// The next batch for `worker`: from the first job in service order that has a new or
    /// taken-back batch; failing that, a speculative duplicate of a straggler at the end
    /// of a job, so that one slow or stuck worker does not hold the last of a job up.
    pub fn assign(&mut self, worker: WorkerId, now: Instant) -> Option<Assignment> {
        if !self.workers.contains_key(&worker) {
            return None;
        }
        self.enforce_deadlines(now);
        let order = self.service_order();
        let pick = |job: &mut Job, speculate: bool| {
            let lease = if speculate {
                job.queue.lease_speculative(worker, now, SPECULATE_PATIENCE, SPECULATE_MIN_AGE)
            } else {
                job.queue.lease_next(worker, now)
            };
            lease.map(|l| (l.spec.clone(), l.attempt))
        };
        let (id, batch, attempt, speculative) = [false, true].into_iter().find_map(|speculate| {
            order.iter().find_map(|id| {
                let job = self.jobs.get_mut(id).expect("ordered ids exist");
                pick(job, speculate).map(|(b, a)| (*id, b, a, speculate))
            })
        })?;
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
        Some(Assignment {
            job: job.id,
            scene,
            scene_hash: job.scene_hash.clone(),
            batch,
            attempt,
            speculative,
            even_sums,
        })
    }

    /// Merges a batch's result, exactly once. The one merge path: the even-sample sums
    /// ride along when the job keeps them.
    pub fn complete(
        &mut self,
        worker: WorkerId,
        r: &BatchResult<'_>,
        now: Instant,
    ) -> Result<(), ResultError> {
        let (job_id, batch) = (r.job, r.batch);
        let job = self.jobs.get_mut(&job_id).ok_or(ResultError::UnknownJob(job_id))?;
        if job.is_over() {
            return Err(CompleteError::NotOutstanding { batch }.into());
        }
        // Check the sums before accepting the batch, so that a malformed result neither
        // merges nor marks the batch done.
        let spec = job.queue.outstanding(batch).ok_or(CompleteError::NotOutstanding { batch })?.clone();
        let samples = spec.samples.end - spec.samples.start;
        if let Err(source) = job.framebuffer.check(&spec.quads, samples, r.sums, r.even) {
            job.queue.take_back(batch);
            return Err(ResultError::Malformed { job: job_id, batch, source });
        }
        job.queue.complete(batch, now)?;
        job.framebuffer.merge(&spec.quads, samples, r.sums, r.even).expect("sums were checked above");
        if let Some((round, tile)) = job.queue.round_of(batch) {
            // The tile's next round: every pixel, or those still above the noise target
            // (decided on merged samples only, so the same whatever the arrival order).
            let next = job.settings.noise.map(|target| {
                spec.quads
                    .iter()
                    .copied()
                    .filter(|q| !converged(&job.framebuffer, *q, Some(target)))
                    .collect()
            });
            job.queue.schedule_round(tile, round + 1, next);
        }
        job.after_merge(r.nonfinite, now);
        if let Some(w) = self.workers.get_mut(&worker) {
            w.batches_done += 1;
        }
        Ok(())
    }

    /// A worker could not render a batch: retry elsewhere, or fail the job if the batch
    /// keeps failing.
    pub fn fail_batch(&mut self, job_id: JobId, batch: BatchId, error: &str, now: Instant) {
        let Some(job) = self.jobs.get_mut(&job_id) else { return };
        if job.is_over() || !job.queue.take_back(batch) {
            return;
        }
        let n = job.failures.entry(batch).or_default();
        *n += 1;
        if *n >= MAX_BATCH_FAILURES {
            job.queue.abandon();
            job.state = JobState::Failed(format!("{batch} failed {n} times; last error: {error}"));
            job.finished = Some(now);
        }
    }
}
