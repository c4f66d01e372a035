//! `tessera bench audit`: what auditing catches and what it costs, on the pure farm (no
//! network, no rendering: fake sums that are pure functions of pixel and sample count, as
//! a renderer's are), with one lying worker among three honest ones served round robin.
//! For each kind of liar, over many seeded trials: how many batches it delivers before
//! it is quarantined (median, 95th percentile, worst); the extra batches auditing renders
//! with honest workers only, as a share of the job's; and whether the repaired image is
//! byte-identical to a clean render.

use std::time::Instant;

use anyhow::{bail, Result};
use tessera_coordinator::farm::{Assignment, AuditPolicy, Farm, JobSettings};
use tessera_description::bundle::Bundle;
use tessera_description::ids::{JobId, WorkerId};

const SCENE: &str = include_str!("../../tests/scenes/small.toml");

/// 64×64 at 16 385 spp: pass-two batches of 2 pixels (32 768 samples), so a job has
/// ~2 000 batches and a trial many jobs' worth of deliveries without costing time.
const JOB: (u32, u32, u32) = (64, 64, 16_385);

/// Deliveries after which a liar counts as never caught.
const CAP: u64 = 200_000;

/// How a liar changes its sums.
#[derive(Debug, Clone, Copy)]
enum Lie {
    /// Every batch, every sum doubled.
    Doubles,
    /// One batch in fifty (at random) all zero.
    ZeroesOneInFifty,
}

/// The sums an honest worker returns.
fn honest(a: &Assignment) -> Vec<u64> {
    let n = u64::from(a.batch.samples.end - a.batch.samples.start);
    a.batch
        .quads
        .iter()
        .flat_map(|q| [1, 2, 3].map(|c| u64::from((q.x * 7 + q.y * 3 + c) % 11) * n))
        .collect()
}

fn bundle() -> Bundle {
    Bundle { name: "small.toml".into(), text: SCENE.into(), assets: vec![], refused: vec![] }
}

fn seed(trial: u64, salt: u8) -> [u8; 32] {
    let mut s = [salt; 32];
    s[..8].copy_from_slice(&trial.to_le_bytes());
    s
}

/// A small, fast generator for the liar's own choices (not the farm's: those come from
/// its CSPRNG, which the liar cannot see).
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

/// A farm with the liar (worker 0) and three honest workers, and one job.
fn farm(trial: u64, policy: AuditPolicy) -> Result<(Farm, [WorkerId; 4], JobId)> {
    let mut f = Farm::with_seed(seed(trial, 7));
    f.set_audit_policy(policy);
    let now = Instant::now();
    let ws = ["liar", "a", "b", "c"].map(|n| f.add_worker(n.into(), 1, now));
    let (w, h, spp) = JOB;
    let job =
        f.submit(bundle(), JobSettings::sized(Some(spp), Some((w, h))), 0).map_err(anyhow::Error::msg)?;
    Ok((f, ws, job))
}

/// One round robin over the workers; `lie` says whether the liar lies on this delivery.
fn round(f: &mut Farm, ws: &[WorkerId; 4], mut lie: impl FnMut() -> Option<Lie>) {
    let now = Instant::now();
    for &w in ws {
        let Some(a) = f.assign(w, now) else { continue };
        let mut sums = honest(&a);
        if w == ws[0] {
            match lie() {
                Some(Lie::Doubles) => sums.iter_mut().for_each(|s| *s *= 2),
                Some(Lie::ZeroesOneInFifty) => sums.iter_mut().for_each(|s| *s = 0),
                None => {}
            }
        }
        let _ = f.complete(w, &a.answer(&sums, None), now);
    }
}

/// Batches the liar delivered (merged) until its quarantine; `None` if not caught by
/// `CAP`. New jobs are submitted as jobs end.
fn survival(trial: u64, policy: AuditPolicy, lie: Lie) -> Result<Option<u64>> {
    let (mut f, ws, mut job) = farm(trial, policy)?;
    let mut mine = SplitMix(trial ^ 0x5eed);
    loop {
        let delivered = f.standing("liar").map_or(0, |s| s.delivered);
        if f.quarantined(ws[0]).is_some() {
            return Ok(Some(delivered));
        }
        if delivered >= CAP {
            return Ok(None);
        }
        if f.job(job).is_some_and(|j| j.is_over()) {
            let (w, h, spp) = JOB;
            job = f
                .submit(bundle(), JobSettings::sized(Some(spp), Some((w, h))), 0)
                .map_err(anyhow::Error::msg)?;
        }
        round(&mut f, &ws, || match lie {
            Lie::Doubles => Some(Lie::Doubles),
            Lie::ZeroesOneInFifty => mine.next().is_multiple_of(50).then_some(Lie::ZeroesOneInFifty),
        });
    }
}

