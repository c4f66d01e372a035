//! The table's draws of the camera's 4-D net (film and lens, [`Sampler::get_4d`]) eight
//! samples at a time, where the CPU has AVX2. A draw is a keyed permutation, three Sobol
//! points by byte tables and four Owen scramblings, all 32-bit integer work, which is the
//! same bits in any lane; the one float step (`fixed_to_unit`: an exact conversion, a
//! multiplication by a power of two, a minimum of two numbers that are not NaN) rounds as
//! the scalar one does. So every value equals `Sampler::pattern_4d`'s
//! (`tests::wide_4d_fill_gives_the_scalar_bits`, and the table's `tabled_draws_are_the_draws`
//! through the sampler). Chosen at run time ([`available`]); a build without it, or a CPU
//! without it, draws one sample at a time.
//!
//! Why: a lens scene's camera draw is one of the longest chains of a sample (`spheres`:
//! `pattern_4d` was 3.2 % of a `perf` profile), and its 32-bit multiplies and table
//! lookups have AVX2 forms, where the 2-D draws' 64-bit hashes need AVX-512
//! (`sampler_avx512.rs`).
#![allow(unsafe_code)]

use std::arch::x86_64::{
    __m256i, _mm256_add_epi32, _mm256_and_si256, _mm256_cvtepi32_ps, _mm256_i32gather_epi32, _mm256_min_ps,
    _mm256_mul_ps, _mm256_mullo_epi32, _mm256_or_si256, _mm256_set1_epi32, _mm256_set1_ps, _mm256_setr_epi32,
    _mm256_setr_epi8, _mm256_shuffle_epi8, _mm256_srl_epi32, _mm256_srli_epi32, _mm256_storeu_ps,
    _mm256_xor_si256, _mm_cvtsi32_si128,
};

use super::sobol::{ByBytes, SOBOL_BYTES};
use super::table::{DrawTable, Shape};
use super::{DimensionKeys, Permutation, Sampler, ONE_MINUS_EPSILON};

/// Whether this CPU runs AVX2 (the standard library caches the answer).
pub(super) fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

/// Samples to a register: 32-bit lanes of 256 bits.
const LANES: usize = 8;

impl Sampler {
    /// Draws the planned samples of the camera's 4-D dimensions (keys `film` and `lens`)
    /// eight at a time; only where [`Sampler::wide_4d`] is set.
    pub(super) fn fill_4d_wide(
        &self,
        d: u32,
        film: DimensionKeys,
        lens: DimensionKeys,
        table: &mut DrawTable,
    ) {
        // SAFETY: `wide_4d` is set only where `available()`.
        table.fill_all(d, Shape::Four, |first, out| unsafe { fill_4d(&self.order, film, lens, first, out) });
    }
}

