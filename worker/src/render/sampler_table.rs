//! A pixel's first dimensions drawn for all of a batch's samples of it at once.
//!
//! A batch renders a pixel's samples one after another, and each draw is a chain of
//! dependent multiplies (a keyed permutation, then two or three 64-bit hashes) whose result
//! the next instructions wait for: a ray's direction, a light's point. Drawn for all of the
//! pixel's planned samples in one loop, the chains are independent and overlap, and each
//! sample then reads its value. Every entry is the function the draw computes one at a
//! time, called with that sample's index, so the bits are the same
//! (`tests::tabled_draws_are_the_draws`). A dimension that few paths reach is drawn for
//! samples that never read it; blocks of eight samples, filled as a sample first reaches
//! them, wasted less and gained less (docs/speed.md, eighteenth part).

use super::Sampler;

/// Dimensions tabulated: a Cook path's first few bounces (film and lens, then a light, a
/// lobe and a direction at each hit). Later ones are drawn by fewer samples, and a table
/// would compute values no sample reads.
pub(super) const TABLED: usize = 16;

/// The most samples a table holds (16 bytes each per dimension, 64 KB at most): more and
/// the values are drawn one at a time.
pub(super) const MOST_SAMPLES: u32 = 256;

/// What a tabulated dimension holds: a 1-D, 2-D or the camera's 4-D draw. A dimension is
/// tabulated as the first sample to reach it draws it; a sample that draws it otherwise
/// (its path took another turn) draws that one alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum Shape {
    #[default]
    Empty,
    One,
    Two,
    Four,
}

/// The draws of the planned samples `first..first + count` of one pixel.
#[derive(Debug, Clone, Default)]
pub(super) struct DrawTable {
    first: u32,
    /// 0 when no samples are planned.
    count: u32,
    shapes: [Shape; TABLED],
    /// Sample-major: a sample's dimensions side by side.
    values: Vec<[f32; 4]>,
    /// The eight-lane fills' output before it is spread into `values` ([`DrawTable::fill_all`]).
    #[cfg_attr(not(all(target_arch = "x86_64", not(feature = "scalar"))), allow(dead_code))]
    scratch: Vec<[f32; 4]>,
}

impl DrawTable {
    /// Plans samples `first..end` (of a pattern of `spp`): the values drawn before are
    /// dropped.
    pub(super) fn plan(&mut self, first: u32, end: u32) {
        let count = end.saturating_sub(first);
        self.count = if count > 1 && count <= MOST_SAMPLES { count } else { 0 };
        self.first = first;
        self.shapes = [Shape::Empty; TABLED];
        let len = self.count as usize * TABLED;
        if self.values.len() < len {
            self.values.resize(len, [0.0; 4]);
        }
    }

    /// No samples planned.
    pub(super) fn clear(&mut self) {
        self.count = 0;
    }

    /// Where sample `index`'s draw of dimension `d` in `shape` is, if it is tabulated or
    /// can be.
    #[inline]
    pub(super) fn entry(&self, d: u32, index: u32, shape: Shape) -> Option<usize> {
        let i = index.wrapping_sub(self.first);
        if i >= self.count {
            return None;
        }
        let held = *self.shapes.get(d as usize)?;
        (held == shape || held == Shape::Empty).then_some(i as usize * TABLED + d as usize)
    }

    /// Sample `index`'s draw of dimension `d`, if the dimension holds its values in
    /// `shape`: [`DrawTable::entry`] and [`DrawTable::is_filled`] in one test, the read
    /// most draws make.
    #[inline(always)]
    pub(super) fn filled(&self, d: u32, index: u32, shape: Shape) -> Option<[f32; 4]> {
        let i = index.wrapping_sub(self.first);
        if i >= self.count || *self.shapes.get(d as usize)? != shape {
            return None;
        }
        Some(self.values[i as usize * TABLED + d as usize])
    }

    /// Whether dimension `d` holds its values.
    #[inline]
    pub(super) fn is_filled(&self, d: u32) -> bool {
        self.shapes[d as usize] != Shape::Empty
    }

    #[inline]
    pub(super) fn get(&self, at: usize) -> [f32; 4] {
        self.values[at]
    }

    /// Draws dimension `d` in `shape` for every planned sample at once: `draw(first, out)`
    /// writes the values of samples `first..first + out.len()` into `out`. The buffer is
    /// kept with the table: an array of [`MOST_SAMPLES`] values on the stack was zeroed
    /// for every pixel and dimension the eight-lane fills drew, whatever the plan's length
    /// (docs/speed.md, thirty-eighth part).
    #[cfg_attr(not(all(target_arch = "x86_64", not(feature = "scalar"))), allow(dead_code))]
    pub(super) fn fill_all(&mut self, d: u32, shape: Shape, draw: impl FnOnce(u32, &mut [[f32; 4]])) {
        let count = self.count as usize;
        if self.scratch.len() < count {
            self.scratch.resize(count, [0.0; 4]);
        }
        draw(self.first, &mut self.scratch[..count]);
        for (i, &v) in self.scratch[..count].iter().enumerate() {
            self.values[i * TABLED + d as usize] = v;
        }
        self.shapes[d as usize] = shape;
    }

    /// Draws dimension `d` in `shape` for every planned sample: `value(index)`.
    pub(super) fn fill(&mut self, d: u32, shape: Shape, mut value: impl FnMut(u32) -> [f32; 4]) {
        for i in 0..self.count {
            self.values[i as usize * TABLED + d as usize] = value(self.first + i);
        }
        self.shapes[d as usize] = shape;
    }
}

