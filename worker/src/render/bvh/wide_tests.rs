//! The wide traversals against the binary tree's (`reference.rs`), on adversarial lattices
//! of boxes (a file of its own: it folds trees, and `fold.rs` builds on `wide.rs`).

use glam::Vec3;

use super::super::{build_binary_with, reference, Aabb, Binary, LeafPolicy};
use super::Wide;
use crate::render::geometry::Ray;
use crate::render::sampler::hash_words;

fn unit(words: &[u64]) -> f32 {
    (hash_words(words) >> 40) as f32 / (1u64 << 24) as f32
}

/// Boxes on a coarse lattice, many flat and sharing faces, so that rays from lattice
/// points along the axes start on faces and run inside slabs (0 × ∞ in the slab test).
fn lattice_boxes(n: usize, seed: u64) -> Vec<Aabb> {
    (0..n as u64)
        .map(|i| {
            let c = |k| (unit(&[seed, i, k]) * 8.0).floor();
            let min = Vec3::new(c(0), c(1), c(2));
            let size = Vec3::new(c(3), c(4), c(5)).min(Vec3::splat(2.0)) * Vec3::new(1.0, 0.5, 1.0);
            Aabb { min, max: min + size }
        })
        .collect()
}

fn random_boxes(n: usize, seed: u64) -> Vec<Aabb> {
    (0..n as u64)
        .map(|i| {
            let c = Vec3::new(unit(&[seed, i, 0]), unit(&[seed, i, 1]), unit(&[seed, i, 2])) * 100.0;
            let r = Vec3::new(unit(&[seed, i, 3]), unit(&[seed, i, 4]), unit(&[seed, i, 5])) * 3.0;
            Aabb { min: c - r, max: c + r }
        })
        .collect()
}

/// Boxes ever farther apart along a line: the binned SAH peels a few off at each
/// level, a tree deeper than the traversal's stack in its frame.
fn exponential_boxes(n: usize) -> Vec<Aabb> {
    std::iter::successors(Some(1.0f32), |x| Some(x * 1.5))
        .take(n)
        .map(|x| Aabb { min: Vec3::new(x, 0.0, 0.0), max: Vec3::new(x + 0.5, 1.0, 1.0) })
        .collect()
}

/// A ray from a lattice point or anywhere, its direction's components often ±0.
fn ray(k: u64, scale: f32) -> Ray {
    let u = |j| unit(&[k, j, 7]);
    let origin = if k.is_multiple_of(2) {
        Vec3::new((u(0) * 10.0).floor(), (u(1) * 10.0).floor() * 0.5, (u(2) * 10.0).floor()) - 1.0
    } else {
        Vec3::new(u(0), u(1), u(2)) * scale * 1.2 - 0.1 * scale
    };
    let comp = |j: u64| match (hash_words(&[k, j, 8]) % 5) as u8 {
        0 => 0.0,
        1 => -0.0,
        _ => u(j + 3) - 0.5,
    };
    let mut dir = Vec3::new(comp(0), comp(1), comp(2));
    if dir == Vec3::ZERO {
        dir = Vec3::X;
    }
    Ray::new(origin, dir)
}

/// Both traversals, every call with its `t_max`: the nearest-hit one with hits at
/// made-up distances (so `t_max` shrinks), the any-order one stopping after a made-up
/// number of slots.
fn calls(binary: &Binary, wide: &Wide, ray: &Ray, k: u64, t_max: f32) -> [(Vec<(usize, u32)>, f32); 5] {
    let made_up = |slot: usize, t_max: f32| {
        let h = hash_words(&[k, slot as u64, 9]);
        h.is_multiple_of(3).then(|| t_max.min(100.0) * unit(&[h]))
    };
    let mut seen = [vec![], vec![], vec![]];
    let ends = [
        reference::traverse_slots(binary, ray, t_max, |s, t| {
            seen[0].push((s, t.to_bits()));
            made_up(s, t)
        }),
        wide.nearest::<false>(ray.origin, ray.dir, t_max, |s, t| {
            seen[1].push((s, t.to_bits()));
            made_up(s, t)
        }),
        wide.nearest::<true>(ray.origin, ray.dir, t_max, |s, t| {
            seen[2].push((s, t.to_bits()));
            made_up(s, t)
        }),
    ];
    let stop = (hash_words(&[k, 10]) % 40) as usize;
    let mut each = [vec![], vec![]];
    reference::visit_slots(binary, ray, t_max, |s| {
        each[0].push((s, 0));
        each[0].len() < stop
    });
    wide.each(ray.origin, ray.dir, t_max, |s| {
        each[1].push((s, 0));
        each[1].len() < stop
    });
    let [a, b, e] = seen;
    let [c, d] = each;
    [(a, ends[0]), (b, ends[1]), (e, ends[2]), (c, 0.0), (d, 0.0)]
}

