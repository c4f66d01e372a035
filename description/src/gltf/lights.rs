//! KHR_lights_punctual: point, spot and directional lights placed by their nodes (shining
//! down the node's −z). glTF's units map onto Tessera's: a point or spot light's candela
//! is its radiant intensity, a directional light's lux its irradiance (per unit colour);
//! `range` is ignored (the inverse-square falloff is physical).

use glam::Vec3;
use gltf::json::extensions::scene::khr_lights_punctual::Type;
use gltf::json::validation::Checked;
use gltf::json::Root;

use super::nodes::Placed;
use super::{at, GltfError};
use crate::model::Light;

/// The lights of the walked nodes, in node order.
pub(crate) fn punctual(file: &str, root: &Root, walked: &[Placed]) -> Result<Vec<Light>, GltfError> {
    let defined = root
        .extensions
        .as_ref()
        .and_then(|e| e.khr_lights_punctual.as_ref())
        .map_or(&[][..], |l| &l.lights[..]);
    let mut out = Vec::new();
    for p in walked {
        let node = &root.nodes[p.node as usize];
        let Some(l) = node.extensions.as_ref().and_then(|e| e.khr_lights_punctual.as_ref()) else { continue };
        let i = l.light.value();
        let path = at!("extensions.KHR_lights_punctual.lights[{i}]");
        let Some(light) = defined.get(i) else {
            return Err(GltfError::new(
                file,
                at!("nodes[{}].extensions.KHR_lights_punctual.light", p.node),
                format!("light {i} does not exist"),
            ));
        };
        let color = Vec3::from(light.color);
        if !color.is_finite()
            || color.min_element() < 0.0
            || !(light.intensity >= 0.0 && light.intensity.is_finite())
        {
            return Err(GltfError::new(file, path, "color and intensity must be finite and not negative"));
        }
        let power = color * light.intensity;
        let w = p.world;
        let direction = (w.rotate * Vec3::NEG_Z).normalize();
        out.push(match light.type_ {
            Checked::Valid(Type::Point) => Light::Point { position: w.translate, intensity: power },
            Checked::Valid(Type::Directional) => Light::Directional { direction, irradiance: power },
            Checked::Valid(Type::Spot) => {
                let spot = light.spot.as_ref();
                let inner = spot.map_or(0.0, |s| s.inner_cone_angle);
                let outer = spot.map_or(std::f32::consts::FRAC_PI_4, |s| s.outer_cone_angle);
                if !(0.0 <= inner && inner < outer && outer <= std::f32::consts::FRAC_PI_2) {
                    return Err(GltfError::new(
                        file,
                        at!("{path}.spot"),
                        format!("cone angles {inner} and {outer} must satisfy 0 <= inner < outer <= π/2"),
                    ));
                }
                Light::Spot {
                    position: w.translate,
                    direction,
                    intensity: power,
                    inner_cone: inner,
                    outer_cone: outer,
                }
            }
            Checked::Invalid => {
                return Err(GltfError::new(file, at!("{path}.type"), "is not a valid light type"))
            }
        });
    }
    Ok(out)
}