/// Runs one job to its end; returns the farm.
fn run_job(trial: u64, policy: AuditPolicy, lie: Option<Lie>) -> Result<(Farm, JobId)> {
    let (mut f, ws, job) = farm(trial, policy)?;
    let mut mine = SplitMix(trial ^ 0x5eed);
    for _ in 0..10_000_000 {
        if f.job(job).is_some_and(|j| j.is_over()) {
            return Ok((f, job));
        }
        round(&mut f, &ws, || match lie? {
            Lie::Doubles => Some(Lie::Doubles),
            Lie::ZeroesOneInFifty => mine.next().is_multiple_of(50).then_some(Lie::ZeroesOneInFifty),
        });
    }
    bail!("trial {trial}: the job did not end")
}

fn percentile(sorted: &[u64], p: f64) -> u64 {
    sorted[((sorted.len() as f64 * p).ceil() as usize).clamp(1, sorted.len()) - 1]
}

/// Runs the benchmark: `trials` seeded trials per liar at audit `fraction`.
pub fn run(trials: usize, fraction: f64) -> Result<()> {
    if trials == 0 {
        bail!("--trials must be at least 1");
    }
    let policy = AuditPolicy::with_fraction(fraction).map_err(anyhow::Error::msg)?;
    let no_probation = AuditPolicy { probation_batches: 0, probation_fraction: 0.0, ..policy };
    let (w, h, spp) = JOB;
    println!(
        "audit fraction {fraction}, probation: first {} batches of an identity at {}; {trials} trials each",
        policy.probation_batches, policy.probation_fraction
    );
    println!("one liar and three honest workers, round robin, jobs of {w}x{h} at {spp} spp");
    println!();
    println!(
        "{:<22} {:<13} {:>9} {:>9} {:>9} {:>9}",
        "liar", "probation", "median", "p95", "worst", "not caught"
    );
    for lie in [Lie::Doubles, Lie::ZeroesOneInFifty] {
        for (name, p) in [("yes", policy), ("no", no_probation)] {
            let t = Instant::now();
            let mut caught = Vec::new();
            let mut missed = 0;
            for trial in 0..trials as u64 {
                match survival(trial, p, lie)? {
                    Some(n) => caught.push(n),
                    None => missed += 1,
                }
            }
            caught.sort_unstable();
            let (med, p95, worst) = if caught.is_empty() {
                (0, 0, 0)
            } else {
                (percentile(&caught, 0.5), percentile(&caught, 0.95), *caught.last().expect("not empty"))
            };
            let label = match lie {
                Lie::Doubles => "doubles every batch",
                Lie::ZeroesOneInFifty => "zeroes 1 batch in 50",
            };
            println!(
                "{label:<22} {name:<13} {med:>9} {p95:>9} {worst:>9} {missed:>10}   ({:.1} s)",
                t.elapsed().as_secs_f64()
            );
        }
    }
    println!("(batches the liar delivered until its quarantine, the caught one included)");
    println!();

    // What auditing costs with honest workers only: re-renders per batch of the job.
    let mut extra = Vec::new();
    for trial in 0..trials.min(20) as u64 {
        let (f, job) = run_job(trial, policy, None)?;
        let j = f.job(job).expect("ran");
        let c = f.fence_counters();
        let delivered: u64 = f.workers().map(|(_, w)| w.batches_done).sum();
        if c.strikes != 0 || c.quarantines != 0 {
            bail!("trial {trial}: an honest worker was struck: {c:?}");
        }
        extra.push((
            c.audit_batches as f64 / delivered as f64,
            delivered,
            j.progress(Instant::now()).samples_done,
        ));
    }
    let mean = extra.iter().map(|e| e.0).sum::<f64>() / extra.len() as f64;
    println!(
        "cost with honest workers: {:.2} % extra batches rendered ({} trials, {} batches a job, probation included)",
        mean * 100.0,
        extra.len(),
        extra[0].1
    );

    // The repaired image against a clean one, byte for byte.
    let (clean, cj) = run_job(0, AuditPolicy::off(), None)?;
    let clean_bytes: Vec<u8> =
        clean.job(cj).expect("ran").framebuffer().resolve().iter().flat_map(|v| v.to_le_bytes()).collect();
    let runs = trials.min(20);
    for lie in [Lie::Doubles, Lie::ZeroesOneInFifty] {
        let (mut identical, mut caught) = (0, 0);
        for trial in 0..runs as u64 {
            let (f, job) = run_job(trial, policy, Some(lie))?;
            let bytes: Vec<u8> = f
                .job(job)
                .expect("ran")
                .framebuffer()
                .resolve()
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            identical += usize::from(bytes == clean_bytes);
            caught += usize::from(f.fence_counters().liars > 0);
        }
        println!(
            "one job with a liar that {}: caught within the job in {caught} of {runs}, final image byte-identical to a clean render in {identical} of {runs}",
            match lie {
                Lie::Doubles => "doubles every batch",
                Lie::ZeroesOneInFifty => "zeroes 1 batch in 50",
            }
        );
    }
    Ok(())
}
