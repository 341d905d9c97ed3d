//! Resident memory of this process, for the replay-memory figure of DESIGN §8.

/// `/proc/self/statm` counts 4 KiB pages on every Linux target this project runs on.
const PAGE_BYTES: u64 = 4096;

/// Resident set size of the current process in bytes, from `/proc/self/statm` (Linux only;
/// `None` elsewhere or if the file cannot be parsed). Thread-safe; reads a file each call.
/// The figure covers the whole process, so measure differences around a single allocation
/// in a process (or test binary) that does nothing else meanwhile.
pub fn resident_set_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * PAGE_BYTES)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resident_set_is_readable_and_plausible() {
        let rss = resident_set_bytes().expect("/proc/self/statm is readable");
        // A running test binary is larger than 1 MiB and smaller than the machine.
        assert!(rss > 1 << 20 && rss < 1 << 40, "rss {rss}");
    }
}
