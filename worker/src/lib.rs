//! Tessera's worker: the distributed ray tracer and the loop that takes batches from a
//! coordinator and returns per-pixel sample sums.
// Denied, not forbidden: the exceptions are the BVH's AVX2 box test (`render/bvh/avx.rs`)
// and the sampler's AVX-512 fill (`render/sampler_avx512.rs`), whose target-feature
// functions can only be called in `unsafe`, after the CPU check.
#![deny(unsafe_code)]
#![deny(missing_docs)]
// `!(x > 0.0)` is how this crate rejects NaN along with the values out of range.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod ab;
pub mod aov;
mod aov_tests;
pub mod batch;
pub mod build;
pub mod client;
pub mod render;

/// The renderer's build. Workers and coordinators refuse each other when it differs, since
/// images are only bit-identical when every worker runs the same renderer.
pub const RENDERER_VERSION: &str = tessera_description::RENDERER_VERSION;
