//! Sampling as a pure function of (seed, pixel, sample index), with three patterns: Cook's
//! jittered strata (the default), independent uniform random numbers, and an Owen-scrambled
//! Sobol sequence in a nested order, whose every power-of-two prefix is a net (jobs in
//! rounds draw it: `Scene::sampler`).
//!
//! Each 2-D dimension of a pixel's samples (the pixel area now; lens, time, light and
//! lobes as the scene needs them) is stratified with a correlated multi-jittered pattern
//! over the pixel's `spp` samples: one sample per cell of an `m × n` grid and per row and
//! column of the finer grid (Kensler 2013). The strata of different dimensions are
//! associated at random, as Cook's paper asks, by passing the sample index through a
//! different keyed permutation for each dimension; the camera's film and lens, which
//! decide together what an out-of-focus ray sees, are the exception: one 4-D pattern
//! ([`Sampler::get_4d`]). Nothing is seeded from entropy, and what a sampler keeps (a
//! pixel's keys, offsets and planned draws) is a function of (seed, pixel, dimension,
//! index), so any worker, in any order, computes the same sample.

use glam::{UVec2, Vec2};

/// Hashes a few words into 64 well-mixed bits (a splitmix64-style finaliser per word).
#[inline]
pub fn hash_words(words: &[u64]) -> u64 {
    words.iter().fold(HASH_START, |h, &w| hash_step(h, w))
}

/// The state [`hash_words`] starts from.
const HASH_START: u64 = 0x9e37_79b9_7f4a_7c15;

/// One word of [`hash_words`]: hashes sharing their first words can share those steps
/// (the sampler keeps the state after seed and pixel, and after a pattern's key and
/// sample), with the same bits as hashing each from the start.
#[inline]
fn hash_step(h: u64, w: u64) -> u64 {
    mix64(h ^ w.wrapping_add(HASH_START).wrapping_add(h << 6).wrapping_add(h >> 2))
}

