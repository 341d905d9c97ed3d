#![warn(missing_docs)]
//! A trained policy as a robot runs it, without the learner, an async runtime or a network
//! stack: what the runtime (`adp-runtime`), the RL environment (`adp-actor`) and evaluation
//! (`adp-eval`) share to run one.
//!
//! - [`learned`]: an export directory (the card and weights of the `adp-policy-file` crate)
//!   loaded and checked against this build's environment: a [`LearnedPolicy`].
//! - [`mlp`]: the actor network ([`MlpPolicy`]: ReLU hidden layers, tanh output) evaluated on
//!   the CPU from its flat weights, without allocating per call.
//! - [`observation`]: the observation vector the network reads (the encoded lidar ranges,
//!   resampled from any lidar; the previous action, velocity, local and global goal, tracks),
//!   the layout the policy card documents, built from the robot's perception.
//! - [`agent_action`]: the network's output turned into the planner's schedule (or gains, or
//!   the velocity command), and the previous action the next observation shows.
//!
//! Everything here is pure and deterministic but [`learned::load`], which reads the export's
//! files.

pub mod agent_action;
pub mod learned;
pub mod mlp;
pub mod observation;

pub use learned::{card_path, load, LearnedPolicy, LoadError};
pub use mlp::{param_count, MlpPolicy, PolicyError, Scratch};
pub use observation::{obs_dim, LaserLayout, LaserResampler, LASER_BEAMS};
