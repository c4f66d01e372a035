//! The BVH as rays traverse it: eight children to a node, their eight boxes tested at once
//! (`node.rs`: two groups of four SIMD lanes; `avx.rs`: one of eight where the CPU has
//! AVX2, the same bits).
//!
//! The tree is the binary one the builder makes, folded: each wide node takes a binary
//! node's children and opens the largest of them until it has eight. A ray visits the same
//! leaves in the same order as it visits the binary tree (`tests::wide_visits_what_the_binary_tree_visits`),
//! so the nearest hit among equal distances and the order in which shadow rays multiply
//! transmissions keep their bits. Two facts make that so:
//! - *Same order.* The binary traversal goes to the near child first by the sign of the
//!   ray's direction on the node's split axis. A folded node keeps the axes of the binary
//!   nodes it swallowed, and so has one visit order of its lanes for each of the eight sign
//!   patterns a direction can have (`Node8::order`).
//! - *Same visits.* The binary traversal skips a child whose box the ray does not enter
//!   before the current `t_max`; the wide one tests a child's box at the parent against
//!   the parent's `t_max` and tests the entry distance again against the current `t_max`
//!   when it takes the child from the stack, which is the binary test split in two (its
//!   exit distance does not depend on `t_max`). The binary nodes folded away are never
//!   tested, and need not be: a box inside another is entered only if that one is
//!   ([`Aabb::hit`] is monotone under containment, the reason for its rule on slabs the ray
//!   runs inside of), and `t_max` only shrinks.
//!
//! Why eight and not four: on a million triangles a random ray's walk is a chain of
//! dependent loads, most of them misses of the L2 cache; a node of eight is one level in
//! three fewer than a node of four, and its four cache lines are adjacent, so they arrive
//! together (docs/speed.md, "Seventh part").

use std::cell::RefCell;

use glam::Vec3;

#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
use super::avx::{available as avx_available, Avx};
use super::flat::Flat;
use super::node::{BoxTest, Node8, RayLanes, Sse, LANE, LANE_BITS, WIDTH};
use super::{Aabb, Leaves, Visits};

/// No AVX2 path where glam runs scalar code or off x86-64.
#[cfg(not(all(target_arch = "x86_64", not(feature = "scalar"))))]
fn avx_available() -> bool {
    false
}

/// A child to visit: its lane (node × 8 + lane) and the distance at which the ray enters it.
#[derive(Debug, Clone, Copy, Default)]
struct Entry {
    t: f32,
    at: u32,
}

/// Entries of the stacks: a small one in the traversal's frame for small trees, and one a
/// thread keeps for the rest; a deeper tree (the builder's worst cases) traverses with a
/// stack on the heap.
const SMALL_STACK: usize = 16;
const STACK: usize = 64;

thread_local! {
    /// A stack made once per thread rather than per ray: zeroing 64 entries in the frame
    /// for every ray took 5 % of the torus knot's camera rays (`bench rays --ab`,
    /// docs/speed.md, forty-second part), where 16 cost a small scene nothing it notices.
    /// A walk inside a walk (a leaf's own tree) finds it taken and zeroes one of its own.
    static THREAD_STACK: RefCell<[Entry; STACK]> = const { RefCell::new([Entry { t: 0.0, at: 0 }; STACK]) };
}

/// The wide tree.
#[derive(Debug, Clone, Default)]
pub(super) struct Wide {
    nodes: Vec<Node8>,
    /// The most entries a traversal's stack can hold.
    depth: usize,
    /// The same tree walked flat, where it has few leaves (`flat.rs`).
    flat: Option<Flat>,
    /// Traversals test boxes with AVX2 (`avx.rs`): this CPU has it.
    #[cfg_attr(not(all(target_arch = "x86_64", not(feature = "scalar"))), allow(dead_code))]
    avx: bool,
}

