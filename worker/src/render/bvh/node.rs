//! A node of the wide BVH as it sits in memory, a ray prepared for its box test, and that
//! test: the eight child boxes of a node in two groups of four SIMD lanes (glam's `Vec4`:
//! SSE2 on x86-64, plain floats with `scalar-math`), which `avx.rs` does in one group of
//! eight where the CPU has AVX2. Both `wide.rs`'s traversals and `avx.rs` build on this
//! file, so neither imports the other's.

use glam::{Vec3, Vec4};

use super::{slab_widening, Aabb, MAX_LEAF};

/// Children to a node.
pub(super) const WIDTH: usize = 8;
/// Groups of four SIMD lanes to a node.
pub(super) const GROUPS: usize = WIDTH / 4;
/// Bits of a lane's index in a visit order and a stack entry.
pub(super) const LANE_BITS: u32 = 3;
/// A lane's index among those bits.
pub(super) const LANE: u32 = (1 << LANE_BITS) - 1;
/// [`Node8::planes`]' lower corners.
pub(super) const LOWER: usize = 0;
/// [`Node8::planes`]' upper corners.
pub(super) const UPPER: usize = 1;
/// Bytes of a node's visit orders: three for each of the eight sign patterns.
pub(super) const ORDERS: usize = 3 * 8;
// A leaf's slot count is kept in four bits.
const _: () = assert!(MAX_LEAF < 16);

/// One node: the boxes of up to eight children, lane by lane, in four cache lines.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
pub(super) struct Node8 {
    /// Lower corners (`[LOWER]`) and upper ones (`[UPPER]`): x, y and z of the eight
    /// children, four lanes to a group. One array, so that a ray's near and far planes are
    /// picked by index, without a branch ([`RayLanes::near`]).
    pub(super) planes: [[[Vec4; GROUPS]; 3]; 2],
    /// An interior child's node; a leaf's first slot.
    pub(super) child: [u32; WIDTH],
    /// A leaf's slot count, four bits a lane (lane k in bits 4k..4k+4); 0 for an interior
    /// child.
    pub(super) counts: u32,
    /// For each sign pattern of the ray's direction (bit k set: negative on axis k), the
    /// order to visit the lanes in: three bytes, three bits a lane, the first in the low
    /// bits.
    pub(super) order: [u8; ORDERS],
    /// Bit k set: lane k holds a child.
    pub(super) lanes: u8,
}

const _: () = assert!(std::mem::size_of::<Node8>() == 256);

impl Node8 {
    /// Lane `lane`'s slot count (0: an interior child).
    #[inline(always)]
    pub(super) fn count(&self, lane: usize) -> usize {
        (self.counts >> (4 * lane) & 0xF) as usize
    }

    /// The visit order of the lanes for direction signs `signs`, three bits a lane.
    #[inline(always)]
    pub(super) fn order(&self, signs: usize) -> u32 {
        let o = &self.order[3 * signs..3 * signs + 3];
        u32::from_le_bytes([o[0], o[1], o[2], 0])
    }
}

/// A ray prepared for box tests: origin and reciprocal direction splatted over the lanes.
pub(super) struct RayLanes {
    pub(super) origin: [Vec4; 3],
    pub(super) inv: [Vec4; 3],
    /// The direction's sign pattern.
    pub(super) signs: usize,
    /// For each axis, the corners the ray enters a box by ([`LOWER`] where the direction
    /// is positive, [`UPPER`] where negative): with a finite, nonzero reciprocal the
    /// slab distances keep the corners' order, so these are the min of the two distances
    /// and the others the max.
    pub(super) near: [usize; 3],
    /// Some component of the direction is zero: a slab test may meet 0 × ∞.
    pub(super) exact: bool,
}

impl RayLanes {
    pub(super) fn new(origin: Vec3, dir: Vec3) -> RayLanes {
        let inv = dir.recip();
        let signs = usize::from(inv.x < 0.0) | usize::from(inv.y < 0.0) << 1 | usize::from(inv.z < 0.0) << 2;
        RayLanes {
            origin: [Vec4::splat(origin.x), Vec4::splat(origin.y), Vec4::splat(origin.z)],
            inv: [Vec4::splat(inv.x), Vec4::splat(inv.y), Vec4::splat(inv.z)],
            signs,
            near: [signs & 1, signs >> 1 & 1, signs >> 2 & 1],
            exact: !inv.is_finite(),
        }
    }
}

