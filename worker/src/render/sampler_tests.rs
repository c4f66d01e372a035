//! The sampler's draws against their definition, hashed from the start (a file of its
//! own: the sampler's tests outgrew it).

use super::sobol::*;
use super::*;

/// The second dimension of Sobol's sequence computed bit by bit from its definition
/// (v₁ = 2³¹, vₖ₊₁ = vₖ ⊕ (vₖ ≫ 1)): the oracle for the direction numbers the sampler
/// derives from the recurrence.
fn sobol_dim1(mut i: u32) -> u32 {
    let (mut v, mut r) = (1u32 << 31, 0u32);
    while i != 0 {
        if i & 1 != 0 {
            r ^= v;
        }
        i >>= 1;
        v ^= v >> 1;
    }
    r
}

/// Owen scrambling of a coordinate in its natural bit order, as the definition states it.
fn owen_scramble(x: u32, key: u32) -> u32 {
    owen_scramble_reversed(x.reverse_bits(), key)
}

/// Sobol's shuffled order as its definition states it: the index as a fraction of as many
/// binary digits as the pattern's rounded-up count has, Owen-scrambled in natural order.
fn nested_order_definition(index: u32, key: u64, spp: u32) -> u32 {
    let bits = spp.next_power_of_two().trailing_zeros();
    if bits == 0 {
        return 0;
    }
    owen_scramble(index << (32 - bits), key as u32) >> (32 - bits)
}

/// The draws of dimension `d` of sample `index` of `pixel`, hashed from the start as
/// the sampler's definition states them (no kept state): the oracle for the kept keys.
fn fresh_2d(kind: SamplerKind, seed: u64, spp: u32, pixel: UVec2, index: u32, d: u32) -> Vec2 {
    let key = hash_words(&[seed, u64::from(pixel.x) | (u64::from(pixel.y) << 32), u64::from(d)]);
    if index >= spp || kind == SamplerKind::Independent {
        let h = hash_words(&[key, u64::from(index)]);
        return Vec2::new(unit_float(h), unit_float(mix64(h)));
    }
    let k = mix64(key);
    if kind == SamplerKind::Sobol {
        let s = nested_order_definition(index, key, spp);
        return Vec2::new(
            fixed_to_unit(owen_scramble(s.reverse_bits(), k as u32)),
            fixed_to_unit(owen_scramble(sobol_dim1(s), (k >> 32) as u32)),
        );
    }
    let s = permute(index, spp, key);
    let (m, rows) = grid(spp);
    let (col, row) = (s % m, s / m);
    let (sx, sy) = (permute(col, m, mix64(k ^ 0x51)), permute(row, rows, mix64(k ^ 0xa3)));
    let (jx, jy) =
        (unit_float(hash_words(&[k, u64::from(s), 1])), unit_float(hash_words(&[k, u64::from(s), 2])));
    let x = (col as f32 + (sy as f32 + jx) / rows as f32) / m as f32;
    let y = (row as f32 + (sx as f32 + jy) / m as f32) / rows as f32;
    Vec2::new(x.min(ONE_MINUS_EPSILON), y.min(ONE_MINUS_EPSILON))
}

/// [`fresh_2d`] for a 1-D draw.
fn fresh_1d(kind: SamplerKind, seed: u64, spp: u32, pixel: UVec2, index: u32, d: u32) -> f32 {
    let key = hash_words(&[seed, u64::from(pixel.x) | (u64::from(pixel.y) << 32), u64::from(d)]);
    if index >= spp || kind == SamplerKind::Independent {
        return unit_float(hash_words(&[key, u64::from(index)]));
    }
    if kind == SamplerKind::Sobol {
        let s = nested_order_definition(index, key, spp);
        return fixed_to_unit(owen_scramble(s.reverse_bits(), mix64(key) as u32));
    }
    let s = permute(index, spp, key);
    let jitter = unit_float(hash_words(&[key, u64::from(s), 3]));
    ((s as f32 + jitter) / spp as f32).min(ONE_MINUS_EPSILON)
}

