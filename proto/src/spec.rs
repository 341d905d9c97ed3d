//! The run's settings on the wire: conversions between the planner name, the
//! [`ActionSpace`] and the [`EnvConfig`] (plain settings of the `adp-settings` crate) and their
//! `adp.v1` messages (`Planner`, `ActionSpace`, `EnvConfig` of the `RunSpec`), both ways.
//!
//! The learner builds the messages from its typed settings; an actor reads them back with the
//! `*_from_wire` functions, which refuse an unknown enum value, a missing part or an
//! out-of-range value with an error naming the field ([`SpecError`]). A decoded [`EnvConfig`]
//! has passed [`EnvConfig::validate`].

use layout::{LaserLayout, MAX_SECTORS};
use settings::compute::{PlannerBudgets, PlannerCosts, Platform, UnitCosts};
use settings::{
    ActionMap, ActionSpace, BeamChoices, ComputeConfig, ComputeModel, Dynamics, EnvConfig, EnvConfigError,
    Gains, PlannerKind, Profile, Randomize,
};

use crate::pb;

/// A run setting that cannot be put on the wire or read back from it.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// An enum field holds a value this build does not know.
    #[error("{field} = {value} is not a known value")]
    UnknownValue {
        /// The field, e.g. `env.action_map`.
        field: &'static str,
        /// The value as sent.
        value: i32,
    },
    /// A required enum field is unspecified (0).
    #[error("{field} is unspecified")]
    Unspecified {
        /// The field.
        field: &'static str,
    },
    /// A required message is absent.
    #[error("{field} is missing")]
    Missing {
        /// The field.
        field: &'static str,
    },
    /// A value outside its range.
    #[error("{field} = {value} is out of range: {why}")]
    OutOfRange {
        /// The field.
        field: &'static str,
        /// The value as sent.
        value: String,
        /// What it must be.
        why: String,
    },
    /// The environment settings decode but do not validate.
    #[error(transparent)]
    Env(#[from] EnvConfigError),
}

/// The wire value of a planner.
pub fn planner_to_wire(kind: PlannerKind) -> pb::Planner {
    match kind {
        PlannerKind::Dwa => pb::Planner::Dwa,
        PlannerKind::Mppi => pb::Planner::Mppi,
        PlannerKind::LogMppi => pb::Planner::LogMppi,
        PlannerKind::System => pb::Planner::System,
    }
}

/// The planner of the wire value `value` of field `field`.
pub fn planner_from_wire(field: &'static str, value: i32) -> Result<PlannerKind, SpecError> {
    match known(field, value, pb::Planner::try_from(value))? {
        pb::Planner::Unspecified => Err(SpecError::Unspecified { field }),
        pb::Planner::Dwa => Ok(PlannerKind::Dwa),
        pb::Planner::Mppi => Ok(PlannerKind::Mppi),
        pb::Planner::LogMppi => Ok(PlannerKind::LogMppi),
        pb::Planner::System => Ok(PlannerKind::System),
    }
}

/// The wire message of an action space.
pub fn action_space_to_wire(space: ActionSpace) -> pb::ActionSpace {
    use pb::ActionSpaceKind as K;
    let (kind, gains) = match space {
        ActionSpace::Decremental => (K::Decremental, None),
        ActionSpace::Incremental => (K::Incremental, None),
        ActionSpace::Unconstrained => (K::Unconstrained, None),
        ActionSpace::Fixed => (K::Fixed, None),
        ActionSpace::Weights(g) => (K::Weights, Some(g)),
        ActionSpace::DecrementalWeights(g) => (K::DecrementalWeights, Some(g)),
        ActionSpace::Velocity => (K::Velocity, None),
    };
    let gains = gains.map_or(pb::Planner::Unspecified, |g| match g {
        Gains::Dwa => pb::Planner::Dwa,
        Gains::Mppi => pb::Planner::Mppi,
        Gains::System => pb::Planner::System,
    });
    pb::ActionSpace {
        kind: kind as i32,
        gains: gains as i32,
    }
}

