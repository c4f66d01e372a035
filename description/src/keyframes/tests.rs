//! Keyframes end to end: scenes parsed at a frame, and their refusals.

use glam::{Quat, Vec3};

use crate::model::{Description, Light};
use crate::{Bundle, SceneError};

const BASE: &str = r#"
[render]
width = 8
height = 6

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
shutter = [0, 0.5]

[materials.red]
color = [1, 0, 0]
"#;

fn bundle(text: &str) -> Bundle {
    Bundle { name: "a.toml".into(), text: text.to_string(), assets: vec![], refused: vec![] }
}

fn frame(text: &str, f: u32) -> Description {
    Description::parse_frame(&bundle(text), f).unwrap_or_else(|e| panic!("{e}"))
}

fn err(text: &str, f: u32) -> SceneError {
    Description::parse_frame(&bundle(text), f).expect_err("should be refused")
}

/// A sphere keyed from x = 0 at frame 0 to x = 8 at frame 8 at 4 fps.
fn moving(interpolation: &str, shutter: &str) -> String {
    format!(
        "{}\n[animation]\nfps = 4\nframes = [0, 8]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
         interpolation = \"{interpolation}\"\n\
         keys = [{{ frame = 0, translate = [0, 0, 0] }}, {{ frame = 8, translate = [8, 0, 0] }}]\n",
        BASE.replace("shutter = [0, 0.5]", shutter)
    )
}

#[test]
fn a_still_scene_is_the_same_at_every_frame() {
    let text =
        format!("{BASE}\n[[sphere]]\nradius = 1\nmaterial = \"red\"\nmotion = {{ translate = [1, 0, 0] }}\n");
    let still = Description::parse(&bundle(&text)).unwrap();
    assert_eq!(still.frames(), None);
    assert_eq!(frame(&text, 7), still);
    assert_eq!(still.camera.shutter, (0.0, 0.5));
}

#[test]
fn parse_is_the_first_frame() {
    let text = moving("linear", "shutter = [0, 0.5]");
    let first = Description::parse(&bundle(&text)).unwrap();
    assert_eq!(first, frame(&text, 0));
    assert_eq!(first.frames(), Some((0, 8)));
    assert_eq!(first.sequence.unwrap().fps, 4.0);
}

#[test]
fn each_frame_blurs_over_its_shutter() {
    let text = moving("linear", "shutter = [0, 0.5]");
    let d = frame(&text, 2);
    let o = &d.objects[0];
    // Frame 2 opens at 2/4 s (x = 2) and closes half a frame later (x = 2.5).
    assert_eq!(o.transform.translate, Vec3::new(2.0, 0.0, 0.0));
    assert_eq!(o.motion.unwrap().translate, Vec3::new(2.5, 0.0, 0.0));
    // The renderer's motion interval is now the shutter itself.
    assert_eq!(d.camera.shutter, (0.0, 1.0));
    let t = d.sequence.unwrap().time;
    assert_eq!((t.frame, t.open, t.close), (2, 0.5, 0.625));
    // The last frame's shutter lies past the last key: held, no motion.
    let last = frame(&text, 8);
    assert_eq!(last.objects[0].transform.translate, Vec3::new(8.0, 0.0, 0.0));
    assert_eq!(last.objects[0].motion, None);
}

#[test]
fn a_closed_shutter_or_step_keys_make_no_motion() {
    let instant = frame(&moving("linear", "shutter = [0, 0]"), 3);
    assert_eq!(instant.objects[0].transform.translate, Vec3::new(3.0, 0.0, 0.0));
    assert_eq!(instant.objects[0].motion, None);
    assert_eq!(instant.camera.shutter, (0.0, 0.0));
    let step = frame(&moving("step", "shutter = [0, 0.5]"), 5);
    assert_eq!(step.objects[0].transform.translate, Vec3::ZERO);
    assert_eq!(step.objects[0].motion, None);
}

#[test]
fn a_frame_on_its_key_has_the_tables_bits() {
    // Keyed where the table stands, with a shutter that sees no change: the same
    // description as the still scene, so its image keeps its bytes.
    let still = format!(
        "{BASE}\n[[sphere]]\nradius = 1\nmaterial = \"red\"\ntransform = {{ translate = [1, 2, 3] }}\n"
    );
    let keyed = format!(
        "{still}keys = [{{ frame = 1, translate = [1, 2, 3] }}, {{ frame = 2, translate = [1, 2, 3] }}]\n\
         [animation]\nframes = [1, 2]\n"
    );
    let (a, b) = (frame(&still, 1), frame(&keyed, 1));
    assert_eq!(a.objects, b.objects);
    assert_eq!(b.objects[0].motion, None);
}

