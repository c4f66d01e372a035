//! Sequences on the command line: `--frames FIRST-LAST` and output names with a run of
//! `#` for the frame number (`shot_####.exr` → `shot_0001.exr`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};

/// `--frames` as given: checked here rather than by clap, so that a bad range is one line
/// (`--frames 5-2: the range is reversed`).
pub fn parse(arg: Option<&str>) -> Result<Option<(u32, u32)>> {
    arg.map(|s| tessera_description::job::parse_frames(s).map_err(anyhow::Error::msg)).transpose()
}

/// The `#` run of a file name that the frame number replaces: the last one.
fn hashes(name: &str) -> Option<(usize, usize)> {
    let end = name.rfind('#')? + 1;
    let start = name[..end].trim_end_matches('#').len();
    Some((start, end))
}

/// The file of frame `frame` for output pattern `pattern`: the last run of `#` in its file
/// name replaced by the frame number, zero-padded to the run's length (longer numbers are
/// written whole). A name without `#` is used as it is.
pub fn frame_path(pattern: &Path, frame: u32) -> PathBuf {
    let Some(name) = pattern.file_name().and_then(|n| n.to_str()) else { return pattern.to_path_buf() };
    let Some((start, end)) = hashes(name) else { return pattern.to_path_buf() };
    let named = format!("{}{frame:0width$}{}", &name[..start], &name[end..], width = end - start);
    pattern.with_file_name(named)
}

/// Checks an output pattern for `frames` before any work: the extension and directory as
/// for a still, and a `#` run when several frames would otherwise go to one name.
pub fn check_pattern(pattern: &Path, frames: Option<(u32, u32)>) -> Result<()> {
    crate::check_output(pattern)?;
    let Some((first, last)) = frames else { return Ok(()) };
    let named = pattern.file_name().and_then(|n| n.to_str()).and_then(hashes).is_some();
    if last > first && !named {
        bail!(
            "{}: {} frames would all be written to this one name; put a run of # where the frame number goes, e.g. shot_####.exr",
            pattern.display(),
            u64::from(last - first) + 1
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_runs_become_padded_frame_numbers() {
        assert_eq!(frame_path(Path::new("out/shot_####.exr"), 7), Path::new("out/shot_0007.exr"));
        assert_eq!(frame_path(Path::new("shot_##.png"), 123), Path::new("shot_123.png"));
        assert_eq!(frame_path(Path::new("a#_b###.png"), 5), Path::new("a#_b005.png"));
        assert_eq!(frame_path(Path::new("##/f#.png"), 2), Path::new("##/f2.png"));
        assert_eq!(frame_path(Path::new("still.png"), 3), Path::new("still.png"));
    }

    #[test]
    fn several_frames_need_a_hash_run() {
        let e = check_pattern(Path::new("shot.exr"), Some((1, 48))).unwrap_err().to_string();
        assert_eq!(
            e,
            "shot.exr: 48 frames would all be written to this one name; put a run of # where the frame number goes, e.g. shot_####.exr"
        );
        assert!(check_pattern(Path::new("shot.exr"), Some((4, 4))).is_ok());
        assert!(check_pattern(Path::new("shot_####.exr"), Some((1, 48))).is_ok());
        assert!(check_pattern(Path::new("shot.exr"), None).is_ok());
    }

    #[test]
    fn frame_ranges_are_checked_in_one_line() {
        assert_eq!(parse(Some("1-48")).unwrap(), Some((1, 48)));
        assert_eq!(parse(None).unwrap(), None);
        assert_eq!(parse(Some("5-2")).unwrap_err().to_string(), "--frames 5-2: the range is reversed");
    }
}
