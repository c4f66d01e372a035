//! Durability: the job store behind the service, state changes written before they are
//! acknowledged, the checkpointer, and jobs taken up again at start. (Submission, which
//! writes a job's row before it answers, is `submit.rs`.)

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tessera_description::ids::JobId;
use tessera_description::job::JobState;
use tonic::Status;
use tracing::{debug, info, warn};

use super::{lock, CoordinatorService, Timing};
use crate::farm::budget::Footprint;
use crate::farm::{Job, RestoreJobError, SubmitError};
use crate::persist::{JobStore, LoadedJob, StoreError};
use crate::store::Store;

/// The store behind a coordinator with a data directory, and what of each job it holds.
pub(super) struct Durable {
    pub(super) store: Mutex<Box<dyn JobStore>>,
    /// How often a job with new samples is checkpointed.
    interval: Duration,
    saved: Mutex<HashMap<JobId, Saved>>,
}

/// The last checkpoint written of a job.
#[derive(Debug, Clone)]
struct Saved {
    version: u64,
    state: JobState,
    pass_one_complete: bool,
    at: Instant,
}

impl Saved {
    fn of(j: &Job, now: Instant) -> Self {
        Saved {
            version: j.framebuffer().version(),
            state: j.state.clone(),
            pass_one_complete: j.pass_one_complete(),
            at: now,
        }
    }
}

/// A job taken up again from a data directory.
#[derive(Debug, Clone)]
pub struct Resumed {
    /// The job.
    pub id: JobId,
    /// Its state.
    pub state: JobState,
    /// Samples kept from its checkpoint.
    pub samples_kept: u64,
    /// Samples in the job.
    pub samples_total: u64,
}

/// What opening a data directory found.
#[derive(Debug, Default)]
pub struct Recovery {
    /// Jobs taken up again, oldest first.
    pub resumed: Vec<Resumed>,
    /// Damage found and how it was handled; jobs that could not be taken up.
    pub problems: Vec<String>,
}

impl CoordinatorService {
    /// A coordinator keeping its jobs in `dir`, with every unfinished job found there taken
    /// up again from its newest good checkpoint. Checkpoints are written every `interval`
    /// while samples come in, at the end of pass one, and when a job ends.
    pub fn open(timing: Timing, dir: &Path, interval: Duration) -> Result<(Self, Recovery), StoreError> {
        Self::open_within(timing, dir, interval, super::default_budget())
    }

    /// As `open`, with a memory budget of `budget` bytes for the jobs (see
    /// `with_memory_budget`): a stored job that does not fit it is marked failed, with a
    /// message naming it, instead of being taken up.
    pub fn open_within(
        timing: Timing,
        dir: &Path,
        interval: Duration,
        budget: u64,
    ) -> Result<(Self, Recovery), StoreError> {
        let (store, loaded) = Store::open(dir)?;
        let recovery = Recovery { problems: loaded.problems, ..Recovery::default() };
        Ok(Self::with_store_within(timing, Box::new(store), loaded.jobs, interval, recovery, budget))
    }

    /// A coordinator writing through `store`, taking up `jobs` (what the store read back).
    pub fn with_store(
        timing: Timing,
        store: Box<dyn JobStore>,
        jobs: Vec<LoadedJob>,
        interval: Duration,
        recovery: Recovery,
    ) -> (Self, Recovery) {
        Self::with_store_within(timing, store, jobs, interval, recovery, super::default_budget())
    }

