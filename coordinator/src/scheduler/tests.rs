//! The queue driven by fake completions: batch sizes, coverage, leases, duplicates,
//! restore.

use super::*;

/// Any token: these tests are about the queue, not fencing.
const TOKEN: LeaseToken = LeaseToken([7; 16]);

fn drain(q: &mut PassQueue, now: Instant) -> Vec<BatchSpec> {
    let mut out = Vec::new();
    while let Some(l) = q.lease_next(WorkerId(1), TOKEN, now) {
        out.push(l.spec.clone());
    }
    out
}

#[test]
fn batches_cover_both_passes_exactly_once() {
    let now = Instant::now();
    for (w, h, spp) in [(1, 1, 1), (7, 5, 1), (33, 17, 4), (100, 80, 16), (1, 300, 3)] {
        let mut q = PassQueue::new(w, h, spp);
        let batches = drain(&mut q, now);
        let mut samples = vec![0u32; (w * h) as usize];
        for b in &batches {
            for quad in &b.quads {
                samples[(quad.y * w + quad.x) as usize] += b.samples.end - b.samples.start;
            }
            q.complete(b.id, now).unwrap();
        }
        assert!(samples.iter().all(|&s| s == spp), "{w}x{h}@{spp}");
        assert!(q.is_finished());
        assert_eq!(q.samples_done(), q.samples_total());
        // Pass two never starts before pass one is fully cut, and ids follow the walk.
        let passes: Vec<Pass> = batches.iter().map(|b| b.pass).collect();
        assert!(passes.windows(2).all(|p| p[0] <= p[1]));
        assert!(batches.windows(2).all(|b| b[0].id < b[1].id));
    }
}

/// The merge of the last batch finishes the job even when nobody asks for more work
/// after the last lease (a hang found with one worker on a tiny image).
#[test]
fn last_result_finishes_without_another_lease() {
    let now = Instant::now();
    for (w, h, spp) in [(1, 1, 1), (48, 30, 4), (7, 5, 1), (16, 16, 2)] {
        let mut counting = PassQueue::new(w, h, spp);
        let n = drain(&mut counting, now).len();
        let mut q = PassQueue::new(w, h, spp);
        let ids: Vec<BatchId> =
            (0..n).map(|_| q.lease_next(WorkerId(1), TOKEN, now).unwrap().spec.id).collect();
        for id in ids {
            assert!(!q.is_finished());
            q.complete(id, now).unwrap();
        }
        assert!(q.is_finished(), "{w}x{h}@{spp}: all batches merged but not finished");
    }
}

#[test]
fn pass_one_batches_grow_from_small_to_max() {
    let mut q = PassQueue::new(256, 256, 1);
    let sizes: Vec<usize> = drain(&mut q, Instant::now()).iter().map(|b| b.quads.len()).collect();
    assert_eq!(sizes[0], PASS_ONE_FIRST);
    assert_eq!(sizes[1], PASS_ONE_FIRST * 2);
    assert!(sizes.iter().all(|&s| s <= PASS_ONE_MAX));
    assert!(sizes.contains(&PASS_ONE_MAX));
}

/// Exactly-once: a batch computed twice (a retry after its worker went silent) is
/// merged once; the second result is refused.
#[test]
fn duplicate_results_are_refused() {
    let now = Instant::now();
    let mut q = PassQueue::new(16, 16, 1);
    let first = q.lease_next(WorkerId(1), TOKEN, now).unwrap().spec.id;
    assert_eq!(q.take_back_worker(WorkerId(1), false), vec![first]);
    let again = q.lease_next(WorkerId(2), TOKEN, now).unwrap();
    assert_eq!((again.spec.id, again.attempt), (first, 2));
    // The silent worker's late result arrives first and wins...
    assert!(q.complete(first, now).is_ok());
    // ...and the retry's result is a duplicate.
    assert_eq!(q.complete(first, now), Err(CompleteError::NotOutstanding { batch: first }));
}

