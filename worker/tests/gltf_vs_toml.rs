//! A glTF model renders as the same model written by hand in TOML: `scenes/gltf_quad/`
//! holds a hand-written `quad.gltf` (buffers and one image as `data:` URIs, one image
//! beside it) and `quad.toml`, the same quad as an OBJ with the equivalent Lambertian
//! material and the same texture. The glTF scene is the TOML one with its mesh, material
//! and texture swapped for the glTF primitive, metallic-roughness material and glTF image
//! that the description's glTF loader makes of `quad.gltf`; both are built and rendered by
//! the worker and compared within noise. Alpha cut-outs are checked on the same files: a
//! fully cut-out occluder changes no bit, a half cut-out one hides half of what lies
//! behind it.

use std::collections::HashMap;
use std::path::Path;

use glam::{UVec2, Vec3, Vec4};
use tessera_description::bundle::{Assets, Bundle};
use tessera_description::math;
use tessera_description::model::{AlphaMode, Description, Material, Object, Pbr, Shape, TexRef, TextureKind};
use tessera_film::fixed;
use tessera_worker::batch::{render_batch, Sums};

/// The files of `scenes/gltf_quad/` by name.
struct Dir(HashMap<String, Vec<u8>>);

impl Assets for Dir {
    fn get(&self, path: &str) -> Option<&[u8]> {
        self.0.get(path).map(Vec::as_slice)
    }
}

fn dir() -> (Dir, Bundle) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/gltf_quad");
    let files = ["quad.gltf", "quad.obj", "checker.png"]
        .into_iter()
        .map(|f| (f.to_string(), std::fs::read(root.join(f)).unwrap()))
        .collect();
    (Dir(files), Bundle::read(&root.join("quad.toml")).unwrap())
}

/// The glTF materials of `quad.gltf`, as its loader reads them.
fn checker_material(texture: u32) -> Pbr {
    Pbr {
        base_color: Vec4::ONE,
        base_color_texture: Some(TexRef { texture, texcoord: 0 }),
        metallic: 0.0,
        roughness: 1.0,
        metallic_roughness_texture: None,
        normal_texture: None,
        emissive: Vec3::ZERO,
        emissive_texture: None,
        alpha: AlphaMode::Opaque,
        double_sided: true,
        ior: 1.0,
        transmission: 0.0,
    }
}

fn gltf_image(image: u32, width: u32, height: u32) -> TextureKind {
    TextureKind::GltfImage { file: "quad.gltf".into(), image, width, height }
}

/// The TOML scene with its quad, material and texture taken from `quad.gltf`.
fn gltf_scene(toml: &Description) -> Description {
    let mut d = toml.clone();
    d.textures[0].kind = gltf_image(0, 4, 4);
    d.materials[0] = Material::Pbr(checker_material(0));
    d.objects[0].shape =
        Shape::GltfPrimitive { file: "quad.gltf".into(), mesh: 0, primitive: 0, triangles: 2, vertices: 4 };
    d
}

/// `quad.gltf`'s mesh 1 in front of the quad, with its MASK material; `alpha` scales the
/// base colour's alpha factor.
fn with_occluder(d: &Description, alpha: f32) -> Description {
    let mut d = d.clone();
    let mut cut = d.textures[0].clone();
    cut.kind = gltf_image(1, 2, 1);
    d.textures.push(cut);
    d.materials.push(Material::Pbr(Pbr {
        base_color: Vec4::new(0.9, 0.1, 0.1, alpha),
        base_color_texture: Some(TexRef { texture: 1, texcoord: 0 }),
        alpha: AlphaMode::Mask(0.5),
        ..checker_material(1)
    }));
    let occluder = Object {
        shape: Shape::GltfPrimitive {
            file: "quad.gltf".into(),
            mesh: 1,
            primitive: 0,
            triangles: 2,
            vertices: 4,
        },
        material: d.materials.len() as u32 - 1,
        ..d.objects[0].clone()
    };
    d.objects.push(occluder);
    d
}

/// Linear RGB per pixel, top row first.
fn render(d: &Description, assets: &dyn Assets) -> Vec<Vec3> {
    let scene = tessera_worker::build::build(d, assets).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (scene.width, scene.height);
    let mut out = Vec::new();
    for row in 0..h {
        let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, h - 1 - row)).collect();
        let sums = render_batch(&scene, &pixels, 0..scene.spp, Sums::Radiance);
        out.extend(sums.sums.chunks_exact(3).map(|c| {
            Vec3::new(
                fixed::mean(c[0], scene.spp),
                fixed::mean(c[1], scene.spp),
                fixed::mean(c[2], scene.spp),
            )
        }));
    }
    out
}

