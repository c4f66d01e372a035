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
    /// Reads a scene file (and, once the format references assets, those assets).
    pub fn read(path: &Path) -> Result<Bundle, BundleError> {
        let bytes =
            std::fs::read(path).map_err(|source| BundleError::Read { path: path.to_owned(), source })?;
        let text = String::from_utf8(bytes).map_err(|_| BundleError::NotText { path: path.to_owned() })?;
        Ok(Bundle { name: path.display().to_string(), text, assets: Vec::new() })
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

    /// Parses the scene.
    pub fn parse(&self) -> Result<crate::render::Scene, crate::scene::SceneError> {
        crate::scene::parse_scene(&self.name, &self.text)
    }
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
