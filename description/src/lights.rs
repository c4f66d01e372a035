//! Lights given by their own tables: spot lights and the environment. Point and
//! directional lights are checked in `validate`; emitting objects in `objects`.

use std::ops::Range;

use crate::bundle::{check_asset_path, unreadable};
use crate::model::{Environment, EnvironmentKind, Light};
use crate::schema::{EnvironmentDef, SpotLightDef};
use crate::validate::{Validator, R};

impl Validator<'_> {
    pub(crate) fn spot_light(&self, span: &Range<usize>, d: &SpotLightDef) -> R<Light> {
        let ctx = &self.ctx;
        let position = ctx.finite(span, "spot_light.position", d.position.0)?;
        let direction = ctx.finite(span, "spot_light.direction", d.direction.0)?;
        let direction = direction
            .try_normalize()
            .ok_or_else(|| ctx.err(span, "spot_light.direction must not be the zero vector"))?;
        let color = ctx.colour(span, "spot_light.color", d.color.0)?;
        let intensity = ctx.number(span, "spot_light.intensity", d.intensity, 0.0..f32::MAX)?;
        let outer =
            ctx.number(span, "spot_light.outer_cone (degrees)", d.outer_cone.unwrap_or(45.0), 0.0..90.0)?;
        let inner =
            ctx.number(span, "spot_light.inner_cone (degrees)", d.inner_cone.unwrap_or(0.0), 0.0..90.0)?;
        // glTF requires inner < outer; the falloff divides by their cosines' difference.
        if !(inner < outer) {
            return Err(ctx.err(
                span,
                format!("spot_light: inner_cone ({inner}) must be smaller than outer_cone ({outer})"),
            ));
        }
        Ok(Light::Spot {
            position,
            direction,
            intensity: color * intensity,
            inner_cone: inner.to_radians(),
            outer_cone: outer.to_radians(),
        })
    }

    pub(crate) fn environment(&self, span: &Range<usize>, d: &EnvironmentDef) -> R<Environment> {
        let ctx = &self.ctx;
        let strength = ctx.number(span, "environment.strength", d.strength.unwrap_or(1.0), 0.0..f32::MAX)?;
        let rotation = ctx.number(
            span,
            "environment.rotation (degrees)",
            d.rotation.unwrap_or(0.0),
            -36_000.0..36_000.0,
        )?;
        let kind = match (&d.file, d.color) {
            (Some(_), Some(_)) => {
                return Err(ctx.err(span, "environment: give `file` (an image) or `color`, not both"))
            }
            (None, None) => {
                return Err(ctx.err(span, "environment needs `file` (an equirectangular image) or `color`"))
            }
            (None, Some(c)) => EnvironmentKind::Uniform(ctx.colour(span, "environment.color", c.0)?),
            (Some(file), None) => {
                let path =
                    check_asset_path(file).map_err(|e| ctx.err(span, format!("environment.file: {e}")))?;
                let lower = path.to_ascii_lowercase();
                if !(lower.ends_with(".hdr") || lower.ends_with(".exr")) {
                    return Err(ctx.err(
                        span,
                        format!(
                            "environment.file: {file:?} must be a Radiance .hdr or an OpenEXR .exr image"
                        ),
                    ));
                }
                let bytes = (self.assets.get(&path))
                    .ok_or_else(|| ctx.err(span, unreadable(self.assets, "environment.file", file)))?;
                let (width, height) = crate::materials::image_size(bytes).map_err(|e| {
                    ctx.err(span, format!("environment.file: {file:?} is not a readable image: {e}"))
                })?;
                if u64::from(width) * u64::from(height) > crate::limits::MAX_TEXTURE_PIXELS {
                    return Err(ctx.err(
                        span,
                        format!(
                            "environment.file: {file:?} is {width}x{height}, more than the limit of {} pixels",
                            crate::limits::MAX_TEXTURE_PIXELS
                        ),
                    ));
                }
                EnvironmentKind::Map { file: path, width, height }
            }
        };
        Ok(Environment { kind, strength, rotation: rotation.to_radians() })
    }
}
