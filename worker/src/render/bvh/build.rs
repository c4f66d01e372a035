//! The builder: binned SAH over the primitives' boxes, subtrees built in parallel, every
//! split a function of the boxes alone (so any thread count gives the same tree, which
//! `tests::build_matches_the_old_builder_on_any_thread_count` holds it to).

use glam::Vec3A;

use super::{Aabb, LeafPolicy, Node, BINS, MAX_LEAF};

/// The primitives' boxes, read by index while building (moving the boxes with the indices
/// instead was measured slower: a swap then moves 28 bytes, not 4).
pub(super) struct Prims<'a> {
    pub(super) boxes: &'a [PrimBox],
    pub(super) policy: LeafPolicy,
}

/// A primitive's box as the builder reads it: both corners in one aligned 32-byte record,
/// one fetch per primitive, its centre computed from them (lane-wise `(min + max) * 0.5`,
/// the bits of [`Aabb::centroid`]) instead of read from a second array.
#[derive(Debug, Clone, Copy)]
pub(super) struct PrimBox {
    pub(super) min: Vec3A,
    pub(super) max: Vec3A,
}

impl PrimBox {
    #[inline(always)]
    fn centroid(&self) -> Vec3A {
        (self.min + self.max) * 0.5
    }
}

/// [`Boxes`] being gathered over primitives, in SIMD lanes: `Vec3A`'s lane-wise min and
/// max differ from `f32::min`/`max` only for NaN (the boxes are finite) and in the sign of
/// a zero (see [`Boxes`]), and cost one instruction each instead of several.
#[derive(Debug, Clone, Copy)]
struct Gather {
    min: Vec3A,
    max: Vec3A,
    cmin: Vec3A,
    cmax: Vec3A,
}

impl Gather {
    const EMPTY: Gather = Gather {
        min: Vec3A::INFINITY,
        max: Vec3A::NEG_INFINITY,
        cmin: Vec3A::INFINITY,
        cmax: Vec3A::NEG_INFINITY,
    };

    #[inline(always)]
    fn add(&mut self, b: &PrimBox, c: Vec3A) {
        self.min = self.min.min(b.min);
        self.max = self.max.max(b.max);
        self.cmin = self.cmin.min(c);
        self.cmax = self.cmax.max(c);
    }

    fn union(&self, o: &Gather) -> Gather {
        Gather {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
            cmin: self.cmin.min(o.cmin),
            cmax: self.cmax.max(o.cmax),
        }
    }

    /// The surface area of the primitives' box, as [`Aabb::surface_area`] computes it.
    #[inline(always)]
    fn area(&self) -> f32 {
        Aabb { min: self.min.into(), max: self.max.into() }.surface_area()
    }

    fn boxes(&self) -> Boxes {
        Boxes {
            bounds: Aabb { min: self.min.into(), max: self.max.into() },
            centroids: Aabb { min: self.cmin.into(), max: self.cmax.into() },
        }
    }
}

/// Subtrees at least this large build on another thread (below, the hand-off costs more
/// than it saves).
pub const PARALLEL_MIN: usize = 16 * 1024;

/// Appends the subtree over `items` to `nodes` in depth first order (a node, its first
/// subtree, its second); `start` is the position of `items[0]` in the final order. `bins`
/// (as long as `items`) is scratch space for the split's bin of each item.
pub(super) fn build_subtree(
    p: &Prims,
    items: &mut [u32],
    bins: &mut [u8],
    start: usize,
    nodes: &mut Vec<Node>,
    known: Option<Boxes>,
) {
    // The node's box and its centres' box: from the parent's bins when it had them, else
    // in one pass.
    let Boxes { bounds: node_bounds, centroids: cb } = known.unwrap_or_else(|| {
        let mut g = Gather::EMPTY;
        for it in items.iter() {
            let b = &p.boxes[*it as usize];
            g.add(b, b.centroid());
        }
        g.boxes()
    });
    let node = nodes.len();
    let Some(Split { mid, axis, children }) = split(p, items, bins, &node_bounds, &cb) else {
        nodes.push(Node { bounds: node_bounds, offset: start as u32, count: items.len() as u32, axis: 0 });
        return;
    };
    nodes.push(Node { bounds: node_bounds, offset: 0, count: 0, axis: axis as u8 });
    let parallel = items.len() >= PARALLEL_MIN;
    let (first, second) = items.split_at_mut(mid);
    let (first_bins, second_bins) = bins.split_at_mut(mid);
    let (a, b) = (children.map(|c| c[0]), children.map(|c| c[1]));
    if parallel {
        // A subtree over n items has at most 2n - 1 nodes: reserved, it never regrows.
        let mut far = Vec::with_capacity(2 * second.len() - 1);
        rayon::join(
            || build_subtree(p, first, first_bins, start, nodes, a),
            || build_subtree(p, second, second_bins, start + mid, &mut far, b),
        );
        nodes[node].offset = (nodes.len() - node) as u32;
        nodes.append(&mut far);
    } else {
        build_subtree(p, first, first_bins, start, nodes, a);
        nodes[node].offset = (nodes.len() - node) as u32;
        build_subtree(p, second, second_bins, start + mid, nodes, b);
    }
}

/// A set of primitives' box and their centres' box.
///
/// Unions are exact (min and max round nothing), and the boxes are finite, so a union in
/// any order is the same box; only the sign of a zero coordinate may differ, which no box
/// test, area or bin below can tell (-0 and +0 compare equal, give the same differences
/// and products up to that sign, and `hit` only compares them). Building the children's
/// boxes from the bins therefore makes the same tree as folding their items.
#[derive(Debug, Clone, Copy)]
pub(super) struct Boxes {
    bounds: Aabb,
    centroids: Aabb,
}

