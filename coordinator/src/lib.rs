//! Tessera's coordinator: holds jobs, walks the progressive-refinement order, cuts it into
//! batches, leases them to workers, and merges results into each job's framebuffer.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod checkpoint;
pub mod farm;
pub mod frames;
pub mod metrics;
pub mod persist;
pub mod scheduler;
pub mod service;
pub mod store;

pub use service::{
    Auth, CoordinatorService, Principal, Recovery, Role, SubmitFailure, Timing, Tokens, DEFAULT_MAX_PRIORITY,
};
