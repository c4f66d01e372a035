//! Previews: what viewers are shown of a framebuffer while its job renders, when exact
//! replicas would need more bytes than viewers may be sent.
//!
//! An exact replica needs a pixel's whole state (three fixed-point sums and a count, about
//! 17 bytes on the wire) every time the pixel changes. A farm of 256 workers changes some
//! 400 000 pixels a second, 6.5 MB/s per viewer; a hundred viewers would need 650 MB/s,
//! twenty times what the coordinator spends on viewers without slowing the workers. A
//! preview instead paints display values (linear RGB, 6 bytes as half floats) over
//! square blocks of `2^shift` pixels a side: each tick, every pixel that changed is
//! painted, in blocks as coarse as the byte budget requires (so a preview is never stale,
//! only blurred while the image changes fast), and what the budget leaves over refines
//! the pixels last painted coarsely, one pixel at a time, in scan order. When the job is
//! over, viewers receive the exact state, so their final image has the coordinator's bits.
//!
//! [`Publisher`] decides, per tick, what every viewer in step is sent (the same blocks for
//! all); [`Overlay`] is a viewer's side, painted over its replica's resolved image. A
//! joining viewer starts from the exact states of the pixels that have samples (few in
//! pass one, where most viewers join; its replica paints the mosaic itself), not from a
//! picture of every pixel.

use crate::framebuffer::{Framebuffer, TILE};
use crate::quadtree::{block_of, mosaic_source};

/// The coarsest block: 256 pixels a side (a 4K frame in 15 × 9 blocks).
pub const MAX_SHIFT: u8 = 8;
/// What one painted block is reckoned to cost on the wire: three half floats and its
/// share of a run. Only used to choose the block size, so an estimate is enough.
pub const BLOCK_BYTES: usize = 8;

/// The most blocks of several pixels a tick paints for what changed, whatever the budget:
/// each one's value reads a grid of pixels scattered over the framebuffer, so these blocks
/// are what a tick costs (`tessera bench farm`: 7 500 of them a tick, for 10 viewers of a
/// 4K job of 256 workers, cost a fifth of the commits). Changed pixels painted alone (one
/// read each) are bounded by the budget only, and so is the refinement of coarse ones.
pub const MAX_CHANGED_BLOCKS: usize = 2048;
/// `Publisher::shown` for a pixel that changed since it was last painted.
const DIRTY: u8 = u8::MAX;
/// A framebuffer tile's side is `2^TILE_SHIFT` pixels.
const TILE_SHIFT: u8 = TILE.trailing_zeros() as u8;
/// Pass-one blocks larger than this are marked changed as rectangles, not pixel by pixel.
const RECT_AREA: u64 = 16;

/// Blocks of one size painted with their display values.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Blocks {
    /// Blocks are `2^shift` pixels a side; those at the right and top edges are cut off
    /// by the image.
    pub shift: u8,
    /// Runs `(first, count)` of consecutive block indices `by · grid width + bx` (paper
    /// coordinates: row 0 at the bottom), in no particular order.
    pub runs: Vec<(u32, u32)>,
    /// Linear RGB of each block, in the order of the runs.
    pub rgb: Vec<[f32; 3]>,
}

impl Blocks {
    fn new(shift: u8) -> Self {
        Blocks { shift, ..Default::default() }
    }

    fn push(&mut self, block: u32, rgb: [f32; 3]) {
        match self.runs.last_mut() {
            Some((first, count)) if *first + *count == block => *count += 1,
            _ => self.runs.push((block, 1)),
        }
        self.rgb.push(rgb);
    }

    /// Blocks painted.
    pub fn len(&self) -> usize {
        self.rgb.len()
    }

    /// Whether nothing is painted.
    pub fn is_empty(&self) -> bool {
        self.rgb.is_empty()
    }
}

/// Columns and rows of blocks of `2^shift` pixels covering a `width × height` image.
pub fn grid(width: u32, height: u32, shift: u8) -> (u32, u32) {
    let side = 1u32 << shift;
    (width.div_ceil(side), height.div_ceil(side))
}

