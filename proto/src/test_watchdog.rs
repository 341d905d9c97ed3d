//! A watchdog for tests that could deadlock.

use std::sync::mpsc;
use std::time::Duration;

/// Aborts the whole test process if it is not dropped within the given time.
pub(crate) struct Watchdog {
    _stop: mpsc::Sender<()>,
}

/// Starts a [`Watchdog`] for `what`: if the guard is still alive after `secs`, the process
/// aborts with a message naming `what` (a hung test fails instead of stalling the suite).
pub(crate) fn watchdog(secs: u64, what: &'static str) -> Watchdog {
    let (stop, stopped) = mpsc::channel::<()>();
    std::thread::spawn(move || {
        if let Err(mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(Duration::from_secs(secs)) {
            eprintln!("watchdog: `{what}` did not finish within {secs} s; aborting");
            std::process::abort();
        }
    });
    Watchdog { _stop: stop }
}
