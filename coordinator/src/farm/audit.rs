//! Auditing workers bit for bit. A sample is a pure function of (scene, seed, pixel,
//! index) and sums are integers, so an honest worker reproduces another's batch exactly:
//! a delivered batch chosen at random (after delivery, from the farm's CSPRNG, so the
//! worker cannot know at render time) is rendered again by a worker of another identity
//! and the sums compared byte for byte. On a mismatch a third identity decides; whoever
//! disagrees with two identities that agree is a liar.

use tessera_film::Framebuffer;

use crate::scheduler::{BatchSpec, Lease};

/// How often delivered batches are audited.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AuditPolicy {
    /// The share of a worker's batches rendered again elsewhere, in [0, 1].
    pub fraction: f64,
    /// A worker's first batches (per identity) on probation...
    pub probation_batches: u64,
    /// ...are audited at this rate instead: a worker that lies from the start is caught
    /// within a few batches (`tessera bench audit` measures it), while an honest one
    /// costs this rate only for its first batches.
    pub probation_fraction: f64,
}

/// 3 % of batches: a worker that lies in every batch survives at most ~100 batches at
/// the 95th percentile after probation, at 3 % more rendering (`docs/security/workers.md`).
pub const DEFAULT_AUDIT_FRACTION: f64 = 0.03;
/// Batches on probation per identity.
pub const PROBATION_BATCHES: u64 = 20;
/// The rate on probation: 25 % catches an always-lying worker within its first 20
/// batches 99.7 % of the time (1 − 0.75^20).
pub const PROBATION_FRACTION: f64 = 0.25;

impl Default for AuditPolicy {
    fn default() -> Self {
        AuditPolicy {
            fraction: DEFAULT_AUDIT_FRACTION,
            probation_batches: PROBATION_BATCHES,
            probation_fraction: PROBATION_FRACTION,
        }
    }
}

impl AuditPolicy {
    /// No auditing at all.
    pub fn off() -> Self {
        AuditPolicy { fraction: 0.0, probation_batches: 0, probation_fraction: 0.0 }
    }

    /// The policy with `fraction`, refused unless it is a share in [0, 1].
    pub fn with_fraction(fraction: f64) -> Result<Self, String> {
        if !(0.0..=1.0).contains(&fraction) {
            return Err(format!("the audit fraction must be a share in [0, 1], e.g. 0.03, got {fraction}"));
        }
        let mut p = AuditPolicy { fraction, ..AuditPolicy::default() };
        // A farm that does not audit does not audit on probation either.
        if fraction == 0.0 {
            p.probation_fraction = 0.0;
        }
        Ok(p)
    }

    /// The rate for an identity that has delivered `delivered` batches so far.
    pub fn rate(&self, delivered: u64) -> f64 {
        if delivered < self.probation_batches {
            self.probation_fraction.max(self.fraction)
        } else {
            self.fraction
        }
    }
}

/// What one identity answered for an audited batch.
#[derive(Debug, Clone)]
pub(super) struct Answer {
    pub(super) identity: String,
    pub(super) sums: Vec<u64>,
    pub(super) even: Option<Vec<u64>>,
    /// The AOV layers' sums (empty for a job without layers): compared too, so that a
    /// worker lying only in its layers is caught like one lying in its radiance.
    pub(super) aov: Vec<u64>,
}

impl Answer {
    pub(super) fn new(identity: &str, sums: &[u64], even: Option<&[u64]>, fb: &Framebuffer) -> Answer {
        // Even sums are part of the answer only where the job keeps them.
        let even = even.filter(|_| fb.has_even()).map(<[u64]>::to_vec);
        Answer { identity: identity.to_owned(), sums: sums.to_vec(), even, aov: Vec::new() }
    }

    /// The answer with the AOV sums it delivered (checked against the job's layers).
    pub(super) fn with_aov(mut self, aov: &[u64]) -> Answer {
        self.aov = aov.to_vec();
        self
    }

