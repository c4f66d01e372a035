//! What a scene will cost, from its description alone: no geometry built, no image
//! decoded. The coordinator can refuse or place a job by it, and the CLI can show it
//! before submitting.
//!
//! Memory figures are estimates from per-item costs, rounded up from the renderer's own
//! types so that they err on the high side; a test in the worker checks each against
//! `size_of` of the type it stands for.

use crate::model::{Description, Shape, TextureKind};

/// Bytes per bounded primitive: the primitive itself (shape, material, light, motion).
pub const PRIMITIVE_BYTES: u64 = 96;
/// Bytes per primitive in the BVH, at the peak of building it and after: the binary tree
/// (at most two nodes of 36 bytes a primitive), the builder's boxes and bins (33), the
/// primitives' bounds (24), the slots in leaf order (48 bytes each: a primitive's index
/// and material, and its corners, a quarter of a 192-byte pack of four; a mesh's leaves
/// start on a pack, and the padding between them, a tenth more slots on the torus knot,
/// is at most a quarter more, `MAX_PADDING`, and 256 slots: 60 a primitive), and the
/// folded nodes of eight
/// with the primitive's index (75: up to 67 measured on the trees with the most nodes per
/// primitive). A worker test (`build::tests`) builds such trees, padding included, and
/// holds the total to this constant.
pub const BVH_BYTES_PER_PRIMITIVE: u64 = 2 * 36 + 33 + 24 + 60 + 75;
/// Bytes per triangle: three corners of (position, normal, uv) indices.
pub const TRIANGLE_BYTES: u64 = 36;
/// Bytes per mesh position or normal.
pub const VEC3_BYTES: u64 = 12;
/// Bytes per mesh texture coordinate.
pub const UV_BYTES: u64 = 8;
/// Bytes per image texel at the peak of decoding: the decoded 8-bit RGBA image, the
/// linear floats and the texels kept.
pub const TEXEL_BYTES: u64 = 4 + 12 + 12;
/// Bytes per environment-map texel, bounding the peak of building from above: the decoded
/// float image, the linear floats, the radiance kept, the luminance weights and the
/// sampling distribution's pdf, CDF and guide-table entries.
pub const ENVIRONMENT_TEXEL_BYTES: u64 = 16 + 12 + 12 + 4 + 8 + 4;
/// Bytes per pixel of the coordinator's framebuffer: sums of three channels in fixed
/// point, a sample count and the version that last changed it, and a share of its tile's
/// (`Framebuffer::bytes_for` is the exact figure; a coordinator test checks that they
/// agree).
pub const FRAMEBUFFER_BYTES_PER_PIXEL: u64 = 37;
/// Extra bytes per pixel when the framebuffer also keeps the sums of even samples (for a
/// noise target).
pub const EVEN_SUMS_BYTES_PER_PIXEL: u64 = 8;

/// A scene's size and cost.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Summary {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Bounded objects and infinite planes.
    pub objects: u64,
    /// Triangles, every use of a mesh counted.
    pub triangles: u64,
    /// Width and height of every image texture.
    pub textures: Vec<(u32, u32)>,
    /// Estimated peak memory of a worker holding the built scene.
    pub worker_bytes: u64,
    /// Estimated memory of the coordinator for the job: framebuffer and bundle.
    pub coordinator_bytes: u64,
}

