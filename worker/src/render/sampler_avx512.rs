//! The table's 2-D draws of Cook's stratified pattern eight samples at a time, where the
//! CPU has AVX-512 (F and DQ: DQ has the 64-bit multiply the hashes need, which AVX2
//! lacks). Integer work is the same bits in any lane, and the float steps are the scalar
//! draw's additions and multiplications in its order (no fused multiply-add: Rust never
//! contracts on its own and `avx512f` asks for none), so every value equals
//! `Sampler::pattern_2d`'s (`tests::wide_fill_gives_the_scalar_bits`, and the table's
//! `tabled_draws_are_the_draws` through the sampler). Chosen at run
//! time ([`available`]); a build without it, or a CPU without it, fills one draw at a time.
#![allow(unsafe_code)]

use std::arch::x86_64::{
    __m512i, _mm256_add_ps, _mm256_min_ps, _mm256_mul_ps, _mm256_set1_ps, _mm256_storeu_ps, _mm512_add_epi64,
    _mm512_and_si512, _mm512_cvtepi64_ps, _mm512_loadu_si512, _mm512_mullo_epi64, _mm512_set1_epi64,
    _mm512_slli_epi64, _mm512_srli_epi64, _mm512_srlv_epi64, _mm512_storeu_si512, _mm512_xor_si512,
};

use super::table::{DrawTable, Shape};
use super::{Cmj, DimensionKeys, Permutation, Sampler, HASH_START, KEPT_OFFSETS, ONE_MINUS_EPSILON};

/// Whether this CPU runs AVX-512 F and DQ (the standard library caches the answer).
pub(super) fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512dq")
}

/// Lanes of 64 bits in a register.
const LANES: usize = 8;

impl Sampler {
    /// Draws the planned samples of the 2-D dimension `d` (keys `k`) eight at a time;
    /// only where [`Sampler::wide`] is set.
    pub(super) fn fill_2d_wide(&mut self, d: u32, k: DimensionKeys, table: &mut DrawTable) {
        // The dimension's fine-grid offsets, through the pixel's kept ones (`wide` asks
        // that they be kept): a run of a pattern's samples meets most of its columns and
        // rows.
        let (m, rows) = (self.cmj.m, self.cmj.rows);
        let mut offsets = [0u32; KEPT_OFFSETS as usize];
        for j in 0..m.max(rows) {
            let (sx, sy) = self.fine_offsets(d, (j.min(m - 1), j.min(rows - 1)), k.pattern);
            (offsets[j.min(m - 1) as usize], offsets[(m + j.min(rows - 1)) as usize]) = (sx, sy);
        }
        let (columns, rows) = offsets[..(m + rows) as usize].split_at(m as usize);
        // SAFETY: `wide` is set only where `available()`.
        #[allow(unsafe_code)]
        table.fill_all(d, Shape::Two, |first, out| unsafe {
            fill_2d(&self.cmj, &self.order, k, columns, rows, first, out)
        });
    }
}

/// Draws samples `first..first + out.len()` of the 2-D dimension keyed by `k` of a
/// pattern whose grid's sides are powers of two (`cmj.pow2`), into `out` as the table's
/// entries, (x, y, 0, 0); `columns` and `rows` are the dimension's fine-grid offsets
/// (`Sampler::fine_offsets`).
///
/// # Safety
/// The CPU must run AVX-512 F and DQ ([`available`]).
unsafe fn fill_2d(
    cmj: &Cmj,
    order: &Permutation,
    k: DimensionKeys,
    columns: &[u32],
    rows: &[u32],
    first: u32,
    out: &mut [[f32; 4]],
) {
    let Some((shift, inv_m, inv_rows)) = cmj.pow2 else { unreachable!("a grid of powers of two") };
    for (n, chunk) in out.chunks_mut(LANES).enumerate() {
        let mut index = [0u64; LANES];
        for (l, i) in index.iter_mut().enumerate() {
            *i = u64::from(first) + (n * LANES + l) as u64;
        }
        // SAFETY: the caller's promise.
        let (strata, jx, jy) = unsafe { strata_and_jitter(order, k, index) };
        let mut sx = [0f32; LANES];
        let mut sy = [0f32; LANES];
        let mut col = [0f32; LANES];
        let mut row = [0f32; LANES];
        for l in 0..LANES {
            let s = strata[l] as u32;
            let (c, r) = (s & (cmj.m - 1), s >> shift);
            (col[l], row[l]) = (c as f32, r as f32);
            (sx[l], sy[l]) = (columns[c as usize] as f32, rows[r as usize] as f32);
        }
        // SAFETY: as above.
        let (x, y) = unsafe { place(col, row, sx, sy, jx, jy, inv_m, inv_rows) };
        for (l, v) in chunk.iter_mut().enumerate() {
            *v = [x[l], y[l], 0.0, 0.0];
        }
    }
}

