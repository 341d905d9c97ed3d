//! Sampling local planners over fidelity schedules.
//!
//! Every planner maps what the robot perceives (lidar points in the robot frame, velocity,
//! local path and goal) plus a [`Schedule`] to a velocity command, behind one trait,
//! [`Planner`]. Schedules come from fixed strategies (vanilla, DDP) or a trained policy (ADP);
//! the [`Prediction`] says how rollouts model the robot (the papers' forward Euler with checks
//! at grid points, or exact arcs with conservative checks).
//!
//! The plain settings (the [`Schedule`], [`ActionSpace`], [`Gains`], [`PlannerKind`] and the
//! compute model's [`ComputeConfig`]) live in the `adp-settings` crate, which the learner
//! shares without linking the planners; they are re-exported here under their old paths.

pub mod action;
pub mod check_points;
pub mod complexity;
pub mod compute;
pub mod dwa;
pub mod kind;
pub mod local_map;
pub mod log_mppi;
pub mod moving;
pub mod mppi;
pub mod padp;
pub mod path_distance;
pub mod prediction;
pub mod recovery;
pub mod residual;
pub mod residual_fit;
pub mod run;
pub mod system;
pub mod tracker;

pub use settings::{gains, schedule};

pub use action::{ActionMap, ActionSpace, NameError, VelocityCommand};
pub use compute::{Budget, Compute, ComputeConfig, ComputeModel, ComputeTally, CycleWork, Work};
pub use dwa::{Dwa, DwaConfig};
pub use gains::{GainRole, Gains, GainsError};
pub use kind::{PlannerConfigs, PlannerFactory, PlannerKind, UnknownPlanner};
pub use log_mppi::{LogMppi, LogMppiConfig};
pub use moving::{ForecastErrors, Predicted, Tracking, TrackingConfig};
pub use mppi::{Mppi, MppiConfig};
pub use padp::{Padp, PadpConfig, PadpParts};
pub use prediction::{CheckMode, Integrator, Prediction};
pub use recovery::{Recovery, RecoveryConfig};
pub use schedule::Schedule;
pub use system::{Mode, ModeMachine, NavSystem, SystemConfig};
pub use tracker::{Track, Tracker, TrackerConfig};

use sim::episode::Perception;
use sim::geometry::Pose;
use sim::robot::Twist;

/// Everything a planner may use in one cycle.
#[derive(Clone, Copy, Debug)]
pub struct PlanInput<'a> {
    /// The robot's perception (robot frame).
    pub perception: Perception<'a>,
    /// The rollout time grid and check densities.
    pub schedule: &'a Schedule,
    /// The run's speed cap (m/s).
    pub max_speed: f64,
    /// How rollouts model the robot.
    pub prediction: Prediction,
    /// The cycle's compute budget ([`Budget::UNLIMITED`] under the free model).
    pub budget: Budget,
    /// Moving obstacles to check each rollout point against where they will be (robot
    /// frame; empty without obstacle tracking: see [`moving`]).
    pub moving: &'a [Predicted],
}

/// A local planner. One instance per episode: `plan` takes `&mut self` so planners keep
/// warm-start state and reusable buffers; instances are `Send` so episodes run on any thread.
pub trait Planner: Send {
    /// Name used in configs and tables.
    fn name(&self) -> &'static str;
    /// Computes the command for this cycle.
    fn plan(&mut self, input: &PlanInput<'_>) -> Twist;
    /// What the planner has recorded and counted.
    fn trace(&self) -> &Trace;
    /// The same, to switch recording on or off.
    fn trace_mut(&mut self) -> &mut Trace;
    /// The rollouts of the last cycle (empty unless recording is on).
    fn rollouts(&self) -> &Rollouts {
        &self.trace().rollouts
    }
    /// Turns recording of rollouts on or off (off by default: it costs time).
    fn set_recording(&mut self, on: bool) {
        self.trace_mut().recording = on;
    }
    /// Collision-check points evaluated since construction (centre + boundary points).
    fn evaluated_points(&self) -> u64 {
        self.trace().evaluated
    }
    /// The objective gains a policy may set ([`gains`]); `None` (the default) for a planner
    /// without any.
    fn gains(&self) -> Option<Gains> {
        None
    }
    /// Multiplies each configured objective weight by its factor (one per name of
    /// [`Planner::gains`], in that order) from the next cycle on; factors of 1 restore the
    /// configured planner exactly. Allocation-free. Refuses a planner without gains, a wrong
    /// count and negative or non-finite factors (the planner is then unchanged).
    fn set_gain_factors(&mut self, factors: &[f64]) -> Result<(), GainsError> {
        let _ = factors;
        Err(GainsError::NoGains(self.name().to_string()))
    }
}

/// The [`Planner`] methods that every planner of this crate writes alike, inside its
/// `impl Planner` block: `name` returning the literal given, and `trace` / `trace_mut` giving
/// the planner's field `trace`.
macro_rules! planner_identity {
    ($name:literal) => {
        fn name(&self) -> &'static str {
            $name
        }

        fn trace(&self) -> &$crate::Trace {
            &self.trace
        }

        fn trace_mut(&mut self) -> &mut $crate::Trace {
            &mut self.trace
        }
    };
}
pub(crate) use planner_identity;

/// What a planner records for rendering and counts for the cost columns. Each planner owns
/// one; plain data, moved with its planner (no sharing between threads).
#[derive(Clone, Debug, Default)]
pub struct Trace {
    /// The rollouts of the last cycle, filled only while `recording` is on.
    pub rollouts: Rollouts,
    /// Whether `plan` records its rollouts (off by default: it costs time).
    pub recording: bool,
    /// Collision-check points evaluated since construction (centre + boundary points).
    pub evaluated: u64,
    /// The work of the last cycle, for the compute model ([`crate::compute`]).
    pub cycle: CycleWork,
}

/// The sampled trajectories of one planning cycle, robot frame, stored flat.
#[derive(Clone, Debug, Default)]
pub struct Rollouts {
    /// All poses, rollout after rollout.
    pub poses: Vec<Pose>,
    /// `(start, end, collision_free)` of each rollout in `poses`.
    pub spans: Vec<(usize, usize, bool)>,
    /// The step lengths of the schedule used (pose k of a rollout ends step k).
    pub dts: Vec<f64>,
    /// Per rollout of `spans`: rolled out for the picture but not considered, because the
    /// cycle's compute budget was spent before its turn ([`crate::compute`]).
    pub skipped: Vec<bool>,
}

impl Rollouts {
    /// Empties the store for a new cycle with the given step lengths.
    pub fn clear(&mut self, dts: &[f64]) {
        self.poses.clear();
        self.spans.clear();
        self.skipped.clear();
        self.dts.clear();
        self.dts.extend_from_slice(dts);
    }

    /// Starts a rollout.
    pub fn begin(&mut self) {
        self.spans.push((self.poses.len(), self.poses.len(), true));
        self.skipped.push(false);
    }

    /// Marks the rollouts whose `admitted` flag is false as skipped (no-op unless there is
    /// one flag per rollout).
    pub fn mark_skipped(&mut self, admitted: &[bool]) {
        if admitted.len() == self.skipped.len() {
            for (s, &a) in self.skipped.iter_mut().zip(admitted) {
                *s = !a;
            }
        }
    }

    /// Appends a pose to the current rollout.
    pub fn push(&mut self, pose: Pose) {
        self.poses.push(pose);
    }

    /// Closes the current rollout.
    pub fn end(&mut self, collision_free: bool) {
        if let Some(last) = self.spans.last_mut() {
            last.1 = self.poses.len();
            last.2 = collision_free;
        }
    }
}
