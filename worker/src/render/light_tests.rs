//! Known answers for the lights: spot falloff, the mesh light's choice by area, the choice
//! among many lights by power, and rendered checks (white furnace under the environment,
//! an emitting mesh against the emitting rectangle of the same shape).

use glam::{UVec2, Vec2, Vec3};

use super::*;
use crate::build::{parse_scene, parse_scene_with_assets};
use crate::render::geometry::Ray;
use crate::render::integrator::SHADOW_SHORTEN;
use crate::render::sampler::{hash_words, unit_float};
use crate::render::{SamplerKind, Scene};
use tessera_description::bundle::Assets;

#[test]
fn the_spot_falls_off_smoothly_between_its_cones() {
    let (inner, outer) = (10f32.to_radians(), 30f32.to_radians());
    let spot = Light::spot(Vec3::new(0.0, 2.0, 0.0), -Vec3::Y, Vec3::splat(8.0), inner, outer);
    // A point at angle θ off the axis at distance 2 (not on a plane: the distance stays 2).
    let at = |deg: f32| {
        let t = deg.to_radians();
        Vec3::new(0.0, 2.0, 0.0) + 2.0 * Vec3::new(math::sin(t), -math::cos(t), 0.0)
    };
    let e = |deg: f32| spot.sample(at(deg), Vec2::ZERO).map_or(0.0, |s| s.weighted.x);
    // Inside the inner cone: the full I / d².
    assert!((e(0.0) - 2.0).abs() < 1e-5 && (e(9.0) - 2.0).abs() < 1e-5, "{}", e(9.0));
    // Past the outer cone: nothing (no sample at all).
    assert!(spot.sample(at(31.0), Vec2::ZERO).is_none());
    // Between: KHR_lights_punctual's recommended t², t linear in cos θ.
    let t = (math::cos(20f32.to_radians()) - math::cos(outer)) / (math::cos(inner) - math::cos(outer));
    assert!((e(20.0) - 2.0 * t * t).abs() < 1e-5, "{} vs {}", e(20.0), 2.0 * t * t);
    assert!(e(25.0) < e(20.0) && e(20.0) < e(15.0));
    let s = spot.sample(at(5.0), Vec2::ZERO).unwrap();
    assert!(spot.is_delta() && s.pdf == 0.0 && (s.dist - 2.0).abs() < 1e-5);
}

#[test]
fn a_mesh_light_picks_triangles_by_area_and_points_uniformly() {
    // Areas 1 and 3 (right triangles with legs √2·√2 and √6·√6).
    let a = [Vec3::ZERO, Vec3::new(2f32.sqrt(), 0.0, 0.0), Vec3::new(0.0, 0.0, 2f32.sqrt())];
    let s6 = 6f32.sqrt();
    let b = [Vec3::new(5.0, 0.0, 0.0), Vec3::new(5.0 + s6, 0.0, 0.0), Vec3::new(5.0, 0.0, s6)];
    let m = MeshLight::new(vec![a, b], Vec3::ONE).unwrap();
    assert!((m.area() - 4.0).abs() < 1e-5);
    assert!((m.triangle_pmf(0) - 0.25).abs() < 1e-6 && (m.triangle_pmf(1) - 0.75).abs() < 1e-6);
    let n = 4000;
    let (mut second, mut near_corner) = (0, 0);
    for i in 0..n {
        let u = Vec2::new((i as f32 + 0.5) / n as f32, (i as f32 * 0.618_034).fract());
        let (p, normal) = m.sample_point(u);
        assert!(normal.y.abs() > 0.999 && p.y.abs() < 1e-6);
        if p.x >= 5.0 {
            second += 1;
            // Uniform over the triangle: the quarter of its area nearest the right angle
            // (the triangle scaled by ½) holds a quarter of its points.
            if (p.x - 5.0) + p.z < 0.5 * s6 {
                near_corner += 1;
            }
        } else {
            assert!(p.x + p.z <= 2f32.sqrt() + 1e-5 && p.x >= 0.0 && p.z >= 0.0, "{p}");
        }
    }
    assert_eq!(second, 3000);
    assert!((near_corner as f32 / 3000.0 - 0.25).abs() < 0.02, "{near_corner}");
    assert!(MeshLight::new(vec![[Vec3::ZERO; 3]], Vec3::ONE).is_none());
}