/// The folded tree visits the slots the binary tree visits, in the same order and with
/// the same `t_max` at each, by both nearest-hit walks (coherent and not), for rays that
/// start on faces and run along them too; with the box test on AVX where the CPU has it,
/// and without. Trees of at most `flat::MOST_LEAVES` leaves are walked flat (`flat.rs`),
/// larger ones are not.
#[test]
fn wide_visits_what_the_binary_tree_visits() {
    let sets = [
        (lattice_boxes(3000, 1), 10.0),
        (lattice_boxes(200, 2), 10.0),
        (random_boxes(20_000, 3), 100.0),
        (random_boxes(5, 4), 100.0),
        (random_boxes(1, 5), 100.0),
        (exponential_boxes(200), 100.0),
        (lattice_boxes(12, 6), 10.0),
        (lattice_boxes(16, 7), 10.0),
        (random_boxes(16, 8), 100.0),
        (random_boxes(17, 9), 100.0),
        (exponential_boxes(16), 100.0),
    ];
    let (mut visits, mut flat, mut flat_visits, mut most_flat) = (0, 0, 0, 0);
    let mut stacks = std::collections::BTreeSet::new();
    let policies = [LeafPolicy::TRIANGLES, LeafPolicy::SHAPES];
    for (set, (boxes, scale, policy)) in
        sets.iter().flat_map(|(b, s)| policies.map(|p| (b, s, p))).enumerate()
    {
        let binary = build_binary_with(boxes, policy);
        let wide = super::super::fold::fold(&binary.nodes);
        stacks.insert(if wide.depth <= super::SMALL_STACK {
            "small"
        } else if wide.depth <= super::STACK {
            "thread"
        } else {
            "heap"
        });
        wide.validate(&binary.indices, boxes).unwrap();
        let leaves = binary.nodes.iter().filter(|n| n.count > 0).count();
        assert_eq!(wide.is_flat(), leaves <= super::super::flat::MOST_LEAVES, "set {set}: {leaves} leaves");
        flat += usize::from(wide.is_flat());
        if wide.is_flat() {
            most_flat = most_flat.max(leaves);
        }
        for wide in [wide.clone(), wide.without_avx()] {
            for k in 0..3000u64 {
                let r = ray(k * 7 + set as u64, *scale);
                for t_max in [f32::INFINITY, 5.0] {
                    let [a, b, e, c, d] = calls(&binary, &wide, &r, k, t_max);
                    assert_eq!(a, b, "set {set}, ray {k}: nearest-hit visits differ");
                    assert_eq!(a, e, "set {set}, ray {k}: the coherent walk's nearest-hit visits differ");
                    assert_eq!(c, d, "set {set}, ray {k}: any-order visits differ");
                    visits += a.0.len();
                    if wide.is_flat() {
                        flat_visits += a.0.len();
                    }
                }
            }
        }
    }
    assert!(visits > 200_000, "only {visits} visits: the rays miss the boxes");
    assert!(flat >= 10 && flat_visits > 20_000, "{flat} flat trees, {flat_visits} visits");
    // The second node's lanes and the order's last four bits are used.
    assert_eq!(most_flat, super::super::flat::MOST_LEAVES, "the largest flat tree");
    assert_eq!(stacks.len(), 3, "every stack size is exercised: {stacks:?}");
}

