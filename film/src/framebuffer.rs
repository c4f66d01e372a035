//! A job's framebuffer: per-pixel fixed-point sums and sample counts (store sums, not
//! averages), resolved into an image on demand, with the pass-one mosaic for pixels that
//! have no sample yet.

use std::sync::Arc;

use crate::fixed;

use crate::quadtree::{mosaic_source, Quad};

/// Why a batch's sums could not be merged.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MergeError {
    /// The result does not have three sums per pixel.
    #[error("expected {expected} sums (3 per pixel), got {got}")]
    WrongLength {
        /// 3 × pixels.
        expected: usize,
        /// What came.
        got: usize,
    },
    /// The result does not have one even-sample sum per pixel.
    #[error("expected {expected} even-sample sums (1 per pixel), got {got}")]
    EvenLength {
        /// Pixels.
        expected: usize,
        /// What came.
        got: usize,
    },
    /// A sum is larger than its samples can produce.
    #[error("sum {value} of pixel {x},{y} exceeds the largest possible for {samples} samples")]
    OutOfRange {
        /// Column.
        x: u32,
        /// Row from the bottom.
        y: u32,
        /// The sum.
        value: u64,
        /// Samples it claims to hold.
        samples: u32,
    },
}

/// The side of a tile, in pixels: the unit of copy-on-write and of the dirty set. 16×16
/// pixels are about 10 KB, so a merge that touches a tile still held by a snapshot copies
/// a few microseconds' worth (pass two's batches are runs of the walk, local in the image,
/// and touch a handful of tiles), while a 4K frame has 32 400 tiles, so a snapshot clones
/// that many pointers (about 0.1 ms) instead of copying 300 MB.
pub const TILE: u32 = 16;

/// One tile's accumulators, pixel index `ly · tile width + lx` within the tile.
#[derive(Debug, Clone, PartialEq)]
struct Tile {
    sums: Vec<[u64; 3]>,
    counts: Vec<u32>,
    /// Per pixel, the sum of the luminance of its even-numbered samples, for jobs with a
    /// noise target: with the full sums it gives two independent half estimates, whose
    /// difference estimates the error of the mean. Empty otherwise.
    even: Vec<u64>,
    /// Per pixel, the version of the merge that last changed it (for viewers' deltas).
    versions: Vec<u64>,
    /// The newest of `versions` in each row of the tile: a pass-two farm's changes are
    /// scattered (one pixel in a tile, hundreds of tiles a batch), so that a tick's
    /// [`Changes`] reads a row of 16 versions per changed pixel rather than a tile's 256.
    rows: [u64; TILE as usize],
}

impl Tile {
    fn new(pixels: usize, even: bool) -> Self {
        Tile {
            sums: vec![[0; 3]; pixels],
            counts: vec![0; pixels],
            even: if even { vec![0; pixels] } else { Vec::new() },
            versions: vec![0; pixels],
            rows: [0; TILE as usize],
        }
    }
}

/// Accumulated samples of a `width × height` image, in the paper's coordinates.
///
/// Stored in tiles behind `Arc`s, so that `clone` is a snapshot that costs a pointer per
/// tile, not a copy of the image: the coordinator clones under its lock and resolves,
/// encodes deltas or writes checkpoints from the clone outside it, while merges go on
/// (copying only the tiles they touch that a snapshot still holds).
#[derive(Debug, Clone)]
pub struct Framebuffer {
    width: u32,
    height: u32,
    tiles_x: u32,
    has_even: bool,
    tiles: Vec<Arc<Tile>>,
    /// Per tile, the newest of its pixels' versions: a tile not changed since a version is
    /// skipped whole. Kept here, side by side, rather than in the tiles, because a scan of
    /// a 4K frame's 32 400 tiles that dereferenced each one was most of a preview's tick.
    tile_versions: Vec<u64>,
    /// Per tile, its pixels that have samples: a preview's tick skips the pixels of a tile
    /// that had all its samples before and has them still (pass two's every tile).
    tile_sampled: Vec<u32>,
    /// Merges so far.
    version: u64,
}