/// The kept keys change no bit: pixels revisited in and out of turn, samples that draw
/// more or fewer dimensions than the one before (paths end at different depths), 1-D
/// and 2-D draws of one dimension in different samples, skipped dimensions, more
/// dimensions than are kept, indices beyond the pattern, every pattern and sample
/// counts of every shape (grids of powers of two, others, and one with more fine-grid
/// offsets than are kept).
#[test]
fn kept_keys_draw_what_fresh_hashes_draw() {
    let kinds = [SamplerKind::Stratified, SamplerKind::Sobol, SamplerKind::Independent];
    for (kind, spp, seed) in kinds
        .into_iter()
        .flat_map(|k| [(k, 1, 3), (k, 7, 0), (k, 16, 9), (k, 60, 1), (k, 64, 4), (k, 5000, 2)])
    {
        let mut sampler = Sampler::new(kind, seed, spp);
        for step in 0..400u64 {
            let h = hash_words(&[step, u64::from(spp)]);
            // Mostly the same pixel again (as a batch walks its samples), sometimes another.
            let pixel = if h.is_multiple_of(4) {
                UVec2::new((h >> 8) as u32 % 3, (h >> 16) as u32 % 2)
            } else {
                sampler.pixel
            };
            let index = (h >> 24) as u32 % (spp + 3);
            let draws = (h >> 32) as u32 % (KEPT_DIMENSIONS as u32 + 12);
            sampler.start_pixel_sample(pixel, index);
            for d in 0..draws {
                if (h >> ((d + 7) % 48)) & 7 == 0 {
                    // A skipped dimension: the draws after it keep their numbers.
                    assert_eq!(sampler.skip(), 0.0);
                    continue;
                }
                if (h >> (d % 48)) & 1 == 0 {
                    let (got, want) = (sampler.get_2d(), fresh_2d(kind, seed, spp, pixel, index, d));
                    let bits = |v: Vec2| (v.x.to_bits(), v.y.to_bits());
                    assert_eq!(
                        bits(got),
                        bits(want),
                        "{kind:?} spp {spp} {pixel} sample {index} dimension {d}"
                    );
                } else {
                    let want = fresh_1d(kind, seed, spp, pixel, index, d);
                    assert_eq!(
                        sampler.get_1d().to_bits(),
                        want.to_bits(),
                        "{kind:?} spp {spp} {pixel} sample {index} dimension {d}"
                    );
                }
            }
        }
    }
}

/// Every sample of a pixel falls in its own stratum of the m×n grid, for any spp.
#[test]
fn pixel_samples_are_stratified() {
    for spp in [1u32, 4, 9, 16, 7, 10, 64] {
        let mut sampler = Sampler::new(SamplerKind::Stratified, 7, spp);
        let (m, rows) = grid(spp);
        assert_eq!(m * rows, spp);
        let mut cells = std::collections::HashSet::new();
        for i in 0..spp {
            sampler.start_pixel_sample(UVec2::new(3, 4), i);
            let p = sampler.get_2d();
            assert!((0.0..1.0).contains(&p.x) && (0.0..1.0).contains(&p.y));
            let cell = ((p.x * m as f32) as u32, (p.y * rows as f32) as u32);
            assert!(cells.insert(cell), "spp {spp}: two samples in cell {cell:?}");
        }
    }
}

/// A point of Cook's pattern is uniform over the pixel: in whichever coarse cell it is,
/// it falls in each quarter of that cell as often, jointly in x and y, over many pixels'
/// patterns. Columns and rows shuffled by keys that differ in a few low bits failed this
/// (in a 2 × 2 grid, the points of the lower-left and upper-right cells were only ever in
/// their cells' lower-left or upper-right quarters, the others' in the other two), which
/// biased every image at low sample counts: a daylight scene came out 0.5 % too bright
/// at 4 spp, 0.1 % at 16 (docs/speed.md, twenty-ninth part).
#[test]
fn a_point_is_anywhere_in_its_cell() {
    for spp in [4u32, 16, 8, 64, 6] {
        let mut sampler = Sampler::new(SamplerKind::Stratified, 3, spp);
        let (m, rows) = grid(spp);
        // Per cell, the points in each of its quarters.
        let mut quarters = vec![[0u32; 4]; spp as usize];
        let pixels = 4096u32;
        for p in 0..pixels {
            for i in 0..spp {
                sampler.start_pixel_sample(UVec2::new(p % 64, p / 64), i);
                sampler.skip();
                let u = sampler.get_2d();
                let (x, y) = (u.x * m as f32, u.y * rows as f32);
                let cell = x as usize + m as usize * y as usize;
                quarters[cell][usize::from(x % 1.0 >= 0.5) + 2 * usize::from(y % 1.0 >= 0.5)] += 1;
            }
        }
        // A cell holds one point of each pattern: `pixels` points.
        let n = f64::from(pixels);
        for (cell, q) in quarters.iter().enumerate() {
            for (k, &c) in q.iter().enumerate() {
                // Five standard deviations of a fair count.
                let f = f64::from(c) / n;
                assert!(
                    (f - 0.25).abs() < 5.0 * (0.1875 / n).sqrt(),
                    "spp {spp}: cell {cell}, quarter {k}: {f:.4}"
                );
            }
        }
    }
}

