//! Each worker's measured speed on a job, which sizes the pass-two batches cut for it: a
//! fast worker gets batches that take as long on its threads as a slow worker's smaller
//! ones (the farm's batch time, `PASS_TWO_BATCH_TIME` unless set), so neither the round
//! trips of a fast tracer nor the tail of a slow machine's last batch cost the farm its
//! speed.
//!
//! Speed is samples per second on one render thread (a worker renders one batch per
//! thread), measured per job because scenes differ a hundredfold in a sample's cost.

use std::collections::HashMap;
use std::time::Duration;

use tessera_description::ids::WorkerId;

use crate::scheduler::Pace;

/// The weight the past keeps at each new batch: the last ~4 batches dominate, so a
/// worker whose machine got busy is re-measured within a second.
const KEEP: f64 = 0.75;

/// How much faster than its turnaround (lease to result, at the coordinator) a worker may
/// claim to have rendered a batch. A worker renders one batch per thread and is leased
/// `CREDIT_PER_THREAD` (2) per thread, so a batch honestly waits for at most about one
/// other; a worker that lies about its render time can inflate its measured speed, and
/// with it its batch size, by at most this factor (and batches stay within
/// `PASS_TWO_MAX_PIXELS`).
const MOST_CLAIMED_SPEEDUP: u32 = 4;

/// Decayed sums of samples rendered and the time they took, per worker: their ratio is the
/// worker's speed, each batch weighted by its size.
#[derive(Debug, Default)]
pub(super) struct Speeds {
    by_worker: HashMap<WorkerId, (f64, f64)>,
}

impl Speeds {
    /// Books a merged batch of `samples` that `worker` says took `render` on one thread,
    /// `turnaround` after its lease (`render` zero: it did not say, and the turnaround
    /// counts, which undercounts its speed).
    pub(super) fn book(&mut self, worker: WorkerId, samples: u64, render: Duration, turnaround: Duration) {
        let took = if render.is_zero() {
            turnaround
        } else {
            render.clamp(turnaround / MOST_CLAIMED_SPEEDUP, turnaround)
        };
        if took.is_zero() || samples == 0 {
            return;
        }
        let (s, t) = self.by_worker.entry(worker).or_insert((0.0, 0.0));
        *s = *s * KEEP + samples as f64;
        *t = *t * KEEP + took.as_secs_f64();
    }

    /// Samples per second on one thread, once measured.
    pub(super) fn speed(&self, worker: WorkerId) -> Option<f64> {
        let &(s, t) = self.by_worker.get(&worker)?;
        (t > 0.0).then(|| s / t)
    }

    /// The pace of pass-two batches cut for `worker` while the farm has `threads` render
    /// threads: what it renders on one thread in `batch_time`.
    pub(super) fn pace(&self, worker: WorkerId, threads: u32, batch_time: Duration) -> Pace {
        // Rounded, not truncated: a speed measured as exactly 10⁶ a second comes out of the
        // decayed sums a few ulps either side, and must not cut one pixel fewer on one side.
        let samples = self.speed(worker).map(|v| (v * batch_time.as_secs_f64()).round().max(1.0) as u64);
        Pace { samples, threads }
    }

    /// Forgets a worker that left.
    pub(super) fn forget(&mut self, worker: WorkerId) {
        self.by_worker.remove(&worker);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: WorkerId = WorkerId(1);

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn a_worker_s_speed_is_its_samples_over_its_render_time() {
        let mut s = Speeds::default();
        assert_eq!(s.pace(W, 2, ms(100)), Pace { samples: None, threads: 2 });
        s.book(W, 10_000, ms(10), ms(25));
        assert_eq!(s.speed(W), Some(1e6));
        // 100 ms of one thread at a million samples a second; a farm set to 20 ms batches
        // cuts a fifth.
        assert_eq!(s.pace(W, 2, ms(100)).samples, Some(100_000));
        assert_eq!(s.pace(W, 2, ms(20)).samples, Some(20_000));
        // A slower batch pulls the speed down, weighted by its size.
        s.book(W, 10_000, ms(40), ms(60));
        let v = s.speed(W).unwrap();
        assert!(v < 1e6 && v > 10_000.0 / 0.040, "{v}");
        s.forget(W);
        assert_eq!(s.speed(W), None);
    }

    /// A worker whose every batch takes exactly a microsecond a sample gets exactly the
    /// batch time's worth, whatever rounding its decayed sums carry.
    #[test]
    fn an_exact_speed_paces_exactly() {
        let mut s = Speeds::default();
        for n in 1..=40u64 {
            // Batches of n + 1 samples (the eighth's sums come out at 99 999.999… a
            // second when truncated).
            let took = Duration::from_micros(n + 1);
            s.book(W, n + 1, took, took);
            assert_eq!(s.pace(W, 1, ms(100)).samples, Some(100_000), "after batch {n}");
        }
    }

    #[test]
    fn an_unreported_render_time_counts_the_turnaround() {
        let mut s = Speeds::default();
        s.book(W, 5_000, Duration::ZERO, ms(50));
        assert_eq!(s.speed(W), Some(100_000.0));
    }

    /// A worker that claims to render in no time gains at most `MOST_CLAIMED_SPEEDUP`
    /// over what the coordinator saw; one that claims more than its turnaround gets the
    /// turnaround.
    #[test]
    fn claimed_render_times_are_bounded_by_the_turnaround() {
        let mut s = Speeds::default();
        s.book(W, 4_000, Duration::from_nanos(1), ms(40));
        assert_eq!(s.speed(W), Some(400_000.0));
        let mut s = Speeds::default();
        s.book(W, 4_000, Duration::from_secs(3600), ms(40));
        assert_eq!(s.speed(W), Some(100_000.0));
    }

    #[test]
    fn empty_or_instant_batches_are_not_booked() {
        let mut s = Speeds::default();
        s.book(W, 0, ms(5), ms(5));
        s.book(W, 100, Duration::ZERO, Duration::ZERO);
        assert_eq!(s.speed(W), None);
    }
}
