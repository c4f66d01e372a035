//! The coordinator's Prometheus metrics (`docs/metrics.md`). Two kinds:
//!
//! - figures of state (jobs by state, samples queued, workers, leases, viewers) and the
//!   farm's event counts (strikes, audits, leases taken back, duplicates) come from a
//!   `Census` taken under the farm's lock at each scrape, so they can never drift from
//!   what the farm holds;
//! - timings (a merge under the lock, a checkpoint write), checkpoint failures and the
//!   scenes sent to workers are recorded where they happen, into the instruments of
//!   `Metrics`.
//!
//! A scrape is not a transaction: it takes the census, then reads the timings, so a
//! scrape taken as a result merges can show the merge's timing without its samples.
//!
//! The text is the Prometheus exposition format 0.0.4 (`CONTENT_TYPE`), which every
//! Prometheus and `promtool check metrics` read.

use std::time::Duration;

use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric};
use prometheus_client::metrics::counter::{ConstCounter, Counter};
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::Registry;

use crate::farm::{Census, JOB_STATES};

/// The `Content-Type` of `Metrics::exposition`'s text.
pub const CONTENT_TYPE: &str = prometheus_client::encoding::prometheus_text::CONTENT_TYPE;

/// The instruments updated where their events happen; cheap to clone (shared counters).
#[derive(Debug, Clone)]
pub struct Metrics {
    merge: Histogram,
    checkpoint_write: Histogram,
    checkpoint_failures: Counter,
    /// Jobs' scenes sent to workers with their bundle, and the bundles' bytes.
    scenes_whole: Counter,
    scene_bytes: Counter,
    /// Jobs' scenes sent by their hash alone (the worker held the scene).
    scenes_by_hash: Counter,
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics {
            // 2 µs to 2 s by fours: a merge of a small batch takes microseconds, and one
            // of milliseconds already holds every other caller of the lock up.
            merge: Histogram::new(exponential_buckets(2e-6, 4.0, 11)),
            // 1 ms to 16 s by fours: a checkpoint is the size of its framebuffer.
            checkpoint_write: Histogram::new(exponential_buckets(1e-3, 4.0, 8)),
            checkpoint_failures: Counter::default(),
            scenes_whole: Counter::default(),
            scene_bytes: Counter::default(),
            scenes_by_hash: Counter::default(),
        }
    }
}

impl Metrics {
    /// A result merged (or compared, for an audit) in `took`, under the farm's lock.
    pub fn observe_merge(&self, took: Duration) {
        self.merge.observe(took.as_secs_f64());
    }

    /// A checkpoint encoded and written in `took`; `ok` false if the write failed.
    pub fn observe_checkpoint(&self, took: Duration, ok: bool) {
        if ok {
            self.checkpoint_write.observe(took.as_secs_f64());
        } else {
            self.checkpoint_failures.inc();
        }
    }

    /// A job's scene sent to a worker: with its bundle of `bytes` (encoded), or by its hash
    /// alone (`None`: the worker held it).
    pub fn observe_scene_sent(&self, bytes: Option<u64>) {
        match bytes {
            Some(b) => {
                self.scenes_whole.inc();
                self.scene_bytes.inc_by(b);
            }
            None => {
                self.scenes_by_hash.inc();
            }
        }
    }

    /// The exposition text of the farm as `census` saw it, with `viewers` watch streams
    /// open, and of these instruments.
    pub fn exposition(&self, census: Census, viewers: usize) -> String {
        let mut state = Registry::default();
        state.register_collector(Box::new(Scrape { census, viewers: viewers as u64 }));
        state.register_collector(Box::new(SceneSends {
            whole: self.scenes_whole.get(),
            by_hash: self.scenes_by_hash.get(),
            bytes: self.scene_bytes.get(),
        }));
        let mut registry = Registry::default();
        registry.register(
            "tessera_merge_seconds",
            "Time to check and merge one worker result (or compare an audit's) under the farm's lock",
            self.merge.clone(),
        );
        registry.register(
            "tessera_checkpoint_write_seconds",
            "Time to encode and write one job's checkpoint to the data directory",
            self.checkpoint_write.clone(),
        );
        registry.register(
            "tessera_checkpoint_failures",
            "Checkpoint writes that failed (the job goes on; the next tick tries again)",
            self.checkpoint_failures.clone(),
        );
        let mut text = String::new();
        // Writing into a String cannot fail, and every name and label here is fixed.
        for r in [&state, &registry] {
            prometheus_client::encoding::prometheus_text::encode(&mut text, r)
                .expect("encoding metrics into a String");
        }
        text
    }
}

/// The figures of one scrape.
#[derive(Debug)]
struct Scrape {
    census: Census,
    viewers: u64,
}

/// Writes one metric family: `name` of `kind`, one sample per label set.
fn family<M: EncodeMetric>(
    encoder: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    kind: MetricType,
    samples: &[(&[(&str, &str)], M)],
) -> Result<(), std::fmt::Error> {
    let mut m = encoder.encode_descriptor(name, help, None, kind)?;
    for (labels, value) in samples {
        value.encode(m.encode_family(labels)?)?;
    }
    Ok(())
}

fn gauge(encoder: &mut DescriptorEncoder, name: &str, help: &str, v: u64) -> Result<(), std::fmt::Error> {
    family(encoder, name, help, MetricType::Gauge, &[(&[], ConstGauge::new(v as i64))])
}

fn counter(encoder: &mut DescriptorEncoder, name: &str, help: &str, v: u64) -> Result<(), std::fmt::Error> {
    family(encoder, name, help, MetricType::Counter, &[(&[], ConstCounter::new(v))])
}

