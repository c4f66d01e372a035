//! glTF assets to render-ready meshes and images: each file read once per build (so once
//! per scene hash, the worker caching built scenes), its primitives' accessors read with
//! the `gltf` crate (indexed or not, sparse accessors applied), its images decoded with
//! their sampler's wrap modes. The description validated every index; what can still fail
//! is only what its checks could not see (damaged buffers or image pixels, assets that
//! changed since), each with one line naming the file and the JSON path.

use std::collections::HashMap;

use glam::{Vec2, Vec3, Vec4};
use gltf::image::Source as ImageSource;
use tessera_description::bundle::{check_asset_path, Assets};

use crate::render::shape::Mesh;
use crate::render::surface::Extras;
use crate::render::texture::{Rgba, Wrap};

/// A parsed glTF file with its buffers' bytes.
pub(super) struct Asset {
    doc: gltf::Document,
    buffers: Vec<Vec<u8>>,
    /// The normalised path of the file, for messages and relative URIs.
    file: String,
}

/// The files of one build, each read once.
#[derive(Default)]
pub(super) struct Files {
    read: HashMap<String, Asset>,
}

/// The path of `uri` (percent-encoded, relative to the glTF file `file`) in the bundle.
fn resolve(file: &str, uri: &str) -> Result<String, String> {
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| format!("URI {uri:?} is not UTF-8 once decoded"))?;
    let dir = file.rsplit_once('/').map_or("", |(d, _)| d);
    let joined = if dir.is_empty() { decoded.to_string() } else { format!("{dir}/{decoded}") };
    check_asset_path(&joined)
}

/// The bytes a URI names: a `data:` URI's payload, or the bundle's asset.
fn uri_bytes(file: &str, uri: &str, assets: &dyn Assets) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) =
            rest.split_once(";base64,").ok_or_else(|| "a data: URI that is not base64".to_string())?;
        use base64::Engine;
        return base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| format!("its base64 data is damaged: {e}"));
    }
    let path = resolve(file, uri)?;
    assets
        .get(&path)
        .map(<[u8]>::to_vec)
        .ok_or_else(|| format!("cannot read {path:?} (relative to the scene's folder)"))
}

impl Files {
    /// The asset `file`, read and its buffers loaded on first use.
    pub(super) fn get(&mut self, file: &str, assets: &dyn Assets) -> Result<&Asset, String> {
        if !self.read.contains_key(file) {
            let bytes = assets
                .get(file)
                .ok_or_else(|| format!("{file}: cannot read it (relative to the scene's folder)"))?;
            let gltf = gltf::Gltf::from_slice(bytes)
                .map_err(|e| format!("{file}: not a readable glTF file: {e}"))?;
            let mut buffers = Vec::new();
            for b in gltf.document.buffers() {
                let data = match b.source() {
                    gltf::buffer::Source::Bin => gltf.blob.clone().ok_or_else(|| {
                        format!("{file}: buffers[{}]: the .glb has no BIN chunk", b.index())
                    })?,
                    gltf::buffer::Source::Uri(uri) => uri_bytes(file, uri, assets)
                        .map_err(|e| format!("{file}: buffers[{}].uri: {e}", b.index()))?,
                };
                if data.len() < b.length() {
                    return Err(format!(
                        "{file}: buffers[{}]: {} bytes where byteLength says {}",
                        b.index(),
                        data.len(),
                        b.length()
                    ));
                }
                buffers.push(data);
            }
            self.read.insert(file.to_string(), Asset { doc: gltf.document, buffers, file: file.to_string() });
        }
        Ok(&self.read[file])
    }
}

