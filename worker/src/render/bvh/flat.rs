//! A tree of a few leaves walked without its nodes: every leaf's box tested at once, two
//! nodes' worth of lanes, then the leaves entered taken in the order the binary tree
//! visits them for the ray's direction signs. The leaves are kept once in that order for
//! each of the eight sign patterns, so that the entered ones are the set bits of the box
//! test's mask, in order: the walk passes over none of the leaves it does not enter
//! (docs/speed.md, fortieth part).
//!
//! On a scene of a dozen spheres or parallelograms a camera ray tests about one primitive
//! (1.07 on `spheres`, 1.15 on the Cornell box), yet its walk visited two or three wide
//! nodes: each a box test, a gather of the lanes entered into the stack and a pop per lane.
//! Walked flat, those scenes take 2 % fewer instructions and 4 % less time, the same
//! images (docs/speed.md, thirty-sixth part).
//!
//! It visits what the wide walk visits, in the same order, with the same `t_max` at each
//! leaf (`wide_tests::wide_visits_what_the_binary_tree_visits` covers trees of up to
//! [`MOST_LEAVES`]):
//! - *Order.* The binary walk goes to a node's second child first where the direction is
//!   negative on its split axis; for a tree this small that order of the leaves is kept
//!   for each of the eight sign patterns. The any-hit walk's order is the depth-first one,
//!   the leaves' own.
//! - *Visits.* The wide walk takes a leaf if the ray enters its box before the `t_max` of
//!   the moment it is taken (its test at the parent, against a `t_max` no smaller, and
//!   again when it leaves the stack). Every box on the way down holds the leaf's box, and
//!   the box test is monotone under containment (`Aabb::hit`), so entering the leaf's box
//!   by then implies entering theirs: the ancestors decide nothing the leaf's own test
//!   does not. Here each leaf's box is tested once against the starting `t_max` and its
//!   entry compared with the current one when its turn comes.

use super::node::{BoxTest, Node8, RayLanes, GROUPS, LOWER, ORDERS, UPPER, WIDTH};
use super::{Leaves, Node, Visits};
use glam::Vec4;

/// The most leaves a tree may have to be walked flat: two nodes' lanes.
pub(super) const MOST_LEAVES: usize = 2 * WIDTH;
// [`Flat::alone`] holds a bit a leaf.
const _: () = assert!(MOST_LEAVES <= u16::BITS as usize);

/// The leaves of a small tree as lanes of one or two nodes, in each sign pattern's order.
#[derive(Debug, Clone)]
pub(super) struct Flat {
    /// The leaves for each sign pattern of a direction (as [`RayLanes::signs`]), in the
    /// order the binary walk visits them: pattern s's k-th leaf is lane k % 8 of node
    /// `s * per + k / 8`, with its box, its first slot (`child`) and its slot count. The
    /// nodes' own visit orders are not used. Pattern 0 (no negative component) swaps no
    /// children: its order is the depth-first one, leaf k the k-th leaf of the array.
    ordered: Vec<Node8>,
    /// Nodes a sign pattern takes in `ordered`.
    per: usize,
    /// For each slot, bit k if leaf k holds that slot alone, else 0 ([`Flat::lone_leaf`]).
    alone: Vec<u16>,
}

impl Flat {
    /// The flat form of the builder's binary tree (depth-first, first child after its
    /// parent), if it has a root and at most [`MOST_LEAVES`] leaves.
    pub(super) fn new(binary: &[Node]) -> Option<Flat> {
        // Counting stops past the limit: a big mesh's tree has millions of nodes.
        let leaves = binary.iter().filter(|n| n.count > 0).take(MOST_LEAVES + 1).count();
        if binary.is_empty() || leaves > MOST_LEAVES {
            return None;
        }
        // Leaf numbers in depth-first order are their order in the array.
        let number: Vec<usize> = binary
            .iter()
            .scan(0, |next, n| {
                let k = *next;
                *next += usize::from(n.count > 0);
                Some(k)
            })
            .collect();
        let leaf_nodes: Vec<&Node> = binary.iter().filter(|n| n.count > 0).collect();
        // A leaf's offset is its first slot; an interior node's is its second child's.
        let slots = leaf_nodes.iter().map(|n| (n.offset + n.count) as usize).max();
        let mut alone = vec![0; slots.unwrap_or(0)];
        for (k, n) in leaf_nodes.iter().enumerate().filter(|(_, n)| n.count == 1) {
            alone[n.offset as usize] = 1 << k;
        }
        let per = leaves.div_ceil(WIDTH);
        let mut ordered = Vec::with_capacity(8 * per);
        for signs in 0..8 {
            let mut visit = Vec::with_capacity(leaves);
            walk(binary, &number, 0, signs, &mut visit);
            ordered.extend(lanes(visit.iter().map(|&k| leaf_nodes[k])));
        }
        Some(Flat { ordered, per, alone })
    }

