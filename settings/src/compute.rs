//! The onboard compute model's configuration: what each unit of a planning cycle's [`Work`]
//! costs on the robot's computer, each planner's cycle budget, and the `[compute]` table
//! ([`ComputeConfig`]) that picks a [`Platform`] and resolves it for one planner
//! ([`Compute`]).
//!
//! On a robot, dynamics fidelity is paid for in computation; the model gives fidelity its
//! price, deterministically (never wall-clock time). The planners count their work and spend
//! their budget (`planner::compute`: the budget, the evaluation order, the tally); here is
//! the plain data they are priced with. Everything is `Copy` and thread-safe.

use std::ops::{Add, AddAssign};

use serde::{Deserialize, Serialize};

/// Work counted in one planning cycle (or summed over many), in the units its cost is made
/// of. Counting is exact and deterministic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Work {
    /// Distance-field (and costmap) cells built this cycle.
    pub cells: u64,
    /// Candidate rollouts started and scored (per-sample set-up and cost terms).
    pub samples: u64,
    /// Random numbers drawn (sampling noise).
    pub draws: u64,
    /// Rollout integration steps taken.
    pub steps: u64,
    /// Footprint collision-check points evaluated (robot centre + boundary points).
    pub points: u64,
}

impl Work {
    /// The counts as an array, in the field order (cells, samples, draws, steps, points).
    pub fn as_array(&self) -> [u64; 5] {
        [self.cells, self.samples, self.draws, self.steps, self.points]
    }

    /// The names of the units, in [`Work::as_array`] order.
    pub const UNITS: [&'static str; 5] = ["cells", "samples", "draws", "steps", "points"];
}

impl Add for Work {
    type Output = Work;

    fn add(self, o: Work) -> Work {
        Work {
            cells: self.cells + o.cells,
            samples: self.samples + o.samples,
            draws: self.draws + o.draws,
            steps: self.steps + o.steps,
            points: self.points + o.points,
        }
    }
}

impl AddAssign for Work {
    fn add_assign(&mut self, o: Work) {
        *self = *self + o;
    }
}

/// Cost of each unit of [`Work`] on a platform (ns), plus a fixed cost per cycle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnitCosts {
    /// Per planning cycle, whatever its work (perception hand-over, selection).
    pub cycle_ns: f64,
    /// Per distance-field cell built.
    pub cell_ns: f64,
    /// Per sample scored.
    pub sample_ns: f64,
    /// Per random number drawn.
    pub draw_ns: f64,
    /// Per rollout integration step.
    pub step_ns: f64,
    /// Per check point.
    pub point_ns: f64,
}

impl UnitCosts {
    /// Nothing costs anything.
    pub const ZERO: UnitCosts = UnitCosts {
        cycle_ns: 0.0,
        cell_ns: 0.0,
        sample_ns: 0.0,
        draw_ns: 0.0,
        step_ns: 0.0,
        point_ns: 0.0,
    };

    /// The modelled time of `w` (ns), without the per-cycle constant.
    pub fn work_ns(&self, w: &Work) -> f64 {
        self.cell_ns * w.cells as f64
            + self.sample_ns * w.samples as f64
            + self.draw_ns * w.draws as f64
            + self.step_ns * w.steps as f64
            + self.point_ns * w.points as f64
    }

    /// The modelled time of one cycle that did `w` (ns).
    pub fn cycle_ns(&self, w: &Work) -> f64 {
        self.cycle_ns + self.work_ns(w)
    }

    /// The same costs multiplied by `k`.
    pub fn scaled(&self, k: f64) -> UnitCosts {
        UnitCosts {
            cycle_ns: self.cycle_ns * k,
            cell_ns: self.cell_ns * k,
            sample_ns: self.sample_ns * k,
            draw_ns: self.draw_ns * k,
            step_ns: self.step_ns * k,
            point_ns: self.point_ns * k,
        }
    }