#[test]
fn cubic_keys_follow_catmull_rom() {
    // Keys 0, 1, 0 at 0, 1 and 2 s. At 0.5 s: tangents 1 (one-sided) and 0 (centred),
    // p = ½·0 + ⅛·1 + ½·1 − ⅛·0 = 0.625. On a key the value is the key's.
    let text = format!(
        "{}\n[animation]\nfps = 2\nframes = [0, 4]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
         interpolation = \"cubic\"\n\
         [[sphere.keys]]\nframe = 0\ntranslate = [0, 0, 0]\n\
         [[sphere.keys]]\nframe = 2\ntranslate = [0, 1, 0]\n\
         [[sphere.keys]]\nframe = 4\ntranslate = [0, 0, 0]\n",
        BASE.replace("shutter = [0, 0.5]", "shutter = [0, 0]")
    );
    let y = |f| frame(&text, f).objects[0].transform.translate.y;
    assert!((y(1) - 0.625).abs() < 1e-6, "{}", y(1));
    assert_eq!(y(2), 1.0);
    assert!((y(3) - 0.625).abs() < 1e-6, "{}", y(3));
    assert_eq!(y(4), 0.0);
}

#[test]
fn rotations_interpolate_their_angles() {
    // Two full turns over 8 frames: a quarter of the way is half a turn.
    let text = format!(
        "{}\n[animation]\nframes = [0, 8]\n\n[[box]]\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\nmaterial = \"red\"\n\
         keys = [{{ frame = 0, rotate = [0, 0, 0] }}, {{ frame = 8, rotate = [0, 720, 0] }}]\n",
        BASE.replace("shutter = [0, 0.5]", "shutter = [0, 0]")
    );
    let q = frame(&text, 2).objects[0].transform.rotate;
    assert!(q.angle_between(Quat::from_rotation_y(std::f32::consts::PI)) < 1e-4, "{q:?}");
    let q = frame(&text, 4).objects[0].transform.rotate;
    assert!(q.angle_between(Quat::IDENTITY) < 1e-4, "{q:?}");
}

#[test]
fn a_scene_motion_spans_each_frame_and_is_cut_to_the_shutter() {
    let text = format!(
        "{BASE}\n[animation]\nframes = [1, 3]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
         motion = {{ translate = [4, 0, 0] }}\n"
    );
    let d = frame(&text, 2);
    assert_eq!(d.objects[0].transform.translate, Vec3::ZERO);
    assert_eq!(d.objects[0].motion.unwrap().translate, Vec3::new(2.0, 0.0, 0.0));
    assert_eq!(d.camera.shutter, (0.0, 1.0));
}

#[test]
fn camera_and_lights_take_their_values_at_shutter_open() {
    let text = format!(
        "{BASE}\n[animation]\nfps = 1\nframes = [0, 4]\n\n\
         [[point_light]]\nposition = [0, 5, 0]\nintensity = 10\ncolor = [1, 0.5, 0]\n\
         keys = [{{ frame = 0, intensity = 0 }}, {{ frame = 4, intensity = 40, position = [4, 5, 0] }}]\n\
         [[directional_light]]\ndirection = [0, -1, 0]\nirradiance = 2\n\
         keys = [{{ frame = 0, direction = [1, 0, 0] }}, {{ frame = 2, direction = [0, 0, -1] }}]\n"
    )
    .replace(
        "look_at = [0, 0, 0]\n",
        "look_at = [0, 0, 0]\nfov = 40\n\
         keys = [{ frame = 0, position = [0, 0, 5], fov = 40 }, { frame = 4, position = [0, 0, 9], fov = 20 }]\n",
    );
    let d = frame(&text, 1);
    assert_eq!(d.camera.position, Vec3::new(0.0, 0.0, 6.0));
    assert!((d.camera.fov - 35f32.to_radians()).abs() < 1e-6);
    // No focus distance given: focus follows the distance to look_at.
    assert_eq!(d.camera.focus_distance, 6.0);
    let Light::Point { position, intensity } = d.lights[0] else { panic!() };
    // The position track has one key: held.
    assert_eq!(position, Vec3::new(4.0, 5.0, 0.0));
    assert_eq!(intensity, Vec3::new(10.0, 5.0, 0.0));
    let Light::Directional { direction, irradiance } = d.lights[1] else { panic!() };
    assert!((direction - Vec3::new(0.5, 0.0, -0.5).normalize()).length() < 1e-6);
    assert_eq!(irradiance, Vec3::splat(2.0));
}

