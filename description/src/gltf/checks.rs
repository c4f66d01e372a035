//! The structural checks of a glTF document, in a fixed order so that the first error
//! found is always the same one: required extensions, the `gltf` crate's own validation
//! (indices that exist, enum values), then what it lets through: buffer views and
//! accessors within their buffers, primitives that Tessera can draw, and the node
//! hierarchy a tree.

use gltf::json::accessor::{ComponentType, Type};
use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::{Checked, Error as JsonError, Validate};
use gltf::json::{Path, Root};

use super::accessors::{components, kind, name, size};
use super::container::Source;
use super::{at, nodes, GltfError};

/// The extensions Tessera reads; a file requiring another is refused.
pub const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_transmission",
];

/// The most elements of an accessor without a buffer view (all zeros, or sparse): its
/// data takes memory that no byte of the file paid for.
pub const MAX_IMPLICIT_ELEMENTS: u64 = 1 << 24;

/// Runs every structural check on a parsed document.
pub(crate) fn document(file: &str, src: &Source) -> Result<(), GltfError> {
    let root = &src.root;
    let err = |path: String, m: String| GltfError::new(file, path, m);
    for (i, e) in root.extensions_required.iter().enumerate() {
        if !SUPPORTED_EXTENSIONS.contains(&e.as_str()) {
            return Err(err(
                at!("extensionsRequired[{i}]"),
                format!(
                    "the file requires extension {e:?}, which Tessera does not support (it reads {})",
                    SUPPORTED_EXTENSIONS.join(", ")
                ),
            ));
        }
    }
    // The crate's own check of POSITION indexes the accessors without a bound check.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(a) = prim.attributes.get(&Checked::Valid(Semantic::Positions)) {
                if a.value() >= root.accessors.len() {
                    return Err(err(
                        at!("meshes[{m}].primitives[{p}].attributes[\"POSITION\"]"),
                        format!("accessor {} does not exist", a.value()),
                    ));
                }
            }
        }
    }
    crate_validation(file, src)?;
    buffer_views(root, &src.buffers).map_err(|(p, m)| err(p, m))?;
    accessors(root).map_err(|(p, m)| err(p, m))?;
    meshes(root).map_err(|(p, m)| err(p, m))?;
    nodes::check_tree(root).map_err(|(p, m)| err(p, m))?;
    Ok(())
}

/// What an index field refers to, from the last part of its JSON path.
fn referent(path: &str) -> &'static str {
    let last = path.rsplit('.').next().unwrap_or(path);
    let field = last.split('[').next().unwrap_or(last);
    let parent = path.rsplit('.').nth(1).unwrap_or("");
    match field {
        "indices" | "attributes" | "input" | "output" | "POSITION" | "NORMAL" | "positions" | "normals"
        | "tangents" => "accessor",
        "bufferView" => "buffer view",
        "buffer" => "buffer",
        "mesh" => "mesh",
        "nodes" | "children" | "node" | "joints" | "skeleton" => "node",
        "material" => "material",
        "camera" => "camera",
        "skin" => "skin",
        "index" => "texture",
        "source" => "image",
        "sampler" if parent.starts_with("channels") => "animation sampler",
        "sampler" => "sampler",
        "scene" => "scene",
        "light" => "light",
        "inverseBindMatrices" => "accessor",
        _ => "index",
    }
}

/// The JSON value at a path such as `meshes[0].primitives[1].attributes["POSITION"]`.
fn lookup<'v>(value: &'v serde_json::Value, path: &str) -> Option<&'v serde_json::Value> {
    let mut v = value;
    for part in path.split('.') {
        let (name, mut rest) = part.split_once('[').map_or((part, ""), |(n, r)| (n, r));
        if !name.is_empty() {
            v = v.get(name)?;
        }
        while !rest.is_empty() {
            let (inside, after) = rest.split_once(']')?;
            v = match inside.strip_prefix('"').and_then(|s| s.strip_suffix('"')) {
                Some(key) => v.get(key)?,
                None => v.get(inside.parse::<usize>().ok()?)?,
            };
            rest = after.strip_prefix('[').unwrap_or(after);
        }
    }
    Some(v)
}

