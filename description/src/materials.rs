//! Textures and materials: checked, their names resolved to indices. Image textures are
//! checked from their header only (format and size); their pixels are the renderer's to
//! decode.

use std::io::Cursor;
use std::ops::Range;

use glam::Vec3;

use crate::bundle::{check_asset_path, unreadable};
use crate::model::{CheckerSpace, Classic, Color, Material, Texture, TextureKind};
use crate::schema::{black, ColorOrTexture, MaterialDef, Rgb, TextureDef};
use crate::validate::{Validator, R};

/// Complex indices of refraction of common metals (R, G, B), as in the benchmark scenes.
fn metal_preset(name: &str) -> Option<(Vec3, Vec3)> {
    Some(match name {
        "gold" => (Vec3::new(0.143, 0.374, 1.442), Vec3::new(3.983, 2.385, 1.603)),
        "copper" => (Vec3::new(0.200, 0.924, 1.102), Vec3::new(3.912, 2.452, 2.142)),
        "aluminium" | "aluminum" => (Vec3::new(1.657, 0.880, 0.521), Vec3::new(9.224, 6.270, 4.837)),
        "silver" => (Vec3::new(0.155, 0.117, 0.138), Vec3::new(4.828, 3.122, 2.147)),
        _ => return None,
    })
}

/// The format and size of an image from its header, without decoding its pixels.
pub(crate) fn image_size(bytes: &[u8]) -> image::ImageResult<(u32, u32)> {
    image::ImageReader::new(Cursor::new(bytes)).with_guessed_format()?.into_dimensions()
}