#[test]
fn refusals_name_what_and_where() {
    let ok = moving("linear", "shutter = [0, 0.5]");
    let cases: Vec<(String, u32, &str)> = vec![
        (ok.replace("translate = [8, 0, 0]", "translat = [8, 0, 0]"), 0, "translat"),
        (ok.replace("frame = 8", "frame = 9"), 0, "frame 9 is outside the animation's frames [0, 8]"),
        (ok.replace("frame = 0,", "frame = 8,"), 0, "frame 8 must come after the previous key's frame 8"),
        (ok.replace("\"linear\"", "\"bezier\""), 0, "expected \"linear\", \"step\" or \"cubic\""),
        (ok.replace("[animation]\nfps = 4\nframes = [0, 8]\n", ""), 0, "need an [animation] table"),
        (ok.clone(), 9, "frame 9 is outside the animation's frames [0, 8]"),
        (ok.replace("frames = [0, 8]", "frames = [8, 0]"), 0, "first <= last"),
        (ok.replace("fps = 4", "fps = 0"), 0, "animation.fps must be in (0, 1000]"),
        (
            ok.replace("material = \"red\"\n", "material = \"red\"\nmotion = { translate = [1, 0, 0] }\n"),
            0,
            "`motion` or `keys`",
        ),
        (ok.replace("translate = [8, 0, 0]", "scale = [1, 2, 1]"), 0, "scale must be uniform"),
        (ok.replace(", translate = [8, 0, 0]", ""), 0, "the key at frame 8 sets nothing"),
        (ok.replace("translate = [8, 0, 0]", "translate = [1e30, 0, 0]"), 0, "beyond the limit"),
    ];
    for (text, f, want) in cases {
        let e = err(&text, f);
        assert!(e.message.contains(want), "want {want:?}, got {e}");
        assert_eq!(e.file, "a.toml");
        assert!(e.line > 1, "{e}");
    }
    // Scale keys that cross zero are refused at the frame that reaches it.
    let through = ok
        .replace("[[sphere]]\nradius = 1", "[[box]]\nmin = [-1, -1, -1]\nmax = [1, 1, 1]")
        .replace("translate = [0, 0, 0]", "scale = 1")
        .replace("translate = [8, 0, 0]", "scale = -1");
    frame(&through, 3);
    let e = err(&through, 4);
    assert!(e.message.contains("box: at frame 4 its scale is"), "{e}");
    // The camera flying through its look_at point.
    let cam = BASE.replace(
        "look_at = [0, 0, 0]\n",
        "look_at = [0, 0, 0]\nkeys = [{ frame = 0, position = [0, 0, 5] }, { frame = 2, position = [0, 0, -5] }]\n",
    ) + "[animation]\nframes = [0, 2]\n";
    let e = err(&cam, 1);
    assert!(e.message.contains("camera: at frame 1"), "{e}");
    assert_eq!(e.line, 6, "{e}");
}

#[test]
fn a_key_error_points_at_its_key() {
    let text = format!(
        "{BASE}\n[animation]\nframes = [1, 10]\n\n[[sphere]]\nradius = 1\nmaterial = \"red\"\n\
         [[sphere.keys]]\nframe = 5\ntranslate = [0, 1, 0]\n\
         [[sphere.keys]]\nframe = 2.5\ntranslate = [0, 2, 0]\n"
    );
    let e = err(&text, 1);
    let line = text.lines().position(|l| l == "frame = 2.5").unwrap();
    assert_eq!(e.line, line, "{e}");
    assert!(e.message.contains("frame 2.5 must come after the previous key's frame 5"), "{e}");
    // Fractional frames are keys between frames.
    let ok = text.replace("frame = 2.5", "frame = 7.5");
    let d = frame(&ok.replace("shutter = [0, 0.5]", "shutter = [0, 0]"), 10);
    assert_eq!(d.objects[0].transform.translate, Vec3::new(0.0, 2.0, 0.0));
}
