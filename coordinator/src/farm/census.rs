//! The farm's figures at one moment, for metrics: jobs by state, the samples still to
//! render, workers by state, leases outstanding, and the event counts kept under the lock.
//! Taken under the farm's lock, so it costs O(jobs + workers + leases): no pixel is read.

use std::collections::HashSet;
use std::time::{Duration, Instant};

use tessera_description::ids::WorkerId;
use tessera_description::job::JobState;

use super::{Farm, FenceCounters};

/// A job that merged nothing for this long adds nothing to the farm's rate (its own
/// figure keeps the rate of its last merges).
const RATE_STALE: Duration = Duration::from_secs(5);

/// Counts of lease events since the coordinator started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LeaseCounters {
    /// Leases taken back from workers that fell silent (their batches go to others).
    pub taken_back_silent: u64,
    /// Leases taken back from workers that disconnected.
    pub taken_back_left: u64,
    /// Results refused as duplicates: the batch was merged already, or the lease was
    /// released (a speculative duplicate won, the job ended).
    pub duplicates: u64,
    /// Samples merged into framebuffers (queue batches and repairs; audit re-renders are
    /// compared, not merged).
    pub samples_merged: u64,
}

/// The farm's state at one moment.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Census {
    /// Jobs in each state, in the order of `JOB_STATES`.
    pub jobs: [u64; 6],
    /// Samples not merged yet of queued and running jobs: the work waiting for workers.
    pub samples_queued: u64,
    /// Samples merged per second, over the running jobs' recent windows.
    pub samples_per_second: f64,
    /// Connected workers holding at least one lease (connections of quarantined identities
    /// are not counted in any connected state).
    pub workers_busy: u64,
    /// Connected workers holding none, heard from lately.
    pub workers_idle: u64,
    /// Connected workers whose leases were taken back for silence, not heard from since.
    pub workers_silent: u64,
    /// Worker identities quarantined (refused; their connections were closed).
    pub identities_quarantined: u64,
    /// Batch leases out, first attempts and retries.
    pub leases_batch: u64,
    /// Speculative duplicates of stragglers' batches out.
    pub leases_speculative: u64,
    /// Audit re-renders out.
    pub leases_audit: u64,
    /// Repair batches out.
    pub leases_repair: u64,
    /// Strikes, quarantines, audits.
    pub fence: FenceCounters,
    /// Leases taken back, duplicates, samples merged.
    pub leases: LeaseCounters,
}

/// The job states as metrics name them, in the order of `Census::jobs`.
pub const JOB_STATES: [&str; 6] = ["queued", "running", "paused", "done", "cancelled", "failed"];

fn state_index(s: &JobState) -> usize {
    match s {
        JobState::Queued => 0,
        JobState::Running => 1,
        JobState::Paused => 2,
        JobState::Done => 3,
        JobState::Cancelled => 4,
        JobState::Failed(_) => 5,
    }
}

impl Farm {
    /// The farm's figures now (see `Census`). O(jobs + workers + leases).
    pub fn census(&self, now: Instant) -> Census {
        let mut c = Census { fence: self.counters, leases: self.lease_counters, ..Census::default() };
        let mut busy: HashSet<WorkerId> = HashSet::new();
        for j in self.jobs.values() {
            c.jobs[state_index(&j.state)] += 1;
            if matches!(j.state, JobState::Queued | JobState::Running) {
                c.samples_queued += j.queue.samples_total().saturating_sub(j.queue.samples_done());
            }
            let fresh = j.rate.back().is_some_and(|&(t, _)| now.saturating_duration_since(t) <= RATE_STALE);
            if j.state == JobState::Running && fresh {
                c.samples_per_second += j.progress(now).samples_per_second;
            }
            for (lease, speculative) in j.queue.outstanding_leases() {
                busy.insert(lease.worker);
                if speculative {
                    c.leases_speculative += 1;
                } else {
                    c.leases_batch += 1;
                }
            }
            for l in j.fence.audits.iter().filter_map(|a| a.lease.as_ref()) {
                busy.insert(l.worker);
                c.leases_audit += 1;
            }
            for l in &j.fence.repairs.leased {
                busy.insert(l.worker);
                c.leases_repair += 1;
            }
        }
        for (id, w) in &self.workers {
            // Its connections are being closed: counted with the quarantined identities.
            if self.standing.get(&w.identity).is_some_and(|s| s.quarantined.is_some()) {
                continue;
            }
            if busy.contains(id) {
                c.workers_busy += 1;
            } else if w.silent {
                c.workers_silent += 1;
            } else {
                c.workers_idle += 1;
            }
        }
        c.identities_quarantined = self.standing.values().filter(|s| s.quarantined.is_some()).count() as u64;
        c
    }
}