impl PartialEq for Framebuffer {
    fn eq(&self, other: &Self) -> bool {
        (self.width, self.height, self.has_even) == (other.width, other.height, other.has_even)
            && self
                .tiles
                .iter()
                .zip(&other.tiles)
                .all(|(a, b)| (&a.sums, &a.counts, &a.even) == (&b.sums, &b.counts, &b.even))
    }
}

/// The state of one pixel as it travels to viewers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelState {
    /// Pixel index, y · width + x.
    pub index: u32,
    /// Fixed-point sums.
    pub sums: [u64; 3],
    /// Samples.
    pub count: u32,
}

impl Framebuffer {
    /// An empty framebuffer.
    pub fn new(width: u32, height: u32) -> Self {
        Self::empty(width, height, false)
    }

    /// An empty framebuffer that also keeps even-sample luminance sums (noise targets).
    pub fn with_even(width: u32, height: u32) -> Self {
        Self::empty(width, height, true)
    }

    fn empty(width: u32, height: u32, has_even: bool) -> Self {
        let (tiles_x, tiles_y) = (width.div_ceil(TILE), height.div_ceil(TILE));
        let mut tiles = Vec::with_capacity(tiles_x as usize * tiles_y as usize);
        for ty in 0..tiles_y {
            for tx in 0..tiles_x {
                let (w, h) = tile_extent(width, height, tx, ty);
                tiles.push(Arc::new(Tile::new(w as usize * h as usize, has_even)));
            }
        }
        let (tile_versions, tile_sampled) = (vec![0; tiles.len()], vec![0; tiles.len()]);
        Framebuffer { width, height, tiles_x, has_even, tiles, tile_versions, tile_sampled, version: 0 }
    }

    /// Whether it keeps even-sample sums.
    pub fn has_even(&self) -> bool {
        self.has_even
    }

    /// The bytes a `width × height` framebuffer holds (with `even` sums or not): its real
    /// per-pixel accumulators and each tile's own overhead. What the coordinator admits a
    /// job by, before allocating it.
    pub fn bytes_for(width: u32, height: u32, even: bool) -> u64 {
        use std::mem::size_of;
        let per_pixel = size_of::<[u64; 3]>() + size_of::<u32>() + size_of::<u64>() // sums, count, version
            + if even { size_of::<u64>() } else { 0 };
        let tiles = u64::from(width.div_ceil(TILE)) * u64::from(height.div_ceil(TILE));
        // The tile behind its Arc (four Vec headers, its rows' versions, two counts), its
        // pointer, its version and its count of sampled pixels.
        let per_tile = size_of::<Tile>()
            + 2 * size_of::<usize>()
            + size_of::<Arc<Tile>>()
            + size_of::<u64>()
            + size_of::<u32>();
        u64::from(width) * u64::from(height) * per_pixel as u64 + tiles * per_tile as u64
    }

    /// Tile index and index within the tile of pixel `(x, y)`.
    #[inline]
    fn locate(&self, x: u32, y: u32) -> (usize, usize) {
        let (tx, ty) = (x / TILE, y / TILE);
        let tw = (self.width - tx * TILE).min(TILE);
        ((ty * self.tiles_x + tx) as usize, ((y % TILE) * tw + x % TILE) as usize)
    }

    /// The samples of pixel `(x, y)`.
    #[inline]
    pub fn count(&self, x: u32, y: u32) -> u32 {
        let (t, i) = self.locate(x, y);
        self.tiles[t].counts[i]
    }

    /// The estimated standard error of pixel `(x, y)`'s mean luminance (the mean of its
    /// channels): half the difference of the means of its even and odd samples (each half
    /// an independent estimate, so that their difference has twice the mean's standard
    /// deviation). With `Some(floor)` relative to the mean, which is floored at `floor` so
    /// that black pixels converge too; with `None` in the image's linear units. `None`
    /// before two samples, or without even sums.
    pub fn noise(&self, x: u32, y: u32, floor: Option<f64>) -> Option<f64> {
        let (t, i) = self.locate(x, y);
        let tile = &self.tiles[t];
        let n = tile.counts[i];
        if n < 2 || !self.has_even {
            return None;
        }
        let total = tile.sums[i].iter().map(|&s| s as f64).sum::<f64>() / 3.0;
        let even = tile.even[i] as f64;
        let (n_even, n_odd) = (f64::from(n.div_ceil(2)), f64::from(n / 2));
        let (m_even, m_odd) = (even / n_even, (total - even).max(0.0) / n_odd);
        let scale = fixed::SCALE;
        let half = (m_even - m_odd).abs() / 2.0;
        Some(match floor {
            Some(floor) => half / (total / f64::from(n) / scale).max(floor) / scale,
            None => half / scale,
        })
    }