/// The pixel rectangle `(x0, y0, x1, y1)` (ends excluded) of block `index` at `shift`.
fn block_rect(width: u32, height: u32, shift: u8, index: u32) -> (u32, u32, u32, u32) {
    let (gw, _) = grid(width, height, shift);
    let (bx, by) = (index % gw, index / gw);
    let (x0, y0) = (bx << shift, by << shift);
    (x0, y0, (x0 + (1 << shift)).min(width), (y0 + (1 << shift)).min(height))
}

/// What pixel `(x, y)` shows: its mean, or before its first sample the mosaic (exactly
/// as `Framebuffer::resolve`).
fn display(fb: &Framebuffer, x: u32, y: u32) -> [f32; 3] {
    fb.mean(x, y)
        .or_else(|| {
            mosaic_source(fb.width(), fb.height(), x, y, |sx, sy| fb.count(sx, sy) > 0)
                .and_then(|(sx, sy)| fb.mean(sx, sy))
        })
        .unwrap_or([0.0; 3])
}

/// Pixels a side a block's value is read from: coarse blocks are painted while the whole
/// image changes, and reading every pixel of each would cost the coordinator a full
/// image per tick; a 3 × 3 grid of pixels is a fair preview of a block's colour (each
/// read is a few cache misses: a 4K tick's 2 000 blocks at 4 × 4 took 8 ms).
const SAMPLES_PER_SIDE: u32 = 3;

/// A block's display value: the mean of those of its pixels on a 3 × 3 grid (and its
/// lower-left, pass one's computed pixel) that have samples, or the mosaic of its
/// lower-left pixel when none has.
fn block_value(fb: &Framebuffer, (x0, y0, x1, y1): (u32, u32, u32, u32)) -> [f32; 3] {
    if x1 - x0 == 1 && y1 - y0 == 1 {
        return display(fb, x0, y0);
    }
    let (w, h) = (x1 - x0, y1 - y0);
    let (nx, ny) = (w.min(SAMPLES_PER_SIDE), h.min(SAMPLES_PER_SIDE));
    let grid = (0..ny).flat_map(|j| {
        (0..nx).map(move |i| (x0 + (2 * i + 1) * w / (2 * nx), y0 + (2 * j + 1) * h / (2 * ny)))
    });
    let mut sum = [0.0f64; 3];
    let mut n = 0u32;
    for (x, y) in std::iter::once((x0, y0)).chain(grid) {
        if let Some(m) = fb.mean(x, y) {
            for (s, v) in sum.iter_mut().zip(m) {
                *s += f64::from(v);
            }
            n += 1;
        }
    }
    if n == 0 {
        return display(fb, x0, y0);
    }
    sum.map(|s| (s / f64::from(n)) as f32)
}

/// The publisher's model of what every viewer in step with it shows, and the choice of
/// each tick's blocks.
#[derive(Debug)]
pub struct Publisher {
    width: u32,
    height: u32,
    /// Per pixel (paper index): 0 painted alone since it last changed; `1..=MAX_SHIFT`
    /// painted as part of a block of that shift; `DIRTY` changed since it was painted.
    shown: Vec<u8>,
    /// Pixels whose `shown` is a block shift: what refinement has left to do.
    coarse: usize,
    /// Where refinement goes on scanning.
    cursor: usize,
    /// The framebuffer version of the previous tick (none before the first).
    version: Option<u64>,
    /// Per pixel, one bit: it had samples at the previous tick. Kept here rather than the
    /// previous snapshot, because a snapshot held makes every merge copy the tiles it
    /// touches.
    sampled: Vec<u64>,
    /// The pixels marked `DIRTY` this tick.
    dirty: Vec<u32>,
    /// Tiles changed this tick, when it paints blocks of a tile or larger (then `dirty`
    /// stays empty), each once.
    tiles: Vec<u32>,
    /// Per tile, one bit: in `tiles` this tick.
    in_tiles: Vec<u64>,
    /// Per tile, one bit: every pixel of it had samples at the previous tick.
    full: Vec<u64>,
    /// Pass-one blocks `(x0, y0, x1, y1)` whose mosaic changed this tick, too large to
    /// mark pixel by pixel (in a tick that paints by tile, the tiles they meet go into
    /// `tiles` instead): painted whole (their sampled pixels too, which costs nothing
    /// at the coarse shifts a large changed area gets anyway).
    rects: Vec<(u32, u32, u32, u32)>,
    /// Scratch bitmap of the blocks a tick paints.
    seen: Vec<u64>,
}

