//! The integrator's tests: transport choices that keep the mean and lower the variance.

use super::*;
use crate::batch::{render_batch, Sums};
use crate::render::sampler::hash_words;
use glam::UVec2;
use tessera_description::bundle::Bundle;

fn scene(name: &str) -> Scene {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    crate::build::parse_bundle(&Bundle::read(&root.join(name)).unwrap()).unwrap()
}

/// A path's last ray skipped where it can find no light: never where its nearest hit
/// is an emitter (random rays), often where it is not, and the images' sums are the
/// bits of tracing every such ray.
#[test]
fn last_rays_skipped_only_where_they_find_no_light() {
    for name in ["cornell.toml", "spheres.toml"] {
        let mut scene = scene(name);
        assert!(scene.world.emitters.is_some(), "{name}: its emitters are few");
        let b = scene.world.bvh.bounds();
        let (c, r) = (b.centroid(), (b.max - b.min).length());
        let (mut lit, mut skipped) = (0, 0);
        for k in 0..20_000u64 {
            let h = |j: u64| (hash_words(&[k, j, 7]) >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            let Some(dir) = Vec3::new(h(3), h(4), h(5)).try_normalize() else { continue };
            let ray = Ray::new(c + Vec3::new(h(0), h(1), h(2)) * r * 0.5, dir);
            let may = scene.may_find_light(&ray, 0.0);
            if scene.intersect(&ray, f32::INFINITY, 0.0).is_some_and(|sh| sh.light.is_some()) {
                assert!(may, "{name}: ray {k} finds a light");
                lit += 1;
            }
            skipped += usize::from(!may);
        }
        assert!(lit > 10 && skipped > 10_000, "{name}: {lit} rays lit, {skipped} skipped");

        let pixels: Vec<_> = (0..24).flat_map(|y| (0..32).map(move |x| UVec2::new(x * 5, y * 6))).collect();
        scene.apply(Some(4), Some((160, 144)));
        let skipping = render_batch(&scene, &pixels, 0..4, Sums::Radiance);
        std::sync::Arc::get_mut(&mut scene.world).unwrap().emitters = None;
        let tracing = render_batch(&scene, &pixels, 0..4, Sums::Radiance);
        assert_eq!(skipping, tracing, "{name}");
    }
    // An emissive mesh has too many emitters to test one by one.
    assert!(scene("emissive_mesh.toml").world.emitters.is_none());
    // Escaping rays that see a background or an environment find light: nothing is
    // skipped (the ray points at the floor, away from the light).
    let away = Ray::new(Vec3::ZERO, Vec3::NEG_Y);
    let mut lit = scene("cornell.toml");
    assert!(!lit.may_find_light(&away, 0.0));
    lit.background = Vec3::splat(0.1);
    assert!(lit.may_find_light(&away, 0.0));
    let sky = scene("environment.toml");
    assert!(sky.world.environment.is_some() && sky.background == Vec3::ZERO);
    let b = sky.world.bvh.bounds();
    assert!(sky.may_find_light(&Ray::new(b.max + Vec3::ONE, Vec3::ONE.normalize()), 0.0));
}

/// Following both lobes of glass estimates what picking one does, with less noise: a
/// glass ball before a black sky, lit by a wide light behind the camera that only its
/// reflections see. Picking, a sample sees the light with probability F (4 % head on);
/// split, every sample sees F of it. The two images agree within their noise, the
/// split's samples vary far less, and pixels that miss the ball are the same bits.
#[test]
fn splitting_glass_keeps_the_mean_and_lowers_the_variance() {
    let scene = crate::build::parse_scene(
        "glass.toml",
        r#"
[render]
width = 12
height = 12
spp = 256
[camera]
position = [0, 0, 4]
look_at = [0, 0, 0]
fov = 40
[materials.glass]
type = "dielectric"
ior = 1.5
[[sphere]]
radius = 1
material = "glass"
[[rectangle]]
center = [0, 0, 6]
u = [16, 0, 0]
v = [0, -16, 0]
emission = 5
"#,
    )
    .unwrap();
    let mut sampler = scene.sampler();
    let (n, mut glass, mut same) = (256.0, 0, 0);
    let (mut picked_var, mut split_var, mut diff) = (0.0, 0.0, 0.0);
    for p in 0..144u32 {
        let pixel = UVec2::new(p % 12, p / 12);
        // Per budget: the sum and the sum of squares of a sample's green channel.
        let mut st = [[0f64; 2]; 2];
        for (budget, st) in [0, SPLITS].into_iter().zip(st.iter_mut()) {
            for index in 0..256 {
                let (ray, time) = scene.camera_ray(&mut sampler, pixel, index);
                let y = f64::from(trace(&scene, &mut sampler, &ray, 0, time, budget).y);
                st[0] += y;
                st[1] += y * y;
            }
        }
        if st[0] == st[1] {
            same += 1;
            continue;
        }
        glass += 1;
        let var = |s: [f64; 2]| (s[1] / n - (s[0] / n) * (s[0] / n)).max(0.0);
        picked_var += var(st[0]);
        split_var += var(st[1]);
        diff += (st[1][0] - st[0][0]) / n;
    }
    assert!(glass > 40 && same > 20, "{glass} pixels see the ball, {same} do not");
    // The difference of the images' sums over the ball against its standard deviation
    // (a fifth more of either lobe's light shows at five or more).
    let z = diff / ((picked_var + split_var) / n).sqrt();
    assert!(z.abs() < 3.5, "the means differ by {z:.2} standard deviations");
    assert!(split_var < 0.2 * picked_var, "sample variance {split_var} split, {picked_var} picked");
}

/// A diffuse lobe's several rays estimate what its one ray does, with less noise: a
/// plastic ball on a diffuse floor under a blue sky, a small light above. The floor's and
/// the ball's diffuse rays see the sky past the ball and the floor, and hit the light
/// (weighed by MIS against its samples); the ball's coat is picked by the same lobe choice
/// as before. Sample by sample (both counts draw the same camera ray, light samples and
/// lobe choice, so the difference holds only the diffuse rays' noise) the two agree
/// within four standard deviations of their difference, and with eight rays a sample
/// varies far less (the sky's share of the variance goes down as the rays' count and
/// more, their directions being stratified together). Without the rays' 1 / count the
/// difference is hundreds of standard deviations.
#[test]
fn diffuse_rays_keep_the_mean_and_lower_the_variance() {
    let mut scene = crate::build::parse_scene(
        "sky.toml",
        r#"
[render]
width = 12
height = 12
spp = 64
background = [0.5, 0.6, 0.8]
[camera]
position = [0, 2.5, 4]
look_at = [0, 0.5, 0]
fov = 50
[materials.floor]
type = "lambert"
albedo = 0.6
[materials.red]
type = "plastic"
albedo = [0.7, 0.1, 0.1]
ior = 1.5
[[plane]]
normal = [0, 1, 0]
material = "floor"
[[sphere]]
center = [0, 0.8, 0]
radius = 0.8
material = "red"
[[sphere]]
center = [1.5, 3, 1]
radius = 0.3
emission = 30
"#,
    )
    .unwrap();
    let mut sampler = scene.sampler();
    let n = 64.0;
    // Per ray count, the summed variance of a pixel's samples (green channel); and the
    // difference of the two counts' values sample by sample: both draw the same camera
    // ray, light samples and lobe choice, so the difference holds only the diffuse rays'.
    let (mut var, mut diff) = ([0f64; 2], [0f64; 2]);
    for p in 0..144u32 {
        let pixel = UVec2::new(p % 12, p / 12);
        let mut st = [[0f64; 2]; 2];
        for index in 0..64 {
            let mut y = [0f64; 2];
            for (k, rays) in [1, 8].into_iter().enumerate() {
                scene.diffuse_rays = rays;
                let (ray, time) = scene.camera_ray(&mut sampler, pixel, index);
                y[k] = f64::from(trace(&scene, &mut sampler, &ray, 0, time, SPLITS).y);
                st[k][0] += y[k];
                st[k][1] += y[k] * y[k];
            }
            diff[0] += y[1] - y[0];
            diff[1] += (y[1] - y[0]) * (y[1] - y[0]);
        }
        for k in 0..2 {
            var[k] += (st[k][1] / n - (st[k][0] / n) * (st[k][0] / n)).max(0.0);
        }
    }
    let samples = 144.0 * n;
    let mean = diff[0] / samples;
    let z = mean / ((diff[1] / samples - mean * mean) / samples).sqrt();
    assert!(z.abs() < 4.0, "eight rays against one: the mean differs by {z:.2} standard deviations");
    // 0.23 when written (z −0.06): the light samples and the ball's edges keep their noise.
    assert!(var[1] < 0.3 * var[0], "sample variance {} with eight rays, {} with one", var[1], var[0]);
}

#[test]
fn snell_and_total_internal_reflection() {
    let n = Vec3::Y;
    let wi = Vec3::new(0.5f32.sqrt(), 0.5f32.sqrt(), 0.0);
    let wt = refract(wi, n, 1.5).unwrap();
    // sin θt = sin θi / η
    assert!((wt.x.abs() - 0.5f32.sqrt() / 1.5).abs() < 1e-6 && wt.y < 0.0);
    assert!(refract(wi, n, 1.0 / 1.5).is_none());
    // Index 1: the ray goes straight on.
    assert!((refract(wi, n, 1.0).unwrap() + wi).length() < 1e-6);
}
