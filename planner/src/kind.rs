//! Which planner a run uses, and the factory that builds one for an episode.
//!
//! [`PlannerKind`] names the four planners the way configuration files, the command line,
//! tables and the wire protocol do; [`PlannerConfigs`] holds every planner's tunables, so one
//! call builds any of them.

use serde::{Deserialize, Serialize};

use crate::{Dwa, DwaConfig, LogMppi, LogMppiConfig, Mppi, MppiConfig, NavSystem, Planner, SystemConfig};

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
    /// `mppi`, `log-mppi`, `system`); the same as [`Planner::name`] of what it builds.
    pub fn name(self) -> &'static str {
        match self {
            PlannerKind::Dwa => "dwa",
            PlannerKind::Mppi => "mppi",
            PlannerKind::LogMppi => "log-mppi",
            PlannerKind::System => "system",
        }
    }

    /// A fresh planner for one episode with the tunables of `cfg`; `seed` drives its sampling
    /// (DWA samples a fixed grid and ignores it).
    pub fn build(self, cfg: &PlannerConfigs, seed: u64) -> Box<dyn Planner> {
        match self {
            PlannerKind::Dwa => Box::new(Dwa::new(cfg.dwa)),
            PlannerKind::Mppi => Box::new(Mppi::new(cfg.mppi, seed)),
            PlannerKind::LogMppi => Box::new(LogMppi::new(cfg.log_mppi, seed)),
            PlannerKind::System => Box::new(NavSystem::new(cfg.system, seed)),
        }
    }
}

/// Every planner's tunables (the `[dwa]`, `[mppi]`, `[log_mppi]` and `[system]` tables of an
/// evaluation configuration). Plain data.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlannerConfigs {
    /// DWA.
    pub dwa: DwaConfig,
    /// MPPI.
    pub mppi: MppiConfig,
    /// Log-MPPI.
    pub log_mppi: LogMppiConfig,
    /// The standalone navigation system.
    pub system: SystemConfig,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_match_the_built_planners() {
        let cfg = PlannerConfigs::default();
        for k in PlannerKind::ALL {
            assert_eq!(k.name().parse::<PlannerKind>(), Ok(k));
            assert_eq!(k.build(&cfg, 1).name(), k.name());
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
