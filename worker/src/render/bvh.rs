//! A bounding volume hierarchy over axis-aligned boxes, built with the binned surface area
//! heuristic. It sees only boxes: the caller keeps the primitives and intersects them in a
//! closure, so the same BVH serves spheres, rectangles, triangles and moving objects (whose
//! box covers their whole motion over the shutter). The builder makes a binary tree
//! (`build.rs`); rays traverse it folded into nodes of eight (`fold.rs`, `wide.rs`), which
//! visit the same leaves in the same order.

use glam::Vec3;

use super::geometry::{gamma, Ray};

/// An axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3,
    /// Upper corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box: the identity of `union`.
    pub const EMPTY: Aabb = Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    /// The box of a set of points.
    pub fn from_points(points: impl IntoIterator<Item = Vec3>) -> Aabb {
        points.into_iter().fold(Aabb::EMPTY, |b, p| b.grow(p))
    }

    /// The box grown to hold `p`.
    pub fn grow(self, p: Vec3) -> Aabb {
        Aabb { min: self.min.min(p), max: self.max.max(p) }
    }

    /// The box holding both.
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    /// Whether the box holds nothing.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// The centre.
    pub fn centroid(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Surface area (0 for an empty box).
    pub fn surface_area(&self) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let d = self.max - self.min;
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }

    /// Whether `other` lies inside this box.
    pub fn contains(&self, other: &Aabb) -> bool {
        other.is_empty() || (self.min.cmple(other.min).all() && self.max.cmpge(other.max).all())
    }

    /// The entry distance of a ray into the box, if it enters before `t_max`. The far
    /// distance is widened by the rounding error bound of the slab test, so that a ray
    /// grazing a box edge is never missed (pbrt's robust test).
    ///
    /// The box is closed: a ray parallel to a slab (a zero direction component, whose
    /// reciprocal is infinite) and inside it or on one of its faces is not limited by it.
    /// On a face the slab test meets 0 × ∞ = NaN; the slab then imposes nothing. That rule
    /// makes the test monotone — a box inside another is entered only if that one is —
    /// which lets the wide BVH skip the binary nodes it folds away (`wide.rs`).
    #[inline]
    pub fn hit(&self, origin: Vec3, inv_dir: Vec3, t_max: f32) -> Option<f32> {
        let t0 = (self.min - origin) * inv_dir;
        let t1 = (self.max - origin) * inv_dir;
        let inside = t0.is_nan_mask() | t1.is_nan_mask();
        let near = Vec3::select(inside, Vec3::NEG_INFINITY, t0.min(t1));
        let far = Vec3::select(inside, Vec3::INFINITY, t0.max(t1));
        let t_enter = near.max_element().max(0.0);
        let t_exit = (far.min_element() * slab_widening()).min(t_max);
        (t_enter <= t_exit).then_some(t_enter)
    }
}

/// The exit distance's widening for the rounding of the slab test (pbrt's robust test):
/// one definition for [`Aabb::hit`] and the wide nodes' lanes, whose decisions must agree.
#[inline(always)]
pub(super) fn slab_widening() -> f32 {
    1.0 + 2.0 * gamma(3)
}

/// A node of the binary tree the builder makes (folded into [`wide`] nodes for traversal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Node {
    bounds: Aabb,
    /// Leaf: first index into `indices`. Interior: distance from this node to its second
    /// child (the first child follows the node), so that subtrees built apart can be
    /// appended without rewriting their links.
    offset: u32,
    /// Primitives in a leaf; 0 for an interior node.
    count: u32,
    /// Split axis of an interior node: which child to visit first.
    axis: u8,
}

/// The hierarchy.
#[derive(Debug, Clone, Default)]
pub struct Bvh {
    wide: Wide,
    indices: Vec<u32>,
}

/// The binary tree the builder makes, in depth-first order (a node, its first subtree, its
/// second), and the primitive of each slot in its leaf order.
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct Binary {
    pub(super) nodes: Vec<Node>,
    pub(super) indices: Vec<u32>,
}

/// Bins of the SAH sweep: 12 is within a percent of a full sweep at a fraction of its cost.
const BINS: usize = 12;
/// Leaves never hold more than this (when the SAH would keep more, split at the median).
const MAX_LEAF: usize = 8;