impl Asset {
    /// Primitive `primitive` of mesh `mesh` as a renderer mesh in the mesh's own space,
    /// with its extra attributes when it has any.
    pub(super) fn primitive(&self, mesh: u32, primitive: u32) -> Result<(Mesh, Option<Extras>), String> {
        let at = format!("{}: meshes[{mesh}].primitives[{primitive}]", self.file);
        let prim = self
            .doc
            .meshes()
            .nth(mesh as usize)
            .and_then(|m| m.primitives().nth(primitive as usize))
            .ok_or_else(|| format!("{at}: does not exist"))?;
        if prim.mode() != gltf::mesh::Mode::Triangles {
            return Err(format!("{at}.mode: only TRIANGLES (4) is rendered"));
        }
        let reader = prim.reader(|b| self.buffers.get(b.index()).map(Vec::as_slice));
        let p: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| format!("{at}.attributes.POSITION: missing or unreadable"))?
            .map(Vec3::from)
            .collect();
        let count = p.len();
        let sized = |name: &str, n: usize| {
            if n == count {
                Ok(())
            } else {
                Err(format!("{at}.attributes.{name}: {n} values for {count} positions"))
            }
        };
        let n: Vec<Vec3> = reader.read_normals().map(|r| r.map(Vec3::from).collect()).unwrap_or_default();
        if !n.is_empty() {
            sized("NORMAL", n.len())?;
        }
        let uv: Vec<Vec2> =
            reader.read_tex_coords(0).map(|r| r.into_f32().map(Vec2::from).collect()).unwrap_or_default();
        if !uv.is_empty() {
            sized("TEXCOORD_0", uv.len())?;
        }
        let uv1: Vec<Vec2> =
            reader.read_tex_coords(1).map(|r| r.into_f32().map(Vec2::from).collect()).unwrap_or_default();
        if !uv1.is_empty() {
            sized("TEXCOORD_1", uv1.len())?;
        }
        let tangents: Vec<Vec4> =
            reader.read_tangents().map(|r| r.map(Vec4::from).collect()).unwrap_or_default();
        if !tangents.is_empty() {
            sized("TANGENT", tangents.len())?;
        }
        let indices: Vec<u32> = match reader.read_indices() {
            Some(r) => r.into_u32().collect(),
            None => (0..count as u32).collect(),
        };
        if !indices.len().is_multiple_of(3) {
            return Err(format!("{at}.indices: {} indices do not make whole triangles", indices.len()));
        }
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= count) {
            return Err(format!("{at}.indices: index {bad} past the {count} vertices"));
        }
        let corner =
            |i: u32| [i, if n.is_empty() { u32::MAX } else { i }, if uv.is_empty() { u32::MAX } else { i }];
        let tris = indices.chunks_exact(3).map(|t| [corner(t[0]), corner(t[1]), corner(t[2])]).collect();
        let extras = (!uv1.is_empty() || !tangents.is_empty()).then_some(Extras { uv1, tangents });
        Ok((Mesh { p, n, uv, tris }, extras))
    }

    /// Image `image` decoded (stored RGBA values in [0, 1]) for the roles the scene reads
    /// it in, with the wrap modes of the first texture that shows it; its bytes from a
    /// buffer view, a `data:` URI or the bundle.
    pub(super) fn image(
        &self,
        image: u32,
        assets: &dyn Assets,
        srgb: bool,
        linear: bool,
    ) -> Result<Rgba, String> {
        let at = format!("{}: images[{image}]", self.file);
        let img = self.doc.images().nth(image as usize).ok_or_else(|| format!("{at}: does not exist"))?;
        let bytes: Vec<u8> = match img.source() {
            ImageSource::View { view, .. } => self.buffers[view.buffer().index()]
                .get(view.offset()..view.offset() + view.length())
                .ok_or_else(|| format!("{at}.bufferView: past the end of its buffer"))?
                .to_vec(),
            ImageSource::Uri { uri, .. } => {
                uri_bytes(&self.file, uri, assets).map_err(|e| format!("{at}.uri: {e}"))?
            }
        };
        self.decode(&at, &bytes, image, srgb, linear)
    }

    fn decode(&self, at: &str, bytes: &[u8], image: u32, srgb: bool, linear: bool) -> Result<Rgba, String> {
        let img =
            super::materials::decode_image(bytes).map_err(|e| format!("{at}: not a readable image: {e}"))?;
        let rgba = img.to_rgba32f();
        let (w, h) = rgba.dimensions();
        let stored = rgba.into_raw().chunks_exact(4).map(Vec4::from_slice).collect();
        let wrap = |m: gltf::texture::WrappingMode| match m {
            gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
            gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
            gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        };
        let wraps = self
            .doc
            .textures()
            .find(|t| t.source().index() == image as usize)
            .map(|t| [wrap(t.sampler().wrap_s()), wrap(t.sampler().wrap_t())])
            .unwrap_or_default();
        Ok(Rgba::new(w, h, wraps, stored, srgb, linear))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine;

    struct None_;
    impl Assets for None_ {
        fn get(&self, _: &str) -> Option<&[u8]> {
            None
        }
    }

    /// A glTF file with one buffer (as a data: URI) holding `bytes`, and `json` spliced
    /// in (accessors, views, meshes).
    fn file(bytes: &[u8], json: &str) -> Vec<u8> {
        let data = base64::engine::general_purpose::STANDARD.encode(bytes);
        format!(
            r#"{{"asset": {{"version": "2.0"}}, "buffers": [{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{data}"}}], {json}}}"#,
            bytes.len()
        )
        .into_bytes()
    }

    fn load(bytes: Vec<u8>) -> Result<Asset, String> {
        struct One(Vec<u8>);
        impl Assets for One {
            fn get(&self, path: &str) -> Option<&[u8]> {
                (path == "m.gltf").then_some(self.0.as_slice())
            }
        }
        let mut files = Files::default();
        let one = One(bytes);
        files.get("m.gltf", &one)?;
        Ok(files.read.remove("m.gltf").expect("read"))
    }

    fn f32s(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    /// A non-indexed triangle whose positions a sparse accessor overrides in part: the
    /// mesh holds the substituted values and one triangle of corners 0, 1, 2.
    #[test]
    fn sparse_accessors_are_applied_and_unindexed_primitives_are_triangles() {
        let mut bytes = f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        bytes.extend(1u16.to_le_bytes());
        bytes.extend([0, 0]);
        bytes.extend(f32s(&[5.0, 6.0, 7.0]));
        let json = r#""bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 2}, {"buffer": 0, "byteOffset": 40, "byteLength": 12}],
          "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
            "min": [0, 0, 0], "max": [5, 6, 7],
            "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123},
                       "values": {"bufferView": 2}}}],
          "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}, {"attributes": {"POSITION": 0}, "mode": 0}]}]"#;
        let asset = load(file(&bytes, json)).unwrap();
        let (mesh, extras) = asset.primitive(0, 0).unwrap();
        assert_eq!(mesh.p, [Vec3::ZERO, Vec3::new(5.0, 6.0, 7.0), Vec3::Y]);
        assert_eq!(mesh.tris, [[[0, u32::MAX, u32::MAX], [1, u32::MAX, u32::MAX], [2, u32::MAX, u32::MAX]]]);
        assert!(extras.is_none() && mesh.n.is_empty() && mesh.uv.is_empty());
        // Other modes are refused, naming the JSON path.
        assert_eq!(
            asset.primitive(0, 1).unwrap_err(),
            "m.gltf: meshes[0].primitives[1].mode: only TRIANGLES (4) is rendered"
        );
        assert_eq!(asset.primitive(3, 0).unwrap_err(), "m.gltf: meshes[3].primitives[0]: does not exist");
    }

    #[test]
    fn uris_resolve_beside_the_file_and_stay_in_the_bundle() {
        assert_eq!(resolve("models/duck/duck.gltf", "tex%20one.png").unwrap(), "models/duck/tex one.png");
        assert_eq!(resolve("duck.gltf", "./a/../b.bin").unwrap(), "b.bin");
        assert!(resolve("duck.gltf", "../../etc/passwd").is_err());
        assert_eq!(
            uri_bytes("d.gltf", "data:application/octet-stream;base64,AAEC", &None_).unwrap(),
            vec![0, 1, 2]
        );
        assert!(uri_bytes("d.gltf", "missing.bin", &None_).unwrap_err().contains("missing.bin"));
        // A buffer shorter than it says is refused at load, with its path.
        let short = br#"{"asset": {"version": "2.0"}, "buffers": [{"byteLength": 9, "uri": "data:application/octet-stream;base64,AAEC"}]}"#;
        assert_eq!(
            load(short.to_vec()).err().unwrap(),
            "m.gltf: buffers[0]: 3 bytes where byteLength says 9"
        );
    }
}
