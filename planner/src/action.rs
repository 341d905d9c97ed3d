//! ADP action spaces: how a policy's normalized action in [-1, 1]^k becomes a fidelity
//! [`Schedule`], and back.
//!
//! The policy always works in [-1, 1]; each dimension maps affinely onto a physical range.
//! Out-of-range values are clamped, NaN/inf are refused. The decremental space contains the
//! DDP schedule exactly (p = 1.7, T = 2 s, N = 20, alpha = 0), which is how ADP starts.

use serde::{Deserialize, Serialize};

use crate::schedule::{Schedule, ScheduleError};

/// Horizon of the unconstrained and fixed-parameter spaces (s).
pub const FIXED_HORIZON: f64 = 2.0;
/// Steps of the unconstrained space.
pub const UNCONSTRAINED_STEPS: usize = 20;
/// The DDP paper's exponent, used for the check-density decay of spaces without their own p.
const DDP_P: f64 = 1.7;

/// The ways a policy may choose the rollout grid (ADP paper, action-space strategies).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ActionSpace {
    /// (p, T, N, alpha): t_i = alpha (i/N) T + (1 - alpha) (i/N)^p T; steps lengthen.
    Decremental,
    /// The decremental intervals (and check densities) in reverse order: steps shorten.
    Incremental,
    /// 20 free intervals in [0.02, 0.18] s, rescaled to sum 2 s when over.
    Unconstrained,
    /// One interval length (uniform grid over 2 s) and one collision-check density.
    Fixed,
}

/// An action that cannot be turned into a schedule.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ActionError {
    /// Wrong number of values.
    #[error("{space:?} action needs {expected} values, got {got}")]
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
}

/// A name that is no action space or action map.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NameError {
    /// Not an action space.
    #[error("unknown action space `{0}` (expected decremental, incremental, unconstrained or fixed)")]
    Space(String),
    /// Not an action map.
    #[error("unknown action map `{0}` (expected ddp-centred or affine)")]
    Map(String),
}

impl std::str::FromStr for ActionSpace {
    type Err = NameError;
    fn from_str(s: &str) -> Result<Self, NameError> {
        match s {
            "decremental" => Ok(ActionSpace::Decremental),
            "incremental" => Ok(ActionSpace::Incremental),
            "unconstrained" => Ok(ActionSpace::Unconstrained),
            "fixed" => Ok(ActionSpace::Fixed),
            _ => Err(NameError::Space(s.to_string())),
        }
    }
}

impl ActionSpace {
    /// Dimension of the action vector.
    pub fn dim(self) -> usize {
        match self {
            ActionSpace::Decremental | ActionSpace::Incremental => 4,
            ActionSpace::Unconstrained => UNCONSTRAINED_STEPS,
            ActionSpace::Fixed => 2,
        }
    }

    /// Name and physical range `(low, high)` of each action dimension.
    pub fn ranges(self) -> Vec<(&'static str, f64, f64)> {
        match self {
            ActionSpace::Decremental | ActionSpace::Incremental => vec![
                ("p", 1.0, 1.7),
                ("T", 1.6, 2.2),
                ("N", 15.0, 22.0),
                ("alpha", 0.0, 0.6),
            ],
            ActionSpace::Unconstrained => vec![("dt", 0.02, 0.18); UNCONSTRAINED_STEPS],
            ActionSpace::Fixed => vec![("dt", 0.05, 0.2), ("check_density", 0.0, 1.0)],
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
        })
    }

    /// The action closest to the DDP schedule (p = 1.7, T = 2 s, N = 20, alpha = 0). Exact for
    /// the decremental space; the other spaces get their nearest representable grid.
    pub fn ddp_action(self) -> Vec<f64> {
        match self {
            ActionSpace::Decremental | ActionSpace::Incremental => self.to_action(&[1.7, 2.0, 20.0, 0.0]),
            ActionSpace::Unconstrained => self.to_action(Schedule::ddp_default().dts()),
            ActionSpace::Fixed => self.to_action(&[0.1, 1.0]),
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
}
