//! [`RuntimeError`]: what the runtime refuses, and the command a robot issues then.

use sim::robot::Twist;

/// The command to issue when a call fails: stop. The runtime never returns a motion command
/// with an error; a robot stack publishes this (or its own safe stop) instead.
pub const STOP: Twist = Twist { v: 0.0, w: 0.0 };

/// Why the runtime could not be built or could not run a cycle. Its message is one line naming
/// the input and the fault. A refused cycle changes nothing: the next good cycle continues as
/// if the bad one had not been offered.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// The runtime configuration (a file, or the values given in code) cannot be used.
    #[error("{origin}: {message}")]
    Config {
        /// The file, or `runtime configuration` for values given in code.
        origin: String,
        /// What is wrong, naming the key.
        message: String,
    },
    /// The policy export cannot be loaded or does not fit the planner and lidar.
    #[error("{0}")]
    Policy(String),
    /// The scan is unusable (wrong beam count, a NaN range when `nan_as_no_return` is off).
    #[error("scan: {0}")]
    Scan(String),
    /// The odometry is unusable (a non-finite value, a pose outside the envelope, or older
    /// than allowed).
    #[error("odometry: {0}")]
    Odometry(String),
    /// The goal is unusable (a non-finite coordinate, or outside the envelope: too far from
    /// the robot).
    #[error("goal: {0}")]
    Goal(String),
    /// The given global path is unusable (empty, too long, or a point not finite or outside
    /// the envelope).
    #[error("global path: {0}")]
    Path(String),
    /// A defect inside the runtime: a panic, caught. The navigator has dropped its run (the
    /// next cycle starts afresh, as for a new goal) and stays usable.
    #[error("internal error: {0}")]
    Internal(String),
}

/// Runs `f`, turning a panic into [`RuntimeError::Internal`] with the panic's message.
pub(crate) fn guarded<T>(f: impl FnOnce() -> Result<T, RuntimeError>) -> Result<T, RuntimeError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into());
        Err(RuntimeError::Internal(what))
    })
}

impl RuntimeError {
    /// The command to issue instead of the refused cycle's: [`STOP`].
    pub fn command(&self) -> Twist {
        STOP
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_an_internal_error_with_its_message() {
        let err = guarded::<()>(|| panic!("index {} out of range", 7)).unwrap_err();
        assert!(matches!(err, RuntimeError::Internal(_)));
        assert_eq!(err.to_string(), "internal error: index 7 out of range");
        assert_eq!(err.command(), STOP);
        let err = guarded::<()>(|| std::panic::panic_any(3u8)).unwrap_err();
        assert_eq!(err.to_string(), "internal error: a panic without a message");
        assert_eq!(guarded(|| Ok(5)).unwrap(), 5);
    }
}