    fn validate(&self) -> Result<(), ComputeError> {
        let fields = [
            ("cycle_ns", self.cycle_ns),
            ("cell_ns", self.cell_ns),
            ("sample_ns", self.sample_ns),
            ("draw_ns", self.draw_ns),
            ("step_ns", self.step_ns),
            ("point_ns", self.point_ns),
        ];
        for (name, v) in fields {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ComputeError::Value {
                    key: name,
                    value: v,
                    why: "must be finite and >= 0",
                });
            }
        }
        Ok(())
    }
}

/// Each planner's cycle budget on a platform (ms of modelled compute).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerBudgets {
    /// DWA.
    pub dwa: f64,
    /// MPPI.
    pub mppi: f64,
    /// Log-MPPI.
    pub log_mppi: f64,
    /// The standalone system.
    pub system: f64,
}

/// Each planner's unit costs on a platform: the planners do different work per unit (a
/// system rollout step scores its obstacle terms, a DWA step is a table lookup), so each is
/// priced by its own table.
///
/// In a `[compute.platform.costs]` table, either one unit-cost table for every planner
/// (`cycle_ns`, `cell_ns`, ... at the top) or one sub-table per planner (`dwa`, `mppi`,
/// `log_mppi`, `system`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "CostsTable")]
pub struct PlannerCosts {
    /// DWA.
    pub dwa: UnitCosts,
    /// MPPI.
    pub mppi: UnitCosts,
    /// Log-MPPI.
    pub log_mppi: UnitCosts,
    /// The standalone system.
    pub system: UnitCosts,
}

impl PlannerCosts {
    /// The same costs for every planner.
    pub const fn shared(c: UnitCosts) -> PlannerCosts {
        PlannerCosts {
            dwa: c,
            mppi: c,
            log_mppi: c,
            system: c,
        }
    }

    /// Every planner's costs multiplied by `k`.
    pub fn scaled(&self, k: f64) -> PlannerCosts {
        PlannerCosts {
            dwa: self.dwa.scaled(k),
            mppi: self.mppi.scaled(k),
            log_mppi: self.log_mppi.scaled(k),
            system: self.system.scaled(k),
        }
    }

    /// The costs of the planner called `name` ([`crate::PlannerKind::name`]), if it is one.
    pub fn of(&self, name: &str) -> Option<UnitCosts> {
        match name {
            "dwa" => Some(self.dwa),
            "mppi" => Some(self.mppi),
            "log-mppi" => Some(self.log_mppi),
            "system" => Some(self.system),
            _ => None,
        }
    }

    /// The tables with their keys, in planner order.
    fn named(&self) -> [(&'static str, &UnitCosts); 4] {
        [
            ("dwa", &self.dwa),
            ("mppi", &self.mppi),
            ("log_mppi", &self.log_mppi),
            ("system", &self.system),
        ]
    }
}

/// The two spellings of a `costs` table (see [`PlannerCosts`]).
#[derive(Deserialize)]
#[serde(
    untagged,
    expecting = "either one unit-cost table for every planner (cycle_ns, \
    cell_ns, sample_ns, draw_ns, step_ns, point_ns) or one such table per planner (dwa, mppi, \
    log_mppi, system), every key present and nothing else"
)]
enum CostsTable {
    Shared(UnitCosts),
    PerPlanner(PerPlanner),
}

/// [`PlannerCosts`] as written per planner.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PerPlanner {
    dwa: UnitCosts,
    mppi: UnitCosts,
    log_mppi: UnitCosts,
    system: UnitCosts,
}

impl From<CostsTable> for PlannerCosts {
    fn from(t: CostsTable) -> PlannerCosts {
        match t {
            CostsTable::Shared(c) => PlannerCosts::shared(c),
            CostsTable::PerPlanner(p) => PlannerCosts {
                dwa: p.dwa,
                mppi: p.mppi,
                log_mppi: p.log_mppi,
                system: p.system,
            },
        }
    }
}

/// A reference computer: unit costs and cycle budgets.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Platform {
    /// What each unit of work costs, per planner.
    pub costs: PlannerCosts,
    /// Each planner's cycle budget (ms).
    pub budget_ms: PlannerBudgets,
}