/// The action space of its wire message (`spec.action_space`).
pub fn action_space_from_wire(m: &pb::ActionSpace) -> Result<ActionSpace, SpecError> {
    use pb::ActionSpaceKind as K;
    let gains = || {
        let planner = planner_from_wire("spec.action_space.gains", m.gains)?;
        Gains::for_planner(planner.name()).map_err(|e| SpecError::OutOfRange {
            field: "spec.action_space.gains",
            value: planner.name().to_owned(),
            why: e.to_string(),
        })
    };
    let field = "spec.action_space.kind";
    Ok(match known(field, m.kind, K::try_from(m.kind))? {
        K::Unspecified => return Err(SpecError::Unspecified { field }),
        K::Decremental => ActionSpace::Decremental,
        K::Incremental => ActionSpace::Incremental,
        K::Unconstrained => ActionSpace::Unconstrained,
        K::Fixed => ActionSpace::Fixed,
        K::Weights => ActionSpace::Weights(gains()?),
        K::DecrementalWeights => ActionSpace::DecrementalWeights(gains()?),
        K::Velocity => ActionSpace::Velocity,
    })
}

/// The wire message of environment settings.
pub fn env_to_wire(env: &EnvConfig) -> pb::EnvConfig {
    pb::EnvConfig {
        agent_period_cycles: env.agent_period_cycles,
        max_agent_steps: env.max_agent_steps,
        laser_clip_m: env.laser_clip_m,
        progress_scale: env.progress_scale,
        step_penalty: env.step_penalty,
        obstacle_threshold_m: env.obstacle_threshold_m,
        obstacle_scale: env.obstacle_scale,
        collision_reward: env.collision_reward,
        timeout_reward: env.timeout_reward,
        stuck_window: env.stuck_window,
        stuck_progress_m: env.stuck_progress_m,
        stuck_reward: env.stuck_reward,
        success_reward: env.success_reward,
        reward_scale: env.reward_scale,
        action_map: match env.action_map {
            ActionMap::DdpCentred => pb::ActionMap::DdpCentred,
            ActionMap::Affine => pb::ActionMap::Affine,
        } as i32,
        profile: match env.profile {
            Profile::Ideal => pb::Profile::Ideal,
            Profile::GazeboJackal => pb::Profile::GazeboJackal,
            Profile::Custom => pb::Profile::Custom,
        } as i32,
        dynamics: env.dynamics.as_ref().map(dynamics_to_wire),
        compute: Some(compute_to_wire(&env.compute)),
        observe_tracks: env.observe_tracks as u32,
        laser_sectors: match env.observation {
            LaserLayout::Scan => 0,
            LaserLayout::Sectors(n) => n as u32,
        },
        randomize: Some(pb::Randomize {
            beams: env.randomize.beams.as_slice().iter().map(|&b| b as u32).collect(),
            noise_fraction: env.randomize.noise_fraction.map(range_to_wire),
            dropout: env.randomize.dropout.map(range_to_wire),
        }),
    }
}