#[test]
fn taken_back_batches_are_leased_again_oldest_first() {
    let now = Instant::now();
    let mut q = PassQueue::new(64, 64, 1);
    let a = q.lease_next(WorkerId(1), TOKEN, now).unwrap().spec.id;
    let b = q.lease_next(WorkerId(2), TOKEN, now).unwrap().spec.id;
    let c = q.lease_next(WorkerId(1), TOKEN, now).unwrap().spec.id;
    q.take_back_worker(WorkerId(1), false);
    assert_eq!(q.lease_next(WorkerId(3), TOKEN, now).unwrap().spec.id, a);
    assert_eq!(q.lease_next(WorkerId(3), TOKEN, now).unwrap().spec.id, c);
    assert!(q.lease(b).is_some());
    // A result for a batch waiting in the retry queue is still accepted once.
    let d = q.lease_next(WorkerId(4), TOKEN, now).unwrap().spec.id;
    q.take_back(d);
    assert!(q.complete(d, now).is_ok());
    assert_ne!(q.lease_next(WorkerId(4), TOKEN, now).unwrap().spec.id, d);
}

/// Stragglers: at the end of the last pass an idle worker gets a duplicate of the
/// oldest lease that has run long; the first result wins, the second is refused.
#[test]
fn stragglers_get_speculative_duplicates_at_the_end() {
    let t0 = Instant::now();
    let ms = Duration::from_millis;
    let mut q = PassQueue::new(8, 8, 1);
    let first = q.lease_next(WorkerId(1), TOKEN, t0).unwrap().spec.id;
    // Not at the end of the pass: no duplicates while there is new work.
    assert!(q.lease_speculative(WorkerId(2), TOKEN, t0 + ms(5000), 2, ms(100)).is_none());
    let mut rest = Vec::new();
    while let Some(l) = q.lease_next(WorkerId(2), TOKEN, t0) {
        rest.push(l.spec.id);
    }
    for id in &rest {
        q.complete(*id, t0 + ms(10)).unwrap();
    }
    assert!(q.all_leased());
    // Mean batch time 10 ms, patience 2: the straggler qualifies after 20 ms, but
    // never before `min_age`; and never as a duplicate for its own holder.
    assert!(q.lease_speculative(WorkerId(2), TOKEN, t0 + ms(50), 2, ms(100)).is_none());
    assert!(q.lease_speculative(WorkerId(1), TOKEN, t0 + ms(500), 2, ms(100)).is_none());
    let spare = q.lease_speculative(WorkerId(2), TOKEN, t0 + ms(500), 2, ms(100)).unwrap();
    assert_eq!((spare.spec.id, spare.attempt), (first, 2));
    // One duplicate per batch.
    assert!(q.lease_speculative(WorkerId(3), TOKEN, t0 + ms(600), 2, ms(100)).is_none());
    assert_eq!(q.leased_by(WorkerId(2)), 1);
    assert!(q.complete(first, t0 + ms(510)).is_ok());
    assert_eq!(q.complete(first, t0 + ms(900)), Err(CompleteError::NotOutstanding { batch: first }));
    assert!(q.is_finished());
    assert_eq!(q.leased_by(WorkerId(2)), 0);
}

/// A straggler's holder leaving hands the batch to its duplicate, not to the retry
/// queue; the duplicate's holder leaving leaves the original lease alone.
#[test]
fn a_duplicate_takes_over_when_its_original_is_taken_back() {
    let t0 = Instant::now();
    let mut q = PassQueue::new(4, 4, 1);
    let id = q.lease_next(WorkerId(1), TOKEN, t0).unwrap().spec.id;
    assert!(q.lease_next(WorkerId(1), TOKEN, t0).is_none());
    q.lease_speculative(WorkerId(2), TOKEN, t0 + Duration::from_secs(1), 2, Duration::ZERO).unwrap();
    q.take_back_worker(WorkerId(3), false);
    assert_eq!(q.take_back_worker(WorkerId(1), false), vec![id]);
    assert_eq!(q.lease(id).unwrap().worker, WorkerId(2));
    assert!(q.lease_next(WorkerId(4), TOKEN, t0).is_none(), "nothing went back to the retry queue");
    q.lease_speculative(WorkerId(4), TOKEN, t0 + Duration::from_secs(2), 2, Duration::ZERO).unwrap();
    assert!(q.take_back_worker(WorkerId(4), false).is_empty());
    assert_eq!(q.lease(id).unwrap().worker, WorkerId(2));
    q.complete(id, t0).unwrap();
    assert!(q.is_finished());
}

