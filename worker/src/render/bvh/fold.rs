//! Folding the builder's binary tree into the wide nodes rays traverse (`wide.rs` says
//! why the folded tree visits what the binary one visits): each wide node takes a binary
//! node's two children and opens the largest interior one (by surface area) until it has
//! four lanes or only leaves, keeping the split axes of the nodes it opened for its visit
//! orders.

use glam::Vec4;

use super::wide::Node4;
use super::Node;

/// A wide node over binary nodes `kids` (in depth-first order), `lanes` of them, with the
/// visit orders `order`; interior kids' lanes point at `child` given alongside.
pub(super) fn node4(kids: &[(&Node, u32)], lanes: usize, order: [u8; 8]) -> Node4 {
    let mut n = Node4 {
        min: [Vec4::ZERO; 3],
        max: [Vec4::ZERO; 3],
        child: [0; 4],
        count: [0; 4],
        order,
        lanes: (1u8 << lanes) - 1,
    };
    for (lane, (kid, child)) in kids.iter().enumerate() {
        for a in 0..3 {
            n.min[a][lane] = kid.bounds.min[a];
            n.max[a][lane] = kid.bounds.max[a];
        }
        if kid.count > 0 {
            n.child[lane] = kid.offset;
            n.count[lane] = u8::try_from(kid.count).expect("leaves hold at most MAX_LEAF slots");
        } else {
            n.child[lane] = *child;
        }
    }
    n
}

/// The binary nodes a wide node holds: a small tree whose leaves are its lanes.
enum Part {
    /// A binary node that becomes a lane.
    Kid(usize),
    /// A binary node opened: its split axis and its two children, first child first.
    Open(u8, Box<[Part; 2]>),
}

impl Part {
    fn open(binary: &[Node], b: usize) -> Part {
        let n = &binary[b];
        Part::Open(n.axis, Box::new([Part::Kid(b + 1), Part::Kid(b + n.offset as usize)]))
    }

    /// The lanes' binary nodes in depth-first order.
    fn kids(&self, out: &mut Vec<usize>) {
        match self {
            Part::Kid(b) => out.push(*b),
            Part::Open(_, parts) => parts.iter().for_each(|p| p.kids(out)),
        }
    }

    /// The lanes in the order a ray with direction signs `signs` visits them: at each
    /// opened node, its far child first when the direction is negative on its axis.
    fn order(&self, signs: usize, kids: &[usize], out: &mut Vec<usize>) {
        match self {
            Part::Kid(b) => out.push(kids.iter().position(|k| k == b).expect("a lane of this node")),
            Part::Open(axis, parts) => {
                let [a, b] = &**parts;
                let (first, second) = if signs & (1 << axis) != 0 { (b, a) } else { (a, b) };
                first.order(signs, kids, out);
                second.order(signs, kids, out);
            }
        }
    }

    /// The interior kid with the largest surface area (the first of equals), to open next.
    fn largest(&self, binary: &[Node]) -> Option<usize> {
        let mut kids = Vec::new();
        self.kids(&mut kids);
        let mut best: Option<(usize, f32)> = None;
        for k in kids {
            let area = binary[k].bounds.surface_area();
            if binary[k].count == 0 && best.is_none_or(|(_, a)| area > a) {
                best = Some((k, area));
            }
        }
        best.map(|(k, _)| k)
    }

    fn open_kid(&mut self, binary: &[Node], target: usize) {
        match self {
            Part::Kid(b) if *b == target => *self = Part::open(binary, target),
            Part::Kid(_) => {}
            Part::Open(_, parts) => parts.iter_mut().for_each(|p| p.open_kid(binary, target)),
        }
    }
}

/// Appends the wide subtree of interior binary node `b` to `nodes` (the node, then its
/// children's subtrees in lane order); returns the most stack entries its traversal needs.
pub(super) fn fold_node(binary: &[Node], b: usize, nodes: &mut Vec<Node4>) -> usize {
    let mut part = Part::open(binary, b);
    let mut kids = Vec::with_capacity(4);
    loop {
        kids.clear();
        part.kids(&mut kids);
        if kids.len() == 4 {
            break;
        }
        match part.largest(binary) {
            Some(k) => part.open_kid(binary, k),
            None => break,
        }
    }
    let mut order = [0u8; 8];
    let mut lanes = Vec::with_capacity(4);
    for (signs, o) in order.iter_mut().enumerate() {
        lanes.clear();
        part.order(signs, &kids, &mut lanes);
        *o = lanes.iter().enumerate().fold(0, |acc, (k, &lane)| acc | (lane as u8) << (2 * k));
    }
    let at = nodes.len();
    nodes.push(node4(&[], 1, order));
    let mut children = [0u32; 4];
    let mut deepest = 0;
    for (lane, &k) in kids.iter().enumerate() {
        if binary[k].count == 0 {
            children[lane] = u32::try_from(nodes.len()).expect("node index");
            deepest = deepest.max(fold_node(binary, k, nodes));
        }
    }
    let with: Vec<(&Node, u32)> = kids.iter().zip(children).map(|(&k, c)| (&binary[k], c)).collect();
    nodes[at] = node4(&with, kids.len(), order);
    // All of a node's lanes may be on the stack at once, above what its deepest child needs.
    kids.len() + deepest
}
