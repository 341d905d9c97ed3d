//! What can go wrong in the learner process, one error type per operation a caller handles
//! differently: the service settings ([`SettingsError`]), resuming a run ([`ResumeError`]),
//! starting the learner ([`StartError`]), training ([`TrainError`]), reading the newest policy
//! ([`PolicyError`]) and the run directory's files ([`FileError`], [`StatusFileError`]).
//!
//! Each message is one line and names what was wrong and where, including the underlying OS,
//! checkpoint or registry error, which is also the [`std::error::Error::source`] where there is
//! one.

use std::path::PathBuf;

use learner::checkpoint::CheckpointError;
use thiserror::Error;

/// A file, socket, directory or thread operation that failed.
#[derive(Debug, Error)]
#[error("{what}: {source}")]
pub struct FileError {
    /// What was attempted, e.g. `cannot write runs/x/learner.addr`.
    pub what: String,
    /// The OS error.
    #[source]
    pub source: std::io::Error,
}

impl FileError {
    /// A [`FileError`] for `what`, to map an OS error with.
    pub fn at(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let what = what.into();
        move |source| Self { what, source }
    }
}

/// `[service]` settings that cannot work ([`crate::ServiceConfig::check`],
/// [`crate::ServiceConfig::check_init_action`]).
#[derive(Debug, Error, PartialEq)]
pub enum SettingsError {
    /// `init_action` has another number of values than the action space's dimensions.
    #[error("[service] init_action has {len} values, but the {space} action space has {dim} dimensions")]
    InitActionLength {
        /// Its number of values.
        len: usize,
        /// The run's action space.
        space: String,
        /// The space's dimensions.
        dim: usize,
    },
    /// A value of `init_action` is outside [-1, 1] (or not a number).
    #[error("[service] init_action[{index}] = {value} is outside [-1, 1] (normalized actions)")]
    InitActionValue {
        /// Its index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// Shared memory is on with no port for actors.
    #[error("[service] shm_max_actors must be at least 1 while shared_memory = true")]
    ShmMaxActors,
    /// The lease is not longer than the heartbeat (or the heartbeat is 0).
    #[error("[service] lease_ttl_ms ({lease_ttl_ms}) must exceed heartbeat_ms ({heartbeat_ms}) > 0")]
    LeaseTtl {
        /// `[service] lease_ttl_ms`.
        lease_ttl_ms: u32,
        /// `[service] heartbeat_ms`.
        heartbeat_ms: u32,
    },
    /// The no-progress timeout is not longer than the heartbeat.
    #[error(
        "[service] progress_timeout_ms ({progress_timeout_ms}) must exceed heartbeat_ms ({heartbeat_ms})"
    )]
    ProgressTimeout {
        /// `[service] progress_timeout_ms`.
        progress_timeout_ms: u32,
        /// `[service] heartbeat_ms`.
        heartbeat_ms: u32,
    },
    /// A connection limit or deadline of 0, which would refuse every connection.
    #[error("[service] {key} must be at least 1 (0 would refuse every connection)")]
    ZeroConnectionLimit {
        /// The key (`max_connections`, `max_connections_per_ip`, `handshake_timeout_ms` or
        /// `auth_deadline_ms`).
        key: &'static str,
    },
    /// A budget of incomplete request bytes that a largest request cannot fit.
    #[error(
        "[service] max_incomplete_bytes_per_connection ({per_connection}) must be at least \
         {least} (a largest request with its head) and max_incomplete_bytes ({total}) at least \
         max_incomplete_bytes_per_connection"
    )]
    IncompleteBytes {
        /// `max_incomplete_bytes_per_connection`.
        per_connection: u64,
        /// `max_incomplete_bytes`.
        total: u64,
        /// The least per-connection budget.
        least: u64,
    },
    /// A network address other than loopback without TLS, and insecure listening not allowed.
    #[error(
        "refusing to listen on {listen} without TLS (the run's token would cross the network in clear \
         text): configure [service.tls], or pass --allow-insecure-listen \
         ([service] allow_insecure_listen = true) on a trusted network"
    )]
    InsecureListen {
        /// `[service] listen`.
        listen: String,
    },
}

/// Why a run directory cannot be resumed (or, without `--resume`, started fresh).
#[derive(Debug, Error)]
pub enum ResumeError {
    /// `--resume` without a complete checkpoint in the run directory.
    #[error("--resume: no complete checkpoint under {}", dir.display())]
    NothingToResume {
        /// The checkpoints directory.
        dir: PathBuf,
    },
    /// A fresh run in a run directory that already holds checkpoints.
    #[error(
        "{} already holds a run (checkpoint {}); pass --resume to continue it or choose another --out",
        run_dir.display(),
        checkpoint.display()
    )]
    RunExists {
        /// The run directory.
        run_dir: PathBuf,
        /// Its newest complete checkpoint.
        checkpoint: PathBuf,
    },
    /// `--resume`, and no complete checkpoint loads.
    #[error(
        "--resume under {}: none of the {tried} checkpoints is usable: {}",
        dir.display(),
        warnings.join("; ")
    )]
    NoUsableCheckpoint {
        /// The checkpoints directory.
        dir: PathBuf,
        /// How many were tried.
        tried: usize,
        /// Why each one was skipped.
        warnings: Vec<String>,
    },
    /// A checkpoint's registry state does not parse.
    #[error("{}: registry state: {source}", checkpoint.display())]
    RegistryState {
        /// The checkpoint.
        checkpoint: PathBuf,
        /// The parser's error.
        source: serde_json::Error,
    },
    /// A checkpoint's registry state does not fit the run's registry settings.
    #[error("{}: registry state: {source}", checkpoint.display())]
    Registry {
        /// The checkpoint.
        checkpoint: PathBuf,
        /// The registry's refusal.
        source: scheduler::RegistryError,
    },
    /// A checkpoint could not be read.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
}