/// A queue rebuilt from its `Completed` set hands out exactly the batches that were
/// not merged, with the same ids and pixels, and the merged counts carry over.
#[test]
fn restore_resumes_exactly_the_unmerged_batches() {
    let now = Instant::now();
    for (w, h, spp, keep) in [(33, 17, 4, 7usize), (64, 64, 1, 3), (20, 9, 3, 0), (5, 5, 2, 1000)] {
        let mut full = PassQueue::new(w, h, spp);
        let all = drain(&mut full, now);
        let mut q = PassQueue::new(w, h, spp);
        let leased: Vec<BatchSpec> = (0..keep.min(all.len()))
            .map(|_| q.lease_next(WorkerId(1), TOKEN, now).unwrap().spec.clone())
            .collect();
        // Merge out of order: every other batch, so there are gaps.
        for b in leased.iter().step_by(2) {
            q.complete(b.id, now).unwrap();
        }
        let done = q.completed();
        let mut r = PassQueue::restore(w, h, spp, &done).unwrap();
        assert_eq!(r.samples_done(), q.samples_done(), "{w}x{h}@{spp}");
        assert_eq!(r.pass_one_pixels_done(), q.pass_one_pixels_done());
        assert_eq!(r.completed(), done);
        let mut rest = drain(&mut r, now);
        rest.sort_by_key(|b| b.id);
        let expect: Vec<BatchSpec> =
            all.iter().filter(|b| !leased.iter().step_by(2).any(|l| l.id == b.id)).cloned().collect();
        assert_eq!(rest, expect, "{w}x{h}@{spp}");
        for b in &rest {
            r.complete(b.id, now).unwrap();
        }
        assert!(r.is_finished());
        assert_eq!(r.samples_done(), r.samples_total());
        assert_eq!((r.completed().below, r.completed().above), (all.len() as u64, vec![]));
    }
}

#[test]
fn restore_refuses_batches_the_job_does_not_have() {
    let done = Completed { below: 0, above: vec![5, 100_000], sizes: vec![] };
    assert!(matches!(PassQueue::restore(8, 8, 2, &done), Err(RestoreError::NoSuchBatch { id: 100_000, .. })));
    let unordered = Completed { below: 3, above: vec![2], sizes: vec![] };
    assert!(matches!(PassQueue::restore(8, 8, 2, &unordered), Err(RestoreError::Unordered { .. })));
    for pixels in [0, PASS_TWO_MAX_PIXELS as u32 + 1] {
        let bad = Completed { below: 0, above: vec![], sizes: vec![3, pixels] };
        assert_eq!(PassQueue::restore(8, 8, 2, &bad).unwrap_err(), RestoreError::BatchSize { pixels });
    }
}

