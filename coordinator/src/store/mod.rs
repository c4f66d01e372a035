//! Durable jobs: every job's scene, settings and state, and its last two checkpoints, in
//! one SQLite database (`jobs.db`) in the coordinator's data directory.
//!
//! Atomicity is SQLite's: each write is one transaction with a rollback journal and a full
//! sync, so a coordinator killed in the middle of a write leaves the previous state. Damage
//! that SQLite cannot see (bits changed on disk) is caught by the checksums of every stored
//! scene and checkpoint part. What is damaged is reported and skipped: a job resumes from its
//! newest checkpoint that reads back whole, else from its start, never from garbage.

use std::path::{Path, PathBuf};

use rusqlite::{params, Connection, OptionalExtension};
use tracing::warn;

use crate::checkpoint::{Checkpoint, Part};
use tessera_description::ids::JobId;
use tessera_description::job::{JobSettings, JobState, Noise};

pub use crate::persist::{JobRecord, JobStore, Loaded, LoadedJob, StoreError};

mod encoding;
mod errors;
mod schema;

use encoding::{blake3_of, decode_bundle, encode_bundle, state_columns, state_from_columns};
use errors::{io_error, sqlite_error};

/// The database file in a data directory.
pub const DB_FILE: &str = "jobs.db";
/// Checkpoints kept per job: the newest, and one to fall back on should it be damaged.
const GENERATIONS_KEPT: i64 = 2;
/// Test hook: a checkpoint write stops this many milliseconds before its commit, so a test
/// can kill the coordinator in the middle of a write.
pub const FAULT_STALL_ENV: &str = "TESSERA_FAULT_STALL_CHECKPOINT_MS";

/// Removes a file when dropped.
struct Removal<'a>(&'a Path);

impl Drop for Removal<'_> {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(self.0);
    }
}

/// Removes a database file this start created, with its journal, when dropped unarmed:
/// a start that fails must not leave an empty `jobs.db` that looks like a damaged one.
struct Created<'a> {
    path: &'a Path,
    armed: bool,
}

impl Drop for Created<'_> {
    fn drop(&mut self) {
        if self.armed {
            let _ = std::fs::remove_file(self.path);
            let _ = std::fs::remove_file(self.path.with_extension("db-journal"));
        }
    }
}

/// The open database.
#[derive(Debug)]
pub struct Store {
    conn: Connection,
    path: PathBuf,
    stall: Option<std::time::Duration>,
}

