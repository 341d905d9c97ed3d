//! Helpers for tests that touch the filesystem.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A fresh directory under `target/tmp/scheduler-tests/`, removed on drop.
pub struct TempDir(PathBuf);

impl TempDir {
    /// Creates `target/tmp/scheduler-tests/<name>-<pid>` (emptied first if it exists).
    pub fn new(name: &str) -> Self {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/tmp/scheduler-tests");
        let dir = testkit::fresh_dir_in(&root, name);
        Self(dir.canonicalize().expect("the directory was just created"))
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Writes an executable script through a shell, so that no file descriptor open for writing
/// exists in this (multi-threaded, forking) test process: a descriptor inherited by another
/// test's child between fork and exec would make executing the script fail with ETXTBSY.
pub fn write_executable(path: &Path, content: &str) {
    let status = Command::new("/bin/sh")
        .args([
            "-c",
            "printf '%s' \"$1\" > \"$2\" && chmod 755 \"$2\"",
            "sh",
            content,
        ])
        .arg(path)
        .status()
        .expect("running /bin/sh");
    assert!(status.success(), "writing {}", path.display());
}
