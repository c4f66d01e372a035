//! Tessera's scene description: what a job is, without the renderer. The scene format,
//! bundles (a scene file with its assets) and their content hashes, the limits a scene
//! must keep, the settings a submission may override, and the typed ids of the farm.
//!
//! The coordinator, the viewer and the CLI's client side depend on this crate and on the
//! wire contract, never on the renderer: nothing here builds geometry or decodes images.
//! [`Description::parse`] turns a bundle into a validated [`Description`] (errors name the
//! file, line and column), and [`Description::summary`] says what rendering it will cost.
#![forbid(unsafe_code)]
#![deny(missing_docs)]
// `!(x > 0.0)` is how this crate rejects NaN along with the values out of range.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod animation;
mod assets;
pub mod bounds;
pub mod bundle;
mod ctx;
pub mod error;
pub mod gltf;
mod gltf_table;
pub mod ids;
pub mod job;
mod keyframes;
mod lights;
pub mod limits;
pub mod machine;
mod materials;
pub mod math;
pub mod model;
pub mod obj;
mod objects;
mod schema;
pub mod summary;
pub mod transform;
mod validate;

#[cfg(test)]
mod tests;

/// The renderer's build: what, with a description, fixes an image's bits. Workers and
/// coordinators refuse each other when it differs, since images are only bit-identical
/// when every worker runs the same renderer. The crate's version stays put while images
/// change, so a suffix counts the renderer changes that changed them: `images.8` places
/// each point of Cook's pattern uniformly over the pixel, where the fine-grid offsets of
/// a cell's column and row were shuffled alike and a permutation of a length that is not
/// a power of two favoured some places (docs/speed.md, twenty-ninth part: every
/// stratified image changed; a daylight scene had come out 0.5 % too bright at 4 spp),
/// `images.7` tests a
/// moving mesh as one object with a tree of its own in object space, so rays meet its
/// triangles, and the scene's other primitives, in another order (docs/speed.md,
/// twenty-eighth part: one pixel of `showcase` at 320×180×16 changed, by 6·10⁻⁸; none at
/// 480×270×64, nor the tiny golden renders), `images.6` bounds a
/// moving primitive by its path over the whole shutter, not by its two ends, which a
/// turning mesh's triangles strayed out of mid-shutter (docs/speed.md, twenty-seventh part:
/// 25 pixels of `showcase` at 480×270×64 changed; the tiny golden renders did not),
/// `images.5` lets a
/// shadow ray towards a sphere or parallelogram light pass over that light's own surface,
/// which rounding made block a grazing ray now and then (docs/speed.md, twenty-fourth
/// part: three pixels of `mesh` and `showcase` at 320×240×16 changed, by 0.4 % at most;
/// the tiny golden renders did not), `images.4` builds
/// meshes' BVH leaves in blocks of four triangles tested at once (docs/speed.md, sixteenth
/// part), which changes the order rays meet triangles in, and with it which of two
/// triangles at one distance a ray takes (the terrain at 320×240×64 changed; the tiny
/// golden renders did not), `images.3` orders Sobol's pattern by a nested scramble and draws jobs in rounds from it (docs/accuracy.md;
/// scenes of `sampler = "sobol"` changed at every count too), `images.2` is the
/// camera's 4-D pattern and glass followed both ways (docs/speed.md, fourteenth part), and
/// every build before them is `images.1` in effect, though it said only `0.1.0`.
/// `worker/tests/golden.rs` fails when the tiny renders of every scene change and this
/// does not, so two builds that render differently cannot join one farm.
pub const RENDERER_VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), "+images.8");

pub use bundle::{AssetRefusal, Assets, Bundle, NoAssets};
pub use error::SceneError;
pub use ids::{BatchId, JobId, WorkerId};
pub use job::{Aovs, JobSettings, JobState, Noise};
pub use model::Description;
pub use summary::Summary;
