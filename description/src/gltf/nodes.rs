//! The node hierarchy: checked to be a forest (no node its own ancestor, none with two
//! parents), walked from a scene's roots with each node's world transform composed
//! (parent × local, glTF §3.5.3), decomposed into Tessera's translate/rotate/scale.

use glam::{Mat3, Mat4, Quat, Vec3};
use gltf::json::Root;
use serde::Deserialize;

use super::animation::{Poses, When};
use super::{at, GltfError};
use crate::math;
use crate::transform::Trs;

/// Which scene of a glTF file: by index or by name.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(untagged)]
pub enum SceneRef {
    /// `scenes[i]`.
    Index(u32),
    /// The scene with this `name`.
    Name(String),
}

/// A node reached from the scene, with its world transform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Placed {
    pub(crate) node: u32,
    /// World matrix at shutter open.
    pub(crate) open: Mat4,
    /// World matrix at shutter close (the same when nothing moves).
    pub(crate) close: Mat4,
    /// `open` decomposed (nodes holding a mesh, camera or light only; else identity).
    pub(crate) world: Trs,
    /// `close` decomposed, when it differs.
    pub(crate) motion: Option<Trs>,
}

/// Checks that the nodes form a forest and that scenes list roots only.
pub(crate) fn check_tree(root: &Root) -> Result<(), (String, String)> {
    let n = root.nodes.len();
    let mut parent: Vec<Option<usize>> = vec![None; n];
    for (i, node) in root.nodes.iter().enumerate() {
        for (k, c) in node.children.iter().flatten().enumerate() {
            let c = c.value();
            if c == i {
                return Err((at!("nodes[{i}].children[{k}]"), format!("node {i} is its own child")));
            }
            if let Some(p) = parent[c] {
                return Err((
                    at!("nodes[{i}].children[{k}]"),
                    format!("node {c} already has parent nodes[{p}]: a node has at most one parent"),
                ));
            }
            parent[c] = Some(i);
        }
    }
    // 0 unseen, 1 on the path being followed, 2 known to reach a root.
    let mut state = vec![0u8; n];
    for start in 0..n {
        let mut path = Vec::new();
        let mut at_node = Some(start);
        while let Some(i) = at_node {
            match state[i] {
                2 => break,
                1 => {
                    return Err((
                        at!("nodes[{i}]"),
                        format!("node {i} is its own ancestor: the node hierarchy has a cycle"),
                    ))
                }
                _ => {}
            }
            state[i] = 1;
            path.push(i);
            at_node = parent[i];
        }
        for i in path {
            state[i] = 2;
        }
    }
    for (s, scene) in root.scenes.iter().enumerate() {
        for (k, r) in scene.nodes.iter().enumerate() {
            if let Some(p) = parent[r.value()] {
                return Err((
                    at!("scenes[{s}].nodes[{k}]"),
                    format!("node {} is a child of nodes[{p}], not a root", r.value()),
                ));
            }
        }
    }
    Ok(())
}

/// `m` as translate/rotate/scale; refused when it shears (a non-uniform scale under a
/// rotation) or collapses an axis, which Tessera's transforms cannot hold.
pub(crate) fn decompose(m: &Mat4) -> Result<Trs, String> {
    if !m.is_finite() {
        return Err("its world transform is not finite".into());
    }
    // Glam's `to_scale_rotation_translation` and `determinant` sum in another order on
    // its SIMD paths than on its scalar one; on the columns as `Vec3`/`Mat3` (one
    // implementation on every target) the bits are every machine's.
    let axes = Mat3::from_mat4(*m);
    let linear = axes.determinant();
    let scale = Vec3::new(axes.x_axis.length() * linear.signum(), axes.y_axis.length(), axes.z_axis.length());
    if !(linear.abs() > 1e-30) || !scale.is_finite() {
        return Err("its world transform collapses an axis (a scale of zero)".into());
    }
    let rotate = Quat::from_mat3(&Mat3::from_cols(
        axes.x_axis / scale.x,
        axes.y_axis / scale.y,
        axes.z_axis / scale.z,
    ));
    let translate = m.w_axis.truncate();
    if !rotate.is_finite() {
        return Err("its world transform collapses an axis (a scale of zero)".into());
    }
    let back = Mat4::from_scale_rotation_translation(scale, rotate, translate);
    let size = m.to_cols_array().iter().take(12).fold(0f32, |a, v| a.max(v.abs())).max(1e-30);
    let off = (back - *m).to_cols_array().iter().take(12).fold(0f32, |a, v| a.max(v.abs()));
    if off > 1e-4 * size {
        return Err(
            "its world transform shears (a non-uniform scale under a rotation), which Tessera's translate/rotate/scale transforms cannot hold"
                .into(),
        );
    }
    Ok(Trs { translate, rotate: math::quat_normalize(rotate), scale })
}