    /// The leaves of `nodes` the ray enters before `t_max` and their entry distances, bit k
    /// for the k-th leaf. The box test's path for rays with a zero direction component is
    /// chosen here: the walk tests boxes only this once, so nothing is gained by choosing it
    /// around the walk.
    #[inline(always)]
    fn entered<B: BoxTest>(nodes: &[Node8], r: &RayLanes, t_max: f32) -> (u32, [f32; MOST_LEAVES]) {
        match r.exact {
            false => Self::entered_as::<false, B>(nodes, r, t_max),
            true => Self::entered_as::<true, B>(nodes, r, t_max),
        }
    }

    #[inline(always)]
    fn entered_as<const EXACT: bool, B: BoxTest>(
        nodes: &[Node8],
        r: &RayLanes,
        t_max: f32,
    ) -> (u32, [f32; MOST_LEAVES]) {
        let mut entries = [0.0; MOST_LEAVES];
        let (mask, first) = B::hit::<EXACT>(&nodes[0], r, t_max);
        entries[..WIDTH].copy_from_slice(&first);
        let Some(node) = nodes.get(1) else { return (mask, entries) };
        let (more, second) = B::hit::<EXACT>(node, r, t_max);
        entries[WIDTH..].copy_from_slice(&second);
        (mask | more << WIDTH, entries)
    }

    /// `Wide::nearest_leaves` on this tree: `leaf(first, count, t_max)` for each leaf the
    /// ray enters before the current `t_max`, in the binary walk's order.
    #[inline(always)]
    pub(super) fn nearest<B: BoxTest>(&self, r: &RayLanes, mut t_max: f32, leaf: &mut impl Leaves) -> f32 {
        let nodes = &self.ordered[r.signs * self.per..][..self.per];
        let (mut mask, entries) = Self::entered::<B>(nodes, r, t_max);
        while mask != 0 {
            let k = mask.trailing_zeros() as usize;
            if entries[k] <= t_max {
                let (first, count) = slots(nodes, k);
                t_max = leaf.leaf(first, count, t_max);
            }
            mask &= mask - 1;
        }
        t_max
    }

    /// `Wide::each_leaf` on this tree: `leaf(first, count)` for each leaf the ray enters
    /// before `t_max`, in depth-first order, while it returns true.
    #[inline(always)]
    pub(super) fn each<B: BoxTest>(&self, r: &RayLanes, t_max: f32, leaf: &mut impl Visits) {
        let nodes = &self.ordered[..self.per];
        let (mut mask, _) = Self::entered::<B>(nodes, r, t_max);
        // A shadow ray ends on its light, so it enters the light's leaf nearly always;
        // where the leaf holds only the light, its visit would change nothing.
        mask &= !leaf.left_out().0;
        while mask != 0 {
            let (first, count) = slots(nodes, mask.trailing_zeros() as usize);
            if !leaf.visit(first, count) {
                return;
            }
            mask &= mask - 1;
        }
    }

    /// The leaf that holds slot `k` alone (bit k), else 0: the leaf an any-hit walk need
    /// not enter when its visit passes the slot over.
    pub(super) fn lone_leaf(&self, k: usize) -> u32 {
        self.alone.get(k).map_or(0, |&bit| u32::from(bit))
    }

    /// The bytes of its nodes and tables.
    pub(super) fn bytes(&self) -> usize {
        std::mem::size_of_val(&self.ordered[..]) + std::mem::size_of_val(&self.alone[..])
    }
}

/// The first slot and slot count of the k-th leaf of `nodes`.
#[inline(always)]
fn slots(nodes: &[Node8], k: usize) -> (usize, usize) {
    let node = &nodes[k / WIDTH];
    (node.child[k % WIDTH] as usize, node.count(k % WIDTH))
}

/// The binary tree's leaves `leaves`, in their order, as the lanes of nodes of eight: the
/// k-th is lane k % 8 of node k / 8.
fn lanes<'a>(leaves: impl ExactSizeIterator<Item = &'a Node>) -> Vec<Node8> {
    let mut nodes = vec![empty_node(); leaves.len().div_ceil(WIDTH)];
    for (k, n) in leaves.enumerate() {
        let (node, lane) = (&mut nodes[k / WIDTH], k % WIDTH);
        for a in 0..3 {
            node.planes[LOWER][a][lane / 4][lane % 4] = n.bounds.min[a];
            node.planes[UPPER][a][lane / 4][lane % 4] = n.bounds.max[a];
        }
        node.child[lane] = n.offset;
        node.counts |= n.count << (4 * lane);
        node.lanes |= 1 << lane;
    }
    nodes
}

/// A node with no lanes.
fn empty_node() -> Node8 {
    Node8 {
        planes: [[[Vec4::ZERO; GROUPS]; 3]; 2],
        child: [0; WIDTH],
        counts: 0,
        order: [0; ORDERS],
        lanes: 0,
    }
}

/// Appends the leaves under binary node `b` in the order a ray with direction signs `signs`
/// visits them: a node's second child first where the direction is negative on its axis.
fn walk(binary: &[Node], number: &[usize], b: usize, signs: usize, out: &mut Vec<usize>) {
    let n = &binary[b];
    if n.count > 0 {
        out.push(number[b]);
        return;
    }
    let (first, second) = (b + 1, b + n.offset as usize);
    let swap = signs & (1 << n.axis) != 0;
    for c in if swap { [second, first] } else { [first, second] } {
        walk(binary, number, c, signs, out);
    }
}