impl Store {
    /// Opens (creating if need be) the database in `dir` and reads every job back, with
    /// damage reported in `Loaded::problems`. A database SQLite finds damaged is salvaged:
    /// what reads back whole is kept, the file is moved aside, and a new one is written.
    pub fn open(dir: &Path) -> Result<(Store, Loaded), StoreError> {
        let path = dir.join(DB_FILE);
        std::fs::create_dir_all(dir).map_err(|e| io_error(&path, e))?;
        // A new database file is created here, not by SQLite, so that a directory that
        // cannot take it says why (SQLite says only "unable to open database file"), and so
        // that it is removed again if the start fails before its tables are written.
        let mut created = Created { path: &path, armed: false };
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(_) => created.armed = true,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(io_error(&path, e)),
        }
        // A directory SQLite can create no journal in fails the first write: better now.
        if let Err(e) = std::fs::OpenOptions::new().append(true).open(&path) {
            return Err(io_error(&path, e));
        }
        let stall = std::env::var(FAULT_STALL_ENV)
            .ok()
            .and_then(|v| v.parse().ok())
            .map(std::time::Duration::from_millis);
        let mut problems = Vec::new();
        if let Some((mut store, jobs)) = Self::open_clean(&path, &mut problems)? {
            created.armed = false;
            store.stall = stall;
            problems.iter().for_each(|p| warn!("{p}"));
            return Ok((store, Loaded { jobs, problems, moved_aside: None }));
        }
        if created.armed {
            // A file this start created and SQLite then found wanting: nothing to salvage.
            return Err(StoreError::Damaged { path: path.clone(), detail: problems.join("; ") });
        }
        let jobs = Self::salvage(&path, &mut problems)?;
        let stamp =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
        let aside = path.with_extension(format!("db.damaged-{stamp}"));
        std::fs::rename(&path, &aside)
            .map_err(|e| StoreError::Open { path: path.clone(), source: e.into() })?;
        let _ = std::fs::remove_file(path.with_extension("db-journal"));
        let mut rebuild_problems = Vec::new();
        let (mut store, fresh) = Self::open_clean(&path, &mut rebuild_problems)?
            .ok_or_else(|| StoreError::Damaged { path: path.clone(), detail: rebuild_problems.join("; ") })?;
        debug_assert!(fresh.is_empty());
        for job in &jobs {
            store.add_job(&job.record)?;
            if let Some(c) = &job.checkpoint {
                store.save(c, &job.record.state)?;
            }
        }
        store.stall = stall;
        problems.push(format!(
            "{} was damaged: moved to {} and rebuilt from the {} jobs that read back",
            path.display(),
            aside.display(),
            jobs.len()
        ));
        problems.iter().for_each(|p| warn!("{p}"));
        Ok((store, Loaded { jobs, problems, moved_aside: Some(aside) }))
    }

    /// Opens the database and reads it back if SQLite finds nothing wrong with it; `None`
    /// (with the reason in `problems`) if it is damaged.
    fn open_clean(
        path: &Path,
        problems: &mut Vec<String>,
    ) -> Result<Option<(Store, Vec<LoadedJob>)>, StoreError> {
        let conn = match Self::connect(path) {
            Ok(conn) => conn,
            Err(StoreError::Damaged { detail, .. }) => {
                problems.push(format!("{}: SQLite cannot read it: {detail}", path.display()));
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        // SQLite's own page check: finds broken tree pages and lost pages.
        let quick: Result<Vec<String>, _> = conn
            .prepare("PRAGMA quick_check")
            .and_then(|mut s| s.query_map([], |r| r.get::<_, String>(0))?.collect());
        match quick {
            Ok(lines) if lines == ["ok"] => {}
            Ok(lines) => {
                let first: Vec<String> = lines.into_iter().take(3).collect();
                problems.push(format!("{}: SQLite finds damage: {}", path.display(), first.join("; ")));
                return Ok(None);
            }
            Err(e) => {
                if let Some(e) = sqlite_error(path, &e) {
                    return Err(e);
                }
                problems.push(format!("{}: SQLite cannot check it: {e}", path.display()));
                return Ok(None);
            }
        }
        schema::migrate(&conn, path)?;
        let mut store = Store { conn, path: path.to_owned(), stall: None };
        match store.read_jobs(problems) {
            Ok(jobs) => Ok(Some((store, jobs))),
            Err(e) => {
                if let Some(e) = sqlite_error(path, &e) {
                    return Err(e);
                }
                problems.push(format!("{}: reading it back failed: {e}", path.display()));
                Ok(None)
            }
        }
    }

    /// Reads what it can from a damaged database, through a copy whose header no longer
    /// claims more pages than the file has (SQLite refuses a truncated file outright
    /// otherwise). The original is left as it is.
    fn salvage(path: &Path, problems: &mut Vec<String>) -> Result<Vec<LoadedJob>, StoreError> {
        use std::io::{Seek, SeekFrom, Write};
        let copy = path.with_extension("db.salvage");
        let damaged = |detail: String| StoreError::Damaged { path: path.to_owned(), detail };
        std::fs::copy(path, &copy).map_err(|e| damaged(format!("copying it to salvage: {e}")))?;
        let cleanup = Removal(&copy);
        // Bytes 28..32 of the header: the size in pages. Zero means "take the file's size".
        let mut f =
            std::fs::OpenOptions::new().write(true).open(&copy).map_err(|e| damaged(e.to_string()))?;
        if f.metadata().map_err(|e| damaged(e.to_string()))?.len() >= 100 {
            f.seek(SeekFrom::Start(28))
                .and_then(|_| f.write_all(&[0; 4]))
                .map_err(|e| damaged(e.to_string()))?;
        }
        drop(f);
        let conn = Connection::open_with_flags(&copy, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
            .map_err(|e| damaged(e.to_string()))?;
        let mut store = Store { conn, path: copy.clone(), stall: None };
        let jobs = store.read_jobs(problems).map_err(|e| damaged(e.to_string()))?;
        drop(store);
        drop(cleanup);
        Ok(jobs)
    }

    fn connect(path: &Path) -> Result<Connection, StoreError> {
        let conn = Connection::open(path).map_err(|e| {
            sqlite_error(path, &e)
                .unwrap_or_else(|| StoreError::Open { path: path.to_owned(), source: e.into() })
        })?;
        // One process per data directory: an exclusive lock held for the connection's life.
        let setup = conn.execute_batch(
            "PRAGMA locking_mode = EXCLUSIVE; PRAGMA journal_mode = DELETE; PRAGMA synchronous = FULL;
             BEGIN EXCLUSIVE; COMMIT;",
        );
        match setup {
            Ok(()) => Ok(conn),
            Err(rusqlite::Error::SqliteFailure(e, _)) if e.code == rusqlite::ErrorCode::DatabaseBusy => {
                Err(StoreError::InUse { path: path.to_owned() })
            }
            Err(e) => Err(sqlite_error(path, &e)
                .unwrap_or_else(|| StoreError::Damaged { path: path.to_owned(), detail: e.to_string() })),
        }
    }

    /// Reads every job. A job whose row fails is reported and left out; only a list of
    /// jobs that cannot be read at all is an error.
    fn read_jobs(&mut self, problems: &mut Vec<String>) -> rusqlite::Result<Vec<LoadedJob>> {
        let ids: Vec<i64> = self
            .conn
            .prepare("SELECT id FROM jobs ORDER BY id")?
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        let mut jobs = Vec::new();
        for id in ids {
            match self.read_job(id, problems) {
                Ok(Some(job)) => jobs.push(job),
                Ok(None) => {}
                Err(e) => problems.push(format!("job {id}: its record cannot be read ({e}); it is lost")),
            }
        }
        Ok(jobs)
    }

    #[allow(clippy::type_complexity)]
    fn read_job(&mut self, id: i64, problems: &mut Vec<String>) -> rusqlite::Result<Option<LoadedJob>> {
        // A layout-1 file being salvaged (read-only, not migrated) has no owners.
        let owner: String = match self.conn.prepare("SELECT owner FROM jobs WHERE id = ?1") {
            Ok(mut s) => s.query_row([id], |r| r.get(0))?,
            Err(_) => String::new(),
        };
        // Nor frames, before layout 3.
        let frames: (Option<u32>, Option<u32>) =
            match self.conn.prepare("SELECT frame_first, frame_last FROM jobs WHERE id = ?1") {
                Ok(mut s) => s.query_row([id], |r| Ok((r.get(0)?, r.get(1)?)))?,
                Err(_) => (None, None),
            };
        let row: (
            i32,
            Option<u32>,
            Option<u32>,
            Option<u32>,
            Option<f64>,
            Option<f64>,
            String,
            Option<String>,
        ) = self.conn.query_row(
            "SELECT priority, spp, width, height, time_limit, noise, state, error FROM jobs WHERE id = ?1",
            [id],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?, r.get(6)?, r.get(7)?)),
        )?;
        let (priority, spp, width, height, time_limit, noise, state, error) = row;
        let time_limit =
            time_limit.filter(|t| t.is_finite() && *t > 0.0).map(std::time::Duration::from_secs_f64);
        // A salvaged copy of a database from before the column has none: relative or no
        // target.
        let absolute: Option<f64> = match self.conn.prepare("SELECT noise_absolute FROM jobs WHERE id = ?1") {
            Ok(mut s) => s.query_row([id], |r| r.get(0))?,
            Err(_) => None,
        };
        let noise = match (noise, absolute) {
            (_, Some(a)) => Some(Noise::Absolute(a as f32)),
            (Some(r), None) => Some(Noise::Relative(r as f32)),
            (None, None) => None,
        };
        // Likewise: the target's own minimum.
        let noise_min: Option<i64> = match self.conn.prepare("SELECT noise_min FROM jobs WHERE id = ?1") {
            Ok(mut s) => s.query_row([id], |r| r.get(0))?,
            Err(_) => None,
        };
        let Ok(noise_min) = noise_min.map(u32::try_from).transpose() else {
            problems.push(format!(
                "job {id}: its stored noise target's minimum {} is not a sample count; it is lost",
                noise_min.unwrap_or_default()
            ));
            return Ok(None);
        };
        let noise_settings = JobSettings { noise, noise_min, ..JobSettings::default() };
        if let Err(reason) = noise_settings.checked_noise() {
            problems
                .push(format!("job {id}: its stored noise settings are out of range: {reason}; it is lost"));
            return Ok(None);
        }
        // A salvaged copy of a database from before the column has none: no layers.
        let aov_bits: u32 = match self.conn.prepare("SELECT aovs FROM jobs WHERE id = ?1") {
            Ok(mut s) => s.query_row([id], |r| r.get(0))?,
            Err(_) => 0,
        };
        let Some(aovs) = tessera_proto::convert::aovs_from_wire(aov_bits) else {
            problems.push(format!(
                "job {id}: its stored AOV layers {aov_bits:#x} name no known layer; it is lost"
            ));
            return Ok(None);
        };
        let (bundle, sum): (Vec<u8>, Vec<u8>) =
            self.conn.query_row("SELECT bundle, bundle_sum FROM scenes WHERE job = ?1", [id], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })?;
        let bundle = (blake3_of(&bundle) == sum).then(|| decode_bundle(&bundle)).flatten();
        let (Some(bundle), Some(state)) = (bundle, state_from_columns(&state, error)) else {
            problems.push(format!("job {id}: its stored scene fails its checksum; it is lost"));
            return Ok(None);
        };
        let size = width.zip(height);
        let record = JobRecord {
            id: JobId(id as u64),
            bundle: std::sync::Arc::new(bundle),
            settings: JobSettings {
                spp,
                size,
                time_limit,
                noise,
                noise_min,
                aovs,
                frames: frames.0.zip(frames.1),
            },
            priority,
            state,
            owner,
        };
        let generations: Vec<i64> = self
            .conn
            .prepare(
                "SELECT DISTINCT generation FROM checkpoint_parts WHERE job = ?1 ORDER BY generation DESC",
            )?
            .query_map([id], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        let mut checkpoint = None;
        for g in generations {
            match self.read_checkpoint(id, g) {
                Ok(Ok(c)) if c.job.0 == id as u64 => {
                    checkpoint = Some(c);
                    break;
                }
                Ok(Ok(c)) => {
                    problems.push(format!("job {id}: checkpoint {g} belongs to job {}; skipped", c.job.0))
                }
                Ok(Err(e)) => {
                    problems.push(format!("job {id}: checkpoint {g} is damaged ({e}); trying an older one"))
                }
                Err(e) => problems
                    .push(format!("job {id}: checkpoint {g} cannot be read ({e}); trying an older one")),
            }
        }
        if checkpoint.is_none() && problems.iter().any(|p| p.starts_with(&format!("job {id}:"))) {
            problems
                .push(format!("job {id}: no checkpoint reads back whole; it restarts from the beginning"));
        }
        Ok(Some(LoadedJob { record, checkpoint }))
    }

    fn read_checkpoint(
        &mut self,
        job: i64,
        generation: i64,
    ) -> rusqlite::Result<Result<Checkpoint, crate::checkpoint::DecodeError>> {
        let parts: Vec<Part> = self
            .conn
            .prepare(
                "SELECT data, sum FROM checkpoint_parts WHERE job = ?1 AND generation = ?2 ORDER BY part",
            )?
            .query_map(params![job, generation], |r| {
                let sum: Vec<u8> = r.get(1)?;
                Ok(Part { data: r.get(0)?, sum: sum.try_into().unwrap_or([0; 32]) })
            })?
            .collect::<Result<_, _>>()?;
        Ok(Checkpoint::decode(&parts))
    }
}