/// The node's own transform at `when`: its matrix, or its TRS with animation applied.
fn local(file: &str, root: &Root, poses: &Poses, i: usize, when: When) -> Result<Mat4, GltfError> {
    let node = &root.nodes[i];
    if let Some(m) = node.matrix {
        if poses.animates(i) {
            return Err(GltfError::new(
                file,
                at!("nodes[{i}].matrix"),
                "an animated node must give translation/rotation/scale, not a matrix (glTF §3.11)",
            ));
        }
        return Ok(Mat4::from_cols_array(&m));
    }
    let (t, r, s) = poses.trs(i, when).unwrap_or((
        node.translation.map_or(Vec3::ZERO, Vec3::from),
        node.rotation.map_or(Quat::IDENTITY, |q| Quat::from_array(q.0)),
        node.scale.map_or(Vec3::ONE, Vec3::from),
    ));
    let r = if math::quat_dot(r, r) > 0.0 { math::quat_normalize(r) } else { Quat::IDENTITY };
    Ok(Mat4::from_scale_rotation_translation(s, r, t))
}

/// The root nodes of the chosen scene: `scene` given, else the document's default, else
/// its first; a file without scenes shows every root node.
fn roots(file: &str, root: &Root, scene: Option<&SceneRef>) -> Result<Vec<usize>, GltfError> {
    let index = match scene {
        Some(SceneRef::Index(i)) => {
            if *i as usize >= root.scenes.len() {
                return Err(GltfError::new(
                    file,
                    "scenes",
                    format!("scene {i} does not exist (the file has {})", root.scenes.len()),
                ));
            }
            Some(*i as usize)
        }
        Some(SceneRef::Name(name)) => {
            let found = root.scenes.iter().position(|s| s.name.as_deref() == Some(name.as_str()));
            let Some(i) = found else {
                let names: Vec<String> =
                    root.scenes.iter().filter_map(|s| s.name.as_ref().map(|n| format!("{n:?}"))).collect();
                return Err(GltfError::new(
                    file,
                    "scenes",
                    format!("no scene is named {name:?} (named: [{}])", names.join(", ")),
                ));
            };
            Some(i)
        }
        None => root.scene.map(|s| s.value()).or(if root.scenes.is_empty() { None } else { Some(0) }),
    };
    Ok(match index {
        Some(i) => root.scenes[i].nodes.iter().map(|n| n.value()).collect(),
        None => {
            let mut child = vec![false; root.nodes.len()];
            for c in root.nodes.iter().flat_map(|n| n.children.iter().flatten()) {
                child[c.value()] = true;
            }
            (0..root.nodes.len()).filter(|&i| !child[i]).collect()
        }
    })
}

/// Every node of the scene, depth first in file order, with its world transform
/// composed after `base` (the TOML table's transform).
pub(crate) fn walk(
    file: &str,
    root: &Root,
    scene: Option<&SceneRef>,
    base: &Trs,
    poses: &Poses,
) -> Result<Vec<Placed>, GltfError> {
    let base = Mat4::from(base.matrix());
    let mut out = Vec::new();
    let mut stack: Vec<(usize, Mat4, Mat4)> =
        roots(file, root, scene)?.into_iter().rev().map(|r| (r, base, base)).collect();
    while let Some((i, parent_open, parent_close)) = stack.pop() {
        let open = parent_open * local(file, root, poses, i, When::Open)?;
        let close = parent_close * local(file, root, poses, i, When::Close)?;
        let node = &root.nodes[i];
        let used = node.mesh.is_some()
            || node.camera.is_some()
            || node.extensions.as_ref().is_some_and(|e| e.khr_lights_punctual.is_some());
        let (world, motion) = if used {
            let d = |m: &Mat4| decompose(m).map_err(|e| GltfError::new(file, at!("nodes[{i}]"), e));
            let w = d(&open)?;
            let c = if close == open { None } else { Some(d(&close)?) };
            (w, c)
        } else {
            (Trs::default(), None)
        };
        out.push(Placed { node: i as u32, open, close, world, motion });
        for c in node.children.iter().flatten().rev() {
            stack.push((c.value(), open, close));
        }
    }
    Ok(out)
}
