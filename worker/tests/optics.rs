//! The effects checked against what optics predicts, not against stored images: the
//! thin-lens circle of confusion, penumbra widths, motion smear, roughness 0 as a mirror,
//! a known radiance, and convergence with the sample count.

mod common;

use common::{lum, render};
use tessera_description::math;

/// The lit extent (first and last pixel above `threshold`) of row `row`.
fn lit_extent(w: u32, img: &[[f32; 3]], row: u32, threshold: f32) -> Option<(u32, u32)> {
    let r = &img[(row * w) as usize..((row + 1) * w) as usize];
    let first = r.iter().position(|p| lum(*p) > threshold)?;
    let last = r.iter().rposition(|p| lum(*p) > threshold)?;
    Some((first as u32, last as u32))
}

/// A small emitting sphere at depth `z` seen through a thin lens focused at 10.
fn lens_scene(z: f32, aperture: f32) -> String {
    format!(
        r#"
[render]
width = 128
height = 128
spp = 64
[camera]
position = [0, 0, 0]
look_at = [0, 0, -1]
fov = {fov}
fov_axis = "horizontal"
aperture = {aperture}
focus_distance = 10
[[sphere]]
center = [0, 0, {center}]
radius = 0.05
emission = 10
"#,
        fov = 2.0 * math::atan(0.1).to_degrees(),
        center = -z
    )
}

/// A point on the focal plane stays sharp; one off it blurs by the circle of confusion of
/// the thin-lens formula: radius aperture · |1 − F/z| on the plane of focus, plus the
/// sphere's own image.
#[test]
fn depth_of_field_blurs_by_the_circle_of_confusion() {
    // The focal plane's half-width is F · tan(fov/2) = 1 unit over 64 pixels.
    let px_per_unit = 64.0;
    for (z, aperture) in [(10.0f32, 0.1f32), (5.0, 0.1), (20.0, 0.1), (5.0, 0.0)] {
        let (w, h, img) = render(&lens_scene(z, aperture));
        let coc = aperture * (1.0 - 10.0 / z).abs();
        let sphere = 0.05 * 10.0 / z;
        let want = 2.0 * (coc + sphere) * px_per_unit;
        let (a, b) = lit_extent(w, &img, h / 2, 1e-4).expect("the sphere is visible");
        let got = (b - a + 1) as f32;
        assert!(
            (got - want).abs() <= 2.0,
            "z {z}, aperture {aperture}: width {got} px, thin lens says {want:.1}"
        );
    }
}

/// Aperture 0 is the pinhole camera, bit for bit (and draws no lens samples).
#[test]
fn aperture_zero_is_the_pinhole_image() {
    let pinhole = lens_scene(5.0, 0.0).replace("aperture = 0\n", "");
    assert_eq!(render(&lens_scene(5.0, 0.0)).2, render(&pinhole).2);
}

/// A straight occluder edge at height h_o under a strip light of width w at height h casts
/// a penumbra of width w · h_o / (h − h_o) on the floor.
#[test]
fn penumbra_width_matches_light_size_and_distances() {
    let scene = |occluder: bool| {
        let plate = if occluder {
            "[[rectangle]]\ncenter = [-5, 1, 0]\nu = [5, 0, 0]\nv = [0, 0, 5]\nmaterial = \"floor\"\n"
        } else {
            ""
        };
        format!(
            r#"
[render]
width = 128
height = 8
spp = 256
[camera]
position = [0, 0.5, 0]
look_at = [0, 0, 0]
up = [0, 0, -1]
fov = 90
fov_axis = "horizontal"
[materials.floor]
type = "lambert"
albedo = 1
[[plane]]
normal = [0, 1, 0]
material = "floor"
[[rectangle]]
center = [0, 3, 0]
u = [0.5, 0, 0]
v = [0, 0, 6]
emission = 5
{plate}"#
        )
    };
    let (w, h, shadowed) = render(&scene(true));
    let (_, _, open) = render(&scene(false));
    let row = h / 2;
    let ratio: Vec<f32> =
        (0..w).map(|x| lum(shadowed[(row * w + x) as usize]) / lum(open[(row * w + x) as usize])).collect();
    // Floor x of pixel centre i: the view spans [-0.5, 0.5].
    let x_of = |i: usize| (i as f32 + 0.5) / w as f32 - 0.5;
    // Umbra until -0.25, full light from +0.25.
    // The visible part of the light grows linearly across the penumbra: it is 10 %, 50 %
    // and 90 % visible at -0.8, 0 and +0.8 of the penumbra's half-width.
    let crossing = |level: f32| x_of(ratio.iter().position(|&r| r > level).expect("ramp reaches the level"));
    let half = 1.0 * 1.0 / (3.0 - 1.0) / 2.0; // (w/2) · h_o / (h − h_o) = 0.25
    let tol = 2.0 / w as f32;
    for (level, want) in [(0.1, -0.8 * half), (0.5, 0.0), (0.9, 0.8 * half)] {
        let got = crossing(level);
        assert!((got - want).abs() < tol, "{}% visible at x = {got}, want {want}", level * 100.0);
    }
    assert!(ratio[0] < 0.01 && ratio[w as usize - 1] > 0.99, "umbra and full light at the ends");
}

fn moving_sphere(shutter: &str, dx: f32) -> String {
    format!(
        r#"
[render]
width = 160
height = 40
spp = 64
ambient = 1
[camera]
position = [0, 0, 10]
look_at = [0, 0, 0]
fov = {fov}
fov_axis = "horizontal"
shutter = {shutter}
[materials.white]
color = 1
diffuse = 0
[[sphere]]
center = [-1, 0, 0]
radius = 0.5
material = "white"
motion = {{ translate = [{end}, 0, 0] }} # object space: the centre goes from -1 to -1 + dx
"#,
        fov = 2.0 * math::atan(0.4).to_degrees(),
        end = dx
    )
}