    /// As `with_store`, with a memory budget of `budget` bytes for the jobs.
    pub fn with_store_within(
        timing: Timing,
        mut store: Box<dyn JobStore>,
        jobs: Vec<LoadedJob>,
        interval: Duration,
        mut recovery: Recovery,
        budget: u64,
    ) -> (Self, Recovery) {
        let mut this = CoordinatorService::with_memory_budget(timing, budget);
        let mut saved = HashMap::new();
        let now = Instant::now();
        // Before the service is shared, so that no request waits for the scenes to parse.
        let mut taken_up = Vec::new();
        for job in jobs {
            let id = job.record.id;
            let record = job.record.clone();
            let mut reservation = None;
            let mut admit = |f: &Footprint| {
                // A second try (the job starting over) gives back the first one's
                // reservation before asking: held, it would count the job twice.
                reservation = None;
                reservation = Some(this.budget.admit(&id.to_string(), f)?);
                Ok(())
            };
            let restored = match Job::restore_within(job, now, &mut admit) {
                // A checkpoint that does not fit its job is not resumed from: the job
                // starts over, its last good state.
                Err(e @ (RestoreJobError::Mismatch { .. } | RestoreJobError::Batches(_))) => {
                    recovery.problems.push(format!("{id}: {e}; it restarts from the beginning"));
                    Job::restore_within(LoadedJob { record, checkpoint: None }, now, &mut admit)
                }
                other => other,
            };
            match restored {
                Ok(j) => taken_up.push((j, reservation)),
                // Over the budget (perhaps a smaller one than it was admitted with): failed
                // for good, so that it is not tried at every start, and the start goes on.
                Err(RestoreJobError::Scene(SubmitError::OverBudget(why))) => {
                    let state = JobState::Failed(format!("not taken up again at start: {why}"));
                    match store.set_state(id, &state) {
                        Ok(()) => recovery.problems.push(format!("{id} does not fit the memory budget, marked failed: {why}")),
                        Err(e) => recovery.problems.push(format!(
                            "{id} does not fit the memory budget ({why}), and marking it failed failed too: {e}"
                        )),
                    }
                }
                Err(e) => recovery.problems.push(format!("{id} cannot be taken up again: {e}")),
            }
        }
        {
            let mut farm = this.farm();
            farm.reserve_ids_through(store.max_job_id());
            for (j, reservation) in taken_up {
                let id = farm.insert_restored(j);
                if let Some(r) = reservation {
                    r.assign(id);
                }
                let j = farm.job(id).expect("just restored");
                let p = j.progress(now);
                saved.insert(id, Saved::of(j, now));
                recovery.resumed.push(Resumed {
                    id,
                    state: p.state,
                    samples_kept: p.samples_done,
                    samples_total: p.samples_total,
                });
            }
        }
        for r in &recovery.resumed {
            info!(id = %r.id, kept = r.samples_kept, total = r.samples_total, state = ?r.state, "job taken up from the data directory");
        }
        this.durable =
            Some(Arc::new(Durable { store: Mutex::new(store), interval, saved: Mutex::new(saved) }));
        (this, recovery)
    }

    /// Records a job's new state on disk (paused, resumed, cancelled).
    pub(super) async fn persist_state(&self, id: JobId) -> Result<(), Status> {
        let Some(durable) = self.durable.clone() else { return Ok(()) };
        let Some(state) = self.farm().job(id).map(|j| j.state.clone()) else { return Ok(()) };
        tokio::task::spawn_blocking(move || {
            lock(&durable.store).set_state(id, &state)?;
            if let Some(s) = lock(&durable.saved).get_mut(&id) {
                s.state = state;
            }
            Ok::<_, StoreError>(())
        })
        .await
        .map_err(|e| Status::internal(format!("writing the state failed: {e}")))?
        .map_err(|e| Status::unavailable(format!("the change is made but not on disk: {e}")))
    }

    /// Records a job's new priority in the store, if there is one.
    pub(super) async fn persist_priority(&self, id: JobId, priority: i32) -> Result<(), Status> {
        let Some(durable) = self.durable.clone() else { return Ok(()) };
        tokio::task::spawn_blocking(move || lock(&durable.store).set_priority(id, priority))
            .await
            .map_err(|e| Status::internal(format!("writing the priority failed: {e}")))?
            .map_err(|e| Status::unavailable(format!("the change is made but not on disk: {e}")))
    }

