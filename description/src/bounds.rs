//! Sizes checked before anything is parsed or kept: the scene file's name, length and
//! longest line, the bundle's total and its asset paths, and that every asset it carries is
//! one the scene uses. Each refusal is one line naming what and where, and never quotes
//! more than [`MAX_QUOTED`] bytes of a name, so that a 60 MB name cannot make a 60 MB error.

use std::collections::BTreeSet;

use crate::bundle::check_asset_path;
use crate::limits::{MAX_BUNDLE_BYTES, MAX_LINE_BYTES, MAX_NAME_BYTES, MAX_SCENE_BYTES};
use crate::model::{Description, Shape, TextureKind};
use crate::{Bundle, SceneError};

/// The most bytes of a name an error message quotes.
pub const MAX_QUOTED: usize = 80;

/// `name`, cut to at most [`MAX_QUOTED`] bytes (at a character boundary) with `…` and its
/// full length when cut: safe to put in a message.
pub fn quoted(name: &str) -> String {
    if name.len() <= MAX_QUOTED {
        return format!("{name:?}");
    }
    let mut end = MAX_QUOTED;
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    format!("{:?}… ({} bytes)", &name[..end], name.len())
}

/// A scene name fit for messages: the name itself, or its start when it is too long.
fn shown(file: &str) -> String {
    if file.len() <= MAX_NAME_BYTES {
        file.to_string()
    } else {
        quoted(file)
    }
}

fn at_start(file: &str, message: String) -> SceneError {
    SceneError { file: shown(file), line: 1, column: 1, message }
}

/// Checks a scene text's size and line lengths before it is parsed.
pub(crate) fn check_text(file: &str, text: &str) -> Result<(), SceneError> {
    if file.len() > MAX_NAME_BYTES {
        return Err(at_start(
            file,
            format!("the scene's name is {} bytes, more than the limit of {MAX_NAME_BYTES}", file.len()),
        ));
    }
    if text.len() as u64 > MAX_SCENE_BYTES {
        return Err(at_start(
            file,
            format!(
                "the scene file is {} bytes, more than the limit of {MAX_SCENE_BYTES}; put geometry in mesh files",
                text.len()
            ),
        ));
    }
    if let Some((i, line)) = text.split('\n').enumerate().find(|(_, l)| l.len() > MAX_LINE_BYTES) {
        return Err(SceneError {
            file: file.to_string(),
            line: i + 1,
            column: 1,
            message: format!("the line is {} bytes, more than the limit of {MAX_LINE_BYTES}", line.len()),
        });
    }
    Ok(())
}

/// Checks a bundle's total size and asset paths before its scene is parsed.
pub(crate) fn check_bundle(bundle: &Bundle) -> Result<(), SceneError> {
    check_text(&bundle.name, &bundle.text)?;
    let mut total = bundle.text.len() as u64;
    if bundle.assets.len() > crate::limits::MAX_ASSETS {
        return Err(at_start(
            &bundle.name,
            format!(
                "the bundle carries {} assets, more than the limit of {}",
                bundle.assets.len(),
                crate::limits::MAX_ASSETS
            ),
        ));
    }
    let mut seen = std::collections::HashSet::with_capacity(bundle.assets.len());
    for (path, data) in bundle.assets.iter() {
        if path.len() > MAX_NAME_BYTES {
            return Err(at_start(
                &bundle.name,
                format!(
                    "the bundle's asset path {} is {} bytes, more than the limit of {MAX_NAME_BYTES}",
                    quoted(path),
                    path.len()
                ),
            ));
        }
        // A set, not a scan of those before: a bundle of many short paths must not cost
        // quadratic time.
        if !seen.insert(path.as_str()) {
            return Err(at_start(&bundle.name, format!("the bundle carries asset {} twice", quoted(path))));
        }
        total += (path.len() + data.len()) as u64;
    }
    if total > MAX_BUNDLE_BYTES {
        return Err(at_start(
            &bundle.name,
            format!(
                "the bundle is {total} bytes (scene and assets), more than the limit of {MAX_BUNDLE_BYTES}"
            ),
        ));
    }
    Ok(())
}

