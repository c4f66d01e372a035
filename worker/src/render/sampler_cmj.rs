//! Cook's correlated multi-jittered pattern (Kensler 2013) for the sampler: keyed
//! permutations of small domains, the grid of an `n`-sample pattern, and where a sample
//! of it lies.

use glam::Vec2;

use super::{hash_step, mix64, unit_float, ONE_MINUS_EPSILON};

/// A keyed bijection of `0..len`, evaluated at `i` without storing the permutation: a
/// keyed invertible mix on the smallest power-of-two domain that holds `len`, repeated
/// (cycle walking) until it lands inside `0..len`, then turned by a keyed amount where
/// `len` is not a power of two, so that over keys every `i` goes anywhere as often.
pub fn permute(i: u32, len: u32, key: u64) -> u32 {
    debug_assert!(i < len);
    Permutation::new(len).apply(i, key)
}

/// The constants of [`permute`] for one length. A sampler's lengths (the sample count, the
/// grid's sides) are fixed, so it keeps these instead of deriving them at every draw.
#[derive(Debug, Clone, Copy)]
pub(super) struct Permutation {
    pub(super) len: u32,
    /// The smallest power-of-two domain holding `len`, less one.
    pub(super) mask: u32,
    /// The two xor-shifts that depend on the domain's bit count.
    pub(super) shift_half: u32,
    pub(super) shift_third: u32,
    /// `len` is not a power of two: the mix's result is walked into `0..len`, and turned.
    pub(super) walks: bool,
}

impl Permutation {
    pub(super) fn new(len: u32) -> Permutation {
        if len <= 1 {
            return Permutation { len, mask: 0, shift_half: 1, shift_third: 1, walks: false };
        }
        let mask = u32::MAX >> (len - 1).leading_zeros();
        let bits = 32 - mask.leading_zeros();
        let walks = !len.is_power_of_two();
        Permutation { len, mask, shift_half: (bits / 2).max(1), shift_third: (bits / 3).max(1), walks }
    }

    #[inline]
    pub(super) fn apply(&self, i: u32, key: u64) -> u32 {
        if self.len <= 1 {
            return 0;
        }
        let (mask, (k0, k1)) = (self.mask, (key as u32, (key >> 32) as u32));
        let mut x = i;
        loop {
            // Every step is invertible modulo 2^bits: xor with a key, multiply by an odd
            // constant, xor-shift right, add a key.
            x ^= k0 & mask;
            x = x.wrapping_mul(0x2c1b_3c6d | 1) & mask;
            x ^= x >> self.shift_half;
            x = x.wrapping_add(k1) & mask;
            x = x.wrapping_mul(0x297a_2d39 | 1) & mask;
            x ^= x >> self.shift_third;
            x ^= (k1 >> 7) & mask;
            x = x.wrapping_mul(0x1b87_3593 | 1) & mask;
            x ^= x >> 1;
            if x < self.len {
                break;
            }
        }
        if !self.walks {
            // The first xor alone sends `i` anywhere in the domain as often. The SIMD
            // fills' copies of this mix (`sampler_avx512.rs`, `sampler_avx2.rs`) run only
            // on powers of two, and so have no turn.
            return x;
        }
        // The walk's ends are not spread evenly: an element of 0..3 went to 2 in half of
        // all keys (`every_element_goes_anywhere_as_often`). A turn by an amount of its
        // own, uniform over `0..len` whatever the mix did, spreads them; the turn keeps
        // the map a bijection.
        let len = u64::from(self.len);
        let turn = ((mix64(key ^ 0x7e57_7e57) >> 32) * len) >> 32;
        let y = u64::from(x) + turn;
        (if y >= len { y - len } else { y }) as u32
    }
}

/// The grid of an `n`-sample pattern: `m` columns by `n / m` rows with `m` the largest
/// divisor of `n` not above √n. The grid must hold exactly `n` cells: a partly filled last
/// row would leave the same corner of every pixel unsampled, a bias that no sample count
/// removes.
pub fn grid(n: u32) -> (u32, u32) {
    let mut m = (n as f64).sqrt() as u32;
    while m > 1 && !n.is_multiple_of(m) {
        m -= 1;
    }
    let m = m.max(1);
    (m, n / m)
}