/// `s = order.apply(index, k.key)` and the jitter `unit_float(hash_step(hash_step(
/// from_pattern, s), 1 | 2))` of eight indices. In the last chunk of a plan the lanes past
/// its end hold indices nothing reads; the permutation masks them into the pattern too,
/// so their cells stay inside the offsets' slices.
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn strata_and_jitter(
    order: &Permutation,
    k: DimensionKeys,
    index: [u64; LANES],
) -> ([u64; LANES], [f32; LANES], [f32; LANES]) {
    let s = permute(order, k.key, load(&index));
    let prefix = hash_step(_mm512_set1_epi64(k.from_pattern as i64), s);
    let jx = unit_float(hash_step(prefix, _mm512_set1_epi64(1)));
    let jy = unit_float(hash_step(prefix, _mm512_set1_epi64(2)));
    let mut strata = [0u64; LANES];
    _mm512_storeu_si512(strata.as_mut_ptr().cast(), s);
    (strata, jx, jy)
}

#[target_feature(enable = "avx512f")]
unsafe fn load(v: &[u64; LANES]) -> __m512i {
    _mm512_loadu_si512(v.as_ptr().cast())
}

/// [`Permutation::apply`] in eight lanes, for a power-of-two length (one round: every
/// value lands inside the domain). The lanes hold values below 2³², and each step masks
/// to the domain, so 64-bit products give the 32-bit products' low bits.
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn permute(p: &Permutation, key: u64, i: __m512i) -> __m512i {
    debug_assert!(p.len.is_power_of_two() && p.len > 1);
    let mask = _mm512_set1_epi64(i64::from(p.mask));
    let (k0, k1) = (key as u32, (key >> 32) as u32);
    let mul =
        |x: __m512i, c: u32| _mm512_and_si512(_mm512_mullo_epi64(x, _mm512_set1_epi64(i64::from(c))), mask);
    let half = _mm512_set1_epi64(i64::from(p.shift_half));
    let third = _mm512_set1_epi64(i64::from(p.shift_third));
    let mut x = _mm512_xor_si512(i, _mm512_set1_epi64(i64::from(k0 & p.mask)));
    x = mul(x, 0x2c1b_3c6d | 1);
    x = _mm512_xor_si512(x, _mm512_srlv_epi64(x, half));
    x = _mm512_and_si512(_mm512_add_epi64(x, _mm512_set1_epi64(i64::from(k1))), mask);
    x = mul(x, 0x297a_2d39 | 1);
    x = _mm512_xor_si512(x, _mm512_srlv_epi64(x, third));
    x = _mm512_xor_si512(x, _mm512_set1_epi64(i64::from((k1 >> 7) & p.mask)));
    x = mul(x, 0x1b87_3593 | 1);
    _mm512_xor_si512(x, _mm512_srli_epi64::<1>(x))
}

/// `hash_step(h, w)` in eight lanes: `mix64(h ^ (w + HASH_START + (h << 6) + (h >> 2)))`.
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn hash_step(h: __m512i, w: __m512i) -> __m512i {
    let sum = _mm512_add_epi64(
        _mm512_add_epi64(
            _mm512_add_epi64(w, _mm512_set1_epi64(HASH_START as i64)),
            _mm512_slli_epi64::<6>(h),
        ),
        _mm512_srli_epi64::<2>(h),
    );
    let mut z = _mm512_xor_si512(h, sum);
    z = _mm512_mullo_epi64(
        _mm512_xor_si512(z, _mm512_srli_epi64::<30>(z)),
        _mm512_set1_epi64(0xbf58_476d_1ce4_e5b9_u64 as i64),
    );
    z = _mm512_mullo_epi64(
        _mm512_xor_si512(z, _mm512_srli_epi64::<27>(z)),
        _mm512_set1_epi64(0x94d0_49bb_1331_11eb_u64 as i64),
    );
    _mm512_xor_si512(z, _mm512_srli_epi64::<31>(z))
}