/// A walk inside a walk (an instance's tree inside the scene's) finds the thread's stack
/// taken and uses one of its own: both visit what they visit alone, nearest-hit and
/// any-order, with the inner walk entered from every leaf of the outer one.
#[test]
fn a_walk_inside_a_walk_visits_what_each_visits_alone() {
    let boxes = random_boxes(20_000, 3);
    let wide = super::super::fold::fold(&build_binary_with(&boxes, LeafPolicy::TRIANGLES).nodes);
    assert!(wide.depth > super::SMALL_STACK && wide.depth <= super::STACK, "depth {}", wide.depth);
    let made_up = |k: u64, slot: usize, t_max: f32| {
        let h = hash_words(&[k, slot as u64, 11]);
        h.is_multiple_of(3).then(|| t_max.min(100.0) * unit(&[h]))
    };
    let alone = |k: u64| {
        let r = ray(k, 100.0);
        let (mut nearest, mut each) = (vec![], vec![]);
        wide.nearest::<false>(r.origin, r.dir, f32::INFINITY, |s, t| {
            nearest.push((s, t.to_bits()));
            made_up(k, s, t)
        });
        wide.each(r.origin, r.dir, f32::INFINITY, |s| {
            each.push(s);
            true
        });
        (nearest, each)
    };
    let mut inner_walks = 0;
    for k in 0..200u64 {
        let (outer, inner) = (k * 2 + 1, k * 2 + 1001);
        let want = (alone(outer), alone(inner));
        let r = ray(outer, 100.0);
        let (mut nearest, mut each) = (vec![], vec![]);
        wide.nearest::<false>(r.origin, r.dir, f32::INFINITY, |s, t| {
            nearest.push((s, t.to_bits()));
            assert_eq!(alone(inner), want.1, "ray {k}: the inner walks inside a nearest-hit walk");
            inner_walks += 1;
            made_up(outer, s, t)
        });
        wide.each(r.origin, r.dir, f32::INFINITY, |s| {
            each.push(s);
            assert_eq!(alone(inner), want.1, "ray {k}: the inner walks inside an any-order walk");
            true
        });
        assert_eq!((nearest, each), want.0, "ray {k}: the outer walks");
    }
    assert!(inner_walks > 1000, "only {inner_walks} walks inside a walk: the rays miss the boxes");
}

/// Whether the AVX2 path can be tested here; says why not where it cannot.
#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
fn avx2_or_skip() -> bool {
    let here = super::super::avx::available();
    if !here {
        eprintln!("skipped: this CPU has no AVX2, so the traversals never take that path");
    }
    here
}

/// The eight box tests on AVX2 decide as the two groups of four do and give the same entry
/// distances, bit for bit, on every node of the trees above, for rays that start on faces,
/// run inside slabs and have zero components (the slab test's NaN path), near and far.
#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
#[test]
fn avx_box_test_gives_the_sse_bits() {
    use super::super::avx::Avx;
    use super::super::node::{BoxTest, RayLanes, Sse};
    if !avx2_or_skip() {
        return;
    }
    let sets = [(lattice_boxes(3000, 1), 10.0), (random_boxes(2000, 3), 100.0), (random_boxes(5, 4), 100.0)];
    let (mut entered, mut exact) = (0, 0);
    for (boxes, scale) in &sets {
        let wide = super::super::fold::fold(&build_binary_with(boxes, LeafPolicy::TRIANGLES).nodes);
        for k in 0..400u64 {
            let ray = ray(k, *scale);
            let r = RayLanes::new(ray.origin, ray.dir);
            exact += usize::from(r.exact);
            for node in &wide.nodes {
                for t_max in [f32::INFINITY, 5.0, 0.0] {
                    let (sse, avx) = match r.exact {
                        false => (Sse::hit::<false>(node, &r, t_max), Avx::hit::<false>(node, &r, t_max)),
                        true => (Sse::hit::<true>(node, &r, t_max), Avx::hit::<true>(node, &r, t_max)),
                    };
                    assert_eq!(sse.0, avx.0, "ray {k} ({ray:?}), t_max {t_max}: lanes entered");
                    for lane in (0..super::super::node::WIDTH).filter(|l| sse.0 & (1 << l) != 0) {
                        assert_eq!(
                            sse.1[lane].to_bits(),
                            avx.1[lane].to_bits(),
                            "ray {k}, lane {lane}: entry"
                        );
                        entered += 1;
                    }
                }
            }
        }
    }
    assert!(entered > 10_000 && exact > 50, "{entered} lanes entered, {exact} rays with zero components");
}

/// The entered lanes put in visit order on AVX2 as the scalar fold puts them: every mask
/// against orders of every length (positions past a node's lanes name lane 7).
#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
#[test]
fn avx_visit_order_gives_the_scalar_bits() {
    use super::super::avx::Avx;
    use super::super::node::{BoxTest, Sse};
    if !avx2_or_skip() {
        return;
    }
    for k in 0..2000u64 {
        let lanes = 2 + (k % 7) as u32;
        let mut order: Vec<u32> = (0..lanes).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, (hash_words(&[k, i as u64]) % (i as u64 + 1)) as usize);
        }
        order.resize(super::super::node::WIDTH, 7);
        let packed = order.iter().enumerate().fold(0, |p, (k, &l)| p | l << (3 * k));
        for mask in 0..256u32 {
            let mask = mask & ((1 << lanes) - 1);
            assert_eq!(
                Avx::visit(mask, packed),
                Sse::visit(mask, packed),
                "mask {mask:08b}, order {order:?}"
            );
        }
    }
}

