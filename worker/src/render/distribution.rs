//! Piecewise-constant distributions for importance sampling: one-dimensional (a light
//! chosen by power, a triangle of an emitting mesh chosen by area) and two-dimensional
//! over the unit square (an environment map's texels, as a marginal distribution over
//! rows and a conditional one over each row's columns).
//!
//! Sampling inverts the cumulative distribution: a guide table (Chen and Asau's
//! cut-points) names, for each of `n` equal slices of [0, 1) (at most 2^22), bins at or
//! before and at or after every answer in it, and a binary search between them finds the bin the search over
//! the whole table finds. A distribution whose weights are all zero falls back to uniform,
//! so that a sample is always defined.

use glam::Vec2;

/// A piecewise-constant density over [0, 1) with `n` equal bins, or equivalently a
/// discrete distribution over `n` items.
#[derive(Debug, Clone)]
pub struct Distribution1D {
    /// The weights, non-negative.
    func: Vec<f32>,
    /// The cumulative distribution at the bins' edges: `cdf[0] = 0`, `cdf[n] = 1`.
    cdf: Vec<f32>,
    /// The integral of the step function over [0, 1]: the mean weight.
    integral: f32,
    /// `guide[k]`: the bin of `k / slices` ([`Distribution1D::search`]), k in 0..=slices.
    guide: Vec<u32>,
}

/// The most slices a guide table has: below 2^22 a slice's float bounds are within a
/// slice of their exact values (`Distribution1D::sample` relies on it).
const MAX_SLICES: usize = 1 << 22;

/// A sample of a [`Distribution1D`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample1D {
    /// The bin (item) picked.
    pub index: usize,
    /// Where in [0, 1) the continuous sample lies.
    pub x: f32,
    /// The continuous sample's offset within its bin, in [0, 1): a fresh uniform number
    /// for a choice made inside the bin.
    pub remapped: f32,
}

impl Distribution1D {
    /// The distribution proportional to `func` (negative or non-finite weights count as 0).
    /// `func` must not be empty.
    pub fn new(func: &[f32]) -> Distribution1D {
        assert!(!func.is_empty(), "a distribution needs at least one bin");
        let func: Vec<f32> = func.iter().map(|&f| if f.is_finite() && f > 0.0 { f } else { 0.0 }).collect();
        let n = func.len();
        // Sum in f64: a large map's running sum would otherwise lose its small bins.
        let mut acc = 0f64;
        let mut cdf = Vec::with_capacity(n + 1);
        cdf.push(0f64);
        for &f in &func {
            acc += f64::from(f);
            cdf.push(acc);
        }
        let total = acc;
        let cdf: Vec<f32> = if total > 0.0 {
            cdf.iter().map(|&c| (c / total) as f32).collect()
        } else {
            (0..=n).map(|i| i as f32 / n as f32).collect()
        };
        let mut d = Distribution1D { func, cdf, integral: (total / n as f64) as f32, guide: Vec::new() };
        let slices = n.min(MAX_SLICES);
        d.guide = (0..=slices).map(|k| d.search(k as f32 / slices as f32) as u32).collect();
        d
    }

    /// The bin whose cdf interval holds `u`: the last edge at or below `u`, skipping empty
    /// bins (which have equal edges), by binary search over the whole table.
    fn search(&self, u: f32) -> usize {
        self.cdf.partition_point(|&c| c <= u).saturating_sub(1).min(self.func.len() - 1)
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.func.len()
    }

    /// Whether there are no bins (never: construction refuses it).
    pub fn is_empty(&self) -> bool {
        self.func.is_empty()
    }