impl JobStore for Store {
    /// Records a new job; durable when this returns. The scene goes in a table of its own,
    /// written once: state changes rewrite only the small row in `jobs`, so the scene's
    /// pages stay where they were first written (early in the file), and a file truncated
    /// later loses checkpoints before it loses scenes.
    fn add_job(&mut self, job: &JobRecord) -> Result<(), StoreError> {
        let bundle = encode_bundle(&job.bundle);
        let (state, error) = state_columns(&job.state);
        let (width, height) = job.settings.size.unzip();
        let path = self.path.clone();
        let err =
            |source: rusqlite::Error| StoreError::Write { path: path.clone(), source: Box::new(source) };
        let tx = self.conn.transaction().map_err(err)?;
        tx.execute(
            "INSERT INTO scenes (job, bundle, bundle_sum) VALUES (?1, ?2, ?3)",
            params![job.id.0 as i64, bundle, blake3_of(&bundle)],
        )
        .map_err(err)?;
        tx.execute(
            "INSERT INTO jobs (id, priority, spp, width, height, time_limit, noise, state, error, owner, aovs,
                               frame_first, frame_last, noise_absolute, noise_min)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15)",
            params![
                job.id.0 as i64,
                job.priority,
                job.settings.spp,
                width,
                height,
                job.settings.time_limit.map(|t| t.as_secs_f64()),
                match job.settings.noise {
                    Some(Noise::Relative(v)) => Some(f64::from(v)),
                    _ => None,
                },
                state,
                error,
                job.owner,
                tessera_proto::convert::aovs_to_wire(job.settings.aovs),
                job.settings.frames.map(|f| f.0),
                job.settings.frames.map(|f| f.1),
                match job.settings.noise {
                    Some(Noise::Absolute(v)) => Some(f64::from(v)),
                    _ => None,
                },
                job.settings.noise_min,
            ],
        )
        .map_err(err)?;
        tx.commit().map_err(err)?;
        Ok(())
    }

    /// Records a job's state (paused, resumed, cancelled, ...).
    fn set_state(&mut self, job: JobId, state: &JobState) -> Result<(), StoreError> {
        let (name, error) = state_columns(state);
        self.conn
            .execute(
                "UPDATE jobs SET state = ?2, error = ?3 WHERE id = ?1",
                params![job.0 as i64, name, error],
            )
            .map_err(|source| StoreError::Write { path: self.path.clone(), source: Box::new(source) })?;
        Ok(())
    }

    fn set_priority(&mut self, job: JobId, priority: i32) -> Result<(), StoreError> {
        self.conn
            .execute("UPDATE jobs SET priority = ?2 WHERE id = ?1", params![job.0 as i64, priority])
            .map_err(|source| StoreError::Write { path: self.path.clone(), source: Box::new(source) })?;
        Ok(())
    }

    fn remove(&mut self, job: JobId) -> Result<(), StoreError> {
        let path = self.path.clone();
        let err =
            |source: rusqlite::Error| StoreError::Write { path: path.clone(), source: Box::new(source) };
        let tx = self.conn.transaction().map_err(err)?;
        for table in [
            "DELETE FROM checkpoint_parts WHERE job = ?1",
            "DELETE FROM scenes WHERE job = ?1",
            "DELETE FROM jobs WHERE id = ?1",
        ] {
            tx.execute(table, params![job.0 as i64]).map_err(err)?;
        }
        tx.commit().map_err(err)
    }

    /// Writes a checkpoint and the job's state in one transaction, keeping the previous
    /// checkpoint to fall back on; returns the new checkpoint's generation.
    fn save(&mut self, checkpoint: &Checkpoint, state: &JobState) -> Result<i64, StoreError> {
        let parts = checkpoint.encode();
        let job = checkpoint.job.0 as i64;
        let (name, error) = state_columns(state);
        let path = self.path.clone();
        let err =
            |source: rusqlite::Error| StoreError::Write { path: path.clone(), source: Box::new(source) };
        let tx = self.conn.transaction().map_err(err)?;
        let generation: i64 = tx
            .query_row(
                "SELECT COALESCE(MAX(generation), 0) + 1 FROM checkpoint_parts WHERE job = ?1",
                [job],
                |r| r.get(0),
            )
            .map_err(err)?;
        {
            let mut insert = tx
                .prepare("INSERT INTO checkpoint_parts (job, generation, part, data, sum) VALUES (?1, ?2, ?3, ?4, ?5)")
                .map_err(err)?;
            for (i, p) in parts.iter().enumerate() {
                insert.execute(params![job, generation, i as i64, p.data, p.sum.as_slice()]).map_err(err)?;
            }
        }
        tx.execute(
            "DELETE FROM checkpoint_parts WHERE job = ?1 AND generation <= ?2",
            params![job, generation - GENERATIONS_KEPT],
        )
        .map_err(err)?;
        tx.execute("UPDATE jobs SET state = ?2, error = ?3 WHERE id = ?1", params![job, name, error])
            .map_err(err)?;
        if let Some(stall) = self.stall {
            eprintln!("tessera: checkpoint {generation} of job {job} written, not committed (test stall)");
            std::thread::sleep(stall);
        }
        tx.commit().map_err(err)?;
        Ok(generation)
    }

    /// The highest job id ever stored, so that ids are never reused.
    fn max_job_id(&self) -> u64 {
        self.conn
            .query_row("SELECT MAX(id) FROM jobs", [], |r| r.get::<_, Option<i64>>(0))
            .optional()
            .ok()
            .flatten()
            .flatten()
            .map_or(0, |v| v as u64)
    }
}

#[cfg(test)]
mod tests;
