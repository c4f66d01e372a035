//! glTF cameras: the scene's first perspective camera, placed by its node (looking down
//! the node's −z with +y up, glTF §3.10).

use glam::Vec3;
use gltf::json::camera::Type;
use gltf::json::validation::Checked;
use gltf::json::Root;

use super::nodes::Placed;
use super::{at, GltfError};

/// A perspective camera in world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GltfCamera {
    /// Eye position.
    pub position: Vec3,
    /// A point on the view axis.
    pub look_at: Vec3,
    /// Up.
    pub up: Vec3,
    /// Full vertical field of view, radians.
    pub yfov: f32,
    /// Width / height, when the file gives it.
    pub aspect_ratio: Option<f32>,
}

/// The first camera met walking the scene; orthographic cameras are refused when they
/// would be the one used.
pub(crate) fn first(file: &str, root: &Root, walked: &[Placed]) -> Result<Option<GltfCamera>, GltfError> {
    let Some((placed, c)) =
        walked.iter().find_map(|p| root.nodes[p.node as usize].camera.map(|c| (p, c.value())))
    else {
        return Ok(None);
    };
    let cam = &root.cameras[c];
    let path = at!("cameras[{c}]");
    let persp = match (&cam.type_, &cam.perspective) {
        (Checked::Valid(Type::Perspective), Some(p)) => p,
        (Checked::Valid(Type::Orthographic), _) => {
            return Err(GltfError::new(
                file,
                at!("{path}.type"),
                "the scene's first camera is orthographic; Tessera renders perspective cameras only (give a [camera] in the TOML scene instead)",
            ))
        }
        _ => return Err(GltfError::new(file, at!("{path}.perspective"), "is missing")),
    };
    if !(persp.yfov > 1e-4 && persp.yfov < std::f32::consts::PI) {
        return Err(GltfError::new(
            file,
            at!("{path}.perspective.yfov"),
            format!("{} is not an angle in (0, π) radians", persp.yfov),
        ));
    }
    let aspect_ratio = persp.aspect_ratio.filter(|a| a.is_finite() && *a > 0.0);
    let w = placed.world;
    let forward = w.rotate * Vec3::NEG_Z;
    Ok(Some(GltfCamera {
        position: w.translate,
        look_at: w.translate + forward,
        up: w.rotate * Vec3::Y,
        yfov: persp.yfov,
        aspect_ratio,
    }))
}