    /// Writes a checkpoint of every job that has new samples and is due: its interval has
    /// passed (since its last checkpoint, or since it started), it finished pass one, or it
    /// ended; with `all`, of every job with anything new (at shutdown). Returns how many
    /// were written.
    pub async fn checkpoint(&self, all: bool) -> Result<usize, StoreError> {
        let Some(durable) = self.durable.clone() else { return Ok(0) };
        let now = Instant::now();
        let due: Vec<JobId> = {
            let farm = self.farm();
            let saved = lock(&durable.saved);
            farm.jobs()
                .filter(|j| {
                    let last = saved.get(&j.id);
                    let changed = last.is_none_or(|s| s.version != j.framebuffer().version());
                    let ended = j.is_over() && last.is_none_or(|s| s.state != j.state);
                    // An interval after the last checkpoint, or after the job started: a
                    // first one at the checkpointer's first tick wrote a 4K image's whole
                    // framebuffer (232 MB) for a quarter second's work (docs/speed.md,
                    // twenty-second part).
                    let since = last.map(|s| s.at).or(j.started());
                    let pass_one_new = j.pass_one_complete() && !last.is_some_and(|s| s.pass_one_complete);
                    let due = all
                        || ended
                        || pass_one_new
                        || since.is_none_or(|t| now.saturating_duration_since(t) >= durable.interval);
                    (changed || ended) && due
                })
                .map(|j| j.id)
                .collect()
        };
        // One job at a time: a checkpoint is the size of its framebuffer, and memory stays
        // bounded by the largest job, not by all of them at once. The snapshot is taken
        // under the lock (copy-on-write, microseconds); the copy and the write are not.
        for &id in &due {
            let Some((snapshot, saved)) = self.farm().job(id).map(|j| (j.snapshot(now), Saved::of(j, now)))
            else {
                continue;
            };
            let (durable, metrics) = (durable.clone(), self.metrics.clone());
            tokio::task::spawn_blocking(move || {
                let started = Instant::now();
                let checkpoint = snapshot.checkpoint();
                let written = lock(&durable.store).save(&checkpoint, &saved.state);
                metrics.observe_checkpoint(started.elapsed(), written.is_ok());
                let generation = written?;
                debug!(job = %checkpoint.job, generation, samples = checkpoint.samples_done, took = ?started.elapsed(), "checkpoint written");
                lock(&durable.saved).insert(checkpoint.job, saved);
                Ok::<_, StoreError>(())
            })
            .await
            .map_err(|e| StoreError::Write { path: "checkpoint".into(), source: e.to_string().into() })??;
        }
        Ok(due.len())
    }

    /// Drops the oldest finished jobs beyond the `keep` newest from memory and the store,
    /// giving their memory back to the budget; returns them. With a store, a job goes only
    /// once its final state is on disk (its last checkpoint written), so that nothing writes
    /// to it after it is removed. `keep` is at least 1, so the newest job id stays stored
    /// and ids are never reused.
    pub async fn retire_finished(&self, keep: usize) -> Vec<JobId> {
        let durable = self.durable.clone();
        let over: Vec<JobId> = {
            let farm = self.farm();
            let saved = durable.as_ref().map(|d| lock(&d.saved));
            let finished: Vec<JobId> = farm.jobs().filter(|j| j.is_over()).map(|j| j.id).collect();
            let excess = finished.len().saturating_sub(keep.max(1));
            finished
                .into_iter()
                .take(excess)
                .filter(|id| saved.as_ref().is_none_or(|s| s.get(id).is_some_and(|s| s.state.is_over())))
                .collect()
        };
        if over.is_empty() {
            return over;
        }
        let this = self.clone();
        tokio::task::spawn_blocking(move || {
            let mut gone = Vec::new();
            for id in over {
                // The store first: a job that could not be removed from it stays in memory.
                if let Some(d) = &durable {
                    if let Err(e) = lock(&d.store).remove(id) {
                        warn!(%id, "a finished job could not be removed from the store: {e}");
                        continue;
                    }
                    lock(&d.saved).remove(&id);
                }
                this.farm().remove_job(id);
                this.budget.release(id);
                gone.push(id);
            }
            gone
        })
        .await
        .unwrap_or_default()
    }