impl Platform {
    /// The onboard computer of the papers' Jackal, as first modelled (`jackal-onboard`):
    /// one table of unit costs pooled over the four planners. Superseded by
    /// [`Platform::JACKAL_ONBOARD_V2`] (the pooled fit could not tell a per-sample cost from
    /// a per-cycle one, and priced a system rollout step like a DWA step); kept so the
    /// results measured under it reproduce.
    ///
    /// - Relative unit costs: measured on an Intel Xeon (2.3 GHz, 2 cores, the development
    ///   machine; 2026-11-25) by `adp bench compute --compute-worlds 6`: a non-negative
    ///   least-squares fit of each planning call's thread CPU time on its counted work, over
    ///   17,210 calls of DWA, MPPI, Log-MPPI and the system with the vanilla, DDP and three
    ///   constant schedules at 1.5 m/s on 6 training worlds (R^2 0.70-0.80 between runs).
    ///   Here: 2.3 ns per cell, 970 ns per sample, 1.6 ns per draw, 14.2 ns per step,
    ///   6.2 ns per point, no fixed cost.
    /// - Scale: the authors' standalone planner evaluates its 550 DDP samples within a 40 ms
    ///   limit per thread (`adp-code-notes.md` §4.3); the costs are scaled (x25.0) so that
    ///   the system's DDP cycle on those worlds at 1.5 m/s takes 40 ms at its 95th
    ///   percentile (it "just fits", as it did for its authors). Its median is then about
    ///   23 ms, the "~25 ms" of planning the `gazebo-jackal` latency assumed
    ///   (`sim::dynamics::PLANNING_LATENCY_S`).
    /// - Budgets: each planner's DDP configuration (550 samples for MPPI, Log-MPPI and the
    ///   system, the 20 x 20 DWA grid) just fits: the budget is that planner's DDP cycle
    ///   compute at its 95th percentile on the same worlds and speed.
    pub const JACKAL_ONBOARD: Platform = Platform {
        costs: PlannerCosts::shared(UnitCosts {
            cycle_ns: 0.0,
            cell_ns: 58.5,
            sample_ns: 24_300.0,
            draw_ns: 41.3,
            step_ns: 356.0,
            point_ns: 156.0,
        }),
        budget_ms: PlannerBudgets {
            dwa: 24.9,
            mppi: 41.0,
            log_mppi: 43.2,
            system: 40.0,
        },
    };

    /// The onboard computer of the papers' Jackal, as modelled here (`jackal-onboard-v2`, the
    /// default): each planner priced by its own fit.
    ///
    /// - Relative unit costs: measured on an Intel Xeon (2.3 GHz, 2 cores, the development
    ///   machine; 2026-11-26) by `adp bench compute --compute-worlds 6`: per planner, a
    ///   non-negative least-squares fit of each planning call's thread CPU time on its
    ///   counted work (and a fixed cost per cycle). 62,959 calls: DWA, MPPI, Log-MPPI and the
    ///   system, each with the vanilla, DDP and four constant schedules (N = 10 to 22) at
    ///   1.5 m/s on 6 training worlds, each at about 1/4, 1 and 2.25 times its configured
    ///   sample count (so that a per-sample cost can be told from a per-cycle one). R^2 per
    ///   planner: DWA 0.945, MPPI 0.994, Log-MPPI 0.996, the system 0.916; a second run gave
    ///   the same costs within 4 % (DWA's fixed cost within 35 %) and budgets within 0.2 ms.
    /// - Here (ns): DWA 26,800 per cycle, 3.9 per cell, 244 per sample, 4.2 per step, 4.1 per
    ///   point; MPPI 5.7 per cell, 182 per sample, 1.1 per draw, 25.7 per step, 4.3 per point;
    ///   Log-MPPI 4,520 per cycle, 5.2 per cell, 88 per sample, 9.2 per draw, 3.2 per point;
    ///   the system 6.7 per cell, 7.2 per sample, 44.1 per step, 5.7 per point. A system
    ///   step scores its obstacle terms and costs ten times a DWA step (a lookup in the
    ///   separable velocity profiles).
    /// - Scale: as for [`Platform::JACKAL_ONBOARD`], one factor (x31.7) for every planner,
    ///   so that the system's DDP cycle takes 40 ms at its 95th percentile (its median is
    ///   then about 22 ms, the "~25 ms" of `sim::dynamics::PLANNING_LATENCY_S`); the
    ///   scaled costs below are rounded to three significant digits.
    /// - Budgets: each planner's DDP cycle at its configured sample count, 95th percentile.
    pub const JACKAL_ONBOARD_V2: Platform = Platform {
        costs: PlannerCosts {
            dwa: UnitCosts {
                cycle_ns: 848_000.0,
                cell_ns: 125.0,
                sample_ns: 7_720.0,
                draw_ns: 0.0,
                step_ns: 134.0,
                point_ns: 130.0,
            },
            mppi: UnitCosts {
                cycle_ns: 0.0,
                cell_ns: 180.0,
                sample_ns: 5_750.0,
                draw_ns: 35.6,
                step_ns: 816.0,
                point_ns: 136.0,
            },
            log_mppi: UnitCosts {
                cycle_ns: 143_000.0,
                cell_ns: 166.0,
                sample_ns: 2_790.0,
                draw_ns: 291.0,
                step_ns: 0.0,
                point_ns: 101.0,
            },
            system: UnitCosts {
                cycle_ns: 0.0,
                cell_ns: 212.0,
                sample_ns: 227.0,
                draw_ns: 0.0,
                step_ns: 1_400.0,
                point_ns: 179.0,
            },
        },
        budget_ms: PlannerBudgets {
            dwa: 16.6,
            mppi: 34.58,
            log_mppi: 33.42,
            system: 40.0,
        },
    };

