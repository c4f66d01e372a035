//! Textures: constant colours, a procedural checker, and images looked up by UV; glTF's
//! images with their sampler's wrap modes, read as sRGB-encoded colour or as linear data.

use glam::{Vec2, Vec3, Vec4};
use tessera_description::math;

pub use tessera_description::model::CheckerSpace;

/// A texture.
#[derive(Debug, Clone)]
pub enum Texture {
    /// `even` where floor(a) + floor(b) is even, else `odd`, with (a, b) the coordinates
    /// divided by `size`.
    Checker {
        /// Colour of even squares.
        even: Vec3,
        /// Colour of odd squares.
        odd: Vec3,
        /// Edge of one square.
        size: f32,
        /// Coordinates.
        space: CheckerSpace,
    },
    /// A linear-RGB image, bilinearly filtered, repeating; v = 0 is the bottom row.
    Image {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Linear RGB, top row first.
        texels: Vec<Vec3>,
    },
    /// A glTF image: RGBA, bilinearly filtered with its sampler's wrap modes; v = 0 is the
    /// top row (glTF's convention). Colour roles read it sRGB-decoded, data roles
    /// (metallic-roughness, normals) as stored.
    Rgba(Box<Rgba>),
}

/// How texture coordinates outside [0, 1] map into the image (glTF sampler wrap modes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wrap {
    /// The image repeats (glTF's default).
    #[default]
    Repeat,
    /// The edge texel extends.
    ClampToEdge,
    /// The image repeats mirrored every other time.
    MirroredRepeat,
}

impl Wrap {
    /// The texel index for integer texel coordinate `i` in an image `n` texels wide.
    fn index(self, i: i64, n: i64) -> i64 {
        match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::ClampToEdge => i.clamp(0, n - 1),
            Wrap::MirroredRepeat => {
                let k = i.rem_euclid(2 * n);
                if k < n {
                    k
                } else {
                    2 * n - 1 - k
                }
            }
        }
    }
}

/// A glTF image as both its roles read it, each decoded once at build time (only the
/// roles the scene uses).
#[derive(Debug, Clone)]
pub struct Rgba {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Wrap modes along u and v.
    pub wrap: [Wrap; 2],
    /// The stored values in [0, 1], top row first: for data roles.
    pub linear: Option<Vec<Vec4>>,
    /// RGB decoded from sRGB, alpha as stored: for colour roles.
    pub srgb: Option<Vec<Vec4>>,
}

/// How a texture lookup reads an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Colour: sRGB-encoded RGB (base colour, emissive).
    Srgb,
    /// Data: the stored values (metallic-roughness, normals, occlusion).
    Linear,
}

impl Rgba {
    /// An image from its stored RGBA values in [0, 1] (top row first), with the roles
    /// the scene reads it in decoded.
    pub fn new(
        width: u32,
        height: u32,
        wrap: [Wrap; 2],
        stored: Vec<Vec4>,
        srgb: bool,
        linear: bool,
    ) -> Rgba {
        let decoded = srgb.then(|| {
            stored
                .iter()
                .map(|c| Vec4::new(srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z), c.w))
                .collect()
        });
        Rgba { width, height, wrap, linear: linear.then_some(stored), srgb: decoded }
    }

    /// The bilinearly filtered value at `uv` (glTF: (0, 0) is the top-left corner of the
    /// image), in `encoding`; a role the image was not decoded for reads as 1.
    pub fn lookup(&self, uv: Vec2, encoding: Encoding) -> Vec4 {
        let texels = match encoding {
            Encoding::Srgb => self.srgb.as_deref(),
            Encoding::Linear => self.linear.as_deref(),
        };
        let Some(texels) = texels else { return Vec4::ONE };
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        let x = uv.x * w as f32 - 0.5;
        let y = uv.y * h as f32 - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return texels[0];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        // Far-away coordinates saturate; the wrap then maps them into the image.
        let (i, j) = (x0.clamp(-1e9, 1e9) as i64, y0.clamp(-1e9, 1e9) as i64);
        let at = |i: i64, j: i64| texels[(self.wrap[1].index(j, h) * w + self.wrap[0].index(i, w)) as usize];
        at(i, j).lerp(at(i + 1, j), fx).lerp(at(i, j + 1).lerp(at(i + 1, j + 1), fx), fy)
    }
}

/// A colour parameter: constant or textured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Tex {
    /// A constant colour.
    Const(Vec3),
    /// A texture by index.
    Map(u32),
}

