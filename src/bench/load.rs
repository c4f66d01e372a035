//! `tessera bench load`: a worker's load of a scene (the bundle already in memory, as it
//! comes off the wire) step by step, in wall and CPU seconds, run after run, and the
//! median of each column.

use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use tessera_description::bundle::Bundle;
use tessera_worker::build::{parse_bundle_observed, Phase};

/// The phases in the order of the table.
const PHASES: [(Phase, &str); 6] = [
    (Phase::ReadObj, "read+parse OBJ"),
    (Phase::Validation, "validation"),
    (Phase::Primitives, "primitives"),
    (Phase::Bvh, "BVH build"),
    (Phase::Slots, "slots"),
    (Phase::Rest, "rest"),
];

/// Wall and CPU seconds of each phase, then of the whole load.
type Row = [(f64, f64); PHASES.len() + 1];

/// The process's CPU time so far in seconds: the sum of its threads' run times
/// (/proc/self/task/*/schedstat, in nanoseconds: /proc/self/stat's clock ticks are too
/// coarse for steps of tens of milliseconds). The benchmark's threads live throughout, so
/// no thread's time is lost between two readings.
fn cpu_seconds() -> Result<f64> {
    let mut ns = 0u64;
    for task in std::fs::read_dir("/proc/self/task").context("reading /proc/self/task")? {
        let path = task?.path().join("schedstat");
        // A thread that ended between the listing and the read has no file left.
        let Ok(stat) = std::fs::read_to_string(&path) else { continue };
        let run = stat.split_whitespace().next().and_then(|f| f.parse::<u64>().ok());
        ns += run.ok_or_else(|| anyhow!("unexpected {}: {stat:?}", path.display()))?;
    }
    Ok(ns as f64 / 1e9)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

/// One load of `bundle`, timed.
fn run_once(bundle: &Bundle) -> Result<(Row, u64)> {
    let mut row: Row = [(0.0, 0.0); PHASES.len() + 1];
    let (mut wall, mut cpu) = (Instant::now(), cpu_seconds()?);
    let (start_wall, start_cpu) = (wall, cpu);
    let mut failed = None;
    let scene = parse_bundle_observed(bundle, &mut |phase| {
        let (now_wall, now_cpu) = (Instant::now(), cpu_seconds());
        let now_cpu = match now_cpu {
            Ok(c) => c,
            Err(e) => {
                failed.get_or_insert(e);
                cpu
            }
        };
        let i = PHASES.iter().position(|(p, _)| *p == phase).expect("every phase is listed");
        row[i].0 += (now_wall - wall).as_secs_f64();
        row[i].1 += now_cpu - cpu;
        (wall, cpu) = (now_wall, now_cpu);
    })
    .map_err(|e| anyhow!("{e}"))?;
    let (end_wall, end_cpu) = (Instant::now(), cpu_seconds()?);
    if let Some(e) = failed {
        return Err(e);
    }
    row[PHASES.len()] = ((end_wall - start_wall).as_secs_f64(), end_cpu - start_cpu);
    let primitives = scene.world.prims.len() as u64;
    // Dropping a large scene takes time of its own: not the load's.
    drop(scene);
    Ok((row, primitives))
}

/// `tessera bench load SCENE`.
pub(super) fn run(scene: &Path, runs: usize, threads: Option<usize>) -> Result<ExitCode> {
    let bundle = Bundle::read(scene)?;
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        pool = pool.num_threads(n);
    }
    let pool = pool.build().context("starting the thread pool")?;
    println!(
        "bench load {}: {} threads, load average {} (1, 5, 15 min) at the start",
        scene.display(),
        pool.current_num_threads(),
        load_average()
    );
    let mut header = format!("{:<7}", "run");
    for (_, name) in PHASES.iter().chain([&(Phase::Rest, "total")]) {
        header.push_str(&format!(" | {name:>15}"));
    }
    println!("{header}");
    println!("{:<7}{}", "", " |     wall    cpu".repeat(PHASES.len() + 1));
    let line = |label: &str, row: &Row| {
        let mut s = format!("{label:<7}");
        for (w, c) in row {
            s.push_str(&format!(" | {w:>8.3} {c:>6.3}"));
        }
        s
    };
    let mut rows = Vec::with_capacity(runs);
    let mut primitives = 0;
    for k in 0..runs {
        let (row, prims) = pool.install(|| run_once(&bundle))?;
        primitives = prims;
        println!("{}", line(&(k + 1).to_string(), &row));
        rows.push(row);
    }
    let mut median: Row = [(0.0, 0.0); PHASES.len() + 1];
    for (i, m) in median.iter_mut().enumerate() {
        let mid = |f: fn(&(f64, f64)) -> f64| {
            let mut v: Vec<f64> = rows.iter().map(|r| f(&r[i])).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        *m = (mid(|p| p.0), mid(|p| p.1));
    }
    println!("{}", line("median", &median));
    println!("{primitives} primitives; load average {} at the end", load_average());
    Ok(ExitCode::SUCCESS)
}
