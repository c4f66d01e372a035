//! A full disk or an unwritable file, told apart from other failures: the system's and
//! SQLite's errors as the `StoreError` that says so.

use std::path::Path;

use crate::persist::StoreError;

/// A full disk or an unwritable file as the error that says so, from the system's error.
pub(super) fn io_error(path: &Path, e: std::io::Error) -> StoreError {
    match e.raw_os_error() {
        Some(libc::ENOSPC) | Some(libc::EDQUOT) => StoreError::NoSpace { path: path.to_owned() },
        Some(libc::EACCES) | Some(libc::EPERM) | Some(libc::EROFS) => {
            StoreError::NotWritable { path: path.to_owned(), detail: e.to_string() }
        }
        _ => StoreError::Open { path: path.to_owned(), source: e.into() },
    }
}

/// A full disk or an unwritable file as the error that says so, from SQLite's error;
/// `None` for every other error.
pub(super) fn sqlite_error(path: &Path, e: &rusqlite::Error) -> Option<StoreError> {
    let rusqlite::Error::SqliteFailure(f, _) = e else { return None };
    match f.code {
        rusqlite::ErrorCode::DiskFull => Some(StoreError::NoSpace { path: path.to_owned() }),
        rusqlite::ErrorCode::ReadOnly | rusqlite::ErrorCode::PermissionDenied => {
            Some(StoreError::NotWritable { path: path.to_owned(), detail: e.to_string() })
        }
        _ => None,
    }
}
