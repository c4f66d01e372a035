//! A node's eight box tests as one group of 256-bit lanes, where the CPU has AVX2: the
//! instructions of [`Node8::hit`]'s two 128-bit groups, lane for lane, so the decisions and
//! entry distances are the same bits (`wide_tests::avx_box_test_gives_the_sse_bits`).
//! AVX2 is chosen at run time ([`available`]) and the traversals are compiled twice, once
//! with it enabled (`Wide::nearest_leaves`, `Wide::each_leaf`): a build for baseline x86-64 then runs
//! the wider test on the machines that have it. No fused multiply-add: `avx` does not
//! enable FMA, and Rust never contracts a multiply and an add on its own.
//!
//! The worker's `unsafe` code is here, at the two calls of the AVX2 traversals in
//! `wide.rs`, and in the sampler's AVX-512 and AVX2 fills (`sampler_avx512.rs`,
//! `sampler_avx2.rs`) and their calls:
//! intrinsics and functions compiled for a CPU feature are unsafe to call.
//! Measured: with the gather below, 21 % fewer instructions on the torus knot's rays and
//! 0–10 % more rays per second (docs/speed.md, eleventh part).
#![allow(unsafe_code)]

use std::arch::x86_64::{
    __m128, _mm256_and_ps, _mm256_and_si256, _mm256_blendv_ps, _mm256_broadcast_ps, _mm256_castsi256_ps,
    _mm256_cmp_ps, _mm256_load_ps, _mm256_max_ps, _mm256_min_ps, _mm256_movemask_ps, _mm256_mul_ps,
    _mm256_set1_epi32, _mm256_set1_ps, _mm256_setr_epi32, _mm256_setzero_ps, _mm256_sllv_epi32,
    _mm256_srlv_epi32, _mm256_storeu_ps, _mm256_sub_epi32, _mm256_sub_ps, _CMP_LE_OQ, _CMP_UNORD_Q,
};

use super::node::{reduce, BoxTest, Node8, RayLanes, LOWER, UPPER, WIDTH};
use super::slab_widening;

/// Whether this CPU runs AVX and AVX2 (the standard library caches the answer).
pub(super) fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx") && std::arch::is_x86_feature_detected!("avx2")
}

/// The box test on 256-bit lanes. Only used once [`available`] said yes.
pub(super) struct Avx;

impl BoxTest for Avx {
    #[inline(always)]
    fn hit<const EXACT: bool>(n: &Node8, r: &RayLanes, t_max: f32) -> (u32, [f32; WIDTH]) {
        // SAFETY: the traversals instantiated with `Avx` run only where `available()` (a
        // `Wide` made by `Wide::new` on this machine: it is never sent elsewhere).
        unsafe { hit::<EXACT>(n, r, t_max) }
    }

    #[inline(always)]
    fn visit(mask: u32, order: u32) -> u32 {
        // SAFETY: as above.
        unsafe { visit(mask, order) }
    }
}

/// [`BoxTest::visit`] in eight 32-bit lanes: lane k shifts the mask so that the bit of
/// the lane at position k lands in its sign bit, and the signs are the answer.
#[target_feature(enable = "avx,avx2")]
#[inline]
unsafe fn visit(mask: u32, order: u32) -> u32 {
    let at = _mm256_and_si256(
        _mm256_srlv_epi32(_mm256_set1_epi32(order as i32), _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21)),
        _mm256_set1_epi32(7),
    );
    let bits = _mm256_sllv_epi32(_mm256_set1_epi32(mask as i32), _mm256_sub_epi32(_mm256_set1_epi32(31), at));
    _mm256_movemask_ps(_mm256_castsi256_ps(bits)) as u32
}

/// [`Node8::hit`] with each pair of 128-bit operations as one 256-bit one, operands in the
/// same order (glam's `min`, `max`, `cmple`, `is_nan_mask` and `select` on SSE2 are
/// `minps`, `maxps`, `cmpleps`, `cmpunordps` and an and/andnot/or blend of a full mask).
#[target_feature(enable = "avx,avx2")]
#[inline]
unsafe fn hit<const EXACT: bool>(n: &Node8, r: &RayLanes, t_max: f32) -> (u32, [f32; WIDTH]) {
    let (mut nears, mut fars) = ([_mm256_setzero_ps(); 3], [_mm256_setzero_ps(); 3]);
    for a in 0..3 {
        let (origin, inv): (__m128, __m128) = (r.origin[a].into(), r.inv[a].into());
        let (origin, inv) = (_mm256_broadcast_ps(&origin), _mm256_broadcast_ps(&inv));
        let (near, far) = if EXACT {
            // SAFETY: a node's lanes of one axis are eight floats at a multiple of 32 bytes
            // from its start, which `Node8`'s repr aligns to 64.
            let (min, max) = unsafe {
                (
                    _mm256_load_ps(n.planes[LOWER][a].as_ptr().cast()),
                    _mm256_load_ps(n.planes[UPPER][a].as_ptr().cast()),
                )
            };
            let t0 = _mm256_mul_ps(_mm256_sub_ps(min, origin), inv);
            let t1 = _mm256_mul_ps(_mm256_sub_ps(max, origin), inv);
            let inside = _mm256_cmp_ps::<_CMP_UNORD_Q>(t0, t1);
            (
                _mm256_blendv_ps(_mm256_min_ps(t0, t1), _mm256_set1_ps(f32::NEG_INFINITY), inside),
                _mm256_blendv_ps(_mm256_max_ps(t0, t1), _mm256_set1_ps(f32::INFINITY), inside),
            )
        } else {
            // The near and far planes by the direction's sign, as `Node8::hit` takes them.
            let near = r.near[a] & 1;
            // SAFETY: as above.
            let (first, last) = unsafe {
                (
                    _mm256_load_ps(n.planes[near][a].as_ptr().cast()),
                    _mm256_load_ps(n.planes[near ^ 1][a].as_ptr().cast()),
                )
            };
            (
                _mm256_mul_ps(_mm256_sub_ps(first, origin), inv),
                _mm256_mul_ps(_mm256_sub_ps(last, origin), inv),
            )
        };
        (nears[a], fars[a]) = (near, far);
    }
    // Closures made here have AVX too, so the two calls are safe in them.
    let (enter, exit) =
        reduce(nears, fars, |a, b| _mm256_max_ps(a, b), |a, b| _mm256_min_ps(a, b), _mm256_setzero_ps());
    // `Node8::hit`'s two comparisons, in the same order.
    let exit = _mm256_mul_ps(exit, _mm256_set1_ps(slab_widening()));
    let entered = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_LE_OQ>(enter, exit),
        _mm256_cmp_ps::<_CMP_LE_OQ>(enter, _mm256_set1_ps(t_max)),
    );
    let mask = _mm256_movemask_ps(entered) as u32;
    let mut entries = [0.0; WIDTH];
    // SAFETY: `entries` holds eight floats.
    unsafe { _mm256_storeu_ps(entries.as_mut_ptr(), enter) };
    (mask & u32::from(n.lanes), entries)
}