    /// The integral of the step function over [0, 1] (the mean weight).
    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Draws with the uniform number `u` in [0, 1).
    pub fn sample(&self, u: f32) -> Sample1D {
        let n = self.func.len();
        let index = if (0.0..1.0).contains(&u) {
            // u * slices rounds to slice k only for u within a slice of [k, k + 1) / slices
            // (fewer than 2^22 slices), and the guide's bounds k / slices round by less
            // than one: the bins of slices k - 1 and k + 2 bound the answer, and
            // `search`'s answer is `lo` plus the edges past it at or below `u`.
            let slices = self.guide.len() - 1;
            let k = ((u * slices as f32) as usize).min(slices - 1);
            let (lo, hi) =
                (self.guide[k.saturating_sub(1)] as usize, self.guide[(k + 2).min(slices)] as usize);
            lo + self.cdf[lo + 1..=hi].partition_point(|&c| c <= u)
        } else {
            self.search(u)
        };
        let (lo, hi) = (self.cdf[index], self.cdf[index + 1]);
        let remapped =
            if hi > lo { ((u - lo) / (hi - lo)).clamp(0.0, 1.0 - f32::EPSILON / 2.0) } else { 0.5 };
        Sample1D { index, x: (index as f32 + remapped) / n as f32, remapped }
    }

    /// The probability of picking item `index` (discrete use).
    pub fn pmf(&self, index: usize) -> f32 {
        self.cdf[index + 1] - self.cdf[index]
    }

    /// The density at a point of bin `index` (continuous use over [0, 1)).
    pub fn pdf(&self, index: usize) -> f32 {
        self.pmf(index) * self.func.len() as f32
    }
}

/// A piecewise-constant density over [0, 1)² on a `width × height` grid, row `v` the
/// second coordinate: p(u, v) = p(v) p(u | v).
#[derive(Debug, Clone)]
pub struct Distribution2D {
    /// One distribution over the columns of each row.
    conditional: Vec<Distribution1D>,
    /// The distribution over rows, by each row's integral.
    marginal: Distribution1D,
}

impl Distribution2D {
    /// The distribution proportional to `func`, row-major with `width` columns.
    pub fn new(func: &[f32], width: usize, height: usize) -> Distribution2D {
        assert!(width > 0 && height > 0 && func.len() == width * height, "a grid of width × height weights");
        let conditional: Vec<Distribution1D> = func.chunks_exact(width).map(Distribution1D::new).collect();
        let rows: Vec<f32> = conditional.iter().map(Distribution1D::integral).collect();
        Distribution2D { conditional, marginal: Distribution1D::new(&rows) }
    }

    /// Draws a point of [0, 1)² with the uniform pair `u`; returns it with its density.
    pub fn sample(&self, u: Vec2) -> (Vec2, f32) {
        let row = self.marginal.sample(u.y);
        let col = self.conditional[row.index].sample(u.x);
        (Vec2::new(col.x, row.x), self.marginal.pdf(row.index) * self.conditional[row.index].pdf(col.index))
    }

