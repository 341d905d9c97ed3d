//! Which planner a run uses.
//!
//! [`PlannerKind`] names the four planners the way configuration files, the command line,
//! tables and the wire protocol do. Building one is the planner crate's business: its
//! `PlannerConfigs` (every planner's tunables) is a [`PlannerFactory`], so
//! [`PlannerKind::build`] builds any of them without this crate knowing the planners.

use serde::{Deserialize, Serialize};

/// A planner selectable in configuration files and on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum PlannerKind {
    /// Dynamic Window Approach.
    Dwa,
    /// Model Predictive Path Integral control.
    Mppi,
    /// MPPI with normal + log-normal mixture sampling (Mohamed et al. 2022).
    LogMppi,
    /// The standalone DDP/ADP navigation system (modes, recovery).
    System,
}

/// A planner name that is none of [`PlannerKind::ALL`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown planner `{0}` (expected dwa, mppi, log-mppi or system)")]
pub struct UnknownPlanner(pub String);

impl std::str::FromStr for PlannerKind {
    type Err = UnknownPlanner;

    /// A planner by [`PlannerKind::name`].
    fn from_str(name: &str) -> Result<Self, UnknownPlanner> {
        PlannerKind::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| UnknownPlanner(name.to_string()))
    }
}

impl std::fmt::Display for PlannerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl PlannerKind {
    /// Every planner, in table order.
    pub const ALL: [PlannerKind; 4] = [
        PlannerKind::Dwa,
        PlannerKind::Mppi,
        PlannerKind::LogMppi,
        PlannerKind::System,
    ];

    /// The planner's name in configuration files, on the command line and in tables (`dwa`,
    /// `mppi`, `log-mppi`, `system`); the same as the `Planner::name` of what it builds.
    pub fn name(self) -> &'static str {
        match self {
            PlannerKind::Dwa => "dwa",
            PlannerKind::Mppi => "mppi",
            PlannerKind::LogMppi => "log-mppi",
            PlannerKind::System => "system",
        }
    }

    /// A fresh planner for one episode from `factory` (the planner crate's `PlannerConfigs`:
    /// `kind.build(&configs, seed)` gives a `Box<dyn Planner>` with those tunables); `seed`
    /// drives its sampling (DWA samples a fixed grid and ignores it).
    pub fn build<F: PlannerFactory + ?Sized>(self, factory: &F, seed: u64) -> F::Planner {
        factory.build_planner(self, seed)
    }
}

/// What builds a planner of any [`PlannerKind`] for one episode: the planner crate's
/// `PlannerConfigs`, whose planners this crate does not know. [`PlannerKind::build`] calls it.
pub trait PlannerFactory {
    /// What is built (the planner crate's `Box<dyn Planner>`).
    type Planner;

    /// A fresh planner of `kind` for one episode; `seed` drives its sampling.
    fn build_planner(&self, kind: PlannerKind, seed: u64) -> Self::Planner;
}

impl<F: PlannerFactory + ?Sized> PlannerFactory for &F {
    type Planner = F::Planner;

    fn build_planner(&self, kind: PlannerKind, seed: u64) -> F::Planner {
        (**self).build_planner(kind, seed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for k in PlannerKind::ALL {
            assert_eq!(k.name().parse::<PlannerKind>(), Ok(k));
            assert_eq!(k.to_string(), k.name());
            let json = serde_json::to_string(&k).unwrap();
            assert_eq!(json, format!("\"{}\"", k.name()));
        }
        let e = "dwb".parse::<PlannerKind>().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown planner `dwb` (expected dwa, mppi, log-mppi or system)"
        );
    }
}
