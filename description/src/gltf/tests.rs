//! Known answers for the glTF import, and bad files with their exact one-line messages.

use base64::Engine;
use glam::Vec3;
use serde_json::{json, Value};

use crate::model::{Light, Material, Shape};
use crate::{Bundle, Description};

/// A buffer of three positions (a right triangle in z = 0) then three u16 indices.
fn triangle_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in v {
            b.extend(c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2] {
        b.extend(i.to_le_bytes());
    }
    b.extend([0, 0]);
    b
}

fn data_uri(bytes: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// One mesh of one triangle on node 0, in scene 0.
fn triangle() -> Value {
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"name": "main", "nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.5}}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 6}
        ],
        "buffers": [{"byteLength": 44, "uri": data_uri(&triangle_buffer())}]
    })
}

const RENDER: &str = "[render]\nwidth = 8\nheight = 6\nspp = 1\n";
const CAMERA: &str = "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n";

fn scene_with(doc: &Value, table: &str, camera: bool) -> Bundle {
    let text = format!("{RENDER}{}\n[[gltf]]\nfile = \"m.gltf\"\n{table}", if camera { CAMERA } else { "" });
    Bundle {
        name: "s.toml".into(),
        text,
        assets: vec![("m.gltf".into(), doc.to_string().into_bytes())],
        refused: vec![],
    }
}

fn parse(doc: &Value) -> Result<Description, String> {
    Description::parse(&scene_with(doc, "", true)).map_err(|e| e.to_string())
}

/// The message of a refused file, after the scene's location.
fn refused(doc: &Value) -> String {
    let e = parse(doc).unwrap_err();
    assert!(!e.contains('\n'), "{e}");
    e.strip_prefix("s.toml:9:1: ").unwrap_or(&e).to_string()
}

#[test]
fn a_triangle_becomes_an_object_with_its_material() {
    // POSITION's min and max are the specification's, computed when absent.
    let mut doc = triangle();
    doc["accessors"][0].as_object_mut().unwrap().retain(|k, _| k != "min" && k != "max");
    let d = parse(&doc).unwrap();
    assert_eq!(d.objects.len(), 1);
    assert_eq!(
        d.objects[0].shape,
        Shape::GltfPrimitive { file: "m.gltf".into(), mesh: 0, primitive: 0, triangles: 1, vertices: 3 }
    );
    let Material::Pbr(p) = d.materials[d.objects[0].material as usize] else { panic!("{:?}", d.materials) };
    assert_eq!(p.base_color, glam::Vec4::new(0.5, 0.25, 1.0, 1.0));
    assert_eq!((p.metallic, p.roughness, p.ior, p.transmission), (0.0, 0.5, 1.5, 0.0));
    assert_eq!(d.objects[0].emission, None);
    let s = d.summary(false);
    assert_eq!((s.objects, s.triangles), (1, 1));
}

#[test]
fn a_rotated_scaled_child_nodes_world_position() {
    let mut doc = triangle();
    let s = std::f32::consts::FRAC_1_SQRT_2;
    // The parent turns 90° about +y and moves 1 along x; the child moves 2 along z and
    // doubles in size. Mesh point (1, 0, 0): scaled (2, 0, 0), moved (2, 0, 2), turned
    // (2, 0, -2), moved (3, 0, -2).
    doc["nodes"] = json!([
        {"children": [1], "translation": [1, 0, 0], "rotation": [0, s, 0, s]},
        {"mesh": 0, "translation": [0, 0, 2], "scale": [2, 2, 2]}
    ]);
    let d = parse(&doc).unwrap();
    let m = d.objects[0].transform.matrix();
    assert!((m.transform_point3(Vec3::X) - Vec3::new(3.0, 0.0, -2.0)).length() < 1e-5, "{:?}", m);
    assert!((m.transform_point3(Vec3::ZERO) - Vec3::new(3.0, 0.0, 0.0)).length() < 1e-5);
    // The same given as the child's matrix (column-major), with the TOML table's
    // transform applied after the file's.
    doc["nodes"][1] = json!({"mesh": 0, "matrix": [2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 0, 0, 2, 1]});
    let b = scene_with(&doc, "transform = { translate = [0, 10, 0] }\n", true);
    let d = Description::parse(&b).unwrap();
    let m = d.objects[0].transform.matrix();
    assert!((m.transform_point3(Vec3::X) - Vec3::new(3.0, 10.0, -2.0)).length() < 1e-5);
}

