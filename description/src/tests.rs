//! The validation tests: every refusal with its message and location.

use crate::bundle::{check_asset_path, Assets, NoAssets};
use crate::model::Shape;
use crate::{Description, SceneError};

fn parse_scene(file: &str, text: &str) -> Result<Description, SceneError> {
    Description::parse_text(file, text, &NoAssets)
}

fn parse_scene_with_assets(file: &str, text: &str, assets: &dyn Assets) -> Result<Description, SceneError> {
    Description::parse_text(file, text, assets)
}

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

fn err(text: &str) -> SceneError {
    parse_scene("t.toml", text).expect_err("scene should be refused")
}

#[test]
fn minimal_scene_parses_with_defaults() {
    let s = parse_scene("t.toml", MINIMAL).unwrap();
    let r = s.render;
    assert_eq!((r.width, r.height, r.spp, r.max_depth, r.diffuse_rays), (8, 6, 16, 8, 1));
    assert_eq!(s.objects.len(), 1);
    assert!(s.camera.lens_radius == 0.0 && s.objects[0].motion.is_none());
}

/// `diffuse_rays` is a count from 1 to its limit; anything else is refused where it is.
#[test]
fn diffuse_rays_are_counted_within_their_limit() {
    let with = |v: &str| MINIMAL.replace("height = 6", &format!("height = 6\ndiffuse_rays = {v}"));
    assert_eq!(parse_scene("t.toml", &with("8")).unwrap().render.diffuse_rays, 8);
    let most = crate::limits::MAX_DIFFUSE_RAYS;
    assert_eq!(parse_scene("t.toml", &with(&most.to_string())).unwrap().render.diffuse_rays, most);
    for bad in ["0".to_string(), (most + 1).to_string()] {
        let e = err(&with(&bad));
        assert_eq!((e.line, e.column), (5, 16), "{e}");
        assert!(e.message.contains(&format!("diffuse_rays must be 1..={most}, got {bad}")), "{e}");
    }
    for bad in ["-1", "2.5", "\"four\""] {
        let e = err(&with(bad));
        assert_eq!(e.line, 5, "{e}");
        assert!(e.message.contains("diffuse_rays") || e.message.contains("invalid"), "{bad}: {e}");
    }
}

#[test]
fn unknown_key_is_an_error_with_location() {
    let e = err(&MINIMAL.replace("radius = 1", "radius = 1\nradius_typo = 2"));
    assert_eq!((e.file.as_str(), e.line), ("t.toml", 16));
    assert!(e.message.contains("radius_typo"), "{e}");
}

#[test]
fn malformed_number_names_line_and_column() {
    let e = err(&MINIMAL.replace("width = 8", "width = 8x"));
    assert_eq!(e.line, 3, "{e}");
    assert!(e.column > 1, "{e}");
}

#[test]
fn negative_radius_is_refused() {
    let e = err(&MINIMAL.replace("radius = 1", "radius = -1"));
    assert!(e.message.contains("positive"), "{e}");
    // The sphere's table header.
    assert_eq!(e.line, 13);
}

#[test]
fn nan_is_refused() {
    let e = err(&MINIMAL.replace("center = [0, 0, 0]", "center = [nan, 0, 0]"));
    assert!(e.message.contains("finite"), "{e}");
}

#[test]
fn unknown_material_lists_known_ones() {
    let e = err(&MINIMAL.replace("material = \"red\"", "material = \"blue\""));
    assert!(e.message.contains("unknown material \"blue\"") && e.message.contains("red"), "{e}");
    let e = err(&MINIMAL.replace("color = [1, 0, 0]", "type = \"velvet\""));
    assert!(e.message.contains("unknown material \"velvet\""), "{e}");
    let e = err(&MINIMAL.replace("color = [1, 0, 0]", "type = \"lambert\"\nior = 1.3"));
    assert!(e.message.contains("`ior` does not apply to a lambert"), "{e}");
}

