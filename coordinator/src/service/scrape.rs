//! The service's side of the metrics: the one timed merge path, and the scrape (a census
//! under the farm's lock, encoded outside it).

use std::time::Instant;

use tessera_description::ids::WorkerId;

use super::CoordinatorService;
use crate::farm::{BatchResult, ResultError};

impl CoordinatorService {
    /// Merges a worker's result (`Farm::complete`), timing the work done under the lock
    /// (not the wait for it) into `tessera_merge_seconds` when it is taken.
    pub(super) fn merge(
        &self,
        worker: WorkerId,
        r: &BatchResult<'_>,
        now: Instant,
    ) -> Result<(), ResultError> {
        let (done, took) = {
            let mut farm = self.farm();
            let started = Instant::now();
            let done = farm.complete(worker, r, now);
            (done, started.elapsed())
        };
        if done.is_ok() {
            self.metrics.observe_merge(took);
        }
        done
    }

    /// The coordinator's metrics in the Prometheus text format (`crate::metrics`,
    /// `docs/metrics.md`): the lock is held for one census, O(jobs + workers + leases).
    pub fn metrics_text(&self) -> String {
        let census = self.farm().census(Instant::now());
        self.metrics.exposition(census, self.viewers())
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use tessera_description::bundle::Bundle;
    use tessera_description::ids::JobId;
    use tessera_description::job::{JobSettings, JobState};

    use super::*;
    use crate::checkpoint::Checkpoint;
    use crate::persist::{JobRecord, JobStore, MemoryStore, StoreError};
    use crate::service::{Recovery, Timing};

    fn bundle() -> Bundle {
        let text = include_str!("../../../tests/scenes/small.toml");
        Bundle { name: "small.toml".into(), text: text.into(), assets: vec![], refused: vec![] }
    }

    /// The value of the sample `name` (with its labels, as written) in `text`.
    fn sample(text: &str, name: &str) -> Option<f64> {
        text.lines().find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
    }

    /// A result merged through the service's path is timed once; a late answer to a
    /// released lease (its job was cancelled) is counted as a duplicate, not timed.
    #[test]
    fn a_merged_result_is_timed_and_a_duplicate_counted() {
        let service = CoordinatorService::new(Timing::default());
        let job = service.farm().submit(bundle(), JobSettings::sized(Some(2), Some((8, 8))), 0).unwrap();
        let w = service.farm().add_worker("w".into(), 1, Instant::now());
        let a = service.farm().assign(w, Instant::now()).unwrap();
        let late = service.farm().assign(w, Instant::now()).unwrap();
        let text = service.metrics_text();
        assert_eq!(sample(&text, "tessera_merge_seconds_count"), Some(0.0), "{text}");
        assert_eq!(sample(&text, "tessera_leases_outstanding{kind=\"batch\"}"), Some(2.0), "{text}");
        assert_eq!(sample(&text, "tessera_workers{state=\"busy\"}"), Some(1.0), "{text}");
        let sums = vec![0; a.batch.quads.len() * 3];
        service.merge(w, &a.answer(&sums, None), Instant::now()).unwrap();
        let queued = 8 * 8 * 2 - a.batch.sample_count();
        assert_eq!(sample(&service.metrics_text(), "tessera_samples_queued"), Some(queued as f64));
        service.farm().cancel(job, Instant::now());
        let sums = vec![0; late.batch.quads.len() * 3];
        let refused = service.merge(w, &late.answer(&sums, None), Instant::now());
        assert!(matches!(refused, Err(ResultError::Duplicate(_))), "{refused:?}");
        let text = service.metrics_text();
        assert_eq!(sample(&text, "tessera_merge_seconds_count"), Some(1.0), "{text}");
        assert!(sample(&text, "tessera_merge_seconds_sum").is_some_and(|s| s > 0.0), "{text}");
        assert_eq!(sample(&text, "tessera_duplicate_results_total"), Some(1.0), "{text}");
        assert_eq!(sample(&text, "tessera_samples_merged_total"), Some(a.batch.sample_count() as f64));
        assert_eq!(sample(&text, "tessera_samples_queued"), Some(0.0), "a cancelled job waits for nothing");
        assert_eq!(sample(&text, "tessera_workers{state=\"idle\"}"), Some(1.0), "{text}");
        assert_eq!(sample(&text, "tessera_viewers"), Some(0.0), "{text}");
    }

    /// A store whose checkpoint writes fail (a full disk).
    struct Full(MemoryStore);
    impl JobStore for Full {
        fn add_job(&mut self, job: &JobRecord) -> Result<(), StoreError> {
            self.0.add_job(job)
        }
        fn set_state(&mut self, job: JobId, state: &JobState) -> Result<(), StoreError> {
            self.0.set_state(job, state)
        }
        fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), StoreError> {
            self.0.set_priority(job, priority)
        }
        fn save(&mut self, _: &Checkpoint, _: &JobState) -> Result<i64, StoreError> {
            Err(StoreError::NoSpace { path: "jobs.db".into() })
        }
        fn max_job_id(&self) -> u64 {
            self.0.max_job_id()
        }
        fn remove(&mut self, job: JobId) -> Result<(), StoreError> {
            self.0.remove(job)
        }
    }

