//! How a job's values are stored in their columns: its state as a name and an error, its
//! bundle as length-prefixed bytes, and the checksums over them.

use tessera_description::bundle::Bundle;
use tessera_description::job::JobState;

pub(super) fn state_columns(s: &JobState) -> (&'static str, Option<&str>) {
    match s {
        JobState::Queued => ("queued", None),
        JobState::Running => ("running", None),
        JobState::Done => ("done", None),
        JobState::Cancelled => ("cancelled", None),
        JobState::Paused => ("paused", None),
        JobState::Failed(e) => ("failed", Some(e)),
    }
}

pub(super) fn state_from_columns(name: &str, error: Option<String>) -> Option<JobState> {
    Some(match name {
        "queued" => JobState::Queued,
        "running" => JobState::Running,
        "done" => JobState::Done,
        "cancelled" => JobState::Cancelled,
        "paused" => JobState::Paused,
        "failed" => JobState::Failed(error.unwrap_or_default()),
        _ => return None,
    })
}

/// A bundle as bytes: each field length-prefixed.
pub(super) fn encode_bundle(b: &Bundle) -> Vec<u8> {
    let mut out = Vec::new();
    let mut field = |bytes: &[u8]| {
        out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
        out.extend_from_slice(bytes);
    };
    field(b.name.as_bytes());
    field(b.text.as_bytes());
    field(&(b.assets.len() as u64).to_le_bytes());
    for (path, data) in &b.assets {
        field(path.as_bytes());
        field(data);
    }
    out
}

pub(super) fn decode_bundle(mut bytes: &[u8]) -> Option<Bundle> {
    let mut field = || -> Option<&[u8]> {
        let len = usize::try_from(u64::from_le_bytes(bytes.get(..8)?.try_into().ok()?)).ok()?;
        let data = bytes.get(8..8usize.checked_add(len)?)?;
        bytes = &bytes[8 + len..];
        Some(data)
    };
    let name = String::from_utf8(field()?.to_vec()).ok()?;
    let text = String::from_utf8(field()?.to_vec()).ok()?;
    let n = u64::from_le_bytes(field()?.try_into().ok()?);
    let mut assets = Vec::new();
    for _ in 0..n {
        let path = String::from_utf8(field()?.to_vec()).ok()?;
        assets.push((path, field()?.to_vec()));
    }
    Some(Bundle { name, text, assets, refused: Vec::new() })
}

pub(super) fn blake3_of(bytes: &[u8]) -> Vec<u8> {
    blake3::hash(bytes).as_bytes().to_vec()
}
