//! The BVH as rays traverse it: four children to a node, their four boxes tested at once
//! in SIMD lanes (glam's `Vec4`: SSE2 on x86-64, plain floats with `scalar-math`).
//!
//! The tree is the binary one the builder makes, folded: each wide node takes a binary
//! node's children and opens the largest of them until it has four. A ray visits the same
//! leaves in the same order as it visits the binary tree (`tests::wide_visits_what_the_binary_tree_visits`),
//! so the nearest hit among equal distances and the order in which shadow rays multiply
//! transmissions keep their bits. Two facts make that so:
//! - *Same order.* The binary traversal goes to the near child first by the sign of the
//!   ray's direction on the node's split axis. A folded node keeps the axes of the binary
//!   nodes it swallowed, and so has one visit order of its lanes for each of the eight sign
//!   patterns a direction can have (`Node4::order`).
//! - *Same visits.* The binary traversal skips a child whose box the ray does not enter
//!   before the current `t_max`; the wide one tests a child's box at the parent against
//!   the parent's `t_max` and tests the entry distance again against the current `t_max`
//!   when it takes the child from the stack, which is the binary test split in two (its
//!   exit distance does not depend on `t_max`). The binary nodes folded away are never
//!   tested, and need not be: a box inside another is entered only if that one is
//!   ([`Aabb::hit`] is monotone under containment, the reason for its rule on slabs the ray
//!   runs inside of), and `t_max` only shrinks.

use glam::{Vec3, Vec4};

use super::{slab_widening, Aabb};

/// One node: the boxes of up to four children, lane by lane.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
pub(super) struct Node4 {
    /// Lower corners: x, y and z of the four children.
    pub(super) min: [Vec4; 3],
    /// Upper corners.
    pub(super) max: [Vec4; 3],
    /// An interior child's node; a leaf's first slot.
    pub(super) child: [u32; 4],
    /// A leaf's slot count; 0 for an interior child.
    pub(super) count: [u8; 4],
    /// For each sign pattern of the ray's direction (bit k set: negative on axis k), the
    /// order to visit the lanes in, two bits a lane, the first in the low bits.
    pub(super) order: [u8; 8],
    /// Bit k set: lane k holds a child.
    pub(super) lanes: u8,
}

/// A child to visit: its lane (node × 4 + lane) and the distance at which the ray enters it.
#[derive(Debug, Clone, Copy, Default)]
struct Entry {
    t: f32,
    at: u32,
}

/// Entries of the stacks kept in the traversal's frame, a small one for small scenes (a
/// stack is zeroed for every ray, which a scene of a few primitives notices); a deeper
/// tree (the builder's worst cases) traverses with a stack on the heap.
const SMALL_STACK: usize = 16;
const STACK: usize = 64;

/// A ray prepared for box tests: origin and reciprocal direction splatted over the lanes.
pub(super) struct RayLanes {
    origin: [Vec4; 3],
    inv: [Vec4; 3],
    /// The direction's sign pattern.
    pub(super) signs: usize,
    /// Some component of the direction is zero: a slab test may meet 0 × ∞.
    exact: bool,
}

impl RayLanes {
    pub(super) fn new(origin: Vec3, dir: Vec3) -> RayLanes {
        let inv = dir.recip();
        let signs = usize::from(inv.x < 0.0) | usize::from(inv.y < 0.0) << 1 | usize::from(inv.z < 0.0) << 2;
        RayLanes {
            origin: [Vec4::splat(origin.x), Vec4::splat(origin.y), Vec4::splat(origin.z)],
            inv: [Vec4::splat(inv.x), Vec4::splat(inv.y), Vec4::splat(inv.z)],
            signs,
            exact: !inv.is_finite(),
        }
    }
}

impl Node4 {
    /// The lanes whose boxes the ray enters before `t_max` (bit k for lane k) and the
    /// entry distances: [`Aabb::hit`] four at a time, with the same decisions. Without
    /// `EXACT` the slab test cannot meet NaN (no direction component is zero and the boxes
    /// and origin are finite), and then lane-wise min and max differ from `f32::min`/`max`
    /// only in the sign of a zero, which comparisons cannot see.
    #[inline(always)]
    fn hit<const EXACT: bool>(&self, r: &RayLanes, t_max: f32) -> (u32, [f32; 4]) {
        let mut enter = Vec4::ZERO;
        let mut exit = Vec4::INFINITY;
        for a in 0..3 {
            let t0 = (self.min[a] - r.origin[a]) * r.inv[a];
            let t1 = (self.max[a] - r.origin[a]) * r.inv[a];
            let (mut near, mut far) = (t0.min(t1), t0.max(t1));
            if EXACT {
                let inside = t0.is_nan_mask() | t1.is_nan_mask();
                near = Vec4::select(inside, Vec4::NEG_INFINITY, near);
                far = Vec4::select(inside, Vec4::INFINITY, far);
            }
            enter = enter.max(near);
            exit = exit.min(far);
        }
        let exit = (exit * slab_widening()).min(Vec4::splat(t_max));
        (enter.cmple(exit).bitmask() & u32::from(self.lanes), enter.to_array())
    }
}