/// Refuses assets the scene does not use: they would be held by the coordinator, stored
/// and sent to every worker for nothing.
pub(crate) fn check_referenced(bundle: &Bundle, desc: &Description) -> Result<(), SceneError> {
    let mut used = BTreeSet::new();
    for o in &desc.objects {
        if let Shape::Mesh { file, .. } = &o.shape {
            used.insert(file.as_str());
        }
    }
    for t in &desc.textures {
        if let TextureKind::Image { file, .. } = &t.kind {
            used.insert(file.as_str());
        }
    }
    // `[[gltf]]` assets (used even when they hold no mesh) and their buffers and images.
    let mut gltf = Vec::new();
    for reference in crate::bundle::asset_references(&bundle.text) {
        if let (Ok(path), true) = (check_asset_path(&reference), crate::bundle::is_gltf(&reference)) {
            if let Some(bytes) = crate::bundle::Assets::get(bundle, &path) {
                gltf.extend(crate::gltf::external_assets(&path, bytes));
            }
            gltf.push(path);
        }
    }
    used.extend(gltf.iter().map(String::as_str));
    if let Some(crate::model::Environment { kind: crate::model::EnvironmentKind::Map { file, .. }, .. }) =
        &desc.environment
    {
        used.insert(file.as_str());
    }
    let unused: Vec<String> = bundle
        .assets
        .iter()
        .map(|(p, _)| p)
        .filter(|p| check_asset_path(p).map_or(true, |n| !used.contains(n.as_str())))
        .take(5)
        .map(|p| quoted(p))
        .collect();
    if unused.is_empty() {
        return Ok(());
    }
    let more = bundle.assets.len().saturating_sub(used.len()).saturating_sub(unused.len());
    let more = if more > 0 { format!(" and {more} more") } else { String::new() };
    Err(at_start(
        &bundle.name,
        format!("the bundle carries assets the scene does not use: {}{more}", unused.join(", ")),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENE: &str = "[render]\nwidth = 8\nheight = 6\nspp = 1\n\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n\n[materials.red]\ncolor = [1, 0, 0]\n";

    fn bundle(text: &str, assets: Vec<(String, Vec<u8>)>) -> Bundle {
        Bundle { name: "s.toml".into(), text: text.into(), assets, refused: vec![] }
    }

    fn refused(b: &Bundle) -> String {
        Description::parse(b).unwrap_err().to_string()
    }

    #[test]
    fn a_scene_over_the_size_limit_is_refused_before_parsing() {
        // Not TOML at all: were it parsed, the error would be a syntax error.
        let text = "x".repeat(MAX_SCENE_BYTES as usize + 1);
        let e = refused(&bundle(&text, vec![]));
        assert_eq!(e, format!("s.toml:1:1: the scene file is {} bytes, more than the limit of {MAX_SCENE_BYTES}; put geometry in mesh files", text.len()));
    }

    #[test]
    fn a_long_line_is_refused_with_its_line() {
        let text = format!("{SCENE}# {}\n", "x".repeat(MAX_LINE_BYTES));
        let e = refused(&bundle(&text, vec![]));
        assert!(e.starts_with("s.toml:12:1: the line is 65538 bytes, more than the limit of 65536"), "{e}");
    }

    #[test]
    fn a_huge_name_is_refused_and_not_repeated() {
        let b = Bundle { name: "n".repeat(60 << 20), ..bundle(SCENE, vec![]) };
        let e = refused(&b);
        assert!(e.len() < 300, "{} bytes", e.len());
        assert!(e.contains("the scene's name is 62914560 bytes, more than the limit of 1024"), "{e}");
    }

    #[test]
    fn unreferenced_duplicate_and_long_assets_are_refused() {
        let e = refused(&bundle(SCENE, vec![("junk.bin".into(), vec![0; 100])]));
        assert_eq!(e, "s.toml:1:1: the bundle carries assets the scene does not use: \"junk.bin\"");
        let e = refused(&bundle(SCENE, vec![("a".into(), vec![]), ("a".into(), vec![])]));
        assert_eq!(e, "s.toml:1:1: the bundle carries asset \"a\" twice");
        let long = "p/".repeat(MAX_NAME_BYTES);
        let e = refused(&bundle(SCENE, vec![(long, vec![])]));
        assert!(
            e.contains("asset path \"p/p/")
                && e.contains("(2048 bytes) is 2048 bytes, more than the limit of 1024"),
            "{e}"
        );
        assert!(e.len() < 300);
    }

    #[test]
    fn a_bundle_over_its_total_is_refused() {
        let big = vec![0u8; (MAX_BUNDLE_BYTES / 2) as usize];
        let e = refused(&bundle(SCENE, vec![("a.obj".into(), big.clone()), ("b.obj".into(), big)]));
        assert!(e.starts_with("s.toml:1:1: the bundle is 2684"), "{e}");
        assert!(e.ends_with("bytes (scene and assets), more than the limit of 268435456"), "{e}");
    }

    #[test]
    fn quoting_cuts_at_a_character_boundary() {
        assert_eq!(quoted("ab"), "\"ab\"");
        let s = "é".repeat(100);
        let q = quoted(&s);
        assert!(q.ends_with("… (200 bytes)") && q.len() < 100, "{q}");
    }
}
