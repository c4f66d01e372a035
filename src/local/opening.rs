//! Where a local render's job comes from: a fresh submission, or with `--resume` the job
//! in its data directory, which must be of the same scene and settings; and the cleanup
//! of a store this run made when the job is refused.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use tessera_coordinator::{CoordinatorService, Timing};
use tessera_description::bundle::Bundle;
use tessera_description::ids::JobId;
use tessera_description::job::JobSettings;

/// Where and how often a local render checkpoints.
pub struct Checkpoints {
    /// The data directory.
    pub dir: PathBuf,
    /// Between checkpoints.
    pub interval: Duration,
    /// Take up the job found there instead of starting afresh.
    pub resume: bool,
}

/// Removes the database this run made in `dir` (and `dir` itself, if this run made it and
/// it is empty); best effort, since the job's own error is what the user needs to see.
fn remove_fresh_store(dir: &Path, dir_existed: bool) {
    let prefix = tessera_coordinator::store::DB_FILE;
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    if !dir_existed {
        let _ = std::fs::remove_dir(dir);
    }
}

/// How a local render's job comes to be.
pub(super) enum Opening {
    /// `--resume`: the job in the data directory.
    Resumed(JobId),
    /// A new job, to submit. If it is refused, the store this run made is removed
    /// (`fresh_store`: its directory, and whether the directory was there before).
    Submit { fresh_store: Option<(PathBuf, bool)> },
}

/// The in-process coordinator, and how its job comes: a new one, or with `--resume` the
/// one in the data directory, which must be of the same scene and settings. Nothing is
/// submitted yet: the coordinator serves first, so that its workers are there while it
/// validates the scene (`render_local`).
pub(super) fn open_job(
    bundle: &Bundle,
    settings: &JobSettings,
    checkpoints: Option<&Checkpoints>,
) -> Result<(CoordinatorService, Opening)> {
    let Some(c) = checkpoints else {
        return Ok((CoordinatorService::new(Timing::default()), Opening::Submit { fresh_store: None }));
    };
    let had = c.dir.join(tessera_coordinator::store::DB_FILE).exists();
    let dir_existed = c.dir.exists();
    if c.resume && !had {
        bail!("nothing to resume: no checkpoint in {}", c.dir.display());
    }
    let (service, recovery) = CoordinatorService::open(Timing::default(), &c.dir, c.interval)
        .with_context(|| format!("checkpoint directory {}", c.dir.display()))?;
    let found: Vec<_> = service.jobs().into_iter().map(|j| (j.id, j.scene_hash, j.settings)).collect();
    match (found.as_slice(), c.resume) {
        ([], _) => {
            if c.resume {
                crate::report::report_recovery(&c.dir, &recovery);
                bail!(
                    "nothing to resume: the checkpoint in {} holds no job that reads back",
                    c.dir.display()
                );
            }
            let fresh_store = (!had).then(|| (c.dir.clone(), dir_existed));
            Ok((service, Opening::Submit { fresh_store }))
        }
        ([(id, hash, stored)], true) => {
            if *hash != bundle.hash() || !stored.same_job_as(settings) {
                bail!(
                    "the checkpoint in {} is of a different scene or settings (the scene file, its assets, --spp, --size, --time, --noise, --noise-abs or --noise-min changed); render without --resume after deleting it",
                    c.dir.display()
                );
            }
            crate::report::report_recovery(&c.dir, &recovery);
            Ok((service, Opening::Resumed(*id)))
        }
        (_, true) => bail!(
            "{} holds several jobs; it is a coordinator's data directory, not a render's",
            c.dir.display()
        ),
        (_, false) => {
            let p = service.progress(found[0].0).expect("listed");
            bail!(
                "{} holds an interrupted render ({:.1}% done); continue it with --resume, or delete the directory to start over",
                c.dir.display(),
                p.fraction() * 100.0
            )
        }
    }
}

/// The render's job: submitted (validated and queued) now, or the one resumed.
pub(super) async fn submit_job(
    service: &CoordinatorService,
    bundle: Bundle,
    settings: JobSettings,
    opening: Opening,
) -> Result<JobId> {
    match opening {
        Opening::Resumed(id) => Ok(id),
        Opening::Submit { fresh_store } => match service.submit(bundle, settings, 0).await {
            Ok(job) => Ok(job),
            Err(e) => {
                // A refused job leaves nothing behind that a later --resume would find.
                if let Some((dir, existed)) = fresh_store {
                    remove_fresh_store(&dir, existed);
                }
                Err(anyhow!(e))
            }
        },
    }
}
