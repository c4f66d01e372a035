//! The work stream: one task per worker, handing out scenes and batches while the worker
//! has credit, and taking its results, failures and heartbeats. Every batch carries its
//! lease's token; an answer counts only from its holder with that token (the farm checks),
//! anything else is a strike, and a quarantined identity is disconnected and refused.

use std::time::Instant;

use tessera_description::ids::{BatchId, JobId, WorkerId};
use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_message::Msg as Out;
use tessera_proto::v1::worker_message::Msg as In;
use tokio::sync::mpsc;
use tonic::{Status, Streaming};
use tracing::{debug, info, warn};

use tessera_proto::convert;

use super::CoordinatorService;
use crate::farm::{AuditPolicy, BatchFailure, BatchResult, Farm, FenceCounters, ResultError, Standing};

/// The most batches a worker may ask to hold at once; bounds the coordinator's lease table.
pub const MAX_CREDIT: u32 = 256;

/// Why a Hello's `held_scenes` is refused, if it is: too many, or one that is not a content
/// hash (so could never name a job's scene).
fn held_scenes_problem(held: &[String]) -> Option<String> {
    use super::limits::{is_scene_hash, MAX_HELD_SCENES};
    if held.len() > MAX_HELD_SCENES {
        return Some(format!(
            "the worker says it holds {} scenes, more than the limit of {MAX_HELD_SCENES}",
            held.len()
        ));
    }
    let (k, bad) = held.iter().enumerate().find(|(_, h)| !is_scene_hash(h))?;
    Some(format!(
        "held scene {k} is not a content hash (64 lower-case hex digits): {}",
        tessera_description::bounds::quoted(bad)
    ))
}

