//! The metrics of a served coordinator after events over the real streams: results
//! merged through the work stream are timed, the leases of a worker that left or fell
//! silent (taken back by the reaper) are re-leases, a viewer is counted while its watch
//! stream is open.

use std::time::{Duration, Instant};

use tessera_coordinator::Timing;
use tessera_harness::{FakeViewer, FakeWorker, Harness};

/// The value of the sample `name` (with its labels as written) in `text`.
fn sample(text: &str, name: &str) -> Option<f64> {
    text.lines().find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
}

/// Polls the metrics until `done` holds of them; panics after 10 s.
async fn until(h: &Harness, what: &str, done: impl Fn(&str) -> bool) -> String {
    let start = Instant::now();
    loop {
        let text = h.service().metrics_text();
        if done(&text) {
            return text;
        }
        assert!(start.elapsed() < Duration::from_secs(10), "{what}: not within 10 s:\n{text}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stream_events_show_in_the_metrics() {
    let timing = Timing {
        heartbeat: Duration::from_millis(100),
        silence_timeout: Duration::from_millis(300),
        ..Default::default()
    };
    let h = Harness::start_with(timing).await.unwrap();
    let job = h.submit_small(32, 32, 4).await.unwrap();
    let _viewer = FakeViewer::watch(&h.channel(), job.0, 0.0, false).await.unwrap();
    until(&h, "a viewer", |t| sample(t, "tessera_viewers") == Some(1.0)).await;

    let mut w = FakeWorker::connect(&h.channel(), "answers", 2).await.unwrap();
    let batch = w.next_batch().await.unwrap();
    w.answer(&batch).await.unwrap();
    // A scrape takes the census, then reads the timings: one taken as a merge lands can
    // show the merge's timing and not yet its samples, so wait for both.
    let t = until(&h, "a merge", |t| {
        sample(t, "tessera_merge_seconds_count") == Some(1.0)
            && sample(t, "tessera_samples_merged_total").is_some_and(|n| n > 0.0)
    })
    .await;
    let merged = u64::from(batch.sample_end - batch.sample_start) * (batch.pixels.len() as u64 / 2);
    assert_eq!(sample(&t, "tessera_samples_merged_total"), Some(merged as f64), "{t}");

    // It holds two leases (its credit of two, one more with its answer); it leaves.
    drop(w);
    until(&h, "re-leases of a worker gone", |t| {
        sample(t, "tessera_leases_taken_back_total{reason=\"disconnected\"}") == Some(2.0)
    })
    .await;

    // Held, never driven again: the reaper takes its two leases back as re-leases.
    let mut frozen = FakeWorker::connect(&h.channel(), "frozen", 2).await.unwrap();
    frozen.next_batch().await.unwrap();
    frozen.next_batch().await.unwrap();
    let t = until(&h, "re-leases", |t| {
        sample(t, "tessera_leases_taken_back_total{reason=\"silent\"}") == Some(2.0)
    })
    .await;
    assert_eq!(sample(&t, "tessera_workers{state=\"silent\"}"), Some(1.0), "{t}");
    drop(frozen);
}