impl Wide {
    /// The folded nodes (`fold::fold`), root first, whose traversals need at most `depth`
    /// stack entries, and the tree's flat form where it has one, which the walks then take.
    pub(super) fn new(nodes: Vec<Node8>, depth: usize, flat: Option<Flat>) -> Wide {
        assert!(nodes.len() <= 1 << (32 - LANE_BITS), "more BVH nodes than a stack entry can name");
        Wide { nodes, depth, flat, avx: avx_available() }
    }

    /// [`Bvh::lone_leaf`]'s bits: only a flat walk leaves out leaves.
    pub(super) fn lone_leaf(&self, k: usize) -> u32 {
        self.flat.as_ref().map_or(0, |flat| flat.lone_leaf(k))
    }

    /// Whether the walks take the flat form. For tests.
    #[cfg(test)]
    pub(super) fn is_flat(&self) -> bool {
        self.flat.is_some()
    }

    /// The same tree traversed with two groups of four lanes even where AVX2 is there: the
    /// tests' second path.
    #[cfg(test)]
    pub(super) fn without_avx(mut self) -> Wide {
        self.avx = false;
        self
    }

    /// [`Wide::nearest_leaves`] a slot at a time: `hit(slot, t_max)` returns the distance
    /// of a hit closer than `t_max`, which then shortens the search. For tests.
    #[cfg(test)]
    pub(super) fn nearest<const COHERENT: bool>(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        mut hit: impl FnMut(usize, f32) -> Option<f32>,
    ) -> f32 {
        self.nearest_leaves::<COHERENT>(origin, dir, t_max, &mut |first, count, t_max| {
            super::nearest_in_leaf(first, count, t_max, &mut hit)
        })
    }

    /// Visits the leaves the ray enters before `t_max` in the binary tree's order,
    /// nearest-first by split axis: `leaf(first, count, t_max)` tests slots
    /// `first..first + count` in order, each against the `t_max` the ones before it left,
    /// and returns the last, which then shortens the search. Returns the final `t_max`.
    ///
    /// `COHERENT` chooses how a node's entered lanes are gathered, never what is visited:
    /// with a branch on each lane for rays traced beside others like them (a pixel's
    /// camera rays, whose branches the CPU predicts, and then runs ahead into the next
    /// node), without one for the rest (a lane's entry is a coin toss there, lost about a
    /// third of the time). Each way costs the other kind of ray 3–30 % (docs/speed.md,
    /// tenth part).
    #[inline]
    pub(super) fn nearest_leaves<const COHERENT: bool>(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_max: f32,
        hit: &mut impl Leaves,
    ) -> f32 {
        if self.nodes.is_empty() {
            return t_max;
        }
        let r = RayLanes::new(origin, dir);
        #[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
        if self.avx {
            // SAFETY: `avx` is set only where the CPU runs AVX and AVX2.
            #[allow(unsafe_code)]
            return unsafe { self.nearest_avx::<COHERENT>(&r, t_max, hit) };
        }
        if let Some(flat) = &self.flat {
            return flat.nearest::<Sse>(&r, t_max, hit);
        }
        self.with_stack(|stack| match r.exact {
            false => self.nearest_in::<false, COHERENT, Sse>(&r, t_max, hit, stack),
            true => self.nearest_in::<true, COHERENT, Sse>(&r, t_max, hit, stack),
        })
    }

    /// [`Wide::nearest_leaves`] compiled with AVX2 enabled, so that its box tests and everything
    /// inlined into it (the primitives' tests too) may use it. The stack's closure is
    /// written here, not in a helper shared with the SSE2 path: a closure made in a function
    /// without the feature does not get it, and with such a helper the knot's rays took
    /// 10 % more instructions (2 515 → 2 760 M, callgrind; `each_avx` likewise).
    #[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
    #[target_feature(enable = "avx,avx2")]
    #[allow(unsafe_code)]
    unsafe fn nearest_avx<const COHERENT: bool>(
        &self,
        r: &RayLanes,
        t_max: f32,
        hit: &mut impl Leaves,
    ) -> f32 {
        if let Some(flat) = &self.flat {
            return flat.nearest::<Avx>(r, t_max, hit);
        }
        self.with_stack(|stack| match r.exact {
            false => self.nearest_in::<false, COHERENT, Avx>(r, t_max, hit, stack),
            true => self.nearest_in::<true, COHERENT, Avx>(r, t_max, hit, stack),
        })
    }