/// The wide tree.
#[derive(Debug, Clone, Default)]
pub(super) struct Wide {
    nodes: Vec<Node4>,
    /// The most entries a traversal's stack can hold.
    depth: usize,
}

impl Wide {
    /// The folded nodes (`fold::fold`), root first, whose traversals need at most `depth`
    /// stack entries.
    pub(super) fn new(nodes: Vec<Node4>, depth: usize) -> Wide {
        assert!(nodes.len() < (1 << 30), "more BVH nodes than a stack entry can name");
        Wide { nodes, depth }
    }

    /// Visits the slots of the leaves the ray enters before `t_max` in the binary tree's
    /// order, nearest-first by split axis; `hit(slot, t_max)` returns the distance of a hit
    /// closer than `t_max`, which then shortens the search. Returns the final `t_max`.
    #[inline]
    pub(super) fn nearest(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        hit: impl FnMut(usize, f32) -> Option<f32>,
    ) -> f32 {
        if self.nodes.is_empty() {
            return t_max;
        }
        let r = RayLanes::new(origin, dir);
        self.with_stack(|stack| match r.exact {
            false => self.nearest_in::<false>(&r, t_max, hit, stack),
            true => self.nearest_in::<true>(&r, t_max, hit, stack),
        })
    }

    /// Runs `f` with a stack deep enough for this tree.
    #[inline(always)]
    fn with_stack<R>(&self, f: impl FnOnce(&mut [Entry]) -> R) -> R {
        if self.depth <= SMALL_STACK {
            f(&mut [Entry::default(); SMALL_STACK])
        } else if self.depth <= STACK {
            f(&mut [Entry::default(); STACK])
        } else {
            f(&mut vec![Entry::default(); self.depth])
        }
    }

    #[inline(always)]
    fn nearest_in<const EXACT: bool>(
        &self,
        r: &RayLanes,
        mut t_max: f32,
        mut hit: impl FnMut(usize, f32) -> Option<f32>,
        stack: &mut [Entry],
    ) -> f32 {
        let mut top = 0;
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            let (mask, enter) = n.hit::<EXACT>(r, t_max);
            if mask != 0 {
                let order = u32::from(n.order[r.signs]);
                // Last to visit goes deepest into the stack.
                for k in (0..n.lanes.count_ones()).rev() {
                    let lane = (order >> (2 * k)) & 3;
                    if mask & (1 << lane) != 0 {
                        stack[top] = Entry { t: enter[lane as usize], at: (node as u32) << 2 | lane };
                        top += 1;
                    }
                }
            }
            // The next child the ray still enters before the current `t_max`.
            loop {
                if top == 0 {
                    return t_max;
                }
                top -= 1;
                let e = stack[top];
                if e.t > t_max {
                    continue;
                }
                let (p, lane) = (&self.nodes[(e.at >> 2) as usize], (e.at & 3) as usize);
                let (first, count) = (p.child[lane] as usize, p.count[lane] as usize);
                if count == 0 {
                    node = first;
                    break;
                }
                for k in first..first + count {
                    if let Some(t) = hit(k, t_max) {
                        t_max = t_max.min(t);
                    }
                }
            }
        }
    }

    /// Visits the slots of the leaves the ray enters before `t_max` in the binary tree's
    /// depth-first order (first child first), while `f` returns true.
    #[inline]
    pub(super) fn each(&self, origin: Vec3, dir: Vec3, t_max: f32, f: impl FnMut(usize) -> bool) {
        if self.nodes.is_empty() {
            return;
        }
        let r = RayLanes::new(origin, dir);
        self.with_stack(|stack| match r.exact {
            false => self.each_in::<false>(&r, t_max, f, stack),
            true => self.each_in::<true>(&r, t_max, f, stack),
        })
    }

    #[inline(always)]
    fn each_in<const EXACT: bool>(
        &self,
        r: &RayLanes,
        t_max: f32,
        mut f: impl FnMut(usize) -> bool,
        stack: &mut [Entry],
    ) {
        let mut top = 0;
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            let (mask, _) = n.hit::<EXACT>(r, t_max);
            // Lanes are in the binary tree's depth-first order: the last goes deepest.
            for lane in (0..4).rev() {
                if mask & (1 << lane) != 0 {
                    stack[top] = Entry { t: 0.0, at: (node as u32) << 2 | lane };
                    top += 1;
                }
            }
            // `t_max` does not change: every entry on the stack is visited.
            loop {
                if top == 0 {
                    return;
                }
                top -= 1;
                let at = stack[top].at;
                let (p, lane) = (&self.nodes[(at >> 2) as usize], (at & 3) as usize);
                let (first, count) = (p.child[lane] as usize, p.count[lane] as usize);
                if count == 0 {
                    node = first;
                    break;
                }
                for k in first..first + count {
                    if !f(k) {
                        return;
                    }
                }
            }
        }
    }

    /// Checks the structure against the primitives' boxes: every slot in exactly one leaf,
    /// every child's box inside the box its parent holds for it, every primitive's box
    /// inside its leaf's. For tests.
    pub(super) fn validate(&self, indices: &[u32], bounds: &[Aabb]) -> Result<(), String> {
        if self.nodes.is_empty() {
            return if bounds.is_empty() { Ok(()) } else { Err("no nodes".into()) };
        }
        let mut seen = vec![false; indices.len()];
        let mut stack = vec![(0usize, None::<Aabb>)];
        while let Some((i, outer)) = stack.pop() {
            let n = &self.nodes[i];
            for lane in 0..4 {
                if n.lanes & (1 << lane) == 0 {
                    continue;
                }
                let b = n.lane_box(lane);
                if outer.is_some_and(|o| !o.contains(&b)) {
                    return Err(format!("node {i} lane {lane} outside its parent's box"));
                }
                let (first, count) = (n.child[lane] as usize, n.count[lane] as usize);
                if count == 0 {
                    stack.push((first, Some(b)));
                    continue;
                }
                for k in first..first + count {
                    if std::mem::replace(&mut seen[k], true) {
                        return Err(format!("slot {k} in two leaves"));
                    }
                    if !b.contains(&bounds[indices[k] as usize]) {
                        return Err(format!("primitive {} outside its leaf", indices[k]));
                    }
                }
            }
        }
        match seen.iter().position(|s| !s) {
            Some(k) => Err(format!("slot {k} in no leaf")),
            None => Ok(()),
        }
    }

    /// The box of everything.
    pub(super) fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, |n| {
            (0..4).filter(|l| n.lanes & (1 << l) != 0).fold(Aabb::EMPTY, |b, l| b.union(n.lane_box(l)))
        })
    }
}

