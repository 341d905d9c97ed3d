//! The configuration of a training run (`configs/local.toml`, embedded as the default;
//! [`TrainConfig`]): what to train (`[run]`), the actors' environment (`[env]`), TD3
//! (`[td3]`), the learner process (`[service]`), the actor sandbox (`[sandbox]`), the greedy
//! monitor (`[greedy]`) and the shape of a cluster job (`[slurm]`).
//!
//! `adp train`, `adp learner`, `adp slurm` and `adp experiment` read it; a resolved copy is
//! written into every run directory as `config.toml`, and an experiment keys a training by it.
//! [`job`] makes the sbatch script of a cluster training job from it.

pub mod job;
mod slurm;
mod train;

pub use slurm::{check_time, SlurmSection};
pub use train::{LearnerSection, RunSection, SandboxSection, TrainConfig};

/// What a fresh run's actor starts from (`[service] init_action`, DDP, or its random
/// initialization): `ServiceConfig::start_action` of a config's `[service]`.
pub use learner_service::StartAction;