#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A uniform float in [0, 1) from 24 bits of a hash.
#[inline]
pub(crate) fn unit_float(h: u64) -> f32 {
    (h >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// The largest f32 below 1.
pub const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

pub use tessera_description::model::SamplerKind;

/// What every draw of one dimension of one pixel shares, whatever the sample index: the
/// dimension's key and the hash states that start from it.
#[derive(Debug, Clone, Copy, Default)]
struct DimensionKeys {
    /// `hash_words(&[seed, pixel, dimension])`: keys the strata's order.
    key: u64,
    /// `mix64(key)`: keys the pattern (its jitter, Sobol's scrambling).
    pattern: u64,
    /// `hash_step(HASH_START, key)`: where 1-D jitter and independent draws start.
    from_key: u64,
    /// `hash_step(HASH_START, pattern)`: where the 2-D pattern's jitter starts.
    from_pattern: u64,
}

impl DimensionKeys {
    fn new(key: u64) -> DimensionKeys {
        let pattern = mix64(key);
        DimensionKeys {
            key,
            pattern,
            from_key: hash_step(HASH_START, key),
            from_pattern: hash_step(HASH_START, pattern),
        }
    }
}

/// Dimensions whose keys a sampler keeps for the pixel at hand: a Cook path of depth 8
/// with a few lights draws about 30; deeper ones compute the rest at every draw.
const KEPT_DIMENSIONS: usize = 64;

/// The most fine-grid offsets a sampler keeps for one dimension (columns and rows of its
/// pattern's grid: 8 at 16 samples, 32 at 256): beyond that (over about 4000 samples a
/// pixel) a table of every kept dimension would outgrow the L1 cache it is meant to stay
/// in, and the offsets are computed at every draw.
const KEPT_OFFSETS: u32 = 128;

/// An offset not computed yet for the pixel at hand.
const UNKNOWN: u16 = u16::MAX;

/// The sample generator of one pixel sample; dimensions are drawn in a fixed order.
///
/// A worker renders a pixel's samples one after another, and everything a draw hashes
/// before the sample index enters depends only on (seed, pixel, dimension): the sampler
/// keeps that for the dimensions drawn so far in the current pixel, and draws the same
/// bits as hashing every word from the start (`tests::kept_keys_draw_what_fresh_hashes_draw`).
/// So are the shuffled fine-grid offsets of a dimension's columns and rows: `spp` draws
/// share `m + rows` of them, each two keyed permutations' worth of work to compute. And
/// when the caller plans the pixel's samples ([`Sampler::plan_pixel`]), its first
/// dimensions are drawn for all of them at once and kept (`sampler_table.rs`).
#[derive(Debug, Clone)]
pub struct Sampler {
    kind: SamplerKind,
    seed: u64,
    spp: u32,
    /// The stratified pattern's order of its samples (Cook's random association).
    order: Permutation,
    /// Sobol's pattern: `spp` rounded up to `2^sobol_bits`, the domain of [`nested_order`].
    sobol_bits: u32,
    cmj: Cmj,
    pixel: UVec2,
    /// The hash state after the seed and the pixel: every dimension's key starts there.
    pixel_key: u64,
    index: u32,
    dimension: u32,
    /// The keys of dimensions `0..kept` of `pixel`.
    keys: Box<[DimensionKeys; KEPT_DIMENSIONS]>,
    kept: u32,
    /// Entries of `offsets` per kept dimension: the pattern's `m` column offsets, then its
    /// row offsets; 0 when they are not kept (not the stratified pattern, or too many).
    stride: usize,
    /// The fine-grid offsets of dimensions `0..kept` of `pixel`, [`UNKNOWN`] until drawn.
    offsets: Box<[u16]>,
    /// Whether [`Sampler::get_4d`] draws one 4-D net (else two 2-D draws).
    joint: bool,
    /// The first dimensions of the planned samples of `pixel` ([`Sampler::plan_pixel`]).
    table: DrawTable,
    /// Whether the table's 2-D draws are drawn eight at a time: Cook's pattern on a grid
    /// of powers of two whose offsets are kept, on a CPU with AVX-512 (`sampler_avx512.rs`).
    wide: bool,
    /// Whether the table's 4-D draws are drawn eight at a time: Cook's pattern of a
    /// power-of-two count above 1, on a CPU with AVX2 (`sampler_avx2.rs`).
    wide_4d: bool,
}

impl Sampler {
    /// A sampler for patterns of `spp` samples per pixel.
    pub fn new(kind: SamplerKind, seed: u64, spp: u32) -> Self {
        let spp = spp.max(1);
        let cmj = Cmj::new(spp);
        let stride = if kind == SamplerKind::Stratified && cmj.m + cmj.rows <= KEPT_OFFSETS {
            (cmj.m + cmj.rows) as usize
        } else {
            0
        };
        Sampler {
            kind,
            seed,
            spp,
            order: Permutation::new(spp),
            // Past 2^31 (no job's count; the farm caps them at 2^20) the domain is all 32 bits.
            sobol_bits: spp.checked_next_power_of_two().map_or(32, u32::trailing_zeros),
            cmj,
            pixel: UVec2::ZERO,
            pixel_key: Self::key_of(seed, UVec2::ZERO),
            index: 0,
            dimension: 0,
            keys: Box::new([DimensionKeys::default(); KEPT_DIMENSIONS]),
            kept: 0,
            stride,
            offsets: vec![UNKNOWN; stride * KEPT_DIMENSIONS].into_boxed_slice(),
            joint: match kind {
                SamplerKind::Sobol => true,
                SamplerKind::Stratified => spp.is_power_of_two(),
                SamplerKind::Independent => false,
            },
            table: DrawTable::default(),
            wide: kind == SamplerKind::Stratified
                && cmj.pow2.is_some()
                && cmj.m * cmj.rows > 1
                && stride > 0
                && avx512_available(),
            wide_4d: kind == SamplerKind::Stratified && spp.is_power_of_two() && spp > 1 && avx2_available(),
        }
    }

    /// `hash_words(&[seed, pixel])`.
    fn key_of(seed: u64, pixel: UVec2) -> u64 {
        hash_words(&[seed, u64::from(pixel.x) | (u64::from(pixel.y) << 32)])
    }

    /// Says that samples `samples` of `pixel` come next, in any order: their first
    /// dimensions are then drawn for all of them at once (`sampler_table.rs`), where the
    /// plan holds 2 to [`MOST_PLANNED`] samples of the pattern. A sample of another
    /// pixel drops the plan. Without a plan every draw is computed alone; the values are
    /// the same.
    pub fn plan_pixel(&mut self, pixel: UVec2, samples: std::ops::Range<u32>) {
        self.move_to_pixel(pixel);
        if self.kind == SamplerKind::Independent {
            return;
        }
        // Indices beyond the pattern draw plain random numbers, never from the table.
        self.table.plan(samples.start, samples.end.min(self.spp));
    }

    fn move_to_pixel(&mut self, pixel: UVec2) {
        if pixel != self.pixel {
            self.pixel_key = Self::key_of(self.seed, pixel);
            self.pixel = pixel;
            self.kept = 0;
            self.table.clear();
        }
    }

    /// Positions the sampler at sample `index` of `pixel`; the next draw is dimension 0.
    pub fn start_pixel_sample(&mut self, pixel: UVec2, index: u32) {
        self.move_to_pixel(pixel);
        self.index = index;
        self.dimension = 0;
    }

    /// Positions the sampler at sample `index` of `pixel` with its first `dimension`
    /// dimensions drawn, as `start_pixel_sample` and those draws leave it (the draws
    /// after them give the same values: a draw depends on the pixel, the index and its
    /// dimension only).
    pub fn resume_pixel_sample(&mut self, pixel: UVec2, index: u32, dimension: u32) {
        self.start_pixel_sample(pixel, index);
        self.dimension = dimension;
    }

    /// The keys of the next dimension (`hash_words(&[seed, pixel, dimension])` and what
    /// follows from it), kept or computed.
    #[inline]
    fn next_dimension(&mut self) -> DimensionKeys {
        let d = self.dimension;
        self.dimension += 1;
        if d < self.kept {
            return self.keys[d as usize];
        }
        self.new_dimension(d)
    }

    /// Whether the current sample's draws come from a pattern: below `spp`, and not
    /// independent samples. Past the pattern, or without one, a draw is a hash.
    #[inline(always)]
    fn in_pattern(&self) -> bool {
        self.index < self.spp && self.kind != SamplerKind::Independent
    }

    /// [`Sampler::next_dimension`] where the draw does not need the keys (the table holds
    /// it): the same dimensions kept, without loading a kept one's keys.
    #[inline(always)]
    fn pass_dimension(&mut self) {
        let d = self.dimension;
        self.dimension += 1;
        if d >= self.kept {
            self.new_dimension(d);
        }
    }

    /// The keys of dimension `d`, not kept yet: the first sample of a pixel to draw it
    /// computes them. Out of line, so that the draws' common path (the keys kept) holds
    /// fewer registers.
    #[cold]
    #[inline(never)]
    fn new_dimension(&mut self, d: u32) -> DimensionKeys {
        let keys = DimensionKeys::new(hash_step(self.pixel_key, u64::from(d)));
        // Dimensions are drawn in order from 0, so the next one to keep is `kept`.
        if d == self.kept && (d as usize) < KEPT_DIMENSIONS {
            self.keys[d as usize] = keys;
            self.kept += 1;
            // Without kept offsets (Sobol's pattern) the fill is empty, but still a call
            // to `memset`: a job in rounds starts a pixel's keys at every round, and those
            // calls were 7 % of its profile.
            if self.stride > 0 {
                let at = d as usize * self.stride;
                self.offsets[at..at + self.stride].fill(UNKNOWN);
            }
        }
        keys
    }

    /// Dimensions drawn since `start_pixel_sample` (a 2-D draw counts once): what a sample
    /// paid for.
    pub fn dimensions_used(&self) -> u32 {
        self.dimension
    }

    /// The next 2-D dimension, following the pixel's pattern.
    #[inline]
    pub fn get_2d(&mut self) -> Vec2 {
        let d = self.dimension;
        if let Some([x, y, ..]) = self.table_hit(d, Shape::Two) {
            self.pass_dimension();
            return Vec2::new(x, y);
        }
        let k = self.next_dimension();
        self.draw_2d(d, k)
    }

    /// [`Sampler::get_2d`] of dimension `d` (keys `k`) where the table does not hold it.
    #[inline(never)]
    fn draw_2d(&mut self, d: u32, k: DimensionKeys) -> Vec2 {
        if !self.in_pattern() {
            // Beyond the pattern, or no pattern: plain random (hash_words(&[key, index])).
            let h = hash_step(k.from_key, u64::from(self.index));
            return Vec2::new(unit_float(h), unit_float(mix64(h)));
        }
        let tabled = if self.wide {
            self.tabled_with(d, Shape::Two, |s, table| s.fill_2d_wide(d, k, table))
        } else {
            self.tabled(d, Shape::Two, |s, i| {
                let v = s.pattern_2d(d, k, i);
                [v.x, v.y, 0.0, 0.0]
            })
        };
        match tabled {
            Some([x, y, ..]) => Vec2::new(x, y),
            None => self.pattern_2d(d, k, self.index),
        }
    }

    /// Dimension `d`'s point (keys `k`) at sample `index`, below `spp`, of a pattern.
    #[inline]
    fn pattern_2d(&mut self, d: u32, k: DimensionKeys, index: u32) -> Vec2 {
        // Cook's random association: each dimension visits the strata (or Sobol's points)
        // in its own order.
        let s = self.shuffle(k.key, index);
        match self.kind {
            SamplerKind::Sobol => Vec2::new(
                scrambled(s, k.pattern),
                scrambled(sobol_reversed(s, &SOBOL_BYTES[0]), k.pattern >> 32),
            ),
            _ => {
                let cell = self.cmj.cell(s);
                let offsets = self.fine_offsets(d, cell, k.pattern);
                self.cmj.place(s, cell, offsets, k.from_pattern)
            }
        }
    }

    /// Which point of the pattern sample `index` is in a dimension keyed by `key`: each
    /// dimension's own order, Sobol's nested so that its prefixes stay nets.
    #[inline]
    fn shuffle(&self, key: u64, index: u32) -> u32 {
        match self.kind {
            SamplerKind::Sobol => nested_order(index, key as u32, self.sobol_bits),
            _ => self.order.apply(index, key),
        }
    }

    /// No AVX-512 fill where glam runs scalar code or off x86-64, and `wide` is never set.
    #[cfg(not(all(target_arch = "x86_64", not(feature = "scalar"))))]
    fn fill_2d_wide(&mut self, _: u32, _: DimensionKeys, _: &mut DrawTable) {
        unreachable!("`wide` is never set without the AVX-512 fill")
    }

    /// No AVX2 fill where glam runs scalar code or off x86-64, and `wide_4d` is never set.
    #[cfg(not(all(target_arch = "x86_64", not(feature = "scalar"))))]
    fn fill_4d_wide(&self, _: u32, _: DimensionKeys, _: DimensionKeys, _: &mut DrawTable) {
        unreachable!("`wide_4d` is never set without the AVX2 fill")
    }

    /// The fine-grid offsets (of the column, of the row) of `cell` in dimension `d`'s
    /// pattern, keyed by `key`: kept for the pixel's later samples where they can be.
    #[inline]
    fn fine_offsets(&mut self, d: u32, (col, row): (u32, u32), key: u64) -> (u32, u32) {
        if d >= self.kept || self.stride == 0 {
            return (self.cmj.column_offset(col, key), self.cmj.row_offset(row, key));
        }
        let at = d as usize * self.stride;
        let (x, y) = (at + col as usize, at + (self.cmj.m + row) as usize);
        if self.offsets[x] == UNKNOWN {
            // Below KEPT_OFFSETS, so it fits and is never UNKNOWN itself.
            self.offsets[x] = self.cmj.column_offset(col, key) as u16;
        }
        if self.offsets[y] == UNKNOWN {
            self.offsets[y] = self.cmj.row_offset(row, key) as u16;
        }
        (u32::from(self.offsets[x]), u32::from(self.offsets[y]))
    }

    /// Passes over the next dimension, 1-D or 2-D, whose value nothing reads: the draws
    /// after it keep their dimensions' numbers, and so their values. Returns 0.
    pub fn skip(&mut self) -> f32 {
        // Through `next_dimension`, so that the skipped dimension's keys are kept too and
        // the draws after it stay on the path that reads kept keys.
        self.next_dimension();
        0.0
    }

    /// The next two 2-D dimensions as one 4-D pattern: the camera's film and lens draws.
    ///
    /// Out of focus, which subpixel and which lens point a ray passes through decide
    /// together what it sees (a small bright thing seen in a mirror is a sliver of the
    /// 4-D domain); Cook's random association stratifies each plane alone and leaves
    /// their interaction to chance, the error that dominated `spheres` (docs/speed.md,
    /// fourteenth part). So both come from one Owen-scrambled Sobol net in four
    /// dimensions (Burley 2020): the film from Sobol's first two dimensions, a (0, 2)
    /// net, as stratified as Cook's pattern; the lens from the next two. The pair is still
    /// associated at random with every later dimension. The stratified pattern takes the
    /// 4-D net at power-of-two sample counts, where it is a net, and keeps two 2-D draws
    /// otherwise; independent samples and indices beyond the pattern are two 2-D draws.
    pub fn get_4d(&mut self) -> (Vec2, Vec2) {
        if !self.joint || self.index >= self.spp {
            return (self.get_2d(), self.get_2d());
        }
        let d = self.dimension;
        let [a, b, c, e] = match self.table_hit(d, Shape::Four) {
            Some(v) => {
                self.pass_dimension();
                self.pass_dimension();
                v
            }
            None => {
                let (film, lens) = (self.next_dimension(), self.next_dimension());
                self.draw_4d(d, film, lens)
            }
        };
        (Vec2::new(a, b), Vec2::new(c, e))
    }

    /// [`Sampler::get_4d`]'s joint draw of dimension `d` (keys `film` and `lens`) where
    /// the table does not hold it.
    #[inline(never)]
    fn draw_4d(&mut self, d: u32, film: DimensionKeys, lens: DimensionKeys) -> [f32; 4] {
        let tabled = if self.wide_4d {
            self.tabled_with(d, Shape::Four, |s, table| s.fill_4d_wide(d, film, lens, table))
        } else {
            self.tabled(d, Shape::Four, |s, i| s.pattern_4d(film, lens, i))
        };
        tabled.unwrap_or_else(|| self.pattern_4d(film, lens, self.index))
    }

    /// The film's and the lens's coordinates of the 4-D net at sample `index`.
    #[inline]
    fn pattern_4d(&self, film: DimensionKeys, lens: DimensionKeys, index: u32) -> [f32; 4] {
        // One index for all four coordinates, so that they stay one net's point.
        let s = self.shuffle(film.key, index);
        let [y, u, v] = sobol_point(s);
        [
            scrambled(s, film.pattern),
            scrambled(y, film.pattern >> 32),
            scrambled(u, lens.pattern),
            scrambled(v, lens.pattern >> 32),
        ]
    }

    /// The next 1-D dimension, following the pixel's pattern.
    #[inline]
    pub fn get_1d(&mut self) -> f32 {
        let d = self.dimension;
        if let Some([x, ..]) = self.table_hit(d, Shape::One) {
            self.pass_dimension();
            return x;
        }
        let k = self.next_dimension();
        self.draw_1d(d, k)
    }

    /// [`Sampler::get_1d`] of dimension `d` (keys `k`) where the table does not hold it.
    #[inline(never)]
    fn draw_1d(&mut self, d: u32, k: DimensionKeys) -> f32 {
        if !self.in_pattern() {
            return unit_float(hash_step(k.from_key, u64::from(self.index)));
        }
        match self.tabled(d, Shape::One, |s, i| [s.pattern_1d(k, i), 0.0, 0.0, 0.0]) {
            Some([x, ..]) => x,
            None => self.pattern_1d(k, self.index),
        }
    }

    /// Dimension `k`'s value at sample `index`, below `spp`, of a pattern.
    #[inline]
    fn pattern_1d(&self, k: DimensionKeys, index: u32) -> f32 {
        let s = self.shuffle(k.key, index);
        match self.kind {
            SamplerKind::Sobol => scrambled(s, k.pattern),
            _ => {
                // hash_words(&[key, s, 3]).
                let jitter = unit_float(hash_step(hash_step(k.from_key, u64::from(s)), 3));
                ((s as f32 + jitter) / self.spp as f32).min(ONE_MINUS_EPSILON)
            }
        }
    }
}

#[path = "sampler_sobol.rs"]
mod sobol;

#[path = "sampler_cmj.rs"]
mod cmj;
pub use cmj::{grid, permute};
use cmj::{Cmj, Permutation};
use sobol::{nested_order, scrambled, sobol_point, sobol_reversed, SOBOL_BYTES};

#[path = "sampler_table.rs"]
mod table;

/// The most samples [`Sampler::plan_pixel`] tabulates at once.
pub const MOST_PLANNED: u32 = table::MOST_SAMPLES;

#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
#[path = "sampler_avx512.rs"]
mod avx512;
#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
use avx512::available as avx512_available;

/// No AVX-512 fill where glam runs scalar code or off x86-64.
#[cfg(not(all(target_arch = "x86_64", not(feature = "scalar"))))]
fn avx512_available() -> bool {
    false
}

#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
#[path = "sampler_avx2.rs"]
mod avx2;
#[cfg(all(target_arch = "x86_64", not(feature = "scalar")))]
use avx2::available as avx2_available;

/// No AVX2 fill where glam runs scalar code or off x86-64.
#[cfg(not(all(target_arch = "x86_64", not(feature = "scalar"))))]
fn avx2_available() -> bool {
    false
}
use table::{DrawTable, Shape};

#[cfg(test)]
#[path = "sampler_tests.rs"]
mod tests;
