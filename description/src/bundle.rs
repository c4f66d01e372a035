//! Scene bundles: a scene file with the assets it references, named by a content hash so
//! that a scene travels once per worker and job and a silently different copy is caught.

use std::path::{Path, PathBuf};

/// A scene file and its assets.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Bundle {
    /// The scene's name for messages (the path it was read from).
    pub name: String,
    /// The scene file's text.
    pub text: String,
    /// Assets by the relative path the scene uses, sorted by path.
    pub assets: Vec<(String, Vec<u8>)>,
}

/// Why a bundle could not be read.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    /// The scene file could not be read.
    #[error("cannot read scene {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The scene file is not UTF-8 text.
    #[error("scene {path} is not UTF-8 text")]
    NotText {
        /// The file.
        path: PathBuf,
    },
}

impl Bundle {
    /// Reads a scene file and the assets it references (meshes, image textures), by paths
    /// relative to the scene's folder. A reference that escapes the folder or names no
    /// readable file is left out here; parsing then reports it with its location.
    pub fn read(path: &Path) -> Result<Bundle, BundleError> {
        let bytes =
            std::fs::read(path).map_err(|source| BundleError::Read { path: path.to_owned(), source })?;
        let text = String::from_utf8(bytes).map_err(|_| BundleError::NotText { path: path.to_owned() })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut assets: Vec<(String, Vec<u8>)> = Vec::new();
        for reference in asset_references(&text) {
            let Ok(rel) = check_asset_path(&reference) else { continue };
            if assets.iter().any(|(p, _)| *p == rel) {
                continue;
            }
            if let Ok(data) = std::fs::read(dir.join(&rel)) {
                assets.push((rel, data));
            }
        }
        assets.sort();
        Ok(Bundle { name: path.display().to_string(), text, assets })
    }

    /// The content hash: blake3 over the text and every asset, each length-prefixed so
    /// that no two different bundles frame the same bytes. The name is not hashed: the
    /// same scene from another path is the same scene.
    pub fn hash(&self) -> String {
        let mut h = blake3::Hasher::new();
        h.update(b"tessera-scene-v1\0");
        h.update(&(self.text.len() as u64).to_le_bytes());
        h.update(self.text.as_bytes());
        for (path, data) in &self.assets {
            h.update(&(path.len() as u64).to_le_bytes());
            h.update(path.as_bytes());
            h.update(&(data.len() as u64).to_le_bytes());
            h.update(data);
        }
        h.finalize().to_hex().to_string()
    }
}

impl Assets for Bundle {
    fn get(&self, path: &str) -> Option<&[u8]> {
        let rel = check_asset_path(path).ok()?;
        self.assets.binary_search_by(|(p, _)| p.as_str().cmp(&rel)).ok().map(|i| self.assets[i].1.as_slice())
    }
}

/// Where a scene's assets (meshes, images) come from: by the relative path the scene
/// uses. A bundle provides them, so workers never touch their file system.
pub trait Assets {
    /// The bytes of the asset at `path`, if the bundle has it.
    fn get(&self, path: &str) -> Option<&[u8]>;
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

/// The asset paths a scene text names: `file` of every mesh and texture. A text that is
/// not valid TOML names none (parsing reports the syntax error).
fn asset_references(text: &str) -> Vec<String> {
    let Ok(table) = text.parse::<toml::Table>() else { return Vec::new() };
    let mut out = Vec::new();
    let file_of = |v: &toml::Value| v.get("file").and_then(|f| f.as_str()).map(str::to_string);
    if let Some(meshes) = table.get("mesh").and_then(|m| m.as_array()) {
        out.extend(meshes.iter().filter_map(file_of));
    }
    if let Some(textures) = table.get("textures").and_then(|t| t.as_table()) {
        out.extend(textures.values().filter_map(file_of));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_names_content_not_path() {
        let a = Bundle { name: "a.toml".into(), text: "x".into(), assets: vec![] };
        let b = Bundle { name: "b.toml".into(), ..a.clone() };
        let c = Bundle { text: "y".into(), ..a.clone() };
        assert_eq!(a.hash(), b.hash());
        assert_ne!(a.hash(), c.hash());
        let d = Bundle { assets: vec![("m.obj".into(), b"v".to_vec())], ..a.clone() };
        assert_ne!(a.hash(), d.hash());
    }
}
