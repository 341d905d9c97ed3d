//! ADP action spaces: how a policy's normalized action in [-1, 1]^k becomes what the robot
//! runs (a fidelity [`Schedule`], the planner's objective gains, or a velocity command), and back.
//! The velocity command itself (a `sim::Twist`) is the planner crate's
//! `planner::action::VelocityCommand`; everything else is here.
//!
//! The policy always works in [-1, 1]; each dimension maps affinely onto a physical range.
//! Out-of-range values are clamped, NaN/inf are refused. The decremental space contains the
//! DDP schedule exactly (p = 1.7, T = 2 s, N = 20, alpha = 0), which is how ADP starts.
//!
//! The objective-weight spaces ([`ActionSpace::Weights`], [`ActionSpace::DecrementalWeights`])
//! add one factor per objective gain of the planner ([`crate::gains`]) in
//! [`FACTOR_RANGE`] = [0, 2], whose centre 1 is the hand-tuned weight: normalized 0 is the
//! hand-tuned gain exactly (`0 + (0 + 1) * 0.5 * 2 = 1` and `2 (1 - 0) / 2 - 1 = 0` are exact in
//! floating point), under either [`ActionMap`]. Their dimension depends on the planner, which
//! the space carries ([`Gains`]) and names: `weights:dwa`, `decremental+weights:mppi`.
//!
//! The [`ActionSpace::Velocity`] space is pure RL: the policy outputs the command itself, the
//! share `v_frac` in [0, 1] of the run's speed cap and the yaw rate `w` in
//! [-[`VELOCITY_MAX_W`], [`VELOCITY_MAX_W`]] rad/s, and no planner runs.

use serde::{Deserialize, Serialize};

use crate::gains::{Gains, GainsError, FACTOR_RANGE};
use crate::schedule::{Schedule, ScheduleError};

/// Horizon of the unconstrained and fixed-parameter spaces (s).
pub const FIXED_HORIZON: f64 = 2.0;
/// Steps of the unconstrained space.
pub const UNCONSTRAINED_STEPS: usize = 20;
/// The DDP paper's exponent, used for the check-density decay of spaces without their own p.
const DDP_P: f64 = 1.7;
/// The DDP schedule's steps.
const DDP_STEPS: usize = 20;
/// Yaw-rate bound of the velocity space (rad/s): the `max_w` every planner is configured with.
pub const VELOCITY_MAX_W: f64 = 2.0;
/// The decremental space's parameters (p, T, N, alpha) and ranges.
const DECREMENTAL: [(&str, f64, f64); 4] = [
    ("p", 1.0, 1.7),
    ("T", 1.6, 2.2),
    ("N", 15.0, 22.0),
    ("alpha", 0.0, 0.6),
];
/// DDP's decremental parameters.
const DDP_PARAMS: [f64; 4] = [DDP_P, FIXED_HORIZON, DDP_STEPS as f64, 0.0];

/// The ways a policy may act (ADP paper, action-space strategies; 3D RL-DWA paper, weights
/// and pure RL). Serialized by its name ([`ActionSpace::name`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(into = "String", try_from = "String")]
pub enum ActionSpace {
    /// (p, T, N, alpha): t_i = alpha (i/N) T + (1 - alpha) (i/N)^p T; steps lengthen.
    Decremental,
    /// The decremental intervals (and check densities) in reverse order: steps shorten.
    Incremental,
    /// 20 free intervals in [0.02, 0.18] s, rescaled to sum 2 s when over.
    Unconstrained,
    /// One interval length (uniform grid over 2 s) and one collision-check density.
    Fixed,
    /// The planner's objective gain factors (in [`FACTOR_RANGE`]); the schedule stays DDP.
    /// Named `weights:<planner>`.
    Weights(Gains),
    /// The 4 decremental parameters, then the gain factors. Named
    /// `decremental+weights:<planner>`.
    DecrementalWeights(Gains),
    /// Pure RL: `(v_frac, w)`, the command the robot runs for the agent step; no planner.
    Velocity,
}

