//! Submission: a job's way in. The scene is validated and the job made outside the farm's
//! lock, its memory admitted to the budget, and with a data directory its row written
//! before the submitter hears its id.

use std::sync::Arc;
use std::time::Duration;

use tessera_description::bundle::Bundle;
use tessera_description::ids::JobId;
use tessera_description::job::JobSettings;
use tracing::info;

use super::{lock, CoordinatorService};
use crate::farm::{Job, SubmitError};
use crate::persist::StoreError;

/// Test hook: a submitted scene's validation stops this many milliseconds once the scene
/// is read and before the job is admitted, so a test can hold validation open for as long
/// as it needs to watch the farm answer meanwhile (tests/big_submit.rs).
pub const FAULT_STALL_VALIDATION_ENV: &str = "TESSERA_FAULT_STALL_VALIDATION_MS";

/// Why a submission was not queued.
#[derive(Debug, thiserror::Error)]
pub enum SubmitFailure {
    /// The scene or settings are refused.
    #[error(transparent)]
    Invalid(#[from] SubmitError),
    /// The job could not be written to the data directory, so it was not queued.
    #[error("the job could not be stored: {0}")]
    Store(#[from] StoreError),
}

impl CoordinatorService {
    /// Queues a job with no owner (in-process, as `tessera render` does); see
    /// [`CoordinatorService::submit_by`].
    pub async fn submit(
        &self,
        bundle: Bundle,
        settings: JobSettings,
        priority: i32,
    ) -> Result<JobId, SubmitFailure> {
        self.submit_by(bundle, settings, priority, String::new()).await
    }

    /// Queues a job owned by `owner`. With a data directory the job is on disk, owner
    /// included, before this returns. The scene is read and the job made before the farm
    /// is touched.
    pub async fn submit_by(
        &self,
        bundle: Bundle,
        settings: JobSettings,
        priority: i32,
        owner: String,
    ) -> Result<JobId, SubmitFailure> {
        // A huge scene takes seconds to validate: say when it starts, not only when it is queued.
        let bytes = bundle.text.len() + bundle.assets.iter().map(|(_, a)| a.len()).sum::<usize>();
        info!(scene = %bundle.name, bytes, "validating a submitted scene");
        let this = self.clone();
        let stall = std::env::var(FAULT_STALL_VALIDATION_ENV).ok().and_then(|v| v.parse().ok());
        let id = tokio::task::spawn_blocking(move || {
            let name = tessera_description::bounds::quoted(&bundle.name);
            let mut reservation = None;
            let mut job = Job::prepare_within(JobId(0), Arc::new(bundle), settings, priority, &mut |f| {
                // Inside validation (the scene is read, the job not yet made): were the
                // farm's lock held around validation, it would be held through the stall.
                if let Some(ms) = stall {
                    std::thread::sleep(Duration::from_millis(ms));
                }
                reservation = Some(this.budget.admit(&name, f)?);
                Ok(())
            })?;
            job.owner = owner;
            // The store's lock is taken first and held until the job's row is written, so
            // the checkpointer never writes a checkpoint of a job that has no row yet.
            let mut store = this.durable.as_ref().map(|d| lock(&d.store));
            let (id, record) = {
                let mut farm = this.farm();
                let id = farm.insert(job);
                (id, farm.job(id).expect("just inserted").record())
            };
            if let Some(store) = store.as_mut() {
                if let Err(e) = store.add_job(&record) {
                    this.farm().remove_job(id);
                    return Err(SubmitFailure::Store(e));
                }
            }
            if let Some(r) = reservation {
                r.assign(id);
            }
            Ok(id)
        })
        .await
        .map_err(|e| SubmitFailure::Invalid(SubmitError::Internal(e.to_string())))??;
        info!(%id, priority, "job queued");
        self.notify();
        Ok(id)
    }
}