/// What the builder's SAH weighs: a node visit against a primitive test, and the largest
/// set it keeps as a leaf without weighing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeafPolicy {
    /// Cost of visiting a node relative to intersecting one primitive.
    traversal_cost: f32,
    /// Sets of at most this many primitives are leaves.
    always_leaf: usize,
    /// Primitives tested at once: a leaf's cost is counted in blocks of this many, and
    /// leaves start on a block in the slots (`Bvh::indices` pads them with [`PADDING`]).
    block: usize,
}

/// A leaf's slots `first..first + count` tested one after another, `hit(slot, t_max)`
/// returning the distance of a hit closer than `t_max`, each against the `t_max` the ones
/// before it left; returns the last. The order every leaf test keeps, the one of four
/// lanes at once included.
#[inline(always)]
pub fn nearest_in_leaf(
    first: usize,
    count: usize,
    mut t_max: f32,
    mut hit: impl FnMut(usize, f32) -> Option<f32>,
) -> f32 {
    for k in first..first + count {
        if let Some(t) = hit(k, t_max) {
            t_max = t_max.min(t);
        }
    }
    t_max
}

/// What a nearest-hit walk does at a leaf: tests slots `first..first + count` in order, each
/// against the `t_max` the ones before it left, and returns the last. A trait, not only a
/// closure (every `FnMut(usize, usize, f32) -> f32` is one), so that the scene's search can
/// ask for its test to be inlined into the walk (`#[inline(always)]` on its method): as a
/// closure it was a call at every leaf, with the AVX state cleared before it and the ray's
/// lanes loaded again after it (docs/speed.md, thirty-seventh part).
pub trait Leaves {
    /// The leaf's test.
    fn leaf(&mut self, first: usize, count: usize, t_max: f32) -> f32;
}

impl<F: FnMut(usize, usize, f32) -> f32> Leaves for F {
    #[inline(always)]
    fn leaf(&mut self, first: usize, count: usize, t_max: f32) -> f32 {
        self(first, count, t_max)
    }
}

/// What an any-hit walk does at a leaf: visits slots `first..first + count` in order and
/// returns whether the walk goes on. A trait for the reason [`Leaves`] is one: the shadow
/// rays' test (`shadow.rs`) is inlined into the walk.
pub trait Visits {
    /// The leaf's visit.
    fn visit(&mut self, first: usize, count: usize) -> bool;

    /// Leaves whose visits would do nothing and go on (the leaf of a shadow ray's own
    /// light, [`Bvh::lone_leaf`]): a walk may leave them out.
    #[inline(always)]
    fn left_out(&self) -> LeftOut {
        LeftOut::NONE
    }
}

/// Leaves an any-hit walk may leave out ([`Visits::left_out`]), as [`Bvh::lone_leaf`]
/// names them: bit k for leaf k of a tree walked flat (`flat.rs`); other trees leave out
/// none.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeftOut(u32);

impl LeftOut {
    /// No leaf.
    pub const NONE: LeftOut = LeftOut(0);
}

impl<F: FnMut(usize, usize) -> bool> Visits for F {
    #[inline(always)]
    fn visit(&mut self, first: usize, count: usize) -> bool {
        self(first, count)
    }
}

/// An entry of [`Bvh::indices`] that holds no primitive: the rest of a leaf's last block.
pub const PADDING: u32 = u32::MAX;

/// The most padding a tree takes, as a fraction of its primitives. Meshes take an eighth or
/// less (the terrain 0.04, the torus knot 0.10, `scenes/mesh.toml` 0.12), but a mesh made
/// for it (clusters of four triangles with lone ones split off at growing distances) could
/// make every other leaf a lone triangle padded to four slots; the bound keeps the memory
/// the summary reserves (`tessera_description::summary::BVH_BYTES_PER_PRIMITIVE`) true.
pub const MAX_PADDING: f64 = 0.25;
/// Padding slots any tree may take beyond [`MAX_PADDING`], so that small meshes (the
/// 33 triangles of `scenes/emissive_mesh.toml` take 12) keep every leaf on a block.
pub const PADDING_ALLOWANCE: usize = 256;

