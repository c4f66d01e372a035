//! What the machine has, for the default memory budgets of the coordinator and the worker:
//! its memory as `/proc/meminfo` reports it (Linux; elsewhere `None`, and the callers fall
//! back to fixed figures). A cgroup limit below it is not seen.

/// The machine's memory (`MemTotal`), in bytes.
pub fn total_memory() -> Option<u64> {
    meminfo("MemTotal")
}

/// The memory available for new work now (`MemAvailable`: free plus reclaimable), in bytes.
pub fn available_memory() -> Option<u64> {
    meminfo("MemAvailable")
}

fn meminfo(key: &str) -> Option<u64> {
    parse_meminfo(&std::fs::read_to_string("/proc/meminfo").ok()?, key)
}

fn parse_meminfo(text: &str, key: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.split(':').next() == Some(key))?;
    let kib: u64 = line.split(':').nth(1)?.trim().strip_suffix("kB")?.trim().parse().ok()?;
    kib.checked_mul(1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn meminfo_lines_are_read_in_kib() {
        let text = "MemTotal:       16303656 kB\nMemFree:         1234 kB\nMemAvailable:   8000000 kB\n";
        assert_eq!(parse_meminfo(text, "MemTotal"), Some(16_303_656 * 1024));
        assert_eq!(parse_meminfo(text, "MemAvailable"), Some(8_000_000 * 1024));
        assert_eq!(parse_meminfo(text, "Mem"), None);
        assert_eq!(parse_meminfo("MemTotal: lots\n", "MemTotal"), None);
        if cfg!(target_os = "linux") {
            assert!(total_memory().unwrap() >= available_memory().unwrap());
        }
    }
}
