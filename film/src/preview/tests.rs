use super::*;
use crate::fixed;
use crate::quadtree::{Quad, Walk};

/// A small deterministic generator, so that failures replay.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        self.0 >> 33
    }
}

fn merge(fb: &mut Framebuffer, pixels: &[(u32, u32)], samples: u32, rng: &mut Lcg) {
    let quads: Vec<Quad> = pixels.iter().map(|&(x, y)| Quad { x, y, w: 1, h: 1 }).collect();
    let max = fixed::max_sum(samples);
    let sums: Vec<u64> = (0..quads.len() * 3).map(|_| rng.next() % max).collect();
    fb.merge(&quads, samples, &sums, None).unwrap();
}

/// What a viewer shows: the image of the replica it joined with, the overlay over it.
fn shown(overlay: &Overlay, joined: &Framebuffer) -> Vec<f32> {
    let mut img = joined.resolve();
    overlay.over(&mut img);
    img
}

fn paint(overlay: &mut Overlay, blocks: &[Blocks]) {
    for b in blocks {
        overlay.paint(b);
    }
}

/// An empty image of `w` × `h` with its publisher past the baseline tick, the replica a
/// viewer joined with then, that viewer's overlay, and the pass-one walk of the image.
struct Joined {
    fb: Framebuffer,
    p: Publisher,
    joined: Framebuffer,
    o: Overlay,
    walk: Vec<(u32, u32)>,
}

fn join_empty(w: u32, h: u32) -> Joined {
    let fb = Framebuffer::new(w, h);
    let mut p = Publisher::new(w, h);
    p.tick(&fb, 0);
    let walk = Walk::new(w, h).map(|q| (q.x, q.y)).collect();
    Joined { joined: fb.clone(), fb, p, o: Overlay::new(w, h), walk }
}

/// With bytes to spare, every tick paints each changed pixel alone, so a viewer in step
/// shows exactly the resolved image: through pass one (where a pixel's first sample
/// repaints its block's mosaic), pass two, and a repair that empties pixels again.
#[test]
fn with_enough_bytes_a_viewer_in_step_shows_the_exact_image() {
    let (w, h) = (37, 21);
    let mut fb = Framebuffer::new(w, h);
    let mut rng = Lcg(2);
    let mut p = Publisher::new(w, h);
    assert!(p.tick(&fb, usize::MAX).is_empty(), "the first tick is the baseline");
    let joined = fb.clone();
    let mut o = Overlay::new(w, h);
    let walk: Vec<(u32, u32)> = Walk::new(w, h).map(|q| (q.x, q.y)).collect();
    for part in walk.chunks(53) {
        merge(&mut fb, part, 1, &mut rng);
        let blocks = p.tick(&fb, usize::MAX);
        assert!(blocks.iter().all(|b| b.shift == 0));
        paint(&mut o, &blocks);
        assert_eq!(shown(&o, &joined), fb.resolve());
    }
    for part in walk.chunks(97) {
        merge(&mut fb, part, 16, &mut rng);
        paint(&mut o, &p.tick(&fb, usize::MAX));
        assert_eq!(shown(&o, &joined), fb.resolve());
    }
    fb.reset(0, 0);
    fb.reset(20, 10);
    paint(&mut o, &p.tick(&fb, usize::MAX));
    assert_eq!(shown(&o, &joined), fb.resolve());
    assert_eq!(p.coarse(), 0);
}

/// With few bytes, a tick paints every change in blocks coarse enough to fit, and ticks
/// with nothing new refine those blocks pixel by pixel until the image is exact again.
#[test]
fn a_tight_budget_paints_coarsely_then_refines_to_the_exact_image() {
    let (w, h) = (64, 48);
    let Joined { mut fb, mut p, joined, mut o, walk: all } = join_empty(w, h);
    let mut rng = Lcg(3);
    merge(&mut fb, &all, 4, &mut rng);
    let budget = 40 * BLOCK_BYTES;
    let blocks = p.tick(&fb, budget);
    let news = &blocks[0];
    assert!(news.shift > 0, "3072 changed pixels cannot be painted one by one in 40 blocks");
    assert!(news.len() * BLOCK_BYTES <= budget, "{} blocks", news.len());
    // Coarse enough to fit, and no coarser.
    let (gw, gh) = grid(w, h, news.shift - 1);
    assert!((gw * gh) as usize * BLOCK_BYTES > budget);
    paint(&mut o, &blocks);
    let mut bare = vec![f32::NAN; w as usize * h as usize * 3];
    o.over(&mut bare);
    assert!(bare.iter().all(|v| v.is_finite()), "every changed pixel is painted");
    assert_ne!(shown(&o, &joined), fb.resolve());
    let mut ticks = 0;
    while p.coarse() > 0 {
        let fine = p.tick(&fb, budget);
        assert!(fine.iter().all(|b| b.shift == 0 && b.len() <= 40));
        paint(&mut o, &fine);
        ticks += 1;
        assert!(ticks < 100, "refinement stalls");
    }
    assert_eq!(ticks, (w * h).div_ceil(40) as usize);
    assert_eq!(shown(&o, &joined), fb.resolve());
    assert!(p.tick(&fb, budget).is_empty(), "nothing left to send");
}

