//! A moving mesh as one object: its triangles in a BVH of their own, in object space, and
//! one box in the scene's tree that holds the mesh over the whole shutter. A ray that
//! enters that box is taken into object space once, at its moment of the shutter, and
//! walks the mesh's tree, testing its triangles four at a time from their packs as a still
//! mesh's are.
//!
//! Before, each moving triangle was a primitive of the scene's tree with a box of its own
//! around its arc, and each test moved the ray into object space and went through the
//! mesh's indices: on the showcase, whose knot turns during the shutter, those tests were
//! a third of the render (docs/speed.md, twenty-eighth part). A triangle's test and the
//! hit it makes are the same operations on the same values as before (the ray moved by
//! the same frames, Möller–Trumbore on the same corners, the hit taken back to world
//! space by [`to_world`]); the order of the tests differs, which chooses among hits at
//! exactly one distance, and so do the boxes that decide which triangles are tested: each
//! triangle's own box in object space, as a still mesh's, where before a box around its
//! whole arc let its test run. A ray that grazes an edge by less than the test's rounding,
//! which the test may still accept, can pass outside the tight box, as with a still mesh.

use super::bvh::{Aabb, Bvh, LeafPolicy};
use super::geometry::{Hit, Ray};
use super::shape::{moller_trumbore, to_object, to_world, Mesh, Primitive, Shape};
use super::transform::Motion;
use super::triangles::{self, Ray4, SlotKind, Slots};

/// A moving mesh's triangles: primitives `first..first + count` of the scene, all of mesh
/// `mesh` with motion `motion` and material `material`.
#[derive(Debug, Clone)]
pub struct Instance {
    /// The mesh.
    pub mesh: u32,
    /// Its motion.
    pub motion: u32,
    /// Its material.
    pub material: u32,
    /// The scene's primitive of the mesh's triangle 0 (triangle t is `first + t`).
    pub first: u32,
    /// The triangles' tree, in object space (its primitive t is triangle t).
    bvh: Bvh,
    /// The tree's slots: its triangles inline, in object space.
    slots: Slots,
}

impl Instance {
    /// The instance of the moving mesh `run` (`moving_meshes` finds them).
    pub fn new(run: &Run, meshes: &[Mesh], motions: &[Motion]) -> Instance {
        let Run { first, mesh, motion, material, .. } = *run;
        // The triangles as still ones: their slots hold them inline, in object space.
        let still: Vec<Primitive> = (0..meshes[mesh as usize].tris.len() as u32)
            .map(|tri| Primitive {
                shape: Shape::Triangle { mesh, tri },
                material,
                light: None,
                motion: None,
            })
            .collect();
        let bounds: Vec<Aabb> = still.iter().map(|s| s.bounds(meshes, motions)).collect();
        let inline = still.iter().filter(|s| triangles::inline(s, meshes).is_some()).count();
        let bvh = Bvh::build_with(&bounds, LeafPolicy::for_scene(inline, still.len() - inline));
        let slots = triangles::slots(&bvh, &still, meshes);
        Instance { mesh, motion, material, first, bvh, slots }
    }

    /// The box that holds the mesh over the whole shutter: its object-space box's bounding
    /// ball, swept (`Motion::swept_ball`).
    pub fn bounds(&self, motions: &[Motion]) -> Aabb {
        let b = self.bvh.bounds();
        motions[self.motion as usize].swept_ball(b.centroid(), (b.max - b.min).length() * 0.5)
    }

    /// The ray in object space at shutter fraction `time`, as `Primitive::intersect`
    /// moves it.
    #[inline]
    fn local(&self, ray: &Ray, time: f32, motions: &[Motion]) -> Ray {
        to_object(ray, &motions[self.motion as usize].frames(time).1)
    }

    /// The nearest hit in (0, t_max) at shutter fraction `time`, in world space, and the
    /// scene's primitive it is on.
    #[inline]
    pub fn intersect(
        &self,
        ray: &Ray,
        t_max: f32,
        time: f32,
        meshes: &[Mesh],
        motions: &[Motion],
    ) -> Option<Hit> {
        let local = self.local(ray, time, motions);
        let mesh = &meshes[self.mesh as usize];
        let r4 = Ray4::new(&local);
        let mut nearest = None;
        self.bvh.traverse_leaves::<false>(&local, t_max, |first, count, mut t_max| {
            self.slots.leaf(first, count, &r4, |k, tri| {
                let slot = &self.slots[k];
                let found = match (slot.kind(), tri) {
                    (SlotKind::Triangle(t), Some((d, b1, b2))) => (d < t_max).then_some((t, d, b1, b2)),
                    // A degenerate triangle: its own test says it is never hit, as
                    // `Mesh::intersect` would.
                    (SlotKind::Generic(t), _) => {
                        let [p0, p1, p2] = mesh.corners(t);
                        moller_trumbore(p0, p1 - p0, p2 - p0, &local, t_max)
                            .filter(|&(d, b1, b2)| mesh.hit_at(t, d, b1, b2).is_some())
                            .map(|(d, b1, b2)| (t, d, b1, b2))
                    }
                    _ => None,
                };
                if let Some(f) = found {
                    t_max = f.1;
                    nearest = Some(f);
                }
                true
            });
            t_max
        });
        let (tri, t, b1, b2) = nearest?;
        let (world_from_object, _) = motions[self.motion as usize].frames(time);
        let mut hit = to_world(&mesh.hit_at(tri, t, b1, b2)?, &world_from_object);
        hit.prim = self.first + tri;
        Some(hit)
    }