/// A chosen split: the first child holds `items[..mid]`; its boxes, when the bins gave them.
struct Split {
    mid: usize,
    axis: usize,
    children: Option<[Boxes; 2]>,
}

/// Chooses a split of `items` by the binned SAH; reorders `items` and returns the split,
/// or `None` for a leaf. `bin_ids` is scratch space: each item's bin, found once for the
/// bins and the partition both.
fn split(p: &Prims, items: &mut [u32], bin_ids: &mut [u8], node_bounds: &Aabb, cb: &Aabb) -> Option<Split> {
    let n = items.len();
    if n <= p.policy.always_leaf {
        return None;
    }
    let extent = cb.max - cb.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let median = |items: &mut [u32]| {
        let mid = median_split(p, items, axis);
        Split { mid, axis, children: None }
    };
    if !(extent[axis] > 0.0) {
        // All centroids coincide: no split can separate them.
        return (n > MAX_LEAF).then_some(Split { mid: n / 2, axis, children: None });
    }
    let bins = if n >= PARALLEL_BINS {
        use rayon::prelude::*;
        // Bins are unions and counts, the same whatever the order they are gathered in.
        (items.par_chunks(PARALLEL_BINS / 4))
            .zip(bin_ids.par_chunks_mut(PARALLEL_BINS / 4))
            .map(|(items, ids)| gather_bins(p, items, ids, axis, cb.min[axis], extent[axis]))
            .reduce(|| [(Gather::EMPTY, 0); BINS], merge_bins)
    } else {
        gather_bins(p, items, bin_ids, axis, cb.min[axis], extent[axis])
    };
    // Sweep from the right to get the boxes, area and count of each right side.
    let mut right = [(Gather::EMPTY, 0.0f32, 0usize); BINS];
    let (mut acc, mut count) = (Gather::EMPTY, 0);
    for b in (1..BINS).rev() {
        acc = acc.union(&bins[b].0);
        count += bins[b].1;
        right[b] = (acc, acc.area(), count);
    }
    let (mut acc, mut count) = (Gather::EMPTY, 0);
    let mut best = (f32::INFINITY, 0, Gather::EMPTY);
    // A leaf's tests are counted in the blocks its primitives are tested in.
    let blocks = |n: usize| n.div_ceil(p.policy.block) as f32;
    for b in 0..BINS - 1 {
        acc = acc.union(&bins[b].0);
        count += bins[b].1;
        let (_, ra, rc) = right[b + 1];
        if count == 0 || rc == 0 {
            continue;
        }
        let cost = acc.area() * blocks(count) + ra * blocks(rc);
        if cost < best.0 {
            best = (cost, b, acc);
        }
    }
    let leaf_cost = node_bounds.surface_area() * blocks(n);
    let split_cost = p.policy.traversal_cost * node_bounds.surface_area() + best.0;
    if best.0.is_infinite() || (split_cost >= leaf_cost && n <= MAX_LEAF) {
        return (n > MAX_LEAF).then(|| median(items));
    }
    let mid = partition(items, bin_ids, best.1 as u8);
    if mid == 0 || mid == n {
        return Some(median(items));
    }
    Some(Split { mid, axis, children: Some([best.2.boxes(), right[best.1 + 1].0.boxes()]) })
}

/// Nodes with at least this many items gather their bins on several threads (the top of
/// the tree, where the subtrees are still too few to keep the threads busy).
pub(super) const PARALLEL_BINS: usize = 64 * 1024;

/// The bins of `items` along `axis` (centres from `lo` over `span`), with each item's bin
/// written to `bin_ids`.
fn gather_bins(
    p: &Prims,
    items: &[u32],
    bin_ids: &mut [u8],
    axis: usize,
    lo: f32,
    span: f32,
) -> [(Gather, usize); BINS] {
    let mut bins = [(Gather::EMPTY, 0usize); BINS];
    for (it, id) in items.iter().zip(bin_ids.iter_mut()) {
        let bx = &p.boxes[*it as usize];
        let c = bx.centroid();
        // The bin as the builder always computed it, operation for operation; through
        // `i32`, whose saturating conversion is shorter than `usize`'s and, clamped to the
        // bins, gives the same bin for every value (NaN and negatives 0, the rest capped).
        let b = (((c[axis] - lo) / span * BINS as f32) as i32).clamp(0, BINS as i32 - 1) as usize;
        *id = b as u8;
        bins[b].0.add(bx, c);
        bins[b].1 += 1;
    }
    bins
}

fn merge_bins(mut a: [(Gather, usize); BINS], b: [(Gather, usize); BINS]) -> [(Gather, usize); BINS] {
    for (x, y) in a.iter_mut().zip(b) {
        x.0 = x.0.union(&y.0);
        x.1 += y.1;
    }
    a
}

fn median_split(p: &Prims, items: &mut [u32], axis: usize) -> usize {
    let mid = items.len() / 2;
    let c = |i: &u32| p.boxes[*i as usize].centroid()[axis];
    items.select_nth_unstable_by(mid, |a, b| c(a).total_cmp(&c(b)));
    mid
}

/// Moves the items whose bin is at most `last` to the front, in the order the builder
/// always did (a Lomuto pass); returns how many. `bin_ids[i]` is the bin of the item that
/// was at `i` before the pass, which is the item the pass finds there: a swap only touches
/// the positions it has passed.
fn partition(items: &mut [u32], bin_ids: &[u8], last: u8) -> usize {
    let mut mid = 0;
    for (i, &bin) in bin_ids.iter().enumerate().take(items.len()) {
        if bin <= last {
            items.swap(i, mid);
            mid += 1;
        }
    }
    mid
}
