//! Which planner a run uses, and the factory that builds one for an episode.
//!
//! [`PlannerKind`] names the four planners the way configuration files, the command line,
//! tables and the wire protocol do ([`settings::kind`], re-exported here); [`PlannerConfigs`]
//! holds every planner's tunables and is the [`PlannerFactory`] behind [`PlannerKind::build`],
//! so one call builds any of them.

pub use settings::kind::{PlannerFactory, PlannerKind, UnknownPlanner};

use crate::{Dwa, DwaConfig, LogMppi, LogMppiConfig, Mppi, MppiConfig, NavSystem, Planner, SystemConfig};

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

impl PlannerFactory for PlannerConfigs {
    type Planner = Box<dyn Planner>;

    /// A fresh planner of `kind` with these tunables; `seed` drives its sampling (DWA samples
    /// a fixed grid and ignores it).
    fn build_planner(&self, kind: PlannerKind, seed: u64) -> Box<dyn Planner> {
        match kind {
            PlannerKind::Dwa => Box::new(Dwa::new(self.dwa)),
            PlannerKind::Mppi => Box::new(Mppi::new(self.mppi, seed)),
            PlannerKind::LogMppi => Box::new(LogMppi::new(self.log_mppi, seed)),
            PlannerKind::System => Box::new(NavSystem::new(self.system, seed)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_planners_have_their_kinds_name() {
        let cfg = PlannerConfigs::default();
        for k in PlannerKind::ALL {
            assert_eq!(k.build(&cfg, 1).name(), k.name());
            assert_eq!(k.build(&&cfg, 1).name(), k.name(), "through a reference too");
        }
    }
}
