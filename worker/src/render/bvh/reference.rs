//! The builder as it was before items moved with their boxes and subtrees built in
//! parallel (only the link to the second child is now relative), and the binary traversal
//! as it was before the tree was folded into wide nodes: the tests check that the builder
//! makes the same tree, node for node, and that the wide tree visits the same leaves in
//! the same order, so that images keep their bits.

use glam::Vec3;

use super::{Aabb, Binary, Node, BINS, MAX_LEAF};
use crate::render::geometry::Ray;

pub(super) fn build(bounds: &[Aabb]) -> Binary {
    let mut bvh =
        Binary { nodes: Vec::with_capacity(bounds.len() * 2), indices: (0..bounds.len() as u32).collect() };
    if bounds.is_empty() {
        return bvh;
    }
    let centroids: Vec<Vec3> = bounds.iter().map(|b| b.centroid()).collect();
    let mut stack = vec![(0usize, bounds.len(), usize::MAX)];
    while let Some((start, end, parent)) = stack.pop() {
        let node = bvh.nodes.len();
        if parent != usize::MAX {
            bvh.nodes[parent].offset = (node - parent) as u32;
        }
        let idx = &mut bvh.indices[start..end];
        let node_bounds = idx.iter().fold(Aabb::EMPTY, |b, &i| b.union(bounds[i as usize]));
        let split = split(idx, bounds, &centroids, &node_bounds);
        match split {
            None => bvh.nodes.push(Node {
                bounds: node_bounds,
                offset: start as u32,
                count: (end - start) as u32,
                axis: 0,
            }),
            Some((mid, axis)) => {
                bvh.nodes.push(Node { bounds: node_bounds, offset: 0, count: 0, axis: axis as u8 });
                // Second child first onto the stack, so that the first child is built
                // right after its parent (and sits at parent + 1).
                stack.push((start + mid, end, node));
                stack.push((start, start + mid, usize::MAX));
            }
        }
    }
    bvh
}

/// Chooses a split of `idx` by the binned SAH; reorders `idx` and returns the split
/// position and axis, or `None` for a leaf.
fn split(idx: &mut [u32], bounds: &[Aabb], centroids: &[Vec3], node_bounds: &Aabb) -> Option<(usize, usize)> {
    let n = idx.len();
    // The triangles' policy: sets of four are leaves, and leaves are costed in the blocks
    // of four their triangles are tested in.
    if n <= 4 {
        return None;
    }
    let blocks = |n: usize| n.div_ceil(4) as f32;
    let cb = Aabb::from_points(idx.iter().map(|&i| centroids[i as usize]));
    let extent = cb.max - cb.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    if !(extent[axis] > 0.0) {
        // All centroids coincide: no split can separate them.
        return (n > MAX_LEAF).then_some((n / 2, axis));
    }
    let bin_of = |i: u32| {
        let b = ((centroids[i as usize][axis] - cb.min[axis]) / extent[axis] * BINS as f32) as usize;
        b.min(BINS - 1)
    };
    let mut bins = [(Aabb::EMPTY, 0usize); BINS];
    for &i in idx.iter() {
        let b = bin_of(i);
        bins[b].0 = bins[b].0.union(bounds[i as usize]);
        bins[b].1 += 1;
    }
    // Sweep from the right to get the area and count of each right side.
    let mut right = [(0.0f32, 0usize); BINS];
    let (mut acc, mut count) = (Aabb::EMPTY, 0);
    for b in (1..BINS).rev() {
        acc = acc.union(bins[b].0);
        count += bins[b].1;
        right[b] = (acc.surface_area(), count);
    }
    let (mut acc, mut count) = (Aabb::EMPTY, 0);
    let mut best = (f32::INFINITY, 0);
    for b in 0..BINS - 1 {
        acc = acc.union(bins[b].0);
        count += bins[b].1;
        let (ra, rc) = right[b + 1];
        if count == 0 || rc == 0 {
            continue;
        }
        let cost = acc.surface_area() * blocks(count) + ra * blocks(rc);
        if cost < best.0 {
            best = (cost, b);
        }
    }
    let leaf_cost = node_bounds.surface_area() * blocks(n);
    // A node visit costs what a block's test does.
    let split_cost = node_bounds.surface_area() + best.0;
    if best.0.is_infinite() || (split_cost >= leaf_cost && n <= MAX_LEAF) {
        return (n > MAX_LEAF).then(|| median_split(idx, centroids, axis));
    }
    let mid = partition(idx, |i| bin_of(i) <= best.1);
    if mid == 0 || mid == n {
        return Some(median_split(idx, centroids, axis));
    }
    Some((mid, axis))
}

fn median_split(idx: &mut [u32], centroids: &[Vec3], axis: usize) -> (usize, usize) {
    let mid = idx.len() / 2;
    idx.select_nth_unstable_by(mid, |&a, &b| {
        centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
    });
    (mid, axis)
}

fn partition(idx: &mut [u32], left: impl Fn(u32) -> bool) -> usize {
    let mut mid = 0;
    for i in 0..idx.len() {
        if left(idx[i]) {
            idx.swap(i, mid);
            mid += 1;
        }
    }
    mid
}

/// The binary tree's nearest-hit traversal: near child first by the sign of the direction
/// on the node's split axis, each node's box tested against the current `t_max`.
pub(super) fn traverse_slots(
    bvh: &Binary,
    ray: &Ray,
    mut t_max: f32,
    mut hit: impl FnMut(usize, f32) -> Option<f32>,
) -> f32 {
    if bvh.nodes.is_empty() {
        return t_max;
    }
    let inv_dir = ray.dir.recip();
    let neg = [inv_dir.x < 0.0, inv_dir.y < 0.0, inv_dir.z < 0.0];
    let mut stack = vec![];
    let mut node = 0u32;
    loop {
        let n = &bvh.nodes[node as usize];
        if n.bounds.hit(ray.origin, inv_dir, t_max).is_some() {
            if n.count > 0 {
                for k in n.offset as usize..(n.offset + n.count) as usize {
                    if let Some(t) = hit(k, t_max) {
                        t_max = t_max.min(t);
                    }
                }
            } else {
                let far = node + n.offset;
                let (first, second) = if neg[n.axis as usize] { (far, node + 1) } else { (node + 1, far) };
                stack.push(second);
                node = first;
                continue;
            }
        }
        match stack.pop() {
            Some(n) => node = n,
            None => return t_max,
        }
    }
}

/// The binary tree's any-order traversal: first child first, while `f` returns true.
pub(super) fn visit_slots(bvh: &Binary, ray: &Ray, t_max: f32, mut f: impl FnMut(usize) -> bool) {
    if bvh.nodes.is_empty() {
        return;
    }
    let inv_dir = ray.dir.recip();
    let mut stack = vec![];
    let mut node = 0u32;
    loop {
        let n = &bvh.nodes[node as usize];
        if n.bounds.hit(ray.origin, inv_dir, t_max).is_some() {
            if n.count > 0 {
                for k in n.offset as usize..(n.offset + n.count) as usize {
                    if !f(k) {
                        return;
                    }
                }
            } else {
                stack.push(node + n.offset);
                node += 1;
                continue;
            }
        }
        match stack.pop() {
            Some(n) => node = n,
            None => return,
        }
    }
}