/// The environment settings of their wire message (`spec.env`), validated.
pub fn env_from_wire(m: &pb::EnvConfig) -> Result<EnvConfig, SpecError> {
    let action_map = match known(
        "env.action_map",
        m.action_map,
        pb::ActionMap::try_from(m.action_map),
    )? {
        pb::ActionMap::Unspecified => {
            return Err(SpecError::Unspecified {
                field: "env.action_map",
            })
        }
        pb::ActionMap::DdpCentred => ActionMap::DdpCentred,
        pb::ActionMap::Affine => ActionMap::Affine,
    };
    let profile = match known("env.profile", m.profile, pb::Profile::try_from(m.profile))? {
        pb::Profile::Unspecified => return Err(SpecError::Unspecified { field: "env.profile" }),
        pb::Profile::Ideal => Profile::Ideal,
        pb::Profile::GazeboJackal => Profile::GazeboJackal,
        pb::Profile::Custom => Profile::Custom,
    };
    let observation = match m.laser_sectors {
        0 => LaserLayout::Scan,
        n if n as usize <= MAX_SECTORS => LaserLayout::Sectors(n as usize),
        n => {
            return Err(SpecError::OutOfRange {
                field: "env.laser_sectors",
                value: n.to_string(),
                why: format!("0 (the scan) or a sector count in 1..={MAX_SECTORS}"),
            })
        }
    };
    let randomize = m.randomize.as_ref().ok_or(SpecError::Missing {
        field: "env.randomize",
    })?;
    let beams: Vec<usize> = randomize.beams.iter().map(|&b| b as usize).collect();
    let env = EnvConfig {
        agent_period_cycles: m.agent_period_cycles,
        max_agent_steps: m.max_agent_steps,
        laser_clip_m: m.laser_clip_m,
        progress_scale: m.progress_scale,
        step_penalty: m.step_penalty,
        obstacle_threshold_m: m.obstacle_threshold_m,
        obstacle_scale: m.obstacle_scale,
        collision_reward: m.collision_reward,
        timeout_reward: m.timeout_reward,
        stuck_window: m.stuck_window,
        stuck_progress_m: m.stuck_progress_m,
        stuck_reward: m.stuck_reward,
        success_reward: m.success_reward,
        reward_scale: m.reward_scale,
        action_map,
        profile,
        dynamics: m.dynamics.as_ref().map(dynamics_from_wire),
        compute: compute_from_wire(
            m.compute
                .as_ref()
                .ok_or(SpecError::Missing { field: "env.compute" })?,
        )?,
        observe_tracks: m.observe_tracks as usize,
        observation,
        randomize: Randomize {
            beams: BeamChoices::try_from(beams).map_err(|e| SpecError::OutOfRange {
                field: "env.randomize.beams",
                value: format!("{:?}", randomize.beams),
                why: e.to_string(),
            })?,
            noise_fraction: randomize.noise_fraction.map(range_from_wire),
            dropout: randomize.dropout.map(range_from_wire),
        },
    };
    env.validate()?;
    Ok(env)
}

/// The known enum value `parsed` of `value`, or the error naming `field`.
fn known<T, E>(field: &'static str, value: i32, parsed: Result<T, E>) -> Result<T, SpecError> {
    parsed.map_err(|_| SpecError::UnknownValue { field, value })
}

fn range_to_wire([low, high]: [f64; 2]) -> pb::Range {
    pb::Range { low, high }
}

fn range_from_wire(r: pb::Range) -> [f64; 2] {
    [r.low, r.high]
}

fn dynamics_to_wire(d: &Dynamics) -> pb::Dynamics {
    pb::Dynamics {
        accel_v: d.accel_v,
        decel_v: d.decel_v,
        accel_w: d.accel_w,
        lag_s: d.lag_s,
        latency_s: d.latency_s,
        slip_per_v: d.slip_per_v,
        slip_per_w: d.slip_per_w,
        max_slip: d.max_slip,
        side_slip: d.side_slip,
        drift_yaw: d.drift_yaw,
        drift_pos: d.drift_pos,
    }
}

fn dynamics_from_wire(d: &pb::Dynamics) -> Dynamics {
    Dynamics {
        accel_v: d.accel_v,
        decel_v: d.decel_v,
        accel_w: d.accel_w,
        lag_s: d.lag_s,
        latency_s: d.latency_s,
        slip_per_v: d.slip_per_v,
        slip_per_w: d.slip_per_w,
        max_slip: d.max_slip,
        side_slip: d.side_slip,
        drift_yaw: d.drift_yaw,
        drift_pos: d.drift_pos,
    }
}

