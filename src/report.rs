//! What the CLI tells people, shared by local renders, remote clients and benchmarks:
//! rates in human units and what a data directory held.

use std::path::Path;

use tessera_coordinator::Recovery;

/// Samples per second in human units.
pub fn rate(samples_per_second: f64) -> String {
    if samples_per_second >= 1e6 {
        format!("{:.2} Msamples/s", samples_per_second / 1e6)
    } else {
        format!("{:.0} ksamples/s", samples_per_second / 1e3)
    }
}

/// Says what was found in a data directory: jobs taken up again, and any damage.
pub fn report_recovery(dir: &Path, recovery: &Recovery) {
    for p in &recovery.problems {
        eprintln!("warning: {}: {p}", dir.display());
    }
    for r in &recovery.resumed {
        let pct = r.samples_kept as f64 / r.samples_total.max(1) as f64 * 100.0;
        eprintln!(
            "resumed job {} ({}) from {}: {pct:.1}% done, {} of {} samples kept",
            r.id.0,
            r.state.name(),
            dir.display(),
            r.samples_kept,
            r.samples_total
        );
    }
}
