//! From the policy's output to what the planner runs for one agent step: the action map, the
//! schedule (and, in the objective-weight spaces, the planner's gain factors) or, in the
//! velocity space, the command itself; and the previous action the next observation shows.
//!
//! The RL environment (the `adp-actor` crate's `AdpEnv`) and a robot's runtime (the `adp-runtime` crate) both
//! apply actions through [`AgentAction`], so a policy drives a planner the same way in
//! training, evaluation and on a robot.

use planner::action::{ActionError, VelocityCommand};
use planner::schedule::DEFAULT_BOUNDARY_POINTS;
use planner::{ActionMap, ActionSpace, GainsError, Planner, Schedule};
use sim::robot::Twist;

/// Why an action was refused; nothing was applied.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ApplyError {
    /// The action has the wrong length or a non-finite value.
    #[error(transparent)]
    Action(#[from] ActionError),
    /// The planner refused the action's gain factors.
    #[error(transparent)]
    Gains(#[from] GainsError),
}

/// What one agent step runs.
#[derive(Clone, Debug, PartialEq)]
pub enum Applied {
    /// The planner plans every control period of the step on this schedule.
    Schedule(Schedule),
    /// No planner: this command is issued every control period of the step.
    Velocity(Twist),
}

/// The action state of one run: the space, the action map, and the previous action.
///
/// Contract: one per run, actions applied in order. Allocation-free per step except for the
/// schedule the planner crate builds. `Send`; not shared between threads.
#[derive(Clone, Debug)]
pub struct AgentAction {
    space: ActionSpace,
    map: ActionMap,
    /// The space's DDP action in box units (for the action map).
    ddp_box: Vec<f64>,
    /// The policy's output as f64, then its box action.
    policy_f64: Vec<f64>,
    action_f64: Vec<f64>,
    /// The last action applied, clamped to [-1, 1]; before the first, the policy output that
    /// selects DDP under the map.
    previous: Vec<f32>,
}

impl AgentAction {
    /// The state before a run's first step in `space` under `map`.
    pub fn new(space: ActionSpace, map: ActionMap) -> Self {
        Self {
            space,
            map,
            ddp_box: space.ddp_action(),
            policy_f64: Vec::with_capacity(space.dim()),
            action_f64: vec![0.0; space.dim()],
            previous: map
                .ddp_policy_action(space)
                .into_iter()
                .map(|a| a as f32)
                .collect(),
        }
    }

    /// The action space.
    pub fn space(&self) -> ActionSpace {
        self.space
    }

    /// The action map.
    pub fn map(&self) -> ActionMap {
        self.map
    }

    /// The previous action (clamped to [-1, 1]): the observation's previous-action segment.
    pub fn previous(&self) -> &[f32] {
        &self.previous
    }

    /// Maps the policy output `action` (normalized; clamped to [-1, 1]) through the action
    /// map and returns what the step runs; in the objective-weight spaces it sets `planner`'s
    /// gain factors first. `max_speed` caps the velocity space's command. Refuses an action
    /// of the wrong length or with a non-finite value, and gain factors the planner refuses;
    /// the previous action changes only when the action is taken.
    pub fn apply(
        &mut self,
        action: &[f32],
        planner: &mut dyn Planner,
        max_speed: f64,
    ) -> Result<Applied, ApplyError> {
        if action.len() != self.space.dim() {
            return Err(ActionError::Dim {
                space: self.space,
                expected: self.space.dim(),
                got: action.len(),
            }
            .into());
        }
        self.policy_f64.clear();
        self.policy_f64.extend(action.iter().map(|&a| f64::from(a)));
        self.map
            .map_into(&self.policy_f64, &self.ddp_box, &mut self.action_f64);
        let applied = if self.space == ActionSpace::Velocity {
            Applied::Velocity(self.space.velocity_command(&self.action_f64, max_speed)?)
        } else {
            let schedule = self.space.schedule(&self.action_f64, DEFAULT_BOUNDARY_POINTS)?;
            if self.space.gains().is_some() {
                let params = self.space.to_params(&self.action_f64)?;
                if let Some(factors) = self.space.gain_factors(&params) {
                    planner.set_gain_factors(factors)?;
                }
            }
            Applied::Schedule(schedule)
        };
        for (p, &a) in self.previous.iter_mut().zip(action) {
            *p = a.clamp(-1.0, 1.0);
        }
        Ok(applied)
    }

    /// The physical parameters of the last applied action ([`ActionSpace::to_params`] of its
    /// box action: the schedule's p, T, N, alpha, then gain factors or the velocity command,
    /// per the space). Meaningful only after an action was applied.
    pub fn params(&self) -> Option<Vec<f64>> {
        self.space.to_params(&self.action_f64).ok()
    }
}