impl Validator<'_> {
    fn tex(&self, span: &Range<usize>, what: &str, c: &ColorOrTexture) -> R<Color> {
        match c {
            ColorOrTexture::Color(v) => Ok(Color::Const(self.ctx.colour(span, what, *v)?)),
            ColorOrTexture::Texture(name) => {
                self.texture_index.get(name).map(|i| Color::Texture(*i)).ok_or_else(|| {
                    let known: Vec<&str> = self.texture_index.keys().map(String::as_str).collect();
                    self.ctx.err(
                        span,
                        format!("{what}: unknown texture \"{name}\"; defined: [{}]", known.join(", ")),
                    )
                })
            }
        }
    }

    pub(crate) fn texture(&mut self, name: &str, span: &Range<usize>, d: &TextureDef) -> R<()> {
        let ctx = &self.ctx;
        let what = |f: &str| format!("textures.{name}.{f}");
        let texture = match d.kind.as_str() {
            "checker" => {
                if d.file.is_some() {
                    return Err(ctx.err(span, format!("{}: a checker has no file", what("file"))));
                }
                let space = match d.space.as_deref().unwrap_or("world_xz") {
                    "world_xz" => CheckerSpace::WorldXz,
                    "uv" => CheckerSpace::Uv,
                    other => {
                        return Err(ctx.err(
                            span,
                            format!("{}: expected \"world_xz\" or \"uv\", got {other:?}", what("space")),
                        ))
                    }
                };
                TextureKind::Checker {
                    even: ctx.colour(span, &what("even"), d.even.unwrap_or(Rgb(Vec3::splat(0.8))).0)?,
                    odd: ctx.colour(span, &what("odd"), d.odd.unwrap_or(Rgb(Vec3::splat(0.2))).0)?,
                    size: ctx.number(span, &what("size"), d.size.unwrap_or(1.0), 1e-6..1e9)?,
                    space,
                }
            }
            "image" => {
                if d.even.is_some() || d.odd.is_some() || d.size.is_some() || d.space.is_some() {
                    return Err(ctx.err(span, format!("textures.{name}: an image texture takes only `file`")));
                }
                let file = d
                    .file
                    .as_deref()
                    .ok_or_else(|| ctx.err(span, format!("{} is required", what("file"))))?;
                let path = check_asset_path(file).map_err(|e| ctx.err(span, e))?;
                let bytes = (self.assets.get(&path))
                    .ok_or_else(|| ctx.err(span, unreadable(self.assets, &what("file"), file)))?;
                let (width, height) = image_size(bytes).map_err(|e| {
                    ctx.err(span, format!("{}: {file:?} is not a readable image: {e}", what("file")))
                })?;
                // From the header, before any worker decodes it.
                if u64::from(width) * u64::from(height) > crate::limits::MAX_TEXTURE_PIXELS {
                    return Err(ctx.err(
                        span,
                        format!(
                            "{}: {file:?} is {width}x{height}, more than the limit of {} pixels for a texture",
                            what("file"),
                            crate::limits::MAX_TEXTURE_PIXELS
                        ),
                    ));
                }
                TextureKind::Image { file: path, width, height }
            }
            other => {
                return Err(ctx.err(
                    span,
                    format!("textures.{name}.type: expected \"checker\" or \"image\", got {other:?}"),
                ))
            }
        };
        let at = self.ctx.at(span);
        self.texture_index.insert(name.to_string(), self.textures.len() as u32);
        self.textures.push(Texture { name: name.to_string(), kind: texture, at });
        Ok(())
    }

    pub(crate) fn material(&mut self, name: &str, span: &Range<usize>, d: &MaterialDef) -> R<()> {
        let kind = d.kind.as_deref().unwrap_or("classic");
        let allowed: &[&str] = match kind {
            "classic" => &["color", "ambient", "diffuse", "specular", "shininess", "reflect", "transmit", "ior", "gloss", "translucency"],
            "lambert" => &["albedo"],
            "mirror" => &["reflectance"],
            "dielectric" => &["ior"],
            "conductor" => &["eta", "k", "metal", "roughness"],
            "rough_dielectric" => &["ior", "roughness"],
            "plastic" => &["albedo", "ior"],
            other => {
                return Err(self.ctx.err(
                    span,
                    format!("materials.{name}.type: unknown material {other:?}; expected one of classic, lambert, mirror, dielectric, conductor, rough_dielectric, plastic"),
                ))
            }
        };
        let set: [(&str, bool); 16] = [
            ("color", d.color.is_some()),
            ("ambient", d.ambient.is_some()),
            ("diffuse", d.diffuse.is_some()),
            ("specular", d.specular.is_some()),
            ("shininess", d.shininess.is_some()),
            ("reflect", d.reflect.is_some()),
            ("transmit", d.transmit.is_some()),
            ("gloss", d.gloss.is_some()),
            ("translucency", d.translucency.is_some()),
            ("ior", d.ior.is_some()),
            ("albedo", d.albedo.is_some()),
            ("reflectance", d.reflectance.is_some()),
            ("eta", d.eta.is_some()),
            ("k", d.k.is_some()),
            ("metal", d.metal.is_some()),
            ("roughness", d.roughness.is_some()),
        ];
        if let Some((field, _)) = set.iter().find(|(f, on)| *on && !allowed.contains(f)) {
            return Err(self.ctx.err(
                span,
                format!(
                    "materials.{name}: `{field}` does not apply to a {kind} material (it takes: {})",
                    allowed.join(", ")
                ),
            ));
        }
        let ctx = &self.ctx;
        let what = |f: &str| format!("materials.{name}.{f}");
        let ior = |default: f32| ctx.number(span, &what("ior"), d.ior.unwrap_or(default), 1e-3..100.0);
        let roughness = || ctx.number(span, &what("roughness"), d.roughness.unwrap_or(0.0), 0.0..4.0);
        let material = match kind {
            "classic" => Material::Classic(Classic {
                color: self.tex(
                    span,
                    &what("color"),
                    d.color.as_ref().unwrap_or(&ColorOrTexture::Color(Vec3::splat(0.8))),
                )?,
                ambient: ctx.number(span, &what("ambient"), d.ambient.unwrap_or(1.0), 0.0..1e3)?,
                diffuse: ctx.number(span, &what("diffuse"), d.diffuse.unwrap_or(1.0), 0.0..1e3)?,
                specular: ctx.number(span, &what("specular"), d.specular.unwrap_or(0.0), 0.0..1e3)?,
                shininess: ctx.number(span, &what("shininess"), d.shininess.unwrap_or(32.0), 0.0..1e6)?,
                reflect: ctx.colour(span, &what("reflect"), d.reflect.unwrap_or(black()).0)?,
                transmit: ctx.colour(span, &what("transmit"), d.transmit.unwrap_or(black()).0)?,
                ior: ior(1.5)?,
                gloss: ctx.number(span, &what("gloss"), d.gloss.unwrap_or(0.0), 0.0..4.0)?,
                translucency: ctx.number(
                    span,
                    &what("translucency"),
                    d.translucency.unwrap_or(0.0),
                    0.0..4.0,
                )?,
            }),
            "lambert" => Material::Lambert {
                albedo: self.tex(
                    span,
                    &what("albedo"),
                    d.albedo.as_ref().unwrap_or(&ColorOrTexture::Color(Vec3::splat(0.8))),
                )?,
            },
            "mirror" => Material::Mirror {
                reflectance: ctx.colour(
                    span,
                    &what("reflectance"),
                    d.reflectance.unwrap_or(Rgb(Vec3::ONE)).0,
                )?,
            },
            "dielectric" => Material::Dielectric { ior: ior(1.5)? },
            "rough_dielectric" => Material::RoughDielectric { ior: ior(1.5)?, roughness: roughness()? },
            "plastic" => Material::Plastic {
                diffuse: self.tex(
                    span,
                    &what("albedo"),
                    d.albedo.as_ref().unwrap_or(&ColorOrTexture::Color(Vec3::splat(0.5))),
                )?,
                ior: ior(1.5)?,
            },
            _ => {
                let (eta, k) = match (&d.metal, d.eta, d.k) {
                    (Some(m), None, None) => metal_preset(m).ok_or_else(|| {
                        ctx.err(
                            span,
                            format!(
                                "{}: unknown metal {m:?}; expected gold, copper, aluminium or silver",
                                what("metal")
                            ),
                        )
                    })?,
                    (None, Some(eta), Some(k)) => {
                        (ctx.colour(span, &what("eta"), eta.0)?, ctx.colour(span, &what("k"), k.0)?)
                    }
                    _ => {
                        return Err(ctx.err(
                            span,
                            format!(
                                "materials.{name}: a conductor takes either `metal` or both `eta` and `k`"
                            ),
                        ))
                    }
                };
                Material::Conductor { eta, k, roughness: roughness()? }
            }
        };
        self.material_index.insert(name.to_string(), self.materials.len() as u32);
        self.materials.push(material);
        Ok(())
    }

    pub(crate) fn material_of(&self, span: &Range<usize>, name: &str) -> R<u32> {
        self.material_index.get(name).copied().ok_or_else(|| {
            let known: Vec<&str> = self.material_index.keys().map(String::as_str).collect();
            self.ctx.err(span, format!("unknown material \"{name}\"; defined: [{}]", known.join(", ")))
        })
    }
}