    /// The density at `p` in [0, 1)².
    pub fn pdf(&self, p: Vec2) -> f32 {
        let (w, h) = (self.conditional[0].len(), self.marginal.len());
        let col = ((p.x * w as f32) as usize).min(w - 1);
        let row = ((p.y * h as f32) as usize).min(h - 1);
        self.marginal.pdf(row) * self.conditional[row].pdf(col)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn picks_in_proportion_to_the_weights() {
        let d = Distribution1D::new(&[1.0, 0.0, 3.0]);
        assert_eq!(d.pmf(0), 0.25);
        assert_eq!(d.pmf(1), 0.0);
        assert_eq!(d.pmf(2), 0.75);
        assert!((d.integral() - 4.0 / 3.0).abs() < 1e-6);
        // u below a quarter picks the first, anything above the third: never the empty one.
        assert_eq!(d.sample(0.0).index, 0);
        assert_eq!(d.sample(0.2499).index, 0);
        assert_eq!(d.sample(0.25).index, 2);
        assert_eq!(d.sample(0.999_999).index, 2);
        // The remapped number is uniform within the bin.
        let s = d.sample(0.625);
        assert!((s.remapped - 0.5).abs() < 1e-6 && (s.x - 2.5 / 3.0).abs() < 1e-6, "{s:?}");
        let n = 10_000;
        let mut counts = [0usize; 3];
        for i in 0..n {
            counts[d.sample((i as f32 + 0.5) / n as f32).index] += 1;
        }
        assert_eq!(counts, [2500, 0, 7500]);
    }

    /// The guided search finds the bin the search over the whole table finds (and so the
    /// same `x` and `remapped`), on distributions with runs of empty bins, spikes a
    /// billion times their neighbours, single bins and equal ones, at every cdf edge, every slice's
    /// bounds and their neighbouring floats, and outside [0, 1).
    #[test]
    fn the_guide_finds_what_the_whole_search_finds() {
        use crate::render::sampler::hash_words;
        let unit = |w: &[u64]| (hash_words(w) >> 40) as f32 / (1u64 << 24) as f32;
        let mut checked = 0;
        for seed in 0..60u64 {
            let n = 1 + (hash_words(&[seed, 1]) % 700) as usize;
            // Every third distribution uniform: its cdf edges are the slices' bounds, where
            // a number just below an edge may still round into the slice above it.
            let uniform = seed % 3 == 0;
            let func: Vec<f32> = (0..n as u64)
                .map(|i| match hash_words(&[seed, i, 2]) % 6 {
                    _ if uniform => 1.0,
                    0 | 1 => 0.0,
                    2 => 1e9 * unit(&[seed, i, 3]),
                    _ => unit(&[seed, i, 4]),
                })
                .collect();
            let d = Distribution1D::new(&func);
            let slices = d.guide.len() - 1;
            let mut us: Vec<f32> = d.cdf.clone();
            us.extend((0..=slices).map(|k| k as f32 / slices as f32));
            us.extend((0..400u64).map(|j| unit(&[seed, j, 5])));
            let near: Vec<f32> = us.iter().flat_map(|&u| [u.next_down(), u, u.next_up()]).collect();
            for u in
                near.into_iter().chain([-0.0, -1.0, 1.0, 2.0, f32::NAN, f32::INFINITY, 1.0f32.next_down()])
            {
                let want = d.search(u);
                let got = d.sample(u);
                assert_eq!(got.index, want, "seed {seed}, n {n}, u {u}");
                checked += 1;
            }
        }
        assert!(checked > 100_000, "{checked}");
    }

    #[test]
    fn all_zero_weights_fall_back_to_uniform() {
        let d = Distribution1D::new(&[0.0, f32::NAN, -1.0, 0.0]);
        assert_eq!(d.integral(), 0.0);
        assert_eq!((0..4).map(|i| d.pmf(i)).collect::<Vec<_>>(), vec![0.25; 4]);
        assert_eq!(d.sample(0.6).index, 2);
    }

    #[test]
    fn the_2d_density_integrates_to_one_and_matches_its_samples() {
        let (w, h) = (5, 4);
        let func: Vec<f32> = (0..w * h).map(|i| ((i * 7) % 5) as f32 + 0.5 * (i % 3) as f32).collect();
        let d = Distribution2D::new(&func, w, h);
        let total: f32 = func.iter().sum();
        let mut integral = 0.0;
        for y in 0..h {
            for x in 0..w {
                let p = d.pdf(Vec2::new((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32));
                // The density is the weight over the mean weight.
                let want = func[y * w + x] / (total / (w * h) as f32);
                assert!((p - want).abs() < 1e-4, "texel ({x}, {y}): {p} != {want}");
                integral += p / (w * h) as f32;
            }
        }
        assert!((integral - 1.0).abs() < 1e-5, "{integral}");
        // A sample's own density is the density at the point it lands on.
        for i in 0..97 {
            let u = Vec2::new((i as f32 * 0.618_034) % 1.0, (i as f32 + 0.5) / 97.0);
            let (p, pdf) = d.sample(u);
            assert!(p.cmpge(Vec2::ZERO).all() && p.cmplt(Vec2::ONE).all(), "{p}");
            assert!((pdf - d.pdf(p)).abs() < 1e-4 * pdf.max(1.0), "{pdf} vs {}", d.pdf(p));
            assert!(pdf > 0.0);
        }
    }
}
