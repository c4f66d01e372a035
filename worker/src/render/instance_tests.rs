//! An instance against its triangles tested one by one, on scenes built from their files
//! (a file of its own: the builder it needs depends on this module).

use glam::Vec3;
use tessera_description::bundle::Bundle;

use super::*;
use crate::render::sampler::hash_words;

fn tri(mesh: u32, tri: u32, material: u32, motion: Option<u32>) -> Primitive {
    Primitive { shape: Shape::Triangle { mesh, tri }, material, light: None, motion }
}

/// Only whole moving meshes of [`MIN_TRIANGLES`] or more become instances: all their
/// triangles in order, one motion, one material, no light, no cut-out.
#[test]
fn moving_meshes_are_whole_meshes_that_need_nothing_triangle_by_triangle() {
    let n = MIN_TRIANGLES;
    let mesh = |n: u32| Mesh {
        p: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
        tris: vec![[[0, u32::MAX, u32::MAX], [1, u32::MAX, u32::MAX], [2, u32::MAX, u32::MAX]]; n as usize],
        ..Mesh::default()
    };
    let mut meshes = vec![mesh(n); 6];
    meshes.push(mesh(n - 1));
    let alpha = [false, true];
    let whole = |m: u32, material: u32, motion: Option<u32>| {
        (0..meshes[m as usize].tris.len() as u32).map(move |t| tri(m, t, material, motion))
    };
    let sphere = Primitive {
        shape: Shape::Sphere(crate::render::geometry::Sphere::new(Vec3::ZERO, 1.0)),
        material: 0,
        light: None,
        motion: Some(4),
    };
    let mut prims: Vec<Primitive> = whole(0, 0, Some(0))
        // Cut out: triangle by triangle.
        .chain(whole(1, 1, Some(1)))
        // Still.
        .chain(whole(2, 0, None))
        // Two motions in one mesh.
        .chain(whole(3, 0, Some(2)).enumerate().map(|(t, mut p)| {
            p.motion = Some(2 + u32::from(t == 5));
            p
        }))
        .chain([sphere])
        // Cut short.
        .chain(whole(4, 0, Some(5)).take(3))
        .chain(whole(5, 0, Some(6)))
        // Too small.
        .chain(whole(6, 0, Some(7)))
        .collect();
    let second = 4 * n + 4;
    assert!(matches!(prims[second as usize].shape, Shape::Triangle { mesh: 5, tri: 0 }));
    let runs = moving_meshes(&prims, &meshes, &alpha);
    let run = |first, mesh, motion| Run { first, count: n, mesh, motion, material: 0 };
    assert_eq!(runs, [run(0, 0, 0), run(second, 5, 6)]);
    // An emitting mesh stays as it is (validation keeps lights still; this is the
    // second line of defence).
    prims[second as usize + 7].light = Some(0);
    assert_eq!(moving_meshes(&prims, &meshes, &alpha), [run(0, 0, 0)]);
}

/// The instance's hits and crossings against its triangles tested one by one
/// (`Primitive::intersect`, in triangle order: the nearest, the first of equals) on
/// rays aimed at them at random moments, and its box against them at 65 moments.
/// Returns the rays that hit and those that crossed twice or more.
fn check_against_triangles(name: &str, scene: &crate::render::Scene, rays: u64) -> (usize, usize) {
    let w = &scene.world;
    assert_eq!(w.instances.len(), 1, "{name}: one moving mesh");
    let inst = &w.instances[0];
    let tris = inst.first..inst.first + w.meshes[inst.mesh as usize].tris.len() as u32;
    let b = inst.bounds(&w.motions);
    let r = (b.max - b.min).length();
    let (mut hits, mut crossed) = (0, 0);
    for k in 0..rays {
        let h = |j: u64| (hash_words(&[k, j, 5]) >> 40) as f32 / (1u64 << 24) as f32;
        let time = h(0);
        let i = tris.start + (hash_words(&[k, 1]) % tris.len() as u64) as u32;
        let Shape::Triangle { mesh, tri } = w.prims[i as usize].shape else { unreachable!() };
        let c = w.meshes[mesh as usize].corners(tri);
        let target = w.motions[inst.motion as usize].at(time).transform_point3((c[0] + c[1] + c[2]) / 3.0);
        let Some(away) = Vec3::new(h(2) - 0.5, h(3) - 0.5, h(4) - 0.5).try_normalize() else { continue };
        let origin = target + away * r * (0.05 + h(5));
        let aimed = k % 4 != 0;
        let dir = if aimed { target - origin } else { -away };
        let Some(dir) = dir.try_normalize() else { continue };
        let ray = Ray::new(origin, dir);
        let (mut want, mut t_max, mut crossings) = (None, f32::INFINITY, 0);
        for i in tris.clone() {
            let p = &w.prims[i as usize];
            if let Some(mut hit) = p.intersect(&ray, t_max, time, &w.meshes, &w.motions) {
                hit.prim = i;
                t_max = hit.t;
                want = Some(hit);
            }
        }
        let got = inst.intersect(&ray, f32::INFINITY, time, &w.meshes, &w.motions);
        let bits = |h: &Hit| {
            (h.prim, [h.t, h.p.x, h.p.y, h.p.z, h.n.x, h.n.y, h.n.z, h.ns.x, h.uv.x].map(f32::to_bits))
        };
        assert_eq!(got.as_ref().map(bits), want.as_ref().map(bits), "{name}: ray {k} at {time}");
        let dist = r * h(6);
        for i in tris.clone() {
            crossings += w.prims[i as usize].crossings(&ray, dist, time, &w.meshes, &w.motions);
        }
        let count = |enough| inst.crossings(&ray, dist, time, enough, &w.meshes, &w.motions);
        assert_eq!(count(u32::MAX), crossings, "{name}: ray {k}");
        assert_eq!(count(1), crossings.min(1), "{name}: ray {k}");
        hits += usize::from(want.is_some());
        crossed += usize::from(crossings > 1);
    }
    for i in tris {
        let Shape::Triangle { mesh, tri } = w.prims[i as usize].shape else { unreachable!() };
        for k in 0..=64 {
            let at = w.motions[inst.motion as usize].at(k as f32 / 64.0);
            for q in w.meshes[mesh as usize].corners(tri) {
                let q = at.transform_point3(q);
                assert!(
                    q.cmpge(b.min).all() && q.cmple(b.max).all(),
                    "{name}: triangle {i} at {k}/64: {q} outside {b:?}"
                );
            }
        }
    }
    (hits, crossed)
}

