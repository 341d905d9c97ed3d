//! ADP on a robot: a local planner (DWA, MPPI, Log-MPPI or the standalone system) and its
//! trained schedule policy, driven by the robot's own scans, odometry and goal, one control
//! cycle per call.
//!
//! ```no_run
//! use adp_runtime::{CycleInput, Navigator, Odometry};
//! use sim::geometry::{Pose, Vec2};
//! use sim::robot::Twist;
//!
//! let mut nav = Navigator::from_file("runtime.toml".as_ref())?;
//! let ranges = vec![10.0; nav.lidar().angles().len()];
//! let out = nav.cycle(&CycleInput {
//!     stamp_s: 0.0,
//!     ranges: &ranges,
//!     odom: Odometry { pose: Pose::new(0.0, 0.0, 0.0), vel: Twist::default(), stamp_s: 0.0 },
//!     goal: Vec2::new(0.0, 10.0),
//!     global_path: None,
//! })?;
//! println!("v = {} m/s, w = {} rad/s", out.command.v, out.command.w);
//! # Ok::<(), adp_runtime::RuntimeError>(())
//! ```
//!
//! * [`Navigator`] holds one robot's planner, costmap, global path and policy; each
//!   [`Navigator::cycle`] runs the simulator's closed loop on real inputs (the same code:
//!   `sim::nav_stack`, `planner::run::CycleDriver`, `policy::agent_action`), so a world
//!   driven through it repeats `adp eval`'s episode bit for bit.
//! * [`input`] states the inputs' units and frames and checks them.
//! * [`envelope`] states the inputs and settings accepted (so no input aborts the process or
//!   makes a cycle unbounded) and the limits every command is clamped to.
//! * [`config`] reads the runtime's configuration file: the planner, the policy, the
//!   robot's laser (any beam count and field of view; mounted anywhere on the base, its
//!   scans re-projected to the base origin).
//! * [`RuntimeError`] names what was refused (or the panic caught); [`STOP`] is the command
//!   to issue then.
//! * [`sim_robot`] is a simulated robot: a BARN episode observed and driven as a robot is.

#![warn(missing_docs)]

pub mod config;
pub mod envelope;
pub mod error;
pub mod input;
mod laser;
pub mod navigator;
pub mod sim_robot;

pub use config::{load_policy, FixedSchedule, RuntimeOptions};
pub use envelope::CommandLimits;
pub use error::{RuntimeError, STOP};
pub use input::{CycleInput, Odometry};
pub use navigator::{CycleOutput, Navigator, ScheduleSummary};
