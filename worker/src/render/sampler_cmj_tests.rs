//! The keyed permutations' tests: bijections, the same as their definition, and every
//! element sent anywhere as often over keys.

use super::*;
use crate::render::sampler::hash_words;

/// `permute` as it was written before its constants were kept per length, with the turn
/// since added: the oracle for [`Permutation`].
fn permute_reference(i: u32, len: u32, key: u64) -> u32 {
    if len <= 1 {
        return 0;
    }
    let mask = u32::MAX >> (len - 1).leading_zeros();
    let bits = 32 - mask.leading_zeros();
    let (k0, k1) = (key as u32, (key >> 32) as u32);
    let mut x = i;
    loop {
        x ^= k0 & mask;
        x = x.wrapping_mul(0x2c1b_3c6d | 1) & mask;
        x ^= x >> (bits / 2).max(1);
        x = x.wrapping_add(k1) & mask;
        x = x.wrapping_mul(0x297a_2d39 | 1) & mask;
        x ^= x >> (bits / 3).max(1);
        x ^= (k1 >> 7) & mask;
        x = x.wrapping_mul(0x1b87_3593 | 1) & mask;
        x ^= x >> 1;
        if x < len {
            break;
        }
    }
    if len.is_power_of_two() {
        return x;
    }
    let turn = ((mix64(key ^ 0x7e57_7e57) >> 32) * u64::from(len)) >> 32;
    ((u64::from(x) + turn) % u64::from(len)) as u32
}

#[test]
fn kept_permutation_constants_permute_as_before() {
    for len in (1..=70).chain([100, 127, 128, 129, 1000, 1024, 4097, 65_536, 1 << 20]) {
        let p = Permutation::new(len);
        for k in 0..200u64 {
            let key = hash_words(&[k, u64::from(len)]);
            let i = (hash_words(&[key]) % u64::from(len)) as u32;
            assert_eq!(p.apply(i, key), permute_reference(i, len, key), "len {len} i {i} key {key:x}");
        }
    }
}

/// Over keys, every element of `0..len` goes to every place as often: what makes each
/// sample's stratum, and a cell's fine-grid offset, uniform, and so each sample's point
/// uniform over the pixel whatever the sample count. Cycle walking alone failed this at
/// every length that is not a power of two (an element of 0..3 went to 2 in half of all
/// keys, one of 0..7 to 5 and 6 half as often again as elsewhere).
#[test]
fn every_element_goes_anywhere_as_often() {
    let keys = 24_000u32;
    for len in [2u32, 3, 5, 6, 7, 8, 12, 100] {
        let mut counts = vec![0u32; (len * len) as usize];
        for k in 0..keys {
            let key = hash_words(&[u64::from(k), 99]);
            for i in 0..len {
                counts[(i * len + permute(i, len, key)) as usize] += 1;
            }
        }
        let p = 1.0 / f64::from(len);
        let sd = (f64::from(keys) * p * (1.0 - p)).sqrt();
        for (at, &c) in counts.iter().enumerate() {
            let z = (f64::from(c) - f64::from(keys) * p) / sd;
            assert!(
                z.abs() < 5.0,
                "len {len}: {} went to {} {c} times in {keys} keys",
                at as u32 / len,
                at as u32 % len
            );
        }
    }
}

#[test]
fn permute_is_a_bijection() {
    for len in [1u32, 2, 3, 5, 16, 17, 100, 1000] {
        for key in [0u64, 1, 0xdead_beef, u64::MAX] {
            let mut seen = vec![false; len as usize];
            for i in 0..len {
                let p = permute(i, len, key) as usize;
                assert!(!seen[p], "len {len} key {key}: {p} twice");
                seen[p] = true;
            }
        }
    }
}
