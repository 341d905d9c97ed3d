//! The actor side of ADP training: the RL environment and CPU inference of the policy.
//!
//! * [`env::AdpEnv`] wraps one BARN [`sim::Episode`] and one [`planner::Planner`]. Every
//!   agent step (0.25 s: five 0.05 s planner cycles) the agent's normalized action becomes
//!   the planner's rollout schedule through an [`planner::ActionSpace`]; the step returns the
//!   reward (progress, step and obstacle penalties, collision / timeout / success terms) and
//!   whether the episode ended as a true terminal or was truncated by a time limit.
//! * [`observation`] defines the observation vector (the encoded lidar ranges, 720 or one per
//!   sector, resampled from any lidar; the previous action, velocity, local and global goal):
//!   the layout the exported policy card documents.
//! * [`agent_action`] turns the policy's output into the planner's schedule (or gains, or
//!   the velocity command) and keeps the previous action the observation shows.
//! * [`reward`] holds the scan-dependent reward term as pure functions.
//! * [`MlpPolicy`] ([`policy`]) evaluates the actor network (ReLU hidden layers, tanh output)
//!   from the flat weight vector the learner publishes, without allocating per call;
//!   [`exploration::Exploration`] adds seeded Gaussian noise for data collection.
//!
//! [`observation`], [`agent_action`] and [`policy`] are the `adp-policy` crate's (its `mlp`
//! module is [`policy`] here), re-exported under these paths: a robot's runtime shares them
//! without linking this crate's async runtime and network stack.
//!
//! * [`closed_loop`] runs one episode whatever chooses its schedule (a fixed schedule, a
//!   constant action, a network greedily or with exploration noise): the one closed loop
//!   that evaluation, training's greedy evaluation, experiments and the actor process share.
//!
//! * [`spec`] converts the run's planner, action space and environment settings to and from
//!   their `adp.v1` messages (`proto::spec`, re-exported).
//!
//! The plain settings ([`EnvConfig`], the action spaces, the planner kind) are the
//! `adp-settings` crate's, which the learner shares without linking the simulator; they are
//! re-exported here and in `planner` under their usual paths.
//!
//! * [`run`] is the actor process loop (register, take assignments, stream steps, report
//!   episodes) over the learner's planes.
//!
//! Everything but [`run`] is pure and deterministic given seeds and actions: no I/O, no
//! clocks; [`run`] holds the process's I/O, clocks and back-off.

#![warn(missing_docs)]

pub mod closed_loop;
pub mod env;
pub mod exploration;
pub mod reward;
pub mod run;
pub mod spec;
pub mod stuck;

/// The actor network's CPU inference: the `adp-policy` crate's `mlp`.
pub use ::policy::mlp as policy;
pub use ::policy::{agent_action, observation};
pub use ::policy::{
    obs_dim, param_count, LaserLayout, LaserResampler, MlpPolicy, PolicyError, Scratch, LASER_BEAMS,
};
pub use env::{AdpEnv, End, EnvConfig, EnvError, EnvResult, StepOutcome};
pub use exploration::Exploration;