    /// The budget of the planner called `name` (ms; [`crate::PlannerKind::name`]), if it is one.
    pub fn budget_ms(&self, name: &str) -> Option<f64> {
        let b = &self.budget_ms;
        match name {
            "dwa" => Some(b.dwa),
            "mppi" => Some(b.mppi),
            "log-mppi" => Some(b.log_mppi),
            "system" => Some(b.system),
            _ => None,
        }
    }

    fn validate(&self) -> Result<(), ComputeError> {
        for (planner, c) in self.costs.named() {
            c.validate().map_err(|e| match e {
                ComputeError::Value { key, value, why } => ComputeError::PlannerValue {
                    planner,
                    key,
                    value,
                    why,
                },
                other => other,
            })?;
        }
        let b = &self.budget_ms;
        for (key, v) in [
            ("budget_ms.dwa", b.dwa),
            ("budget_ms.mppi", b.mppi),
            ("budget_ms.log_mppi", b.log_mppi),
            ("budget_ms.system", b.system),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ComputeError::Value {
                    key,
                    value: v,
                    why: "must be finite and > 0",
                });
            }
        }
        Ok(())
    }
}

/// Which platform prices the planners' work.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ComputeModel {
    /// Nothing costs anything: no budget, and the command acts after the profile's fixed
    /// latency (the behaviour before the model; old results stay reproducible).
    Free,
    /// [`Platform::JACKAL_ONBOARD`]: the first fit, one unit-cost table for all planners;
    /// the platform of the results measured before `jackal-onboard-v2` (policies trained
    /// under it record its name, so they still evaluate under it).
    JackalOnboard,
    /// [`Platform::JACKAL_ONBOARD_V2`]: each planner priced by its own fit (the default).
    #[default]
    JackalOnboardV2,
    /// The `[compute.platform]` table of the configuration.
    Custom,
}

/// The `[compute]` table of evaluation and training configurations.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ComputeConfig {
    /// The platform: `free`, `jackal-onboard-v2` (default), `jackal-onboard` (the first,
    /// pooled fit) or `custom`.
    pub model: ComputeModel,
    /// Multiplies every cycle budget (the budget sweep: 0.5, 1, 2); 1 by default.
    pub budget_scale: f64,
    /// The platform of `model = "custom"` (must be absent otherwise).
    pub platform: Option<Platform>,
}

impl Default for ComputeConfig {
    fn default() -> Self {
        Self {
            model: ComputeModel::default(),
            budget_scale: 1.0,
            platform: None,
        }
    }
}