    /// Runs `f` with a stack deep enough for this tree.
    #[inline(always)]
    fn with_stack<R>(&self, f: impl FnOnce(&mut [Entry]) -> R) -> R {
        if self.depth <= SMALL_STACK {
            f(&mut [Entry::default(); SMALL_STACK])
        } else if self.depth <= STACK {
            THREAD_STACK.with(|stack| match stack.try_borrow_mut() {
                Ok(mut stack) => f(&mut stack[..]),
                Err(_) => f(&mut [Entry::default(); STACK]),
            })
        } else {
            f(&mut vec![Entry::default(); self.depth])
        }
    }

    #[inline(always)]
    fn nearest_in<const EXACT: bool, const COHERENT: bool, B: BoxTest>(
        &self,
        r: &RayLanes,
        mut t_max: f32,
        hit: &mut impl Leaves,
        stack: &mut [Entry],
    ) -> f32 {
        let mut top = 0;
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            let (mask, enter) = B::hit::<EXACT>(n, r, t_max);
            if mask != 0 {
                // The lanes entered go on the stack, the last to visit deepest, except the
                // first: it would be taken straight back (its entry is at most `t_max`,
                // which has not changed), so it is visited now.
                let lane = if mask & (mask - 1) == 0 {
                    mask.trailing_zeros()
                } else if COHERENT {
                    let order = n.order(r.signs);
                    let mut first = 0;
                    for k in (0..n.lanes.count_ones()).rev() {
                        let lane = (order >> (LANE_BITS * k)) & LANE;
                        if mask & (1 << lane) != 0 {
                            stack[top] =
                                Entry { t: enter[lane as usize], at: (node as u32) << LANE_BITS | lane };
                            top += 1;
                            first = lane;
                        }
                    }
                    top -= 1;
                    first
                } else {
                    // The entered lanes in visit order (bit k: the lane at position k),
                    // gathered without a branch; positions past the node's lanes name a
                    // lane it does not have. The same entries are pushed in the same order.
                    let order = n.order(r.signs);
                    let lane_at = |k: u32| (order >> (LANE_BITS * k)) & LANE;
                    let visit = B::visit(mask, order);
                    let mut rest = visit & (visit - 1);
                    while rest != 0 {
                        let k = 31 - rest.leading_zeros();
                        let lane = lane_at(k);
                        stack[top] = Entry { t: enter[lane as usize], at: (node as u32) << LANE_BITS | lane };
                        top += 1;
                        rest &= !(1 << k);
                    }
                    lane_at(visit.trailing_zeros())
                } as usize;
                // The visit below is written out again for entries from the stack: one
                // visit site fed by an `Option` of the lane cost 1 % more instructions on
                // the small scenes and 5 % on the knot's rays (callgrind, 2026-12-03).
                let (first, count) = (n.child[lane] as usize, n.count(lane));
                if count == 0 {
                    node = first;
                    continue;
                }
                t_max = hit.leaf(first, count, t_max);
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
                let (p, lane) = (&self.nodes[(e.at >> LANE_BITS) as usize], (e.at & LANE) as usize);
                let (first, count) = (p.child[lane] as usize, p.count(lane));
                if count == 0 {
                    node = first;
                    break;
                }
                t_max = hit.leaf(first, count, t_max);
            }
        }
    }

    /// [`Wide::each_leaf`] a slot at a time, while `f` returns true. For tests.
    #[cfg(test)]
    pub(super) fn each(&self, origin: Vec3, dir: Vec3, t_max: f32, mut f: impl FnMut(usize) -> bool) {
        self.each_leaf(origin, dir, t_max, &mut |first, count| (first..first + count).all(&mut f))
    }

    /// Visits the leaves the ray enters before `t_max` in the binary tree's depth-first
    /// order (first child first): `leaf(first, count)` visits slots `first..first + count`
    /// in order and returns whether the walk goes on.
    #[inline]
    pub(super) fn each_leaf(&self, origin: Vec3, dir: Vec3, t_max: f32, f: &mut impl Visits) {
        if self.nodes.is_empty() {
            return;
        }
        let r = RayLanes::new(origin, dir);
        #[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
        if self.avx {
            // SAFETY: `avx` is set only where the CPU runs AVX and AVX2.
            #[allow(unsafe_code)]
            return unsafe { self.each_avx(&r, t_max, f) };
        }
        if let Some(flat) = &self.flat {
            return flat.each::<Sse>(&r, t_max, f);
        }
        self.with_stack(|stack| match r.exact {
            false => self.each_in::<false, Sse>(&r, t_max, f, stack),
            true => self.each_in::<true, Sse>(&r, t_max, f, stack),
        })
    }

    /// [`Wide::each_leaf`] compiled with AVX2 enabled.
    #[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
    #[target_feature(enable = "avx,avx2")]
    #[allow(unsafe_code)]
    unsafe fn each_avx(&self, r: &RayLanes, t_max: f32, f: &mut impl Visits) {
        if let Some(flat) = &self.flat {
            return flat.each::<Avx>(r, t_max, f);
        }
        self.with_stack(|stack| match r.exact {
            false => self.each_in::<false, Avx>(r, t_max, f, stack),
            true => self.each_in::<true, Avx>(r, t_max, f, stack),
        })
    }

    #[inline(always)]
    fn each_in<const EXACT: bool, B: BoxTest>(
        &self,
        r: &RayLanes,
        t_max: f32,
        f: &mut impl Visits,
        stack: &mut [Entry],
    ) {
        let mut top = 0;
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            let (mask, _) = B::hit::<EXACT>(n, r, t_max);
            if mask != 0 {
                // Lanes are in the binary tree's depth-first order: the last goes deepest,
                // and the first, which would be taken straight back, is visited now.
                let lane = mask.trailing_zeros();
                let mut rest = mask & (mask - 1);
                while rest != 0 {
                    let last = 31 - rest.leading_zeros();
                    stack[top] = Entry { t: 0.0, at: (node as u32) << LANE_BITS | last };
                    top += 1;
                    rest &= !(1 << last);
                }
                let (first, count) = (n.child[lane as usize] as usize, n.count(lane as usize));
                if count == 0 {
                    node = first;
                    continue;
                }
                if !f.visit(first, count) {
                    return;
                }
            }
            // `t_max` does not change: every entry on the stack is visited.
            loop {
                if top == 0 {
                    return;
                }
                top -= 1;
                let at = stack[top].at;
                let (p, lane) = (&self.nodes[(at >> LANE_BITS) as usize], (at & LANE) as usize);
                let (first, count) = (p.child[lane] as usize, p.count(lane));
                if count == 0 {
                    node = first;
                    break;
                }
                if !f.visit(first, count) {
                    return;
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
            for lane in 0..WIDTH {
                if n.lanes & (1 << lane) == 0 {
                    continue;
                }
                let b = n.lane_box(lane);
                if outer.is_some_and(|o| !o.contains(&b)) {
                    return Err(format!("node {i} lane {lane} outside its parent's box"));
                }
                let (first, count) = (n.child[lane] as usize, n.count(lane));
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
        match seen.iter().zip(indices).position(|(s, &i)| !s && i != super::PADDING) {
            Some(k) => Err(format!("slot {k} in no leaf")),
            None => Ok(()),
        }
    }

    /// The bytes of the nodes.
    pub(super) fn bytes(&self) -> usize {
        std::mem::size_of_val(&self.nodes[..]) + self.flat.as_ref().map_or(0, Flat::bytes)
    }

    /// The box of everything.
    pub(super) fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, |n| {
            (0..WIDTH).filter(|l| n.lanes & (1 << l) != 0).fold(Aabb::EMPTY, |b, l| b.union(n.lane_box(l)))
        })
    }
}

#[cfg(test)]
#[path = "wide_tests.rs"]
mod tests;