impl Texture {
    /// The colour at a surface point.
    pub fn eval(&self, p: Vec3, uv: Vec2) -> Vec3 {
        match self {
            Texture::Checker { even, odd, size, space } => {
                let c = match space {
                    CheckerSpace::WorldXz => Vec2::new(p.x, p.z),
                    CheckerSpace::Uv => uv,
                } / *size;
                // (⌊x⌋ + ⌊y⌋) mod 2 is the low bit of the sum, that of the two low bits'
                // exclusive or.
                if (floor_i64(c.x) ^ floor_i64(c.y)) & 1 == 0 {
                    *even
                } else {
                    *odd
                }
            }
            Texture::Image { width, height, texels } => {
                let (w, h) = (*width as i64, *height as i64);
                let x = uv.x.rem_euclid(1.0) * w as f32 - 0.5;
                let y = (1.0 - uv.y.rem_euclid(1.0)) * h as f32 - 0.5;
                let (x0, y0) = (x.floor(), y.floor());
                let (fx, fy) = (x - x0, y - y0);
                let at = |i: i64, j: i64| texels[(j.rem_euclid(h) * w + i.rem_euclid(w)) as usize];
                let (i, j) = (x0 as i64, y0 as i64);
                at(i, j).lerp(at(i + 1, j), fx).lerp(at(i, j + 1).lerp(at(i + 1, j + 1), fx), fy)
            }
            Texture::Rgba(t) => t.lookup(uv, Encoding::Srgb).truncate(),
        }
    }

    /// RGBA at `uv` read in `encoding`: glTF images as their role reads them; the other
    /// textures give their colour with alpha 1.
    pub fn rgba(&self, p: Vec3, uv: Vec2, encoding: Encoding) -> Vec4 {
        match self {
            Texture::Rgba(t) => t.lookup(uv, encoding),
            _ => self.eval(p, uv).extend(1.0),
        }
    }
}

/// `x.floor() as i64`. Written out because `f32::floor` on baseline x86-64 (SSE2, no
/// rounding instruction) is a call: it was 0.9 % of a `spheres` profile, whose
/// checkerboard ground calls it at every hit. Truncation rounds towards zero, one too high below
/// zero where `x` is not whole; the casts saturate (and take NaN to 0) as `floor`'s does.
#[inline]
fn floor_i64(x: f32) -> i64 {
    let t = x as i64;
    if t as f32 > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// The sRGB transfer function inverted: an encoded value in [0, 1] to linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        math::powf((v + 0.055) / 1.055, 2.4)
    }
}

/// An image as linear RGB, top row first: float images (EXR) as stored, 8-bit ones
/// decoded from sRGB. Returns width, height and 3 floats a pixel.
pub fn linear_rgb(img: &image::DynamicImage) -> (u32, u32, Vec<f32>) {
    let is_float = matches!(img.color(), image::ColorType::Rgb32F | image::ColorType::Rgba32F);
    let rgb = img.to_rgb32f();
    let (w, h) = rgb.dimensions();
    let values = rgb.into_raw().into_iter().map(|v| if is_float { v } else { srgb_to_linear(v) }).collect();
    (w, h, values)
}