impl Publisher {
    /// A publisher for a `width × height` framebuffer; its first tick only takes the
    /// baseline (viewers that join start from a snapshot of their own).
    pub fn new(width: u32, height: u32) -> Self {
        Publisher {
            width,
            height,
            shown: vec![0; width as usize * height as usize],
            coarse: 0,
            cursor: 0,
            version: None,
            sampled: vec![0; (width as usize * height as usize).div_ceil(64)],
            dirty: Vec::new(),
            rects: Vec::new(),
            tiles: Vec::new(),
            in_tiles: vec![0; (width.div_ceil(TILE) as usize * height.div_ceil(TILE) as usize).div_ceil(64)],
            full: vec![0; (width.div_ceil(TILE) as usize * height.div_ceil(TILE) as usize).div_ceil(64)],
            seen: Vec::new(),
        }
    }

    /// The framebuffer version the last tick brought viewers to (none before the first).
    pub fn version(&self) -> Option<u64> {
        self.version
    }

    /// Pixels painted only as part of a block, waiting to be refined.
    pub fn coarse(&self) -> usize {
        self.coarse
    }

    fn set_shown(&mut self, i: usize, to: u8) {
        let was = self.shown[i];
        self.coarse -= usize::from((1..=MAX_SHIFT).contains(&was));
        self.coarse += usize::from((1..=MAX_SHIFT).contains(&to));
        self.shown[i] = to;
    }

    /// `set_shown` for a rectangle, a row at a time.
    fn set_rect(&mut self, (x0, y0, x1, y1): (u32, u32, u32, u32), to: u8) {
        let coarse = |v: &u8| (1..=MAX_SHIFT).contains(v);
        for y in y0..y1 {
            let row = (y * self.width) as usize;
            let span = &mut self.shown[row + x0 as usize..row + x1 as usize];
            // Written as a sum of comparisons, which the compiler vectorises: a busy farm's
            // tick repaints most of a 4K frame, and a filtered count took a nanosecond a
            // pixel.
            let was: usize = span.iter().map(|&v| usize::from(v.wrapping_sub(1) < MAX_SHIFT)).sum();
            self.coarse -= was;
            span.fill(to);
            if coarse(&to) {
                self.coarse += span.len();
            }
        }
    }

    fn mark(&mut self, i: usize) {
        if self.shown[i] != DIRTY {
            self.set_shown(i, DIRTY);
            self.dirty.push(i as u32);
        }
    }

    /// Marks what changed since version `since` in `fb`: the pixels merged since, and
    /// where a pixel gained its first sample (or lost its samples to a repair), the pixels
    /// of its pass-one block that show it as their mosaic. With `by_tile` (the tick can
    /// only paint blocks of a tile or larger), changed tiles are marked whole instead of
    /// their pixels, and a tile that had every sample and still has is not read at all:
    /// pass two's ticks then cost a scan of the tile versions, not a read per pixel (at 4K,
    /// 30 000 scattered pixels a tick were a microsecond each in cache misses).
    fn mark_changes(&mut self, since: u64, fb: &Framebuffer, by_tile: bool) {
        let (tiles, _) = fb.tiles();
        for t in 0..tiles {
            if !fb.tile_changed(t, since) {
                continue;
            }
            let (word, bit) = (t / 64, 1u64 << (t % 64));
            let (was, full) = (self.full[word] & bit != 0, fb.tile_full(t));
            self.full[word] = if full { self.full[word] | bit } else { self.full[word] & !bit };
            if by_tile {
                self.mark_tile(t);
                if was && full {
                    continue;
                }
            }
            fb.tile_changes(t, since, |index, count| self.changed(fb, index, count, by_tile));
        }
    }

