//! Limits that keep a hostile scene from exhausting a worker or the coordinator.

/// The longest image side, in pixels.
pub const MAX_SIDE: u32 = 65_536;
/// The most pixels an image may have (256 Mpixel).
pub const MAX_PIXELS: u64 = 1 << 28;
/// The most samples per pixel.
pub const MAX_SPP: u32 = 1 << 20;
/// The most path segments / classic recursion depth.
pub const MAX_DEPTH: u32 = 64;
/// The most rays a diffuse lobe sends a sample ([`crate::model::RenderSettings`]): each
/// is a ray and a sampler dimension per sample, so a sample costs at most this many times
/// Cook's.
pub const MAX_DIFFUSE_RAYS: u32 = 256;
/// The most triangles in a scene.
pub const MAX_TRIANGLES: usize = 1 << 26;
/// The largest scene file, in bytes (16 MiB): scene text is small; meshes and images are
/// assets. Checked before parsing, since the TOML parser needs about 7 bytes of memory per
/// byte of text (~115 MB at this limit).
pub const MAX_SCENE_BYTES: u64 = 16 << 20;
/// The longest line of a scene file, in bytes: no legal value needs more.
pub const MAX_LINE_BYTES: usize = 64 << 10;
/// The most corners of one OBJ face (each fan-triangulated into a triangle).
pub const MAX_FACE_CORNERS: usize = 4096;
/// The most pixels of one image texture (8192 × 8192): a worker holds ~28 bytes a texel
/// at the peak of decoding, ~1.9 GB at this limit.
pub const MAX_TEXTURE_PIXELS: u64 = 1 << 26;
/// The largest asset (mesh or image) a scene may reference, in bytes (1 GiB): the whole
/// bundle is held in memory by the client, the coordinator and every worker.
pub const MAX_ASSET_BYTES: u64 = 1 << 30;
/// The farthest from the origin a placed object may reach in world space: products of two
/// coordinates (cross products, squared lengths) then stay finite in `f32`.
pub const MAX_COORDINATE: f64 = 1e18;
/// The longest name (a scene's file name, a worker's name, an asset's path, an object's or
/// material's name), in bytes: names travel in every `Status` and viewer update.
pub const MAX_NAME_BYTES: usize = 1024;
/// The largest bundle (scene text and every asset), in bytes: the client, the coordinator
/// and every worker hold it whole, and it travels in one message.
pub const MAX_BUNDLE_BYTES: u64 = 256 << 20;
/// What a message carrying a bundle may hold beyond it (settings, ids, names, framing).
pub const BUNDLE_MESSAGE_SLACK: u64 = 1 << 20;

/// The most assets a bundle may carry. Far beyond any scene's meshes and textures; it
/// bounds what decoding a bundle of tiny or empty assets costs (about 50 bytes each in
/// memory against 2 on the wire), checked on the wire before decoding.
pub const MAX_ASSETS: usize = 65_536;
/// The most frames an animated scene may declare: each frame is a job's worth of work,
/// and the coordinator keeps state per frame.
pub const MAX_FRAMES: u32 = 100_000;
