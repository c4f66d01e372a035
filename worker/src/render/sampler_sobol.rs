//! Sobol's sequence for the sampler: the direction numbers of its first four dimensions,
//! their tables by bytes, and Owen scrambling by hashing (Burley 2020).

use super::ONE_MINUS_EPSILON;

/// The direction numbers of one dimension of Sobol's sequence from its primitive
/// polynomial of degree `s` (inner coefficients `a`, top one first) and initial odd `m`s
/// (Bratley and Fox's recurrence, as Joe and Kuo tabulate them), each held bit-reversed:
/// the scrambling below works on reversed coordinates.
pub(super) const fn sobol_directions(s: usize, a: u32, m: [u32; 3]) -> [u32; 32] {
    let mut mk = [0u32; 32];
    let mut k = 0;
    while k < 32 {
        mk[k] = if k < s {
            m[k]
        } else {
            let mut v = mk[k - s] ^ (mk[k - s] << s);
            let mut j = 1;
            while j < s {
                if (a >> (s - 1 - j)) & 1 == 1 {
                    v ^= mk[k - j] << j;
                }
                j += 1;
            }
            v
        };
        k += 1;
    }
    let mut reversed = [0u32; 32];
    let mut k = 0;
    while k < 32 {
        // vₖ = mₖ · 2^(31 − k), bit-reversed: mₖ's bits from bit k down.
        reversed[k] = (mk[k] << (31 - k)).reverse_bits();
        k += 1;
    }
    reversed
}

/// Sobol's second dimension (the first is the index itself, bit-reversed).
pub(super) const SOBOL_DIM1: [u32; 32] = sobol_directions(1, 0, [1, 0, 0]);
/// Sobol's dimensions 3 and 4 (polynomials x² + x + 1 and x³ + x + 1), the lens's
/// coordinates in the camera's 4-D pattern.
pub(super) const SOBOL_DIM2: [u32; 32] = sobol_directions(2, 1, [1, 3, 0]);
pub(super) const SOBOL_DIM3: [u32; 32] = sobol_directions(3, 1, [1, 3, 1]);

/// A Sobol dimension's reversed direction numbers regrouped by the index's bytes: entry
/// `[p][b]` is the sum (xor) of the directions of the bits set in `b` as byte `p`.
pub(super) type ByBytes = [[u32; 256]; 4];

pub(super) const fn by_bytes(directions: [u32; 32]) -> ByBytes {
    let mut t = [[0u32; 256]; 4];
    let mut p = 0;
    while p < 4 {
        let mut b = 1;
        while b < 256 {
            // b's lowest set bit added to the entry of b without it.
            let low = (b as u32).trailing_zeros() as usize;
            t[p][b] = t[p][b & (b - 1)] ^ directions[8 * p + low];
            b += 1;
        }
        p += 1;
    }
    t
}

/// [`SOBOL_DIM1`], [`SOBOL_DIM2`] and [`SOBOL_DIM3`] by bytes (4 KB each).
pub(super) static SOBOL_BYTES: [ByBytes; 3] =
    [by_bytes(SOBOL_DIM1), by_bytes(SOBOL_DIM2), by_bytes(SOBOL_DIM3)];

/// Point `i` of a Sobol dimension, bit-reversed, from its directions by bytes. A point is
/// linear in the index's bits (a sum of the directions of the bits set), so four lookups
/// make it: a pattern drawn in rounds takes indices of 20 bits, whose bit-by-bit sum
/// branched on every bit and made a draw a fifth slower.
#[inline]
pub(super) fn sobol_reversed(i: u32, t: &ByBytes) -> u32 {
    t[0][(i & 0xff) as usize]
        ^ t[1][((i >> 8) & 0xff) as usize]
        ^ t[2][((i >> 16) & 0xff) as usize]
        ^ t[3][(i >> 24) as usize]
}

/// Point `i`'s coordinates in Sobol's dimensions 2, 3 and 4, bit-reversed (the first is
/// `i` itself, reversed).
#[inline]
pub(super) fn sobol_point(i: u32) -> [u32; 3] {
    [
        sobol_reversed(i, &SOBOL_BYTES[0]),
        sobol_reversed(i, &SOBOL_BYTES[1]),
        sobol_reversed(i, &SOBOL_BYTES[2]),
    ]
}