impl LeafPolicy {
    /// For triangle meshes: a leaf's inline triangles are tested four at a time
    /// (`triangles::Pack`), which costs about what a node's box test does, so leaves fill
    /// blocks of four and start on one. Against leaves of one to three triangles tested one
    /// by one, the terrain's render took 10 % less time and the torus knot's random rays
    /// about a tenth (docs/speed.md, sixteenth part).
    pub const TRIANGLES: LeafPolicy = LeafPolicy { traversal_cost: 1.0, always_leaf: 4, block: 4 };
    /// For scenes made mostly of other shapes than still triangles (spheres,
    /// parallelograms, moving primitives): one of their tests costs several box tests (a
    /// sphere's is in f64), and a node's boxes are tested at once, so the SAH may put each in
    /// a leaf of its own. On the Cornell box (160×90, 16 spp) it takes the primitives a
    /// nearest-hit ray tests from 7.9 of 8 to 1.1, a shadow ray's from 8.0 to 0.03, and a
    /// quarter of the instructions per sample (docs/speed.md).
    pub const SHAPES: LeafPolicy = LeafPolicy { traversal_cost: 0.25, always_leaf: 1, block: 1 };

    /// The policy for a scene whose primitives are `inline_triangles` triangles tested
    /// from the BVH's slots (`triangles::inline`) and `others` other items (primitives, or
    /// moving meshes' instances).
    pub fn for_scene(inline_triangles: usize, others: usize) -> LeafPolicy {
        if others > inline_triangles {
            LeafPolicy::SHAPES
        } else {
            LeafPolicy::TRIANGLES
        }
    }
}

impl Bvh {
    /// Builds the hierarchy over primitives with the given boxes. Subtrees of more than
    /// [`PARALLEL_MIN`] primitives build in parallel; every split depends only on the
    /// boxes, so the tree is the same for any number of threads.
    pub fn build(bounds: &[Aabb]) -> Bvh {
        Self::build_with(bounds, LeafPolicy::TRIANGLES)
    }

    /// [`Bvh::build`] with the leaves `policy` asks for.
    pub fn build_with(bounds: &[Aabb], policy: LeafPolicy) -> Bvh {
        let Binary { mut nodes, indices } = build_binary_with(bounds, policy);
        let indices = if policy.block > 1 { pad(&mut nodes, &indices, policy.block) } else { indices };
        Bvh { wide: fold::fold(&nodes), indices }
    }

    /// Bounds of everything.
    pub fn bounds(&self) -> Aabb {
        self.wide.bounds()
    }

    /// The bytes its nodes and primitive indices take (what the memory estimate of
    /// `tessera_description::summary` must cover).
    pub fn bytes(&self) -> usize {
        self.wide.bytes() + std::mem::size_of_val(&self.indices[..])
    }

    /// The most bytes per primitive a build holds beside what [`Bvh::bytes`] counts: the
    /// binary tree (at most two nodes per primitive) and the builder's boxes and bins.
    pub const BUILD_BYTES_PER_PRIMITIVE: usize =
        2 * std::mem::size_of::<Node>() + std::mem::size_of::<PrimBox>() + std::mem::size_of::<u8>();

    /// The primitive in each slot of the leaf order: a leaf holds slots `offset..offset +
    /// count`. Slots between leaves of a policy with blocks hold [`PADDING`], no primitive:
    /// the walks never hand them over, and whatever reads this array whole must skip them.
    pub fn indices(&self) -> &[u32] {
        &self.indices
    }

    /// The leaf that holds slot `k` alone, for a visit that passes that slot over to hand
    /// the walk as [`Visits::left_out`]; [`LeftOut::NONE`] where no walk leaves it out.
    pub fn lone_leaf(&self, k: usize) -> LeftOut {
        LeftOut(self.wide.lone_leaf(k))
    }

    /// Renames the primitives: slot k then holds `name(indices()[k])` (padding stays
    /// padding). For a tree built over a list of some primitives and other objects.
    pub fn rename(&mut self, name: impl Fn(u32) -> u32) {
        for i in self.indices.iter_mut().filter(|i| **i != PADDING) {
            *i = name(*i);
        }
    }