#[test]
fn bad_image_size_and_camera_are_refused() {
    assert!(err(&MINIMAL.replace("width = 8", "width = 0")).message.contains("image size"));
    assert!(err(&MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 5]")).message.contains("look_at"));
    assert!(err(&MINIMAL.replace("[camera]", "[cam]")).message.contains("cam"));
    let e = err(&MINIMAL.replace("look_at = [0, 0, 0]", "look_at = [0, 0, 0]\naperture = 0.1\nf_number = 2"));
    assert!(e.message.contains("not a mix"), "{e}");
}

#[test]
fn vectors_need_three_numbers() {
    let e = err(&MINIMAL.replace("center = [0, 0, 0]", "center = [0, 0]"));
    assert!(e.message.contains("three numbers"), "{e}");
}

#[test]
fn asset_paths_stay_in_the_scene_folder() {
    assert_eq!(check_asset_path("meshes/../bunny.obj").unwrap(), "bunny.obj");
    assert!(check_asset_path("../secret.obj").unwrap_err().contains("escapes"));
    assert!(check_asset_path("a/../../b.obj").unwrap_err().contains("escapes"));
    assert!(check_asset_path("/etc/passwd").unwrap_err().contains("relative"));
    let e = err(&format!("{MINIMAL}\n[[mesh]]\nfile = \"../x.obj\"\nmaterial = \"red\"\n"));
    assert!(e.message.contains("escapes") && e.line == 18, "{e}");
    let e = err(&format!("{MINIMAL}\n[[mesh]]\nfile = \"x.obj\"\nmaterial = \"red\"\n"));
    assert!(e.message.contains("cannot read \"x.obj\""), "{e}");
}

#[test]
fn broken_obj_is_reported_with_its_line() {
    struct One(&'static [u8]);
    impl Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "m.obj").then_some(self.0)
        }
    }
    let text = format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n");
    let e = parse_scene_with_assets("t.toml", &text, &One(b"v 0 0 0\nf 1 2 3\n")).unwrap_err();
    assert!(e.message.contains("line 2") && e.message.contains("out of range"), "{e}");
    let ok = parse_scene_with_assets("t.toml", &text, &One(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")).unwrap();
    assert_eq!(ok.objects.len(), 2);
    assert!(matches!(ok.objects[1].shape, Shape::Mesh { ref counts, .. } if counts.triangles == 1));
}

#[test]
fn emitters_and_motion_are_validated() {
    let e = err(&MINIMAL.replace("material = \"red\"", "material = \"red\"\nemission = 5"));
    assert!(e.message.contains("not both"), "{e}");
    let moving_light =
        MINIMAL.replace("material = \"red\"", "emission = 5\nmotion = { translate = [1, 0, 0] }");
    assert!(err(&moving_light).message.contains("cannot move"));
    let moving = parse_scene(
        "t.toml",
        &MINIMAL.replace("material = \"red\"", "material = \"red\"\nmotion = { translate = [1, 0, 0] }"),
    )
    .unwrap();
    assert!(moving.objects[0].motion.is_some());
    let e =
        err(&MINIMAL.replace("material = \"red\"", "material = \"red\"\ntransform = { scale = [1, 2, 1] }"));
    assert!(e.message.contains("uniform"), "{e}");
}

#[test]
fn the_triangle_budget_counts_every_use_before_building() {
    struct One(Vec<u8>);
    impl Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "m.obj").then_some(self.0.as_slice())
        }
    }
    // Fans of the most corners a face may have: a short file with many triangles.
    let corners = crate::limits::MAX_FACE_CORNERS;
    let faces = (crate::limits::MAX_TRIANGLES / 2) / (corners - 2) + 1;
    let n = faces * (corners - 2);
    let mut obj = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    let face = format!("f{}\n", " 1".repeat(corners));
    for _ in 0..faces {
        obj.push_str(&face);
    }
    let mesh = "\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n";
    let once = parse_scene_with_assets("t.toml", &format!("{MINIMAL}{mesh}"), &One(obj.clone().into_bytes()));
    assert_eq!(once.unwrap().objects[1].triangles(), n as u64);
    let e = parse_scene_with_assets("t.toml", &format!("{MINIMAL}{mesh}{mesh}"), &One(obj.into_bytes()))
        .unwrap_err();
    assert!(e.message.contains("more than") && e.message.contains("triangles") && e.line == 22, "{e}");
}