/// A sphere moving during the shutter smears by its displacement; with the shutter open
/// half as long, by half of it; with it closed, not at all.
#[test]
fn motion_blur_smears_by_the_displacement() {
    // Plane z = 0 spans x in [-4, 4] over 160 pixels: 20 px a unit.
    let px = 20.0;
    let sphere_width = 2.0 * 0.5 * 10.0 / (10.0f32 * 10.0 - 0.25).sqrt() * px; // silhouette
    for (shutter, moved) in [("[0, 1]", 2.0f32), ("[0, 0.5]", 1.0), ("[0, 0]", 0.0)] {
        let (w, h, img) = render(&moving_sphere(shutter, 2.0));
        let (a, b) = lit_extent(w, &img, h / 2, 1e-3).unwrap();
        let got = (b - a + 1) as f32;
        let want = sphere_width + moved * px;
        assert!((got - want).abs() <= 2.0, "shutter {shutter}: smear {got} px, want {want:.1}");
    }
}

fn metal_scene(roughness: f32) -> String {
    format!(
        r#"
[render]
width = 48
height = 48
spp = 64
[camera]
position = [0, 0.5, 4]
look_at = [0, 0.5, 0]
fov = 30
[textures.checks]
type = "checker"
even = 0.9
odd = 0.1
size = 0.5
[materials.floor]
type = "lambert"
albedo = "checks"
[materials.metal]
type = "conductor"
metal = "silver"
roughness = {roughness}
[[plane]]
normal = [0, 1, 0]
material = "floor"
[[sphere]]
center = [0, 0.7, 0]
radius = 0.7
material = "metal"
[[rectangle]]
center = [0, 4, 2]
u = [1, 0, 0]
v = [0, 0, 1]
emission = 8
"#
    )
}

/// A glossy lobe of vanishing roughness tends to the mirror: GGX at α = 0.001 renders
/// what the smooth conductor renders.
#[test]
fn glossy_roughness_zero_equals_the_mirror() {
    let (_, _, mirror) = render(&metal_scene(0.0));
    let (_, _, rough) = render(&metal_scene(0.001));
    let diff: f32 =
        mirror.iter().zip(&rough).map(|(a, b)| (lum(*a) - lum(*b)).abs()).sum::<f32>() / mirror.len() as f32;
    let mean: f32 = mirror.iter().map(|p| lum(*p)).sum::<f32>() / mirror.len() as f32;
    assert!(diff < 0.02 * mean, "mean difference {diff} against mean {mean}");
    let (_, _, blurred) = render(&metal_scene(0.3));
    let diff_rough: f32 = mirror.iter().zip(&blurred).map(|(a, b)| (lum(*a) - lum(*b)).abs()).sum::<f32>()
        / mirror.len() as f32;
    assert!(diff_rough > 5.0 * diff, "roughness 0.3 should blur visibly ({diff_rough} vs {diff})");
}

/// A Lambertian plane of albedo ρ under a directional light of irradiance E at normal
/// incidence has radiance ρE/π, exactly (a known answer before any golden image).
#[test]
fn lambertian_under_directional_light_has_known_radiance() {
    let text = r#"
[render]
width = 4
height = 4
spp = 4
[camera]
position = [0, 3, 0.001]
look_at = [0, 0, 0]
fov = 10
[materials.m]
type = "lambert"
albedo = 0.6
[[plane]]
normal = [0, 1, 0]
material = "m"
[[directional_light]]
direction = [0, -1, 0]
irradiance = 2
"#;
    let want = 0.6 * 2.0 / std::f32::consts::PI;
    for p in render(text).2 {
        assert!((lum(p) - want).abs() < 1e-5, "{p:?} vs {want}");
    }
}

/// Mean pixel values converge as samples grow: the error against a high-sample render
/// falls with the sample count, about as 1/√spp.
#[test]
fn mean_pixel_values_converge_with_samples() {
    let scene = |spp: u32| {
        format!(
            r#"
[render]
width = 24
height = 24
spp = {spp}
seed = {seed}
[camera]
position = [0, 2, 4]
look_at = [0, 0.4, 0]
fov = 40
aperture = 0.05
[materials.floor]
type = "lambert"
albedo = 0.7
[materials.ball]
type = "conductor"
metal = "gold"
roughness = 0.2
[[plane]]
normal = [0, 1, 0]
material = "floor"
[[sphere]]
center = [0, 0.5, 0]
radius = 0.5
material = "ball"
[[sphere]]
center = [1, 2.5, 1]
radius = 0.4
emission = 10
"#,
            seed = spp
        )
    };
    let (_, _, reference) = render(&scene(1024));
    let rmse = |img: &[[f32; 3]]| {
        let se: f32 = img
            .iter()
            .zip(&reference)
            .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]) * (a[c] - b[c])).sum::<f32>())
            .sum();
        (se / (img.len() * 3) as f32).sqrt()
    };
    let errors: Vec<f32> = [1u32, 4, 16, 64].iter().map(|&spp| rmse(&render(&scene(spp)).2)).collect();
    assert!(errors.windows(2).all(|e| e[1] < e[0]), "errors do not fall: {errors:?}");
    assert!(errors[3] < errors[0] / 4.0, "64 spp should be at least 4x better than 1 spp: {errors:?}");
}
