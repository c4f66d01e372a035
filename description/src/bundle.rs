//! Scene bundles: a scene file with the assets it references, named by a content hash so
//! that a scene travels once per worker and job and a silently different copy is caught.

use std::fs::{File, OpenOptions};
use std::io::Read;
use std::path::{Path, PathBuf};

pub use crate::assets::{check_asset_path, AssetRefusal, Assets, NoAssets};
pub(crate) use crate::assets::{is_gltf, unreadable};
use crate::limits;

/// A scene file and its assets.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Bundle {
    /// The scene's name for messages (the path it was read from).
    pub name: String,
    /// The scene file's text.
    pub text: String,
    /// Assets by the relative path the scene uses, sorted by path.
    pub assets: Vec<(String, Vec<u8>)>,
    /// Assets the scene names that were not read, with why: for messages only, neither
    /// hashed nor sent.
    pub refused: Vec<(String, AssetRefusal)>,
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
    /// The scene file is a FIFO, a device, a directory or a socket.
    #[error("cannot read scene {path}: it is {kind}, not a regular file")]
    NotRegular {
        /// The file.
        path: PathBuf,
        /// What it is, with its article ("a FIFO").
        kind: &'static str,
    },
    /// The scene file is larger than [`limits::MAX_SCENE_BYTES`].
    #[error("cannot read scene {path}: it is larger than the limit of {limit} bytes ({size} bytes)")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size (at least), in bytes.
        size: u64,
        /// The limit.
        limit: u64,
    },
    /// A glTF file given as the scene is not a usable glTF asset.
    #[error("{0}")]
    Gltf(#[from] crate::gltf::GltfError),
}

/// Why [`read_regular`] read nothing.
enum Unread {
    NotRegular(&'static str),
    TooLarge(u64),
    Io(std::io::Error),
}

impl From<std::io::Error> for Unread {
    fn from(e: std::io::Error) -> Self {
        Unread::Io(e)
    }
}

impl From<Unread> for AssetRefusal {
    fn from(u: Unread) -> Self {
        match u {
            Unread::NotRegular(kind) => AssetRefusal::NotRegular { kind },
            Unread::TooLarge(size) => AssetRefusal::TooLarge { size, limit: limits::MAX_ASSET_BYTES },
            Unread::Io(e) => AssetRefusal::Io(e.to_string()),
        }
    }
}

/// What a file that is not a regular file is, for messages.
fn kind_of(t: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else if t.is_symlink() {
        "a symlink"
    } else {
        "not a file"
    }
}

/// Reads a regular file of at most `limit` bytes. The type and size are checked before it
/// is opened (opening a device can have effects of its own) and again on the open file,
/// which is opened non-blocking so that a FIFO swapped in between cannot hang the open;
/// the read stops at `limit + 1` bytes so that a file growing under us cannot exceed it.
/// With `nofollow`, a symlink swapped in for the last component is refused too.
fn read_regular(path: &Path, limit: u64, nofollow: bool) -> Result<Vec<u8>, Unread> {
    let check = |meta: &std::fs::Metadata| -> Result<(), Unread> {
        if !meta.is_file() {
            return Err(Unread::NotRegular(kind_of(meta.file_type())));
        }
        if meta.len() > limit {
            return Err(Unread::TooLarge(meta.len()));
        }
        Ok(())
    };
    check(&std::fs::metadata(path)?)?;
    let mut options = OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        let follow = if nofollow { libc::O_NOFOLLOW } else { 0 };
        options.custom_flags(libc::O_NONBLOCK | follow);
    }
    let file: File = options.open(path)?;
    let meta = file.metadata()?;
    check(&meta)?;
    let mut data = Vec::with_capacity(meta.len() as usize);
    file.take(limit + 1).read_to_end(&mut data)?;
    if data.len() as u64 > limit {
        return Err(Unread::TooLarge(data.len() as u64));
    }
    Ok(data)
}