/// The `gltf` crate's validation, its first complaint made a sentence.
fn crate_validation(file: &str, src: &Source) -> Result<(), GltfError> {
    let mut first: Option<(String, JsonError)> = None;
    src.root.validate(&src.root, Path::new, &mut |path: &dyn Fn() -> Path, e| {
        let path = path().0;
        // The specification wants POSITION's bounds; Tessera computes them when absent.
        let bounds = path.ends_with("[\"POSITION\"].min") || path.ends_with("[\"POSITION\"].max");
        if first.is_none() && !(bounds && e == JsonError::Missing) {
            first = Some((path, e));
        }
    });
    let Some((path, e)) = first else { return Ok(()) };
    let value = lookup(&src.value, &path);
    let message = match (e, value) {
        (JsonError::IndexOutOfBounds, Some(v)) => format!("{} {v} does not exist", referent(&path)),
        (JsonError::IndexOutOfBounds, None) => "refers to something that does not exist".into(),
        (JsonError::Invalid, Some(v)) => format!("{v} is not a valid value here"),
        (JsonError::Invalid, None) => "is not a valid value".into(),
        (JsonError::Missing, _) => "is missing".into(),
        (JsonError::Oversize, _) => "is larger than this system can address".into(),
        (JsonError::Unsupported, _) => "is an extension Tessera does not support".into(),
    };
    Err(GltfError::new(file, path, message))
}

type Check = Result<(), (String, String)>;

fn buffer_views(root: &Root, buffers: &[Vec<u8>]) -> Check {
    for (i, v) in root.buffer_views.iter().enumerate() {
        let b = v.buffer.value();
        let have = buffers.get(b).map_or(0, |d| d.len() as u64);
        let start = v.byte_offset.map_or(0, |o| o.0);
        let end = start.checked_add(v.byte_length.0);
        if end.is_none_or(|e| e > have) {
            return Err((
                at!("bufferViews[{i}]"),
                format!(
                    "bytes {start}..{} lie beyond the end of buffer {b} ({have} bytes)",
                    start.saturating_add(v.byte_length.0)
                ),
            ));
        }
        if let Some(s) = v.byte_stride {
            if !(4..=252).contains(&s.0) || s.0 % 4 != 0 {
                return Err((
                    at!("bufferViews[{i}].byteStride"),
                    format!("{} is not a multiple of 4 in 4..=252", s.0),
                ));
            }
        }
    }
    Ok(())
}

fn accessors(root: &Root) -> Check {
    for (i, a) in root.accessors.iter().enumerate() {
        let path = at!("accessors[{i}]");
        let (c, t) = kind(a).ok_or_else(|| (path.clone(), "has an invalid type".to_string()))?;
        let count = a.count.0;
        if count == 0 {
            return Err((at!("{path}.count"), "must be at least 1".into()));
        }
        let elem = (components(t) * size(c)) as u64;
        match a.buffer_view {
            Some(view) => {
                let v = &root.buffer_views[view.value()];
                let stride = v.byte_stride.map_or(elem, |s| s.0 as u64);
                let offset = a.byte_offset.map_or(0, |o| o.0);
                let need = (count - 1).checked_mul(stride).and_then(|n| n.checked_add(offset + elem));
                if need.is_none_or(|n| n > v.byte_length.0) {
                    return Err((
                        path,
                        format!(
                            "{count} elements of {elem} bytes (stride {stride}, offset {offset}) need more than buffer view {} holds ({} bytes)",
                            view.value(),
                            v.byte_length.0
                        ),
                    ));
                }
            }
            None if count > MAX_IMPLICIT_ELEMENTS => {
                return Err((
                    at!("{path}.count"),
                    format!(
                    "{count} elements without a buffer view, more than the limit of {MAX_IMPLICIT_ELEMENTS}"
                ),
                ))
            }
            None => {}
        }
        if let Some(s) = &a.sparse {
            let sp = at!("{path}.sparse");
            if s.count.0 == 0 || s.count.0 > count {
                return Err((at!("{sp}.count"), format!("{} is not in 1..={count}", s.count.0)));
            }
            let ic = match &s.indices.component_type {
                Checked::Valid(ic)
                    if ic.0 != ComponentType::I8
                        && ic.0 != ComponentType::I16
                        && ic.0 != ComponentType::F32 =>
                {
                    ic.0
                }
                _ => {
                    return Err((
                        at!("{sp}.indices.componentType"),
                        "must be an unsigned integer type".into(),
                    ))
                }
            };
            let fits = |view: usize, offset: u64, bytes: u64, what: &str| -> Check {
                let have = root.buffer_views[view].byte_length.0;
                if offset.checked_add(bytes).is_none_or(|n| n > have) {
                    return Err((
                        at!("{sp}.{what}"),
                        format!(
                            "{bytes} bytes at offset {offset} lie beyond buffer view {view} ({have} bytes)"
                        ),
                    ));
                }
                Ok(())
            };
            fits(
                s.indices.buffer_view.value(),
                s.indices.byte_offset.0,
                s.count.0 * size(ic) as u64,
                "indices",
            )?;
            fits(s.values.buffer_view.value(), s.values.byte_offset.0, s.count.0 * elem, "values")?;
        }
    }
    Ok(())
}