/// A farm's pass two changes a pixel or two in every tile: with more changed tiles than
/// the budget has blocks, a tick paints whole tiles (no pixel is read to mark them), in
/// blocks of a tile or more, and a repair that empties pixels of a full tile still
/// repaints their mosaic; ticks with nothing new then refine to the exact image.
#[test]
fn changes_in_more_tiles_than_blocks_are_painted_by_tile_then_refined() {
    let (w, h) = (160, 96); // 10 × 6 tiles
    let Joined { mut fb, mut p, joined, mut o, walk } = join_empty(w, h);
    let mut rng = Lcg(4);
    merge(&mut fb, &walk, 1, &mut rng);
    paint(&mut o, &p.tick(&fb, usize::MAX));
    assert_eq!(shown(&o, &joined), fb.resolve(), "pass one, painted exactly");
    let budget = 12 * BLOCK_BYTES;
    let scattered: Vec<(u32, u32)> =
        (0..6).flat_map(|ty| (0..10).map(move |tx| (tx * 16 + 5, ty * 16 + 9))).collect();
    for round in 0..3 {
        merge(&mut fb, &scattered, 4, &mut rng);
        if round == 2 {
            // A repair in a full tile: the pixel shows its block's mosaic again.
            fb.reset(37, 21);
        }
        let blocks = p.tick(&fb, budget);
        assert_eq!(blocks[0].shift, 6, "60 changed tiles in 12 blocks: 64-pixel blocks (3 × 2)");
        assert!(blocks[0].len() * BLOCK_BYTES <= budget);
        paint(&mut o, &blocks);
        assert_ne!(shown(&o, &joined), fb.resolve());
    }
    let mut ticks = 0;
    while p.coarse() > 0 {
        paint(&mut o, &p.tick(&fb, budget));
        ticks += 1;
        assert!(ticks < 2000, "refinement stalls");
    }
    assert_eq!(shown(&o, &joined), fb.resolve());
}

/// Pass one painted by tile (a tight budget, more changed tiles than blocks), on an image
/// whose pass-one blocks straddle tile edges: a pixel's first sample repaints its block's
/// mosaic in every tile the block meets, so that refinement, once nothing changes, ends at
/// the exact image; and a tick's marks are bounded by the tiles however many pixels
/// changed.
#[test]
fn pass_one_painted_by_tile_repaints_every_tile_its_blocks_meet() {
    let (w, h) = (150, 90); // 10 × 6 tiles, the last ones partial
    let Joined { mut fb, mut p, joined, mut o, walk } = join_empty(w, h);
    let mut rng = Lcg(9);
    let budget = 12 * BLOCK_BYTES;
    // Parts of the walk small enough that some ticks change only some tiles.
    let mut by_tile = 0;
    for part in walk.chunks(walk.len() / 150 + 1) {
        merge(&mut fb, part, 1, &mut rng);
        let blocks = p.tick(&fb, budget);
        if !p.tiles.is_empty() {
            by_tile += 1;
            assert!(blocks[0].shift >= TILE_SHIFT, "painted by tile");
            assert!(
                p.tiles.len() <= 60 && p.rects.is_empty(),
                "{} tiles, {} rects",
                p.tiles.len(),
                p.rects.len()
            );
        }
        paint(&mut o, &blocks);
        // Refined to the exact image before the next part: a pixel that part's mosaic
        // changes without marking it would stay as it was.
        let mut ticks = 0;
        while p.coarse() > 0 {
            paint(&mut o, &p.tick(&fb, budget));
            ticks += 1;
            assert!(ticks < 2000, "refinement stalls");
        }
        assert_eq!(shown(&o, &joined), fb.resolve(), "pass one up to {:?}", part.last());
    }
    assert!(by_tile >= 5, "{by_tile} ticks painted by tile");
}
