//! The bytes of a glTF asset: the JSON document (from a `.gltf` text or a `.glb`
//! container), its buffers (the GLB's binary chunk, `data:` URIs, or files beside it that
//! the bundle carries) and its images' encoded bytes. Nothing here touches the file
//! system or the network: external URIs are assets of the bundle.

use base64::Engine;
use gltf::json;

use super::{at, GltfError};
use crate::assets::{check_asset_path, Assets};

/// A `.glb` split into its JSON and binary chunks (glTF 2.0 §4.4), every length checked
/// against the bytes there are.
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let word = |i: usize| -> Option<u32> {
        bytes.get(i..i + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (Some(version), Some(length)) = (word(4), word(8)) else {
        return Err(format!("the GLB header is cut short ({} bytes)", bytes.len()));
    };
    if version != 2 {
        return Err(format!("GLB version {version}: only glTF 2.0 is read"));
    }
    let length = length as usize;
    if length > bytes.len() || length < 12 {
        return Err(format!("the GLB header declares {length} bytes, the file has {}", bytes.len()));
    }
    let mut chunks = Vec::new();
    let mut offset = 12usize;
    while offset < length {
        let (Some(len), Some(kind)) = (word(offset), word(offset + 4)) else {
            return Err(format!("the GLB chunk header at byte {offset} is cut short"));
        };
        let start = offset + 8;
        let end = start.checked_add(len as usize).filter(|&e| e <= length).ok_or_else(|| {
            format!("the GLB chunk at byte {offset} declares {len} bytes, beyond the file's end")
        })?;
        chunks.push((kind, &bytes[start..end]));
        offset = end;
    }
    const JSON: u32 = 0x4E4F_534A;
    const BIN: u32 = 0x004E_4942;
    match chunks.first() {
        Some((JSON, json)) => {
            let bin = chunks.get(1).filter(|(kind, _)| *kind == BIN).map(|(_, b)| *b);
            Ok((json, bin))
        }
        _ => Err("the GLB's first chunk is not its JSON".into()),
    }
}

/// A parsed glTF asset with every buffer's bytes.
pub struct Source {
    /// The document, not yet validated.
    pub root: json::Root,
    /// The JSON as a generic value, to quote what an invalid index was.
    pub value: serde_json::Value,
    /// Each buffer's bytes, in `buffers` order.
    pub buffers: Vec<Vec<u8>>,
}

/// The asset path of `uri` (relative to the glTF file `file`), percent-decoded and
/// checked like every asset path; `what` is its JSON path.
pub(crate) fn beside(file: &str, uri: &str) -> Result<String, String> {
    let decoded =
        percent_decode(uri).ok_or_else(|| format!("URI {uri:?} is not valid percent-encoded UTF-8"))?;
    if decoded.contains("://") {
        return Err(format!("URI {uri:?} is not a relative path: Tessera reads no network resource"));
    }
    let dir = file.rsplit_once('/').map_or("", |(d, _)| d);
    let joined = if dir.is_empty() { decoded } else { format!("{dir}/{decoded}") };
    check_asset_path(&joined)
}

fn percent_decode(s: &str) -> Option<String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = s.get(i + 1..i + 3)?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The bytes of a `data:` URI (base64 only, as glTF writers emit).
fn data_uri(uri: &str) -> Option<Result<Vec<u8>, String>> {
    let rest = uri.strip_prefix("data:")?;
    let Some((_, payload)) = rest.split_once(";base64,") else {
        return Some(Err("a data: URI must be base64 (\";base64,\")".into()));
    };
    Some(
        base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| format!("bad base64 in a data: URI: {e}")),
    )
}

/// What `uri` holds: decoded when a `data:` URI, else the bundle's asset beside `file`.
pub(crate) fn resolve(file: &str, uri: &str, assets: &dyn Assets) -> Result<Vec<u8>, String> {
    if let Some(data) = data_uri(uri) {
        return data;
    }
    let path = beside(file, uri)?;
    assets
        .get(&path)
        .map(<[u8]>::to_vec)
        .ok_or_else(|| format!("cannot read {path:?} (the URI {uri:?}, relative to the glTF file's folder)"))
}

