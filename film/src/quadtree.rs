//! The progressive-refinement walk of the seed paper's appendix, in O(log N) memory.
//!
//! The appendix keeps quadrants in a FIFO queue: the root is computed at its lower-left
//! pixel; each quadrant taken from the queue is split in four, the upper-left,
//! lower-right and upper-right children get their lower-left pixel computed (in that
//! order), and the children that are more than one pixel go back to the queue in the order
//! upper-left, lower-right, upper-right, lower-left. That queue peaks at almost half the
//! pixel count (0.446·N at 1920×1080).
//!
//! A FIFO queue of a tree is a breadth-first walk: every quadrant of depth `d` leaves the
//! queue before any of depth `d + 1`, and the quadrants of one depth leave it in the
//! lexicographic order of their child paths. [`Walk`] therefore enumerates depth `d` by a
//! depth-first descent from the root that only stops at depth `d`, one depth after the
//! other; it holds one stack frame per level, so its memory is O(log N) while the order
//! is exactly the appendix's. Re-descending from the root for every depth costs a
//! geometric series, about a third more node visits than the queue.
//!
//! Coordinates are the paper's: origin at the lower-left corner, y grows upward.

/// A quadrant of the walk: `(x, y)` is its computed pixel (the lower-left one) and `w × h`
/// the block that pixel paints in pass one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Quad {
    /// Column of the lower-left pixel.
    pub x: u32,
    /// Row of the lower-left pixel, counted from the bottom.
    pub y: u32,
    /// Width in pixels, at least 1.
    pub w: u32,
    /// Height in pixels, at least 1.
    pub h: u32,
}

impl Quad {
    /// Pixel count of the block.
    pub fn area(&self) -> u64 {
        u64::from(self.w) * u64::from(self.h)
    }

    /// Whether the block contains pixel `(px, py)`.
    pub fn contains(&self, px: u32, py: u32) -> bool {
        px >= self.x && py >= self.y && px - self.x < self.w && py - self.y < self.h
    }

    /// The appendix's split: the four children in queue order (upper-left, lower-right,
    /// upper-right, lower-left), each with whether its pixel is computed when this quadrant
    /// leaves the queue and whether it goes back into the queue.
    fn split(&self) -> [Child; 4] {
        let (x, y, w, h) = (self.x, self.y, self.w, self.h);
        // The appendix's odd-size rules, verbatim: halves rounded down, the second halves
        // take the remainder, and a zero first half is raised to one.
        let mut w1 = w / 2;
        let mut h1 = h / 2;
        let xm = x + w1;
        let ym = y + h1;
        let w2 = w - w1;
        let h2 = h - h1;
        if w1 == 0 {
            w1 = 1;
        }
        if h1 == 0 {
            h1 = 1;
        }
        let ul = Quad { x, y: ym, w: w1, h: h2 };
        let lr = Quad { x: xm, y, w: w2, h: h1 };
        let ur = Quad { x: xm, y: ym, w: w2, h: h2 };
        let ll = Quad { x, y, w: w1, h: h1 };
        [
            Child { quad: ul, computed: h > 1, queued: h > 1 && (w1 > 1 || h2 > 1) },
            Child { quad: lr, computed: w > 1, queued: w > 1 && (w2 > 1 || h1 > 1) },
            Child { quad: ur, computed: w > 1 && h > 1, queued: w > 1 && h > 1 && (w2 > 1 || h2 > 1) },
            Child { quad: ll, computed: false, queued: w1 > 1 || h1 > 1 },
        ]
    }
}

#[derive(Debug, Clone, Copy)]
struct Child {
    quad: Quad,
    computed: bool,
    queued: bool,
}

/// One level of the depth-first descent: a queued quadrant's children, split once when
/// the frame is pushed (the descent reads them one at a time, and splitting the quadrant
/// again for each was half the walk's time: a 3840×2160 walk took 352 ms, now 178), and
/// the next one to visit.
#[derive(Debug, Clone, Copy)]
struct Frame {
    children: [Child; 4],
    next_child: u8,
}

impl Frame {
    fn new(quad: Quad) -> Frame {
        Frame { children: quad.split(), next_child: 0 }
    }
}