/// Revisiting (pixel, i) after other pixels gives identical values: the property that
/// makes reassignment and resume correct.
#[test]
fn samples_are_pure_functions_of_pixel_and_index() {
    let mut a = Sampler::new(SamplerKind::Stratified, 1, 16);
    a.start_pixel_sample(UVec2::new(10, 20), 5);
    let first = (a.get_2d(), a.get_1d(), a.get_2d());
    for i in 0..16 {
        a.start_pixel_sample(UVec2::new(i, 2 * i), i);
        a.get_2d();
    }
    a.start_pixel_sample(UVec2::new(10, 20), 5);
    assert_eq!(first, (a.get_2d(), a.get_1d(), a.get_2d()));
}

/// Every region of the pixel gets its share of samples, for any spp: a sample count
/// that is not a square must not leave a corner of the pixel unsampled (a bias found
/// against Mitsuba's Cornell box at 128 spp).
#[test]
fn samples_cover_the_pixel_evenly_for_any_count() {
    for spp in [2u32, 7, 10, 128, 200] {
        let mut sampler = Sampler::new(SamplerKind::Stratified, 11, spp);
        let (mut top, mut right, mut n) = (0u32, 0u32, 0u32);
        for p in 0..256u32 {
            for i in 0..spp {
                sampler.start_pixel_sample(UVec2::new(p % 16, p / 16), i);
                let u = sampler.get_2d();
                top += u32::from(u.y >= 0.8);
                right += u32::from(u.x >= 0.8);
                n += 1;
            }
        }
        for (what, count) in [("top", top), ("right", right)] {
            let f = f64::from(count) / f64::from(n);
            assert!((f - 0.2).abs() < 0.02, "spp {spp}: {what} fifth holds {f:.3} of the samples");
        }
    }
    assert_eq!(grid(128), (8, 16));
    assert_eq!(grid(16), (4, 4));
    assert_eq!(grid(7), (1, 7));
}

#[test]
fn dimensions_are_associated_at_random() {
    // Pixel-area stratum and the next dimension's stratum must not be the same index.
    let spp = 16;
    let mut sampler = Sampler::new(SamplerKind::Stratified, 3, spp);
    let mut same = 0;
    for i in 0..spp {
        sampler.start_pixel_sample(UVec2::new(1, 1), i);
        let a = sampler.get_1d();
        let b = sampler.get_1d();
        if (a * spp as f32) as u32 == (b * spp as f32) as u32 {
            same += 1;
        }
    }
    assert!(same < spp / 2, "{same} of {spp} strata paired identically");
}

/// Sobol at a power-of-two count is a (0, m, 2)-net: every elementary interval of area
/// 1/spp holds exactly one sample, whatever the scrambling key.
#[test]
fn sobol_is_a_net_at_powers_of_two() {
    for k in [2u32, 4, 6] {
        let spp = 1u32 << k;
        for pixel in [UVec2::new(0, 0), UVec2::new(17, 5)] {
            let mut sampler = Sampler::new(SamplerKind::Sobol, 9, spp);
            let pts: Vec<Vec2> = (0..spp)
                .map(|i| {
                    sampler.start_pixel_sample(pixel, i);
                    sampler.get_2d()
                })
                .collect();
            for a in 0..=k {
                let (nx, ny) = (1u32 << a, 1u32 << (k - a));
                let mut cells = std::collections::HashSet::new();
                for p in &pts {
                    assert!((0.0..1.0).contains(&p.x) && (0.0..1.0).contains(&p.y));
                    assert!(
                        cells.insert(((p.x * nx as f32) as u32, (p.y * ny as f32) as u32)),
                        "spp {spp}, {nx}x{ny}"
                    );
                }
            }
        }
    }
}