/// An action that cannot be turned into a schedule.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ActionError {
    /// Wrong number of values.
    #[error("{space} action needs {expected} values, got {got}")]
    Dim {
        /// The space.
        space: ActionSpace,
        /// Its dimension.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// A NaN or infinite value.
    #[error("action value {index} ({name}) is {value}: must be finite")]
    NotFinite {
        /// Position in the action.
        index: usize,
        /// The parameter it controls.
        name: &'static str,
        /// The value.
        value: f64,
    },
    /// The parameters do not make a schedule.
    #[error(transparent)]
    Schedule(#[from] ScheduleError),
    /// The velocity space drives the robot directly: it has no schedule.
    #[error("the velocity action space outputs the command itself and has no rollout schedule")]
    NoSchedule,
    /// A schedule-only path was given gain factors other than the configured gains'.
    #[error(
        "the {space} action sets gain factors {factors:?}; only the ADP environment (a policy) \
         sets a planner's gains, a constant action runs the configured gains (factors 1)"
    )]
    GainsIgnored {
        /// The space.
        space: ActionSpace,
        /// The factors the action sets.
        factors: Vec<f64>,
    },
}

/// A name that is no action space or action map.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NameError {
    /// Not an action space.
    #[error(
        "unknown action space `{0}` (expected decremental, incremental, unconstrained, fixed, \
         weights:<planner>, decremental+weights:<planner> or velocity)"
    )]
    Space(String),
    /// An objective-weight space without its planner.
    #[error(
        "action space `{0}` sets a planner's objective gains and needs the planner: write \
         `{0}:dwa`, `{0}:mppi` or `{0}:system`"
    )]
    NeedsPlanner(String),
    /// An objective-weight space for a planner without gains.
    #[error("action space `{space}`: {source}")]
    Gains {
        /// The name given.
        space: String,
        /// Why the planner does not fit.
        source: GainsError,
    },
    /// Not an action map.
    #[error("unknown action map `{0}` (expected ddp-centred or affine)")]
    Map(String),
}

impl std::str::FromStr for ActionSpace {
    type Err = NameError;
    fn from_str(s: &str) -> Result<Self, NameError> {
        let gains = |planner: &str| {
            Gains::for_planner(planner).map_err(|source| NameError::Gains {
                space: s.to_string(),
                source,
            })
        };
        match s.split_once(':') {
            Some(("weights", planner)) => Ok(ActionSpace::Weights(gains(planner)?)),
            Some(("decremental+weights", planner)) => Ok(ActionSpace::DecrementalWeights(gains(planner)?)),
            Some(_) => Err(NameError::Space(s.to_string())),
            None => match s {
                "decremental" => Ok(ActionSpace::Decremental),
                "incremental" => Ok(ActionSpace::Incremental),
                "unconstrained" => Ok(ActionSpace::Unconstrained),
                "fixed" => Ok(ActionSpace::Fixed),
                "velocity" => Ok(ActionSpace::Velocity),
                "weights" | "decremental+weights" => Err(NameError::NeedsPlanner(s.to_string())),
                _ => Err(NameError::Space(s.to_string())),
            },
        }
    }
}

impl TryFrom<String> for ActionSpace {
    type Error = NameError;
    fn try_from(s: String) -> Result<Self, NameError> {
        s.parse()
    }
}

impl From<ActionSpace> for String {
    fn from(space: ActionSpace) -> String {
        space.name()
    }
}

impl std::fmt::Display for ActionSpace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

impl ActionSpace {
    /// The name in configs, cards and on the command line (`decremental`, `weights:dwa`,
    /// `decremental+weights:system`, `velocity`, ...); [`str::parse`] reads it back.
    pub fn name(self) -> String {
        match self {
            ActionSpace::Decremental => "decremental".into(),
            ActionSpace::Incremental => "incremental".into(),
            ActionSpace::Unconstrained => "unconstrained".into(),
            ActionSpace::Fixed => "fixed".into(),
            ActionSpace::Weights(g) => format!("weights:{}", g.planner()),
            ActionSpace::DecrementalWeights(g) => format!("decremental+weights:{}", g.planner()),
            ActionSpace::Velocity => "velocity".into(),
        }
    }

    /// Dimension of the action vector (for the weight spaces, it depends on the planner).
    pub fn dim(self) -> usize {
        match self {
            ActionSpace::Decremental | ActionSpace::Incremental => 4,
            ActionSpace::Unconstrained => UNCONSTRAINED_STEPS,
            ActionSpace::Fixed | ActionSpace::Velocity => 2,
            ActionSpace::Weights(g) => g.len(),
            ActionSpace::DecrementalWeights(g) => 4 + g.len(),
        }
    }

