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

#[cfg(test)]
mod tests {
    use crate::bundle::Assets;
    use crate::model::{EnvironmentKind, Light};
    use crate::Description;

    const BASE: &str =
        "[render]\nwidth = 8\nheight = 6\n\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n";

    struct One(&'static str, Vec<u8>);
    impl Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == self.0).then_some(self.1.as_slice())
        }
    }

    fn parse(extra: &str, assets: &dyn Assets) -> Result<Description, String> {
        Description::parse_text("t.toml", &format!("{BASE}{extra}"), assets).map_err(|e| e.to_string())
    }

    fn hdr(w: u32, h: u32) -> Vec<u8> {
        let img = image::Rgb32FImage::from_pixel(w, h, image::Rgb([1.0; 3]));
        let mut out = std::io::Cursor::new(Vec::new());
        image::DynamicImage::ImageRgb32F(img).write_to(&mut out, image::ImageFormat::Hdr).unwrap();
        out.into_inner()
    }

    #[test]
    fn a_spot_light_is_read_in_degrees_and_checked() {
        let spot = "\n[[spot_light]]\nposition = [0, 2, 0]\ndirection = [0, -2, 0]\nintensity = 3\ncolor = [1, 0.5, 0]\ninner_cone = 10\nouter_cone = 20\n";
        let d = parse(spot, &crate::NoAssets).unwrap();
        let Light::Spot { direction, intensity, inner_cone, outer_cone, .. } = d.lights[0] else { panic!() };
        assert_eq!((direction, intensity), (glam::Vec3::NEG_Y, glam::Vec3::new(3.0, 1.5, 0.0)));
        assert!(
            (inner_cone - 10f32.to_radians()).abs() < 1e-7 && (outer_cone - 20f32.to_radians()).abs() < 1e-7
        );
        // glTF's defaults: 0 and 45°.
        let d = parse(
            "\n[[spot_light]]\nposition = [0, 2, 0]\ndirection = [0, -1, 0]\nintensity = 1\n",
            &crate::NoAssets,
        )
        .unwrap();
        assert!(
            matches!(d.lights[0], Light::Spot { inner_cone, outer_cone, .. } if inner_cone == 0.0 && outer_cone == 45f32.to_radians())
        );
        let e = parse(&spot.replace("inner_cone = 10", "inner_cone = 20"), &crate::NoAssets).unwrap_err();
        assert_eq!(e, "t.toml:9:1: spot_light: inner_cone (20) must be smaller than outer_cone (20)");
        let e = parse(&spot.replace("outer_cone = 20", "outer_cone = 100"), &crate::NoAssets).unwrap_err();
        assert_eq!(e, "t.toml:9:1: spot_light.outer_cone (degrees) must be in [0, 90], got 100");
        let e = parse(&spot.replace("[0, -2, 0]", "[0, 0, 0]"), &crate::NoAssets).unwrap_err();
        assert_eq!(e, "t.toml:9:1: spot_light.direction must not be the zero vector");
        let e =
            parse(&spot.replace("intensity = 3", "intensity = 3\nangle = 4"), &crate::NoAssets).unwrap_err();
        assert!(e.starts_with("t.toml:13:") && e.contains("unknown field `angle`"), "{e}");
    }

    #[test]
    fn the_environment_is_a_colour_or_an_image_checked_from_its_header() {
        let d =
            parse("\n[environment]\ncolor = [0.5, 1, 2]\nstrength = 2\nrotation = 90\n", &crate::NoAssets)
                .unwrap();
        let env = d.environment.unwrap();
        assert_eq!(env.kind, EnvironmentKind::Uniform(glam::Vec3::new(0.5, 1.0, 2.0)));
        assert!((env.strength, (env.rotation - std::f32::consts::FRAC_PI_2).abs()) == (2.0, 0.0));
        let sky = One("sky.hdr", hdr(16, 8));
        let d = parse("\n[environment]\nfile = \"sky.hdr\"\n", &sky).unwrap();
        let env = d.environment.unwrap();
        assert_eq!(env.kind, EnvironmentKind::Map { file: "sky.hdr".into(), width: 16, height: 8 });
        assert_eq!((env.strength, env.rotation), (1.0, 0.0));
        assert!(parse("", &crate::NoAssets).unwrap().environment.is_none());

        let e = parse("\n[environment]\nfile = \"sky.hdr\"\ncolor = 1\n", &sky).unwrap_err();
        assert_eq!(e, "t.toml:9:1: environment: give `file` (an image) or `color`, not both");
        let e = parse("\n[environment]\nstrength = 1\n", &sky).unwrap_err();
        assert_eq!(e, "t.toml:9:1: environment needs `file` (an equirectangular image) or `color`");
        let e = parse("\n[environment]\nfile = \"sky.png\"\n", &sky).unwrap_err();
        assert_eq!(
            e,
            "t.toml:9:1: environment.file: \"sky.png\" must be a Radiance .hdr or an OpenEXR .exr image"
        );
        let e = parse("\n[environment]\nfile = \"other.hdr\"\n", &sky).unwrap_err();
        assert!(e.starts_with("t.toml:9:1: environment.file: cannot read \"other.hdr\""), "{e}");
        let e =
            parse("\n[environment]\nfile = \"sky.hdr\"\n", &One("sky.hdr", b"#?RADIANCE\nnonsense".to_vec()))
                .unwrap_err();
        assert!(e.starts_with("t.toml:9:1: environment.file: \"sky.hdr\" is not a readable image"), "{e}");
        let e = parse("\n[environment]\nfile = \"../sky.hdr\"\n", &sky).unwrap_err();
        assert!(e.starts_with("t.toml:9:1: environment.file: "), "{e}");
        let e = parse("\n[environment]\ncolor = -1\n", &sky).unwrap_err();
        assert!(e.starts_with("t.toml:9:1: environment.color must not be negative"), "{e}");
    }

    #[test]
    fn triangles_and_meshes_may_emit_but_not_move() {
        let tri = "\n[[triangle]]\nvertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nemission = [1, 2, 3]\n";
        let d = parse(tri, &crate::NoAssets).unwrap();
        assert_eq!(d.objects[0].emission, Some(glam::Vec3::new(1.0, 2.0, 3.0)));
        let e = parse(&format!("{tri}motion = {{ translate = [1, 0, 0] }}\n"), &crate::NoAssets).unwrap_err();
        assert_eq!(
            e,
            "t.toml:9:1: triangle: lights cannot move (give `emission` or `motion`/`keys`, not both)"
        );
        let quad = One("q.obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n".to_vec());
        let d = parse("\n[[mesh]]\nfile = \"q.obj\"\nemission = 2\n", &quad).unwrap();
        assert_eq!(d.objects[0].emission, Some(glam::Vec3::splat(2.0)));
        let e = parse("\n[[mesh]]\nfile = \"q.obj\"\n", &quad).unwrap_err();
        assert_eq!(e, "t.toml:9:1: mesh needs a `material` (or an `emission`, for a light)");
    }
}