impl CoordinatorService {
    /// Feeds one worker stream until it ends.
    pub(super) async fn serve_worker(
        self,
        mut inbound: Streaming<pb::WorkerMessage>,
        tx: mpsc::Sender<Result<pb::CoordinatorMessage, Status>>,
        identity: impl FnOnce(&str) -> String,
    ) {
        let refuse =
            |reason: String| pb::CoordinatorMessage { msg: Some(Out::Refused(pb::Refused { reason })) };
        // A stream that never says Hello holds its buffers no longer than a silent worker.
        let first = tokio::time::timeout(self.timing.silence_timeout, inbound.message()).await;
        let Ok(first) = first else {
            debug!("worker stream sent no Hello within {:?}; closed", self.timing.silence_timeout);
            return;
        };
        let mut hello = match first {
            Ok(Some(pb::WorkerMessage { msg: Some(In::Hello(h)) })) => h,
            Ok(_) => {
                let _ =
                    tx.send(Ok(refuse("the first message of a worker stream must be Hello".into()))).await;
                return;
            }
            Err(e) => {
                debug!("worker stream failed before Hello: {e}");
                return;
            }
        };
        // Names travel in every Status: bounded, and never echoed whole.
        if hello.name.len() > tessera_description::limits::MAX_NAME_BYTES {
            let reason = format!(
                "the worker's name is {} bytes, more than the limit of {}",
                hello.name.len(),
                tessera_description::limits::MAX_NAME_BYTES
            );
            warn!("{reason}");
            let _ = tx.send(Ok(refuse(reason))).await;
            return;
        }
        if hello.protocol_version != pb::ProtocolVersion::Current as i32 {
            let reason = format!(
                "protocol version {} is not supported; this coordinator speaks version {}",
                hello.protocol_version,
                pb::ProtocolVersion::Current as i32
            );
            warn!(name = %hello.name, "{reason}");
            let _ = tx.send(Ok(refuse(reason))).await;
            return;
        }
        if hello.renderer_version != tessera_description::RENDERER_VERSION {
            let reason = format!(
                "worker runs renderer {}, coordinator {}: images would not be bit-identical; run the same tessera build everywhere",
                tessera_description::bounds::quoted(&hello.renderer_version),
                tessera_description::RENDERER_VERSION
            );
            warn!(name = %hello.name, "{reason}");
            let _ = tx.send(Ok(refuse(reason))).await;
            return;
        }
        if let Some(reason) = held_scenes_problem(&hello.held_scenes) {
            warn!(name = %hello.name, "{reason}");
            let _ = tx.send(Ok(refuse(reason))).await;
            return;
        }
        // Scenes this worker read itself: their jobs' scenes go to it by hash alone.
        let held: std::collections::HashSet<String> =
            std::mem::take(&mut hello.held_scenes).into_iter().collect();
        let threads = hello.threads.clamp(1, 4096);
        let identity = identity(&hello.name);
        let joined = self.farm().add_worker_as(identity.clone(), hello.name.clone(), threads, Instant::now());
        let id = match joined {
            Ok(id) => {
                self.farm().set_renders_frames(id, hello.frames);
                id
            }
            Err(reason) => {
                warn!(%identity, "{reason}; refused");
                let _ = tx.send(Ok(refuse(reason))).await;
                return;
            }
        };
        info!(worker = %id, name = %hello.name, %identity, threads, "worker joined");
        let welcome =
            pb::Welcome { worker_id: id.0, heartbeat_interval_ms: self.timing.heartbeat.as_millis() as u32 };
        if tx.send(Ok(pb::CoordinatorMessage { msg: Some(Out::Welcome(welcome)) })).await.is_err() {
            self.farm().remove_worker(id, Instant::now());
            return;
        }
        let mut credit = hello.credit.min(MAX_CREDIT);
        let mut changed = self.subscribe();
        let mut stop = self.shutting_down();
        let end = loop {
            // Quarantined by its own answer or by another connection's (an audit, strikes).
            let quarantined = self.farm().quarantined(id).map(str::to_owned);
            if let Some(why) = quarantined {
                warn!(worker = %id, %identity, "quarantined: {why}; disconnecting it");
                let _ = tx.send(Ok(refuse(format!("worker {identity} is quarantined: {why}")))).await;
                break "quarantined";
            }
            // Hand out work while the worker wants it and there is some.
            while credit > 0 {
                let Some(a) = self.farm().assign(id, Instant::now()) else { break };
                credit -= 1;
                if a.speculative {
                    info!(worker = %id, job = %a.job, batch = %a.batch.id, attempt = a.attempt, "speculative duplicate of a straggler's batch");
                }
                if let Some((bundle, hash, settings)) = a.scene {
                    let bundle = if held.contains(&hash) {
                        debug!(worker = %id, job = %a.job, "the worker holds the job's scene: sent by its hash");
                        None
                    } else {
                        Some(convert::bundle_to_wire(&bundle))
                    };
                    self.metrics
                        .observe_scene_sent(bundle.as_ref().map(|b| prost::Message::encoded_len(b) as u64));
                    let scene = pb::JobScene {
                        job_id: a.job.0,
                        scene_hash: hash,
                        bundle,
                        settings: Some(convert::settings_to_wire(&settings)),
                    };
                    if tx.send(Ok(pb::CoordinatorMessage { msg: Some(Out::Scene(scene)) })).await.is_err() {
                        break;
                    }
                }
                let pixels = a.batch.quads.iter().flat_map(|q| [q.x, q.y - a.frame_row]).collect();
                let batch = pb::Batch {
                    job_id: a.job.0,
                    batch_id: a.batch.id.0,
                    attempt: a.attempt,
                    scene_hash: a.scene_hash,
                    pass: a.batch.pass.number(),
                    sample_start: a.batch.samples.start,
                    sample_end: a.batch.samples.end,
                    pixels,
                    even_sums: a.even_sums,
                    lease: a.token.0.to_vec(),
                    aovs: a.aovs,
                    frame: a.frame,
                };
                if tx.send(Ok(pb::CoordinatorMessage { msg: Some(Out::Batch(batch)) })).await.is_err() {
                    break;
                }
            }
            tokio::select! {
                msg = inbound.message() => match msg {
                    Ok(Some(m)) => {
                        self.farm().touch(id, Instant::now());
                        match self.handle(id, m, &mut credit) {
                            Ok(()) => {}
                            Err(reason) => {
                                warn!(worker = %id, "{reason}; disconnecting it");
                                let _ = tx.send(Ok(refuse(reason))).await;
                                break "refused";
                            }
                        }
                    }
                    Ok(None) => break "closed",
                    Err(e) => { debug!(worker = %id, "stream error: {e}"); break "lost" }
                },
                r = changed.changed() => if r.is_err() { break "shutdown" },
                _ = stop.changed() => break "shutdown",
                _ = tx.closed() => break "lost",
            }
        };
        let n = self.farm().remove_worker(id, Instant::now());
        info!(worker = %id, batches_taken_back = n, "worker left ({end})");
        self.notify();
    }

    /// Applies one worker message; `Err` is a reason to disconnect the worker.
    fn handle(&self, id: WorkerId, m: pb::WorkerMessage, credit: &mut u32) -> Result<(), String> {
        let heartbeat = matches!(m.msg, Some(In::Heartbeat(_)));
        let before = self.farm().fence_counters();
        let outcome = self.apply(id, m, credit);
        let after = self.farm().fence_counters();
        if after.liars > before.liars || after.quarantines > before.quarantines {
            for (identity, s) in self.farm().standings().iter().filter(|(_, s)| s.quarantined.is_some()) {
                debug!(%identity, strikes = s.strikes, "quarantined identity");
            }
            warn!(
                liars = after.liars,
                quarantines = after.quarantines,
                repaired_pixels = after.repaired_pixels,
                "a worker identity was quarantined; what it delivered is being rendered again"
            );
        }
        if after.audits_mismatched > before.audits_mismatched {
            warn!(worker = %id, "an audit found sums that differ between two workers; a third decides");
        }
        if !heartbeat {
            self.notify();
        }
        outcome
    }