/// Reads the asset `rel` (normalised by [`check_asset_path`]) beneath `root`, a
/// canonical folder. The path is resolved with every symlink (`canonicalize`) and must
/// stay beneath `root`: std does this without a new dependency (`cap-std` would also
/// close the race of a folder swapped for a symlink between resolving and opening, which
/// matters against a local attacker racing the client, not against a scene handed to it).
fn read_asset(root: &Path, rel: &str) -> Result<Vec<u8>, AssetRefusal> {
    let resolved = std::fs::canonicalize(root.join(rel)).map_err(|e| AssetRefusal::Io(e.to_string()))?;
    if !resolved.starts_with(root) {
        return Err(AssetRefusal::Outside);
    }
    // The resolved path has no symlinks left: one appearing now is refused, not followed.
    Ok(read_regular(&resolved, limits::MAX_ASSET_BYTES, true)?)
}

impl Bundle {
    /// Reads a scene file and the assets it references (meshes, image textures), by paths
    /// relative to the scene's folder. Only regular files beneath the folder are read (no
    /// symlink out of it, no FIFO or device), each within [`limits::MAX_ASSET_BYTES`] and
    /// the scene within [`limits::MAX_SCENE_BYTES`]. A reference that escapes the folder
    /// or names no readable file is left out here, with why in `refused`; parsing then
    /// reports it with its location.
    ///
    /// A `.gltf` or `.glb` file is a scene too: the bundle's scene is then a generated
    /// TOML text wrapping it as a `[[gltf]]` table (`crate::gltf::wrap`), with its
    /// buffers and images beside it as assets.
    pub fn read(path: &Path) -> Result<Bundle, BundleError> {
        if is_gltf(&path.to_string_lossy()) {
            return Bundle::read_gltf(path);
        }
        let bytes = read_regular(path, limits::MAX_SCENE_BYTES, false).map_err(|u| match u {
            Unread::NotRegular(kind) => BundleError::NotRegular { path: path.to_owned(), kind },
            Unread::TooLarge(size) => {
                BundleError::TooLarge { path: path.to_owned(), size, limit: limits::MAX_SCENE_BYTES }
            }
            Unread::Io(source) => BundleError::Read { path: path.to_owned(), source },
        })?;
        let text = String::from_utf8(bytes).map_err(|_| BundleError::NotText { path: path.to_owned() })?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let root = std::fs::canonicalize(dir);
        let mut assets: Vec<(String, Vec<u8>)> = Vec::new();
        let mut refused: Vec<(String, AssetRefusal)> = Vec::new();
        let mut references = asset_references(&text);
        let mut next = 0;
        while next < references.len() {
            let reference = references[next].clone();
            next += 1;
            let Ok(rel) = check_asset_path(&reference) else { continue };
            if assets.iter().any(|(p, _)| *p == rel) || refused.iter().any(|(p, _)| *p == rel) {
                continue;
            }
            let read = match &root {
                Ok(root) => read_asset(root, &rel),
                Err(e) => Err(AssetRefusal::Io(e.to_string())),
            };
            match read {
                // A glTF asset's buffers and images beside it are assets too (checked like
                // every asset path; `data:` URIs are inside it).
                Ok(data) if is_gltf(&rel) => {
                    references.extend(crate::gltf::external_assets(&rel, &data));
                    assets.push((rel, data));
                }
                Ok(data) => assets.push((rel, data)),
                Err(why) => refused.push((rel, why)),
            }
        }
        assets.sort();
        Ok(Bundle { name: path.display().to_string(), text, assets, refused })
    }

