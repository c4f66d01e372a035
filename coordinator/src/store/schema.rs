//! The tables' layout: created in a new file, older layouts migrated in place.

use std::path::Path;

use rusqlite::Connection;

use super::errors::sqlite_error;
use crate::persist::StoreError;

/// The layout version of the tables, in `PRAGMA user_version`. Layout 2 added the jobs'
/// owners; a layout-1 file is migrated at open (its jobs get no owner). Layout 3 added a
/// sequence's frames (`frame_first`, `frame_last`; NULL for a still), migrated alike.
pub(super) const SCHEMA_VERSION: i64 = 3;
/// The columns layout 3 added.
const FRAME_COLUMNS: &str = "ALTER TABLE jobs ADD COLUMN frame_first INTEGER;
                 ALTER TABLE jobs ADD COLUMN frame_last INTEGER;";

/// Brings the tables of an open database to the current layout: creates them in a new
/// file, migrates an older layout (each in one transaction), adds the columns of the AOV
/// layers and the noise settings where they are missing; a newer layout is refused.
pub(super) fn migrate(conn: &Connection, path: &Path) -> Result<(), StoreError> {
    let write_err = |source: rusqlite::Error| {
        sqlite_error(path, &source)
            .unwrap_or_else(|| StoreError::Write { path: path.to_owned(), source: Box::new(source) })
    };
    let version: i64 = conn.query_row("PRAGMA user_version", [], |r| r.get(0)).map_err(write_err)?;
    if version == 0 {
        conn.execute_batch(&format!(
            "CREATE TABLE IF NOT EXISTS jobs (
                id INTEGER PRIMARY KEY,
                priority INTEGER NOT NULL,
                spp INTEGER, width INTEGER, height INTEGER, time_limit REAL, noise REAL,
                state TEXT NOT NULL, error TEXT, owner TEXT NOT NULL DEFAULT '',
                frame_first INTEGER, frame_last INTEGER);
             CREATE TABLE IF NOT EXISTS scenes (
                job INTEGER PRIMARY KEY, bundle BLOB NOT NULL, bundle_sum BLOB NOT NULL);
             CREATE TABLE IF NOT EXISTS checkpoint_parts (
                job INTEGER NOT NULL, generation INTEGER NOT NULL, part INTEGER NOT NULL,
                data BLOB NOT NULL, sum BLOB NOT NULL,
                PRIMARY KEY (job, generation, part));
             PRAGMA user_version = {SCHEMA_VERSION};"
        ))
        .map_err(write_err)?;
    } else if version == 1 {
        // One transaction: a coordinator killed here leaves a layout-1 file to migrate again.
        conn.execute_batch(&format!(
            "BEGIN; ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '';
             {FRAME_COLUMNS}
             PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
        ))
        .map_err(write_err)?;
    } else if version == 2 {
        conn.execute_batch(&format!(
            "BEGIN; {FRAME_COLUMNS}
             PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
        ))
        .map_err(write_err)?;
    } else if version != SCHEMA_VERSION {
        return Err(StoreError::Version { expected: SCHEMA_VERSION, path: path.to_owned(), found: version });
    }
    // Columns added where they are missing, whatever the layout version (older files, and
    // older Tessera versions, which name their columns and so ignore them):
    // - the jobs' AOV layers (a job without the column keeps no layers);
    // - an absolute noise target (NULL: none, or the relative one in `noise`). Its own
    //   column rather than a flag beside `noise`: an older Tessera, which does not read it,
    //   then sees a job without a target instead of a relative one of the wrong size;
    // - the noise target's minimum of samples (NULL: the target's own). An older Tessera
    //   uses the target's own, a render with other stopping points but still the job's.
    for (column, declaration) in
        [("aovs", "INTEGER NOT NULL DEFAULT 0"), ("noise_absolute", "REAL"), ("noise_min", "INTEGER")]
    {
        let present = conn
            .prepare("SELECT 1 FROM pragma_table_info('jobs') WHERE name = ?1")
            .and_then(|mut q| q.exists([column]))
            .map_err(write_err)?;
        if !present {
            conn.execute_batch(&format!("ALTER TABLE jobs ADD COLUMN {column} {declaration}"))
                .map_err(write_err)?;
        }
    }
    Ok(())
}