/// The pass-one visit order of a `width × height` image: every pixel exactly once, as the
/// quadrant whose lower-left pixel it is. Starts with `(0, 0, width, height)`.
#[derive(Debug, Clone)]
pub struct Walk {
    root: Quad,
    /// Depth of the queued quadrants whose computed children are being emitted.
    depth: u32,
    /// Whether the current descent reached any quadrant of `depth`; if not, the walk is over.
    found_at_depth: bool,
    stack: Vec<Frame>,
    /// Computed children of the quadrant just reached, still to be yielded (at most 3).
    pending: [Option<Quad>; 3],
    pending_next: usize,
    root_emitted: bool,
    done: bool,
}

impl Walk {
    /// The walk of a `width × height` image; an empty image yields nothing.
    pub fn new(width: u32, height: u32) -> Self {
        let root = Quad { x: 0, y: 0, w: width, h: height };
        let empty = width == 0 || height == 0;
        let mut stack = Vec::with_capacity(Self::max_stack(width, height));
        if !empty {
            // The appendix queues the root unconditionally, whatever its size.
            stack.push(Frame::new(root));
        }
        Walk {
            root,
            depth: 0,
            found_at_depth: false,
            stack,
            pending: [None; 3],
            pending_next: 3,
            root_emitted: empty,
            done: empty,
        }
    }

    /// An upper bound on the stack the walk ever holds for this size: one frame per level
    /// of the quadtree, whose depth is the number of halvings of the longer side.
    pub fn max_stack(width: u32, height: u32) -> usize {
        let longest = width.max(height).max(1);
        (u32::BITS - longest.leading_zeros()) as usize + 1
    }

    /// The stack the walk holds right now (for memory tests).
    pub fn stack_len(&self) -> usize {
        self.stack.len()
    }

    /// Descends to the next queued quadrant of the target depth and puts its computed
    /// children in `pending`. Returns false when the walk is over.
    fn advance(&mut self) -> bool {
        loop {
            let level = self.stack.len();
            let Some(top) = self.stack.last_mut() else {
                if !self.found_at_depth {
                    return false;
                }
                self.depth += 1;
                self.found_at_depth = false;
                self.stack.push(Frame::new(self.root));
                continue;
            };
            if level as u32 - 1 == self.depth {
                let children = top.children;
                self.stack.pop();
                self.found_at_depth = true;
                self.pending = [None; 3];
                let computed = children.into_iter().filter(|c| c.computed);
                for (slot, child) in self.pending.iter_mut().zip(computed) {
                    *slot = Some(child.quad);
                }
                self.pending_next = 0;
                if self.pending[0].is_some() {
                    return true;
                }
                continue;
            }
            if top.next_child >= 4 {
                self.stack.pop();
                continue;
            }
            let child = top.children[usize::from(top.next_child)];
            top.next_child += 1;
            if child.queued {
                self.stack.push(Frame::new(child.quad));
            }
        }
    }
}

impl Iterator for Walk {
    type Item = Quad;

    fn next(&mut self) -> Option<Quad> {
        if !self.root_emitted {
            self.root_emitted = true;
            return Some(self.root);
        }
        loop {
            if let Some(q) = self.pending.get(self.pending_next).copied().flatten() {
                self.pending_next += 1;
                return Some(q);
            }
            if self.done || !self.advance() {
                self.done = true;
                return None;
            }
        }
    }
}

/// The appendix transcribed literally, with its FIFO queue: the reference [`Walk`] is
/// tested against, and the measure of the queue the paper needed. Returns the visit order
/// and the queue's peak length.
pub fn fifo_walk(width: u32, height: u32) -> (Vec<Quad>, usize) {
    fifo_walk_in(width, height, ChildOrder::Paper)
}

/// The order in which a quadrant's children are visited.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChildOrder {
    /// The paper's: upper-left, lower-right, upper-right (the lower-left is known).
    Paper,
    /// The plain sequential order the paper rejects for its rising "lines": lower-left
    /// (known), lower-right, upper-left, upper-right. For measuring previews only.
    Sequential,
}

/// [`fifo_walk`] with the children of each quadrant in `order`.
pub fn fifo_walk_in(width: u32, height: u32, order_of_children: ChildOrder) -> (Vec<Quad>, usize) {
    use std::collections::VecDeque;
    let mut order = Vec::new();
    if width == 0 || height == 0 {
        return (order, 0);
    }
    let mut queue = VecDeque::new();
    let root = Quad { x: 0, y: 0, w: width, h: height };
    queue.push_back(root);
    order.push(root);
    let mut peak = queue.len();
    while let Some(q) = queue.pop_front() {
        let [ul, lr, ur, ll] = q.split();
        let children = match order_of_children {
            ChildOrder::Paper => [ul, lr, ur, ll],
            ChildOrder::Sequential => [ll, lr, ul, ur],
        };
        for child in children {
            if child.queued {
                queue.push_back(child.quad);
            }
            if child.computed {
                order.push(child.quad);
            }
        }
        peak = peak.max(queue.len());
    }
    (order, peak)
}