/// A `[compute]` table that cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ComputeError {
    /// A value out of its domain.
    #[error("[compute] {key} = {value} is invalid: {why}")]
    Value {
        /// The key.
        key: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
    /// A planner's unit cost out of its domain.
    #[error("[compute.platform.costs.{planner}] {key} = {value} is invalid: {why}")]
    PlannerValue {
        /// The planner's key.
        planner: &'static str,
        /// The unit's key.
        key: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
    /// `model = "custom"` without a platform, or a platform with another model.
    #[error("[compute] model = \"custom\" needs a [compute.platform] table, and only it may have one")]
    Platform,
    /// A planner this model has no budget for.
    #[error("[compute] has no budget for planner {0:?}")]
    Planner(String),
}

/// The compute model resolved for one planner: unit costs and the cycle budget.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Compute {
    /// Unit costs (ns).
    pub costs: UnitCosts,
    /// The cycle budget (ns of modelled compute).
    pub budget_ns: f64,
}

impl ComputeConfig {
    /// The model that prices nothing.
    pub const FREE: ComputeConfig = ComputeConfig {
        model: ComputeModel::Free,
        budget_scale: 1.0,
        platform: None,
    };

    /// Checks the table; the error names the key.
    pub fn validate(&self) -> Result<(), ComputeError> {
        if !(self.budget_scale.is_finite() && self.budget_scale > 0.0) {
            return Err(ComputeError::Value {
                key: "budget_scale",
                value: self.budget_scale,
                why: "must be finite and > 0",
            });
        }
        match (self.model, &self.platform) {
            (ComputeModel::Custom, Some(p)) => p.validate(),
            (ComputeModel::Custom, None) | (_, Some(_)) => Err(ComputeError::Platform),
            _ => Ok(()),
        }
    }

    /// The platform, or `None` for the free model.
    pub fn platform(&self) -> Option<Platform> {
        match self.model {
            ComputeModel::Free => None,
            ComputeModel::JackalOnboard => Some(Platform::JACKAL_ONBOARD),
            ComputeModel::JackalOnboardV2 => Some(Platform::JACKAL_ONBOARD_V2),
            ComputeModel::Custom => self.platform,
        }
    }