/// Sobol's pattern drawn in prefixes, as a job in rounds draws it: the first 2^k samples
/// of a pixel, whatever k, are a (0, k, 2)-net in every 2-D dimension but the lens's,
/// each of whose coordinates is stratified, and the film's and lens's four coordinates a
/// net in 4-D as a whole pattern's are (boxes of volume 8/2^k hold eight), for a pattern
/// of a power of two and of another count. A keyed permutation of the order, as the
/// stratified pattern has, fails this from k = 2 on.
#[test]
fn sobol_prefixes_are_nets() {
    for spp in [1u32 << 20, 1_000_000, 4096] {
        for (seed, pixel) in [(9, UVec2::new(0, 0)), (2, UVec2::new(17, 5))] {
            let mut sampler = Sampler::new(SamplerKind::Sobol, seed, spp);
            // Per sample: film and lens, a 1-D draw, then two 2-D draws.
            let draws: Vec<[Vec2; 4]> = (0..1024)
                .map(|i| {
                    sampler.start_pixel_sample(pixel, i);
                    let (film, lens) = sampler.get_4d();
                    sampler.get_1d();
                    [film, lens, sampler.get_2d(), sampler.get_2d()]
                })
                .collect();
            for k in 0..=10u32 {
                let prefix = &draws[..1 << k];
                for (d, name) in [(0, "film"), (1, "lens"), (2, "a 2-D draw"), (3, "the next 2-D draw")] {
                    // The lens's pair (Sobol's third and fourth dimensions) is no (0, 2)
                    // net: each coordinate alone is stratified, and the four together.
                    let splits: Vec<u32> = if d == 1 { vec![0, k] } else { (0..=k).collect() };
                    for a in splits {
                        let cells: std::collections::HashSet<_> = prefix
                            .iter()
                            .map(|p| {
                                (
                                    (p[d].x * (1u32 << a) as f32) as u32,
                                    (p[d].y * (1u32 << (k - a)) as f32) as u32,
                                )
                            })
                            .collect();
                        assert_eq!(cells.len(), 1 << k, "spp {spp}: {name}, prefix 2^{k}, {a}");
                    }
                }
                if k < 3 {
                    continue;
                }
                let t = k - 3;
                for l0 in 0..=t {
                    for l1 in 0..=t - l0 {
                        for l2 in 0..=t - l0 - l1 {
                            let levels = [l0, l1, l2, t - l0 - l1 - l2];
                            let mut count = std::collections::HashMap::new();
                            for p in prefix {
                                let c = [p[0].x, p[0].y, p[1].x, p[1].y];
                                let cell: Vec<u32> =
                                    (0..4).map(|j| (c[j] * (1u32 << levels[j]) as f32) as u32).collect();
                                *count.entry(cell).or_insert(0u32) += 1;
                            }
                            assert!(
                                count.values().all(|&n| n == 8),
                                "spp {spp}: prefix 2^{k}, 4-D box {levels:?}"
                            );
                        }
                    }
                }
            }
        }
    }
    // The largest count a sampler may be handed (no job's; the farm caps them at 2^20).
    let mut huge = Sampler::new(SamplerKind::Sobol, 1, u32::MAX);
    huge.start_pixel_sample(UVec2::ZERO, u32::MAX - 1);
    let (film, _) = huge.get_4d();
    assert!((0.0..1.0).contains(&film.x) && (0.0..1.0).contains(&huge.get_2d().y));
    // The stratified pattern's order: its prefixes are not nets.
    let mut sampler = Sampler::new(SamplerKind::Stratified, 9, 1 << 20);
    let cells: std::collections::HashSet<_> = (0..16)
        .map(|i| {
            sampler.start_pixel_sample(UVec2::ZERO, i);
            let p = sampler.get_2d();
            ((p.x * 4.0) as u32, (p.y * 4.0) as u32)
        })
        .collect();
    assert!(cells.len() < 16, "{cells:?}");
}