    /// The planner gains the space sets, if any.
    pub fn gains(self) -> Option<Gains> {
        match self {
            ActionSpace::Weights(g) | ActionSpace::DecrementalWeights(g) => Some(g),
            _ => None,
        }
    }

    /// The gain factors among the physical parameters `params` of an action of this space
    /// (what follows the schedule's parameters); `None` for a space without gains.
    pub fn gain_factors(self, params: &[f64]) -> Option<&[f64]> {
        match self {
            ActionSpace::Weights(_) => Some(params),
            ActionSpace::DecrementalWeights(_) => params.get(DECREMENTAL.len()..),
            _ => None,
        }
    }

    /// Name and physical range `(low, high)` of each action dimension. Gain factors multiply
    /// the planner's configured weight; `v_frac` is the share of the run's speed cap.
    pub fn ranges(self) -> Vec<(&'static str, f64, f64)> {
        let gains = |g: Gains| {
            g.names()
                .iter()
                .map(|&name| (name, FACTOR_RANGE.0, FACTOR_RANGE.1))
        };
        match self {
            ActionSpace::Decremental | ActionSpace::Incremental => DECREMENTAL.to_vec(),
            ActionSpace::Unconstrained => vec![("dt", 0.02, 0.18); UNCONSTRAINED_STEPS],
            ActionSpace::Fixed => vec![("dt", 0.05, 0.2), ("check_density", 0.0, 1.0)],
            ActionSpace::Weights(g) => gains(g).collect(),
            ActionSpace::DecrementalWeights(g) => DECREMENTAL.into_iter().chain(gains(g)).collect(),
            ActionSpace::Velocity => vec![("v_frac", 0.0, 1.0), ("w", -VELOCITY_MAX_W, VELOCITY_MAX_W)],
        }
    }

    /// Physical parameters of a normalized action (clamped to [-1, 1] first; N rounded).
    pub fn to_params(self, action: &[f64]) -> Result<Vec<f64>, ActionError> {
        let ranges = self.ranges();
        if action.len() != ranges.len() {
            return Err(ActionError::Dim {
                space: self,
                expected: ranges.len(),
                got: action.len(),
            });
        }
        action
            .iter()
            .zip(&ranges)
            .enumerate()
            .map(|(i, (&a, &(name, lo, hi)))| {
                if !a.is_finite() {
                    return Err(ActionError::NotFinite {
                        index: i,
                        name,
                        value: a,
                    });
                }
                let v = lo + (a.clamp(-1.0, 1.0) + 1.0) * 0.5 * (hi - lo);
                Ok(if name == "N" { v.round() } else { v })
            })
            .collect()
    }

    /// The normalized action of physical parameters (clamped to their ranges).
    pub fn to_action(self, params: &[f64]) -> Vec<f64> {
        params
            .iter()
            .zip(self.ranges())
            .map(|(&v, (_, lo, hi))| 2.0 * (v.clamp(lo, hi) - lo) / (hi - lo) - 1.0)
            .collect()
    }

    /// The schedule an action selects, with up to `n` footprint boundary points per check.
    pub fn schedule(self, action: &[f64], n: usize) -> Result<Schedule, ActionError> {
        let q = self.to_params(action)?;
        Ok(match self {
            ActionSpace::Decremental => Schedule::decremental(q[0], q[1], q[2] as usize, q[3], n)?,
            ActionSpace::Incremental => Schedule::decremental(q[0], q[1], q[2] as usize, q[3], n)?.reversed(),
            ActionSpace::Unconstrained => {
                let sum: f64 = q.iter().sum();
                let scale = if sum > FIXED_HORIZON {
                    FIXED_HORIZON / sum
                } else {
                    1.0
                };
                let dts: Vec<f64> = q.iter().map(|d| d * scale).collect();
                let horizon: f64 = dts.iter().sum();
                let mut t = 0.0;
                let checks = dts
                    .iter()
                    .map(|d| {
                        t += d;
                        (n as f64 * (1.0 - (t / horizon).powf(DDP_P))).round() as u16
                    })
                    .collect();
                Schedule::from_parts(dts, checks, n)?
            }
            ActionSpace::Fixed => {
                let steps = (FIXED_HORIZON / q[0]).round().max(1.0) as usize;
                let checks = (q[1] * n as f64).round() as usize;
                Schedule::from_parts(vec![q[0]; steps], vec![checks as u16; steps], n)?
            }
            ActionSpace::Weights(_) => Schedule::ddp(DDP_P, FIXED_HORIZON, DDP_STEPS, n)?,
            ActionSpace::DecrementalWeights(_) => Schedule::decremental(q[0], q[1], q[2] as usize, q[3], n)?,
            ActionSpace::Velocity => return Err(ActionError::NoSchedule),
        })
    }