/// The external URIs (asset paths beside `file`) of a glTF asset's buffers and images:
/// what a bundle must carry with it. A file that does not parse names none (its error
/// comes when the scene is validated).
pub fn external_assets(file: &str, bytes: &[u8]) -> Vec<String> {
    let Ok((root, _)) = document(bytes) else { return Vec::new() };
    let uris = root.buffers.iter().filter_map(|b| b.uri.as_deref());
    let uris = uris.chain(root.images.iter().filter_map(|i| i.uri.as_deref()));
    uris.filter(|u| !u.starts_with("data:")).filter_map(|u| beside(file, u).ok()).collect()
}

/// The document of a `.gltf` or `.glb`, and the GLB's binary chunk.
/// A document, its JSON as a value, and a GLB's binary chunk.
type Parsed<'a> = (json::Root, (serde_json::Value, Option<&'a [u8]>));

fn document(bytes: &[u8]) -> Result<Parsed<'_>, String> {
    let (text, bin) = if bytes.starts_with(b"glTF") { split_glb(bytes)? } else { (bytes, None) };
    let value: serde_json::Value =
        serde_json::from_slice(text).map_err(|e| format!("not a glTF file: the JSON does not parse: {e}"))?;
    let root = json::Root::from_slice(text).map_err(|e| format!("not a glTF 2.0 document: {e}"))?;
    Ok((root, (value, bin)))
}

/// Parses `bytes` (the asset `file`) and reads every buffer.
pub(crate) fn open(file: &str, bytes: &[u8], assets: &dyn Assets) -> Result<Source, GltfError> {
    let (root, (value, bin)) = document(bytes).map_err(|m| GltfError::new(file, "", m))?;
    let mut buffers = Vec::with_capacity(root.buffers.len());
    for (i, b) in root.buffers.iter().enumerate() {
        let path = at!("buffers[{i}]");
        let data = match (&b.uri, i, bin) {
            (Some(uri), _, _) => {
                resolve(file, uri, assets).map_err(|m| GltfError::new(file, format!("{path}.uri"), m))?
            }
            (None, 0, Some(bin)) => bin.to_vec(),
            (None, _, _) => {
                return Err(GltfError::new(file, path, "has no uri and is not the GLB's binary chunk"))
            }
        };
        let declared = b.byte_length.0;
        if (data.len() as u64) < declared {
            return Err(GltfError::new(
                file,
                format!("{path}.byteLength"),
                format!("declares {declared} bytes, the data holds {}", data.len()),
            ));
        }
        buffers.push(data);
    }
    Ok(Source { root, value, buffers })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uris_resolve_beside_the_file_and_stay_in_the_bundle() {
        assert_eq!(beside("models/duck.gltf", "duck%20body.bin").unwrap(), "models/duck body.bin");
        assert_eq!(beside("duck.gltf", "tex/a.png").unwrap(), "tex/a.png");
        assert!(beside("duck.gltf", "../../etc/passwd").unwrap_err().contains("escapes the scene's folder"));
        assert!(beside("duck.gltf", "https://example.com/a.bin").unwrap_err().contains("network"));
        assert!(beside("duck.gltf", "/etc/passwd").unwrap_err().contains("must be relative"));
        assert!(beside("duck.gltf", "%zz").is_err());
    }

    #[test]
    fn glb_lengths_are_checked() {
        assert!(split_glb(b"glTF").unwrap_err().contains("cut short"));
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(4u32.to_le_bytes());
        assert!(split_glb(&glb).unwrap_err().contains("declares 4 bytes"));
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(28u32.to_le_bytes());
        glb.extend(1000u32.to_le_bytes());
        glb.extend(b"JSON");
        glb.extend(b"{}{}{}{}");
        assert!(split_glb(&glb).unwrap_err().contains("beyond the file's end"));
    }
}
