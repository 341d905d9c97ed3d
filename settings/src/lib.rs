#![warn(missing_docs)]
//! The run's settings as plain data, shared by the simulator, the planners, the actors and
//! the learner: which planner runs ([`PlannerKind`]), how a policy acts ([`ActionSpace`],
//! [`ActionMap`], the objective [`Gains`] and the fidelity [`Schedule`] an action selects), what
//! a planning cycle costs ([`ComputeConfig`]), how the robot responds ([`Profile`],
//! [`Dynamics`]) and the RL environment's settings ([`EnvConfig`]).
//!
//! Everything here is data, parsing, validation and arithmetic: no simulator, no planner, no
//! I/O. So the learner can hold, check and record a run's settings without linking the
//! simulator or the planners; the crates that do the work re-export these types where they
//! have always been (`planner::ActionSpace`, `sim::Profile`, `actor::EnvConfig`, ...) and add
//! the behaviour that needs them (`planner::PlannerConfigs` builds a planner of a
//! [`PlannerKind`]; `actor::AdpEnv` runs an [`EnvConfig`]). Their wire form (`adp.v1`) is
//! `proto::spec`.

pub mod action;
pub mod compute;
pub mod dynamics;
pub mod env;
pub mod error;
pub mod gains;
pub mod kind;
pub mod schedule;

pub use action::{ActionError, ActionMap, ActionSpace, NameError};
pub use compute::{Compute, ComputeConfig, ComputeError, ComputeModel, Platform, UnitCosts, Work};
pub use dynamics::{Dynamics, Profile};
pub use env::{BeamChoices, EnvConfig, EnvConfigError, Randomize, RandomizeError, MAX_BEAM_CHOICES};
pub use error::ConfigError;
pub use gains::{GainRole, Gains, GainsError};
pub use kind::{PlannerFactory, PlannerKind, UnknownPlanner};
pub use schedule::{Schedule, ScheduleError};