/// The coarse grid of a sampler's correlated multi-jittered pattern and the permutations
/// of its columns and rows.
#[derive(Debug, Clone, Copy)]
pub(super) struct Cmj {
    /// Columns and rows (`m · rows = n`).
    pub(super) m: u32,
    pub(super) rows: u32,
    pub(super) columns: Permutation,
    pub(super) row_order: Permutation,
    /// Both sides powers of two (every power-of-two sample count): `log2 m`, `1 / m` and
    /// `1 / rows`. A cell is then a mask and a shift of the stratum, and dividing by a side
    /// is multiplying by its reciprocal, which is exact for a power of two: the same bits
    /// without the divisions' latency.
    pub(super) pow2: Option<(u32, f32, f32)>,
}

impl Cmj {
    pub(super) fn new(n: u32) -> Cmj {
        let (m, rows) = grid(n);
        let pow2 = (m.is_power_of_two() && rows.is_power_of_two())
            .then(|| (m.trailing_zeros(), 1.0 / m as f32, 1.0 / rows as f32));
        Cmj { m, rows, columns: Permutation::new(m), row_order: Permutation::new(rows), pow2 }
    }

    /// The coarse cell (column, row) of stratum `s`.
    #[inline]
    pub(super) fn cell(&self, s: u32) -> (u32, u32) {
        match self.pow2 {
            Some((shift, _, _)) => (s & (self.m - 1), s >> shift),
            None => (s % self.m, s / self.m),
        }
    }

    /// The fine-grid offset of column `col` in the pattern keyed by `key`. Offsets are
    /// shuffled per pattern, so that columns and rows of the coarse grid do not line up;
    /// the columns' and the rows' shuffles must be independent, which keys that differ in
    /// a few low bits are not: a small domain's permutation reads few of the key's bits,
    /// and with keys `key ^ 0x51` and `key ^ 0xa3` the columns and rows of a 2 × 2 grid
    /// were always shuffled alike, every point in its cell's lower-left or upper-right
    /// quarter (`a_point_is_anywhere_in_its_cell`). Hence a hash of each.
    #[inline]
    pub(super) fn column_offset(&self, col: u32, key: u64) -> u32 {
        self.columns.apply(col, mix64(key ^ 0x51))
    }

    /// The fine-grid offset of row `row`.
    #[inline]
    pub(super) fn row_offset(&self, row: u32, key: u64) -> u32 {
        self.row_order.apply(row, mix64(key ^ 0xa3))
    }

    /// Sample `s` of the `n`-sample pattern, in cell (`col`, `row`) with fine-grid offsets
    /// `sx` and `sy`; `from_key` is `hash_step(HASH_START, key)`, the state its jitter
    /// hashes start from.
    #[inline]
    pub(super) fn place(&self, s: u32, (col, row): (u32, u32), (sx, sy): (u32, u32), from_key: u64) -> Vec2 {
        // hash_words(&[key, s, 1]) and (&[key, s, 2]), sharing their first two steps.
        let prefix = hash_step(from_key, u64::from(s));
        let jx = unit_float(hash_step(prefix, 1));
        let jy = unit_float(hash_step(prefix, 2));
        let (x, y) = match self.pow2 {
            Some((_, inv_m, inv_rows)) => (
                (col as f32 + (sy as f32 + jx) * inv_rows) * inv_m,
                (row as f32 + (sx as f32 + jy) * inv_m) * inv_rows,
            ),
            None => {
                let (m, rows) = (self.m as f32, self.rows as f32);
                ((col as f32 + (sy as f32 + jx) / rows) / m, (row as f32 + (sx as f32 + jy) / m) / rows)
            }
        };
        Vec2::new(x.min(ONE_MINUS_EPSILON), y.min(ONE_MINUS_EPSILON))
    }
}

#[cfg(test)]
#[path = "sampler_cmj_tests.rs"]
mod tests;