    /// Marks tile `t` to be painted whole this tick.
    fn mark_tile(&mut self, t: usize) {
        let (word, bit) = (t / 64, 1u64 << (t % 64));
        if self.in_tiles[word] & bit == 0 {
            self.in_tiles[word] |= bit;
            self.tiles.push(t as u32);
        }
    }

    /// Pixel `index` changed and has `count` samples now.
    fn changed(&mut self, fb: &Framebuffer, index: u32, count: u32, by_tile: bool) {
        let (w, h) = (self.width, self.height);
        if !by_tile {
            self.mark(index as usize);
        }
        let (word, bit) = (index as usize / 64, 1u64 << (index % 64));
        let had = self.sampled[word] & bit != 0;
        if count > 0 {
            self.sampled[word] |= bit;
        } else {
            self.sampled[word] &= !bit;
        }
        if had == (count > 0) {
            return;
        }
        let q = block_of(w, h, index % w, index / w);
        if by_tile {
            // Painted by tile: the tiles the block meets are what it adds (at a tile's shift
            // or more a block holds whole tiles), each once, so that a tick's marks are
            // bounded by the tiles however many pixels gained their first sample (a
            // rectangle a pixel was 16 bytes each, hundreds of MB for a 4K pass one).
            let tiles_x = w.div_ceil(TILE);
            for ty in q.y / TILE..=(q.y + q.h - 1) / TILE {
                for tx in q.x / TILE..=(q.x + q.w - 1) / TILE {
                    self.mark_tile((ty * tiles_x + tx) as usize);
                }
            }
            return;
        }
        if q.area() > RECT_AREA {
            // Pass one repaints every pixel once per level of the walk (a 4K frame: 11
            // times), which pixel by pixel was most of a tick.
            self.rects.push((q.x, q.y, q.x + q.w, q.y + q.h));
            return;
        }
        for qy in q.y..q.y + q.h {
            for qx in q.x..q.x + q.w {
                if fb.count(qx, qy) == 0 {
                    self.mark((qy * w + qx) as usize);
                }
            }
        }
    }

    /// Blocks of `2^shift` pixels that hold a dirty pixel or meet a dirty rectangle,
    /// marked in `self.seen`; stops early, with a count over `most`, once there are more.
    fn count_blocks(&mut self, shift: u8, most: usize) -> usize {
        let (gw, gh) = grid(self.width, self.height, shift);
        let words = (gw as usize * gh as usize).div_ceil(64);
        self.seen.clear();
        self.seen.resize(words, 0);
        // Marks block `b` seen; 1 if it was not yet.
        fn see(seen: &mut [u64], b: u32) -> usize {
            let (word, bit) = (b as usize / 64, 1u64 << (b % 64));
            let new = seen[word] & bit == 0;
            seen[word] |= bit;
            usize::from(new)
        }
        let mut n = 0;
        for &i in &self.dirty {
            let (x, y) = (i % self.width, i / self.width);
            n += see(&mut self.seen, (y >> shift) * gw + (x >> shift));
        }
        if !self.tiles.is_empty() {
            // Only asked at shifts of a tile or more (`tick`), so a tile lies in one block.
            let tiles_x = self.width.div_ceil(TILE);
            let up = shift - TILE_SHIFT;
            for &t in &self.tiles {
                n += see(&mut self.seen, ((t / tiles_x) >> up) * gw + ((t % tiles_x) >> up));
            }
        }
        for &(x0, y0, x1, y1) in &self.rects {
            for by in y0 >> shift..=(y1 - 1) >> shift {
                for bx in x0 >> shift..=(x1 - 1) >> shift {
                    n += see(&mut self.seen, by * gw + bx);
                }
            }
            if n > most {
                return n;
            }
        }
        n
    }

