//! The building tests: what the description becomes in the renderer.

use std::sync::Arc;

use super::*;

const MINIMAL: &str = r#"
[render]
width = 8
height = 6

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]

[materials.red]
color = [1, 0, 0]

[[sphere]]
center = [0, 0, 0]
radius = 1
material = "red"
"#;

#[test]
fn minimal_scene_builds_with_defaults() {
    let s = parse_scene("t.toml", MINIMAL).unwrap();
    assert_eq!((s.width, s.height, s.spp, s.max_depth), (8, 6, 16, 8));
    assert_eq!(s.world.prims.len(), 1);
    assert!(!s.camera.has_lens() && !s.has_motion_blur());
}

#[test]
fn a_mesh_becomes_one_primitive_per_triangle() {
    struct One(&'static [u8]);
    impl Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "m.obj").then_some(self.0)
        }
    }
    let text = format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n");
    let quad = One(b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    let s = parse_scene_with_assets("t.toml", &text, &quad).unwrap();
    assert_eq!((s.world.prims.len(), s.world.meshes.len()), (3, 1));
    // Used again, moved: read once, each use its own copy in world space.
    let twice = format!(
        "{text}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\ntransform = {{ translate = [5, 0, 0] }}\n"
    );
    let s = parse_scene_with_assets("t.toml", &twice, &quad).unwrap();
    assert_eq!((s.world.prims.len(), s.world.meshes.len()), (5, 2));
    assert_eq!(s.world.meshes[1].p[0] - s.world.meshes[0].p[0], glam::Vec3::new(5.0, 0.0, 0.0));
}

/// Contract 6: a sample draws only the dimensions the scene uses.
#[test]
fn samples_pay_only_for_the_dimensions_used() {
    let used = |text: &str| {
        let s = parse_scene("t.toml", text).unwrap();
        let mut sampler = s.sampler();
        s.render_sample(&mut sampler, glam::UVec2::new(4, 3), 0);
        sampler.dimensions_used()
    };
    // A classic scene with no light at all: the pixel position only.
    assert_eq!(used(MINIMAL), 1);
    let lens = MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0]\naperture = 0.1");
    assert_eq!(used(&lens), 2);
    let moving =
        MINIMAL.replace("material = \"red\"", "material = \"red\"\nmotion = { translate = [1, 0, 0] }");
    assert_eq!(used(&moving), 2);
    assert!(parse_scene("t.toml", &moving).unwrap().has_motion_blur());
    let closed = moving.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0]\nshutter = [0, 0]");
    assert_eq!(used(&closed), 1);
}

#[test]
fn emitters_get_a_black_surface_and_a_light() {
    let s = parse_scene("t.toml", &MINIMAL.replace("material = \"red\"", "emission = 5")).unwrap();
    assert_eq!((s.world.materials.len(), s.world.lights.len()), (2, 1));
    assert_eq!(s.world.prims[0].light, Some(0));
}

#[test]
fn a_job_s_overrides_share_the_world() {
    let mut s = parse_scene("t.toml", MINIMAL).unwrap();
    let world = s.world.clone();
    s.apply(Some(3), Some((40, 30)));
    assert_eq!((s.width, s.height, s.spp), (40, 30, 3));
    assert!(Arc::ptr_eq(&world, &s.world));
}

/// A job in rounds draws the stratified scene's samples from Sobol's pattern (whose
/// prefixes are nets); an independent scene stays independent; a job drawn whole keeps
/// the scene's pattern.
#[test]
fn a_job_in_rounds_draws_sobol_s_pattern() {
    use crate::render::{Sampler, SamplerKind};
    let draws = |s: &crate::render::Scene, kind: Option<SamplerKind>| {
        let mut sampler = kind.map_or_else(|| s.sampler(), |k| Sampler::new(k, s.seed, s.spp));
        (0..8)
            .map(|i| {
                sampler.start_pixel_sample(glam::UVec2::new(3, 2), i);
                (sampler.get_2d(), sampler.get_1d())
            })
            .collect::<Vec<_>>()
    };
    let mut s = parse_scene("t.toml", MINIMAL).unwrap();
    s.apply(Some(1 << 20), None);
    assert_eq!(s.sampler, SamplerKind::Stratified);
    assert_eq!(draws(&s, None), draws(&s, Some(SamplerKind::Stratified)));
    s.progressive = true;
    assert_eq!(draws(&s, None), draws(&s, Some(SamplerKind::Sobol)));
    assert_ne!(draws(&s, None), draws(&s, Some(SamplerKind::Stratified)));
    s.sampler = SamplerKind::Independent;
    assert_eq!(draws(&s, None), draws(&s, Some(SamplerKind::Independent)));
}

