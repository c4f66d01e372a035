//! Where a scene's assets come from and what a path to one may be: the trait the
//! validator, the glTF reader and the renderer read assets through, and the path rules.
//! Apart from `bundle.rs`, which reads bundles from disk, so that the glTF reader (which
//! the bundle uses to find a glTF asset's own files) does not depend on the bundle.

/// Why an asset a scene names was not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AssetRefusal {
    /// It resolves (through a symlink) to a file outside the scene's folder.
    #[error("it leads outside the scene's folder (through a symlink); assets must lie beneath it")]
    Outside,
    /// It is a FIFO, a device, a directory or a socket.
    #[error("it is {kind}, not a regular file")]
    NotRegular {
        /// What it is, with its article ("a FIFO").
        kind: &'static str,
    },
    /// It is larger than [`limits::MAX_ASSET_BYTES`].
    #[error("it is larger than the limit of {limit} bytes ({size} bytes)")]
    TooLarge {
        /// Its size (at least), in bytes.
        size: u64,
        /// The limit.
        limit: u64,
    },
    /// It cannot be opened or read (missing, permissions).
    #[error("{0}")]
    Io(String),
}

/// Where a scene's assets (meshes, images) come from: by the relative path the scene
/// uses. A bundle provides them, so workers never touch their file system.
pub trait Assets {
    /// The bytes of the asset at `path`, if the bundle has it.
    fn get(&self, path: &str) -> Option<&[u8]>;

    /// Why the asset at `path` is missing, if that is known.
    fn refusal(&self, _path: &str) -> Option<&AssetRefusal> {
        None
    }
}

/// The message for an asset `file` (as the scene writes it) that `assets` lacks.
pub(crate) fn unreadable(assets: &dyn Assets, what: &str, file: &str) -> String {
    match assets.refusal(file) {
        Some(AssetRefusal::Io(e)) => {
            format!("{what}: cannot read {file:?} (relative to the scene's folder): {e}")
        }
        Some(why) => format!("{what}: cannot read {file:?}: {why}"),
        None => format!("{what}: cannot read {file:?} (relative to the scene's folder)"),
    }
}

/// No assets at all.
pub struct NoAssets;

impl Assets for NoAssets {
    fn get(&self, _: &str) -> Option<&[u8]> {
        None
    }
}

/// Checks that an asset path stays inside the scene's folder: relative, and never
/// climbing above its start. Returns the normalised path.
pub fn check_asset_path(path: &str) -> Result<String, String> {
    if path.is_empty() {
        return Err("asset path is empty".into());
    }
    let p = std::path::Path::new(path);
    if p.is_absolute() || path.starts_with('/') || path.starts_with('\\') || path.contains(':') {
        return Err(format!("asset path {path:?} must be relative to the scene's folder"));
    }
    let mut parts: Vec<&str> = Vec::new();
    for c in path.split(['/', '\\']) {
        match c {
            "" | "." => {}
            ".." => {
                if parts.pop().is_none() {
                    return Err(format!("asset path {path:?} escapes the scene's folder"));
                }
            }
            c => parts.push(c),
        }
    }
    Ok(parts.join("/"))
}

/// Whether an asset path names a glTF file (`.gltf` or `.glb`).
pub(crate) fn is_gltf(path: &str) -> bool {
    let lower = path.to_ascii_lowercase();
    lower.ends_with(".gltf") || lower.ends_with(".glb")
}
