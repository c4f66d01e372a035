//! Fencing: who a worker is (its identity, given by the service), its strikes, and
//! quarantine. A strike is a result or failure the sender had no lease for (a forged or
//! stale token, another worker's lease, a scene it was never sent), or one that is
//! malformed (sums out of range, an attempt number that is not its lease's, more
//! non-finite samples than the batch has). Honest workers get none: every way an honest
//! worker's lease ends without its answer (a speculative duplicate won, the job ended,
//! it fell silent) keeps its token as released, and an answer with it is a harmless
//! duplicate. A worker caught lying by an audit is quarantined at once.

use std::collections::BTreeMap;

use tessera_description::ids::{JobId, WorkerId};

use super::Farm;
use crate::scheduler::Lease;

/// Strikes after which an identity is quarantined. Three: an honest worker gets none (see
/// above), so this leaves room only for a bug of ours on a bad day, not for an attacker's
/// second and third try.
pub const STRIKES_TO_QUARANTINE: u32 = 3;

/// What the farm holds against an identity, across its connections.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Standing {
    /// Strikes so far.
    pub strikes: u32,
    /// Why it is quarantined, if it is.
    pub quarantined: Option<String>,
    /// Batches it delivered that merged (its probation is its first ones).
    pub delivered: u64,
}

/// Counts of fencing and auditing events since the coordinator started, for Status, logs
/// and metrics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FenceCounters {
    /// Strikes given.
    pub strikes: u64,
    /// Identities quarantined.
    pub quarantines: u64,
    /// Audits begun (batches chosen to be rendered again).
    pub audits: u64,
    /// Audit re-renders handed out (checks and decisions).
    pub audit_batches: u64,
    /// Audits whose answers agreed.
    pub audits_passed: u64,
    /// Audits with a mismatch.
    pub audits_mismatched: u64,
    /// Audits with a mismatch that a third identity settled (the liars named).
    pub audits_decided: u64,
    /// Audits dropped because no worker of another identity was left to render them
    /// while the job could otherwise end.
    pub audits_skipped: u64,
    /// Identities caught lying by an audit.
    pub liars: u64,
    /// Repair batches handed out.
    pub repair_batches: u64,
    /// Pixels reset for repair.
    pub repaired_pixels: u64,
}

impl Farm {
    /// The standing of `identity`.
    pub fn standing(&self, identity: &str) -> Option<&Standing> {
        self.standing.get(identity)
    }

    /// Every identity with strikes or a quarantine.
    pub fn standings(&self) -> &BTreeMap<String, Standing> {
        &self.standing
    }

    /// Why `worker` is quarantined, if it is (the service then disconnects it).
    pub fn quarantined(&self, worker: WorkerId) -> Option<&str> {
        let w = self.workers.get(&worker)?;
        self.standing.get(&w.identity)?.quarantined.as_deref()
    }

    /// The strikes against `worker`'s identity.
    pub fn strikes(&self, worker: WorkerId) -> u32 {
        self.workers.get(&worker).and_then(|w| self.standing.get(&w.identity)).map_or(0, |s| s.strikes)
    }

    /// The figures of fencing and auditing so far.
    pub fn fence_counters(&self) -> FenceCounters {
        self.counters
    }

    /// One strike against `worker`'s identity; quarantines it at `STRIKES_TO_QUARANTINE`.
    pub(super) fn strike(&mut self, worker: WorkerId, why: &str) {
        let Some(identity) = self.workers.get(&worker).map(|w| w.identity.clone()) else { return };
        self.counters.strikes += 1;
        let s = self.standing.entry(identity.clone()).or_default();
        s.strikes += 1;
        if s.strikes >= STRIKES_TO_QUARANTINE && s.quarantined.is_none() {
            let reason = format!("{} strikes, the last: {why}", s.strikes);
            self.quarantine(&identity, reason);
        }
    }

    /// Quarantines `identity`: refused from now on, every lease of its connections taken
    /// back (their tokens released, so nothing they send counts). The service disconnects
    /// the connections.
    pub fn quarantine(&mut self, identity: &str, reason: String) {
        let s = self.standing.entry(identity.to_owned()).or_default();
        if s.quarantined.is_some() {
            return;
        }
        s.quarantined = Some(reason);
        self.counters.quarantines += 1;
        let ids: Vec<WorkerId> =
            self.workers.iter().filter(|(_, w)| w.identity == identity).map(|(id, _)| *id).collect();
        for id in ids {
            self.take_back_all(id, false);
        }
    }

    /// Takes back every lease of `worker` in every job: batches, audits, repairs. With
    /// `keep_late` (silence) its batch tokens stay valid until the batches merge;
    /// otherwise they are released (a late answer is a harmless duplicate). Returns how
    /// many were taken back.
    pub(super) fn take_back_all(&mut self, worker: WorkerId, keep_late: bool) -> usize {
        let mut n = 0;
        for job in self.jobs.values_mut() {
            let before: Vec<Lease> = job.queue.leases_of_worker(worker);
            n += job.queue.take_back_worker(worker, keep_late).len();
            if !keep_late {
                job.fence.release_all(before);
            }
            let width = job.framebuffer.width();
            let repairs = job.fence.repairs.take_back_worker(worker, width);
            n += repairs.len();
            job.fence.release_all(repairs);
            for a in &mut job.fence.audits {
                if a.lease.as_ref().is_some_and(|l| l.worker == worker) {
                    let l = a.lease.take().expect("checked");
                    job.fence.released.entry(l.spec.id).or_default().push((l.worker, l.token));
                    n += 1;
                }
            }
        }
        n
    }

    /// The workers connected now that may render `job` (heard from, not quarantined, not
    /// refusing its scene).
    fn able_workers(&self, job: JobId) -> impl Iterator<Item = &str> + '_ {
        let refused = self.jobs.get(&job).map(|j| &j.fence.refused_by);
        self.workers
            .values()
            .filter(|w| !w.silent && self.standing.get(&w.identity).is_none_or(|s| s.quarantined.is_none()))
            .filter(move |w| refused.is_none_or(|r| !r.contains(&w.identity)))
            .map(|w| w.identity.as_str())
    }

    /// Whether a connected identity other than `identity` may render `job`.
    pub(super) fn able_other_than(&self, job: JobId, identity: &str) -> bool {
        self.able_workers(job).any(|i| i != identity)
    }

    /// The identities connected now that may render `job` (heard from, not quarantined,
    /// not refusing its scene).
    pub(super) fn able_identities(&self, job: JobId) -> Vec<String> {
        let mut v: Vec<String> = self.able_workers(job).map(str::to_owned).collect();
        v.sort();
        v.dedup();
        v
    }
}