    fn apply(&self, id: WorkerId, m: pb::WorkerMessage, credit: &mut u32) -> Result<(), String> {
        match m.msg {
            Some(In::Results(r)) => {
                // More answers in one message than the protocol allows are not a worker's:
                // refused whole, not walked one strike at a time.
                if r.results.len() > tessera_proto::MAX_RESULTS_PER_MESSAGE {
                    return Err(format!(
                        "{} results in one message, more than the {} the protocol allows",
                        r.results.len(),
                        tessera_proto::MAX_RESULTS_PER_MESSAGE
                    ));
                }
                let now = Instant::now();
                for res in r.results {
                    let (job, batch) = (JobId(res.job_id), BatchId(res.batch_id));
                    // Even sums count only for jobs that keep them; the farm knows which.
                    let result = BatchResult {
                        job,
                        batch,
                        sums: &res.sums,
                        even: Some(&res.even_sums),
                        aov: &res.aov_sums,
                        nonfinite: res.nonfinite_samples,
                        attempt: res.attempt,
                        lease: &res.lease,
                        render: std::time::Duration::from_micros(res.render_micros),
                    };
                    let done = self.merge(id, &result, now);
                    match done {
                        Ok(()) => {}
                        Err(ResultError::Duplicate(e)) => {
                            debug!(worker = %id, %job, "dropped duplicate: {e}")
                        }
                        Err(ResultError::UnknownJob(j)) => debug!(worker = %id, "result for unknown {j}"),
                        Err(e @ ResultError::Forged { .. }) => {
                            warn!(worker = %id, "strike: {e}");
                            // Struck out: the rest of the message is not heard.
                            if let Some(why) = self.farm().quarantined(id).map(str::to_owned) {
                                return Err(format!("quarantined: {why}"));
                            }
                        }
                        Err(ResultError::NotConnected) => return Err("not a connected worker".into()),
                        Err(e @ (ResultError::Malformed { .. } | ResultError::Invalid { .. })) => {
                            return Err(format!("malformed result: {e}"));
                        }
                    }
                }
                *credit = credit.saturating_add(r.credit).min(MAX_CREDIT);
                Ok(())
            }
            // Heartbeats name no leases: they only keep the worker's leases from expiring.
            Some(In::Heartbeat(_)) => Ok(()),
            Some(In::Failed(mut f)) => {
                // The error is logged, kept in the job's state and shown in every Status:
                // bounded (a worker may send megabytes), cut at a character boundary.
                if f.error.len() > super::limits::MAX_WORKER_ERROR_BYTES {
                    let mut end = super::limits::MAX_WORKER_ERROR_BYTES;
                    while !f.error.is_char_boundary(end) {
                        end -= 1;
                    }
                    f.error.truncate(end);
                    f.error.push('…');
                }
                warn!(worker = %id, job = f.job_id, batch = f.batch_id, scene_refused = f.scene_refused, "batch failed: {}", f.error);
                let failure = BatchFailure {
                    job: JobId(f.job_id),
                    batch: BatchId(f.batch_id),
                    attempt: f.attempt,
                    lease: &f.lease,
                    scene_refused: f.scene_refused,
                    error: &f.error,
                };
                if let Err(e) = self.farm().fail_batch(id, &failure, Instant::now()) {
                    warn!(worker = %id, "strike: {e}");
                }
                *credit = credit.saturating_add(f.credit).min(MAX_CREDIT);
                Ok(())
            }
            Some(In::Hello(_)) => Err("Hello sent twice".into()),
            None => Err("empty message".into()),
        }
    }

    /// Sets how often delivered batches are audited (`coordinator --audit-fraction`).
    pub fn set_audit_policy(&self, policy: AuditPolicy) {
        self.farm().set_audit_policy(policy);
    }

    /// The figures of fencing and auditing so far (strikes, quarantines, audits, repairs).
    pub fn fence_counters(&self) -> FenceCounters {
        self.farm().fence_counters()
    }

    /// The standing of a worker identity, if it has strikes or a quarantine.
    pub fn standing(&self, identity: &str) -> Option<Standing> {
        self.farm().standing(identity).cloned()
    }
}

/// The quarantined identities, as Status lists them (after their workers' entries).
pub(super) fn quarantined_to_wire(farm: &Farm) -> impl Iterator<Item = pb::WorkerStatus> + '_ {
    farm.standings().iter().filter_map(|(identity, s)| {
        s.quarantined.as_ref().map(|why| pb::WorkerStatus {
            worker_id: 0,
            name: identity.clone(),
            strikes: s.strikes,
            quarantined: true,
            quarantine_reason: why.clone(),
            ..Default::default()
        })
    })
}