/// The showcase's turning knot as an instance finds, at every moment of the shutter,
/// the hit its triangles tested one by one find, bit for bit, and crosses what they
/// cross; its box holds it all shutter long.
#[test]
fn an_instance_finds_what_its_triangles_find_one_by_one() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let scene = crate::build::parse_bundle(&Bundle::read(&root.join("showcase.toml")).unwrap()).unwrap();
    let (hits, crossed) = check_against_triangles("showcase", &scene, 6_000);
    assert!(hits > 3_000 && crossed > 300, "{hits} hits, {crossed} rays crossing twice or more");
}

/// The same for a moving sheet whose every fifth triangle is degenerate (its slot is
/// not inline, and its own test says it is never hit) and whose material lets light
/// through, so that shadow rays count every crossing.
#[test]
fn an_instance_with_degenerate_triangles_finds_what_they_find() {
    struct Sheet(String);
    impl tessera_description::bundle::Assets for Sheet {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "sheet.obj").then_some(self.0.as_bytes())
        }
    }
    let mut obj = String::new();
    let mut v = 0;
    for t in 0..300u32 {
        let (x, z) = ((t % 20) as f32 * 0.3, (t / 20) as f32 * 0.3);
        let y = |x: f32, z: f32| 0.1 * (x * x - 2.0 * x * z + z);
        let corners = if t % 5 == 4 {
            // Collinear: no normal.
            [Vec3::new(x, 0.0, z), Vec3::new(x + 0.2, 0.0, z), Vec3::new(x + 0.4, 0.0, z)]
        } else {
            [(x, z), (x + 0.3, z), (x, z + 0.3)].map(|(x, z)| Vec3::new(x, y(x, z), z))
        };
        for p in corners {
            obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
        }
        obj += &format!("f {} {} {}\n", v + 1, v + 2, v + 3);
        v += 3;
    }
    let text = "[render]\nwidth = 1\nheight = 1\nspp = 1\n[camera]\nposition = [0, 3, 8]\n\
                look_at = [0, 0, 0]\nfov = 40\n[materials.t]\ntype = \"classic\"\n\
                transmit = [0.5, 0.7, 0.9]\n[[mesh]]\nfile = \"sheet.obj\"\nmaterial = \"t\"\n\
                transform = { translate = [-3, 0, -2] }\n\
                motion = { translate = [-2, 0.5, -2], rotate = [20, 70, 0] }\n";
    let scene = crate::build::parse_scene_with_assets("sheet.toml", text, &Sheet(obj)).unwrap();
    let inst = &scene.world.instances[0];
    let generic = inst.slots.iter().filter(|s| matches!(s.kind(), SlotKind::Generic(t) if t < 300)).count();
    assert_eq!(generic, 60, "the degenerate triangles' slots");
    let (hits, crossed) = check_against_triangles("sheet", &scene, 4_000);
    assert!(hits > 2_000 && crossed > 40, "{hits} hits, {crossed} rays crossing twice or more");
}