    /// Visits the primitives whose boxes the ray enters before `t_max`, nearest subtree
    /// first. `hit(primitive, t_max)` returns the distance of a hit closer than `t_max`,
    /// which then shortens the search. Returns the final `t_max`.
    pub fn traverse(&self, ray: &Ray, t_max: f32, mut hit: impl FnMut(u32, f32) -> Option<f32>) -> f32 {
        self.traverse_slots::<false>(ray, t_max, |k, t_max| hit(self.indices[k], t_max))
    }

    /// [`Bvh::traverse`] by slot: `hit(slot, t_max)`, where slot k holds primitive
    /// `indices()[k]` (for data stored in leaf order). `COHERENT`: the ray is traced among
    /// others like it (a pixel's camera rays), which chooses the walk's loop and nothing it
    /// visits (`Wide::nearest_leaves`).
    #[inline]
    pub fn traverse_slots<const COHERENT: bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        mut hit: impl FnMut(usize, f32) -> Option<f32>,
    ) -> f32 {
        self.wide.nearest_leaves::<COHERENT>(ray.origin, ray.dir, t_max, &mut |first, count, t_max| {
            nearest_in_leaf(first, count, t_max, &mut hit)
        })
    }

    /// [`Bvh::traverse_slots`] a leaf at a time: `leaf(first, count, t_max)` tests slots
    /// `first..first + count` in order, each against the `t_max` the ones before it left,
    /// and returns the last (so that a leaf's triangles can be tested at once).
    #[inline]
    pub fn traverse_leaves<const COHERENT: bool>(
        &self,
        ray: &Ray,
        t_max: f32,
        leaf: &mut impl Leaves,
    ) -> f32 {
        self.wide.nearest_leaves::<COHERENT>(ray.origin, ray.dir, t_max, leaf)
    }

    /// Visits the primitives whose boxes the ray enters before `t_max`, in no particular
    /// order, while `f` returns true (for shadow rays, which need any blocker).
    pub fn visit(&self, ray: &Ray, t_max: f32, mut f: impl FnMut(u32) -> bool) {
        self.visit_slots(ray, t_max, |k| f(self.indices[k]))
    }

    /// [`Bvh::visit`] by slot (see [`Bvh::traverse_slots`]).
    #[inline]
    pub fn visit_slots(&self, ray: &Ray, t_max: f32, mut f: impl FnMut(usize) -> bool) {
        self.visit_leaves(ray, t_max, &mut |first, count| (first..first + count).all(&mut f))
    }

    /// [`Bvh::visit_slots`] a leaf at a time: `leaf(first, count)` visits slots
    /// `first..first + count` in order and returns whether the walk goes on.
    #[inline]
    pub fn visit_leaves(&self, ray: &Ray, t_max: f32, leaf: &mut impl Visits) {
        self.wide.each_leaf(ray.origin, ray.dir, t_max, leaf)
    }

    /// Checks the structure: every primitive in exactly one leaf, every box inside its
    /// parent's, every primitive's box inside its leaf's. For tests.
    pub fn validate(&self, bounds: &[Aabb]) -> Result<(), String> {
        let held = self.indices.iter().filter(|&&i| i != PADDING).count();
        if held != bounds.len() {
            return Err(format!("{held} slots for {} primitives", bounds.len()));
        }
        self.wide.validate(&self.indices, bounds)
    }
}

/// `indices` with each leaf of `nodes` moved to start on a multiple of `block`, the gaps
/// filled with [`PADDING`]; the leaves' offsets follow. At most [`MAX_PADDING`] of the
/// primitives' count is padding: once that is spent, leaves start where the last one
/// ended, which the leaf tests take as well (a leaf of up to eight then spans three
/// blocks), at some speed.
fn pad(nodes: &mut [Node], indices: &[u32], block: usize) -> Vec<u32> {
    let mut spare = (indices.len() as f64 * MAX_PADDING) as usize + PADDING_ALLOWANCE;
    let mut out = Vec::with_capacity(indices.len() + spare + block);
    for n in nodes.iter_mut().filter(|n| n.count > 0) {
        let gap = out.len().next_multiple_of(block) - out.len();
        if gap <= spare {
            out.resize(out.len() + gap, PADDING);
            spare -= gap;
        }
        let first = n.offset as usize;
        n.offset = out.len() as u32;
        out.extend_from_slice(&indices[first..first + n.count as usize]);
    }
    out
}