    fn same(&self, other: &Answer) -> bool {
        self.sums == other.sums && self.even == other.even && self.aov == other.aov
    }
}

/// One batch being audited: its spec, the answers so far (the first is the one merged),
/// and the lease of whoever renders it again now.
#[derive(Debug, Clone)]
pub(super) struct Audit {
    pub(super) spec: BatchSpec,
    /// The attempt number the audited delivery had: the re-render goes out as the next
    /// one, like any retry, so that its worker cannot tell it is an audit.
    pub(super) attempt: u32,
    pub(super) answers: Vec<Answer>,
    /// Identities that failed the re-render (not asked again).
    pub(super) declined: Vec<String>,
    pub(super) lease: Option<Lease>,
}

/// What an answer settled.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum Verdict {
    /// Every answer so far agrees: the delivery was honest.
    Agreed,
    /// Two identities agree; these others answered differently.
    Liars(Vec<String>),
    /// Answers differ and no two identities agree yet: another identity must decide.
    Undecided,
}

impl Audit {
    /// Whether `identity` may render this audit: it has not answered or declined.
    pub(super) fn open_to(&self, identity: &str) -> bool {
        self.lease.is_none()
            && !self.answers.iter().any(|a| a.identity == identity)
            && !self.declined.iter().any(|d| d == identity)
    }

    /// Adds an answer and judges.
    pub(super) fn answer(&mut self, a: Answer) -> Verdict {
        self.answers.push(a);
        judge(&self.answers)
    }
}

/// The verdict on a set of answers from distinct identities.
pub(super) fn judge(answers: &[Answer]) -> Verdict {
    if answers.windows(2).all(|w| w[0].same(&w[1])) {
        return Verdict::Agreed;
    }
    // A value two identities agree on is the truth: samples are pure functions, and two
    // liars agreeing on the same wrong bits is collusion this cannot see (documented).
    for (i, a) in answers.iter().enumerate() {
        if answers[i + 1..].iter().any(|b| b.identity != a.identity && a.same(b)) {
            let liars = answers.iter().filter(|b| !a.same(b)).map(|b| b.identity.clone()).collect();
            return Verdict::Liars(liars);
        }
    }
    Verdict::Undecided
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ans(who: &str, s: u64) -> Answer {
        Answer { identity: who.into(), sums: vec![s, s, s], even: None, aov: Vec::new() }
    }

    #[test]
    fn the_identity_that_two_others_contradict_is_the_liar() {
        assert_eq!(judge(&[ans("a", 1), ans("b", 1)]), Verdict::Agreed);
        assert_eq!(judge(&[ans("a", 2), ans("b", 1)]), Verdict::Undecided);
        assert_eq!(judge(&[ans("a", 2), ans("b", 1), ans("c", 1)]), Verdict::Liars(vec!["a".into()]));
        assert_eq!(judge(&[ans("a", 1), ans("b", 2), ans("c", 1)]), Verdict::Liars(vec!["b".into()]));
        assert_eq!(judge(&[ans("a", 1), ans("b", 2), ans("c", 3)]), Verdict::Undecided);
        let mut even = ans("b", 1);
        even.even = Some(vec![9]);
        assert_eq!(judge(&[ans("a", 1), even]), Verdict::Undecided, "even sums are compared too");
    }

    #[test]
    fn fractions_outside_zero_to_one_are_refused() {
        assert!(AuditPolicy::with_fraction(1.5).is_err());
        assert!(AuditPolicy::with_fraction(f64::NAN).is_err());
        assert_eq!(AuditPolicy::with_fraction(0.0).unwrap().rate(0), 0.0);
        let p = AuditPolicy::with_fraction(0.03).unwrap();
        assert_eq!((p.rate(0), p.rate(PROBATION_BATCHES)), (PROBATION_FRACTION, 0.03));
    }
}
