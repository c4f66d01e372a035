//! `tessera bench checkpoint`: what durability costs. For images from 640×480 to 4K, the
//! time to take a checkpoint's snapshot under the farm's lock (copy-on-write), to copy it
//! out and write it to the database (both outside the lock), and to take a job up again
//! from it at a coordinator's start (read, verify, re-cut the walk).

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use tessera_coordinator::farm::Farm;
use tessera_coordinator::persist::JobStore;
use tessera_coordinator::store::Store;
use tessera_description::bundle::Bundle;
use tessera_description::job::JobSettings;

fn fastest(runs: usize, mut f: impl FnMut() -> Result<()>) -> Result<Duration> {
    let mut best = Duration::MAX;
    for _ in 0..runs {
        let t = Instant::now();
        f()?;
        best = best.min(t.elapsed());
    }
    Ok(best)
}

/// Runs the benchmark on `scene` at each size, `spp` samples per pixel, half done.
pub fn run(scene: &Path, spp: u32, runs: usize) -> Result<()> {
    let bundle = Bundle::read(scene)?;
    let dir = std::env::temp_dir().join(format!("tessera-bench-checkpoint-{}", std::process::id()));
    println!("scene {}, {spp} spp, job half done; fastest of {runs} runs", scene.display());
    println!(
        "{:>10} {:>9} {:>12} {:>9} {:>12} {:>12} {:>10}",
        "size", "MB", "snapshot ms", "copy ms", "write ms", "take up ms", "write MB/s"
    );
    for (w, h) in [(640, 480), (1920, 1080), (3840, 2160)] {
        let _ = std::fs::remove_dir_all(&dir);
        let mut farm = Farm::new();
        let settings = JobSettings::sized(Some(spp), Some((w, h)));
        let id = farm.submit(bundle.clone(), settings, 0).map_err(|e| anyhow!(e))?;
        // Complete half the samples with plausible sums, as workers would.
        let worker = farm.add_worker("bench".into(), 1, Instant::now());
        let total = farm.job(id).expect("submitted").progress(Instant::now()).samples_total;
        while farm.job(id).expect("submitted").progress(Instant::now()).samples_done < total / 2 {
            let a = farm.assign(worker, Instant::now()).expect("work left");
            let n = u64::from(a.batch.samples.end - a.batch.samples.start);
            let sums: Vec<u64> =
                (0..a.batch.quads.len() * 3).map(|i| (i as u64 % 5 + 1) * n * 4_000_000).collect();
            farm.complete(worker, &a.answer(&sums, None), Instant::now()).map_err(|e| anyhow!(e))?;
        }
        let job = farm.job(id).expect("submitted");
        let snapshot = fastest(runs, || {
            std::hint::black_box(job.snapshot(Instant::now()));
            Ok(())
        })?;
        let taken = job.snapshot(Instant::now());
        let copy = fastest(runs, || {
            std::hint::black_box(taken.checkpoint());
            Ok(())
        })?;
        let checkpoint = taken.checkpoint();
        let bytes: usize = checkpoint.encode().iter().map(|p| p.data.len()).sum();
        let (mut store, _) = Store::open(&dir).context("opening the bench database")?;
        store.add_job(&job.record())?;
        let write = fastest(runs, || {
            store.save(&checkpoint, &job.state)?;
            Ok(())
        })?;
        drop(store);
        let take_up = fastest(runs, || {
            let (_store, loaded) = Store::open(&dir)?;
            let mut fresh = Farm::new();
            for j in loaded.jobs {
                fresh.restore(j, Instant::now()).map_err(|e| anyhow!(e))?;
            }
            Ok(())
        })?;
        let mb = bytes as f64 / 1e6;
        println!(
            "{:>10} {:>9.1} {:>12.3} {:>9.1} {:>12.1} {:>12.1} {:>10.0}",
            format!("{w}x{h}"),
            mb,
            snapshot.as_secs_f64() * 1e3,
            copy.as_secs_f64() * 1e3,
            write.as_secs_f64() * 1e3,
            take_up.as_secs_f64() * 1e3,
            mb / write.as_secs_f64()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