    /// The model for the planner called `name` ([`crate::PlannerKind::name`]): `None` when
    /// free.
    pub fn resolve(&self, name: &str) -> Result<Option<Compute>, ComputeError> {
        self.validate()?;
        let Some(p) = self.platform() else {
            return Ok(None);
        };
        let ms = p
            .budget_ms(name)
            .ok_or_else(|| ComputeError::Planner(name.to_string()))?;
        Ok(Some(Compute {
            costs: p
                .costs
                .of(name)
                .ok_or_else(|| ComputeError::Planner(name.to_string()))?,
            budget_ns: ms * 1e6 * self.budget_scale,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn costs() -> UnitCosts {
        UnitCosts {
            cycle_ns: 1000.0,
            cell_ns: 1.0,
            sample_ns: 10.0,
            draw_ns: 2.0,
            step_ns: 3.0,
            point_ns: 4.0,
        }
    }

    #[test]
    fn cycle_cost_is_the_priced_sum_of_the_units() {
        let w = Work {
            cells: 100,
            samples: 2,
            draws: 5,
            steps: 7,
            points: 11,
        };
        // 1000 + 100 + 20 + 10 + 21 + 44
        assert_eq!(costs().cycle_ns(&w), 1195.0);
        assert_eq!(costs().scaled(2.0).cycle_ns(&w), 2390.0);
    }

    #[test]
    fn config_resolves_budgets_and_refuses_bad_tables() {
        let free = ComputeConfig::FREE;
        assert_eq!(free.resolve("dwa"), Ok(None));
        let mut custom = ComputeConfig {
            model: ComputeModel::Custom,
            budget_scale: 0.5,
            platform: Some(Platform {
                costs: PlannerCosts::shared(costs()),
                budget_ms: PlannerBudgets {
                    dwa: 10.0,
                    mppi: 20.0,
                    log_mppi: 30.0,
                    system: 40.0,
                },
            }),
        };
        let c = custom.resolve("system").unwrap().unwrap();
        assert_eq!(c.budget_ns, 20e6);
        assert_eq!(custom.resolve("nope"), Err(ComputeError::Planner("nope".into())));
        custom.budget_scale = 0.0;
        assert!(matches!(
            custom.resolve("dwa"),
            Err(ComputeError::Value {
                key: "budget_scale",
                ..
            })
        ));
        custom.budget_scale = 1.0;
        custom.model = ComputeModel::JackalOnboard;
        assert_eq!(custom.validate(), Err(ComputeError::Platform));
        let parsed: ComputeConfig = toml::from_str("model = \"free\"").unwrap();
        assert_eq!(parsed, ComputeConfig::FREE);
        assert!(toml::from_str::<ComputeConfig>("model = \"fast\"").is_err());
    }

    #[test]
    fn each_planner_is_priced_by_its_own_table() {
        let per = |k: f64| {
            format!(
            "cycle_ns = {k}\ncell_ns = 0.0\nsample_ns = 0.0\ndraw_ns = 0.0\nstep_ns = {k}\npoint_ns = 0.0\n"
        )
        };
        let budgets = "[platform.budget_ms]\ndwa = 1.0\nmppi = 2.0\nlog_mppi = 3.0\nsystem = 4.0\n";
        let text = format!(
            "model = \"custom\"\n[platform.costs.dwa]\n{}[platform.costs.mppi]\n{}\
             [platform.costs.log_mppi]\n{}[platform.costs.system]\n{}{budgets}",
            per(1.0),
            per(2.0),
            per(3.0),
            per(4.0)
        );
        let cfg: ComputeConfig = toml::from_str(&text).unwrap();
        // One cycle of 10 steps: 1 + 10 ns for DWA, 4 + 40 ns for the system.
        let w = Work {
            steps: 10,
            ..Work::default()
        };
        for (name, want) in [
            ("dwa", 11.0),
            ("mppi", 22.0),
            ("log-mppi", 33.0),
            ("system", 44.0),
        ] {
            let c = cfg.resolve(name).unwrap().unwrap();
            assert_eq!(c.costs.cycle_ns(&w), want, "{name}");
        }
        // One shared table prices every planner alike.
        let shared: ComputeConfig = toml::from_str(&format!(
            "model = \"custom\"\n[platform.costs]\n{}{budgets}",
            per(5.0)
        ))
        .unwrap();
        for name in ["dwa", "mppi", "log-mppi", "system"] {
            assert_eq!(shared.resolve(name).unwrap().unwrap().costs.cycle_ns(&w), 55.0);
        }
        // A table with a planner missing is refused, saying what a costs table may be.
        let missing = text.replace("[platform.costs.system]", "[platform.costs.elsewhere]");
        let err = toml::from_str::<ComputeConfig>(&missing).unwrap_err().to_string();
        assert!(err.contains("one such table per planner"), "{err}");
        // A negative cost names the planner and the key.
        let negative = text.replacen("step_ns = 3", "step_ns = -3", 1);
        let cfg: ComputeConfig = toml::from_str(&negative).unwrap();
        let err = cfg.validate().unwrap_err();
        assert_eq!(
            err.to_string(),
            "[compute.platform.costs.log_mppi] step_ns = -3 is invalid: must be finite and >= 0"
        );
        // The named platforms: v2 (the default) prices each planner by its own table, the
        // first platform every planner alike.
        assert_eq!(ComputeConfig::default().model, ComputeModel::JackalOnboardV2);
        let v2 = ComputeConfig::default();
        assert_ne!(
            v2.resolve("dwa").unwrap().unwrap().costs,
            v2.resolve("system").unwrap().unwrap().costs
        );
        let v1 = ComputeConfig {
            model: ComputeModel::JackalOnboard,
            ..ComputeConfig::default()
        };
        assert_eq!(
            v1.resolve("dwa").unwrap().unwrap().costs,
            v1.resolve("system").unwrap().unwrap().costs
        );
        let parsed: ComputeConfig = toml::from_str("model = \"jackal-onboard-v2\"").unwrap();
        assert_eq!(parsed, v2);
    }
}
