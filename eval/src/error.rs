//! [`Error`]: what can go wrong in an evaluation, a policy load, the greedy monitor or a
//! picture.

use std::path::PathBuf;

/// An error of this crate. Its message is one line that names what failed and where: the
/// file, the world and run, the option or the configuration key.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read, created or written.
    #[error("cannot {action} {}: {source}", path.display())]
    Io {
        /// What was being done: `read config`, `write`, `create`, ...
        action: &'static str,
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A configuration (a file, or an option that overrides it) holds a value that cannot be
    /// used.
    #[error("{origin}: {message}")]
    Config {
        /// Where the value comes from: the file, or the options that set it.
        origin: String,
        /// What is wrong with it.
        message: String,
    },
    /// An evaluation, a greedy monitor or a picture was asked something it cannot do (no
    /// runs, a speed over the robot's, a world that does not exist, a policy that does not fit
    /// the rows); the message names the option.
    #[error("{0}")]
    Refused(String),
    /// A policy file or export directory is unusable.
    #[error("policy {}: {message}", path.display())]
    Policy {
        /// The file at fault.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A world cannot be loaded.
    #[error("world {world} cannot be loaded: {message}")]
    World {
        /// The world's id.
        world: usize,
        /// Why.
        message: String,
    },
    /// An episode failed.
    #[error("world {world}, run {run}: {source}")]
    Episode {
        /// The world's id.
        world: usize,
        /// The run's index within the world.
        run: usize,
        /// Why.
        #[source]
        source: actor::EnvError,
    },
    /// A component this crate drives (a planner's schedule or compute model, the residual
    /// corrector, the newest policy of a training run) refused; `context` says which.
    #[error("{context}: {source}")]
    Component {
        /// What was being set up.
        context: String,
        /// Its error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Drawing a picture failed.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// The greedy evaluation of a training run's newest policy failed.
    #[error("greedy evaluation failed: {0}")]
    Greedy(#[source] Box<Error>),
    /// The greedy evaluation's thread panicked.
    #[error("greedy evaluation panicked")]
    Panicked,
}

impl Error {
    /// An [`Error::Io`] of `action` on `path`.
    pub fn io(action: &'static str, path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            action,
            path: path.into(),
            source,
        }
    }

    /// An [`Error::Policy`] of `path`.
    pub fn policy(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Policy {
            path: path.into(),
            message: message.into(),
        }
    }

    /// An [`Error::Component`]: `source` while setting up `context`.
    pub fn component(
        context: impl Into<String>,
        source: impl Into<Box<dyn std::error::Error + Send + Sync>>,
    ) -> Self {
        Self::Component {
            context: context.into(),
            source: source.into(),
        }
    }
}

impl From<eval_config::ConfigError> for Error {
    fn from(e: eval_config::ConfigError) -> Self {
        match e {
            eval_config::ConfigError::Read { path, source } => Self::io("read config", path, source),
            eval_config::ConfigError::Invalid { origin, message } => Self::Config { origin, message },
        }
    }
}

impl From<policy::LoadError> for Error {
    fn from(e: policy::LoadError) -> Self {
        Self::Policy {
            path: e.path,
            message: e.message,
        }
    }
}

impl From<actor::EnvError> for Error {
    fn from(e: actor::EnvError) -> Self {
        Self::component("the RL environment", e)
    }
}

/// A result of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
