//! `--ab`: a change timed against the code it replaces in one process, a chunk of work at
//! a time (`tessera_worker::ab`, the switch the change reads). Each chunk runs on both
//! sides, A (the switch off) and B (on), the side that goes first alternating from chunk
//! to chunk and from round to round, so that the machine's drift, which on a shared host
//! moves two runs of one binary by 10 % within minutes, falls on both sides alike.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};

/// The two sides' times over all chunks and rounds, and each chunk's A / B.
#[derive(Debug, Default)]
pub struct Interleaved {
    pub a: Duration,
    pub b: Duration,
    /// A's time over B's, chunk by chunk (above 1: B is faster).
    pub ratios: Vec<f64>,
    /// Chunks whose answers (hits, image sums) differ between the sides.
    pub differing: usize,
}

impl Interleaved {
    /// A's total time over B's: B's speed-up.
    pub fn speedup(&self) -> f64 {
        self.a.as_secs_f64() / self.b.as_secs_f64().max(f64::MIN_POSITIVE)
    }

    /// The median chunk's A / B: the figure least moved by a chunk the host interrupted.
    pub fn median_ratio(&self) -> f64 {
        let mut r = self.ratios.clone();
        r.sort_by(f64::total_cmp);
        r.get(r.len() / 2).copied().unwrap_or(f64::NAN)
    }

    /// One line for a report.
    pub fn line(&self) -> String {
        format!(
            "A {:.3} s, B {:.3} s: B's speed-up {:.4} in all, {:.4} the median chunk's ({} chunks){}",
            self.a.as_secs_f64(),
            self.b.as_secs_f64(),
            self.speedup(),
            self.median_ratio(),
            self.ratios.len(),
            if self.differing > 0 {
                format!("; {} chunks answered differently: B changes the results", self.differing)
            } else {
                String::new()
            }
        )
    }
}

/// Runs `work(chunk, side_b)` on each of `chunks` chunks, `rounds` times, on both sides,
/// timing each with `timed`; `work` returns its answer (a count of hits, a checksum), which
/// the two sides must give alike. `set` turns the switch before each side.
pub fn interleave(
    chunks: usize,
    rounds: usize,
    mut set: impl FnMut(bool),
    mut work: impl FnMut(usize, bool) -> u64,
    mut timed: impl FnMut(&mut dyn FnMut() -> u64) -> (Duration, u64),
) -> Interleaved {
    let mut out = Interleaved::default();
    for round in 0..rounds {
        for chunk in 0..chunks {
            let first_b = (chunk + round) % 2 == 1;
            let mut took = [Duration::ZERO; 2];
            let mut answer = [0; 2];
            for side_b in [first_b, !first_b] {
                set(side_b);
                let (t, a) = timed(&mut || work(chunk, side_b));
                took[usize::from(side_b)] = t;
                answer[usize::from(side_b)] = a;
            }
            set(false);
            out.a += took[0];
            out.b += took[1];
            out.ratios.push(took[0].as_secs_f64() / took[1].as_secs_f64().max(f64::MIN_POSITIVE));
            out.differing += usize::from(answer[0] != answer[1]);
        }
    }
    out
}

/// [`interleave`] on the wall clock with the worker's switch.
pub fn interleave_timed(chunks: usize, rounds: usize, work: impl FnMut(usize, bool) -> u64) -> Interleaved {
    interleave(chunks, rounds, tessera_worker::ab::set, work, |f| {
        let start = Instant::now();
        let answer = f();
        (start.elapsed(), answer)
    })
}

/// Refuses `--ab` in a build without the switch, where both sides would be A.
pub fn require_switch() -> Result<()> {
    if !tessera_worker::ab::BUILT {
        bail!(
            "--ab needs a build with the switch: cargo build --release --features ab, with the change \
             reading tessera_worker::ab::on() (worker/src/ab.rs)"
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fake clock: B's work takes 0.8 of A's, and every other chunk is slowed down
    /// threefold for both sides, as a busy host would.
    #[test]
    fn each_chunk_runs_on_both_sides_in_alternating_order() {
        let order = std::cell::RefCell::new(Vec::new());
        let mut side = false;
        let r = interleave(
            4,
            2,
            |b| side = b,
            |chunk, b| {
                order.borrow_mut().push((chunk, b));
                chunk as u64
            },
            |f| {
                let answer = f();
                let (chunk, b) = *order.borrow().last().expect("work ran");
                let base = if chunk % 2 == 0 { 10 } else { 30 };
                (Duration::from_millis(if b { base * 8 / 10 } else { base }), answer)
            },
        );
        assert!(!side, "the switch is left off");
        let order = order.into_inner();
        assert_eq!(order.len(), 16);
        assert_eq!(&order[..4], &[(0, false), (0, true), (1, true), (1, false)]);
        assert_eq!(&order[8..10], &[(0, true), (0, false)], "the next round starts with the other side");
        assert!((r.speedup() - 1.25).abs() < 1e-9);
        assert!((r.median_ratio() - 1.25).abs() < 1e-9);
        assert_eq!(r.differing, 0);
    }

    #[test]
    fn answers_that_differ_between_the_sides_are_counted() {
        let r = interleave(
            3,
            1,
            |_| {},
            |chunk, b| chunk as u64 + u64::from(b && chunk == 1),
            |f| (Duration::from_millis(1), f()),
        );
        assert_eq!(r.differing, 1);
        assert!(r.line().contains("1 chunks answered differently"));
    }
}
