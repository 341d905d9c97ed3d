//! Objective gains a policy may set every agent step (the 3D RL-DWA paper's RL-tuned weights).
//!
//! A planner with gains names them ([`Gains::names`]) and takes one *factor* per name (the
//! planner crate's `Planner::set_gain_factors` applies them): each factor multiplies the
//! weight its planner's configuration sets (the hand-tuned value), so factor 1 is today's
//! planner bit for bit (`w * 1.0 == w` exactly), 0 switches the term off and 2 doubles it. The
//! action spaces of [`crate::action`] map a normalized output onto [`FACTOR_RANGE`], whose
//! centre is 1.
//!
//! Factors rather than absolute weights keep one action space per planner whatever weights a
//! configuration sets, and make the hand-tuned gains the box centre exactly under both action
//! maps. Setting factors only writes a few numbers into the planner's configuration: no
//! allocation, and nothing changes inside the planning cycle.

/// The range of every gain factor: `[0, 2]` times the configured weight (centre 1: the
/// hand-tuned weight).
pub const FACTOR_RANGE: (f64, f64) = (0.0, 2.0);

/// The gain sets of the planners that have them. Log-MPPI has none: its cost is a single goal
/// weight against hard costmap collisions and a control cost fixed by its sampling
/// distribution, so there is no trade-off between objectives for a policy to tune.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Gains {
    /// DWA: `w_goal`, `w_path`, `w_obstacle`, `w_speed` of `planner::DwaConfig`.
    Dwa,
    /// MPPI: `w_goal`, `w_path`, `w_obstacle`, `w_heading`, `w_smooth` of
    /// `planner::MppiConfig`.
    Mppi,
    /// The navigation system: `goal`, `obstacle`, `heading`, `space`, each scaling the term's
    /// weight in both the normal and the low-speed / recovery modes of
    /// `planner::SystemConfig` (`normal_goal` and `low_goal`, ...), so the modes keep their
    /// hand-tuned balance.
    System,
}

const DWA: &[&str] = &["w_goal", "w_path", "w_obstacle", "w_speed"];
const MPPI: &[&str] = &["w_goal", "w_path", "w_obstacle", "w_heading", "w_smooth"];
const SYSTEM: &[&str] = &["goal", "obstacle", "heading", "space"];

/// What a gain weighs, as PADP's pressure modes see it (`planner::complexity::ModeEffects`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GainRole {
    /// Efficiency: progress to the goal, speed.
    Efficiency,
    /// Local risk: clearance to obstacles (the forecast of moving ones included).
    Risk,
    /// Anything else (following the path, heading, smoothness, free space): left alone.
    Other,
}

use GainRole::{Efficiency, Other, Risk};
const DWA_ROLES: &[GainRole] = &[Efficiency, Other, Risk, Efficiency];
const MPPI_ROLES: &[GainRole] = &[Efficiency, Other, Risk, Other, Other];
const SYSTEM_ROLES: &[GainRole] = &[Efficiency, Risk, Other, Other];

impl Gains {
    /// Every gain set.
    pub const ALL: [Gains; 3] = [Gains::Dwa, Gains::Mppi, Gains::System];

    /// The planner's name (as in configs, [`crate::PlannerKind::name`] and the
    /// planner crate's `Planner::name`).
    pub fn planner(self) -> &'static str {
        match self {
            Gains::Dwa => "dwa",
            Gains::Mppi => "mppi",
            Gains::System => "system",
        }
    }

    /// The gains' names, in the order of their factors.
    pub fn names(self) -> &'static [&'static str] {
        match self {
            Gains::Dwa => DWA,
            Gains::Mppi => MPPI,
            Gains::System => SYSTEM,
        }
    }

    /// The gains' roles, in the order of their factors.
    pub fn roles(self) -> &'static [GainRole] {
        match self {
            Gains::Dwa => DWA_ROLES,
            Gains::Mppi => MPPI_ROLES,
            Gains::System => SYSTEM_ROLES,
        }
    }

    /// Number of gains.
    pub fn len(self) -> usize {
        self.names().len()
    }

    /// Always false (every gain set has gains); for clippy's `len_without_is_empty`.
    pub fn is_empty(self) -> bool {
        false
    }

    /// The gain set of the planner named `planner`; refuses a planner without gains.
    pub fn for_planner(planner: &str) -> Result<Gains, GainsError> {
        Gains::ALL
            .into_iter()
            .find(|g| g.planner() == planner)
            .ok_or_else(|| GainsError::NoGains(planner.to_string()))
    }

    /// Checks `factors` for this set: one per gain, each finite and >= 0; the error names the
    /// planner and the gain.
    pub fn check(self, factors: &[f64]) -> Result<(), GainsError> {
        if factors.len() != self.len() {
            return Err(GainsError::Count {
                planner: self.planner(),
                expected: self.len(),
                got: factors.len(),
            });
        }
        match factors
            .iter()
            .zip(self.names())
            .find(|(f, _)| !(f.is_finite() && **f >= 0.0))
        {
            Some((&value, &name)) => Err(GainsError::Factor {
                planner: self.planner(),
                name,
                value,
            }),
            None => Ok(()),
        }
    }
}

/// Gain factors that cannot be applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GainsError {
    /// The planner has no objective gains a policy may set.
    #[error(
        "planner `{0}` has no objective gains an action may set (planners with gains: dwa, mppi, system)"
    )]
    NoGains(String),
    /// Wrong number of factors.
    #[error("{planner} takes {expected} gain factors, got {got}")]
    Count {
        /// The planner.
        planner: &'static str,
        /// Its number of gains.
        expected: usize,
        /// Factors given.
        got: usize,
    },
    /// A negative or non-finite factor.
    #[error("{planner} gain factor {name} = {value}: must be finite and >= 0")]
    Factor {
        /// The planner.
        planner: &'static str,
        /// The gain.
        name: &'static str,
        /// The factor.
        value: f64,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_planners_and_checks() {
        assert_eq!(Gains::for_planner("mppi"), Ok(Gains::Mppi));
        assert_eq!(Gains::Mppi.len(), 5);
        assert_eq!(Gains::System.names()[3], "space");
        let e = Gains::for_planner("log-mppi").unwrap_err();
        assert!(e.to_string().contains("`log-mppi` has no objective gains"), "{e}");
        assert!(Gains::Dwa.check(&[1.0, 0.0, 2.0, 5.0]).is_ok());
        let e = Gains::Dwa.check(&[1.0, -0.1, 1.0, 1.0]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "dwa gain factor w_path = -0.1: must be finite and >= 0"
        );
        let e = Gains::Dwa.check(&[1.0; 5]).unwrap_err();
        assert_eq!(e.to_string(), "dwa takes 4 gain factors, got 5");
        for g in Gains::ALL {
            assert_eq!(g.roles().len(), g.len(), "{g:?}");
        }
        assert_eq!(Gains::Dwa.roles()[3], GainRole::Efficiency, "w_speed");
        assert_eq!(Gains::System.roles()[1], GainRole::Risk, "obstacle");
    }
}
