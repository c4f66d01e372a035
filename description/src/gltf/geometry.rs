//! A triangle primitive's data: scanned at validation (index values below the vertex
//! count, positions finite, their bounds) and read whole for the renderer.

use glam::{Vec2, Vec3, Vec4};
use gltf::json::mesh::Semantic;
use gltf::json::validation::Checked;
use gltf::json::Root;

use super::{accessors, at, GltfError};

/// What validation learns of a primitive without keeping its data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Scan {
    pub(crate) triangles: u64,
    pub(crate) vertices: u64,
    pub(crate) min: Vec3,
    pub(crate) max: Vec3,
}

/// A primitive's vertices and triangles, in its mesh's space.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Geometry {
    /// Positions.
    pub positions: Vec<Vec3>,
    /// Normals, when the file gives them (else the renderer computes flat ones).
    pub normals: Option<Vec<Vec3>>,
    /// Tangents (xyz, w the bitangent's sign), when the file gives them.
    pub tangents: Option<Vec<Vec4>>,
    /// Texture coordinates: `TEXCOORD_0`, `TEXCOORD_1`, … as far as they go without a gap.
    pub texcoords: Vec<Vec<Vec2>>,
    /// Triangles as vertex indices, each below `positions.len()`.
    pub triangles: Vec<[u32; 3]>,
}

fn attribute(root: &Root, mesh: u32, primitive: u32, s: Semantic) -> Option<usize> {
    let prim = root.meshes.get(mesh as usize)?.primitives.get(primitive as usize)?;
    prim.attributes.get(&Checked::Valid(s)).map(|a| a.value())
}

/// The triangles of a primitive, every index checked against `vertices`.
fn triangles(
    file: &str,
    root: &Root,
    buffers: &[Vec<u8>],
    (mesh, primitive): (u32, u32),
    vertices: u64,
) -> Result<Vec<[u32; 3]>, GltfError> {
    let path = at!("meshes[{mesh}].primitives[{primitive}]");
    let prim = root
        .meshes
        .get(mesh as usize)
        .and_then(|m| m.primitives.get(primitive as usize))
        .ok_or_else(|| GltfError::new(file, path.clone(), "does not exist"))?;
    let Some(ix) = prim.indices else {
        return Ok((0..vertices as u32 / 3).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect());
    };
    let unreadable =
        || GltfError::new(file, at!("{path}.indices"), format!("accessor {} cannot be read", ix.value()));
    let values = accessors::uints(root, buffers, ix.value()).ok_or_else(unreadable)?;
    if let Some((k, v)) = values.iter().enumerate().find(|(_, &v)| u64::from(v) >= vertices) {
        return Err(GltfError::new(
            file,
            at!("{path}.indices"),
            format!("index {k} of accessor {} is {v}, but the primitive has {vertices} vertices", ix.value()),
        ));
    }
    Ok(values.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect())
}

fn positions(
    file: &str,
    root: &Root,
    buffers: &[Vec<u8>],
    mesh: u32,
    primitive: u32,
) -> Result<Vec<Vec3>, GltfError> {
    let path = at!("meshes[{mesh}].primitives[{primitive}].attributes[\"POSITION\"]");
    let a = attribute(root, mesh, primitive, Semantic::Positions)
        .ok_or_else(|| GltfError::new(file, path.clone(), "is missing"))?;
    let raw = accessors::floats(root, buffers, a)
        .ok_or_else(|| GltfError::new(file, path.clone(), format!("accessor {a} cannot be read")))?;
    let p: Vec<Vec3> = raw.chunks_exact(3).map(Vec3::from_slice).collect();
    if let Some((i, v)) = p.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(GltfError::new(file, path, format!("vertex {i} of accessor {a} is {v}, not finite")));
    }
    Ok(p)
}

/// Scans a primitive (validated structurally before).
pub(crate) fn scan(
    file: &str,
    root: &Root,
    buffers: &[Vec<u8>],
    mesh: u32,
    primitive: u32,
) -> Result<Scan, GltfError> {
    let p = positions(file, root, buffers, mesh, primitive)?;
    let tris = triangles(file, root, buffers, (mesh, primitive), p.len() as u64)?;
    let (min, max) =
        p.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(a, b), v| (a.min(*v), b.max(*v)));
    Ok(Scan { triangles: tris.len() as u64, vertices: p.len() as u64, min, max })
}

/// Reads a primitive whole.
pub(crate) fn read(
    file: &str,
    root: &Root,
    buffers: &[Vec<u8>],
    mesh: u32,
    primitive: u32,
) -> Result<Geometry, GltfError> {
    let positions = positions(file, root, buffers, mesh, primitive)?;
    let n = positions.len();
    let triangles = triangles(file, root, buffers, (mesh, primitive), n as u64)?;
    let read = |s: Semantic, name: String, width: usize| -> Result<Option<Vec<f32>>, GltfError> {
        let Some(a) = attribute(root, mesh, primitive, s) else { return Ok(None) };
        let path = at!("meshes[{mesh}].primitives[{primitive}].attributes[\"{name}\"]");
        let v = accessors::floats(root, buffers, a)
            .filter(|v| v.len() == n * width)
            .ok_or_else(|| GltfError::new(file, path.clone(), format!("accessor {a} cannot be read")))?;
        if v.iter().any(|x| !x.is_finite()) {
            return Err(GltfError::new(file, path, format!("accessor {a} holds a value that is not finite")));
        }
        Ok(Some(v))
    };
    let normals = read(Semantic::Normals, "NORMAL".into(), 3)?
        .map(|v| v.chunks_exact(3).map(Vec3::from_slice).collect());
    let tangents = read(Semantic::Tangents, "TANGENT".into(), 4)?
        .map(|v| v.chunks_exact(4).map(Vec4::from_slice).collect());
    let mut texcoords = Vec::new();
    while let Some(v) =
        read(Semantic::TexCoords(texcoords.len() as u32), format!("TEXCOORD_{}", texcoords.len()), 2)?
    {
        texcoords.push(v.chunks_exact(2).map(Vec2::from_slice).collect());
    }
    Ok(Geometry { positions, normals, tangents, texcoords, triangles })
}