    /// The schedule of an action run by a path that sets only the schedule (a constant action
    /// on the plain episode driver, whose planner keeps its configured gains): as
    /// [`ActionSpace::schedule`], and refuses an action whose gain factors are not all 1 instead
    /// of silently running other gains than it names.
    pub fn schedule_only(self, action: &[f64], n: usize) -> Result<Schedule, ActionError> {
        let schedule = self.schedule(action, n)?;
        let params = self.to_params(action)?;
        match self.gain_factors(&params) {
            Some(f) if f.iter().any(|&x| x != 1.0) => Err(ActionError::GainsIgnored {
                space: self,
                factors: f.to_vec(),
            }),
            _ => Ok(schedule),
        }
    }

    /// The action closest to the DDP schedule (p = 1.7, T = 2 s, N = 20, alpha = 0) with the
    /// hand-tuned gains (factor 1, normalized 0). Exact for the decremental and the weight
    /// spaces; the other schedule spaces get their nearest representable grid. The velocity
    /// space has no DDP: its reference action is the box centre (zeros: half the speed cap,
    /// straight ahead).
    pub fn ddp_action(self) -> Vec<f64> {
        let ones = |g: Gains| vec![1.0; g.len()];
        match self {
            ActionSpace::Decremental | ActionSpace::Incremental => self.to_action(&DDP_PARAMS),
            ActionSpace::Unconstrained => self.to_action(Schedule::ddp_default().dts()),
            ActionSpace::Fixed => self.to_action(&[0.1, 1.0]),
            ActionSpace::Weights(g) => self.to_action(&ones(g)),
            ActionSpace::DecrementalWeights(g) => self.to_action(&[DDP_PARAMS.to_vec(), ones(g)].concat()),
            ActionSpace::Velocity => vec![0.0; 2],
        }
    }
}

/// How a policy's output `u` in [-1, 1]^k becomes the box action `a` that
/// [`ActionSpace::schedule`] reads.
///
/// The paper's physical ranges put the DDP schedule on a corner of the decremental box
/// (p = 1.7 and alpha = 0 are range ends), where a tanh actor is saturated: its gradient there
/// is `1 - tanh^2`, about 1 % at the 0.995 clip a fit can reach, and half of the exploration
/// noise is clipped away. [`ActionMap::DdpCentred`] keeps the ranges but moves DDP to `u = 0`,
/// the actor's unsaturated centre. Plain data (`Copy`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ActionMap {
    /// `a = u`: the box maps affinely onto the ranges (the paper's parametrization; DDP is
    /// [`ActionSpace::ddp_action`]).
    Affine,
    /// Piecewise affine about DDP, per dimension with `d` its DDP value in box units:
    /// `a = d + u (1 - d)` for `u >= 0`, `a = d + u (1 + d)` for `u < 0`. So `u = 0` is DDP,
    /// `u = ±1` are the range ends, and a dimension whose DDP value is a range end (p, alpha)
    /// keeps DDP's value on one side: the policy reaches every schedule of the box, and DDP is
    /// an interior point of what it outputs.
    #[default]
    DdpCentred,
}

impl std::str::FromStr for ActionMap {
    type Err = NameError;
    fn from_str(s: &str) -> Result<Self, NameError> {
        match s {
            "affine" => Ok(ActionMap::Affine),
            "ddp-centred" => Ok(ActionMap::DdpCentred),
            _ => Err(NameError::Map(s.to_string())),
        }
    }
}

