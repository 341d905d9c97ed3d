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
    /// The scan is unusable (wrong beam count, a NaN range).
    #[error("scan: {0}")]
    Scan(String),
    /// The odometry is unusable (a non-finite value, or older than allowed).
    #[error("odometry: {0}")]
    Odometry(String),
    /// The goal is unusable (a non-finite coordinate).
    #[error("goal: {0}")]
    Goal(String),
    /// The given global path is unusable (empty, or a non-finite point).
    #[error("global path: {0}")]
    Path(String),
}

impl RuntimeError {
    /// The command to issue instead of the refused cycle's: [`STOP`].
    pub fn command(&self) -> Twist {
        STOP
    }
}
