//! The framebuffer's tests: merge order, snapshots, deltas, resets and sizes.

use super::*;
use crate::quadtree::Walk;

fn one(v: f32) -> u64 {
    fixed::to_fixed(v).unwrap()
}

#[test]
fn merge_order_does_not_change_the_bits() {
    let quads: Vec<Quad> = Walk::new(4, 4).collect();
    let sums_a: Vec<u64> = (0..48).map(|i| one(0.1 * i as f32 + 0.013)).collect();
    let sums_b: Vec<u64> = (0..48).map(|i| one(1.7 / (i as f32 + 1.0))).collect();
    let mut ab = Framebuffer::new(4, 4);
    ab.merge(&quads, 1, &sums_a, None).unwrap();
    ab.merge(&quads, 1, &sums_b, None).unwrap();
    let mut ba = Framebuffer::new(4, 4);
    ba.merge(&quads, 1, &sums_b, None).unwrap();
    ba.merge(&quads, 1, &sums_a, None).unwrap();
    let bits = |f: &Framebuffer| f.resolve().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&ab), bits(&ba));
}

/// A replica fed the changes of every version resolves to the same bits.
#[test]
fn replica_from_changes_resolves_identically() {
    let quads: Vec<Quad> = Walk::new(9, 7).collect();
    let mut fb = Framebuffer::new(9, 7);
    let mut replica = Framebuffer::new(9, 7);
    let mut sent = 0;
    for (k, chunk) in quads.chunks(5).enumerate() {
        let sums: Vec<u64> = (0..chunk.len() * 3).map(|i| one((i + k) as f32 * 0.01)).collect();
        fb.merge(chunk, 1, &sums, None).unwrap();
        if k % 3 == 0 {
            for px in fb.changes(sent, 4) {
                assert!(px.len() <= 4);
                px.iter().for_each(|p| assert!(replica.set(p)));
            }
            sent = fb.version();
            let bits = |f: &Framebuffer| f.resolve().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&replica), bits(&fb));
        }
    }
}

#[test]
fn bad_results_are_refused_without_change() {
    let quads: Vec<Quad> = Walk::new(2, 2).collect();
    let mut fb = Framebuffer::new(2, 2);
    assert!(matches!(fb.merge(&quads, 1, &[0; 5], None), Err(MergeError::WrongLength { .. })));
    let mut sums = vec![0; 12];
    sums[4] = u64::MAX;
    assert!(matches!(fb.merge(&quads, 1, &sums, None), Err(MergeError::OutOfRange { .. })));
    assert!(fb.mean(0, 0).is_none());
}

/// An early image shows the mosaic, not black with a few dots.
#[test]
fn mosaic_fills_the_frame_from_the_first_pixel() {
    let mut fb = Framebuffer::new(8, 8);
    let root = Walk::new(8, 8).next().unwrap();
    fb.merge(&[root], 1, &[one(0.5), one(0.25), one(1.0)], None).unwrap();
    let img = fb.resolve();
    assert!(img.chunks(3).all(|p| p == [0.5, 0.25, 1.0]));
}

fn px(x: u32, y: u32) -> Quad {
    Quad { x, y, w: 1, h: 1 }
}

/// A clone is a snapshot: merges after it change the original only, and only the
/// tiles they touch are copied (so a snapshot under the farm's lock is cheap).
#[test]
fn a_clone_is_a_snapshot() {
    let mut fb = Framebuffer::new(200, 130);
    fb.merge(&[px(3, 4)], 1, &[one(0.5); 3], None).unwrap();
    let snap = fb.clone();
    fb.merge(&[px(3, 4), px(199, 129)], 1, &[one(0.25); 6], None).unwrap();
    assert_eq!(snap.count(3, 4), 1);
    assert_eq!(snap.count(199, 129), 0);
    assert_eq!(fb.count(3, 4), 2);
    assert_eq!(fb.count(199, 129), 1);
    let shared = fb.tiles.iter().zip(&snap.tiles).filter(|(a, b)| Arc::ptr_eq(a, b)).count();
    assert_eq!(shared, fb.tiles.len() - 2, "only the two touched tiles were copied");
}