    /// Checkpoints jobs as they fall due, until the service shuts down.
    pub fn spawn_checkpointer(&self) -> Option<tokio::task::JoinHandle<()>> {
        // A job falls due at most a quarter interval late.
        let tick = (self.durable.as_ref()?.interval / 4).min(Duration::from_millis(250));
        let this = self.clone();
        let mut stop = self.shutting_down();
        Some(tokio::spawn(async move {
            loop {
                tokio::select! {
                    _ = tokio::time::sleep(tick) => {}
                    _ = stop.changed() => return,
                }
                if let Err(e) = this.checkpoint(false).await {
                    // The farm goes on; the next tick tries again, and status shows the age.
                    warn!("checkpoint failed: {e}");
                }
            }
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::Checkpoint;
    use crate::persist::{JobRecord, MemoryStore};
    use crate::scheduler::Completed;
    use crate::service::SubmitFailure;
    use tessera_description::bundle::Bundle;
    use tessera_description::job::JobSettings;

    fn bundle() -> Bundle {
        Bundle {
            name: "small.toml".into(),
            text: include_str!("../../../tests/scenes/small.toml").into(),
            assets: vec![],
            refused: vec![],
        }
    }

    /// A checkpoint that does not fit its job (here: another spp) is reported and the job
    /// starts over, instead of being resumed from or dropped.
    #[test]
    fn a_checkpoint_that_does_not_fit_restarts_its_job() {
        let dir = tempfile::tempdir().unwrap();
        {
            let (mut store, _) = Store::open(dir.path()).unwrap();
            let settings = JobSettings::sized(Some(4), Some((8, 8)));
            let record = JobRecord {
                id: JobId(3),
                bundle: Arc::new(bundle()),
                settings,
                priority: 0,
                state: JobState::Running,
                owner: String::new(),
            };
            store.add_job(&record).unwrap();
            let wrong = Checkpoint {
                job: JobId(3),
                width: 8,
                height: 8,
                spp: 3,
                completed: Completed { below: 1, ..Completed::default() },
                nonfinite_samples: 0,
                samples_done: 16,
                sums: vec![[0; 3]; 64],
                counts: [vec![1; 16], vec![0; 48]].concat(),
                aov_layout: 0,
                aov: Vec::new(),
                renderer: tessera_description::RENDERER_VERSION.into(),
                even: vec![],
                spent: Duration::ZERO,
            };
            store.save(&wrong, &JobState::Running).unwrap();
        }
        // Within a budget that holds the job once but not twice: starting over gives back
        // the first try's reservation before asking again.
        let footprint = crate::farm::budget::Footprint {
            width: 8,
            height: 8,
            even_sums: false,
            bundle_bytes: tessera_description::Description::parse(&bundle()).unwrap().bundle_bytes,
            aovs: Default::default(),
        };
        let budget = footprint.bytes() * 3 / 2;
        let (service, recovery) =
            CoordinatorService::open_within(Timing::default(), dir.path(), Duration::from_secs(1), budget)
                .unwrap();
        assert!(
            recovery
                .problems
                .iter()
                .any(|p| p.contains("its checkpoint is") && p.contains("restarts from the beginning")),
            "{:?}",
            recovery.problems
        );
        assert_eq!(recovery.resumed.len(), 1);
        assert_eq!(recovery.resumed[0].samples_kept, 0);
        assert_eq!(service.progress(JobId(3)).unwrap().state, JobState::Queued);
        // Ids go on above the stored ones.
        assert!(service.farm().submit(bundle(), JobSettings::default(), 0).unwrap() > JobId(3));
    }

    /// The durability path through the store trait, with no database: a submitted job's
    /// record and checkpoint reach the store, and a service opened on what it holds takes
    /// the job up with the samples kept.
    #[tokio::test]
    async fn jobs_and_checkpoints_go_through_the_store_trait() {
        let store = Arc::new(Mutex::new(MemoryStore::new()));
        let (service, _) = CoordinatorService::with_store(
            Timing::default(),
            Box::new(SharedStore(store.clone())),
            vec![],
            Duration::from_secs(60),
            Recovery::default(),
        );
        let id = service.submit(bundle(), JobSettings::sized(Some(2), Some((8, 8))), 0).await.unwrap();
        let w = service.farm().add_worker("w".into(), 1, Instant::now());
        let a = service.farm().assign(w, Instant::now()).unwrap();
        let sums = vec![0; a.batch.quads.len() * 3];
        service.farm().complete(w, &a.answer(&sums, None), Instant::now()).unwrap();
        assert_eq!(service.checkpoint(true).await.unwrap(), 1);
        let loaded = lock(&store).load();
        assert_eq!(loaded.jobs.len(), 1);
        let (again, recovery) = CoordinatorService::with_store(
            Timing::default(),
            Box::new(MemoryStore::new()),
            loaded.jobs,
            Duration::from_secs(60),
            Recovery::default(),
        );
        assert_eq!(recovery.resumed[0].samples_kept, a.batch.sample_count());
        assert_eq!(again.progress(id).unwrap().samples_done, a.batch.sample_count());
    }

    /// A job's first checkpoint comes an interval after it started or when pass one is
    /// complete, whichever is first, not at the checkpointer's first tick; then one each
    /// interval, and one when it ends.
    #[tokio::test]
    async fn the_first_checkpoint_waits_an_interval_or_the_end_of_pass_one() {
        let run = |interval: Duration| async move {
            let store = Arc::new(Mutex::new(MemoryStore::new()));
            let (service, _) = CoordinatorService::with_store(
                Timing::default(),
                Box::new(SharedStore(store.clone())),
                vec![],
                interval,
                Recovery::default(),
            );
            let id = service.submit(bundle(), JobSettings::sized(Some(2), Some((8, 8))), 0).await.unwrap();
            let w = service.farm().add_worker("w".into(), 1, Instant::now());
            let step = move |service: &CoordinatorService| {
                let a = service.farm().assign(w, Instant::now()).unwrap();
                let sums = vec![0; a.batch.quads.len() * 3];
                service.farm().complete(w, &a.answer(&sums, None), Instant::now()).unwrap();
            };
            step(&service);
            (service, id, store, step)
        };

        // A long interval: nothing in pass one, one at its end, one at the job's end.
        let (service, id, store, step) = run(Duration::from_secs(3600)).await;
        assert_eq!(service.checkpoint(false).await.unwrap(), 0, "a first batch in is not due");
        while !service.farm().job(id).unwrap().pass_one_complete() {
            step(&service);
        }
        assert_eq!(service.checkpoint(false).await.unwrap(), 1, "pass one complete");
        assert_eq!(service.checkpoint(false).await.unwrap(), 0, "nothing new");
        while !service.farm().job(id).unwrap().is_over() {
            step(&service);
        }
        assert_eq!(service.checkpoint(false).await.unwrap(), 1, "the job ended");
        assert_eq!(lock(&store).load().jobs.len(), 1);

        // A short one: due once an interval has passed since the job started (that it is
        // not due before is the long interval's first check, which a loaded machine
        // cannot make late).
        let (service, _, _, _) = run(Duration::from_millis(50)).await;
        tokio::time::sleep(Duration::from_millis(60)).await;
        assert_eq!(service.checkpoint(false).await.unwrap(), 1, "an interval in");
    }

    /// A store shared by the services of a test, as a database file would be.
    struct SharedStore(Arc<Mutex<MemoryStore>>);
    impl JobStore for SharedStore {
        fn add_job(&mut self, job: &JobRecord) -> Result<(), StoreError> {
            lock(&self.0).add_job(job)
        }
        fn set_state(&mut self, job: JobId, state: &JobState) -> Result<(), StoreError> {
            lock(&self.0).set_state(job, state)
        }
        fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), StoreError> {
            lock(&self.0).set_priority(job, priority)
        }
        fn save(&mut self, c: &Checkpoint, state: &JobState) -> Result<i64, StoreError> {
            lock(&self.0).save(c, state)
        }
        fn max_job_id(&self) -> u64 {
            lock(&self.0).max_job_id()
        }
        fn remove(&mut self, job: JobId) -> Result<(), StoreError> {
            lock(&self.0).remove(job)
        }
    }

    fn shared(store: &Arc<Mutex<MemoryStore>>, budget: u64) -> CoordinatorService {
        let jobs = lock(store).load().jobs;
        let store = Box::new(SharedStore(store.clone()));
        let recovery = Recovery::default();
        let (service, recovery) = CoordinatorService::with_store_within(
            Timing::default(),
            store,
            jobs,
            Duration::from_secs(60),
            recovery,
            budget,
        );
        for p in &recovery.problems {
            eprintln!("{p}");
        }
        service
    }

    /// A stored job that does not fit a (smaller) budget at start is marked failed, with a
    /// message naming it, and the coordinator starts with the jobs that fit.
    #[tokio::test]
    async fn a_stored_job_over_the_budget_is_marked_failed_and_the_start_goes_on() {
        let store = Arc::new(Mutex::new(MemoryStore::new()));
        let service = shared(&store, 1 << 30);
        let small = service.submit(bundle(), JobSettings::sized(Some(2), Some((8, 8))), 0).await.unwrap();
        let big = service.submit(bundle(), JobSettings::sized(Some(2), Some((2000, 1000))), 0).await.unwrap();
        drop(service);
        let jobs = lock(&store).load().jobs;
        let loaded = jobs.len();
        let store_box = Box::new(SharedStore(store.clone()));
        let (service, recovery) = CoordinatorService::with_store_within(
            Timing::default(),
            store_box,
            jobs,
            Duration::from_secs(60),
            Recovery::default(),
            10_000_000,
        );
        assert_eq!(loaded, 2);
        assert_eq!(service.jobs().iter().map(|j| j.id).collect::<Vec<_>>(), vec![small]);
        assert_eq!(recovery.problems.len(), 1, "{:?}", recovery.problems);
        let p = &recovery.problems[0];
        assert!(
            p.starts_with(&format!("{big} does not fit the memory budget, marked failed: {big} needs 75 MB")),
            "{p}"
        );
        let stored = lock(&store).load().jobs;
        let state = &stored.iter().find(|j| j.record.id == big).unwrap().record.state;
        assert!(
            matches!(state, JobState::Failed(m) if m.starts_with("not taken up again at start: job 2 needs 75 MB")),
            "{state:?}"
        );
        // And a submission over what is left is refused, with nothing allocated.
        let e =
            service.submit(bundle(), JobSettings::sized(Some(2), Some((2000, 1000))), 0).await.unwrap_err();
        assert!(matches!(e, SubmitFailure::Invalid(SubmitError::OverBudget(_))), "{e}");
        assert!(
            e.to_string()
                .starts_with("\"small.toml\" needs 75 MB of coordinator memory (2000x1000 framebuffer 75 MB"),
            "{e}"
        );
        assert_eq!(service.jobs().len(), 1);
    }

    /// Finished jobs past the retention count leave memory and the store, oldest first,
    /// and give their memory back.
    #[tokio::test]
    async fn finished_jobs_past_the_retention_count_are_dropped_oldest_first() {
        let store = Arc::new(Mutex::new(MemoryStore::new()));
        let service = shared(&store, 1 << 30);
        let mut ids = Vec::new();
        for _ in 0..4 {
            let id = service.submit(bundle(), JobSettings::sized(Some(1), Some((8, 8))), 0).await.unwrap();
            service.farm().cancel(id, Instant::now());
            service.persist_state(id).await.unwrap();
            ids.push(id);
        }
        // The final states are on disk through checkpoints.
        service.checkpoint(true).await.unwrap();
        let held = service.memory().1;
        let gone = service.retire_finished(2).await;
        assert_eq!(gone, ids[..2]);
        assert_eq!(service.jobs().iter().map(|j| j.id).collect::<Vec<_>>(), ids[2..]);
        assert_eq!(lock(&store).load().jobs.len(), 2);
        assert_eq!(service.memory().1, held / 2);
    }
}
