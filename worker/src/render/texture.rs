//! Textures: constant colours, a procedural checker, and images looked up by UV.

use glam::{Vec2, Vec3};

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
                let parity = (c.x.floor() as i64 + c.y.floor() as i64).rem_euclid(2);
                if parity == 0 {
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
        }
    }
}

/// The sRGB transfer function inverted: an encoded value in [0, 1] to linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
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
}
