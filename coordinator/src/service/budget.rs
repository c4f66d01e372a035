//! The coordinator's memory budget: every job in memory holds a reservation of its
//! framebuffer and bundle (`farm::budget::Footprint`), taken before the framebuffer is
//! allocated and given back when the job leaves memory. A job that does not fit is refused
//! with `RESOURCE_EXHAUSTED` and a message saying what it needs and what holds the rest;
//! nothing is allocated for it.
//!
//! Submissions are also admitted one or two at a time ([`SUBMITS_AT_ONCE`]): a submit's
//! bundle is buffered whole and its scene parsed (~7 bytes a byte of text) before its
//! footprint is known, so that transient is bounded by a count, not by the budget.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use tessera_description::ids::JobId;

use super::lock;
use crate::farm::budget::Footprint;
use crate::farm::SubmitError;

/// Submissions decoded and validated at once; more wait their turn.
pub const SUBMITS_AT_ONCE: usize = 2;

/// The default budget when none is given: half the machine's memory (the rest for the
/// process itself, submissions in flight and everything else on the machine), or 4 GiB
/// where the machine's memory cannot be read.
pub fn default_budget() -> u64 {
    tessera_description::machine::total_memory().map_or(4 << 30, |m| m / 2)
}

#[derive(Debug)]
struct Held {
    /// Reservations of jobs in memory.
    jobs: BTreeMap<JobId, u64>,
    /// Reservations of jobs admitted but not yet given their id.
    pending: u64,
}

/// The budget, shared by the service's clones.
#[derive(Debug, Clone)]
pub(super) struct MemoryBudget {
    limit: u64,
    held: Arc<Mutex<Held>>,
}

/// An admitted job's reservation: given back on drop unless it was given to a job.
#[derive(Debug)]
pub(super) struct Reservation {
    budget: MemoryBudget,
    bytes: u64,
}

impl MemoryBudget {
    pub(super) fn new(limit: u64) -> Self {
        MemoryBudget { limit, held: Arc::new(Mutex::new(Held { jobs: BTreeMap::new(), pending: 0 })) }
    }

    /// The budget in bytes.
    pub(super) fn limit(&self) -> u64 {
        self.limit
    }

    /// Bytes reserved now.
    pub(super) fn held(&self) -> u64 {
        let h = lock(&self.held);
        h.pending + h.jobs.values().sum::<u64>()
    }

    /// Reserves `job`'s footprint, or says why it does not fit. `what` names the job.
    pub(super) fn admit(&self, what: &str, job: &Footprint) -> Result<Reservation, SubmitError> {
        self.reserve(job.bytes(), |free, jobs| {
            format!(
                "{what} needs {} MB of coordinator memory ({}x{} framebuffer {} MB{}, bundle {} MB), but \
                 {} MB of the budget of {} MB are free (the rest held by {jobs} jobs and submissions \
                 in progress); a smaller image, or a coordinator with a larger --memory-budget",
                mb(job.bytes()),
                job.width,
                job.height,
                mb(job.framebuffer_bytes()),
                if job.even_sums { " with even sums" } else { "" },
                mb(job.bundle_bytes),
                mb(free),
                mb(self.limit),
            )
        })
    }

    /// Reserves what decoding and validating a submission of `message` bytes takes
    /// (`bytes`), for as long as the reservation lives.
    pub(super) fn admit_submission(&self, message: u64, bytes: u64) -> Result<Reservation, SubmitError> {
        self.reserve(bytes, |free, jobs| {
            format!(
                "a submission of {} MB needs up to {} MB of coordinator memory to decode and validate, but \
                 {} MB of the budget of {} MB are free (the rest held by {jobs} jobs and submissions in \
                 progress); try again later, or send a smaller bundle",
                mb(message),
                mb(bytes),
                mb(free),
                mb(self.limit),
            )
        })
    }

    fn reserve(
        &self,
        needs: u64,
        refusal: impl FnOnce(u64, usize) -> String,
    ) -> Result<Reservation, SubmitError> {
        let mut h = lock(&self.held);
        let held = h.pending + h.jobs.values().sum::<u64>();
        if held.saturating_add(needs) > self.limit {
            return Err(SubmitError::OverBudget(refusal(self.limit.saturating_sub(held), h.jobs.len())));
        }
        h.pending += needs;
        Ok(Reservation { budget: self.clone(), bytes: needs })
    }

    /// Gives back `job`'s reservation (it left memory).
    pub(super) fn release(&self, job: JobId) {
        lock(&self.held).jobs.remove(&job);
    }
}

impl Reservation {
    /// The reservation now belongs to `job`, until `MemoryBudget::release`.
    pub(super) fn assign(mut self, job: JobId) {
        let mut h = lock(&self.budget.held);
        h.pending -= self.bytes;
        h.jobs.insert(job, self.bytes);
        self.bytes = 0;
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        if self.bytes > 0 {
            lock(&self.budget.held).pending -= self.bytes;
        }
    }
}

/// Bytes in MB, rounded up, for messages.
fn mb(bytes: u64) -> u64 {
    bytes.div_ceil(1_000_000)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(width: u32, height: u32) -> Footprint {
        Footprint { width, height, even_sums: false, bundle_bytes: 1000, aovs: Default::default() }
    }

    #[test]
    fn jobs_are_admitted_while_they_fit_and_give_their_memory_back() {
        let budget = MemoryBudget::new(100_000_000);
        let a = budget.admit("job a", &job(1000, 1000)).unwrap();
        a.assign(JobId(1));
        let held = budget.held();
        assert!(held > 37_000_000 && held < 38_000_000, "{held}");
        let b = budget.admit("job b", &job(1000, 1000)).unwrap();
        let e = budget.admit("scene.toml", &job(1000, 1000)).unwrap_err().to_string();
        assert_eq!(
            e,
            "scene.toml needs 38 MB of coordinator memory (1000x1000 framebuffer 38 MB, bundle 1 MB), but 26 MB of \
             the budget of 100 MB are free (the rest held by 1 jobs and submissions in progress); a smaller image, \
             or a coordinator with a larger --memory-budget"
        );
        // A reservation never given to a job (its submission failed) comes back.
        drop(b);
        assert_eq!(budget.held(), held);
        budget.release(JobId(1));
        assert_eq!(budget.held(), 0);
        // The largest legal image is refused, not allocated.
        assert!(budget.admit("huge", &job(16384, 16384)).is_err());
    }

    #[test]
    fn the_description_s_estimate_matches_the_film() {
        use tessera_description::summary::{EVEN_SUMS_BYTES_PER_PIXEL, FRAMEBUFFER_BYTES_PER_PIXEL};
        let (w, h) = (4096u32, 2048u32);
        let px = u64::from(w) * u64::from(h);
        let plain = tessera_film::Framebuffer::bytes_for(w, h, false);
        assert_eq!(plain / px, FRAMEBUFFER_BYTES_PER_PIXEL);
        let even = tessera_film::Framebuffer::bytes_for(w, h, true);
        assert_eq!(even / px, FRAMEBUFFER_BYTES_PER_PIXEL + EVEN_SUMS_BYTES_PER_PIXEL);
    }
}
