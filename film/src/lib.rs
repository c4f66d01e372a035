//! Tessera's film: the fixed-point representation of radiance, the framebuffer of
//! per-pixel sums that the coordinator merges into and every viewer replicates, and the
//! paper's quadrant order with the mosaic it paints. Shared by the coordinator, the
//! worker (which writes fixed-point sums) and the viewer; no renderer and no I/O.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod aov;
pub mod exr_layers;
pub mod fixed;
pub mod framebuffer;
pub mod output;
pub mod preview;
pub mod quadtree;

pub use framebuffer::{Framebuffer, MergeError, PixelState};
pub use quadtree::Quad;