    /// A framebuffer holding these accumulators (a checkpoint read back), pixel index
    /// y · width + x, or `None` if their lengths do not fit the size. Every pixel with
    /// samples is new to viewers.
    pub fn from_accumulators(
        width: u32,
        height: u32,
        sums: Vec<[u64; 3]>,
        counts: Vec<u32>,
        even: Vec<u64>,
    ) -> Option<Self> {
        let n = width as usize * height as usize;
        if sums.len() != n || counts.len() != n || !(even.is_empty() || even.len() == n) {
            return None;
        }
        let mut fb = Self::empty(width, height, !even.is_empty());
        fb.version = 1;
        for y in 0..height {
            for x in 0..width {
                let g = y as usize * width as usize + x as usize;
                let (t, i) = fb.locate(x, y);
                let tile = Arc::get_mut(&mut fb.tiles[t]).expect("not shared yet");
                tile.sums[i] = sums[g];
                tile.counts[i] = counts[g];
                if let Some(e) = even.get(g) {
                    tile.even[i] = *e;
                }
                if counts[g] > 0 {
                    tile.versions[i] = 1;
                    fb.tile_versions[t] = 1;
                    fb.tile_sampled[t] += 1;
                    tile.rows[(y % TILE) as usize] = 1;
                }
            }
        }
        Some(fb)
    }

    /// Copies of the per-pixel sums and sample counts, pixel index y · width + x (for
    /// checkpoints, written from a snapshot).
    pub fn accumulators(&self) -> (Vec<[u64; 3]>, Vec<u32>) {
        let n = self.width as usize * self.height as usize;
        let (mut sums, mut counts) = (Vec::with_capacity(n), Vec::with_capacity(n));
        self.each_row(|tile, range| {
            sums.extend_from_slice(&tile.sums[range.clone()]);
            counts.extend_from_slice(&tile.counts[range]);
        });
        (sums, counts)
    }

    /// A copy of the even-sample luminance sums, pixel index y · width + x (empty unless
    /// `with_even`).
    pub fn even(&self) -> Vec<u64> {
        let mut even = Vec::new();
        if self.has_even {
            self.each_row(|tile, range| even.extend_from_slice(&tile.even[range]));
        }
        even
    }