impl Collector for Scrape {
    fn encode(&self, mut e: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let c = &self.census;
        let g = |v: u64| ConstGauge::new(v as i64);
        let protocol = (tessera_proto::v1::ProtocolVersion::Current as i32).to_string();
        let build: &[(&str, &str)] = &[
            ("version", env!("CARGO_PKG_VERSION")),
            ("renderer", tessera_description::RENDERER_VERSION),
            ("protocol", &protocol),
        ];
        family(
            &mut e,
            "tessera_build_info",
            "The coordinator's build: always 1.",
            MetricType::Gauge,
            &[(build, g(1))],
        )?;
        let states: Vec<[(&str, &str); 1]> = JOB_STATES.iter().map(|s| [("state", *s)]).collect();
        let jobs: Vec<(&[(&str, &str)], _)> =
            states.iter().zip(c.jobs).map(|(l, n)| (l.as_slice(), g(n))).collect();
        family(&mut e, "tessera_jobs", "Jobs held, by state.", MetricType::Gauge, &jobs)?;
        gauge(
            &mut e,
            "tessera_samples_queued",
            "Samples not rendered yet of queued and running jobs: the work waiting for workers (scale workers on it).",
            c.samples_queued,
        )?;
        family(
            &mut e,
            "tessera_samples_per_second",
            "Samples merged per second over the running jobs' last few seconds.",
            MetricType::Gauge,
            &[(&[], ConstGauge::new(c.samples_per_second))],
        )?;
        counter(
            &mut e,
            "tessera_samples_merged",
            "Samples merged into framebuffers (rate() of it is the farm's throughput).",
            c.leases.samples_merged,
        )?;
        let workers: &[(&[(&str, &str)], _)] = &[
            (&[("state", "busy")], g(c.workers_busy)),
            (&[("state", "idle")], g(c.workers_idle)),
            (&[("state", "silent")], g(c.workers_silent)),
            (&[("state", "quarantined")], g(c.identities_quarantined)),
        ];
        family(
            &mut e,
            "tessera_workers",
            "Connected workers by state (busy: holds leases; silent: its leases were taken back for silence), and quarantined worker identities.",
            MetricType::Gauge,
            workers,
        )?;
        let leases: &[(&[(&str, &str)], _)] = &[
            (&[("kind", "batch")], g(c.leases_batch)),
            (&[("kind", "speculative")], g(c.leases_speculative)),
            (&[("kind", "audit")], g(c.leases_audit)),
            (&[("kind", "repair")], g(c.leases_repair)),
        ];
        family(
            &mut e,
            "tessera_leases_outstanding",
            "Leases out to workers now, by kind.",
            MetricType::Gauge,
            leases,
        )?;
        let taken: &[(&[(&str, &str)], _)] = &[
            (&[("reason", "silent")], ConstCounter::new(c.leases.taken_back_silent)),
            (&[("reason", "disconnected")], ConstCounter::new(c.leases.taken_back_left)),
        ];
        family(
            &mut e,
            "tessera_leases_taken_back",
            "Leases taken back from workers that fell silent or disconnected, to be leased again.",
            MetricType::Counter,
            taken,
        )?;
        counter(
            &mut e,
            "tessera_duplicate_results",
            "Results refused as duplicates (already merged, or a released lease: harmless).",
            c.leases.duplicates,
        )?;
        let f = &c.fence;
        counter(
            &mut e,
            "tessera_audits_begun",
            "Delivered batches chosen to be rendered again elsewhere.",
            f.audits,
        )?;
        let audits: &[(&[(&str, &str)], _)] = &[
            (&[("outcome", "agreed")], ConstCounter::new(f.audits_passed)),
            (&[("outcome", "disagreed")], ConstCounter::new(f.audits_mismatched)),
            (&[("outcome", "decided")], ConstCounter::new(f.audits_decided)),
            (&[("outcome", "skipped")], ConstCounter::new(f.audits_skipped)),
        ];
        family(
            &mut e,
            "tessera_audits",
            "Audits by outcome: agreed (bit for bit), disagreed (a mismatch, a third identity asked), decided (the third named the liar), skipped (no other identity could render it).",
            MetricType::Counter,
            audits,
        )?;
        counter(
            &mut e,
            "tessera_strikes",
            "Strikes given to worker identities (answers without a lease, malformed results).",
            f.strikes,
        )?;
        counter(
            &mut e,
            "tessera_quarantines",
            "Worker identities quarantined (strikes, or caught lying by an audit).",
            f.quarantines,
        )?;
        counter(
            &mut e,
            "tessera_repaired_pixels",
            "Pixels reset and rendered again because a liar had delivered them.",
            f.repaired_pixels,
        )?;
        gauge(
            &mut e,
            "tessera_viewers",
            "Watch streams open (desktop viewers, live web pages).",
            self.viewers,
        )
    }
}

/// The scenes sent to workers, read from their counters at a scrape: one family with the
/// way each was sent as a label, which the registry's plain counters cannot have.
#[derive(Debug)]
struct SceneSends {
    whole: u64,
    by_hash: u64,
    bytes: u64,
}

impl Collector for SceneSends {
    fn encode(&self, mut e: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let sent: &[(&[(&str, &str)], _)] = &[
            (&[("how", "whole")], ConstCounter::new(self.whole)),
            (&[("how", "by_hash")], ConstCounter::new(self.by_hash)),
        ];
        family(
            &mut e,
            "tessera_scenes_sent",
            "Jobs' scenes sent to workers: whole (the scene file and its assets), or by their hash alone to a worker that holds the scene (--preload).",
            MetricType::Counter,
            sent,
        )?;
        counter(
            &mut e,
            "tessera_scene_bytes_sent",
            "Bytes of the scenes sent whole to workers (each worker gets a job's scene once).",
            self.bytes,
        )
    }
}

#[cfg(test)]
mod tests;