/// Accumulators in pixel-index order survive the trip through a checkpoint, for a
/// size that is not a multiple of the tile, with even sums.
#[test]
fn accumulators_round_trip_in_pixel_order() {
    let (w, h) = (131, 67);
    let mut fb = Framebuffer::with_even(w, h);
    let quads: Vec<Quad> = (0..w * h).step_by(7).map(|i| px(i % w, i / w)).collect();
    let sums: Vec<u64> = (0..quads.len() * 3).map(|i| i as u64).collect();
    let even: Vec<u64> = (0..quads.len()).map(|i| i as u64 / 2).collect();
    fb.merge(&quads, 2, &sums, Some(&even)).unwrap();
    let (s, c) = fb.accumulators();
    assert_eq!(c[(7 * 5) as usize], 2);
    assert_eq!(s[7][0], 3);
    let back = Framebuffer::from_accumulators(w, h, s, c, fb.even()).unwrap();
    assert_eq!(back, fb);
    assert_eq!(back.resolve(), fb.resolve());
}

/// A delta scans only what changed since the version asked for, and holds exactly the
/// pixels changed after it.
#[test]
fn changes_hold_exactly_the_pixels_changed_since() {
    let mut fb = Framebuffer::new(300, 200);
    fb.merge(&[px(0, 0), px(299, 199)], 1, &[one(1.0); 6], None).unwrap();
    let since = fb.version();
    fb.merge(&[px(150, 100), px(151, 100)], 1, &[one(1.0); 6], None).unwrap();
    let got: Vec<u32> = fb.changes(since, 1).flatten().map(|p| p.index).collect();
    assert_eq!(got, vec![100 * 300 + 150, 100 * 300 + 151]);
    assert_eq!(fb.changes(fb.version(), 10).count(), 0);
    assert_eq!(fb.changes(0, 3).flatten().count(), 4);
}

/// Even sums are required exactly when the framebuffer keeps them.
/// Invariant: a reset pixel, merged again, holds the bits it would have had without
/// the merge that was undone (how a liar's pixels are repaired), and viewers see it.
#[test]
fn a_reset_pixel_merged_again_has_the_bits_of_a_clean_one() {
    let q = [px(1, 2), px(3, 0)];
    let mut clean = Framebuffer::with_even(4, 4);
    clean.merge(&q, 2, &[5, 6, 7, 8, 9, 10], Some(&[3, 4])).unwrap();
    let mut fb = Framebuffer::with_even(4, 4);
    fb.merge(&q, 2, &[50, 60, 70, 8, 9, 10], Some(&[30, 4])).unwrap();
    let before = fb.version();
    fb.reset(1, 2);
    assert_eq!(fb.count(1, 2), 0);
    assert_eq!(fb.changes(before, 100).flatten().map(|p| p.index).collect::<Vec<_>>(), vec![2 * 4 + 1]);
    fb.merge(&q[..1], 2, &[5, 6, 7], Some(&[3])).unwrap();
    assert_eq!(fb, clean);
    fb.reset(9, 9); // outside: nothing, no panic
    assert_eq!(fb, clean);
}

#[test]
fn even_sums_are_checked_when_kept() {
    let mut fb = Framebuffer::with_even(2, 1);
    let q = [px(0, 0), px(1, 0)];
    assert!(matches!(fb.merge(&q, 1, &[0; 6], None), Err(MergeError::EvenLength { .. })));
    assert!(matches!(fb.merge(&q, 1, &[0; 6], Some(&[u64::MAX, 0])), Err(MergeError::OutOfRange { .. })));
    fb.merge(&q, 1, &[0; 6], Some(&[0, 0])).unwrap();
    Framebuffer::new(2, 1).merge(&q, 1, &[0; 6], None).unwrap();
}

#[test]
fn bytes_for_counts_every_accumulator() {
    // 36 bytes a pixel, 44 with even sums, plus the tiles' overhead (a byte a pixel).
    let plain = Framebuffer::bytes_for(1920, 1080, false);
    let even = Framebuffer::bytes_for(1920, 1080, true);
    assert_eq!(even - plain, 1920 * 1080 * 8);
    assert!((1920 * 1080 * 36..1920 * 1080 * 38).contains(&plain), "{plain}");
    let fb = Framebuffer::with_even(40, 33);
    let held: usize = fb
        .tiles
        .iter()
        .map(|t| t.sums.len() * 24 + t.counts.len() * 4 + t.even.len() * 8 + t.versions.len() * 8)
        .sum();
    assert!(Framebuffer::bytes_for(40, 33, true) >= held as u64);
}
