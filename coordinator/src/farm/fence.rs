//! A job's share of fencing and auditing: tokens released without an answer, failures by
//! identity, identities that refused its scene, the pixels each identity delivered, the
//! audits under way and the repairs.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use tessera_description::ids::{BatchId, WorkerId};

use super::audit::Audit;
use super::repair::{PixelSet, Repairs};
use crate::scheduler::{Lease, LeaseToken};

/// See the module doc.
#[derive(Debug, Default)]
pub(super) struct JobFence {
    /// Leases that ended without their holder's answer (a speculative duplicate won, the
    /// job ended, a repair was recalled): an answer with one is a harmless duplicate, not
    /// a strike. A job holds few (at most its leases when it ends, plus lost races).
    pub(super) released: HashMap<BatchId, Vec<(WorkerId, LeaseToken)>>,
    /// Per batch, how often each identity failed it.
    pub(super) failures: HashMap<BatchId, BTreeMap<String, u32>>,
    /// Identities whose workers refused the scene (not sent this job again).
    pub(super) refused_by: BTreeSet<String>,
    /// Per identity, the pixels it delivered samples for (merged batches and repairs):
    /// what is reset and rendered again if it turns out to lie.
    pub(super) delivered: BTreeMap<String, PixelSet>,
    pub(super) audits: Vec<Audit>,
    pub(super) repairs: Repairs,
}

impl JobFence {
    /// Keeps the tokens of `leases` as released.
    pub(super) fn release_all(&mut self, leases: impl IntoIterator<Item = Lease>) {
        for l in leases {
            self.released.entry(l.spec.id).or_default().push((l.worker, l.token));
        }
    }

    /// Whether `worker` held a lease of `batch` with `token` that was released.
    pub(super) fn was_released(&self, batch: BatchId, worker: WorkerId, token: &[u8]) -> bool {
        self.released.get(&batch).is_some_and(|v| {
            v.iter().fold(false, |found, (w, t)| {
                let ok = t.matches(token);
                found | (ok && *w == worker)
            })
        })
    }

    /// Whether audits and repairs are all resolved.
    pub(super) fn is_idle(&self) -> bool {
        self.audits.is_empty() && self.repairs.is_idle()
    }

    /// Ends everything (the job is over): leases released.
    pub(super) fn abandon(&mut self) {
        let repairs = self.repairs.abandon();
        self.release_all(repairs);
        let audits: Vec<Lease> = self.audits.drain(..).filter_map(|a| a.lease).collect();
        self.release_all(audits);
        // The record of deliveries is needed only while the job can still be repaired.
        self.delivered.clear();
    }
}
