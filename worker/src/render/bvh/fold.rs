//! Folding the builder's binary tree into the wide nodes rays traverse (`wide.rs` says
//! why the folded tree visits what the binary one visits): each wide node takes a binary
//! node's two children and opens the largest interior one (by surface area) until it has
//! eight lanes or only leaves, keeping the split axes of the nodes it opened for its visit
//! orders.

use glam::Vec4;

use super::flat::Flat;
use super::node::{Node8, GROUPS, LOWER, ORDERS, UPPER, WIDTH};
use super::wide::Wide;
use super::Node;

/// Folds the binary tree (in the builder's depth-first layout) into wide nodes.
pub(super) fn fold(binary: &[Node]) -> Wide {
    // Wide nodes number 0.27-0.34 of the binary interior nodes on the scenes measured
    // (179 568 of 524 030 on the terrain), which are half the binary tree: a quarter of it
    // leaves room. A regrowth would copy the vector, and a 64-byte-aligned vector's
    // regrowth is a fresh allocation, a copy and a free.
    let mut nodes = Vec::with_capacity(binary.len() / 4 + 1);
    let depth = match binary.first() {
        None => 0,
        Some(root) if root.count > 0 => {
            // A root leaf: one lane.
            let one = order_bits(&[0]);
            nodes.push(node(&[(root, 0)], 1, std::array::from_fn(|i| one[i % 3])));
            1
        }
        Some(_) => fold_node(binary, 0, &mut nodes),
    };
    Wide::new(nodes, depth, Flat::new(binary))
}

/// A wide node over binary nodes `kids` (in depth-first order), `lanes` of them, with the
/// visit orders `order`; interior kids' lanes point at `child` given alongside.
fn node(kids: &[(&Node, u32)], lanes: usize, order: [u8; ORDERS]) -> Node8 {
    let mut n = Node8 {
        planes: [[[Vec4::ZERO; GROUPS]; 3]; 2],
        child: [0; WIDTH],
        counts: 0,
        order,
        lanes: ((1u32 << lanes) - 1) as u8,
    };
    for (lane, (kid, child)) in kids.iter().enumerate() {
        for a in 0..3 {
            n.planes[LOWER][a][lane / 4][lane % 4] = kid.bounds.min[a];
            n.planes[UPPER][a][lane / 4][lane % 4] = kid.bounds.max[a];
        }
        if kid.count > 0 {
            n.child[lane] = kid.offset;
            // MAX_LEAF < 16 (asserted in wide.rs).
            n.counts |= kid.count << (4 * lane);
        } else {
            n.child[lane] = *child;
        }
    }
    n
}

/// One visit order's three bytes: the lanes of `visit`, three bits each, the first in the
/// low bits. Positions past them name the last lane, which a node of fewer than eight does
/// not have: the incoherent walk reads all eight positions without a branch, and a lane
/// that holds no child is never entered.
fn order_bits(visit: &[usize]) -> [u8; 3] {
    let bits = (0..WIDTH).fold(0u32, |acc, k| {
        let lane = visit.get(k).copied().unwrap_or(WIDTH - 1);
        acc | (lane as u32) << (3 * k)
    });
    let b = bits.to_le_bytes();
    [b[0], b[1], b[2]]
}

/// A child of an opened binary node: a binary node that is a lane, or another opened one.
#[derive(Debug, Clone, Copy)]
enum Part {
    Kid(usize),
    Open(usize),
}

/// The binary nodes a wide node holds: up to seven opened binary nodes (the first is the
/// wide node's own), each with its split axis and its two children, first child first;
/// the children not opened are its lanes. Fixed arrays, no allocation: the fold makes one
/// per wide node.
struct Opened {
    axis: [u8; WIDTH - 1],
    parts: [[Part; 2]; WIDTH - 1],
    len: usize,
}

impl Opened {
    fn new(binary: &[Node], b: usize) -> Opened {
        let mut o = Opened { axis: [0; WIDTH - 1], parts: [[Part::Kid(0); 2]; WIDTH - 1], len: 0 };
        o.push(binary, b);
        o
    }