/// The sampler's reads of its table.
impl Sampler {
    /// The current sample's draw of dimension `d` in `shape` from the pixel's table, drawn
    /// for all its planned samples (`value(sampler, index)`) if it is not there yet; `None`
    /// when the table cannot hold it.
    #[inline]
    pub(super) fn tabled(
        &mut self,
        d: u32,
        shape: Shape,
        value: impl Fn(&mut Self, u32) -> [f32; 4],
    ) -> Option<[f32; 4]> {
        self.tabled_with(d, shape, |s, table| table.fill(d, shape, |i| value(s, i)))
    }

    /// The current sample's draw of dimension `d` if the pixel's table holds it in
    /// `shape` already: the draws' common path. The draws' other paths (filling the
    /// table, drawing one value alone) are out of line behind it; inlined into one
    /// function with it, they made every draw pay their stack frame and saved registers
    /// (docs/speed.md, fortieth part).
    #[inline(always)]
    pub(super) fn table_hit(&self, d: u32, shape: Shape) -> Option<[f32; 4]> {
        // Past the pattern, or without one, a draw is a hash, whatever a plan holds.
        if !self.in_pattern() {
            return None;
        }
        self.table.filled(d, self.index, shape)
    }

    /// [`Sampler::tabled`] with the dimension's values drawn by `fill`.
    #[inline]
    pub(super) fn tabled_with(
        &mut self,
        d: u32,
        shape: Shape,
        fill: impl FnOnce(&mut Self, &mut DrawTable),
    ) -> Option<[f32; 4]> {
        let at = self.table.entry(d, self.index, shape)?;
        if !self.table.is_filled(d) {
            let mut table = std::mem::take(&mut self.table);
            fill(self, &mut table);
            self.table = table;
        }
        Some(self.table.get(at))
    }
}

#[cfg(test)]
mod tests {
    use glam::UVec2;

    use super::super::{hash_words, Sampler, SamplerKind};
    use super::*;

    /// A sample's draws: the camera's 4-D pair, then 1-D, 2-D, 4-D and skipped dimensions
    /// in an order of the sample's own (paths that end early, take another lobe, or draw a
    /// dimension as 1-D where others draw it as 2-D), past the tabulated dimensions.
    fn path(sampler: &mut Sampler, pixel: UVec2, index: u32) -> Vec<u32> {
        sampler.start_pixel_sample(pixel, index);
        let h = hash_words(&[u64::from(index), u64::from(pixel.x)]);
        let (film, lens) = sampler.get_4d();
        let mut bits = vec![film.x.to_bits(), film.y.to_bits(), lens.x.to_bits(), lens.y.to_bits()];
        for d in 0..(h % (TABLED as u64 + 6)) {
            match (h >> (2 * d % 60)) & 3 {
                0 => bits.push(sampler.get_1d().to_bits()),
                3 if d % 4 == 0 => bits.push(sampler.skip().to_bits()),
                3 if d % 4 == 1 => {
                    let (a, b) = sampler.get_4d();
                    bits.extend([a.x, a.y, b.x, b.y].map(f32::to_bits));
                }
                _ => {
                    let v = sampler.get_2d();
                    bits.extend([v.x.to_bits(), v.y.to_bits()]);
                }
            }
        }
        bits
    }

    /// Draws from a planned pixel's table have the bits of draws computed one at a time,
    /// filled draw by draw and (where this CPU has AVX-512) eight at a time: every
    /// pattern; sample counts of powers of two (grids square and not), others, one whose
    /// fine-grid offsets are not kept (254: 2 × 127), and more than a table holds; plans
    /// that start mid-pattern, run past it, hold one sample, or are walked backwards; and
    /// a sample of another pixel near a plan's end, which drops the plan.
    #[test]
    fn tabled_draws_are_the_draws() {
        let kinds = [SamplerKind::Stratified, SamplerKind::Sobol, SamplerKind::Independent];
        let counts = [1, 2, 12, 16, 64, 128, 254, 256, 300];
        let cases = kinds.into_iter().flat_map(|k| counts.map(|n| (k, n)));
        // The AVX-512 fill where this CPU takes it, and the scalar fill everywhere.
        for ((kind, spp), wide) in cases.flat_map(|c| [(c, true), (c, false)]) {
            let (mut planned, mut alone) = (Sampler::new(kind, 5, spp), Sampler::new(kind, 5, spp));
            planned.wide &= wide;
            let (a, b) = (UVec2::new(3, 1), UVec2::new(0, 7));
            for (pixel, samples, backwards) in [
                (a, 0..spp, false),
                (b, 1..spp, true),
                (a, spp / 2..spp + 3, false),
                (b, spp - 1..spp, false),
                (a, 0..spp, true),
            ] {
                planned.plan_pixel(pixel, samples.clone());
                let mut order: Vec<u32> = samples.collect();
                if backwards {
                    order.reverse();
                }
                for (n, &i) in order.iter().enumerate() {
                    if n + 2 == order.len() {
                        // Another pixel: the plan's table is not that pixel's.
                        assert_eq!(path(&mut planned, pixel + 1, i), path(&mut alone, pixel + 1, i));
                    }
                    let where_ = format!("{kind:?} spp {spp} {pixel} sample {i} wide {}", planned.wide);
                    assert_eq!(path(&mut planned, pixel, i), path(&mut alone, pixel, i), "{where_}");
                }
            }
            // The table was used where it can be, so the comparison above compared it.
            planned.plan_pixel(a, 0..spp);
            path(&mut planned, a, 0);
            let tabled = kind != SamplerKind::Independent && (2..=MOST_SAMPLES).contains(&spp);
            assert_eq!(planned.table.is_filled(0), tabled, "{kind:?} spp {spp}");
        }
    }
}