/// For pixel `(px, py)`, the computed pixel whose block covers it at the finest level at
/// which `is_computed` says a sample exists: the mosaic colour source of pass one. Walks
/// the quadtree from the root, O(log N). Returns `None` when not even the root is computed.
///
/// Because it depends only on which pixels have samples, never on the order results
/// arrived in, a coarse block can never paint over a finer one (DESIGN contract 3).
pub fn mosaic_source(
    width: u32,
    height: u32,
    px: u32,
    py: u32,
    mut is_computed: impl FnMut(u32, u32) -> bool,
) -> Option<(u32, u32)> {
    let mut best = None;
    descend(width, height, px, py, |quad| {
        if is_computed(quad.x, quad.y) {
            best = Some((quad.x, quad.y));
        }
        true
    });
    best
}

/// The pass-one block that pixel `(px, py)` paints: the largest quadrant whose computed
/// (lower-left) pixel it is, the walk's [`Quad`] for that pixel. O(log N). Viewers' previews
/// use it to know which pixels show a pixel as their mosaic.
pub fn block_of(width: u32, height: u32, px: u32, py: u32) -> Quad {
    // The lower-left child keeps its parent's computed pixel, so the first quadrant met
    // with `(px, py)` at its corner is the largest.
    let mut found = Quad { x: px, y: py, w: 1, h: 1 };
    descend(width, height, px, py, |quad| {
        if (quad.x, quad.y) == (px, py) {
            found = quad;
            return false;
        }
        true
    });
    found
}