impl Node8 {
    /// The lanes whose boxes the ray enters before `t_max` (bit k for lane k) and the
    /// entry distances: [`Aabb::hit`] four at a time, with the same decisions. Without
    /// `EXACT` the slab test cannot meet NaN (no direction component is zero and the boxes
    /// and origin are finite), and then lane-wise min and max differ from `f32::min`/`max`
    /// only in the sign of a zero, which comparisons cannot see.
    #[inline(always)]
    fn hit<const EXACT: bool>(&self, r: &RayLanes, t_max: f32) -> (u32, [f32; WIDTH]) {
        let mut mask = 0;
        let mut entries = [0.0; WIDTH];
        // A node with four children or fewer (near the leaves) tests one group.
        let groups = if self.lanes >> 4 == 0 { 1 } else { GROUPS };
        for g in 0..groups {
            let (mut near, mut far) = ([Vec4::ZERO; 3], [Vec4::ZERO; 3]);
            for a in 0..3 {
                let (n, f) = if EXACT {
                    let t0 = (self.planes[LOWER][a][g] - r.origin[a]) * r.inv[a];
                    let t1 = (self.planes[UPPER][a][g] - r.origin[a]) * r.inv[a];
                    let inside = t0.is_nan_mask() | t1.is_nan_mask();
                    (
                        Vec4::select(inside, Vec4::NEG_INFINITY, t0.min(t1)),
                        Vec4::select(inside, Vec4::INFINITY, t0.max(t1)),
                    )
                } else {
                    let side = r.near[a] & 1;
                    (
                        (self.planes[side][a][g] - r.origin[a]) * r.inv[a],
                        (self.planes[side ^ 1][a][g] - r.origin[a]) * r.inv[a],
                    )
                };
                (near[a], far[a]) = (n, f);
            }
            // [`reduce`]: the axes' distances folded as a tree.
            let (enter, exit) = reduce(near, far, Vec4::max, Vec4::min, Vec4::ZERO);
            // Entered before both the widened exit and `t_max`: two comparisons side by
            // side, where the minimum of the two and then one comparison were a step
            // longer. The same decisions, none of the three being NaN.
            let entered = enter.cmple(exit * slab_widening()) & enter.cmple(Vec4::splat(t_max));
            mask |= entered.bitmask() << (4 * g);
            entries[4 * g..4 * g + 4].copy_from_slice(&enter.to_array());
        }
        (mask & u32::from(self.lanes), entries)
    }
}

/// A box test's entry and exit distances from the three axes' near and far distances:
/// the entry the largest of 0 and the nears, the exit the smallest far, folded as a tree
/// (two steps deep) where each was a chain three deep, from 0 and from +∞. The box test is a step
/// of every walk's chain of dependent steps, node to node, and these were the longest part
/// of it after the loads (docs/speed.md, forty-first part). The same values: the distances
/// are never NaN (the origin is finite, and a slab the ray runs inside of is given ±∞
/// first), a maximum or minimum of them is exact in any order but for the sign of a zero,
/// which the comparisons that read them cannot see, and the minimum with +∞ the chain began
/// with was its other operand. Both box tests fold in this order, so their bits stay equal
/// (`wide_tests::avx_box_test_gives_the_sse_bits`).
#[inline(always)]
pub(super) fn reduce<V: Copy>(
    near: [V; 3],
    far: [V; 3],
    max: impl Fn(V, V) -> V,
    min: impl Fn(V, V) -> V,
    zero: V,
) -> (V, V) {
    (max(max(zero, near[0]), max(near[1], near[2])), min(far[0], min(far[1], far[2])))
}

/// A node's eight box tests: [`Node8::hit`]'s decisions and entry distances, bit for bit.
pub(super) trait BoxTest {
    fn hit<const EXACT: bool>(n: &Node8, r: &RayLanes, t_max: f32) -> (u32, [f32; WIDTH]);

    /// The lanes of `mask` in the visit order `order` (three bits a lane, as
    /// [`Node8::order`] gives it): bit k set if the lane at position k is in `mask`.
    #[inline(always)]
    fn visit(mask: u32, order: u32) -> u32 {
        (0..WIDTH as u32).fold(0, |v, k| v | (mask >> ((order >> (LANE_BITS * k)) & LANE) & 1) << k)
    }
}

/// Two groups of four lanes (SSE2 on x86-64; glam's scalar code elsewhere).
pub(super) struct Sse;

impl BoxTest for Sse {
    #[inline(always)]
    fn hit<const EXACT: bool>(n: &Node8, r: &RayLanes, t_max: f32) -> (u32, [f32; WIDTH]) {
        n.hit::<EXACT>(r, t_max)
    }
}

impl Node8 {
    /// Lane `lane`'s box.
    pub(super) fn lane_box(&self, lane: usize) -> Aabb {
        let (g, l) = (lane / 4, lane % 4);
        let corner =
            |c: usize| Vec3::new(self.planes[c][0][g][l], self.planes[c][1][g][l], self.planes[c][2][g][l]);
        let (min, max) = (corner(LOWER), corner(UPPER));
        Aabb { min, max }
    }
}