    /// How many of its triangles the segment (0, dist) crosses at shutter fraction `time`,
    /// counting no further than `enough`.
    #[inline]
    pub fn crossings(
        &self,
        ray: &Ray,
        dist: f32,
        time: f32,
        enough: u32,
        meshes: &[Mesh],
        motions: &[Motion],
    ) -> u32 {
        let local = self.local(ray, time, motions);
        let mesh = &meshes[self.mesh as usize];
        let r4 = Ray4::new(&local);
        let mut crossed = 0;
        self.bvh.visit_leaves(&local, dist, |first, count| {
            self.slots.leaf(first, count, &r4, |k, tri| {
                let hit = match (self.slots[k].kind(), tri) {
                    (SlotKind::Triangle(_), Some((d, ..))) => d < dist,
                    (SlotKind::Generic(t), _) => {
                        let [p0, p1, p2] = mesh.corners(t);
                        moller_trumbore(p0, p1 - p0, p2 - p0, &local, dist)
                            .is_some_and(|(d, b1, b2)| mesh.hit_at(t, d, b1, b2).is_some())
                    }
                    _ => false,
                };
                crossed += u32::from(hit);
                crossed < enough
            })
        });
        crossed
    }

    /// The bytes of its tree and slots.
    pub fn bytes(&self) -> usize {
        self.bvh.bytes() + self.slots.len() * Slots::BYTES_PER_SLOT
    }
}

/// A moving mesh's triangles among the scene's primitives: `first..first + count`, its
/// triangles 0..count in order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Run {
    /// The primitive of triangle 0.
    pub first: u32,
    /// Its triangles.
    pub count: u32,
    /// The mesh.
    pub mesh: u32,
    /// Its motion.
    pub motion: u32,
    /// Its material.
    pub material: u32,
}

/// The fewest triangles a moving mesh needs to be an instance. An instance's tree, slots
/// and record take about half a kilobyte whatever its size, which the memory estimate
/// (`tessera_description::summary`, per primitive) does not count: a scene of many moving
/// `[[triangle]]`s, each a mesh of one, would outgrow its estimate, and a tree over a few
/// triangles spares nothing.
pub const MIN_TRIANGLES: u32 = 64;

/// The moving meshes among `prims` that can be instances: runs of one mesh's triangles
/// 0..n in order (at least [`MIN_TRIANGLES`]) with one motion, emitting nothing, of a
/// material that `alpha` does not say cuts out hits (a cut-out is decided triangle by
/// triangle, through its primitive).
pub fn moving_meshes(prims: &[Primitive], meshes: &[Mesh], alpha: &[bool]) -> Vec<Run> {
    let mut runs = Vec::new();
    let mut i = 0;
    while i < prims.len() {
        let p = &prims[i];
        let run = match (&p.shape, p.motion) {
            (Shape::Triangle { mesh, tri: 0 }, Some(motion))
                if p.light.is_none() && !alpha[p.material as usize] =>
            {
                let count = meshes[*mesh as usize].tris.len() as u32;
                Some(Run { first: i as u32, count, mesh: *mesh, motion, material: p.material })
            }
            _ => None,
        };
        let whole = run.filter(|r| {
            prims.get(i..i + r.count as usize).is_some_and(|triangles| {
                triangles.iter().enumerate().all(|(t, q)| {
                    matches!(q.shape, Shape::Triangle { mesh, tri } if mesh == r.mesh && tri as usize == t)
                        && q.motion == Some(r.motion)
                        && q.material == r.material
                        && q.light.is_none()
                })
            })
        });
        match whole {
            Some(r) if r.count >= MIN_TRIANGLES => {
                runs.push(r);
                i += r.count as usize;
            }
            _ => i += 1,
        }
    }
    runs
}

#[cfg(test)]
mod tests {
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
            tris: vec![
                [[0, u32::MAX, u32::MAX], [1, u32::MAX, u32::MAX], [2, u32::MAX, u32::MAX]];
                n as usize
            ],
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
            let target =
                w.motions[inst.motion as usize].at(time).transform_point3((c[0] + c[1] + c[2]) / 3.0);
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
        let generic =
            inst.slots.iter().filter(|s| matches!(s.kind(), SlotKind::Generic(t) if t < 300)).count();
        assert_eq!(generic, 60, "the degenerate triangles' slots");
        let (hits, crossed) = check_against_triangles("sheet", &scene, 4_000);
        assert!(hits > 2_000 && crossed > 40, "{hits} hits, {crossed} rays crossing twice or more");
    }
}