    fn push(&mut self, binary: &[Node], b: usize) -> usize {
        let n = &binary[b];
        let i = self.len;
        self.axis[i] = n.axis;
        self.parts[i] = [Part::Kid(b + 1), Part::Kid(b + n.offset as usize)];
        self.len += 1;
        i
    }

    /// Opens lane `target` (an interior binary node).
    fn open(&mut self, binary: &[Node], target: usize) {
        let i = self.push(binary, target);
        for parts in &mut self.parts[..i] {
            for p in parts.iter_mut() {
                if matches!(p, Part::Kid(k) if *k == target) {
                    *p = Part::Open(i);
                }
            }
        }
    }

    /// Renames the lanes' binary nodes to their lane numbers (their depth-first order), so
    /// that the walks for the visit orders name lanes without looking them up.
    fn number_lanes(&mut self) {
        let mut next = 0;
        self.number(0, &mut next);
    }

    fn number(&mut self, at: usize, next: &mut usize) {
        for j in 0..2 {
            match self.parts[at][j] {
                Part::Kid(_) => {
                    self.parts[at][j] = Part::Kid(*next);
                    *next += 1;
                }
                Part::Open(i) => self.number(i, next),
            }
        }
    }

    /// The lanes' binary nodes (or lane numbers, once numbered): in depth-first order
    /// (first child first) without `signs`; with them, in the order a ray with those
    /// direction signs visits them (at each opened node, its second child first when the
    /// direction is negative on its axis).
    fn kids(&self, signs: Option<usize>) -> ([usize; WIDTH], usize) {
        let mut out = ([0; WIDTH], 0);
        self.walk(0, signs, &mut out);
        out
    }

    fn walk(&self, at: usize, signs: Option<usize>, out: &mut ([usize; WIDTH], usize)) {
        let [a, b] = self.parts[at];
        let swap = signs.is_some_and(|s| s & (1 << self.axis[at]) != 0);
        for p in if swap { [b, a] } else { [a, b] } {
            match p {
                Part::Kid(k) => {
                    out.0[out.1] = k;
                    out.1 += 1;
                }
                Part::Open(i) => self.walk(i, signs, out),
            }
        }
    }
}

/// The interior kid with the largest surface area (the first of equals), to open next.
fn largest(binary: &[Node], kids: &[usize]) -> Option<usize> {
    let mut best: Option<(usize, f32)> = None;
    for &k in kids {
        let area = binary[k].bounds.surface_area();
        if binary[k].count == 0 && best.is_none_or(|(_, a)| area > a) {
            best = Some((k, area));
        }
    }
    best.map(|(k, _)| k)
}

/// Appends the wide subtree of interior binary node `b` to `nodes` (the node, then its
/// children's subtrees in lane order); returns the most stack entries its traversal needs.
fn fold_node(binary: &[Node], b: usize, nodes: &mut Vec<Node8>) -> usize {
    let mut part = Opened::new(binary, b);
    let (mut kids, mut lanes) = part.kids(None);
    while lanes < WIDTH {
        let Some(k) = largest(binary, &kids[..lanes]) else { break };
        part.open(binary, k);
        (kids, lanes) = part.kids(None);
    }
    let kids = &kids[..lanes];
    part.number_lanes();
    let mut order = [0u8; ORDERS];
    for (signs, o) in order.chunks_exact_mut(3).enumerate() {
        let (visit, n) = part.kids(Some(signs));
        o.copy_from_slice(&order_bits(&visit[..n]));
    }
    let at = nodes.len();
    nodes.push(node(&[], 1, order));
    let mut with = [(&binary[b], 0u32); WIDTH];
    let mut deepest = 0;
    for (lane, &k) in kids.iter().enumerate() {
        with[lane].0 = &binary[k];
        if binary[k].count == 0 {
            with[lane].1 = u32::try_from(nodes.len()).expect("node index");
            deepest = deepest.max(fold_node(binary, k, nodes));
        }
    }
    nodes[at] = node(&with[..lanes], lanes, order);
    // All of a node's lanes are on the stack at once when it is visited; while a child's
    // subtree is, at most the other lanes are.
    lanes.max(lanes - 1 + deepest)
}