    /// Calls `f` with each image row's pieces in pixel-index order: the tile and the range
    /// of its pixel indices that lie on that row.
    fn each_row(&self, mut f: impl FnMut(&Tile, std::ops::Range<usize>)) {
        for y in 0..self.height {
            let ty = y / TILE;
            for tx in 0..self.tiles_x {
                let (tw, _) = tile_extent(self.width, self.height, tx, ty);
                let start = ((y % TILE) * tw) as usize;
                f(&self.tiles[(ty * self.tiles_x + tx) as usize], start..start + tw as usize);
            }
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Adds `samples` samples to each of `quads`' pixels, with the batch's even-sample
    /// luminance sums (one per pixel) when the framebuffer keeps them. Checks everything
    /// before changing anything, so a refused result leaves the framebuffer as it was.
    /// Integer addition makes the result independent of merge order (DESIGN contract 1).
    pub fn merge(
        &mut self,
        quads: &[Quad],
        samples: u32,
        sums: &[u64],
        even: Option<&[u64]>,
    ) -> Result<(), MergeError> {
        self.check(quads, samples, sums, even)?;
        self.version += 1;
        let version = self.version;
        let even = even.filter(|_| self.has_even);
        for (k, (q, s)) in quads.iter().zip(sums.chunks_exact(3)).enumerate() {
            let (t, i) = self.locate(q.x, q.y);
            // Copies the tile only if a snapshot still holds it.
            let tile = Arc::make_mut(&mut self.tiles[t]);
            tile.versions[i] = version;
            self.tile_versions[t] = version;
            tile.rows[(q.y % TILE) as usize] = version;
            for (acc, v) in tile.sums[i].iter_mut().zip(s) {
                // Saturating: only a scene far beyond the documented limits can get here.
                *acc = acc.saturating_add(*v);
            }
            self.tile_sampled[t] += u32::from(tile.counts[i] == 0 && samples > 0);
            tile.counts[i] = tile.counts[i].saturating_add(samples);
            if let Some(e) = even {
                tile.even[i] = tile.even[i].saturating_add(e[k]);
            }
        }
        Ok(())
    }

    /// Checks that `sums` (and `even`, when this framebuffer keeps even sums) can be the
    /// result of `samples` samples of each of `quads`.
    pub fn check(
        &self,
        quads: &[Quad],
        samples: u32,
        sums: &[u64],
        even: Option<&[u64]>,
    ) -> Result<(), MergeError> {
        if sums.len() != quads.len() * 3 {
            return Err(MergeError::WrongLength { expected: quads.len() * 3, got: sums.len() });
        }
        let max = fixed::max_sum(samples);
        for (q, s) in quads.iter().zip(sums.chunks_exact(3)) {
            if let Some(&value) = s.iter().find(|&&v| v > max) {
                return Err(MergeError::OutOfRange { x: q.x, y: q.y, value, samples });
            }
        }
        if self.has_even {
            // The even samples are at most half of them, rounded up.
            let even = even.unwrap_or(&[]);
            if even.len() != quads.len() {
                return Err(MergeError::EvenLength { expected: quads.len(), got: even.len() });
            }
            let max = fixed::max_sum(samples.div_ceil(2));
            if let Some((q, &value)) = quads.iter().zip(even).find(|(_, &v)| v > max) {
                return Err(MergeError::OutOfRange { x: q.x, y: q.y, value, samples });
            }
        }
        Ok(())
    }

    /// Merges so far: the framebuffer's version.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// The pixels changed after version `since`, in chunks of at most `limit`. Only the
    /// tiles changed since then are scanned (the dirty set), so a delta costs what changed,
    /// not the image; a snapshot taken under the lock serves it outside the lock.
    pub fn changes(&self, since: u64, limit: usize) -> Changes<'_> {
        Changes { fb: self, since, limit: limit.max(1), tile: 0, pixel: 0 }
    }

    /// Tiles of `TILE × TILE` pixels (less at the right and top edges), `tiles_x` a row.
    pub fn tiles(&self) -> (usize, u32) {
        (self.tiles.len(), self.tiles_x)
    }

    /// Whether tile `t` changed after version `since`. Reads one contiguous array, so that
    /// a scan of every tile costs what a scan of a few hundred kilobytes does.
    pub fn tile_changed(&self, t: usize, since: u64) -> bool {
        self.tile_versions[t] > since
    }

    /// Whether every pixel of tile `t` has samples.
    pub fn tile_full(&self, t: usize) -> bool {
        let (tx, ty) = (t as u32 % self.tiles_x, t as u32 / self.tiles_x);
        let (w, h) = tile_extent(self.width, self.height, tx, ty);
        self.tile_sampled[t] == w * h
    }

    /// Calls `f(index, count)` for each pixel of tile `t` changed after version `since`
    /// (index y · width + x), skipping the tile's rows that did not change.
    pub fn tile_changes(&self, t: usize, since: u64, mut f: impl FnMut(u32, u32)) {
        let tile = &self.tiles[t];
        let (tx, ty) = (t as u32 % self.tiles_x, t as u32 / self.tiles_x);
        let (tw, th) = tile_extent(self.width, self.height, tx, ty);
        for r in 0..th {
            if tile.rows[r as usize] <= since {
                continue;
            }
            let row = (r * tw) as usize;
            for c in 0..tw {
                let i = row + c as usize;
                if tile.versions[i] > since {
                    f((ty * TILE + r) * self.width + tx * TILE + c, tile.counts[i]);
                }
            }
        }
    }

    /// Sets a pixel's state (a viewer's replica applying an update).
    pub fn set(&mut self, p: &PixelState) -> bool {
        if p.index as u64 >= u64::from(self.width) * u64::from(self.height) {
            return false;
        }
        let (x, y) = (p.index % self.width, p.index / self.width);
        let (t, i) = self.locate(x, y);
        let tile = Arc::make_mut(&mut self.tiles[t]);
        tile.sums[i] = p.sums;
        self.tile_sampled[t] = self.tile_sampled[t] + u32::from(p.count > 0) - u32::from(tile.counts[i] > 0);
        tile.counts[i] = p.count;
        true
    }

    /// Empties pixel `(x, y)`: sums, count and even sums back to zero, as a change that
    /// viewers see. The coordinator does this to a pixel a lying worker touched, before
    /// its samples are rendered again (sums are additive, so the pixel then ends with the
    /// same bits as if the liar had never delivered).
    pub fn reset(&mut self, x: u32, y: u32) {
        if x >= self.width || y >= self.height {
            return;
        }
        self.version += 1;
        let version = self.version;
        let (t, i) = self.locate(x, y);
        let tile = Arc::make_mut(&mut self.tiles[t]);
        tile.sums[i] = [0; 3];
        self.tile_sampled[t] -= u32::from(tile.counts[i] > 0);
        tile.counts[i] = 0;
        if let Some(e) = tile.even.get_mut(i) {
            *e = 0;
        }
        tile.versions[i] = version;
        self.tile_versions[t] = version;
        tile.rows[(y % TILE) as usize] = version;
    }

    /// The mean radiance of pixel `(x, y)`, or `None` before its first sample.
    pub fn mean(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        let (t, i) = self.locate(x, y);
        let tile = &self.tiles[t];
        let n = tile.counts[i];
        (n > 0).then(|| tile.sums[i].map(|s| fixed::mean(s, n)))
    }

    /// The image as linear RGB, top row first (image order, ready to encode). A pixel
    /// without samples shows the mosaic: the mean of the finest computed block covering it.
    pub fn resolve(&self) -> Vec<f32> {
        let (w, h) = (self.width, self.height);
        let mut out = Vec::with_capacity(w as usize * h as usize * 3);
        for row in 0..h {
            let y = h - 1 - row;
            for x in 0..w {
                let rgb = self.mean(x, y).or_else(|| {
                    mosaic_source(w, h, x, y, |sx, sy| self.count(sx, sy) > 0)
                        .and_then(|(sx, sy)| self.mean(sx, sy))
                });
                out.extend_from_slice(&rgb.unwrap_or([0.0; 3]));
            }
        }
        out
    }
}

/// The width and height of tile `(tx, ty)`: `TILE`, less at the right and top edges.
fn tile_extent(width: u32, height: u32, tx: u32, ty: u32) -> (u32, u32) {
    ((width - tx * TILE).min(TILE), (height - ty * TILE).min(TILE))
}

/// The chunks of a delta: see `Framebuffer::changes`.
#[derive(Debug)]
pub struct Changes<'a> {
    fb: &'a Framebuffer,
    since: u64,
    limit: usize,
    tile: usize,
    pixel: usize,
}