/// Owen scrambling by hashing of the 32-bit fixed-point coordinate whose bit-reversal is
/// `v`: a keyed function in which each bit of the coordinate is flipped depending only on
/// the bits above it (Burley 2020, after Laine and Karras), which on the reversed value
/// runs from the top bit down as a multiplication carries.
#[inline]
pub(super) fn owen_scramble_reversed(mut v: u32, key: u32) -> u32 {
    v = v.wrapping_add(key);
    v ^= v.wrapping_mul(0x6c50_b47c);
    v ^= v.wrapping_mul(0xb82f_1e52);
    v ^= v.wrapping_mul(0xc7af_e638);
    v ^= v.wrapping_mul(0x8d22_f6e6);
    v.reverse_bits()
}

/// Sobol's order of a pixel's samples, shuffled: index `i` of a pattern whose sample count
/// rounds up to `2^bits`, Owen-scrambled as a `bits`-digit fraction (Burley 2020's nested
/// uniform scramble of the index). Each bit of the index flips depending only on the bits
/// above it, so the first `2^k` indices go to one aligned block of `2^k` points, and the
/// points of an aligned block of a digital net are a net: every power-of-two prefix of the
/// shuffled pattern is as stratified as a whole pattern of that size. A keyed permutation
/// of the indices (the stratified pattern's order) sends a prefix anywhere, and a pattern
/// drawn in prefixes (rounds) then converges like independent samples (docs/accuracy.md).
#[inline]
pub(super) fn nested_order(i: u32, key: u32, bits: u32) -> u32 {
    if bits == 0 {
        return 0;
    }
    // Reversed, the index's top digit is bit 0, as the scramble wants it.
    owen_scramble_reversed((i << (32 - bits)).reverse_bits(), key) >> (32 - bits)
}

/// A scrambled Sobol coordinate in [0, 1), from its bit-reversal and the pattern's key
/// (its low 32 bits).
#[inline]
pub(super) fn scrambled(reversed: u32, key: u64) -> f32 {
    fixed_to_unit(owen_scramble_reversed(reversed, key as u32))
}

pub(super) fn fixed_to_unit(x: u32) -> f32 {
    ((x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)).min(ONE_MINUS_EPSILON)
}

impl super::Sampler {
    /// `count` points of the next 2-D dimension for the current sample, passed to `f` in
    /// order: points `s · count .. (s + 1) · count` of one Owen-scrambled Sobol sequence
    /// per pixel and dimension, `s` being where the dimension's order puts the sample.
    /// Where `count` is a power of two a sample's points are a net (one in each of
    /// `count` elementary intervals of every shape), and the pixel's `spp · count` points
    /// are the start of one sequence (for Cook's pattern at any count, for Sobol's where
    /// `spp` is a power of two), a net too where `spp · count` is one: several directions drawn at
    /// one hit then cover its lobe as evenly as the pixel's samples cover the pixel,
    /// where as many separate dimensions would leave them independent of one another.
    /// Beyond the pattern, and for independent samples, the points are independent.
    pub fn each_2d_of_set(&mut self, count: u32, mut f: impl FnMut(glam::Vec2)) {
        use super::{hash_step, mix64, unit_float};
        debug_assert!(count <= tessera_description::limits::MAX_DIFFUSE_RAYS);
        let k = self.next_dimension();
        if !self.in_pattern() {
            let from = hash_step(k.from_key, u64::from(self.index));
            for j in 0..count {
                let h = hash_step(from, u64::from(j));
                f(glam::Vec2::new(unit_float(h), unit_float(mix64(h))));
            }
            return;
        }
        // Below 2^20 samples (`limits::MAX_SPP`) times 256 (`MAX_DIFFUSE_RAYS`): no wrap.
        let first = self.shuffle(k.key, self.index).wrapping_mul(count);
        for j in 0..count {
            let n = first.wrapping_add(j);
            f(glam::Vec2::new(
                scrambled(n, k.pattern),
                scrambled(sobol_reversed(n, &SOBOL_BYTES[0]), k.pattern >> 32),
            ));
        }
    }
}
