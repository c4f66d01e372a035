//! Taking a stored job up again after a restart: from its newest good checkpoint, or from
//! the start.

use std::time::Instant;

use tessera_description::job::JobState;
use tessera_film::aov::AovLayers;
use tessera_film::{Framebuffer, Quad};

use super::adaptive::converged;
use super::{Farm, Job, RestoreJobError};
use crate::persist::LoadedJob;
use crate::scheduler::PassQueue;
use tessera_description::ids::JobId;

impl Farm {
    /// Takes up a stored job again: from its checkpoint if it has one, else from the start.
    /// Its id is kept, and later jobs get higher ones.
    pub fn restore(&mut self, stored: LoadedJob, now: Instant) -> Result<JobId, RestoreJobError> {
        Ok(self.insert_restored(Job::restore(stored, now)?))
    }

    /// Queues a job taken up again, under its own id; later jobs get higher ones.
    pub fn insert_restored(&mut self, job: Job) -> JobId {
        let id = job.id;
        self.next_job = self.next_job.max(id.0);
        self.jobs.insert(id, job);
        id
    }
}

impl Job {
    /// A stored job made ready to go on, from its checkpoint if it has one. Costly (the
    /// scene is read, the framebuffer rebuilt): done before the farm is touched.
    pub fn restore(stored: LoadedJob, now: Instant) -> Result<Job, RestoreJobError> {
        Job::restore_within(stored, now, &mut |_| Ok(()))
    }

    /// As `restore`, with `admit` asked about the job's memory before it is allocated.
    pub fn restore_within(
        stored: LoadedJob,
        now: Instant,
        admit: super::budget::Admit<'_>,
    ) -> Result<Job, RestoreJobError> {
        let LoadedJob { record, checkpoint } = stored;
        let id = record.id;
        let mut job = Job::prepare_within(id, record.bundle, record.settings, record.priority, admit)?;
        job.owner = record.owner;
        if let Some(c) = checkpoint {
            let (w, h) = (job.framebuffer.width(), job.framebuffer.height());
            if (c.width, c.height, c.spp) != (w, h, job.spp) {
                return Err(RestoreJobError::Mismatch {
                    expected: format!("{w}x{h}@{}", job.spp),
                    got: format!("{}x{}@{}", c.width, c.height, c.spp),
                });
            }
            if c.even.is_empty() == job.framebuffer.has_even() {
                return Err(RestoreJobError::Mismatch {
                    expected: job
                        .settings
                        .noise
                        .map_or("no noise target".into(), |n| format!("a noise target ({n})")),
                    got: "a checkpoint with other accumulators".into(),
                });
            }
            let fb = Framebuffer::from_accumulators(w, h, c.sums, c.counts, c.even)
                .expect("decode checked lengths");
            job.queue = if job.settings.in_rounds() {
                let target = job.settings.adaptive();
                let keep = |q: Quad| !converged(&fb, q, target);
                let decide: Option<&dyn Fn(Quad) -> bool> = if target.is_some() { Some(&keep) } else { None };
                PassQueue::restore_rounds(w, h, job.spp, &c.completed, &fb.accumulators().1, decide)?
            } else {
                let frames = job.settings.frame_count();
                PassQueue::restore_sequence(w, job.queue.frame_height(), frames, job.spp, &c.completed)?
            };
            // Another renderer's samples of the same indices differ: going on would mix
            // them into an image neither renders. A checkpoint that does not say (format
            // 3 and older) is another renderer's too: such checkpoints were written by
            // builds from before +images.2 to +images.3, and which of their samples a
            // later renderer keeps depends on the scene (glass and lenses, jobs in rounds,
            // Sobol's pattern, triangles) in ways no rule of the coordinator's can follow
            // without mistakes; starting over costs time, never the image. A job that
            // renders nothing more keeps its image whatever made it.
            let renderer = tessera_description::RENDERER_VERSION;
            let over = matches!(record.state, JobState::Done | JobState::Cancelled | JobState::Failed(_));
            if c.renderer != renderer && !over && !job.queue.is_finished() {
                let made_by = if c.renderer.is_empty() {
                    "a renderer that did not name itself (checkpoint format 3 or older)".to_owned()
                } else {
                    format!("renderer {}", c.renderer)
                };
                return Err(RestoreJobError::Mismatch {
                    expected: format!("rendered by renderer {renderer}"),
                    got: format!("from {made_by}, whose samples differ"),
                });
            }
            if job.queue.samples_done() != c.samples_done {
                return Err(RestoreJobError::Mismatch {
                    expected: format!("{} samples for its merged batches", job.queue.samples_done()),
                    got: format!("{} samples", c.samples_done),
                });
            }
            let layout = job.aov.layout();
            job.aov = AovLayers::from_sums(layout, w, h, c.aov)
                .filter(|_| c.aov_layout == layout.bits())
                .ok_or_else(|| RestoreJobError::Mismatch {
                    expected: format!("AOV layers {:?}", job.settings.aovs),
                    got: "a checkpoint with other AOV layers".into(),
                })?;
            job.framebuffer = fb;
            job.nonfinite_samples = c.nonfinite_samples;
            job.spent_before = c.spent;
        }
        job.state = match record.state {
            JobState::Cancelled | JobState::Failed(_) => {
                job.abandon_all();
                job.finished = Some(now);
                record.state
            }
            JobState::Paused => JobState::Paused,
            // A job recorded as done whose final checkpoint did not survive renders the rest.
            _ if job.queue.is_finished() => {
                job.finished = Some(now);
                JobState::Done
            }
            _ => JobState::Queued,
        };
        Ok(job)
    }
}