fn compute_to_wire(c: &ComputeConfig) -> pb::ComputeConfig {
    let unit = |u: &UnitCosts| pb::UnitCosts {
        cycle_ns: u.cycle_ns,
        cell_ns: u.cell_ns,
        sample_ns: u.sample_ns,
        draw_ns: u.draw_ns,
        step_ns: u.step_ns,
        point_ns: u.point_ns,
    };
    pb::ComputeConfig {
        model: match c.model {
            ComputeModel::Free => pb::ComputeModel::Free,
            ComputeModel::JackalOnboard => pb::ComputeModel::JackalOnboard,
            ComputeModel::JackalOnboardV2 => pb::ComputeModel::JackalOnboardV2,
            ComputeModel::Custom => pb::ComputeModel::Custom,
        } as i32,
        budget_scale: c.budget_scale,
        platform: c.platform.as_ref().map(|p| pb::Platform {
            costs: Some(pb::PlannerCosts {
                dwa: Some(unit(&p.costs.dwa)),
                mppi: Some(unit(&p.costs.mppi)),
                log_mppi: Some(unit(&p.costs.log_mppi)),
                system: Some(unit(&p.costs.system)),
            }),
            budget_ms: Some(pb::PlannerBudgets {
                dwa: p.budget_ms.dwa,
                mppi: p.budget_ms.mppi,
                log_mppi: p.budget_ms.log_mppi,
                system: p.budget_ms.system,
            }),
        }),
    }
}