#[test]
fn damaged_pixels_behind_a_good_header_fail_the_build_at_the_texture() {
    // A real 2x2 PNG, its image data chunk then spoiled.
    let img = image::RgbImage::from_pixel(2, 2, image::Rgb([200, 100, 50]));
    let mut png = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let idat = png.windows(4).position(|w| w == b"IDAT").unwrap();
    for b in &mut png[idat + 4..idat + 10] {
        *b ^= 0xA5;
    }
    let bundle = Bundle {
        name: "t.toml".into(),
        text: format!("{MINIMAL}\n[textures.wood]\ntype = \"image\"\nfile = \"w.png\"\n"),
        assets: vec![("w.png".into(), png)],
        refused: vec![],
    };
    let desc = Description::parse(&bundle).expect("the header is good");
    let e = build(&desc, &bundle).unwrap_err();
    assert!(e.message.contains("textures.wood.file: \"w.png\" is not a readable image"), "{e}");
    assert_eq!((e.file.as_str(), e.line), ("t.toml", 18));
}

/// The summary's per-item costs are at least what the renderer's types take.
#[test]
fn the_summary_costs_cover_the_renderer_types() {
    use tessera_description::summary as s;
    let size = |n: usize| n as u64;
    assert!(size(std::mem::size_of::<crate::render::shape::Primitive>()) <= s::PRIMITIVE_BYTES);
    assert!(size(std::mem::size_of::<[[u32; 3]; 3]>()) <= s::TRIANGLE_BYTES);
    assert!(size(std::mem::size_of::<crate::render::bvh::Aabb>()) <= 24);
    assert!(size(std::mem::size_of::<glam::Vec3>()) <= s::VEC3_BYTES);
}

/// The summary's BVH cost per primitive covers the peak of building one (the binary tree
/// of at most two nodes per primitive and the primitives' bounds, beside the folded nodes
/// and indices) and the slots kept after, on the trees that take the most nodes per
/// primitive: one primitive to a leaf (scenes of spheres and parallelograms) and small
/// triangle leaves, on scattered boxes, on boxes in a row, and on clusters of four with a
/// lone box split off each, which would pad three slots for every five primitives but
/// for `bvh::MAX_PADDING`.
#[test]
fn the_summary_bvh_cost_covers_the_nodes_and_slots() {
    use crate::render::bvh::{Aabb, Bvh, LeafPolicy, MAX_PADDING, PADDING_ALLOWANCE};
    use crate::render::sampler::hash_words;
    use tessera_description::summary as s;
    let unit = |w: &[u64]| (hash_words(w) >> 40) as f32 / (1u64 << 24) as f32;
    let scattered: Vec<Aabb> = (0..20_000u64)
        .map(|i| {
            let c = glam::Vec3::new(unit(&[i, 0]), unit(&[i, 1]), unit(&[i, 2])) * 100.0;
            Aabb { min: c, max: c + unit(&[i, 3]) }
        })
        .collect();
    let row: Vec<Aabb> = (0..20_000)
        .map(|i| Aabb {
            min: glam::Vec3::new(i as f32, 0.0, 0.0),
            max: glam::Vec3::new(i as f32 + 0.5, 1.0, 1.0),
        })
        .collect();
    let lone: Vec<Aabb> = (0..20_000)
        .map(|i| {
            let x = (i / 5) as f32 * 1000.0 + if i % 5 == 4 { 300.0 } else { (i % 5) as f32 };
            let min = glam::Vec3::new(x, 0.0, 0.0);
            Aabb { min, max: min + 0.001 }
        })
        .collect();
    // The primitives' bounds are held while the tree is built.
    let building = Bvh::BUILD_BYTES_PER_PRIMITIVE + std::mem::size_of::<Aabb>();
    let slot = crate::render::triangles::Slots::BYTES_PER_SLOT;
    for (name, boxes) in [("scattered", &scattered), ("row", &row), ("lone", &lone)] {
        for policy in [LeafPolicy::TRIANGLES, LeafPolicy::SHAPES] {
            let bvh = Bvh::build_with(boxes, policy);
            let padding = bvh.indices().len() - boxes.len();
            let most = (boxes.len() as f64 * MAX_PADDING) as usize + PADDING_ALLOWANCE;
            assert!(padding <= most, "{name} {policy:?}: {padding} padding slots");
            // A slot for every entry of the leaf order, the padding of leaves to blocks too.
            let slots = bvh.indices().len() * slot;
            let per = (bvh.bytes() + boxes.len() * building + slots) as f64 / boxes.len() as f64;
            assert!(
                per <= s::BVH_BYTES_PER_PRIMITIVE as f64,
                "{name} {policy:?}: {per:.1} bytes a primitive"
            );
        }
    }
}