/// Pass two's batches are as large as the worker's pace asks (in samples, so pixels ×
/// (spp − 1)), the fixed `PASS_TWO_SAMPLES` without one, within 1..=`PASS_TWO_MAX_PIXELS`;
/// pass one's sizes ignore the pace.
#[test]
fn pass_two_batches_follow_the_pace() {
    let now = Instant::now();
    let mut q = PassQueue::new(256, 256, 9);
    let fast = Pace { samples: Some(8 * 1000), threads: 0 };
    let mut first = Vec::new();
    while q.pass() == Pass::One {
        first.push(q.lease_paced(WorkerId(1), TOKEN, now, fast).unwrap().spec.quads.len());
    }
    let mut fixed = PassQueue::new(256, 256, 9);
    let fixed_sizes: Vec<usize> = drain(&mut fixed, now).iter().map(|b| b.quads.len()).collect();
    // The lease that moved the cut to pass two was still pass one's, and cut alike.
    assert_eq!(first[..], fixed_sizes[..first.len()]);
    assert_eq!(q.lease_paced(WorkerId(1), TOKEN, now, fast).unwrap().spec.quads.len(), 1000);
    let slow = Pace { samples: Some(8 * 3), threads: 0 };
    assert_eq!(q.lease_paced(WorkerId(2), TOKEN, now, slow).unwrap().spec.quads.len(), 3);
    let crawl = Pace { samples: Some(1), threads: 0 };
    assert_eq!(q.lease_paced(WorkerId(2), TOKEN, now, crawl).unwrap().spec.quads.len(), 1);
    let unmeasured = q.lease_paced(WorkerId(3), TOKEN, now, Pace::default()).unwrap();
    assert_eq!(unmeasured.spec.quads.len() as u64, PASS_TWO_SAMPLES / 8);
    let huge = Pace { samples: Some(u64::MAX), threads: 0 };
    assert_eq!(q.lease_paced(WorkerId(1), TOKEN, now, huge).unwrap().spec.quads.len(), PASS_TWO_MAX_PIXELS);
    assert_eq!(q.completed().sizes, vec![1000, 3, 1, 4096, PASS_TWO_MAX_PIXELS as u32]);
}

/// With the farm's thread count known, the end of pass two is shared out: no batch is
/// more than half a thread's share of the pixels left, or the floor, whichever is more;
/// every pixel still gets exactly its samples.
#[test]
fn the_end_of_pass_two_is_shared_among_the_threads() {
    let now = Instant::now();
    let (w, h, spp) = (200u32, 150u32, 5u32);
    let mut q = PassQueue::new(w, h, spp);
    let pace = Pace { samples: Some(4 * 8192), threads: 2 };
    let floor = (PASS_TWO_FLOOR_SAMPLES / 4) as usize;
    let mut left = (w * h) as usize;
    let mut sizes = Vec::new();
    let mut samples = vec![0u32; left];
    while let Some(l) = q.lease_paced(WorkerId(1), TOKEN, now, pace) {
        let b = l.spec.clone();
        for p in &b.quads {
            samples[(p.y * w + p.x) as usize] += b.samples.end - b.samples.start;
        }
        if b.pass == Pass::Two {
            assert!(b.quads.len() <= left.div_ceil(4).max(floor).min(8192), "{} of {left}", b.quads.len());
            left -= b.quads.len();
            sizes.push(b.quads.len());
        }
        q.complete(b.id, now).unwrap();
    }
    assert!(samples.iter().all(|&s| s == spp));
    assert!(q.is_finished());
    assert_eq!(sizes[0], (w * h) as usize / 4, "the first batch is a quarter of the pass");
    assert!(sizes.windows(2).all(|s| s[0] >= s[1]), "{sizes:?}");
    assert!(sizes[..sizes.len() - 1].iter().all(|&s| s >= floor), "{sizes:?}");
}