/// The attribute's name as the file spells it.
fn semantic(s: &Semantic) -> String {
    match s {
        Semantic::Positions => "POSITION".into(),
        Semantic::Normals => "NORMAL".into(),
        Semantic::Tangents => "TANGENT".into(),
        Semantic::Colors(n) => format!("COLOR_{n}"),
        Semantic::TexCoords(n) => format!("TEXCOORD_{n}"),
        Semantic::Joints(n) => format!("JOINTS_{n}"),
        Semantic::Weights(n) => format!("WEIGHTS_{n}"),
        Semantic::Extras(name) => format!("_{name}"),
    }
}

fn meshes(root: &Root) -> Check {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let path = at!("meshes[{m}].primitives[{p}]");
            match prim.mode {
                Checked::Valid(Mode::Triangles) => {}
                Checked::Valid(other) => {
                    return Err((
                        at!("{path}.mode"),
                        format!(
                        "mode {} ({other:?}) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only",
                        other.as_gl_enum()
                    ),
                    ))
                }
                Checked::Invalid => return Err((at!("{path}.mode"), "is not a valid mode".into())),
            }
            let mut vertices = None;
            for (s, a) in &prim.attributes {
                let Checked::Valid(s) = s else { continue };
                let name_of = semantic(s);
                let apath = at!("{path}.attributes[\"{name_of}\"]");
                let acc = &root.accessors[a.value()];
                let Some((c, t)) = kind(acc) else { continue };
                let ok = match s {
                    Semantic::Positions | Semantic::Normals => t == Type::Vec3 && c == ComponentType::F32,
                    Semantic::Tangents => t == Type::Vec4 && c == ComponentType::F32,
                    Semantic::TexCoords(_) => {
                        t == Type::Vec2
                            && (c == ComponentType::F32
                                || (acc.normalized && matches!(c, ComponentType::U8 | ComponentType::U16)))
                    }
                    _ => true,
                };
                if !ok {
                    let want = match s {
                        Semantic::Positions | Semantic::Normals => "VEC3 of FLOAT",
                        Semantic::Tangents => "VEC4 of FLOAT",
                        _ => "VEC2 of FLOAT, or of normalized UNSIGNED_BYTE or UNSIGNED_SHORT",
                    };
                    return Err((
                        apath,
                        format!("accessor {} is {t:?} of {}; {name_of} must be {want}", a.value(), name(c)),
                    ));
                }
                match vertices {
                    None => vertices = Some((acc.count.0, name_of)),
                    Some((n, ref first)) if n != acc.count.0 => {
                        return Err((
                            apath,
                            format!(
                                "accessor {} has {} elements, {first} has {n}: attributes must agree",
                                a.value(),
                                acc.count.0
                            ),
                        ))
                    }
                    Some(_) => {}
                }
            }
            let Some(position) = prim.attributes.get(&Checked::Valid(Semantic::Positions)) else {
                return Err((
                    at!("{path}.attributes"),
                    "has no POSITION: a primitive without positions draws nothing".into(),
                ));
            };
            let vertices = root.accessors[position.value()].count.0;
            match prim.indices {
                Some(ix) => {
                    let acc = &root.accessors[ix.value()];
                    let Some((c, t)) = kind(acc) else { continue };
                    if t != Type::Scalar
                        || !matches!(c, ComponentType::U8 | ComponentType::U16 | ComponentType::U32)
                    {
                        return Err((
                            at!("{path}.indices"),
                            format!("accessor {} is {t:?} of {}; indices must be SCALAR of an unsigned integer type", ix.value(), name(c)),
                        ));
                    }
                    if !acc.count.0.is_multiple_of(3) {
                        return Err((
                            at!("{path}.indices"),
                            format!(
                                "accessor {} holds {} indices, not a multiple of 3 (TRIANGLES)",
                                ix.value(),
                                acc.count.0
                            ),
                        ));
                    }
                }
                None if !vertices.is_multiple_of(3) => {
                    return Err((
                        at!("{path}.attributes[\"POSITION\"]"),
                        format!("{vertices} vertices without indices, not a multiple of 3 (TRIANGLES)"),
                    ))
                }
                None => {}
            }
        }
    }
    Ok(())
}