impl ActionMap {
    /// The box action of one policy output `u` (clamped to [-1, 1]) of a dimension whose DDP
    /// value is `ddp` (box units). Non-finite `u` passes through, for
    /// [`ActionSpace::schedule`] to refuse.
    pub fn to_box(self, u: f64, ddp: f64) -> f64 {
        if !u.is_finite() {
            return u;
        }
        let u = u.clamp(-1.0, 1.0);
        match self {
            ActionMap::Affine => u,
            ActionMap::DdpCentred if u >= 0.0 => ddp + u * (1.0 - ddp),
            ActionMap::DdpCentred => ddp + u * (1.0 + ddp),
        }
    }

    /// The policy output of a box action `a` (the inverse of [`ActionMap::to_box`] where it is
    /// one-to-one; a box value equal to a one-sided DDP value maps to 0).
    pub fn to_policy(self, a: f64, ddp: f64) -> f64 {
        let a = a.clamp(-1.0, 1.0);
        match self {
            ActionMap::Affine => a,
            ActionMap::DdpCentred if a > ddp => (a - ddp) / (1.0 - ddp),
            ActionMap::DdpCentred if a < ddp => (a - ddp) / (1.0 + ddp),
            ActionMap::DdpCentred => 0.0,
        }
    }

    /// Writes the box action of the policy output `u` into `out` (same length), with
    /// `ddp = space.ddp_action()` precomputed by the caller. Allocation-free.
    ///
    /// # Panics
    /// If the three lengths differ.
    pub fn map_into(self, u: &[f64], ddp: &[f64], out: &mut [f64]) {
        assert!(
            u.len() == ddp.len() && u.len() == out.len(),
            "action map: length mismatch"
        );
        for ((o, &x), &d) in out.iter_mut().zip(u).zip(ddp) {
            *o = self.to_box(x, d);
        }
    }

    /// The physical parameters ([`ActionSpace::to_params`]) that the policy output `u` of
    /// `space` chooses under this map: what an agent step with that output runs. Refuses an
    /// output of the wrong length or with a non-finite value.
    pub fn params(self, space: ActionSpace, u: &[f32]) -> Result<Vec<f64>, ActionError> {
        let ddp = space.ddp_action();
        if u.len() != ddp.len() {
            return Err(ActionError::Dim {
                space,
                expected: ddp.len(),
                got: u.len(),
            });
        }
        let u: Vec<f64> = u.iter().map(|&x| f64::from(x)).collect();
        let mut a = vec![0.0; u.len()];
        self.map_into(&u, &ddp, &mut a);
        space.to_params(&a)
    }