/// Independent samples are uniform (a coarse histogram) and, like every pattern, a pure
/// function of (seed, pixel, index).
#[test]
fn independent_samples_are_uniform_and_repeatable() {
    let mut s = Sampler::new(SamplerKind::Independent, 5, 4096);
    let mut bins = [0u32; 8];
    for i in 0..4096 {
        s.start_pixel_sample(UVec2::new(2, 3), i);
        let v = s.get_2d();
        bins[(v.x * 8.0) as usize] += 1;
        s.start_pixel_sample(UVec2::new(2, 3), i);
        assert_eq!(s.get_2d(), v);
    }
    assert!(bins.iter().all(|&b| (412..=612).contains(&b)), "{bins:?}");
    assert_eq!(SamplerKind::from_name("sobol"), Some(SamplerKind::Sobol));
    assert_eq!(SamplerKind::from_name("halton"), None);
}

/// The direction numbers from the recurrence give the second dimension that
/// `sobol_dim1` computes bit by bit, and the third and fourth dimensions start as Joe and
/// Kuo's table does (their first points by the index's bits, worked by hand).
#[test]
fn sobol_directions_follow_the_recurrence() {
    // Every index of 16 bits, and indices spread over all 32.
    let indices = (0..1u32 << 16).chain((0..1u32 << 16).map(|k| k.wrapping_mul(0x9e37_79b9)));
    for i in indices {
        assert_eq!(sobol_reversed(i, &SOBOL_BYTES[0]), sobol_dim1(i).reverse_bits(), "point {i}");
        // By bytes, a point is the sum of the directions of the index's bits.
        for (d, directions) in [SOBOL_DIM1, SOBOL_DIM2, SOBOL_DIM3].iter().enumerate() {
            let sum = (0..32).filter(|&k| i >> k & 1 == 1).fold(0, |r, k| r ^ directions[k]);
            assert_eq!(sobol_reversed(i, &SOBOL_BYTES[d]), sum, "dimension {d}, point {i}");
        }
    }
    let unit = |i: u32, d: &ByBytes| f64::from(sobol_reversed(i, d).reverse_bits()) / 4_294_967_296.0;
    let third: Vec<f64> = (0..8).map(|i| unit(i, &SOBOL_BYTES[1])).collect();
    let fourth: Vec<f64> = (0..8).map(|i| unit(i, &SOBOL_BYTES[2])).collect();
    assert_eq!(third, [0.0, 0.5, 0.75, 0.25, 0.375, 0.875, 0.625, 0.125]);
    assert_eq!(fourth, [0.0, 0.5, 0.75, 0.25, 0.125, 0.625, 0.875, 0.375]);
}

/// The camera's film and lens draws at a power-of-two count: the film a (0, m, 2)-net,
/// every coordinate one sample per 1/spp interval, and the four together a net in 4-D
/// (every elementary box of volume 8/spp holds eight samples, as the quality t = 3 of
/// Sobol's first four dimensions promises), whatever the seed and pixel, for both patterns
/// that take it, at counts up to 2^13; independent samples and other counts draw what two
/// 2-D draws draw.
#[test]
fn film_and_lens_are_one_net_in_four_dimensions() {
    for kind in [SamplerKind::Stratified, SamplerKind::Sobol] {
        for k in [4u32, 6, 8, 13] {
            let spp = 1u32 << k;
            for (seed, pixel) in [(9, UVec2::new(0, 0)), (2, UVec2::new(17, 5))] {
                let mut sampler = Sampler::new(kind, seed, spp);
                let pts: Vec<[f32; 4]> = (0..spp)
                    .map(|i| {
                        sampler.start_pixel_sample(pixel, i);
                        let (f, l) = sampler.get_4d();
                        assert_eq!(sampler.dimensions_used(), 2);
                        [f.x, f.y, l.x, l.y]
                    })
                    .collect();
                let boxes = |levels: [u32; 4]| {
                    let mut count = std::collections::HashMap::new();
                    for p in &pts {
                        let cell: Vec<u32> =
                            (0..4).map(|c| (f64::from(p[c]) * f64::from(1u32 << levels[c])) as u32).collect();
                        *count.entry(cell).or_insert(0u32) += 1;
                    }
                    count
                };
                for a in 0..=k {
                    let film = boxes([a, k - a, 0, 0]);
                    assert!(film.len() == spp as usize, "{kind:?} spp {spp}: film {a}");
                }
                for c in 0..4 {
                    let mut levels = [0; 4];
                    levels[c] = k;
                    assert_eq!(boxes(levels).len(), spp as usize, "{kind:?} spp {spp}: coordinate {c}");
                }
                // Every split of 2^(k-3) into four coordinates' levels.
                let t = k - 3;
                for l0 in 0..=t {
                    for l1 in 0..=t - l0 {
                        for l2 in 0..=t - l0 - l1 {
                            let levels = [l0, l1, l2, t - l0 - l1 - l2];
                            let count = boxes(levels);
                            assert!(
                                count.len() == (spp / 8) as usize && count.values().all(|&n| n == 8),
                                "{kind:?} spp {spp}: box {levels:?}"
                            );
                        }
                    }
                }
            }
        }
    }
    for (kind, spp) in [(SamplerKind::Independent, 64), (SamplerKind::Stratified, 48)] {
        let (mut joint, mut apart) = (Sampler::new(kind, 3, spp), Sampler::new(kind, 3, spp));
        for i in [0, 5, spp - 1, spp + 2] {
            joint.start_pixel_sample(UVec2::new(4, 1), i);
            apart.start_pixel_sample(UVec2::new(4, 1), i);
            assert_eq!(joint.get_4d(), (apart.get_2d(), apart.get_2d()), "{kind:?} spp {spp} index {i}");
            assert_eq!(joint.get_1d(), apart.get_1d());
        }
    }
}