impl Tex {
    /// The colour at a surface point.
    pub fn eval(&self, textures: &[Texture], p: Vec3, uv: Vec2) -> Vec3 {
        match self {
            Tex::Const(c) => *c,
            Tex::Map(i) => textures[*i as usize].eval(p, uv),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `floor_i64` against `floor` and the cast: values around the sixteenths from −256
    /// to 256, around powers of two up to past i64's range, the specials, and a million
    /// bit patterns.
    #[test]
    fn floor_i64_is_floor_then_the_cast() {
        let check = |x: f32| assert_eq!(floor_i64(x), x.floor() as i64, "{x:e} ({:#x})", x.to_bits());
        for i in -(1 << 12)..(1 << 12) {
            let x = i as f32 / 16.0;
            for v in [x, x.next_up(), x.next_down()] {
                check(v);
            }
        }
        for e in 0..70u32 {
            let x = f32::from_bits((127 + e) << 23);
            for v in [x, -x, x.next_up(), x.next_down(), -x.next_up(), -x.next_down()] {
                check(v);
            }
        }
        for v in
            [0.0, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN, f32::MIN_POSITIVE]
        {
            check(v);
        }
        for k in 0..1_000_000u64 {
            check(f32::from_bits(crate::render::sampler::hash_words(&[k, 13]) as u32));
        }
    }

    #[test]
    fn checker_alternates_in_world_xz() {
        let t =
            Texture::Checker { even: Vec3::ONE, odd: Vec3::ZERO, size: 1.0, space: CheckerSpace::WorldXz };
        assert_eq!(t.eval(Vec3::new(0.5, 9.0, 0.5), Vec2::ZERO), Vec3::ONE);
        assert_eq!(t.eval(Vec3::new(1.5, 0.0, 0.5), Vec2::ZERO), Vec3::ZERO);
        assert_eq!(t.eval(Vec3::new(-0.5, 0.0, 0.5), Vec2::ZERO), Vec3::ZERO);
        assert_eq!(t.eval(Vec3::new(-0.5, 0.0, -0.5), Vec2::ZERO), Vec3::ONE);
    }

    #[test]
    fn image_lookup_hits_texel_centres() {
        let t = Texture::Image { width: 2, height: 1, texels: vec![Vec3::X, Vec3::Y] };
        assert!((t.eval(Vec3::ZERO, Vec2::new(0.25, 0.5)) - Vec3::X).length() < 1e-6);
        assert!((t.eval(Vec3::ZERO, Vec2::new(0.75, 0.5)) - Vec3::Y).length() < 1e-6);
    }

    fn rgba(stored: Vec<Vec4>, w: u32, h: u32, wrap: Wrap) -> Rgba {
        Rgba::new(w, h, [wrap; 2], stored, true, true)
    }

    #[test]
    fn wrap_modes_map_outside_coordinates() {
        assert_eq!((0..6).map(|i| Wrap::Repeat.index(i - 3, 3)).collect::<Vec<_>>(), [0, 1, 2, 0, 1, 2]);
        assert_eq!((0..6).map(|i| Wrap::ClampToEdge.index(i - 3, 3)).collect::<Vec<_>>(), [0, 0, 0, 0, 1, 2]);
        assert_eq!(
            (0..9).map(|i| Wrap::MirroredRepeat.index(i - 3, 3)).collect::<Vec<_>>(),
            [2, 1, 0, 0, 1, 2, 2, 1, 0]
        );
        // Two texels, black then white: at u = 1.25 repeat is back in the black texel,
        // clamp stays white, mirror reads the white one again.
        let t = |wrap| rgba(vec![Vec4::ZERO, Vec4::ONE], 2, 1, wrap);
        let at = |wrap, u| t(wrap).lookup(Vec2::new(u, 0.5), Encoding::Linear).x;
        assert!(at(Wrap::Repeat, 1.25).abs() < 1e-6);
        assert!((at(Wrap::ClampToEdge, 1.25) - 1.0).abs() < 1e-6);
        assert!((at(Wrap::MirroredRepeat, 1.25) - 1.0).abs() < 1e-6);
        // Between the texel centres it is bilinear: a quarter of the way.
        assert!((at(Wrap::ClampToEdge, 0.375) - 0.25).abs() < 1e-6);
    }

    #[test]
    fn colour_roles_decode_srgb_and_data_roles_do_not() {
        let t = rgba(vec![Vec4::new(0.5, 0.04045, 1.0, 0.5)], 1, 1, Wrap::Repeat);
        let c = t.lookup(Vec2::splat(0.5), Encoding::Srgb);
        // sRGB 0.5 is linear 0.214; alpha is never decoded.
        assert!(
            (c.x - 0.214_041).abs() < 1e-5
                && (c.y - 0.04045 / 12.92).abs() < 1e-7
                && c.z == 1.0
                && c.w == 0.5
        );
        assert_eq!(t.lookup(Vec2::splat(0.5), Encoding::Linear), Vec4::new(0.5, 0.04045, 1.0, 0.5));
        // glTF's v runs down the image: v near 0 reads the top row.
        let tall = rgba(vec![Vec4::ONE, Vec4::ZERO], 1, 2, Wrap::ClampToEdge);
        assert_eq!(tall.lookup(Vec2::new(0.5, 0.1), Encoding::Linear), Vec4::ONE);
        // A role the image was not decoded for is never read from garbage.
        let only_data = Rgba::new(1, 1, [Wrap::Repeat; 2], vec![Vec4::ZERO], false, true);
        assert_eq!(only_data.lookup(Vec2::ZERO, Encoding::Srgb), Vec4::ONE);
    }
}