#[test]
fn a_shearing_hierarchy_is_refused() {
    let mut doc = triangle();
    // 45° about z under a scale of 3 along y.
    let (s, c) = crate::math::sin_cos(std::f32::consts::FRAC_PI_8);
    doc["nodes"] = json!([
        {"children": [1], "scale": [1, 3, 1]},
        {"mesh": 0, "rotation": [0, 0, s, c]}
    ]);
    assert_eq!(
        refused(&doc),
        "m.gltf: nodes[1]: its world transform shears (a non-uniform scale under a rotation), which Tessera's translate/rotate/scale transforms cannot hold"
    );
}

#[test]
fn bad_files_get_one_line_naming_the_json_path() {
    type Case = (fn(&mut Value), &'static str);
    let cases: Vec<Case> = vec![
        (|d| d["meshes"][0]["primitives"][0]["indices"] = json!(9), "m.gltf: meshes[0].primitives[0].indices: accessor 9 does not exist"),
        (|d| d["nodes"][0]["mesh"] = json!(3), "m.gltf: nodes[0].mesh: mesh 3 does not exist"),
        (|d| d["accessors"][0]["bufferView"] = json!(7), "m.gltf: accessors[0].bufferView: buffer view 7 does not exist"),
        (
            |d| d["meshes"][0]["primitives"][0]["mode"] = json!(1),
            "m.gltf: meshes[0].primitives[0].mode: mode 1 (Lines) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only",
        ),
        (
            |d| d["meshes"][0]["primitives"][0]["attributes"] = json!({"NORMAL": 0}),
            "m.gltf: meshes[0].primitives[0].attributes[\"POSITION\"]: is missing",
        ),
        (
            |d| d["nodes"] = json!([{"mesh": 0, "children": [1]}, {"children": [0]}]),
            "m.gltf: nodes[0]: node 0 is its own ancestor: the node hierarchy has a cycle",
        ),
        (|d| d["nodes"] = json!([{"mesh": 0, "children": [0]}]), "m.gltf: nodes[0].children[0]: node 0 is its own child"),
        (
            |d| d["nodes"] = json!([{"mesh": 0, "children": [2]}, {"children": [2]}, {}]),
            "m.gltf: nodes[1].children[0]: node 2 already has parent nodes[0]: a node has at most one parent",
        ),
        (
            |d| d["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]),
            "m.gltf: extensionsRequired[0]: the file requires extension \"KHR_draco_mesh_compression\", which Tessera does not support (it reads KHR_lights_punctual, KHR_materials_emissive_strength, KHR_materials_ior, KHR_materials_transmission)",
        ),
        (
            |d| d["bufferViews"][1]["byteLength"] = json!(60),
            "m.gltf: bufferViews[1]: bytes 36..96 lie beyond the end of buffer 0 (44 bytes)",
        ),
        (
            |d| d["accessors"][0]["count"] = json!(4),
            "m.gltf: accessors[0]: 4 elements of 12 bytes (stride 12, offset 0) need more than buffer view 0 holds (36 bytes)",
        ),
        (
            |d| {
                d["accessors"][1]["count"] = json!(2);
            },
            "m.gltf: meshes[0].primitives[0].indices: accessor 1 holds 2 indices, not a multiple of 3 (TRIANGLES)",
        ),
        (
            |d| d["accessors"][0]["componentType"] = json!(5123),
            "m.gltf: meshes[0].primitives[0].attributes[\"POSITION\"]: accessor 0 is Vec3 of UNSIGNED_SHORT; POSITION must be VEC3 of FLOAT",
        ),
        (|d| d["buffers"][0]["byteLength"] = json!(100), "m.gltf: buffers[0].byteLength: declares 100 bytes, the data holds 44"),
        (
            |d| d["buffers"][0]["uri"] = json!("../outside.bin"),
            "m.gltf: buffers[0].uri: asset path \"../outside.bin\" escapes the scene's folder",
        ),
        (
            |d| d["buffers"][0]["uri"] = json!("beside.bin"),
            "m.gltf: buffers[0].uri: cannot read \"beside.bin\" (the URI \"beside.bin\", relative to the glTF file's folder)",
        ),
        (
            |d| d["materials"][0]["pbrMetallicRoughness"]["roughnessFactor"] = json!(2),
            "m.gltf: materials[0].pbrMetallicRoughness.roughnessFactor: 2 is not in [0, 1]",
        ),
        (|d| d["scene"] = json!(4), "m.gltf: scene: scene 4 does not exist"),
        (|d| d["asset"] = json!(7), "m.gltf: not a glTF 2.0 document: invalid type: integer `7`, expected struct Asset at line 1 column 178"),
    ];
    for (mutate, want) in cases {
        let mut doc = triangle();
        mutate(&mut doc);
        assert_eq!(refused(&doc), want);
    }
}

/// Index values past the vertex count: the buffer holds index 5.
#[test]
fn an_index_past_the_vertices_is_refused() {
    let mut buf = triangle_buffer();
    buf[40..42].copy_from_slice(&5u16.to_le_bytes());
    let mut doc = triangle();
    doc["buffers"][0]["uri"] = json!(data_uri(&buf));
    assert_eq!(
        refused(&doc),
        "m.gltf: meshes[0].primitives[0].indices: index 2 of accessor 1 is 5, but the primitive has 3 vertices"
    );
}

fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |v: &[u8], with: u8| {
        let mut v = v.to_vec();
        while !v.len().is_multiple_of(4) {
            v.push(with);
        }
        v
    };
    let (j, b) = (pad(json, b' '), pad(bin, 0));
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + 8 + j.len() + 8 + b.len()) as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&j);
    out.extend((b.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(&b);
    out
}

fn triangle_glb() -> Vec<u8> {
    let mut doc = triangle();
    doc["buffers"] = json!([{"byteLength": 44}]);
    glb(doc.to_string().as_bytes(), &triangle_buffer())
}

#[test]
fn a_glb_reads_its_binary_chunk() {
    let text = format!("{RENDER}{CAMERA}\n[[gltf]]\nfile = \"m.glb\"\n");
    let b = Bundle {
        name: "s.toml".into(),
        text,
        assets: vec![("m.glb".into(), triangle_glb())],
        refused: vec![],
    };
    let d = Description::parse(&b).unwrap();
    assert_eq!(d.summary(false).triangles, 1);
    let asset = super::Asset::open("m.glb", &b).unwrap();
    let g = asset.geometry(0, 0).unwrap();
    assert_eq!(g.positions, vec![Vec3::ZERO, Vec3::X, Vec3::Y]);
    assert_eq!(g.triangles, vec![[0, 1, 2]]);
    assert_eq!(g.normals, None);
}

/// Truncated and byte-flipped files: an error or a scene, never a panic, and every error
/// one line naming the file.
#[test]
fn damaged_files_never_panic() {
    let whole = triangle_glb();
    let text = triangle().to_string().into_bytes();
    let mut inputs: Vec<(&str, Vec<u8>)> = Vec::new();
    for cut in (0..whole.len()).step_by(3) {
        inputs.push(("m.glb", whole[..cut].to_vec()));
    }
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    for _ in 0..400 {
        for (name, base) in [("m.glb", &whole), ("m.gltf", &text)] {
            let mut m = base.clone();
            for _ in 0..3 {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let at = (seed % m.len() as u64) as usize;
                m[at] = (seed >> 32) as u8;
            }
            inputs.push((name, m));
        }
    }
    for (name, bytes) in inputs {
        let text = format!("{RENDER}{CAMERA}\n[[gltf]]\nfile = \"{name}\"\n");
        let b = Bundle { name: "s.toml".into(), text, assets: vec![(name.into(), bytes)], refused: vec![] };
        let got = std::panic::catch_unwind(|| Description::parse(&b).map(|_| ()).map_err(|e| e.to_string()));
        let got = got.unwrap_or_else(|_| panic!("panicked on {:?}", b.assets[0].1));
        if let Err(e) = got {
            assert!(!e.contains('\n') && e.contains(name), "{e}");
        }
    }
}

#[test]
fn the_files_camera_and_lights_are_used() {
    let mut doc = triangle();
    doc["nodes"] = json!([
        {"mesh": 0},
        {"camera": 0, "translation": [0, 0, 4]},
        {"extensions": {"KHR_lights_punctual": {"light": 0}}, "translation": [1, 2, 3]},
        {"extensions": {"KHR_lights_punctual": {"light": 1}}, "rotation": [-0.70710677, 0, 0, 0.70710677]},
        {"extensions": {"KHR_lights_punctual": {"light": 2}}, "translation": [0, 5, 0], "rotation": [-0.70710677, 0, 0, 0.70710677]}
    ]);
    doc["scenes"][0]["nodes"] = json!([0, 1, 2, 3, 4]);
    doc["cameras"] = json!([{"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}}]);
    doc["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    doc["extensions"] = json!({"KHR_lights_punctual": {"lights": [
        {"type": "point", "color": [1, 0.5, 0.25], "intensity": 8},
        {"type": "directional", "intensity": 3},
        {"type": "spot", "intensity": 2, "spot": {"innerConeAngle": 0.25, "outerConeAngle": 0.5}}
    ]}});
    let d = Description::parse(&scene_with(&doc, "", false)).unwrap();
    assert_eq!(d.camera.position, Vec3::new(0.0, 0.0, 4.0));
    assert!((d.camera.look_at - Vec3::new(0.0, 0.0, 3.0)).length() < 1e-6);
    assert_eq!(d.camera.fov, 0.5);
    assert_eq!(
        d.lights[0],
        Light::Point { position: Vec3::new(1.0, 2.0, 3.0), intensity: Vec3::new(8.0, 4.0, 2.0) }
    );
    // −90° about x turns −z (the light's direction) into −y: straight down.
    let Light::Directional { direction, irradiance } = d.lights[1] else { panic!() };
    assert!((direction - Vec3::NEG_Y).length() < 1e-5, "{direction}");
    assert_eq!(irradiance, Vec3::splat(3.0));
    let Light::Spot { position, direction, intensity, inner_cone, outer_cone } = d.lights[2] else {
        panic!()
    };
    assert!((direction - Vec3::NEG_Y).length() < 1e-5 && position == Vec3::new(0.0, 5.0, 0.0));
    assert_eq!((intensity, inner_cone, outer_cone), (Vec3::splat(2.0), 0.25, 0.5));
    // A TOML camera wins.
    let d = Description::parse(&scene_with(&doc, "", true)).unwrap();
    assert_eq!(d.camera.position, Vec3::new(0.0, 0.0, 5.0));
    // No camera at all.
    let e = Description::parse(&scene_with(&triangle(), "", false)).unwrap_err().to_string();
    assert_eq!(e, "s.toml:1:1: missing table [camera] (required unless a [[gltf]] asset has a camera)");
}

#[test]
fn emissive_materials_emit() {
    let mut doc = triangle();
    doc["materials"][0]["emissiveFactor"] = json!([1, 0.5, 0]);
    doc["materials"][0]["extensions"] = json!({"KHR_materials_emissive_strength": {"emissiveStrength": 4}});
    let d = parse(&doc).unwrap();
    assert_eq!(d.objects[0].emission, Some(Vec3::new(4.0, 2.0, 0.0)));
}

#[test]
fn scenes_are_chosen_by_name_or_index() {
    let mut doc = triangle();
    doc["nodes"] = json!([{"mesh": 0}, {"mesh": 0, "translation": [5, 0, 0]}]);
    doc["scenes"] = json!([{"name": "main", "nodes": [0]}, {"name": "other", "nodes": [1]}]);
    let at = |table: &str| {
        let d = Description::parse(&scene_with(&doc, table, true)).unwrap();
        d.objects[0].transform.translate
    };
    assert_eq!(at(""), Vec3::ZERO);
    assert_eq!(at("scene = 1\n"), Vec3::new(5.0, 0.0, 0.0));
    assert_eq!(at("scene = \"other\"\n"), Vec3::new(5.0, 0.0, 0.0));
    let e = Description::parse(&scene_with(&doc, "scene = \"nope\"\n", true)).unwrap_err().to_string();
    assert_eq!(e, "s.toml:9:1: m.gltf: scenes: no scene is named \"nope\" (named: [\"main\", \"other\"])");
}

#[test]
fn animation_is_sampled_over_the_shutter() {
    let mut doc = triangle();
    // Key times 0 and 2 s; translation x from 0 to 4 (linear).
    let mut buf = triangle_buffer();
    for t in [0f32, 2.0] {
        buf.extend(t.to_le_bytes());
    }
    for v in [0f32, 0.0, 0.0, 4.0, 0.0, 0.0] {
        buf.extend(v.to_le_bytes());
    }
    doc["buffers"] = json!([{"byteLength": buf.len(), "uri": data_uri(&buf)}]);
    doc["bufferViews"].as_array_mut().unwrap().push(json!({"buffer": 0, "byteOffset": 44, "byteLength": 8}));
    doc["bufferViews"].as_array_mut().unwrap().push(json!({"buffer": 0, "byteOffset": 52, "byteLength": 24}));
    doc["accessors"]
        .as_array_mut()
        .unwrap()
        .push(json!({"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR"}));
    doc["accessors"]
        .as_array_mut()
        .unwrap()
        .push(json!({"bufferView": 3, "componentType": 5126, "count": 2, "type": "VEC3"}));
    doc["animations"] = json!([{
        "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
        "samplers": [{"input": 2, "output": 3, "interpolation": "LINEAR"}]
    }]);
    let b = scene_with(&doc, "", true);
    let frame = crate::animation::FrameTime { frame: 12, open: 0.5, close: 1.0 };
    let imported = super::import("m.gltf", &b, None, &crate::transform::Trs::default(), Some(frame)).unwrap();
    let i = &imported.instances[0];
    assert_eq!(i.world.translate, Vec3::new(1.0, 0.0, 0.0));
    assert_eq!(i.motion.unwrap().translate, Vec3::new(2.0, 0.0, 0.0));
    // Without a frame: the node's rest pose.
    let d = Description::parse(&b).unwrap();
    assert_eq!((d.objects[0].transform.translate, d.objects[0].motion), (Vec3::ZERO, None));
    // In a TOML scene with an [animation], each frame plays the file's animation at the
    // frame's time (frame f starts at f / fps seconds).
    let text =
        format!("{RENDER}{CAMERA}[animation]\nfps = 2\nframes = [1, 4]\n[[gltf]]\nfile = \"m.gltf\"\n");
    let animated = Bundle { text, ..b.clone() };
    for (frame, x) in [(1, 1.0), (3, 3.0)] {
        let d = Description::parse_frame(&animated, frame).unwrap();
        assert_eq!(d.objects[0].transform.translate, Vec3::new(x, 0.0, 0.0), "frame {frame}");
    }
    // Times that go backwards are refused with the sampler's path.
    let mut bad = doc.clone();
    bad["accessors"][2]["bufferView"] = json!(3);
    bad["accessors"][2]["count"] = json!(6);
    bad["accessors"][2]["type"] = json!("SCALAR");
    let e = refused(&bad);
    assert!(e.starts_with("m.gltf: animations[0].samplers[0]: key "), "{e}");
}

#[test]
fn a_bundle_carries_the_buffers_beside_a_gltf() {
    let dir = tempfile::tempdir().unwrap();
    let mut doc = triangle();
    doc["buffers"][0]["uri"] = json!("bin/tri%20angle.bin");
    std::fs::create_dir(dir.path().join("models")).unwrap();
    std::fs::create_dir(dir.path().join("models/bin")).unwrap();
    std::fs::write(dir.path().join("models/m.gltf"), doc.to_string()).unwrap();
    std::fs::write(dir.path().join("models/bin/tri angle.bin"), triangle_buffer()).unwrap();
    let scene = dir.path().join("s.toml");
    std::fs::write(&scene, format!("{RENDER}{CAMERA}\n[[gltf]]\nfile = \"models/m.gltf\"\n")).unwrap();
    let b = Bundle::read(&scene).unwrap();
    let paths: Vec<&str> = b.assets.iter().map(|(p, _)| p.as_str()).collect();
    assert_eq!(paths, ["models/bin/tri angle.bin", "models/m.gltf"]);
    assert_eq!(Description::parse(&b).unwrap().summary(false).triangles, 1);
}

#[test]
fn the_framing_camera_sees_the_whole_box() {
    let c = super::framing_camera((Vec3::splat(-1.0), Vec3::splat(1.0)), 0.8, 1.0);
    assert_eq!(c.look_at, Vec3::ZERO);
    // The bounding sphere (radius √3) fits within the half-angle with its margin.
    let d = c.position.length();
    assert!(((3f32).sqrt() * 1.1 / d - crate::math::sin(0.4)).abs() < 1e-5, "{d}");
}

#[test]
fn a_glb_read_as_the_scene_is_framed_and_lit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tri.glb");
    std::fs::write(&path, triangle_glb()).unwrap();
    let b = Bundle::read(&path).unwrap();
    assert!(b.text.contains("[[gltf]]\nfile = \"tri.glb\"\n"), "{}", b.text);
    let d = Description::parse(&b).unwrap();
    assert_eq!((d.render.width, d.render.height, d.render.spp), (640, 480, super::wrap::DEFAULT_SPP));
    let sky = d.environment.as_ref().map(|e| (e.kind.clone(), e.strength));
    assert_eq!(
        sky,
        Some((crate::model::EnvironmentKind::Uniform(Vec3::splat(super::wrap::DEFAULT_SKY)), 1.0))
    );
    // The camera looks at the triangle's bounding box's centre.
    assert!((d.camera.look_at - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-5, "{:?}", d.camera);
    // A bad file is refused when read, in one line naming it and the JSON path.
    let mut doc = triangle();
    doc["meshes"][0]["primitives"][0]["indices"] = json!(9);
    std::fs::write(dir.path().join("bad.gltf"), doc.to_string()).unwrap();
    let e = Bundle::read(&dir.path().join("bad.gltf")).unwrap_err().to_string();
    assert_eq!(e, "bad.gltf: meshes[0].primitives[0].indices: accessor 9 does not exist");
}
