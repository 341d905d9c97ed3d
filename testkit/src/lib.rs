//! Helpers shared by the tests of every crate in the workspace: defined once here, used as a
//! dev-dependency (nothing in it ships).

pub mod netem;
pub mod process;

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

/// A fresh, empty directory `<root>/<name>-<pid>` (emptied first if it exists; the process id
/// keeps overlapping test runs on one machine apart).
pub fn fresh_dir_in(root: &Path, name: &str) -> PathBuf {
    let dir = root.join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("creating {}: {e}", dir.display()));
    dir
}

/// A fresh, empty directory `<system temp>/adp-<name>-<pid>`.
pub fn fresh_dir(name: &str) -> PathBuf {
    fresh_dir_in(&std::env::temp_dir(), &format!("adp-{name}"))
}

/// Aborts the whole test process if it is not dropped within the given time.
pub struct Watchdog {
    _stop: mpsc::Sender<()>,
}

/// Starts a [`Watchdog`] for `what`: if the guard is still alive after `secs`, the process
/// aborts with a message naming `what` (a hung test fails instead of stalling the suite).
pub fn watchdog(secs: u64, what: &'static str) -> Watchdog {
    let (stop, stopped) = mpsc::channel::<()>();
    std::thread::spawn(move || {
        if let Err(mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(Duration::from_secs(secs)) {
            eprintln!("watchdog: `{what}` did not finish within {secs} s; aborting");
            std::process::abort();
        }
    });
    Watchdog { _stop: stop }
}

#[cfg(test)]
mod tests {
    #[test]
    fn fresh_dirs_are_empty_and_distinct() {
        let a = super::fresh_dir("testkit-a");
        std::fs::write(a.join("f"), "x").unwrap();
        let again = super::fresh_dir("testkit-a");
        assert_eq!(a, again);
        assert!(std::fs::read_dir(&again).unwrap().next().is_none());
        assert_ne!(again, super::fresh_dir("testkit-b"));
        std::fs::remove_dir_all(&again).unwrap();
        std::fs::remove_dir_all(super::fresh_dir("testkit-b")).unwrap();
    }
}