    /// A checkpoint written is timed; one that fails is counted as a failure instead.
    #[tokio::test]
    async fn checkpoints_are_timed_and_failures_counted() {
        for (store, written, failed) in [
            (Box::new(MemoryStore::new()) as Box<dyn JobStore>, 1.0, 0.0),
            (Box::new(Full(MemoryStore::new())), 0.0, 1.0),
        ] {
            let (service, _) = CoordinatorService::with_store(
                Timing::default(),
                store,
                vec![],
                Duration::from_secs(60),
                Recovery::default(),
            );
            service.submit(bundle(), JobSettings::sized(Some(2), Some((8, 8))), 0).await.unwrap();
            let w = service.farm().add_worker("w".into(), 1, Instant::now());
            let a = service.farm().assign(w, Instant::now()).unwrap();
            let sums = vec![0; a.batch.quads.len() * 3];
            service.merge(w, &a.answer(&sums, None), Instant::now()).unwrap();
            let _ = service.checkpoint(true).await;
            let text = service.metrics_text();
            assert_eq!(sample(&text, "tessera_checkpoint_write_seconds_count"), Some(written), "{text}");
            assert_eq!(sample(&text, "tessera_checkpoint_failures_total"), Some(failed), "{text}");
        }
    }

    /// Viewers are counted from their slots, which are given back when a viewer leaves.
    #[test]
    fn viewers_are_counted_while_they_hold_a_slot() {
        let service = CoordinatorService::new(Timing::default());
        let slots: Vec<_> = (0..3).map(|_| service.viewer_slot(JobId(1)).unwrap()).collect();
        assert_eq!(sample(&service.metrics_text(), "tessera_viewers"), Some(3.0));
        drop(slots);
        assert_eq!(sample(&service.metrics_text(), "tessera_viewers"), Some(0.0));
    }
}

/// What a scrape costs on a large farm: `cargo test -p tessera-coordinator scrape_cost --
/// --ignored --nocapture` prints the time the census holds the lock and the
/// time of the whole text, for 64 jobs and 512 workers holding 4 leases each.
#[cfg(test)]
mod cost {
    use std::time::Instant;

    use tessera_description::bundle::Bundle;
    use tessera_description::job::JobSettings;

    use crate::service::{CoordinatorService, Timing};

    #[test]
    #[ignore = "a measurement, not a check"]
    fn scrape_cost() {
        let service = CoordinatorService::new(Timing::default());
        let text = include_str!("../../../tests/scenes/small.toml");
        let bundle = Bundle { name: "small.toml".into(), text: text.into(), assets: vec![], refused: vec![] };
        let now = Instant::now();
        {
            let mut farm = service.farm();
            for _ in 0..64 {
                farm.submit(bundle.clone(), JobSettings::sized(Some(16), Some((256, 256))), 0).unwrap();
            }
            for i in 0..512 {
                let w = farm.add_worker(format!("w{i}"), 4, now);
                for _ in 0..4 {
                    farm.assign(w, now).unwrap();
                }
            }
        }
        let rounds = 200;
        let (mut census, mut whole) = (0.0, 0.0);
        for _ in 0..rounds {
            let t = Instant::now();
            let c = service.farm().census(Instant::now());
            census += t.elapsed().as_secs_f64();
            assert_eq!(c.leases_batch, 2048);
            let t = Instant::now();
            let text = service.metrics_text();
            whole += t.elapsed().as_secs_f64();
            assert!(text.contains("tessera_workers{state=\"busy\"} 512"));
        }
        let n = f64::from(rounds);
        eprintln!(
            "64 jobs, 512 workers, 2048 leases: census under the lock {:.1} µs, whole scrape {:.1} µs (mean of {rounds})",
            census / n * 1e6,
            whole / n * 1e6
        );
    }
}
