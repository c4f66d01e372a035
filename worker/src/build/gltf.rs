//! glTF assets to render-ready meshes and images. The description crate opens and
//! validates each file (`tessera_description::gltf::Asset`: buffers from the bundle, every
//! index and byte range checked, accessors read with sparse substitutions and normalised
//! integers applied); here each file is opened once per build (so once per scene hash:
//! the worker caches built scenes), its primitives become meshes with their extra
//! attributes, its images are decoded for the roles the scene reads them in, with their
//! sampler's wrap modes. Errors are one line naming the file and the JSON path.

use std::collections::HashMap;

use glam::Vec4;
use tessera_description::bundle::Assets;
use tessera_description::gltf::Asset;

use crate::render::shape::Mesh;
use crate::render::surface::Extras;
use crate::render::texture::{Rgba, Wrap};

/// The glTF files of one build, each opened once.
#[derive(Default)]
pub(super) struct Files {
    read: HashMap<String, Asset>,
}

impl Files {
    /// The asset `file`, opened on first use.
    pub(super) fn get(&mut self, file: &str, assets: &dyn Assets) -> Result<&Asset, String> {
        if !self.read.contains_key(file) {
            let asset = Asset::open(file, assets).map_err(|e| e.to_string())?;
            self.read.insert(file.to_string(), asset);
        }
        Ok(&self.read[file])
    }
}

/// Primitive `primitive` of mesh `mesh` of `asset` as a renderer mesh in the mesh's own
/// space (one index for every attribute, as glTF has it), with its extra attributes
/// (`TEXCOORD_1`, `TANGENT`) when it has any.
pub(super) fn primitive(asset: &Asset, mesh: u32, primitive: u32) -> Result<(Mesh, Option<Extras>), String> {
    let mut g = asset.geometry(mesh, primitive).map_err(|e| e.to_string())?;
    let n = g.normals.take().unwrap_or_default();
    let mut sets = g.texcoords.drain(..);
    let uv = sets.next().unwrap_or_default();
    let uv1 = sets.next().unwrap_or_default();
    let tangents = g.tangents.take().unwrap_or_default();
    let corner =
        |i: u32| [i, if n.is_empty() { u32::MAX } else { i }, if uv.is_empty() { u32::MAX } else { i }];
    let tris = g.triangles.iter().map(|t| [corner(t[0]), corner(t[1]), corner(t[2])]).collect();
    let extras = (!uv1.is_empty() || !tangents.is_empty()).then_some(Extras { uv1, tangents });
    Ok((Mesh { p: g.positions, n, uv, tris }, extras))
}

/// Image `image` of `asset` decoded (stored RGBA values in [0, 1]) for the roles the
/// scene reads it in, with the wrap modes of the first texture that shows it (glTF's
/// samplers belong to textures; the description names images).
pub(super) fn image(
    asset: &Asset,
    image: u32,
    assets: &dyn Assets,
    srgb: bool,
    linear: bool,
) -> Result<Rgba, String> {
    let bytes = asset.image(image, assets).map_err(|e| e.to_string())?;
    let img = super::images::decode_image(&bytes)
        .map_err(|e| format!("{}: images[{image}]: not a readable image: {e}", asset.file))?;
    let rgba = img.to_rgba32f();
    let (w, h) = rgba.dimensions();
    let stored = rgba.into_raw().chunks_exact(4).map(Vec4::from_slice).collect();
    let wrap = |m: gltf::texture::WrappingMode| match m {
        gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
    };
    let wraps = asset
        .document
        .textures()
        .find(|t| t.source().index() == image as usize)
        .map(|t| [wrap(t.sampler().wrap_s()), wrap(t.sampler().wrap_t())])
        .unwrap_or_default();
    Ok(Rgba::new(w, h, wraps, stored, srgb, linear))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    struct One(Vec<u8>);
    impl Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "m.gltf").then_some(self.0.as_slice())
        }
    }

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    fn base64(bytes: &[u8]) -> String {
        const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for c in bytes.chunks(3) {
            let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
            let n = u32::from(b[0]) << 16 | u32::from(b[1]) << 8 | u32::from(b[2]);
            for k in 0..4 {
                out.push(if k <= c.len() { A[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
            }
        }
        out
    }

    /// A non-indexed triangle whose positions a sparse accessor overrides in part, with
    /// two texture coordinate sets: the mesh holds the substituted positions, one
    /// triangle of corners 0, 1, 2, set 0 as its uv and set 1 in its extras.
    #[test]
    fn sparse_unindexed_primitives_with_two_texcoord_sets() {
        let mut bytes = f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        bytes.extend(1u16.to_le_bytes());
        bytes.extend([0, 0]);
        bytes.extend(f32s(&[5.0, 6.0, 7.0]));
        bytes.extend(f32s(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]));
        bytes.extend(f32s(&[0.5, 0.5, 0.25, 0.5, 0.5, 0.25]));
        let json = format!(
            r#"{{"asset": {{"version": "2.0"}},
              "buffers": [{{"byteLength": {len}, "uri": "data:application/octet-stream;base64,{data}"}}],
              "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 36}},
                {{"buffer": 0, "byteOffset": 36, "byteLength": 2}}, {{"buffer": 0, "byteOffset": 40, "byteLength": 12}},
                {{"buffer": 0, "byteOffset": 52, "byteLength": 24}}, {{"buffer": 0, "byteOffset": 76, "byteLength": 24}}],
              "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                "min": [0, 0, 0], "max": [5, 6, 7],
                "sparse": {{"count": 1, "indices": {{"bufferView": 1, "componentType": 5123}},
                           "values": {{"bufferView": 2}}}}}},
                {{"bufferView": 3, "componentType": 5126, "count": 3, "type": "VEC2"}},
                {{"bufferView": 4, "componentType": 5126, "count": 3, "type": "VEC2"}}],
              "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_0": 1, "TEXCOORD_1": 2}}}}]}}]}}"#,
            len = bytes.len(),
            data = base64(&bytes)
        );
        let one = One(json.into_bytes());
        let mut files = Files::default();
        let asset = files.get("m.gltf", &one).unwrap();
        let (mesh, extras) = primitive(asset, 0, 0).unwrap();
        assert_eq!(mesh.p, [Vec3::ZERO, Vec3::new(5.0, 6.0, 7.0), Vec3::Y]);
        assert_eq!(mesh.tris, [[[0, u32::MAX, 0], [1, u32::MAX, 1], [2, u32::MAX, 2]]]);
        assert_eq!(mesh.uv[1], glam::Vec2::X);
        let extras = extras.unwrap();
        assert_eq!(extras.uv1[1], glam::Vec2::new(0.25, 0.5));
        assert!(extras.tangents.is_empty() && mesh.n.is_empty());
        // What does not exist is refused with its JSON path.
        let e = primitive(asset, 3, 0).unwrap_err();
        assert!(e.starts_with("m.gltf: meshes[3]"), "{e}");
    }
}