    /// One tick: what changed from the previous snapshot to `fb`, painted in blocks as
    /// fine as `budget` bytes and `MAX_CHANGED_BLOCKS` allow (each changed pixel is
    /// painted every tick, coarsely if need be), then with what is left, pixels painted
    /// coarsely before, refined one by one. Empty when nothing is to be painted.
    pub fn tick(&mut self, fb: &Framebuffer, budget: usize) -> Vec<Blocks> {
        assert_eq!((fb.width(), fb.height()), (self.width, self.height), "one publisher per image size");
        let Some(since) = self.version.replace(fb.version()) else {
            for t in (0..fb.tiles().0).filter(|&t| fb.tile_changed(t, 0)) {
                let sampled = &mut self.sampled;
                fb.tile_changes(t, 0, |index, count| {
                    if count > 0 {
                        sampled[index as usize / 64] |= 1u64 << (index % 64);
                    }
                });
                if fb.tile_full(t) {
                    self.full[t / 64] |= 1u64 << (t % 64);
                }
            }
            return Vec::new();
        };
        self.dirty.clear();
        self.rects.clear();
        for &t in &self.tiles {
            self.in_tiles[t as usize / 64] = 0;
        }
        self.tiles.clear();
        // Single pixels are read once each, so only blocks of several are capped. Each
        // changed tile holds a changed pixel, so a block finer than a tile per changed tile
        // at least: with more of those than the budget's blocks, only tiles matter.
        let alone = budget / BLOCK_BYTES;
        let fits = |shift: u8| if shift == 0 { alone } else { alone.min(MAX_CHANGED_BLOCKS) };
        let by_tile = (0..fb.tiles().0).filter(|&t| fb.tile_changed(t, since)).count() > alone;
        self.mark_changes(since, fb, by_tile);
        let mut out = Vec::new();
        let mut spent = 0;
        if !self.dirty.is_empty() || !self.rects.is_empty() || !self.tiles.is_empty() {
            // A block holds at most 4^shift dirty pixels, so no shift below `first` can fit:
            // the bitmaps of the finest shifts (the largest) are never filled for nothing.
            // Rectangles may overlap each other and the pixels, so the largest one is what
            // they surely add.
            let area = |r: &(u32, u32, u32, u32)| (r.2 - r.0) as usize * (r.3 - r.1) as usize;
            let least = self.dirty.len().max(self.rects.iter().map(area).max().unwrap_or(0));
            let first =
                (0..=MAX_SHIFT).find(|&s| least.div_ceil(1 << (2 * s)) <= fits(s)).unwrap_or(MAX_SHIFT);
            let first = if by_tile { first.max(TILE_SHIFT) } else { first };
            let shift = (first..=MAX_SHIFT)
                .find(|&s| self.count_blocks(s, fits(s)) <= fits(s))
                .unwrap_or_else(|| {
                    self.count_blocks(MAX_SHIFT, usize::MAX);
                    MAX_SHIFT
                });
            let news = self.paint(fb, shift);
            spent = news.len() * BLOCK_BYTES;
            out.push(news);
        }
        if self.coarse > 0 && spent + BLOCK_BYTES <= budget {
            let fine = self.refine(fb, (budget - spent) / BLOCK_BYTES);
            if !fine.is_empty() {
                out.push(fine);
            }
        }
        out
    }