#[test]
fn many_lights_are_chosen_by_power_without_bias() {
    // Nine point lights (more than ALL_LIGHTS_UP_TO) of different intensities over a point.
    let lights: Vec<Light> = (0..9)
        .map(|i| Light::Point {
            position: Vec3::new(i as f32 - 4.0, 2.0, 0.5 * i as f32),
            intensity: Vec3::splat(1.0 + i as f32 * i as f32),
        })
        .collect();
    let choice = LightChoice::new(&lights, 5.0);
    let total: f32 = (0..9).map(|i| 4.0 * std::f32::consts::PI * (1.0 + (i * i) as f32)).sum();
    for i in 0..9 {
        let want = 4.0 * std::f32::consts::PI * (1.0 + (i * i) as f32) / total;
        assert!((choice.pmf(i) - want).abs() < 1e-5, "light {i}: {} vs {want}", choice.pmf(i));
    }
    let p = Vec3::ZERO;
    let exact: f32 = lights.iter().map(|l| l.sample(p, Vec2::ZERO).unwrap().weighted.x).sum();
    let spp = 4096;
    let mut sampler = Sampler::new(SamplerKind::Stratified, 7, spp);
    let mut sum = 0.0f64;
    for s in 0..spp {
        sampler.start_pixel_sample(UVec2::ZERO, s);
        choice.for_each(&lights, &mut sampler, |_, l, pick, _| {
            sum += f64::from(l.sample(p, Vec2::ZERO).unwrap().weighted.x / pick);
        });
    }
    let mean = sum / f64::from(spp);
    assert!((mean - f64::from(exact)).abs() < 0.02 * f64::from(exact), "{mean} vs {exact}");
    // A handful: every light, each with probability 1.
    let few = LightChoice::new(&lights[..ALL_LIGHTS_UP_TO], 5.0);
    let mut calls = 0;
    few.for_each(&lights[..ALL_LIGHTS_UP_TO], &mut sampler, |i, _, pick, _| {
        assert_eq!(pick, 1.0);
        assert_eq!(i as usize, calls);
        calls += 1;
    });
    assert_eq!(calls, ALL_LIGHTS_UP_TO);
}

/// The mean radiance of the pixels in `region` (x and y ranges, paper coordinates).
fn mean(scene: &Scene, xs: std::ops::Range<u32>, ys: std::ops::Range<u32>) -> Vec3 {
    let mut sampler = scene.sampler();
    let mut sum = Vec3::ZERO;
    let mut n = 0;
    for y in ys {
        for x in xs.clone() {
            for s in 0..scene.spp {
                sum += scene.render_sample(&mut sampler, UVec2::new(x, y), s);
                n += 1;
            }
        }
    }
    sum / n as f32
}

const FURNACE: &str = r#"
[render]
width = 32
height = 32
spp = 64
max_depth = 4

[camera]
position = [0, 0, 5]
look_at = [0, 0, 0]
fov = 20

[materials.white]
type = "lambert"
albedo = 1

[[sphere]]
radius = 1
material = "white"
"#;

/// A map of one constant radiance, as a Radiance .hdr file.
fn constant_hdr(w: u32, h: u32, value: f32) -> Vec<u8> {
    let img = image::Rgb32FImage::from_pixel(w, h, image::Rgb([value; 3]));
    let mut out = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb32F(img).write_to(&mut out, image::ImageFormat::Hdr).unwrap();
    out.into_inner()
}