/// The builder's binary tree over primitives with the given boxes.
#[cfg(test)]
pub(super) fn build_binary(bounds: &[Aabb]) -> Binary {
    build_binary_with(bounds, LeafPolicy::TRIANGLES)
}

/// [`build_binary`] with the leaves `policy` asks for.
pub(super) fn build_binary_with(bounds: &[Aabb], policy: LeafPolicy) -> Binary {
    if bounds.is_empty() {
        return Binary::default();
    }
    use rayon::prelude::*;
    let boxes: Vec<PrimBox> =
        bounds.par_iter().map(|b| PrimBox { min: b.min.into(), max: b.max.into() }).collect();
    let prims = Prims { boxes: &boxes, policy };
    let mut indices: Vec<u32> = (0..bounds.len() as u32).collect();
    let mut bins = vec![0u8; bounds.len()];
    // At most 2n - 1 nodes (every leaf holds a primitive): reserved, the vector never
    // regrows and copies itself (twice on the 1M-triangle terrain, whose tree has about
    // 1.05 nodes a primitive). Pages never touched cost nothing.
    let mut nodes = Vec::with_capacity(2 * bounds.len() - 1);
    build_subtree(&prims, &mut indices, &mut bins, 0, &mut nodes, None);
    Binary { nodes, indices }
}

#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
mod avx;
mod build;
mod flat;
mod fold;
mod node;
#[cfg(test)]
mod reference;
mod wide;

pub use build::PARALLEL_MIN;
use build::{build_subtree, PrimBox, Prims};
use wide::Wide;

#[cfg(test)]
mod tests {
    use super::build::PARALLEL_BINS;
    use super::*;
    use crate::render::sampler::hash_words;

    fn random_boxes(n: usize, seed: u64) -> Vec<Aabb> {
        (0..n)
            .map(|i| {
                let h = |k: u64| (hash_words(&[seed, i as u64, k]) >> 40) as f32 / (1u64 << 24) as f32;
                let c = Vec3::new(h(0), h(1), h(2)) * 100.0;
                let r = Vec3::new(h(3), h(4), h(5)) * 2.0;
                Aabb { min: c - r, max: c + r }
            })
            .collect()
    }

    #[test]
    fn degenerate_inputs_build_valid_trees() {
        for boxes in [
            vec![],
            vec![Aabb { min: Vec3::ZERO, max: Vec3::ZERO }; 100],
            vec![Aabb { min: Vec3::splat(-1e30), max: Vec3::splat(1e30) }; 3],
            random_boxes(1, 1),
            random_boxes(1000, 2),
        ] {
            for policy in [LeafPolicy::TRIANGLES, LeafPolicy::SHAPES] {
                let bvh = Bvh::build_with(&boxes, policy);
                bvh.validate(&boxes).unwrap();
            }
        }
    }

    /// The shapes' policy builds another tree than the meshes' on a handful of spheres
    /// (leaves of one where the triangles' keeps them together), and a scene gets it when
    /// most of its primitives are not inline triangles.
    #[test]
    fn the_shapes_policy_splits_small_sets_the_triangle_policy_keeps() {
        let boxes = random_boxes(8, 11);
        let leaves = |b: &Binary| b.nodes.iter().filter(|n| n.count > 0).count();
        let (tri, shapes) =
            (build_binary_with(&boxes, LeafPolicy::TRIANGLES), build_binary_with(&boxes, LeafPolicy::SHAPES));
        assert!(leaves(&shapes) > leaves(&tri), "{} leaves against {}", leaves(&shapes), leaves(&tri));
        assert_eq!(LeafPolicy::for_scene(0, 8), LeafPolicy::SHAPES);
        assert_eq!(LeafPolicy::for_scene(1_000_000, 1), LeafPolicy::TRIANGLES);
        assert_eq!(LeafPolicy::for_scene(4, 4), LeafPolicy::TRIANGLES);
    }

