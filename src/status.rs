//! `tessera status`'s table: the coordinator's jobs, each with how it may end and a
//! sequence's frames under it, then its workers.

use tessera_proto::convert::{halted_from_wire, settings_from_wire, state_name};
use tessera_proto::v1 as pb;

/// The table `tessera status` prints for the coordinator's answer `s`; with `each_frame`, a
/// line per frame of a sequence.
pub fn table(s: &pb::StatusResponse, each_frame: bool) -> String {
    let mut out = String::new();
    macro_rules! outln {
        ($o:ident, $($arg:tt)*) => {{
            use std::fmt::Write as _;
            let _ = writeln!($o, $($arg)*);
        }};
    }
    outln!(
        out,
        "{:>5}  {:<10} {:>5} {:>7}  {:>6} {:>4} {:>16}  scene",
        "job",
        "state",
        "pass",
        "done",
        "spp",
        "prio",
        "rate"
    );
    for j in &s.jobs {
        let state = state_name(j.state);
        // A job that ended at its noise target or time budget is done, short of its spp:
        // the line under it says how far it got.
        let finished = j.state == pb::JobState::Done as i32;
        let done =
            if finished { 100.0 } else { j.samples_done as f64 / j.samples_total.max(1) as f64 * 100.0 };
        outln!(
            out,
            "{:>5}  {:<10} {:>5} {:>6.1}%  {:>6} {:>4} {:>16}  {} ({}x{}){}",
            j.job_id,
            state,
            j.pass,
            done,
            j.spp,
            j.priority,
            crate::report::rate(j.samples_per_second),
            j.scene,
            j.width,
            j.height,
            if j.error.is_empty() { String::new() } else { format!(": {}", j.error) }
        );
        if let Some(line) = ending_line(j) {
            outln!(out, "{line}");
        }
        if let Some(f) = &j.frames {
            out.push_str(&frames_lines(f, &j.frame_status, each_frame));
        }
    }
    outln!(out, "");
    outln!(out, "{:>6}  {:<24} {:>7} {:>9} {:>12}", "worker", "name", "threads", "in flight", "batches done");
    for w in &s.workers {
        outln!(
            out,
            "{:>6}  {:<24} {:>7} {:>9} {:>12}",
            w.worker_id,
            w.name,
            w.threads,
            w.batches_in_flight,
            w.batches_done
        );
    }
    if s.workers.is_empty() {
        outln!(out, "(no workers connected)");
    }
    out
}

/// The line under a job in `tessera status` that says how it ended before its spp (a
/// finished job that its noise target or time budget stopped), or how it may (one still to
/// finish, with a target or a budget); `None` otherwise, or from a coordinator too old to
/// say.
fn ending_line(j: &pb::JobStatus) -> Option<String> {
    let ongoing = [pb::JobState::Queued, pb::JobState::Running, pb::JobState::Paused].map(|s| s as i32);
    let halted = halted_from_wire(&j.halted).filter(|_| j.state == pb::JobState::Done as i32);
    if let Some(halted) = halted {
        let frames = j.frames.map_or(1, |f| u64::from(f.last.saturating_sub(f.first)) + 1);
        let pixels = (u64::from(j.width) * u64::from(j.height) * frames).max(1);
        return Some(format!(
            "       ended by its {} at {:.1} samples a pixel on average, of at most {}",
            halted,
            j.samples_done as f64 / pixels as f64,
            j.spp
        ));
    }
    if !ongoing.contains(&j.state) {
        return None;
    }
    match settings_from_wire(j.settings?) {
        Ok(s) => s.early_end().map(|e| format!("       ends {e}")),
        Err(e) => Some(format!("       (the coordinator sent settings that make no sense: {e})")),
    }
}