/// A box inside another is entered only if the outer one is, also where the slab test
/// meets 0 × ∞: what lets the folded tree skip the binary nodes it swallowed.
#[test]
fn box_test_is_monotone_under_containment() {
    let outer = Aabb { min: Vec3::new(0.0, 0.0, 0.0), max: Vec3::new(2.0, 2.0, 2.0) };
    let inners = [
        outer,
        Aabb { min: Vec3::new(0.0, 1.0, 0.0), max: Vec3::new(2.0, 1.0, 2.0) },
        Aabb { min: Vec3::new(0.0, 0.0, 0.0), max: Vec3::new(0.0, 2.0, 2.0) },
        Aabb { min: Vec3::new(1.0, 1.0, 1.0), max: Vec3::new(2.0, 2.0, 2.0) },
    ];
    let coords = [-1.0, 0.0, 1.0, 2.0, 3.0];
    let dirs = [0.0, -0.0, 1.0, -1.0, 0.5];
    let mut checked = 0;
    for o in coords.iter().flat_map(|&x| coords.iter().flat_map(move |&y| coords.map(|z| Vec3::new(x, y, z))))
    {
        for inv in dirs.iter().flat_map(|&x| dirs.iter().flat_map(move |&y| dirs.map(|z| Vec3::new(x, y, z))))
        {
            let inv = inv.recip();
            for inner in &inners {
                for t_max in [f32::INFINITY, 1.0] {
                    if inner.hit(o, inv, t_max).is_some() {
                        assert!(outer.hit(o, inv, t_max).is_some(), "origin {o}, 1/dir {inv}, {inner:?}");
                        checked += 1;
                    }
                }
            }
        }
    }
    assert!(checked > 1000, "{checked} hits");
}

/// A visit that hands the walk the leaf of a slot it passes over, and records the slots it
/// is given.
struct PassingOver<F> {
    /// The walk's bits of the leaf that holds the slot alone, if any.
    leaf: u32,
    f: F,
}

impl<F: FnMut(usize, usize) -> bool> super::super::Visits for PassingOver<F> {
    fn visit(&mut self, first: usize, count: usize) -> bool {
        (self.f)(first, count)
    }

    fn left_out(&self) -> super::super::LeftOut {
        super::super::LeftOut(self.leaf)
    }
}

/// Given a slot its visit passes over, a flat any-hit walk leaves out the leaf that holds
/// that slot alone, and nothing else: its visits are the binary tree's without that leaf.
/// A tree walked with its nodes visits what the binary tree visits.
#[test]
fn a_flat_walk_leaves_out_a_lone_slot_passed_over() {
    let sets = [
        (lattice_boxes(12, 6), 10.0),
        (random_boxes(16, 8), 100.0),
        (random_boxes(5, 4), 100.0),
        (exponential_boxes(16), 100.0),
        (random_boxes(40, 9), 100.0),
    ];
    let (mut left_out, mut flat) = (0, 0);
    for (set, (boxes, scale)) in sets.iter().enumerate() {
        let binary = build_binary_with(boxes, LeafPolicy::SHAPES);
        let lone: Vec<usize> =
            binary.nodes.iter().filter(|n| n.count == 1).map(|n| n.offset as usize).collect();
        let wide = super::super::fold::fold(&binary.nodes);
        flat += usize::from(wide.is_flat());
        for wide in [wide.clone(), wide.without_avx()] {
            for k in 0..2000u64 {
                let r = ray(k * 5 + set as u64, *scale);
                let mut expected = vec![];
                reference::visit_slots(&binary, &r, f32::INFINITY, |s| {
                    expected.push(s);
                    true
                });
                // A slot the ray reaches, mostly (as a shadow ray reaches its light).
                let h = hash_words(&[k, 11]);
                let over = if expected.is_empty() || h.is_multiple_of(4) {
                    (h / 4 % boxes.len() as u64) as usize
                } else {
                    expected[(h / 4 % expected.len() as u64) as usize]
                };
                if wide.is_flat() && lone.contains(&over) {
                    let before = expected.len();
                    expected.retain(|&s| s != over);
                    left_out += before - expected.len();
                }
                let mut seen = vec![];
                let f = |first, count| {
                    seen.extend(first..first + count);
                    true
                };
                let mut visit = PassingOver { leaf: wide.lone_leaf(over), f };
                wide.each_leaf(r.origin, r.dir, f32::INFINITY, &mut visit);
                assert_eq!(seen, expected, "set {set}, ray {k}: slot {over} passed over");
            }
        }
    }
    assert_eq!(flat, 4, "the sets walked flat");
    assert!(left_out > 500, "only {left_out} leaves left out: the rays miss the lone slots");
}