struct One(&'static str, Vec<u8>);
impl Assets for One {
    fn get(&self, path: &str) -> Option<&[u8]> {
        (path == self.0).then_some(self.1.as_slice())
    }
}

#[test]
fn a_white_lambert_sphere_in_a_uniform_environment_is_white() {
    // The white furnace: radiance 1 from everywhere, albedo 1, no self-occlusion: every
    // pixel is 1 (the sphere's, and the environment's around it), by light and BSDF
    // samples weighed together.
    let uniform = format!("{FURNACE}\n[environment]\ncolor = 1\n");
    let s = parse_scene("t.toml", &uniform).unwrap();
    let centre = mean(&s, 12..20, 12..20);
    assert!((centre - Vec3::ONE).abs().max_element() < 0.02, "uniform: {centre}");
    assert_eq!(mean(&s, 0..2, 0..2), Vec3::ONE);
    // The same through an image of constant radiance 0.5 at strength 2, turned.
    let map = format!("{FURNACE}\n[environment]\nfile = \"e.hdr\"\nstrength = 2\nrotation = 70\n");
    let assets = One("e.hdr", constant_hdr(16, 8, 0.5));
    let s = parse_scene_with_assets("t.toml", &map, &assets).unwrap();
    let centre = mean(&s, 12..20, 12..20);
    assert!((centre - Vec3::ONE).abs().max_element() < 0.02, "map: {centre}");
    // The classic model takes light as irradiance × colour: ∫ L cos θ dω = π.
    let classic = uniform.replace("type = \"lambert\"\nalbedo = 1", "color = 1\nambient = 0");
    let s = parse_scene("t.toml", &classic).unwrap();
    let centre = mean(&s, 15..17, 15..17);
    assert!((centre / std::f32::consts::PI - Vec3::ONE).abs().max_element() < 0.02, "classic: {centre}");
}

#[test]
fn an_emitting_mesh_lights_like_the_emitting_rectangle_of_its_shape() {
    // A floor lit from above by a 1×1 panel: once an emitting rectangle, once an emitting
    // mesh of two triangles (facing down, so the rectangle's front side lights the floor).
    let base = r#"
[render]
width = 24
height = 24
spp = 64

[camera]
position = [0, 3, 0]
look_at = [0, 0, 0]
up = [0, 0, -1]
fov = 60

[materials.floor]
type = "lambert"
albedo = 0.8

[[rectangle]]
center = [0, 0, 0]
u = [3, 0, 0]
v = [0, 0, -3]
material = "floor"
"#;
    let rect = format!(
        "{base}\n[[rectangle]]\ncenter = [0, 1, 0]\nu = [0.5, 0, 0]\nv = [0, 0, 0.5]\nemission = 4\n"
    );
    let obj = b"v -0.5 1 -0.5\nv 0.5 1 -0.5\nv 0.5 1 0.5\nv -0.5 1 0.5\nf 1 2 3 4\n".to_vec();
    let mesh = format!("{base}\n[[mesh]]\nfile = \"panel.obj\"\nemission = 4\n");
    let a = parse_scene("t.toml", &rect).unwrap();
    let b = parse_scene_with_assets("t.toml", &mesh, &One("panel.obj", obj)).unwrap();
    assert!(matches!(b.world.lights[0], Light::Mesh(_)));
    assert_eq!(b.world.prims.iter().filter(|p| p.light == Some(0)).count(), 2);
    // Floor beside the panel (which covers the pixels 7..17 across the middle: seen from
    // above, the rectangle shows its dark back and the mesh its other emitting side).
    for (xs, ys) in [(0..6, 0..6), (18..24, 9..15), (0..24, 0..5)] {
        let (ra, rb) = (mean(&a, xs.clone(), ys.clone()), mean(&b, xs.clone(), ys.clone()));
        assert!(
            (ra - rb).abs().max_element() < 0.03 * ra.max_element(),
            "{xs:?} {ys:?}: rect {ra}, mesh {rb}"
        );
        assert!(ra.x > 0.05, "{ra}");
    }
}

/// A one-pixel render and a grey lambert material `m`: the shadow tests' scenes add their
/// camera and shapes.
const ONE_PIXEL_GREY: &str = r#"
[render]
width = 1
height = 1
spp = 1

[materials.m]
type = "lambert"
albedo = 0.5
"#;

#[test]
fn a_shadow_ray_passes_over_its_own_convex_light_and_nothing_else() {
    // A sphere light, a parallelogram light, an emitting mesh of two triangles folded so
    // that one can block the other, and an opaque ball in the middle of it all.
    let text = format!(
        r#"{ONE_PIXEL_GREY}
[camera]
position = [0, 0, 8]
look_at = [0, 0, 0]
fov = 40

[[sphere]]
center = [0, 0, 0]
radius = 0.6
material = "m"

[[sphere]]
center = [1.5, 1.8, 0]
radius = 0.5
emission = 3

[[rectangle]]
center = [-1.5, 1.8, 0.5]
u = [0.4, 0, 0]
v = [0, 0.3, 0.4]
emission = 2

[[mesh]]
file = "fold.obj"
emission = 1
"#
    );
    let fold =
        b"v 0 -2 -1\nv 1 -2 -1\nv 0 -1 -2\nv 1 -1 -2\nv 0 -1 -1.2\nv 1 -1 -1.2\nf 1 2 4 3\nf 3 4 6 5\n";
    let s = parse_scene_with_assets("t.toml", &text, &One("fold.obj", fold.to_vec())).unwrap();
    let lights = &s.world.lights;
    assert!(matches!(lights[0], Light::Sphere { .. }) && matches!(lights[1], Light::Rect { .. }));
    assert!(lights[0].is_one_convex_primitive() && lights[1].is_one_convex_primitive());
    assert!(matches!(lights[2], Light::Mesh(_)) && !lights[2].is_one_convex_primitive());
    let (blocked, open, by_itself) = shadows_against_brute_force(&s, Vec3::ZERO, 6.0);
    assert!(by_itself < 100, "{by_itself} rays blocked by their own light");
    assert!(blocked > 1000 && open > 1000, "{blocked} blocked, {open} open");
    // A ray through the sphere light: its own surface is passed over, no other light's is.
    let through = Ray::new(Vec3::new(1.5, 1.8, 3.0), -Vec3::Z);
    assert_eq!(s.transmittance(&through, 6.0, 0.0), Vec3::ZERO);
    assert_eq!(s.shadow(&through, 6.0, 0.0, 0), Vec3::ONE);
    assert_eq!(s.shadow(&through, 6.0, 0.0, 1), Vec3::ZERO);
    // Through the parallelogram light likewise; the mesh light's triangles always count.
    let across = Ray::new(Vec3::new(-1.5, 1.8, 3.0), -Vec3::Z);
    assert_eq!(s.shadow(&across, 6.0, 0.0, 1), Vec3::ONE);
    assert_eq!(s.shadow(&across, 6.0, 0.0, 0), Vec3::ZERO);
    let folded = Ray::new(Vec3::new(0.5, -1.5, 0.0), -Vec3::Z);
    assert_eq!(s.shadow(&folded, 6.0, 0.0, 2), Vec3::ZERO);
}

/// A light alone in a leaf of a small scene's tree, as `spheres`' is: its shadow rays' walk
/// leaves that leaf out (`World::own_leaves`), with the same answers as every primitive's
/// crossings but the light's own.
#[test]
fn a_shadow_ray_leaves_out_the_leaf_of_its_own_light() {
    let text = format!(
        r#"{ONE_PIXEL_GREY}
[camera]
position = [0, 3, 10]
look_at = [0, 0.5, 0]
fov = 40

[[rectangle]]
center = [0, 0, 0]
u = [10, 0, 0]
v = [0, 0, -10]
material = "m"

[[sphere]]
center = [0, 1, 0]
radius = 1
material = "m"

[[sphere]]
center = [-2.5, 0.8, -0.9]
radius = 0.8
material = "m"

[[sphere]]
center = [2.5, 0.8, -0.7]
radius = 0.8
material = "m"

[[sphere]]
center = [-4, 6, 4]
radius = 0.6
emission = 10

[[rectangle]]
center = [5, 7, -4]
u = [0.5, 0, 0]
v = [0, 0, 0.5]
emission = 10
"#
    );
    let s = parse_scene("t.toml", &text).unwrap();
    let own = &s.world.own_leaves;
    assert!(
        own.iter().all(|&leaf| leaf != crate::render::bvh::LeftOut::NONE),
        "lights alone in their leaves: {own:?}"
    );
    let (blocked, open, by_itself) = shadows_against_brute_force(&s, Vec3::new(0.0, 2.0, 0.0), 8.0);
    assert!(by_itself < 100, "{by_itself} rays blocked by their own light");
    assert!(blocked > 1000 && open > 1000, "{blocked} blocked, {open} open");
}

/// [`Scene::shadow`] and [`Scene::transmittance`] against every primitive's crossings taken
/// one by one, for light samples from 20 000 points in a cube of side `size` around
/// `centre`, up to the edges of the lights' cones and parallelograms (grazing rays): the
/// shadow rays blocked, those open, and those a light's own surface blocked in
/// `transmittance` but not in `shadow`.
fn shadows_against_brute_force(s: &Scene, centre: Vec3, size: f32) -> (u32, u32, u32) {
    let (w, lights) = (&*s.world, &s.world.lights);
    let h = |k: u32, i: u64| unit_float(hash_words(&[u64::from(k), i]));
    // Every primitive's crossings but `skip`'s, one by one: opaque and emitting surfaces
    // both block, so the answer is all or nothing.
    let brute = |ray: &Ray, dist: f32, skip: Option<usize>| {
        let crossed = (w.prims.iter().enumerate())
            .filter(|&(i, _)| Some(i) != skip)
            .any(|(_, prim)| prim.crossings(ray, dist, 0.0, &w.meshes, &w.motions) > 0);
        if crossed {
            Vec3::ZERO
        } else {
            Vec3::ONE
        }
    };
    let own = |i: usize| w.prims.iter().position(|p| p.light == Some(i as u32));
    let (mut blocked, mut open, mut by_itself) = (0, 0, 0);
    for k in 0..20_000u32 {
        // Points around the scene, some close to the lights, and light samples up to the
        // edges of their cones and parallelograms (grazing rays).
        let p = centre + Vec3::new(h(k, 0) - 0.5, h(k, 1) - 0.5, h(k, 2) - 0.5) * size;
        let mut u = Vec2::new(h(k, 3), h(k, 4));
        if k % 4 == 0 {
            u.x = 1.0 - u.x * 1e-6;
        }
        for (i, light) in lights.iter().enumerate() {
            let Some(ls) = light.sample(p, u) else { continue };
            let ray = Ray::new(p, ls.wi);
            let dist = ls.dist * SHADOW_SHORTEN;
            let tr = s.transmittance(&ray, dist, 0.0);
            assert_eq!(tr, brute(&ray, dist, None), "point {k}, light {i}");
            let skip = if light.is_one_convex_primitive() { own(i) } else { None };
            let shadow = s.shadow(&ray, dist, 0.0, i as u32);
            assert_eq!(shadow, brute(&ray, dist, skip), "point {k}, light {i}");
            if shadow != tr {
                // Only grazing rays meet their own light short of its sampled point, by
                // rounding: a light's own surface does not shadow it.
                assert!(ls.pdf > 1e3, "point {k}, light {i}: {ls:?}");
                by_itself += 1;
            }
            if shadow == Vec3::ZERO {
                blocked += 1;
            } else {
                open += 1;
            }
        }
    }
    (blocked, open, by_itself)
}