/// Restored from a checkpoint taken mid-pass-two, a queue whose pass-two sizes followed
/// different paces cuts the batches up to the last merged one exactly as before (ids,
/// pixels), and the rest at any pace covers every pixel exactly once more.
#[test]
fn restore_replays_the_paced_sizes() {
    let now = Instant::now();
    let (w, h, spp) = (90u32, 70u32, 6u32);
    let paces = [Some(5 * 700), Some(5 * 37), None, Some(5 * 3000), Some(1)];
    let mut q = PassQueue::new(w, h, spp);
    let mut leased = Vec::new();
    for k in 0.. {
        let pace = Pace { samples: paces[k % paces.len()], threads: 0 };
        let Some(l) = q.lease_paced(WorkerId(1), TOKEN, now, pace) else { break };
        leased.push(l.spec.clone());
        if leased.len() == 40 {
            break;
        }
    }
    assert!(leased.last().unwrap().pass == Pass::Two);
    let merged: Vec<&BatchSpec> = leased.iter().step_by(3).collect();
    for b in &merged {
        q.complete(b.id, now).unwrap();
    }
    let done = q.completed();
    let mut r = PassQueue::restore(w, h, spp, &done).unwrap();
    assert_eq!(r.samples_done(), q.samples_done());
    let mut samples = vec![0u32; (w * h) as usize];
    for b in &merged {
        for p in &b.quads {
            samples[(p.y * w + p.x) as usize] += b.samples.end - b.samples.start;
        }
    }
    let end = done.end();
    while let Some(l) = r.lease_paced(WorkerId(2), TOKEN, now, Pace { samples: Some(5 * 111), threads: 0 }) {
        let b = l.spec.clone();
        if b.id.0 < end {
            assert_eq!(Some(&b), leased.iter().find(|o| o.id == b.id), "batch {} cut anew", b.id.0);
        }
        for p in &b.quads {
            samples[(p.y * w + p.x) as usize] += b.samples.end - b.samples.start;
        }
        r.complete(b.id, now).unwrap();
    }
    assert!(samples.iter().all(|&s| s == spp));
    assert!(r.is_finished());
    assert_eq!(r.samples_done(), r.samples_total());
}

/// A sequence's frames, stacked: every frame's pass one is cut before any frame's pass
/// two, frames in order within each pass; no batch spans two frames; every pixel of every
/// frame gets exactly spp samples; each frame's own figures add up.
#[test]
fn a_sequence_cuts_every_frame_s_pass_one_before_any_pass_two() {
    let now = Instant::now();
    for (w, h, frames, spp) in [(7, 5, 3, 4), (16, 16, 2, 2), (33, 17, 4, 1), (1, 1, 5, 3)] {
        let mut q = PassQueue::sequence(w, h, frames, spp);
        assert_eq!(q.samples_total(), u64::from(w * h * frames * spp));
        let batches = drain(&mut q, now);
        let mut samples = vec![0u32; (w * h * frames) as usize];
        let mut order = Vec::new();
        for b in &batches {
            let frame = b.quads[0].y / h;
            assert!(b.quads.iter().all(|p| p.y / h == frame), "{w}x{h}x{frames}: a batch spans frames");
            for p in &b.quads {
                samples[(p.y * w + p.x) as usize] += b.samples.end - b.samples.start;
            }
            order.push((b.pass, frame));
            q.complete(b.id, now).unwrap();
        }
        assert!(samples.iter().all(|&s| s == spp), "{w}x{h}x{frames}@{spp}");
        assert!(order.windows(2).all(|o| o[0] <= o[1]), "{w}x{h}x{frames}: {order:?}");
        assert_eq!(q.frames_done().len(), frames as usize);
        for &(pass_one, done) in q.frames_done() {
            assert_eq!((pass_one, done), (u64::from(w * h), u64::from(w * h * spp)));
        }
        assert!(q.is_finished());
    }
}

/// A sequence taken up from its merged batches hands out exactly the rest, with each
/// frame's figures as they were.
#[test]
fn a_restored_sequence_resumes_exactly_the_unmerged_batches() {
    let now = Instant::now();
    let (w, h, frames, spp) = (12, 9, 3, 4);
    let mut q = PassQueue::sequence(w, h, frames, spp);
    let all = drain(&mut q, now);
    for b in all.iter().step_by(3).take(all.len() / 2) {
        q.complete(b.id, now).unwrap();
    }
    let mut r = PassQueue::restore_sequence(w, h, frames, spp, &q.completed()).unwrap();
    assert_eq!(r.frames_done(), q.frames_done());
    assert_eq!(r.samples_done(), q.samples_done());
    for b in drain(&mut r, now) {
        r.complete(b.id, now).unwrap();
    }
    assert!(r.is_finished());
    assert_eq!(r.samples_done(), r.samples_total());
}