fn compute_from_wire(c: &pb::ComputeConfig) -> Result<ComputeConfig, SpecError> {
    let field = "env.compute.model";
    let model = match known(field, c.model, pb::ComputeModel::try_from(c.model))? {
        pb::ComputeModel::Unspecified => return Err(SpecError::Unspecified { field }),
        pb::ComputeModel::Free => ComputeModel::Free,
        pb::ComputeModel::JackalOnboard => ComputeModel::JackalOnboard,
        pb::ComputeModel::JackalOnboardV2 => ComputeModel::JackalOnboardV2,
        pb::ComputeModel::Custom => ComputeModel::Custom,
    };
    let unit = |u: &Option<pb::UnitCosts>, field: &'static str| {
        u.as_ref()
            .map(|u| UnitCosts {
                cycle_ns: u.cycle_ns,
                cell_ns: u.cell_ns,
                sample_ns: u.sample_ns,
                draw_ns: u.draw_ns,
                step_ns: u.step_ns,
                point_ns: u.point_ns,
            })
            .ok_or(SpecError::Missing { field })
    };
    let platform = match &c.platform {
        None => None,
        Some(p) => {
            let costs = p.costs.as_ref().ok_or(SpecError::Missing {
                field: "env.compute.platform.costs",
            })?;
            let budget = p.budget_ms.as_ref().ok_or(SpecError::Missing {
                field: "env.compute.platform.budget_ms",
            })?;
            Some(Platform {
                costs: PlannerCosts {
                    dwa: unit(&costs.dwa, "env.compute.platform.costs.dwa")?,
                    mppi: unit(&costs.mppi, "env.compute.platform.costs.mppi")?,
                    log_mppi: unit(&costs.log_mppi, "env.compute.platform.costs.log_mppi")?,
                    system: unit(&costs.system, "env.compute.platform.costs.system")?,
                },
                budget_ms: PlannerBudgets {
                    dwa: budget.dwa,
                    mppi: budget.mppi,
                    log_mppi: budget.log_mppi,
                    system: budget.system,
                },
            })
        }
    };
    Ok(ComputeConfig {
        model,
        budget_scale: c.budget_scale,
        platform,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_setting_survives_the_wire_both_ways() {
        let custom: EnvConfig = toml::from_str(
            r#"
            agent_period_cycles = 4
            max_agent_steps = 300
            laser_clip_m = 4.5
            reward_scale = 0.02
            action_map = "affine"
            profile = "custom"
            observe_tracks = 3
            observation = "sectors:25"
            stuck_window = 20
            stuck_progress_m = 0.4
            stuck_reward = -5.0
            [dynamics]
            accel_v = 2.0
            decel_v = 2.5
            accel_w = 3.0
            lag_s = 0.1
            latency_s = 0.05
            slip_per_v = 0.01
            slip_per_w = 0.02
            max_slip = 0.3
            side_slip = 0.01
            drift_yaw = 0.001
            drift_pos = 0.002
            [compute]
            model = "custom"
            budget_scale = 2.0
            [compute.platform]
            budget_ms = { dwa = 20.0, mppi = 30.0, log_mppi = 31.0, system = 40.0 }
            [compute.platform.costs]
            dwa = { cycle_ns = 1.0, cell_ns = 2.0, sample_ns = 3.0, draw_ns = 4.0, step_ns = 5.0, point_ns = 6.0 }
            mppi = { cycle_ns = 1.5, cell_ns = 2.0, sample_ns = 3.0, draw_ns = 4.0, step_ns = 5.0, point_ns = 6.0 }
            log_mppi = { cycle_ns = 1.0, cell_ns = 2.5, sample_ns = 3.0, draw_ns = 4.0, step_ns = 5.0, point_ns = 6.0 }
            system = { cycle_ns = 1.0, cell_ns = 2.0, sample_ns = 3.5, draw_ns = 4.0, step_ns = 5.0, point_ns = 6.0 }
            [randomize]
            beams = [90, 360, 720]
            noise_fraction = [0.0, 0.02]
            dropout = [0.0, 0.1]
            "#,
        )
        .unwrap();
        custom.validate().unwrap();
        for env in [EnvConfig::default(), custom] {
            assert_eq!(env_from_wire(&env_to_wire(&env)).unwrap(), env);
        }
        for space in [
            ActionSpace::Decremental,
            ActionSpace::Incremental,
            ActionSpace::Unconstrained,
            ActionSpace::Fixed,
            ActionSpace::Weights(Gains::Dwa),
            ActionSpace::DecrementalWeights(Gains::System),
            ActionSpace::Velocity,
        ] {
            assert_eq!(
                action_space_from_wire(&action_space_to_wire(space)).unwrap(),
                space
            );
        }
        for kind in PlannerKind::ALL {
            let wire = planner_to_wire(kind) as i32;
            assert_eq!(planner_from_wire("spec.planner", wire).unwrap(), kind);
        }
        assert!(planner_from_wire("spec.planner", 9).is_err());
    }

    #[test]
    fn bad_values_are_refused_naming_the_field() {
        let good = env_to_wire(&EnvConfig::default());
        let refused = |m: pb::EnvConfig| env_from_wire(&m).unwrap_err().to_string();
        let e = refused(pb::EnvConfig {
            action_map: 7,
            ..good.clone()
        });
        assert_eq!(e, "env.action_map = 7 is not a known value");
        let e = refused(pb::EnvConfig {
            profile: 0,
            ..good.clone()
        });
        assert_eq!(e, "env.profile is unspecified");
        let e = refused(pb::EnvConfig {
            laser_sectors: 721,
            ..good.clone()
        });
        assert!(e.starts_with("env.laser_sectors = 721 is out of range"), "{e}");
        let e = refused(pb::EnvConfig {
            observe_tracks: 17,
            ..good.clone()
        });
        assert!(e.contains("observe_tracks = 17"), "{e}");
        let e = refused(pb::EnvConfig {
            laser_clip_m: f64::NAN,
            ..good.clone()
        });
        assert!(e.contains("laser_clip_m = NaN"), "{e}");
        let e = refused(pb::EnvConfig {
            compute: None,
            ..good.clone()
        });
        assert_eq!(e, "env.compute is missing");
        let e = refused(pb::EnvConfig {
            randomize: Some(pb::Randomize {
                beams: vec![90; 9],
                ..Default::default()
            }),
            ..good
        });
        assert!(e.starts_with("env.randomize.beams"), "{e}");
        let e = action_space_from_wire(&pb::ActionSpace {
            kind: pb::ActionSpaceKind::Weights as i32,
            gains: pb::Planner::LogMppi as i32,
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("spec.action_space.gains = log-mppi is out of range"),
            "{e}"
        );
        let e = action_space_from_wire(&pb::ActionSpace { kind: 42, gains: 0 })
            .unwrap_err()
            .to_string();
        assert_eq!(e, "spec.action_space.kind = 42 is not a known value");
    }
}