/// `unit_float`: the top 24 bits as a float in [0, 1) (exact: they fit a float's
/// significand, and the scale is a power of two).
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn unit_float(h: __m512i) -> [f32; LANES] {
    let f = _mm256_mul_ps(
        _mm512_cvtepi64_ps(_mm512_srli_epi64::<40>(h)),
        _mm256_set1_ps(1.0 / (1u64 << 24) as f32),
    );
    let mut out = [0f32; LANES];
    _mm256_storeu_ps(out.as_mut_ptr(), f);
    out
}

/// `Cmj::place`'s arithmetic for a grid of powers of two, lane for lane.
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn place(
    col: [f32; LANES],
    row: [f32; LANES],
    sx: [f32; LANES],
    sy: [f32; LANES],
    jx: [f32; LANES],
    jy: [f32; LANES],
    inv_m: f32,
    inv_rows: f32,
) -> ([f32; LANES], [f32; LANES]) {
    use std::arch::x86_64::_mm256_loadu_ps as ld;
    let (im, ir, top) = (_mm256_set1_ps(inv_m), _mm256_set1_ps(inv_rows), _mm256_set1_ps(ONE_MINUS_EPSILON));
    // (col + (sy + jx) · 1/rows) · 1/m and (row + (sx + jy) · 1/m) · 1/rows.
    let x = _mm256_mul_ps(
        _mm256_add_ps(ld(col.as_ptr()), _mm256_mul_ps(_mm256_add_ps(ld(sy.as_ptr()), ld(jx.as_ptr())), ir)),
        im,
    );
    let y = _mm256_mul_ps(
        _mm256_add_ps(ld(row.as_ptr()), _mm256_mul_ps(_mm256_add_ps(ld(sx.as_ptr()), ld(jy.as_ptr())), im)),
        ir,
    );
    // min(x, top): no lane is NaN, so the order of the operands does not matter.
    let (mut xs, mut ys) = ([0f32; LANES], [0f32; LANES]);
    _mm256_storeu_ps(xs.as_mut_ptr(), _mm256_min_ps(x, top));
    _mm256_storeu_ps(ys.as_mut_ptr(), _mm256_min_ps(y, top));
    (xs, ys)
}

#[cfg(test)]
mod tests {
    use glam::UVec2;

    use super::super::{Sampler, SamplerKind};
    use super::*;

    /// Every power-of-two pattern up to 4096 samples, many pixels and dimensions, plans
    /// starting anywhere and of any length: the eight-lane fill gives `pattern_2d`'s bits.
    /// (Past 2^13 samples the offsets are not kept, and the sampler does not choose it.)
    #[test]
    fn wide_fill_gives_the_scalar_bits() {
        if !available() {
            println!("SKIPPED: this CPU has no AVX-512 F and DQ; the fill is never chosen here");
            return;
        }
        for spp in (1..=12).map(|k| 1u32 << k) {
            let mut sampler = Sampler::new(SamplerKind::Stratified, u64::from(spp), spp);
            assert_eq!(sampler.wide, spp > 1, "spp {spp}: where the fill is chosen");
            for p in 0..6 {
                let pixel = UVec2::new(p * 7, p);
                let first = (p * 13) % spp;
                let count = (spp - first).min(1 + (p * 37) % 256);
                sampler.start_pixel_sample(pixel, first);
                for d in 0..20 {
                    let k = sampler.next_dimension();
                    let cmj = sampler.cmj;
                    let columns: Vec<u32> = (0..cmj.m).map(|c| cmj.column_offset(c, k.pattern)).collect();
                    let rows: Vec<u32> = (0..cmj.rows).map(|r| cmj.row_offset(r, k.pattern)).collect();
                    let mut wide = vec![[0f32; 4]; count as usize];
                    // SAFETY: `available()` said yes above.
                    unsafe { fill_2d(&cmj, &sampler.order, k, &columns, &rows, first, &mut wide) };
                    for (i, w) in (first..).zip(&wide) {
                        let v = sampler.pattern_2d(d, k, i);
                        assert_eq!(
                            (w[0].to_bits(), w[1].to_bits()),
                            (v.x.to_bits(), v.y.to_bits()),
                            "spp {spp} {pixel} dimension {d} sample {i}"
                        );
                    }
                }
            }
        }
    }
}
