//! What the farm keeps across restarts, behind a trait: the service writes through
//! `JobStore`, which the SQLite database (`store.rs`) implements and an in-memory store
//! serves tests with. Nothing here knows SQLite.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use tessera_description::bundle::Bundle;
use tessera_description::ids::JobId;
use tessera_description::job::{JobSettings, JobState};

use crate::checkpoint::Checkpoint;

/// Why the data directory cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The directory or the database file cannot be created or opened.
    #[error("cannot open {path}: {source}")]
    Open {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The disk holding the database is full (ENOSPC, SQLite's "disk is full").
    #[error("{path}: no space left on its disk; free some and start again")]
    NoSpace {
        /// The file.
        path: PathBuf,
    },
    /// The database or its directory cannot be written: permissions, a read-only mount.
    #[error("{path} cannot be written: {detail}; the data directory must be writable")]
    NotWritable {
        /// The file.
        path: PathBuf,
        /// The system's account ("Permission denied (os error 13)").
        detail: String,
    },
    /// Another coordinator (or render) holds the database.
    #[error("{path} is in use by another coordinator or render; one process per data directory")]
    InUse {
        /// The file.
        path: PathBuf,
    },
    /// The database is damaged beyond reading its list of jobs.
    #[error("{path} is damaged beyond reading its jobs ({detail}); move it aside to start with no jobs")]
    Damaged {
        /// The file.
        path: PathBuf,
        /// SQLite's account.
        detail: String,
    },
    /// The database is from a different version of tessera.
    #[error("{path} has table layout {found}, this tessera reads layout {expected}")]
    Version {
        /// The file.
        path: PathBuf,
        /// The layout found.
        found: i64,
        /// The layout this build reads.
        expected: i64,
    },
    /// A write failed; the previous state stays.
    #[error("writing {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The store's account.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// A job as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct JobRecord {
    /// The id.
    pub id: JobId,
    /// The scene as submitted (shared with the job: a record is cheap to make).
    pub bundle: Arc<Bundle>,
    /// The settings.
    pub settings: JobSettings,
    /// Higher runs first.
    pub priority: i32,
    /// The state last recorded.
    pub state: JobState,
    /// Who submitted it ("" for an in-process submission, and for jobs stored before
    /// owners were).
    pub owner: String,
}

/// A job read back, with its newest good checkpoint (`None`: start from scratch).
#[derive(Debug)]
pub struct LoadedJob {
    /// The job.
    pub record: JobRecord,
    /// The checkpoint to resume from.
    pub checkpoint: Option<Checkpoint>,
}

/// Everything read from a data directory, and what was wrong with it.
#[derive(Debug, Default)]
pub struct Loaded {
    /// Jobs, oldest first.
    pub jobs: Vec<LoadedJob>,
    /// Damage found and how it was handled, one line each (also logged).
    pub problems: Vec<String>,
    /// Where a damaged database was moved before being rebuilt from what read back.
    pub moved_aside: Option<PathBuf>,
}

/// Where jobs and their checkpoints are kept. Each call is durable when it returns.
pub trait JobStore: Send {
    /// Records a new job.
    fn add_job(&mut self, job: &JobRecord) -> Result<(), StoreError>;
    /// Records a job's state (paused, resumed, cancelled, ...).
    fn set_state(&mut self, job: JobId, state: &JobState) -> Result<(), StoreError>;
    /// Records a job's new priority.
    fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), StoreError>;
    /// Writes a checkpoint and the job's state together, keeping the previous checkpoint
    /// to fall back on; returns the new checkpoint's generation.
    fn save(&mut self, checkpoint: &Checkpoint, state: &JobState) -> Result<i64, StoreError>;
    /// The highest job id ever stored, so that ids are never reused.
    fn max_job_id(&self) -> u64;
    /// Forgets a finished job: its row, scene and checkpoints (retention).
    fn remove(&mut self, job: JobId) -> Result<(), StoreError>;
}

/// A store in memory: the jobs and newest checkpoints of one process's life, for tests of
/// the durability path without a database.
#[derive(Debug, Default)]
pub struct MemoryStore {
    jobs: BTreeMap<JobId, (JobRecord, Option<(i64, Checkpoint)>)>,
}

impl MemoryStore {
    /// An empty store.
    pub fn new() -> Self {
        MemoryStore::default()
    }

    /// What a restarted coordinator would read back: every job with its newest checkpoint.
    pub fn load(&self) -> Loaded {
        let jobs = self
            .jobs
            .values()
            .map(|(record, c)| LoadedJob {
                record: record.clone(),
                checkpoint: c.as_ref().map(|(_, c)| c.clone()),
            })
            .collect();
        Loaded { jobs, ..Loaded::default() }
    }
}

impl JobStore for MemoryStore {
    fn add_job(&mut self, job: &JobRecord) -> Result<(), StoreError> {
        self.jobs.insert(job.id, (job.clone(), None));
        Ok(())
    }

    fn set_state(&mut self, job: JobId, state: &JobState) -> Result<(), StoreError> {
        if let Some((r, _)) = self.jobs.get_mut(&job) {
            r.state = state.clone();
        }
        Ok(())
    }

    fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), StoreError> {
        if let Some((r, _)) = self.jobs.get_mut(&job) {
            r.priority = priority;
        }
        Ok(())
    }

    fn save(&mut self, checkpoint: &Checkpoint, state: &JobState) -> Result<i64, StoreError> {
        let Some((r, c)) = self.jobs.get_mut(&checkpoint.job) else {
            return Err(StoreError::Write {
                path: PathBuf::from("memory"),
                source: format!("{} was never added", checkpoint.job).into(),
            });
        };
        r.state = state.clone();
        let generation = c.as_ref().map_or(1, |(g, _)| g + 1);
        *c = Some((generation, checkpoint.clone()));
        Ok(generation)
    }

    fn max_job_id(&self) -> u64 {
        self.jobs.keys().next_back().map_or(0, |id| id.0)
    }

    fn remove(&mut self, job: JobId) -> Result<(), StoreError> {
        self.jobs.remove(&job);
        Ok(())
    }
}