/// Why the learner did not start ([`crate::Learner::start`]).
#[derive(Debug, Error)]
pub enum StartError {
    /// The `[service]` settings cannot work.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The `[learner]` device cannot be opened.
    #[error("[learner] {0}")]
    Device(#[from] learner::DeviceError),
    /// The run cannot be resumed or started fresh in its directory.
    #[error(transparent)]
    Resume(#[from] ResumeError),
    /// A file, socket, directory, runtime or thread could not be made.
    #[error(transparent)]
    File(#[from] FileError),
    /// A Unix socket path longer than `sockaddr_un` holds.
    #[error("{} is longer than a socket path may be", .0.display())]
    SocketPath(PathBuf),
    /// Another learner holds the run directory's lock.
    #[error(
        "{} is in use by another learner ({holder}; lock file {}): stop it first or choose another --out",
        run_dir.display(),
        lock.display()
    )]
    InUse {
        /// The run directory.
        run_dir: PathBuf,
        /// The holder's host and pid, as it recorded them.
        holder: String,
        /// The lock file.
        lock: PathBuf,
    },
    /// The scheduler's registry refused its configuration (the training worlds).
    #[error("[run] worlds: {0}")]
    Registry(#[source] scheduler::RegistryError),
    /// The networks could not be built.
    #[error("[td3]: {0}")]
    Td3(#[source] learner::td3::Td3Error),
    /// The actor could not be fitted to its start action (the DDP schedule, or `[service]
    /// init_action`).
    #[error("actor initialization (ddp_init or init_action): {0}")]
    DdpInit(#[source] learner::ddp_init::FitError),
    /// `[td3]` sizes that do not fit the run's action space and laser layout.
    #[error(
        "[td3] obs_dim {obs_dim} / act_dim {act_dim} / laser_dim {laser_dim} do not fit the {space} action \
         space with the {laser} laser layout ({space_obs_dim} / {space_act_dim} / at most {laser_size})"
    )]
    SpaceMismatch {
        /// `[td3] obs_dim`.
        obs_dim: usize,
        /// `[td3] act_dim`.
        act_dim: usize,
        /// `[td3] laser_dim`.
        laser_dim: usize,
        /// The action space.
        space: String,
        /// The laser layout (`env.observation`).
        laser: layout::LaserLayout,
        /// Its observation size.
        space_obs_dim: usize,
        /// Its action size.
        space_act_dim: usize,
        /// Its laser values: `laser_dim` may not exceed them (the replay stores that many
        /// leading values as laser).
        laser_size: usize,
    },
    /// The environment settings the actors would be sent are invalid.
    #[error("[env]: {0}")]
    Env(#[source] settings::EnvConfigError),
    /// The run's settings cannot be put on the wire (`RunSpec`).
    #[error("the run spec: {0}")]
    Spec(#[source] proto::spec::SpecError),
    /// The TensorBoard event file could not be created or resumed.
    #[error(transparent)]
    TensorBoard(#[from] learner::tensorboard::TensorBoardError),
    /// The token or TLS files could not be read.
    #[error(transparent)]
    Auth(#[from] proto::auth::AuthError),
    /// The server refused the TLS configuration.
    #[error("TLS: {0}")]
    Tls(#[source] tonic::transport::Error),
}

/// Why training stopped with an error ([`crate::Learner::wait`]).
#[derive(Debug, Error)]
pub enum TrainError {
    /// The checkpoints directory could not be made.
    #[error(transparent)]
    File(#[from] FileError),
    /// A checkpoint could not be written.
    #[error("checkpoint {}: {source}", dir.display())]
    Save {
        /// The checkpoint directory.
        dir: PathBuf,
        /// Why.
        source: CheckpointError,
    },
    /// The replay buffer could not be copied for a checkpoint.
    #[error("copying the replay buffer for {}: {source}", dir.display())]
    ReplayCopy {
        /// The checkpoint directory.
        dir: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Sampling the replay buffer failed.
    #[error("sampling the replay buffer: {0}")]
    Sample(#[source] learner::replay::ReplayError),
    /// A TD3 update failed.
    #[error("TD3 update: {0}")]
    Update(#[source] learner::td3::Td3Error),
    /// The training thread panicked.
    #[error("the training thread panicked")]
    Panicked,
}

/// The newest published policy's weights do not decode ([`crate::Learner::latest_policy`]).
#[derive(Debug, Error)]
#[error("policy version {version}: {source}")]
pub struct PolicyError {
    /// The version.
    pub version: u64,
    /// Why.
    #[source]
    pub source: proto::floats::RaggedBytes,
}

/// `status.json` cannot be read ([`crate::status::read_status`]).
#[derive(Debug, Error)]
pub enum StatusFileError {
    /// The file cannot be read.
    #[error(transparent)]
    File(#[from] FileError),
    /// It does not parse.
    #[error("{}: {source}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's error.
        source: serde_json::Error,
    },
}