#[test]
fn a_gltf_model_renders_as_the_same_model_written_in_toml() {
    let (assets, bundle) = dir();
    let toml = Description::parse(&bundle).unwrap();
    let by_hand = render(&toml, &bundle);
    let gltf = render(&gltf_scene(&toml), &assets);
    let mean = by_hand.iter().map(|c| c.element_sum()).sum::<f32>() / (3 * by_hand.len()) as f32;
    assert!(mean > 0.05, "the quad is lit: mean {mean}");
    let lit = by_hand.iter().filter(|c| c.max_element() > 0.02).count();
    assert!(lit > by_hand.len() / 3, "the quad fills the frame: {lit} lit pixels");
    let mut worst = 0.0f32;
    let mut total = 0.0f32;
    for (a, b) in by_hand.iter().zip(&gltf) {
        let d = (*a - *b).abs().max_element();
        worst = worst.max(d);
        total += d;
    }
    let mean_diff = total / by_hand.len() as f32;
    eprintln!("glTF against TOML: mean level {mean}, worst pixel {worst}, mean difference {mean_diff}");
    // Same geometry, same texels, same samples: what differs is Schlick's layer
    // (< 1e-5 at these angles) and the edge texels' wrap (repeat in both, but glTF's v
    // is flipped), so within a small fraction of the image's level.
    assert!(worst < 0.02 * mean.max(1.0) + 0.01, "worst pixel differs by {worst} (mean level {mean})");
    assert!(mean_diff < 0.002, "mean difference {mean_diff}");
    // And the texture is the right way up: the top-left quadrant is the red texel.
    let (w, h) = (bundle_size(&toml).0 as usize, bundle_size(&toml).1 as usize);
    let top_left = gltf[(h / 2 - 3) * w + (w / 2 - 3)];
    assert!(top_left.x > 2.0 * top_left.y && top_left.x > 2.0 * top_left.z, "top left is {top_left}");
    let bottom_right = gltf[(h / 2 + 3) * w + (w / 2 + 3)];
    assert!(bottom_right.x > 2.0 * bottom_right.z && bottom_right.y > 2.0 * bottom_right.z, "{bottom_right}");
}

/// The same, with the glTF file placed by the description's own loader (`[[gltf]]` in
/// `quad_gltf.toml`): its material, image and primitive are the ones the test above
/// writes by hand, and the render is the same.
#[test]
fn a_gltf_table_renders_as_the_hand_written_scene() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/gltf_quad");
    let (_, bundle) = dir();
    let toml = Description::parse(&bundle).unwrap();
    let placed = Bundle::read(&root.join("quad_gltf.toml")).unwrap();
    let desc = Description::parse(&placed).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        matches!(desc.materials.last(), Some(Material::Pbr(p)) if p.ior == 1.0 && p.base_color_texture.is_some())
    );
    let by_hand = render(&toml, &bundle);
    let gltf = render(&desc, &placed);
    let worst = by_hand.iter().zip(&gltf).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
    eprintln!("[[gltf]] against TOML: worst pixel {worst}");
    assert!(worst < 0.01, "worst pixel differs by {worst}");
}

fn bundle_size(d: &Description) -> (u32, u32) {
    (d.render.width, d.render.height)
}

#[test]
fn alpha_cut_outs_are_no_hits() {
    let (assets, bundle) = dir();
    let toml = Description::parse(&bundle).unwrap();
    let plain = gltf_scene(&toml);
    let without = render(&plain, &assets);
    // Alpha factor 0: every hit on the occluder is cut out, for camera and shadow rays
    // alike, and the any-hit path finds exactly the plain path's hits.
    let gone = render(&with_occluder(&plain, 0.0), &assets);
    assert!(without
        .iter()
        .zip(&gone)
        .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)));
    // Alpha factor 1: the texture's left half (alpha 0) is cut out, its right half is an
    // opaque red occluder.
    let half = render(&with_occluder(&plain, 1.0), &assets);
    let (w, h) = (toml.render.width as usize, toml.render.height as usize);
    let row = h / 2;
    let (left, right) = (w / 2 - 4, w / 2 + 4);
    assert_eq!(
        half[row * w + left].to_array().map(f32::to_bits),
        without[row * w + left].to_array().map(f32::to_bits)
    );
    let r = half[row * w + right];
    assert!(r.x > 4.0 * r.y && r.x > 4.0 * r.z, "the occluder's opaque half is red: {r}");
}

/// An emissive glTF primitive is a light whose radiance the emissive texture multiplies
/// where rays meet it: seen directly, each quadrant shows its texel's sRGB-decoded colour
/// times the emissive factor.
#[test]
fn the_emissive_texture_multiplies_the_emission() {
    let (assets, bundle) = dir();
    let toml = Description::parse(&bundle).unwrap();
    let mut d = gltf_scene(&toml);
    let factor = Vec3::new(2.0, 1.0, 0.5);
    d.materials[0] = Material::Pbr(Pbr {
        emissive: factor,
        emissive_texture: Some(TexRef { texture: 0, texcoord: 0 }),
        ..checker_material(0)
    });
    d.objects[0].emission = Some(factor);
    d.lights.clear();
    let img = render(&d, &assets);
    let (w, h) = (toml.render.width as usize, toml.render.height as usize);
    let decode = |c: u8| {
        let v = f32::from(c) / 255.0;
        math::powf((v + 0.055) / 1.055, 2.4)
    };
    // Pixels at the quadrants' centres (±0.5): bilinear lookups there blend only texels
    // of the quadrant's own colour.
    for ((dx, dy), texel) in
        [((-6i32, -6i32), [200u8, 40, 40]), ((5, 5), [230, 210, 60]), ((-6, 5), [50, 70, 200])]
    {
        let px = img[(h as i32 / 2 + dy) as usize * w + (w as i32 / 2 + dx) as usize];
        let want = Vec3::new(decode(texel[0]), decode(texel[1]), decode(texel[2])) * factor;
        assert!((px - want).abs().max_element() < 1e-3, "pixel {px}, texel {want}");
    }
}
