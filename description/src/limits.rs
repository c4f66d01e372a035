//! Limits that keep a hostile scene from exhausting a worker or the coordinator.

/// The longest image side, in pixels.
pub const MAX_SIDE: u32 = 65_536;
/// The most pixels an image may have (256 Mpixel).
pub const MAX_PIXELS: u64 = 1 << 28;
/// The most samples per pixel.
pub const MAX_SPP: u32 = 1 << 20;
/// The most path segments / classic recursion depth.
pub const MAX_DEPTH: u32 = 64;
/// The most triangles in a scene.
pub const MAX_TRIANGLES: usize = 1 << 26;