#[test]
fn geometry_a_transform_overflows_fails_the_build_at_the_object() {
    struct One(&'static [u8]);
    impl Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "m.obj").then_some(self.0)
        }
    }
    let far = One(b"v 1e17 0 0\nv 0 1e17 0\nv 0 0 1e17\nf 1 2 3\n");
    let text = format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n");
    // Validation refuses it; a description changed past validation is caught when built.
    let mut desc = Description::parse_text("t.toml", &text, &far).unwrap();
    for o in desc.objects.iter_mut().skip(1) {
        o.transform.scale = glam::Vec3::splat(1e30);
    }
    let Err(e) = build(&desc, &far) else { panic!("overflowing geometry is refused") };
    assert_eq!(e.to_string(), "t.toml:18:1: the transformed geometry overflows to non-finite coordinates");
}

/// A PNG of `width × height` 8-bit RGB whose image data is `idat` (usually not enough).
fn png_declaring(width: u32, height: u32, idat: &[u8]) -> Vec<u8> {
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
    let chunk = |png: &mut Vec<u8>, kind: &[u8], data: &[u8]| {
        png.extend((data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend(data);
        png.extend(&body);
        png.extend(crc32(&body).to_be_bytes());
    };
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(width.to_be_bytes());
    ihdr.extend(height.to_be_bytes());
    ihdr.extend([8, 2, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"IDAT", idat);
    chunk(&mut png, b"IEND", &[]);
    png
}

#[test]
fn a_small_png_declaring_a_huge_image_is_refused_before_decoding() {
    let png = png_declaring(12_000, 12_000, &[0; 400_000]);
    let e = super::images::decode_image(&png).unwrap_err();
    assert!(matches!(e, image::ImageError::Limits(_)), "{e}");
    // Within the pixel budget but with data missing: an error, not a panic.
    let png = png_declaring(4096, 4096, &[0; 1000]);
    assert!(super::images::decode_image(&png).is_err());
    // And a good one decodes.
    let img = image::RgbImage::from_pixel(2, 2, image::Rgb([1, 2, 3]));
    let mut good = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut good), image::ImageFormat::Png)
        .unwrap();
    assert_eq!(super::images::decode_image(&good).unwrap().width(), 2);
}

#[test]
fn each_frame_of_an_animated_scene_builds_with_its_blur() {
    use crate::batch::{render_batch, Sums};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/bouncing_ball.toml");
    let bundle = Bundle::read(&path).unwrap();
    let render = |mut scene: Scene| {
        scene.apply(Some(2), Some((16, 10)));
        let pixels: Vec<glam::UVec2> = (0..160).map(|i| glam::UVec2::new(i % 16, i / 16)).collect();
        render_batch(&scene, &pixels, 0..2, Sums::Radiance).sums
    };
    // The scene without a frame is its first frame, to the bit.
    let first = render(parse_bundle(&bundle).unwrap());
    assert_eq!(first, render(parse_bundle_frame(&bundle, 1).unwrap()));
    // The ball moves during a frame's shutter; the camera dollies between frames.
    let frame7 = parse_bundle_frame_within(&bundle, Some(7), u64::MAX).unwrap();
    assert!(frame7.has_motion_blur());
    let origin = |s: &Scene| s.camera.generate_ray(glam::Vec2::ZERO, glam::Vec2::ZERO).origin;
    assert!(origin(&frame7).z < origin(&parse_bundle(&bundle).unwrap()).z);
    assert_ne!(first, render(frame7));
    let e = parse_bundle_frame(&bundle, 9).unwrap_err();
    assert!(e.to_string().contains("frame 9 is outside the animation's frames [1, 8]"), "{e}");
}

/// The old load: validation scans each OBJ, then the build parses it again.
fn two_reads(bundle: &Bundle) -> Result<Scene, SceneError> {
    build(&Description::parse(bundle)?, bundle)
}

/// A worker reads each OBJ file once (parsed ahead, its scan handed to validation): the
/// description, the tree and the image are those of the old two reads, bit for bit.
#[test]
fn one_read_of_each_obj_builds_what_two_reads_built() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    for name in ["mesh.toml", "emissive_mesh.toml", "showcase.toml"] {
        let bundle = Bundle::read(&root.join(name)).unwrap();
        let files = Description::mesh_files(&bundle);
        assert!(!files.is_empty(), "{name} names meshes");
        let meshes = read_meshes(&bundle, &files);
        assert_eq!(meshes.len(), files.len(), "{name}: every mesh read ahead");
        let scans = meshes.iter().map(|(f, p)| (f.clone(), (p.counts, p.extent))).collect();
        assert_eq!(
            Description::parse_scanned(&bundle, None, scans).unwrap(),
            Description::parse(&bundle).unwrap()
        );
        let (old, new) = (two_reads(&bundle).unwrap(), parse_bundle(&bundle).unwrap());
        assert_eq!(new.world.bvh.indices(), old.world.bvh.indices(), "{name}");
        assert_eq!(new.world.bvh.bounds(), old.world.bvh.bounds(), "{name}");
        let bits = |s: &Scene| -> Vec<u32> {
            s.world
                .meshes
                .iter()
                .flat_map(|m| m.p.iter().chain(&m.n))
                .flat_map(|p| p.to_array().map(f32::to_bits))
                .collect()
        };
        assert_eq!(bits(&new), bits(&old), "{name}");
        let pixels: Vec<glam::UVec2> =
            (0..48).map(|i| glam::UVec2::new(i * old.width / 48, (i * 7) % old.height)).collect();
        let sums = |s: &Scene| crate::batch::render_batch(s, &pixels, 0..2, crate::batch::Sums::Radiance);
        assert_eq!(sums(&new), sums(&old), "{name}");
    }
}