    /// Paints the blocks counted in `self.seen` (the last `count_blocks`, at `shift`).
    fn paint(&mut self, fb: &Framebuffer, shift: u8) -> Blocks {
        let mut b = Blocks::new(shift);
        let (gw, gh) = grid(self.width, self.height, shift);
        let all =
            (gw as usize * gh as usize) == self.seen.iter().map(|w| w.count_ones() as usize).sum::<usize>();
        if all {
            // Every block (a fast farm's pass two at a tight budget): one fill for the whole
            // image rather than one per block's row.
            self.shown.fill(shift);
            self.coarse = if shift > 0 { self.shown.len() } else { 0 };
        }
        let seen = std::mem::take(&mut self.seen);
        // A run of blocks side by side in a row of blocks, marked shown as one rectangle:
        // its pixel rows are then one span each, not one per block (at 4K, a block's 64
        // rows were 64 cache misses).
        let mut run: Option<(u32, u32, u32, u32)> = None;
        for (word, &bits) in seen.iter().enumerate() {
            let mut bits = bits;
            while bits != 0 {
                let index = (word * 64 + bits.trailing_zeros() as usize) as u32;
                bits &= bits - 1;
                let rect = block_rect(self.width, self.height, shift, index);
                b.push(index, block_value(fb, rect));
                if all {
                    continue;
                }
                run = match run {
                    Some(r) if r.2 == rect.0 && r.1 == rect.1 => Some((r.0, r.1, rect.2, r.3)),
                    Some(r) => {
                        self.set_rect(r, shift);
                        Some(rect)
                    }
                    None => Some(rect),
                };
            }
        }
        if let Some(r) = run {
            self.set_rect(r, shift);
        }
        self.seen = seen;
        b
    }

    /// Paints up to `most` coarsely painted pixels alone, scanning on from the cursor.
    fn refine(&mut self, fb: &Framebuffer, most: usize) -> Blocks {
        let mut b = Blocks::new(0);
        let n = self.shown.len();
        let mut scanned = 0;
        while b.len() < most && self.coarse > 0 && scanned < n {
            let i = self.cursor;
            // Between ticks `shown` holds no `DIRTY`, so a non-zero byte is a coarse pixel;
            // 64 exact ones are skipped at once (a few coarse pixels left in a 4K frame made
            // this scan the whole image every tick).
            if i.is_multiple_of(64) && i + 64 <= n && self.shown[i..i + 64].iter().fold(0, |a, &v| a | v) == 0
            {
                self.cursor = (i + 64) % n;
                scanned += 64;
                continue;
            }
            if (1..=MAX_SHIFT).contains(&self.shown[i]) {
                b.push(i as u32, display(fb, i as u32 % self.width, i as u32 / self.width));
                self.set_shown(i, 0);
            }
            self.cursor = (i + 1) % n;
            scanned += 1;
        }
        b
    }
}

/// A viewer's preview: display values painted over its replica's image until exact
/// states replace them.
#[derive(Debug, Clone, PartialEq)]
pub struct Overlay {
    width: u32,
    height: u32,
    /// Per pixel (paper index), the painted value, if any.
    rgb: Vec<Option<[f32; 3]>>,
}

impl Overlay {
    /// An empty overlay of a `width × height` image.
    pub fn new(width: u32, height: u32) -> Self {
        Overlay { width, height, rgb: vec![None; width as usize * height as usize] }
    }

    /// Paints blocks (checked against this size when they were decoded).
    pub fn paint(&mut self, b: &Blocks) {
        let mut values = b.rgb.iter();
        for &(first, count) in &b.runs {
            for index in first..first + count {
                let Some(&rgb) = values.next() else { return };
                let (x0, y0, x1, y1) = block_rect(self.width, self.height, b.shift, index);
                for y in y0..y1 {
                    let row = (y * self.width) as usize;
                    self.rgb[row + x0 as usize..row + x1 as usize].fill(Some(rgb));
                }
            }
        }
    }

    /// Pixel `index` (paper index) now has its exact state: the replica shows it.
    pub fn clear(&mut self, index: u32) {
        if let Some(p) = self.rgb.get_mut(index as usize) {
            *p = None;
        }
    }

    /// Paints the overlay over `image` (linear RGB, top row first, as `resolve` makes it).
    pub fn over(&self, image: &mut [f32]) {
        let w = self.width as usize;
        for (i, p) in self.rgb.iter().enumerate() {
            if let Some(rgb) = p {
                let (x, y) = (i % w, i / w);
                let at = ((self.height as usize - 1 - y) * w + x) * 3;
                if let Some(dst) = image.get_mut(at..at + 3) {
                    dst.copy_from_slice(rgb);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