/// Whether `pts` (2^k of them) are a (0, k, 2)-net: one in each elementary interval of
/// every shape of area 2^-k.
fn is_net(pts: &[Vec2]) -> bool {
    let k = pts.len().trailing_zeros();
    assert_eq!(pts.len(), 1 << k);
    (0..=k).all(|a| {
        let (nx, ny) = (1u32 << a, 1u32 << (k - a));
        let mut cells = std::collections::HashSet::new();
        pts.iter().all(|p| {
            (0.0..1.0).contains(&p.x)
                && (0.0..1.0).contains(&p.y)
                && cells.insert(((p.x * nx as f32) as u32, (p.y * ny as f32) as u32))
        })
    })
}

/// A set drawn at one sample (`each_2d_of_set`: a diffuse lobe's several rays) is a net
/// of its own at a power-of-two count, and a pixel's sets are together a net of `spp ·
/// count` points, for Cook's pattern and Sobol's; a set takes one dimension, so the
/// draws after it keep their numbers, and it is a pure function of (pixel, sample), as
/// every draw is. Beyond the pattern and for independent samples the points are plain
/// random numbers, still the same at every call. Four rays drawn from four dimensions of
/// Cook's pattern instead (the first version) were a net at none of 16 samples: each
/// dimension is stratified over the pixel's samples, not among one sample's rays.
#[test]
fn a_sample_s_set_is_a_net_and_a_pixel_s_sets_are_one() {
    let pixel = UVec2::new(7, 3);
    for kind in [SamplerKind::Stratified, SamplerKind::Sobol] {
        for (spp, count) in [(16u32, 4u32), (64, 8), (4, 64), (1, 16)] {
            let mut sampler = Sampler::new(kind, 5, spp);
            let mut all = Vec::new();
            for index in (0..spp).rev() {
                sampler.start_pixel_sample(pixel, index);
                sampler.get_2d();
                let mut set = Vec::new();
                sampler.each_2d_of_set(count, |u| set.push(u));
                assert!(is_net(&set), "{kind:?} spp {spp}: sample {index}'s {count} points");
                assert_eq!(sampler.dimensions_used(), 2);
                let after = sampler.get_2d();
                sampler.start_pixel_sample(pixel, index);
                sampler.get_2d();
                sampler.each_2d_of_set(count, |_| {});
                assert_eq!(sampler.get_2d(), after, "the draw after a set");
                all.extend(set);
            }
            assert!(is_net(&all), "{kind:?} spp {spp}: the pixel's {} points", all.len());
        }
    }
    for (kind, index) in [(SamplerKind::Independent, 0), (SamplerKind::Stratified, 16)] {
        let mut sampler = Sampler::new(kind, 5, 16);
        let draw = |sampler: &mut Sampler| {
            sampler.start_pixel_sample(pixel, index);
            let mut set = Vec::new();
            sampler.each_2d_of_set(8, |u| set.push(u));
            set
        };
        let set = draw(&mut sampler);
        assert_eq!(draw(&mut sampler), set);
        assert!(set.iter().all(|p| (0.0..1.0).contains(&p.x) && (0.0..1.0).contains(&p.y)));
        assert_eq!(set.iter().map(|p| p.x.to_bits()).collect::<std::collections::HashSet<_>>().len(), 8);
    }
}
