//! The render threads: batches rendered off the async threads, their results sent back
//! to the connection that asked, batches of a connection that is gone skipped.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use glam::UVec2;
use tessera_proto::v1 as pb;
use tokio::sync::mpsc;

use crate::batch::{render_batch_layers, Sums};
use crate::render::Scene;

/// One batch for the render pool.
pub(super) struct Task {
    pub(super) generation: u64,
    pub(super) scene: Arc<Scene>,
    pub(super) batch: pb::Batch,
    pub(super) pixels: Vec<UVec2>,
    pub(super) reply: mpsc::UnboundedSender<pb::BatchResult>,
}

/// Render threads shared by every connection of the process.
pub(super) struct Pool {
    pub(super) tasks: crossbeam_channel::Sender<Task>,
    pub(super) generation: Arc<AtomicU64>,
}

impl Pool {
    pub(super) fn new(threads: usize) -> Pool {
        let (tasks, rx) = crossbeam_channel::unbounded::<Task>();
        let generation = Arc::new(AtomicU64::new(0));
        for i in 0..threads {
            let rx = rx.clone();
            let current = generation.clone();
            std::thread::Builder::new()
                .name(format!("render-{i}"))
                .spawn(move || {
                    for task in rx {
                        // Batches of a connection that is gone were taken back already.
                        if task.generation != current.load(Ordering::Relaxed) {
                            continue;
                        }
                        let start = Instant::now();
                        let b = &task.batch;
                        let range = b.sample_start..b.sample_end;
                        // Unknown layer bits come from a newer coordinator: the layers this
                        // worker knows are rendered, and the coordinator's check refuses the
                        // result's length rather than this worker guessing.
                        let layout = tessera_film::aov::Layout::from_bits(b.aovs & 7).unwrap_or_default();
                        let sums = render_batch_layers(
                            &task.scene,
                            &task.pixels,
                            range,
                            if b.even_sums { Sums::WithEven } else { Sums::Radiance },
                            layout,
                        );
                        let _ = task.reply.send(pb::BatchResult {
                            job_id: b.job_id,
                            batch_id: b.batch_id,
                            attempt: b.attempt,
                            sums: sums.sums,
                            nonfinite_samples: sums.nonfinite,
                            render_micros: start.elapsed().as_micros() as u64,
                            even_sums: sums.even,
                            lease: b.lease.clone(),
                            aov_sums: sums.aov,
                        });
                    }
                })
                .expect("spawning a render thread");
        }
        Pool { tasks, generation }
    }
}