/// A broken, missing or foreign mesh file is refused by the one-read path with the old
/// path's one-line error, at the same place (the OBJ's line included), and an earlier
/// error still comes first.
#[test]
fn one_read_refuses_broken_meshes_as_two_reads_did() {
    let mut big = String::new();
    for i in 0..40_000 {
        big.push_str(&format!("v {} {} 0\n", i % 200, i / 200));
    }
    for i in 3..40_000 {
        big.push_str(&format!("f {} {} {}\n", i - 2, i - 1, i));
    }
    assert!(big.len() > 1 << 20, "large enough to be read in parallel chunks");
    let late = format!("{big}f 1 2 40001\n");
    let with = |obj: &[u8], extra: &str| Bundle {
        name: "t.toml".into(),
        text: format!("{MINIMAL}{extra}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n"),
        assets: vec![("m.obj".into(), obj.to_vec())],
        refused: vec![],
    };
    let cases: Vec<(Bundle, &str)> = vec![
        (with(b"v 0 0 0\nv 1 0 0\n\nf 1 2 7\n", ""), "line 4: vertex index 7 is out of range"),
        (with(late.as_bytes(), ""), "line 79998: vertex index 40001 is out of range"),
        (with(b"v 0 0 0\nv 1 0 0\nv 1 1 0\n", ""), "has no faces"),
        (with(b"v 0 0 0\nv 1 0 \xff0\n", ""), "is not text"),
        (
            with(
                b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n",
                "\n[[mesh]]\nfile = \"n.obj\"\nmaterial = \"red\"\n",
            ),
            "cannot read \"n.obj\"",
        ),
        // The sphere's error is met before the mesh's, in both paths.
        (with(b"bogus\n", "\n[[sphere]]\ncenter = [0, 0, 0]\nradius = -1\nmaterial = \"red\"\n"), "radius"),
    ];
    for (bundle, words) in cases {
        let old = two_reads(&bundle).expect_err("the old path refuses it");
        let new = parse_bundle(&bundle).expect_err("the one-read path refuses it");
        assert_eq!(new, old);
        assert!(new.to_string().contains(words), "{new}");
        assert!(!new.to_string().contains('\n'), "one line: {new}");
        assert_eq!(parse_bundle_within(&bundle, u64::MAX).unwrap_err(), LoadError::Scene(old.clone()));
        assert_eq!(parse_bundle_frame(&bundle, 0).unwrap_err(), old);
    }
    // A worker whose memory could not hold the parse scans first, as before.
    let bundle = with(late.as_bytes(), "");
    assert_eq!(
        parse_bundle_within(&bundle, 1 << 20).unwrap_err(),
        LoadError::Scene(two_reads(&bundle).unwrap_err())
    );
}