/// Assets holding only `m.obj`.
struct OneMesh(&'static [u8]);
impl Assets for OneMesh {
    fn get(&self, path: &str) -> Option<&[u8]> {
        (path == "m.obj").then_some(self.0)
    }
}

#[test]
fn a_face_with_too_many_corners_is_refused_before_anything_is_made() {
    let obj = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nf{}\n", " 1".repeat(crate::limits::MAX_FACE_CORNERS + 1));
    let obj: &'static [u8] = Box::leak(obj.into_bytes().into_boxed_slice());
    let text = format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n");
    let e = parse_scene_with_assets("t.toml", &text, &OneMesh(obj)).unwrap_err();
    assert_eq!(e.to_string(), "t.toml:18:1: mesh \"m.obj\": line 4: a face has more than 4096 corners");
}

#[test]
fn an_empty_mesh_is_refused_with_its_location() {
    let text = format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n");
    for empty in [&b""[..], b"# nothing\n", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"] {
        let e = parse_scene_with_assets("t.toml", &text, &OneMesh(empty)).unwrap_err();
        assert_eq!(e.to_string(), "t.toml:18:1: mesh \"m.obj\" has no faces (`f`): it would draw nothing");
    }
}

#[test]
fn a_transform_that_overflows_is_refused_with_its_location() {
    let far = b"v 1e20 0 0\nv 0 1e20 0\nv 0 0 1e20\nf 1 2 3\n";
    let mesh = |t: &str| format!("{MINIMAL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n{t}\n");
    let e =
        parse_scene_with_assets("t.toml", &mesh("transform = { scale = 1e30 }"), &OneMesh(far)).unwrap_err();
    assert_eq!((e.line, e.column), (18, 1), "{e}");
    assert!(e.message.starts_with("mesh: its transform takes it 1.732e50 from the origin"), "{e}");
    assert!(e.message.ends_with("beyond the limit of 1e18; its coordinates would overflow"), "{e}");
    // The motion's end counts too; an ordinary transform of the same mesh is fine.
    let moving = mesh("motion = { scale = 1e30 }");
    assert!(parse_scene_with_assets("t.toml", &moving, &OneMesh(far))
        .unwrap_err()
        .message
        .contains("overflow"));
    let near = b"v 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n";
    parse_scene_with_assets(
        "t.toml",
        &mesh("transform = { scale = 1e6, rotate = [0, 45, 0] }"),
        &OneMesh(near),
    )
    .unwrap();
    // Spheres, boxes, rectangles and triangles the same.
    let e = err(&MINIMAL.replace("radius = 1", "radius = 1e30\ntransform = { scale = 1e30 }"));
    assert!(e.message.starts_with("sphere: its transform takes it") && e.line == 13, "{e}");
    let e = err(&MINIMAL.replace("center = [0, 0, 0]", "center = [3e38, 3e38, 0]"));
    assert!(e.message.contains("overflow"), "{e}");
    let e = err(&format!(
        "{MINIMAL}\n[[triangle]]\nvertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nmaterial = \"red\"\n\
         transform = {{ translate = [1e19, 0, 0] }}\n"
    ));
    assert!(e.message.starts_with("triangle: its transform takes it 1.000e19") && e.line == 18, "{e}");
    let e = err(&format!(
        "{MINIMAL}\n[[box]]\nmin = [0, 0, 0]\nmax = [1e10, 1, 1]\nmaterial = \"red\"\ntransform = {{ scale = 1e10 }}\n"
    ));
    assert!(e.message.starts_with("box: its transform"), "{e}");
}

#[test]
fn a_mesh_used_many_times_is_scanned_once_and_counted_every_time() {
    // 8 MB of vertices and one triangle, used 2000 times: 16 GB of scanning were it scanned
    // per use.
    let mut obj = "v 0.5 0.5 0.5\n".repeat(8 << 20 >> 4);
    obj.push_str("f 1 2 3\n");
    let obj: &'static [u8] = Box::leak(obj.into_bytes().into_boxed_slice());
    let mesh = "\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"red\"\n";
    let text = format!("{MINIMAL}{}", mesh.repeat(2000));
    let start = std::time::Instant::now();
    let d = crate::Description::parse_text("t.toml", &text, &OneMesh(obj)).unwrap();
    assert!(start.elapsed() < std::time::Duration::from_secs(3), "{:?}", start.elapsed());
    assert_eq!(d.summary(false).triangles, 2000);
}