impl Iterator for Changes<'_> {
    type Item = Vec<PixelState>;

    fn next(&mut self) -> Option<Vec<PixelState>> {
        let fb = self.fb;
        let mut out = Vec::new();
        while self.tile < fb.tiles.len() {
            if fb.tile_versions[self.tile] <= self.since {
                self.tile += 1;
                self.pixel = 0;
                continue;
            }
            let tile = &fb.tiles[self.tile];
            let (tx, ty) = (self.tile as u32 % fb.tiles_x, self.tile as u32 / fb.tiles_x);
            let (tw, _) = tile_extent(fb.width, fb.height, tx, ty);
            while self.pixel < tile.versions.len() {
                let row = self.pixel / tw as usize;
                if tile.rows[row] <= self.since {
                    self.pixel = (row + 1) * tw as usize;
                    continue;
                }
                let i = self.pixel;
                if tile.versions[i] > self.since {
                    if out.len() == self.limit {
                        return Some(out);
                    }
                    let (x, y) = (tx * TILE + i as u32 % tw, ty * TILE + i as u32 / tw);
                    out.push(PixelState {
                        index: y * fb.width + x,
                        sums: tile.sums[i],
                        count: tile.counts[i],
                    });
                }
                self.pixel += 1;
            }
            self.tile += 1;
            self.pixel = 0;
        }
        (!out.is_empty()).then_some(out)
    }
}

#[cfg(test)]
mod tests;