impl Node4 {
    fn lane_box(&self, lane: usize) -> Aabb {
        let min = Vec3::new(self.min[0][lane], self.min[1][lane], self.min[2][lane]);
        let max = Vec3::new(self.max[0][lane], self.max[1][lane], self.max[2][lane]);
        Aabb { min, max }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::super::{build_binary, reference, Aabb, Binary};
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
    fn calls(binary: &Binary, wide: &Wide, ray: &Ray, k: u64, t_max: f32) -> [(Vec<(usize, u32)>, f32); 4] {
        let made_up = |slot: usize, t_max: f32| {
            let h = hash_words(&[k, slot as u64, 9]);
            h.is_multiple_of(3).then(|| t_max.min(100.0) * unit(&[h]))
        };
        let mut seen = [vec![], vec![]];
        let ends = [
            reference::traverse_slots(binary, ray, t_max, |s, t| {
                seen[0].push((s, t.to_bits()));
                made_up(s, t)
            }),
            wide.nearest(ray.origin, ray.dir, t_max, |s, t| {
                seen[1].push((s, t.to_bits()));
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
        let [a, b] = seen;
        let [c, d] = each;
        [(a, ends[0]), (b, ends[1]), (c, 0.0), (d, 0.0)]
    }

    /// The folded tree visits the slots the binary tree visits, in the same order and with
    /// the same `t_max` at each, for rays that start on faces and run along them too.
    #[test]
    fn wide_visits_what_the_binary_tree_visits() {
        let sets = [
            (lattice_boxes(3000, 1), 10.0),
            (lattice_boxes(200, 2), 10.0),
            (random_boxes(20_000, 3), 100.0),
            (random_boxes(5, 4), 100.0),
            (random_boxes(1, 5), 100.0),
            (exponential_boxes(200), 100.0),
        ];
        let mut visits = 0;
        let mut stacks = std::collections::BTreeSet::new();
        for (set, (boxes, scale)) in sets.iter().enumerate() {
            let binary = build_binary(boxes);
            let wide = super::super::fold::fold(&binary.nodes);
            stacks.insert(if wide.depth <= super::SMALL_STACK {
                "small"
            } else if wide.depth <= super::STACK {
                "frame"
            } else {
                "heap"
            });
            wide.validate(&binary.indices, boxes).unwrap();
            for k in 0..3000u64 {
                let r = ray(k * 7 + set as u64, *scale);
                for t_max in [f32::INFINITY, 5.0] {
                    let [a, b, c, d] = calls(&binary, &wide, &r, k, t_max);
                    assert_eq!(a, b, "set {set}, ray {k}: nearest-hit visits differ");
                    assert_eq!(c, d, "set {set}, ray {k}: any-order visits differ");
                    visits += a.0.len();
                }
            }
        }
        assert!(visits > 100_000, "only {visits} visits: the rays miss the boxes");
        assert_eq!(stacks.len(), 3, "every stack size is exercised: {stacks:?}");
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
        for o in
            coords.iter().flat_map(|&x| coords.iter().flat_map(move |&y| coords.map(|z| Vec3::new(x, y, z))))
        {
            for inv in
                dirs.iter().flat_map(|&x| dirs.iter().flat_map(move |&y| dirs.map(|z| Vec3::new(x, y, z))))
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
}