/// Visits the quadrants that contain pixel `(px, py)`, from the root down to a single
/// pixel, while `visit` returns true.
///
/// The appendix's split halves each axis on its own (the first half `len / 2`, the second
/// the rest; an axis one pixel long is not split), and the child holding the pixel is the
/// one whose halves hold its coordinates, so a descent is two 1-D halvings side by side.
/// Previews call this for every pixel that gains its first sample (a 4K frame's pass one:
/// eight million times), which is why it does not build [`Quad::split`]'s four children
/// per level; `tests::descend_follows_the_split` holds it to them.
fn descend(width: u32, height: u32, px: u32, py: u32, mut visit: impl FnMut(Quad) -> bool) {
    fn half(start: u32, len: u32, c: u32) -> (u32, u32) {
        let first = len / 2;
        match len {
            0 | 1 => (start, len),
            _ if c >= start + first => (start + first, len - first),
            _ => (start, first),
        }
    }
    let mut quad = Quad { x: 0, y: 0, w: width, h: height };
    loop {
        if !visit(quad) || (quad.w <= 1 && quad.h <= 1) {
            return;
        }
        let (x, w) = half(quad.x, quad.w, px);
        let (y, h) = half(quad.y, quad.h, py);
        quad = Quad { x, y, w, h };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The descent as the split defines it: among the children in queue order, the first
    /// that is computed (or the lower-left one) and holds the pixel.
    fn descend_by_split(width: u32, height: u32, px: u32, py: u32) -> Vec<Quad> {
        let mut quad = Quad { x: 0, y: 0, w: width, h: height };
        let mut path = vec![quad];
        while quad.w > 1 || quad.h > 1 {
            let children = quad.split();
            let next = children
                .iter()
                .enumerate()
                .find(|(i, c)| (c.computed || *i == 3) && c.quad.contains(px, py))
                .map(|(_, c)| c.quad);
            match next {
                Some(q) if q != quad => quad = q,
                _ => break,
            }
            path.push(quad);
        }
        path
    }

    #[test]
    fn descend_follows_the_split() {
        for (w, h) in [(1, 1), (1, 9), (9, 1), (2, 3), (5, 3), (16, 16), (37, 21), (64, 7), (190, 108)] {
            for py in 0..h {
                for px in 0..w {
                    let mut path = Vec::new();
                    descend(w, h, px, py, |q| {
                        path.push(q);
                        true
                    });
                    assert_eq!(path, descend_by_split(w, h, px, py), "{w}x{h} at {px},{py}");
                }
            }
        }
    }

    #[test]
    fn block_of_is_the_walks_quadrant_of_each_pixel() {
        for (w, h) in [(1, 1), (1, 9), (9, 1), (5, 3), (16, 16), (37, 21), (64, 7), (190, 108)] {
            for q in Walk::new(w, h) {
                assert_eq!(block_of(w, h, q.x, q.y), q, "{w}x{h}");
            }
        }
    }

    fn check_exactly_once(width: u32, height: u32, order: &[Quad]) {
        let mut seen = vec![false; (width * height) as usize];
        for q in order {
            assert!(q.x < width && q.y < height, "{q:?} outside {width}x{height}");
            let i = (q.y * width + q.x) as usize;
            assert!(!seen[i], "pixel {},{} computed twice in {width}x{height}", q.x, q.y);
            seen[i] = true;
        }
        assert!(seen.iter().all(|s| *s), "a pixel of {width}x{height} was never computed");
    }

    /// The invariant the whole farm rests on: every pixel computed exactly once, in the
    /// appendix's order, for every size up to 64×64.
    #[test]
    fn walk_matches_appendix_up_to_64() {
        for width in 1..=64 {
            for height in 1..=64 {
                let (reference, _) = fifo_walk(width, height);
                check_exactly_once(width, height, &reference);
                let walk: Vec<Quad> = Walk::new(width, height).collect();
                assert_eq!(walk, reference, "walk differs from the appendix at {width}x{height}");
            }
        }
    }

    #[test]
    fn walk_matches_appendix_on_thin_and_large_images() {
        for (w, h) in [(1, 1000), (1000, 1), (1, 4097), (8193, 3), (1920, 1080), (4096, 2160)] {
            let (reference, _) = fifo_walk(w, h);
            check_exactly_once(w, h, &reference);
            let mut walk = Walk::new(w, h);
            let bound = Walk::max_stack(w, h);
            let mut n = 0;
            while let Some(q) = walk.next() {
                assert_eq!(q, reference[n], "walk differs at step {n} of {w}x{h}");
                assert!(walk.stack_len() <= bound, "stack {} > {bound}", walk.stack_len());
                n += 1;
            }
            assert_eq!(n, reference.len());
        }
    }

    #[test]
    fn walk_starts_with_root_and_follows_paper_order() {
        let order: Vec<Quad> = Walk::new(4, 4).take(4).collect();
        // Root, then upper-left, lower-right, upper-right children of the root.
        assert_eq!(order[0], Quad { x: 0, y: 0, w: 4, h: 4 });
        assert_eq!(order[1], Quad { x: 0, y: 2, w: 2, h: 2 });
        assert_eq!(order[2], Quad { x: 2, y: 0, w: 2, h: 2 });
        assert_eq!(order[3], Quad { x: 2, y: 2, w: 2, h: 2 });
    }

    #[test]
    fn memory_is_logarithmic() {
        // The appendix's queue grows with the image; the walk's stack with its log.
        let (_, peak) = fifo_walk(1920, 1080);
        assert!(peak as f64 > 0.4 * 1920.0 * 1080.0, "queue peak {peak}");
        assert!(Walk::max_stack(1920, 1080) <= 12);
        assert!(Walk::max_stack(u32::MAX, u32::MAX) <= 33);
    }

    #[test]
    fn empty_image_has_no_walk() {
        assert_eq!(Walk::new(0, 5).count(), 0);
        assert_eq!(Walk::new(5, 0).count(), 0);
    }

    /// Contract 3: the mosaic colour of a pixel comes from the finest computed block that
    /// covers it, whatever subset of pixels is done.
    #[test]
    fn mosaic_source_is_finest_covering_block() {
        for (w, h) in [(7, 5), (16, 16), (1, 9), (9, 1), (13, 31)] {
            let order: Vec<Quad> = Walk::new(w, h).collect();
            for done in [1, 2, 5, order.len() / 2, order.len()] {
                let computed: std::collections::HashSet<(u32, u32)> =
                    order[..done].iter().map(|q| (q.x, q.y)).collect();
                for py in 0..h {
                    for px in 0..w {
                        let got = mosaic_source(w, h, px, py, |x, y| computed.contains(&(x, y)));
                        // Brute force: the smallest computed block (in walk order) covering it.
                        let want = order[..done]
                            .iter()
                            .filter(|q| q.contains(px, py))
                            .min_by_key(|q| q.area())
                            .map(|q| (q.x, q.y));
                        assert_eq!(got, want, "{w}x{h} pixel {px},{py} after {done}");
                    }
                }
            }
        }
    }
}
