//! Tessera's scene description: what a job is, without the renderer. The scene format,
//! bundles (a scene file with its assets) and their content hashes, the limits a scene
//! must keep, the settings a submission may override, and the typed ids of the farm.
//!
//! The coordinator, the viewer and the CLI's client side depend on this crate and on the
//! wire contract, never on the renderer: nothing here builds geometry or decodes images.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod bundle;
pub mod error;
pub mod ids;
pub mod job;
pub mod limits;

/// The renderer's build: what, with a description, fixes an image's bits. Workers and
/// coordinators refuse each other when it differs, since images are only bit-identical
/// when every worker runs the same renderer.
pub const RENDERER_VERSION: &str = env!("CARGO_PKG_VERSION");

pub use bundle::Bundle;
pub use error::SceneError;
pub use ids::{BatchId, JobId, WorkerId};
pub use job::{JobSettings, JobState};