impl Description {
    /// The scene's size and cost; `even_sums` when the job keeps even-sample sums (a
    /// noise target), which the coordinator's framebuffer pays for.
    pub fn summary(&self, even_sums: bool) -> Summary {
        let (mut primitives, mut triangles, mut vertices, mut uvs) = (0u64, 0u64, 0u64, 0u64);
        for o in &self.objects {
            primitives += o.primitives();
            triangles += o.triangles();
            match &o.shape {
                Shape::Triangle { .. } => vertices += 3,
                // Every use of a mesh is its own copy: static ones are baked into world space.
                Shape::Mesh { counts, .. } => {
                    vertices += (counts.positions + counts.normals) as u64;
                    uvs += counts.uvs as u64;
                }
                // A glTF primitive's vertices carry a position, a normal and a texture
                // coordinate each (the normal computed when absent).
                Shape::GltfPrimitive { vertices: n, .. } => {
                    vertices += 2 * n;
                    uvs += n;
                }
                _ => {}
            }
        }
        let textures: Vec<(u32, u32)> =
            self.textures
                .iter()
                .filter_map(|t| match t.kind {
                    TextureKind::Image { width, height, .. }
                    | TextureKind::GltfImage { width, height, .. } => Some((width, height)),
                    TextureKind::Checker { .. } => None,
                })
                .collect();
        let texels: u64 = textures.iter().map(|&(w, h)| u64::from(w) * u64::from(h)).sum();
        let environment_texels = match &self.environment {
            Some(crate::model::Environment {
                kind: crate::model::EnvironmentKind::Map { width, height, .. },
                ..
            }) => u64::from(*width) * u64::from(*height),
            _ => 0,
        };
        let worker_bytes = primitives * (PRIMITIVE_BYTES + BVH_BYTES_PER_PRIMITIVE)
            + triangles * TRIANGLE_BYTES
            + vertices * VEC3_BYTES
            + uvs * UV_BYTES
            + texels * TEXEL_BYTES
            + environment_texels * ENVIRONMENT_TEXEL_BYTES
            + self.bundle_bytes;
        let pixels = u64::from(self.render.width) * u64::from(self.render.height);
        let per_pixel = FRAMEBUFFER_BYTES_PER_PIXEL + if even_sums { EVEN_SUMS_BYTES_PER_PIXEL } else { 0 };
        Summary {
            width: self.render.width,
            height: self.render.height,
            spp: self.render.spp,
            objects: (self.objects.len() + self.planes.len()) as u64,
            triangles,
            textures,
            worker_bytes,
            coordinator_bytes: pixels * per_pixel + self.bundle_bytes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Bundle;

    const BASE: &str = r#"
[render]
width = 8
height = 6
spp = 4

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]

[materials.red]
color = [1, 0, 0]
"#;

    const QUAD: &[u8] = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";

    fn bundle(extra: &str, assets: Vec<(String, Vec<u8>)>) -> Bundle {
        Bundle { name: "t.toml".into(), text: format!("{BASE}{extra}"), assets, refused: vec![] }
    }

    #[test]
    fn a_mesh_used_twice_counts_twice() {
        let mesh = "\n[[mesh]]\nfile = \"q.obj\"\nmaterial = \"red\"\n";
        let once = bundle(mesh, vec![("q.obj".into(), QUAD.to_vec())]);
        let twice = bundle(&format!("{mesh}{mesh}"), once.assets.clone());
        let (a, b) = (
            Description::parse(&once).unwrap().summary(false),
            Description::parse(&twice).unwrap().summary(false),
        );
        assert_eq!((a.objects, a.triangles), (1, 2));
        assert_eq!((b.objects, b.triangles), (2, 4));
        let geometry = |s: &Summary, bundle: &Bundle| {
            let bytes =
                bundle.text.len() + bundle.assets.iter().map(|(p, d)| p.len() + d.len()).sum::<usize>();
            s.worker_bytes - bytes as u64
        };
        assert_eq!(geometry(&b, &twice), 2 * geometry(&a, &once));
    }

    #[test]
    fn the_coordinator_pays_per_pixel_and_for_the_bundle() {
        let b = bundle("\n[[sphere]]\nmaterial = \"red\"\n", vec![]);
        let mut d = Description::parse(&b).unwrap();
        let text = b.text.len() as u64;
        let s = d.summary(false);
        assert_eq!((s.width, s.height, s.spp, s.objects, s.triangles), (8, 6, 4, 1, 0));
        assert_eq!(s.coordinator_bytes, 48 * 37 + text);
        assert_eq!(d.summary(true).coordinator_bytes, 48 * 45 + text);
        d.apply(Some(64), Some((100, 10)));
        let s = d.summary(false);
        assert_eq!((s.width, s.height, s.spp), (100, 10, 64));
        assert_eq!(s.coordinator_bytes, 1000 * 37 + text);
    }

    /// A PNG's header: signature, IHDR and an empty IDAT for a `w × h` 8-bit RGB image. No pixel data
    /// follows, so decoding it would fail: the summary must not need to.
    fn png_header(w: u32, h: u32) -> Vec<u8> {
        let mut ihdr = b"IHDR".to_vec();
        ihdr.extend(w.to_be_bytes());
        ihdr.extend(h.to_be_bytes());
        ihdr.extend([8, 2, 0, 0, 0]);
        let crc = crc32(&ihdr);
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend(13u32.to_be_bytes());
        png.extend(ihdr);
        png.extend(crc.to_be_bytes());
        // The reader stops at the first data chunk's header: an empty one, cut short.
        png.extend(0u32.to_be_bytes());
        png.extend(b"IDAT");
        png.extend(crc32(b"IDAT").to_be_bytes());
        png
    }

    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
            }
        }
        !crc
    }

    #[test]
    fn a_huge_image_is_counted_from_its_header() {
        let text = "\n[textures.big]\ntype = \"image\"\nfile = \"big.png\"\n";
        let b = bundle(text, vec![("big.png".into(), png_header(8192, 8192))]);
        let s = Description::parse(&b).unwrap().summary(false);
        assert_eq!(s.textures, vec![(8192, 8192)]);
        assert!(s.worker_bytes >= 8192 * 8192 * TEXEL_BYTES, "{}", s.worker_bytes);
        // A 0.4 MB file may declare 12000x12000: refused from its header.
        let b = bundle(text, vec![("big.png".into(), png_header(12_000, 12_000))]);
        let e = Description::parse(&b).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.toml:14:1: textures.big.file: \"big.png\" is 12000x12000, more than the limit of 67108864 pixels for a texture"
        );
        let junk = bundle(text, vec![("big.png".into(), b"not an image".to_vec())]);
        let e = Description::parse(&junk).unwrap_err();
        assert!(e.message.contains("\"big.png\" is not a readable image"), "{e}");
    }
}
