//! The AOV layers' tests end to end: scenes parsed by `build`, rendered in batches by
//! `batch` with the first hits of `aov`. They sit in a module of their own above all
//! three, so that `aov` needs neither the batch renderer nor the scene builder, which
//! depend on it.
#![cfg(test)]

use glam::{UVec2, Vec3};

use crate::aov::{background_albedo, emitted_albedo, first_hit};
use crate::batch::{render_batch, render_batch_layers, Sums};
use crate::build::parse_scene;
use tessera_film::aov::{AovLayers, Layout};
use tessera_film::Quad;

/// A white Lambert wall at z = -2 facing a camera at the origin looking down -z, lit
/// by a point light; a thin lens, so that the lens dimension is drawn too.
const WALL: &str = r#"
[render]
width = 8
height = 6
spp = 4
background = [0.1, 0.2, 0.3]

[camera]
position = [0, 0, 0]
look_at = [0, 0, -1]
fov = 30
aperture = 0.05
focus_distance = 2

[materials.white]
type = "lambert"
albedo = [0.9, 0.8, 0.7]

[[plane]]
point = [0, 0, -2]
normal = [0, 0, 1]
material = "white"

[[point_light]]
position = [0, 0, 0]
intensity = 4
"#;

const ALL: Layout = Layout { albedo: true, normal: true, depth: true };

fn pixels(w: u32, h: u32) -> Vec<UVec2> {
    (0..h).flat_map(|y| (0..w).map(move |x| UVec2::new(x, y))).collect()
}

#[test]
fn layers_leave_the_radiance_bits_alone() {
    let scene = parse_scene("wall.toml", WALL).unwrap();
    let px = pixels(8, 6);
    let plain = render_batch(&scene, &px, 0..4, Sums::WithEven);
    let layered = render_batch_layers(&scene, &px, 0..4, Sums::WithEven, ALL);
    assert_eq!((&plain.sums, &plain.even), (&layered.sums, &layered.even));
    assert_eq!(layered.aov.len(), px.len() * 8);
}

#[test]
fn a_wall_gives_its_colour_its_normal_and_its_distance() {
    let scene = parse_scene("wall.toml", WALL).unwrap();
    let px = pixels(8, 6);
    let quads: Vec<Quad> = px.iter().map(|p| Quad { x: p.x, y: p.y, w: 1, h: 1 }).collect();
    let r = render_batch_layers(&scene, &px, 0..4, Sums::Radiance, ALL);
    let mut layers = AovLayers::new(ALL, 8, 6);
    layers.merge(&quads, 4, &r.aov).unwrap();
    let out = layers.resolve(|_, _| 4);
    for a in out.albedo.chunks(3) {
        assert!((a[0] - 0.9).abs() < 1e-6 && (a[1] - 0.8).abs() < 1e-6 && (a[2] - 0.7).abs() < 1e-6, "{a:?}");
    }
    for n in out.normal.chunks(3) {
        assert!(n[0].abs() < 1e-6 && n[1].abs() < 1e-6 && (n[2] - 1.0).abs() < 1e-6, "{n:?}");
    }
    // The distance along each ray: 2 at the centre, 2 / cos θ towards the corners
    // (half the 30° vertical field of view, and more across the diagonal).
    for &d in &out.depth {
        assert!((2.0..2.0 / 0.93).contains(&d), "{d}");
    }
}

#[test]
fn rays_that_escape_see_the_background() {
    let scene = parse_scene("wall.toml", &WALL.replace("[0, 0, -2]", "[0, 0, 2]")).unwrap();
    let hit = first_hit(&scene, &mut scene.sampler(), UVec2::new(3, 3), 0);
    assert_eq!(hit, None);
    assert_eq!(background_albedo(&scene), [0.1, 0.2, 0.3]);
    assert_eq!(emitted_albedo(Vec3::new(10.0, 5.0, 0.0)), [1.0, 0.5, 0.0]);
}