    /// The same nodes (boxes equal as numbers: see `Boxes` on the sign of zero) and the
    /// same leaf order.
    fn same_tree(a: &Binary, b: &Binary) -> bool {
        a == b
    }

    /// The builder makes the tree the sequential builder it replaced made, bit for bit,
    /// and the same tree on 1 and 4 threads.
    #[test]
    fn build_matches_the_old_builder_on_any_thread_count() {
        // The second set is large enough for bins gathered in parallel (PARALLEL_BINS).
        let mut sets = vec![random_boxes(1000, 7), random_boxes(PARALLEL_BINS + 3 * PARALLEL_MIN, 8)];
        // Zeros of both signs on the box faces (an OBJ's "-0.0"), small and large.
        for (n, seed) in [(20_000, 9), (PARALLEL_BINS + 5000, 10)] {
            sets.push(
                random_boxes(n, seed)
                    .into_iter()
                    .enumerate()
                    .map(|(i, b)| {
                        let z = if i % 2 == 0 { 0.0 } else { -0.0 };
                        let min = if i % 3 == 0 { Vec3::new(z, b.min.y, z) } else { b.min };
                        Aabb { min: min.min(b.max), max: b.max }
                    })
                    .collect(),
            );
        }
        // Many equal centroids and flat boxes: the median and leaf fallbacks.
        sets.push(
            (0..40_000)
                .map(|i| {
                    let c = Vec3::new((i % 7) as f32, 0.0, (i % 3) as f32);
                    Aabb { min: c, max: c + Vec3::new(1.0, 0.0, 1.0) }
                })
                .collect(),
        );
        for boxes in sets {
            let old = reference::build(&boxes);
            let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
            let one = pool(1).install(|| build_binary(&boxes));
            let four = pool(4).install(|| build_binary(&boxes));
            assert!(same_tree(&old, &one), "{} boxes: not the old tree", boxes.len());
            assert!(same_tree(&one, &four), "{} boxes: 1 and 4 threads differ", boxes.len());
            Bvh { wide: fold::fold(&four.nodes), indices: four.indices }.validate(&boxes).unwrap();
            // The shapes' policy has no old builder to match, but must not depend on threads.
            let one = pool(1).install(|| build_binary_with(&boxes, LeafPolicy::SHAPES));
            let four = pool(4).install(|| build_binary_with(&boxes, LeafPolicy::SHAPES));
            assert!(same_tree(&one, &four), "{} boxes, shapes' policy: 1 and 4 threads differ", boxes.len());
            Bvh { wide: fold::fold(&four.nodes), indices: four.indices }.validate(&boxes).unwrap();
        }
    }

    /// Traversal finds exactly the boxes a brute-force test finds.
    #[test]
    fn traversal_visits_every_box_the_ray_enters() {
        let boxes = random_boxes(500, 3);
        let bvh = Bvh::build(&boxes);
        for k in 0..200u64 {
            let h = |j: u64| (hash_words(&[k, j]) >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            let ray = Ray::new(Vec3::new(h(0), h(1), h(2)) * 200.0, Vec3::new(h(3), h(4), h(5)).normalize());
            let inv = ray.dir.recip();
            let mut visited = std::collections::HashSet::new();
            bvh.traverse(&ray, f32::INFINITY, |i, _| {
                visited.insert(i);
                None
            });
            for (i, b) in boxes.iter().enumerate() {
                if b.hit(ray.origin, inv, f32::INFINITY).is_some() {
                    assert!(visited.contains(&(i as u32)), "ray {k} missed box {i}");
                }
            }
            // The triangles' leaves start on a block of four (these boxes take less padding
            // than `MAX_PADDING` allows) and hold no padding.
            bvh.visit_leaves(&ray, f32::INFINITY, &mut |first, count| {
                assert_eq!(first % 4, 0, "ray {k}: a leaf at slot {first}");
                assert!((1..=MAX_LEAF).contains(&count), "ray {k}: a leaf of {count}");
                assert!(bvh.indices[first..first + count].iter().all(|&i| i != PADDING), "ray {k}");
                true
            });
        }
    }
}