/// Draws samples `first..first + out.len()` of the 4-D net keyed by `film` and `lens`, for
/// a permutation of a power-of-two length above 1, into `out`.
///
/// # Safety
/// The CPU must run AVX2 ([`available`]).
#[target_feature(enable = "avx2")]
unsafe fn fill_4d(
    order: &Permutation,
    film: DimensionKeys,
    lens: DimensionKeys,
    first: u32,
    out: &mut [[f32; 4]],
) {
    for (n, chunk) in out.chunks_mut(LANES).enumerate() {
        let start = first.wrapping_add((n * LANES) as u32) as i32;
        let index = _mm256_add_epi32(_mm256_set1_epi32(start), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
        // One index for all four coordinates, as in `pattern_4d`. In the last chunk the
        // lanes past the plan's end hold indices nothing reads; the permutation masks them
        // into the pattern's domain, and the byte tables take any index.
        let s = permute(order, film.key, index);
        // SAFETY (the gathers): the caller's promise; `sobol` indexes its table by bytes.
        let (y, u, v) =
            unsafe { (sobol(s, &SOBOL_BYTES[0]), sobol(s, &SOBOL_BYTES[1]), sobol(s, &SOBOL_BYTES[2])) };
        let coords = [
            scrambled(s, film.pattern as u32),
            scrambled(y, (film.pattern >> 32) as u32),
            scrambled(u, lens.pattern as u32),
            scrambled(v, (lens.pattern >> 32) as u32),
        ];
        for (l, value) in chunk.iter_mut().enumerate() {
            *value = std::array::from_fn(|c| coords[c][l]);
        }
    }
}

/// [`Permutation::apply`] in eight lanes, for a power-of-two length above 1 (one round:
/// every value lands inside the domain).
#[target_feature(enable = "avx2")]
fn permute(p: &Permutation, key: u64, i: __m256i) -> __m256i {
    debug_assert!(p.len.is_power_of_two() && p.len > 1);
    let mask = _mm256_set1_epi32(p.mask as i32);
    let (k0, k1) = (key as u32, (key >> 32) as u32);
    let mul = |x: __m256i, c: u32| _mm256_and_si256(_mm256_mullo_epi32(x, _mm256_set1_epi32(c as i32)), mask);
    let half = _mm_cvtsi32_si128(p.shift_half as i32);
    let third = _mm_cvtsi32_si128(p.shift_third as i32);
    let mut x = _mm256_xor_si256(i, _mm256_set1_epi32((k0 & p.mask) as i32));
    x = mul(x, 0x2c1b_3c6d | 1);
    x = _mm256_xor_si256(x, _mm256_srl_epi32(x, half));
    x = _mm256_and_si256(_mm256_add_epi32(x, _mm256_set1_epi32(k1 as i32)), mask);
    x = mul(x, 0x297a_2d39 | 1);
    x = _mm256_xor_si256(x, _mm256_srl_epi32(x, third));
    x = _mm256_xor_si256(x, _mm256_set1_epi32(((k1 >> 7) & p.mask) as i32));
    x = mul(x, 0x1b87_3593 | 1);
    _mm256_xor_si256(x, _mm256_srli_epi32::<1>(x))
}

/// `sobol_reversed` in eight lanes: a table entry for each byte of the index, summed.
///
/// # Safety
/// The CPU must run AVX2.
#[target_feature(enable = "avx2")]
unsafe fn sobol(i: __m256i, t: &ByBytes) -> __m256i {
    let byte = _mm256_set1_epi32(0xff);
    let mut sum = _mm256_set1_epi32(0);
    for (p, bytes) in t.iter().enumerate() {
        let b = _mm256_and_si256(_mm256_srl_epi32(i, _mm_cvtsi32_si128(8 * p as i32)), byte);
        // SAFETY: each lane's index is below 256, the length of `bytes`.
        sum = _mm256_xor_si256(sum, unsafe { _mm256_i32gather_epi32::<4>(bytes.as_ptr().cast(), b) });
    }
    sum
}

/// `scrambled`: the Owen scrambling of `owen_scramble_reversed`, its bits reversed, then
/// `fixed_to_unit`.
#[target_feature(enable = "avx2")]
fn scrambled(v: __m256i, key: u32) -> [f32; LANES] {
    let step = |v: __m256i, c: u32| _mm256_xor_si256(v, _mm256_mullo_epi32(v, _mm256_set1_epi32(c as i32)));
    let mut v = _mm256_add_epi32(v, _mm256_set1_epi32(key as i32));
    v = step(v, 0x6c50_b47c);
    v = step(v, 0xb82f_1e52);
    v = step(v, 0xc7af_e638);
    v = step(v, 0x8d22_f6e6);
    let x = reverse_bits(v);
    // (x >> 8) as f32 · 2⁻²⁴, at most ONE_MINUS_EPSILON: 24 bits convert exactly, and the
    // scale is a power of two. No lane is NaN, so the minimum's operand order is free.
    let f = _mm256_mul_ps(
        _mm256_cvtepi32_ps(_mm256_srli_epi32::<8>(x)),
        _mm256_set1_ps(1.0 / (1u32 << 24) as f32),
    );
    let mut out = [0f32; LANES];
    // SAFETY: `out` holds eight floats.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), _mm256_min_ps(f, _mm256_set1_ps(ONE_MINUS_EPSILON))) };
    out
}

/// `u32::reverse_bits` in eight lanes: the bytes of each lane reversed, then the bits of
/// each byte, a nibble at a time through a table of reversed nibbles.
#[target_feature(enable = "avx2")]
fn reverse_bits(v: __m256i) -> __m256i {
    #[rustfmt::skip]
    let bytes = _mm256_setr_epi8(
        3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12,
        3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12,
    );
    let v = _mm256_shuffle_epi8(v, bytes);
    // Nibble n reversed, as the low nibble of a byte and as the high one.
    #[rustfmt::skip]
    let low = _mm256_setr_epi8(
        0, 8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15,
        0, 8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15,
    );
    #[rustfmt::skip]
    let high = _mm256_setr_epi8(
        0, -128, 64, -64, 32, -96, 96, -32, 16, -112, 80, -48, 48, -80, 112, -16,
        0, -128, 64, -64, 32, -96, 96, -32, 16, -112, 80, -48, 48, -80, 112, -16,
    );
    let nibble = _mm256_set1_epi32(0x0f0f_0f0f);
    let lo = _mm256_and_si256(v, nibble);
    let hi = _mm256_and_si256(_mm256_srli_epi32::<4>(v), nibble);
    // A byte's low nibble, reversed, becomes its high one, and its high nibble its low one.
    _mm256_or_si256(_mm256_shuffle_epi8(high, lo), _mm256_shuffle_epi8(low, hi))
}

#[cfg(test)]
mod tests {
    use glam::UVec2;

    use super::super::{Sampler, SamplerKind};
    use super::*;

    /// Every power-of-two pattern up to 4096 samples, many pixels, plans starting anywhere
    /// and of any length: the eight-lane fill gives `pattern_4d`'s bits.
    #[test]
    fn wide_4d_fill_gives_the_scalar_bits() {
        if !available() {
            println!("SKIPPED: this CPU has no AVX2; the 4-D fill is never chosen here");
            return;
        }
        for spp in (1..=12).map(|k| 1u32 << k) {
            let mut sampler = Sampler::new(SamplerKind::Stratified, u64::from(spp) * 7, spp);
            assert!(sampler.wide_4d, "spp {spp}: where the fill is chosen");
            for p in 0..8 {
                let pixel = UVec2::new(p * 11, p * 3);
                let first = (p * 13) % spp;
                let count = (spp - first).min(1 + (p * 37) % 256);
                sampler.start_pixel_sample(pixel, first);
                for _ in 0..4 {
                    let (film, lens) = (sampler.next_dimension(), sampler.next_dimension());
                    let mut wide = vec![[0f32; 4]; count as usize];
                    // SAFETY: `available()` said yes above.
                    unsafe { fill_4d(&sampler.order, film, lens, first, &mut wide) };
                    for (i, w) in (first..).zip(&wide) {
                        let v = sampler.pattern_4d(film, lens, i);
                        assert_eq!(w.map(f32::to_bits), v.map(f32::to_bits), "spp {spp} {pixel} sample {i}");
                    }
                }
            }
        }
    }

    /// The lane-wise bit reversal against `u32::reverse_bits` on patterns that catch a
    /// byte or nibble put in the wrong place.
    #[test]
    fn lanes_reverse_bits_as_u32_does() {
        if !available() {
            println!("SKIPPED: this CPU has no AVX2");
            return;
        }
        let mut x = 0x0123_4567_u32;
        for _ in 0..4096 {
            let lanes: [u32; LANES] = std::array::from_fn(|l| x.rotate_left(l as u32 * 5) ^ (1 << (l * 4)));
            // SAFETY: `available()` said yes above; the array and the register are 32 bytes.
            let reversed: [u32; LANES] = unsafe {
                std::mem::transmute(reverse_bits(std::mem::transmute::<[u32; LANES], __m256i>(lanes)))
            };
            assert_eq!(reversed, lanes.map(u32::reverse_bits), "{lanes:x?}");
            x = x.wrapping_mul(0x9e37_79b9).wrapping_add(0x7f4a_7c15);
        }
    }
}
