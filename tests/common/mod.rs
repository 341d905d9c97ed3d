//! Helpers shared by the multi-process service tests (`service.rs`, `faults.rs`).

use std::path::{Path, PathBuf};
use std::process::Command;

use adp_learner::service::{read_status, Status};

/// The `adp` binary under test.
pub fn adp() -> Command {
    Command::new(env!("CARGO_BIN_EXE_adp"))
}

/// An empty directory `<target>/tmp/<name>`.
pub fn fresh_dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The run's `status.json`, when it is there and readable.
pub fn status(run: &Path) -> Option<Status> {
    read_status(run).ok()
}

/// How many messages of `kind` the learner refused.
pub fn refused(s: &Status, kind: &str) -> u64 {
    s.refused.iter().find(|(k, _)| k == kind).map_or(0, |r| r.1)
}