/// A sequence's lines under its job in `tessera status`: the frames done, rendering and
/// with their pass one; with `each_frame`, a line per frame.
fn frames_lines(range: &pb::FrameRange, frames: &[pb::FrameStatus], each_frame: bool) -> String {
    let done = frames.iter().filter(|f| f.samples_done >= f.samples_total).count();
    let started = frames.iter().filter(|f| f.samples_done > 0 && f.samples_done < f.samples_total).count();
    let previewed = frames.iter().filter(|f| f.pass_one_done > 0).count();
    let mut out = format!(
        "       frames {}-{}: {done} of {} done, {started} rendering, {previewed} with a preview\n",
        range.first,
        range.last,
        frames.len()
    );
    if each_frame {
        for f in frames {
            let pct = f.samples_done as f64 / f.samples_total.max(1) as f64 * 100.0;
            out.push_str(&format!(
                "       frame {:>5} {:>6.1}%  pass one {} pixels\n",
                f.frame, pct, f.pass_one_done
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;
    use tessera_description::job::{JobSettings, Noise};
    use tessera_proto::convert::settings_to_wire;

    fn job(id: u64, settings: Option<JobSettings>) -> pb::JobStatus {
        pb::JobStatus {
            job_id: id,
            scene: "spheres.toml".into(),
            state: pb::JobState::Running as i32,
            width: 64,
            height: 32,
            spp: 256,
            pass: 2,
            samples_done: 64 * 32 * 64,
            samples_total: 64 * 32 * 256,
            settings: settings.as_ref().map(settings_to_wire),
            ..Default::default()
        }
    }

    #[test]
    fn a_job_says_how_it_may_end_under_its_line() {
        let target = JobSettings {
            noise: Some(Noise::Relative(0.02)),
            time_limit: Some(Duration::from_secs(600)),
            ..JobSettings::default()
        };
        let s = pb::StatusResponse {
            jobs: vec![job(1, Some(target)), job(2, Some(JobSettings::sized(Some(256), None))), job(3, None)],
            workers: vec![],
        };
        let out = table(&s, false);
        let lines: Vec<&str> = out.lines().collect();
        assert!(lines[1].starts_with("    1  running") && lines[1].contains("25.0%"), "{out}");
        assert_eq!(
            lines[2],
            "       ends at a relative noise of 0.02, each pixel after at least 16 samples, or when its time budget of 600s is spent"
        );
        // A job that runs to its spp, and one from a coordinator too old to send settings:
        // no line.
        assert!(lines[3].starts_with("    2  running") && lines[4].starts_with("    3  running"), "{out}");
        assert!(out.contains("(no workers connected)"), "{out}");
    }

    /// A finished job says why it stopped short of its spp, and shows as all done; a
    /// cancelled one says nothing of how it would have ended.
    #[test]
    fn a_finished_job_says_what_ended_it() {
        let target = JobSettings { noise: Some(Noise::Absolute(0.05)), ..JobSettings::default() };
        let mut done = job(4, Some(target.clone()));
        done.state = pb::JobState::Done as i32;
        done.halted = "noise target".into();
        let mut cancelled = job(5, Some(target));
        cancelled.state = pb::JobState::Cancelled as i32;
        // A reason this build does not know is not printed: it comes from the coordinator.
        let mut unknown = done.clone();
        unknown.job_id = 6;
        unknown.halted = "\u{1b}[2Jthe moon".into();
        let out = table(&pb::StatusResponse { jobs: vec![done, cancelled, unknown], workers: vec![] }, false);
        let lines: Vec<&str> = out.lines().collect();
        assert!(lines[1].starts_with("    4  done") && lines[1].contains("100.0%"), "{out}");
        assert_eq!(
            lines[2],
            "       ended by its noise target at 64.0 samples a pixel on average, of at most 256"
        );
        assert!(lines[3].starts_with("    5  cancelled") && lines[3].contains("25.0%"), "{out}");
        assert!(lines[4].starts_with("    6  done") && lines[5].is_empty(), "{out}");
    }

    /// A coordinator may lie: settings no submission could have are shown as nonsense, in
    /// one line, not trusted and not a failure.
    #[test]
    fn nonsense_settings_are_named_not_shown() {
        let mut lying = job(7, Some(JobSettings::default()));
        let wire = lying.settings.as_mut().unwrap();
        wire.noise = 0.1;
        wire.noise_absolute = 0.2;
        let out = table(&pb::StatusResponse { jobs: vec![lying], workers: vec![] }, false);
        let line = out.lines().nth(2).unwrap();
        assert!(line.starts_with("       (the coordinator sent settings that make no sense:"), "{out}");
        assert!(line.contains("not both"), "{out}");
    }
}