    /// The policy output that selects the DDP schedule in `space`: zeros for
    /// [`ActionMap::DdpCentred`], [`ActionSpace::ddp_action`] for [`ActionMap::Affine`].
    pub fn ddp_policy_action(self, space: ActionSpace) -> Vec<f64> {
        match self {
            ActionMap::Affine => space.ddp_action(),
            ActionMap::DdpCentred => vec![0.0; space.dim()],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ddp_is_exactly_the_decremental_initial_action() {
        let a = ActionSpace::Decremental.ddp_action();
        assert_eq!(a[0], 1.0);
        assert_eq!(a[3], -1.0);
        let s = ActionSpace::Decremental.schedule(&a, 20).unwrap();
        let ddp = Schedule::ddp(1.7, 2.0, 20, 20).unwrap();
        assert_eq!(s.checks(), ddp.checks());
        for (x, y) in s.dts().iter().zip(ddp.dts()) {
            assert!((x - y).abs() < 1e-12);
        }
    }

    #[test]
    fn decremental_formula_and_ranges() {
        // p = 1.35, T = 1.9, N = 18 (after rounding), alpha = 0.3, from the mid action.
        let q = ActionSpace::Decremental
            .to_params(&[0.0, 0.0, -0.1, 0.0])
            .unwrap();
        for (x, y) in q.iter().zip([1.35, 1.9, 18.0, 0.3]) {
            assert!((x - y).abs() < 1e-12, "{q:?}");
        }
        let s = ActionSpace::Decremental
            .schedule(&[0.0, 0.0, -0.1, 0.0], 20)
            .unwrap();
        assert_eq!(s.len(), 18);
        let t = |i: f64| 0.3 * (i / 18.0) * 1.9 + 0.7 * (i / 18.0f64).powf(1.35) * 1.9;
        for (i, d) in s.dts().iter().enumerate() {
            assert!((d - (t(i as f64 + 1.0) - t(i as f64))).abs() < 1e-12);
        }
        assert!((s.horizon() - 1.9).abs() < 1e-12);
        // Anywhere in the box, steps never shorten (decremental fidelity).
        for a in [
            [-1.0, -1.0, -1.0, -1.0],
            [1.0, 1.0, 1.0, 1.0],
            [0.3, -0.7, 0.9, 0.2],
        ] {
            let s = ActionSpace::Decremental.schedule(&a, 20).unwrap();
            assert!(s.dts().windows(2).all(|w| w[1] >= w[0] - 1e-12));
            let (lo, hi) = (1.6 - 1e-9, 2.2 + 1e-9);
            assert!(s.horizon() > lo && s.horizon() < hi && (15..=22).contains(&s.len()));
        }
    }

    #[test]
    fn incremental_reverses_decremental() {
        let a = [0.5, -0.2, 0.1, -0.5];
        let dec = ActionSpace::Decremental.schedule(&a, 20).unwrap();
        let inc = ActionSpace::Incremental.schedule(&a, 20).unwrap();
        let mut rev = dec.dts().to_vec();
        rev.reverse();
        assert_eq!(inc.dts(), rev.as_slice());
        let mut rc = dec.checks().to_vec();
        rc.reverse();
        assert_eq!(inc.checks(), rc.as_slice());
    }

    #[test]
    fn unconstrained_rescales_only_when_over() {
        let max = vec![1.0; 20]; // 20 x 0.18 = 3.6 s > 2 s: rescaled to 0.1 each
        let s = ActionSpace::Unconstrained.schedule(&max, 20).unwrap();
        assert!((s.horizon() - 2.0).abs() < 1e-12);
        assert!(s.dts().iter().all(|d| (d - 0.1).abs() < 1e-12));
        let min = vec![-1.0; 20]; // 20 x 0.02 = 0.4 s: kept
        let s = ActionSpace::Unconstrained.schedule(&min, 20).unwrap();
        assert!((s.horizon() - 0.4).abs() < 1e-12);
        let mut mixed = vec![-1.0; 20];
        mixed[19] = 1.0;
        let s = ActionSpace::Unconstrained.schedule(&mixed, 20).unwrap();
        assert!((s.dts()[19] - 0.18).abs() < 1e-12 && (s.dts()[0] - 0.02).abs() < 1e-12);
    }

    #[test]
    fn fixed_parameter_grid() {
        // dt = 0.125 (mid), density 0.5 -> 16 steps of 0.125 s, 10 of 20 points.
        let s = ActionSpace::Fixed.schedule(&[0.0, 0.0], 20).unwrap();
        assert_eq!(s.len(), 16);
        assert!(s.checks().iter().all(|&c| c == 10));
        assert!((s.horizon() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn round_trip_clamping_and_nan() {
        for space in [
            ActionSpace::Decremental,
            ActionSpace::Unconstrained,
            ActionSpace::Fixed,
        ] {
            let a: Vec<f64> = (0..space.dim()).map(|i| ((i as f64) * 0.37).sin()).collect();
            let back = space.to_action(&space.to_params(&a).unwrap());
            for (i, (x, y)) in a.iter().zip(&back).enumerate() {
                if space.ranges()[i].0 != "N" {
                    assert!((x - y).abs() < 1e-12, "{space:?}[{i}]: {x} vs {y}");
                }
            }
        }
        // Out of range: clamped.
        let q = ActionSpace::Decremental
            .to_params(&[5.0, -9.0, 1.0, 1.0])
            .unwrap();
        for (x, y) in q.iter().zip([1.7, 1.6, 22.0, 0.6]) {
            assert!((x - y).abs() < 1e-12, "{q:?}");
        }
        // NaN: refused with the parameter named.
        let e = ActionSpace::Decremental
            .schedule(&[0.0, f64::NAN, 0.0, 0.0], 20)
            .unwrap_err();
        assert!(matches!(
            e,
            ActionError::NotFinite {
                index: 1,
                name: "T",
                ..
            }
        ));
        assert!(e.to_string().contains("(T) is NaN"));
        assert!(matches!(
            ActionSpace::Unconstrained.schedule(&[0.0; 4], 20),
            Err(ActionError::Dim {
                expected: 20,
                got: 4,
                ..
            })
        ));
    }

    #[test]
    fn ddp_centred_map_puts_ddp_at_zero_and_keeps_the_box() {
        let space = ActionSpace::Decremental;
        let ddp = space.ddp_action();
        let map = ActionMap::DdpCentred;
        let mut a = vec![0.0; 4];
        map.map_into(&[0.0; 4], &ddp, &mut a);
        assert_eq!(a, ddp, "u = 0 is DDP exactly");
        // Hand-computed: T's DDP value 2.0 in [1.6, 2.2] is d = 1/3 in box units; u = 0.5 is
        // halfway from 2.0 to 2.2 = 2.1 s, u = -0.5 halfway from 2.0 to 1.6 = 1.8 s.
        let t = |u: f64| space.to_params(&[0.0, map.to_box(u, ddp[1]), 0.0, 0.0]).unwrap()[1];
        assert!((t(0.5) - 2.1).abs() < 1e-12 && (t(-0.5) - 1.8).abs() < 1e-12);
        assert!((t(1.0) - 2.2).abs() < 1e-12 && (t(-1.0) - 1.6).abs() < 1e-12);
        // p (DDP at the top of its range): u >= 0 keeps 1.7, u = -1 reaches 1.0, u = -0.5 1.35.
        let p = |u: f64| space.to_params(&[map.to_box(u, ddp[0]), 0.0, 0.0, 0.0]).unwrap()[0];
        assert!((p(0.7) - 1.7).abs() < 1e-12 && (p(-1.0) - 1.0).abs() < 1e-12);
        assert!((p(-0.5) - 1.35).abs() < 1e-12);
        // Monotone, continuous at 0, and the inverse where one-to-one.
        for d in [-1.0, -0.2, 1.0 / 3.0, 1.0] {
            let mut last = f64::NEG_INFINITY;
            for k in -100..=100 {
                let u = k as f64 / 100.0;
                let b = map.to_box(u, d);
                assert!(b >= last - 1e-15 && (-1.0..=1.0).contains(&b));
                last = b;
                if b != d {
                    assert!((map.to_policy(b, d) - u).abs() < 1e-12, "d {d} u {u}");
                }
            }
        }
        assert!(map.to_box(f64::NAN, 0.0).is_nan());
        assert_eq!(ActionMap::Affine.to_box(0.3, 0.9), 0.3);
        assert_eq!(map.ddp_policy_action(space), vec![0.0; 4]);
        assert_eq!(ActionMap::Affine.ddp_policy_action(space), ddp);
        assert_eq!("affine".parse::<ActionMap>(), Ok(ActionMap::Affine));
        assert!("x"
            .parse::<ActionMap>()
            .unwrap_err()
            .to_string()
            .contains("ddp-centred or affine"));
    }

    #[test]
    fn weight_spaces_start_exactly_at_the_hand_tuned_gains_and_ddp() {
        for g in Gains::ALL {
            for space in [ActionSpace::Weights(g), ActionSpace::DecrementalWeights(g)] {
                assert_eq!(space.dim(), space.ranges().len());
                assert_eq!(space.gains(), Some(g));
                for map in [ActionMap::DdpCentred, ActionMap::Affine] {
                    let u = map.ddp_policy_action(space);
                    let mut a = vec![0.0; space.dim()];
                    map.map_into(&u, &space.ddp_action(), &mut a);
                    let q = space.to_params(&a).unwrap();
                    // Factor 1 exactly (bit for bit), so the planner's weights are unchanged.
                    let factors = space.gain_factors(&q).unwrap();
                    assert_eq!(factors, vec![1.0; g.len()].as_slice(), "{space} {map:?}");
                    assert!(factors.iter().all(|f| f.to_bits() == 1.0f64.to_bits()));
                    let s = space.schedule(&a, 20).unwrap();
                    let want = if matches!(space, ActionSpace::Weights(_)) {
                        Schedule::ddp_default()
                    } else {
                        let dec = ActionSpace::Decremental;
                        let mut d = vec![0.0; 4];
                        map.map_into(&map.ddp_policy_action(dec), &dec.ddp_action(), &mut d);
                        dec.schedule(&d, 20).unwrap()
                    };
                    assert_eq!(s, want, "{space} {map:?}: the schedule is today's DDP start");
                }
            }
        }
        assert_eq!(ActionSpace::Weights(Gains::Dwa).dim(), 4);
        assert_eq!(ActionSpace::DecrementalWeights(Gains::Mppi).dim(), 9);
        assert_eq!(ActionSpace::DecrementalWeights(Gains::System).dim(), 8);
        let names: Vec<&str> = ActionSpace::DecrementalWeights(Gains::Dwa)
            .ranges()
            .iter()
            .map(|r| r.0)
            .collect();
        assert_eq!(
            names,
            [
                "p",
                "T",
                "N",
                "alpha",
                "w_goal",
                "w_path",
                "w_obstacle",
                "w_speed"
            ]
        );
        assert_eq!(ActionSpace::Decremental.gain_factors(&[1.0; 4]), None);
        // A path that sets only the schedule refuses gains it would not apply.
        let w = ActionSpace::Weights(Gains::Dwa);
        assert_eq!(w.schedule_only(&[0.0; 4], 20), Ok(Schedule::ddp_default()));
        assert_eq!(
            w.schedule_only(&[0.0, 0.0, 1.0, 0.0], 20)
                .unwrap_err()
                .to_string(),
            "the weights:dwa action sets gain factors [1.0, 1.0, 2.0, 1.0]; only the ADP environment \
             (a policy) sets a planner's gains, a constant action runs the configured gains (factors 1)"
        );
    }

    #[test]
    fn names_round_trip_and_bad_names_say_what_is_wrong() {
        for space in [
            ActionSpace::Decremental,
            ActionSpace::Fixed,
            ActionSpace::Weights(Gains::System),
            ActionSpace::DecrementalWeights(Gains::Mppi),
            ActionSpace::Velocity,
        ] {
            assert_eq!(space.name().parse::<ActionSpace>(), Ok(space));
            let json = serde_json::to_string(&space).unwrap();
            assert_eq!(json, format!("\"{space}\""));
            assert_eq!(serde_json::from_str::<ActionSpace>(&json).unwrap(), space);
        }
        assert_eq!(
            ActionSpace::DecrementalWeights(Gains::Dwa).name(),
            "decremental+weights:dwa"
        );
        let e = "weights".parse::<ActionSpace>().unwrap_err().to_string();
        assert!(e.contains("needs the planner: write `weights:dwa`"), "{e}");
        let e = "decremental+weights:log-mppi"
            .parse::<ActionSpace>()
            .unwrap_err()
            .to_string();
        assert!(e.contains("`log-mppi` has no objective gains"), "{e}");
        let e = "speed:dwa".parse::<ActionSpace>().unwrap_err().to_string();
        assert!(e.starts_with("unknown action space `speed:dwa`"), "{e}");
        let e = ActionSpace::Weights(Gains::Dwa)
            .schedule(&[0.0, f64::INFINITY, 0.0, 0.0], 20)
            .unwrap_err();
        assert_eq!(e.to_string(), "action value 1 (w_path) is inf: must be finite");
        let e = ActionSpace::Weights(Gains::Mppi)
            .to_params(&[0.0; 4])
            .unwrap_err();
        assert_eq!(e.to_string(), "weights:mppi action needs 5 values, got 4");
    }

    #[test]
    fn velocity_ranges_are_the_speed_share_and_the_yaw_rate_bound() {
        let v = ActionSpace::Velocity;
        assert_eq!(v.dim(), 2);
        assert_eq!(v.ranges(), vec![("v_frac", 0.0, 1.0), ("w", -2.0, 2.0)]);
        // Clamped: never backwards, never beyond the bounds.
        assert_eq!(v.to_params(&[-3.0, 9.0]), Ok(vec![0.0, 2.0]));
        assert!(matches!(
            v.to_params(&[f64::NAN, 0.0]),
            Err(ActionError::NotFinite { name: "v_frac", .. })
        ));
        assert_eq!(v.schedule(&[0.0, 0.0], 20), Err(ActionError::NoSchedule));
        assert_eq!(v.ddp_action(), vec![0.0, 0.0]);
        assert_eq!(ActionMap::DdpCentred.to_box(0.3, v.ddp_action()[0]), 0.3);
    }
}
