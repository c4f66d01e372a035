//! Fixed-point radiance: the exact, order-free representation in which sample sums travel
//! and accumulate, so that the final image does not depend on the order results arrive in,
//! the batch sizes or the number of workers (DESIGN contract 1).
//!
//! A sample's radiance is clamped to `[0, SAMPLE_MAX]` and rounded to a multiple of
//! `2^-24` (6e-8, far below what 8-bit output or half floats resolve). Integer addition is
//! associative, so any grouping of sums gives the same bits. A `u64` holds 2^40 radiance
//! units: 131 072 samples of the brightest allowed radiance, and far more of ordinary ones.

/// Fractional bits of the fixed-point representation.
pub const FRACTION_BITS: u32 = 24;
/// The scale from radiance to fixed point.
pub const SCALE: f64 = (1u64 << FRACTION_BITS) as f64;
/// The brightest radiance a single sample may carry (8.4 million); brighter is clamped.
pub const SAMPLE_MAX: f32 = (1u32 << 23) as f32;

/// Converts one sample channel to fixed point. Non-finite values become 0 and are
/// reported, so that no NaN or infinity can reach a framebuffer (contract 5).
#[inline]
pub fn to_fixed(v: f32) -> Option<u64> {
    if !v.is_finite() {
        return None;
    }
    let x = f64::from(v.clamp(0.0, SAMPLE_MAX)) * SCALE;
    // `f64::round` is a call into compiler-builtins on baseline x86-64 (no SSE4.1), paid per
    // channel of every sample. Here `x` is non-negative and below 2^48, so truncating it is
    // exact and so is the fraction left over: rounding that half up gives `round`'s bits
    // (`rounds_as_f64_round`). Through `i64`, exact for the same reason: x86-64 before
    // AVX-512 converts to `i64` in one instruction, to `u64` with a branch and two.
    let whole = x as i64;
    Some(whole as u64 + u64::from(x - whole as f64 >= 0.5))
}

/// The mean radiance of `count` samples whose fixed-point sum is `sum`.
#[inline]
pub fn mean(sum: u64, count: u32) -> f32 {
    if count == 0 {
        return 0.0;
    }
    (sum as f64 / SCALE / f64::from(count)) as f32
}

/// The largest fixed-point sum `count` samples can legitimately have: results beyond it
/// are refused as corrupt.
pub fn max_sum(count: u32) -> u64 {
    (SAMPLE_MAX as u64 * u64::from(count)) << FRACTION_BITS
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_ordinary_radiance() {
        for v in [0.0f32, 1.0, 0.5, 1e-3, 123.456, 1e6] {
            let f = to_fixed(v).unwrap();
            assert!((mean(f, 1) - v).abs() <= v * 1e-6 + 1e-7, "{v}");
        }
    }

    #[test]
    fn clamps_and_rejects_non_finite() {
        assert_eq!(to_fixed(f32::NAN), None);
        assert_eq!(to_fixed(f32::INFINITY), None);
        assert_eq!(to_fixed(-1.0), Some(0));
        assert_eq!(to_fixed(1e30), to_fixed(SAMPLE_MAX));
    }

    /// Every radiance that leaves a fraction at 2^-24 (those below 0.5), strided, every one
    /// that lands exactly on or next to a half, and the ends: the same bits as `f64::round`.
    #[test]
    fn rounds_as_f64_round() {
        let reference = |v: f32| (f64::from(v.clamp(0.0, SAMPLE_MAX)) * SCALE).round() as u64;
        let strided = (0..0.5f32.to_bits()).step_by(9973).map(f32::from_bits);
        let halves = (0..1u32 << 16).flat_map(|k| {
            let half = ((f64::from(k) + 0.5) / SCALE) as f32;
            [half, half.next_down(), half.next_up()]
        });
        let ends =
            [0.0, -0.0, -1.0, 0.5, 1.0, 1e-45, f32::MIN_POSITIVE, SAMPLE_MAX.next_down(), SAMPLE_MAX, 1e30];
        for v in strided.chain(halves).chain(ends) {
            assert_eq!(to_fixed(v), Some(reference(v)), "{v:e}");
        }
    }

    /// 65 536 samples at the clamp still fit a u64: accumulation never wraps.
    #[test]
    fn sums_of_65536_brightest_samples_fit() {
        let one = to_fixed(SAMPLE_MAX).unwrap();
        assert!(one.checked_mul(65_536).is_some());
        assert_eq!(max_sum(65_536), one * 65_536);
    }
}
