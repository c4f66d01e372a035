//! The farm's randomness: lease tokens and the choice of which batches to audit. Both must
//! be unpredictable to workers, so they come from a CSPRNG: BLAKE3 in keyed
//! extendable-output mode, keyed once with 32 bytes from the operating system (getrandom).
//! This is the farm's one input that is not an argument; it is drawn at construction
//! (`Farm::new`), and tests and benchmarks that need reproducible runs seed it
//! (`Farm::with_seed`), so the farm's logic stays free of I/O.

use crate::scheduler::LeaseToken;

/// A stream of unpredictable bytes.
pub struct Entropy(blake3::OutputReader);

impl Entropy {
    /// Keyed from the operating system's CSPRNG.
    pub fn from_os() -> Result<Entropy, getrandom::Error> {
        let mut key = [0u8; 32];
        getrandom::fill(&mut key)?;
        Ok(Entropy::from_seed(key))
    }

    /// A reproducible stream (tests and benchmarks only: a known seed makes tokens and
    /// audits predictable).
    pub fn from_seed(seed: [u8; 32]) -> Entropy {
        let mut h = blake3::Hasher::new_keyed(&seed);
        h.update(b"tessera farm entropy v1");
        Entropy(h.finalize_xof())
    }

    /// A fresh lease token: 128 bits, never repeated in practice.
    pub fn token(&mut self) -> LeaseToken {
        let mut t = [0u8; 16];
        self.0.fill(&mut t);
        LeaseToken(t)
    }

    /// `true` with probability `p` (clamped to [0, 1]).
    pub fn chance(&mut self, p: f64) -> bool {
        let mut b = [0u8; 8];
        self.0.fill(&mut b);
        // 53 bits: exactly representable as an f64 in [0, 1).
        let u = (u64::from_le_bytes(b) >> 11) as f64 / (1u64 << 53) as f64;
        u < p
    }
}

impl Default for Entropy {
    fn default() -> Self {
        // getrandom fails only where the OS has no entropy source at all; std's hasher
        // keys (themselves from the OS where it has one) are then the best left.
        Entropy::from_os().unwrap_or_else(|_| {
            use std::hash::{BuildHasher, Hasher};
            let mut key = [0u8; 32];
            for chunk in key.chunks_exact_mut(8) {
                let mut h = std::collections::hash_map::RandomState::new().build_hasher();
                h.write_u64(0);
                chunk.copy_from_slice(&h.finish().to_le_bytes());
            }
            Entropy::from_seed(key)
        })
    }
}

impl std::fmt::Debug for Entropy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Entropy(..)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_differ_and_chance_follows_its_probability() {
        let mut e = Entropy::from_seed([1; 32]);
        let (a, b) = (e.token(), e.token());
        assert_ne!(a, b);
        let hits = (0..100_000).filter(|_| e.chance(0.03)).count();
        assert!((2_700..3_300).contains(&hits), "{hits} hits of 100 000 at 3 %");
        assert!(!(0..1000).any(|_| e.chance(0.0)));
        assert!((0..1000).all(|_| e.chance(1.0)));
        // Two keys from the OS give different streams.
        let (mut x, mut y) = (Entropy::from_os().unwrap(), Entropy::from_os().unwrap());
        assert_ne!(x.token(), y.token());
    }
}