    fn read_gltf(path: &Path) -> Result<Bundle, BundleError> {
        let data = read_regular(path, limits::MAX_ASSET_BYTES, false).map_err(|u| match u {
            Unread::NotRegular(kind) => BundleError::NotRegular { path: path.to_owned(), kind },
            Unread::TooLarge(size) => {
                BundleError::TooLarge { path: path.to_owned(), size, limit: limits::MAX_ASSET_BYTES }
            }
            Unread::Io(source) => BundleError::Read { path: path.to_owned(), source },
        })?;
        let name = path.file_name().map_or_else(|| "model.gltf".into(), |n| n.to_string_lossy().into_owned());
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let root = std::fs::canonicalize(dir);
        let mut bundle =
            Bundle { name: path.display().to_string(), text: String::new(), assets: vec![], refused: vec![] };
        for rel in crate::gltf::external_assets(&name, &data) {
            if bundle.assets.iter().any(|(p, _)| *p == rel) || bundle.refused.iter().any(|(p, _)| *p == rel) {
                continue;
            }
            match root.as_ref().map_err(|e| AssetRefusal::Io(e.to_string())).and_then(|r| read_asset(r, &rel))
            {
                Ok(bytes) => bundle.assets.push((rel, bytes)),
                Err(why) => bundle.refused.push((rel, why)),
            }
        }
        bundle.assets.push((name.clone(), data));
        bundle.assets.sort();
        bundle.text = crate::gltf::wrap::scene_text(&name, &bundle)?;
        Ok(bundle)
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

    fn refusal(&self, path: &str) -> Option<&AssetRefusal> {
        let rel = check_asset_path(path).ok()?;
        self.refused.iter().find(|(p, _)| *p == rel).map(|(_, why)| why)
    }
}

/// The asset paths a scene text names: `file` of every mesh, texture and glTF asset. A
/// text that is not valid TOML names none (parsing reports the syntax error).
pub(crate) fn asset_references(text: &str) -> Vec<String> {
    let Ok(table) = text.parse::<toml::Table>() else { return Vec::new() };
    let mut out = Vec::new();
    let file_of = |v: &toml::Value| v.get("file").and_then(|f| f.as_str()).map(str::to_string);
    if let Some(meshes) = table.get("mesh").and_then(|m| m.as_array()) {
        out.extend(meshes.iter().filter_map(file_of));
    }
    if let Some(models) = table.get("gltf").and_then(|m| m.as_array()) {
        out.extend(models.iter().filter_map(file_of));
    }
    if let Some(textures) = table.get("textures").and_then(|t| t.as_table()) {
        out.extend(textures.values().filter_map(file_of));
    }
    if let Some(environment) = table.get("environment") {
        out.extend(file_of(environment));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_names_content_not_path() {
        let a = Bundle { name: "a.toml".into(), text: "x".into(), assets: vec![], refused: vec![] };
        let b = Bundle { name: "b.toml".into(), ..a.clone() };
        let c = Bundle { text: "y".into(), ..a.clone() };
        assert_eq!(a.hash(), b.hash());
        assert_ne!(a.hash(), c.hash());
        let d = Bundle { assets: vec![("m.obj".into(), b"v".to_vec())], ..a.clone() };
        assert_ne!(a.hash(), d.hash());
    }

    /// A scene in a fresh folder naming the mesh `m.obj`.
    fn scene() -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("s.toml");
        let text = "[render]\nwidth = 4\nheight = 4\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n\
                    [materials.red]\ncolor = 1\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n";
        std::fs::write(&scene, text).unwrap();
        (dir, scene)
    }

    /// Reads the scene, parses it and returns the one-line error about `m.obj`.
    fn refusal(scene: &Path) -> String {
        let started = std::time::Instant::now();
        let bundle = Bundle::read(scene).unwrap();
        assert!(
            started.elapsed() < std::time::Duration::from_secs(5),
            "reading took {:?}",
            started.elapsed()
        );
        assert!(bundle.assets.is_empty(), "{:?}", bundle.assets.iter().map(|a| &a.0).collect::<Vec<_>>());
        let e = crate::Description::parse(&bundle).unwrap_err().to_string();
        assert!(!e.contains('\n'), "{e}");
        assert!(e.starts_with(&format!("{}:9:1: mesh.file: cannot read \"m.obj\"", scene.display())), "{e}");
        e
    }

    #[test]
    fn a_symlink_out_of_the_folder_is_refused_and_nothing_outside_is_quoted() {
        let (dir, scene) = scene();
        let outside = tempfile::tempdir().unwrap();
        let secret = outside.path().join("secret.obj");
        std::fs::write(&secret, "root:x:0:0:root:/root:/bin/bash\n").unwrap();
        std::os::unix::fs::symlink(&secret, dir.path().join("m.obj")).unwrap();
        let e = refusal(&scene);
        assert!(e.ends_with(
            "it leads outside the scene's folder (through a symlink); assets must lie beneath it"
        ));
        assert!(!e.contains("root:x"), "{e}");
        // A folder inside that is a symlink out of it is refused the same way.
        std::fs::remove_file(dir.path().join("m.obj")).unwrap();
        std::os::unix::fs::symlink(outside.path(), dir.path().join("sub")).unwrap();
        std::fs::write(&scene, std::fs::read_to_string(&scene).unwrap().replace("m.obj", "sub/secret.obj"))
            .unwrap();
        let bundle = Bundle::read(&scene).unwrap();
        assert!(bundle.assets.is_empty());
        assert_eq!(bundle.refused, vec![("sub/secret.obj".to_string(), AssetRefusal::Outside)]);
    }

    #[test]
    fn a_symlink_inside_the_folder_is_followed() {
        let (dir, scene) = scene();
        std::fs::create_dir(dir.path().join("meshes")).unwrap();
        std::fs::write(dir.path().join("meshes/tri.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        std::os::unix::fs::symlink("meshes/tri.obj", dir.path().join("m.obj")).unwrap();
        let bundle = Bundle::read(&scene).unwrap();
        assert_eq!(bundle.assets.len(), 1);
        crate::Description::parse(&bundle).unwrap();
    }

    #[test]
    fn a_symlink_to_dev_zero_is_refused_without_reading_it() {
        let (dir, scene) = scene();
        std::os::unix::fs::symlink("/dev/zero", dir.path().join("m.obj")).unwrap();
        assert!(refusal(&scene).ends_with(
            "it leads outside the scene's folder (through a symlink); assets must lie beneath it"
        ));
    }

    #[test]
    fn a_fifo_is_refused_at_once() {
        let (dir, scene) = scene();
        let fifo = dir.path().join("m.obj");
        match std::process::Command::new("mkfifo").arg(&fifo).status() {
            Ok(s) if s.success() => {}
            other => {
                eprintln!("skipped: mkfifo is not available ({other:?})");
                return;
            }
        }
        assert!(refusal(&scene).ends_with("cannot read \"m.obj\": it is a FIFO, not a regular file"));
    }

    #[test]
    fn a_fifo_opened_is_refused_without_hanging() {
        // The check after opening: a FIFO swapped in after the first check must not hang.
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("m.obj");
        match std::process::Command::new("mkfifo").arg(&fifo).status() {
            Ok(s) if s.success() => {}
            other => {
                eprintln!("skipped: mkfifo is not available ({other:?})");
                return;
            }
        }
        let mut options = OpenOptions::new();
        std::os::unix::fs::OpenOptionsExt::custom_flags(options.read(true), libc::O_NONBLOCK);
        let file = options.open(&fifo).unwrap();
        assert!(!file.metadata().unwrap().is_file());
    }

    #[test]
    fn a_directory_named_like_a_mesh_is_refused() {
        let (dir, scene) = scene();
        std::fs::create_dir(dir.path().join("m.obj")).unwrap();
        assert!(refusal(&scene).ends_with("cannot read \"m.obj\": it is a directory, not a regular file"));
    }

    #[test]
    fn an_oversized_asset_is_refused_before_reading() {
        let (dir, scene) = scene();
        // Sparse: no disk space taken, and a read of it would take seconds and a gigabyte.
        let f = File::create(dir.path().join("m.obj")).unwrap();
        f.set_len(limits::MAX_ASSET_BYTES + 1).unwrap();
        let e = refusal(&scene);
        assert!(e.ends_with("it is larger than the limit of 1073741824 bytes (1073741825 bytes)"), "{e}");
    }

    #[test]
    fn a_missing_asset_says_why() {
        let (_dir, scene) = scene();
        assert!(refusal(&scene)
            .ends_with("(relative to the scene's folder): No such file or directory (os error 2)"));
    }

    #[test]
    fn the_scene_file_itself_is_checked() {
        let (dir, scene) = scene();
        let e = Bundle::read(dir.path()).unwrap_err().to_string();
        assert!(e.ends_with("it is a directory, not a regular file"), "{e}");
        File::options().write(true).open(&scene).unwrap().set_len(limits::MAX_SCENE_BYTES + 1).unwrap();
        let e = Bundle::read(&scene).unwrap_err().to_string();
        assert!(e.contains("larger than the limit of 16777216 bytes"), "{e}");
        assert!(matches!(
            Bundle::read(Path::new("/dev/null")),
            Err(BundleError::NotRegular { kind: "a device", .. })
        ));
    }
}
