//! PADP wired into the planning loop: the predictive cost field in the global path (Eqs. 4-6)
//! and the complexity-adaptive planning weights (Eqs. 7-8) of Wang and Yang's PADP paper
//! (`/work/shared/papers/padp-kalman-prediction-complexity-adaptive.md`).
//!
//! Both run on the obstacle tracker's forecast ([`Tracking`]), once per planning cycle, after
//! the tracker's update and before the planner ([`crate::run::CycleDriver::with_padp`]):
//!
//! - **path** ([`PadpParts::path`]): the confirmed moving tracks are handed to the episode's
//!   global path search, which adds `predictive_cost_weight x J_dyn` to every cell's cost
//!   ([`sim::navigation::PathRisk`]) at its next replans;
//! - **adapt** ([`PadpParts::adapt`]): the three terms of Eq. 7 are measured on the robot's
//!   own map, path and tracks ([`measure_pressure`]), the hysteresis switch of Eq. 8 picks the
//!   mode, and a change of mode rescales the planner's gains by their role and the global
//!   replanning interval ([`ModeEffects`]; the mapping is documented in
//!   [`crate::complexity`]). A planner without gains (Log-MPPI) only changes its replanning
//!   interval.
//!
//! Without tracks nothing is added to the path search, and with neither part on nothing runs:
//! the rows of `--prediction kf` are unchanged.

use serde::{Deserialize, Serialize};
use sim::costmap::LETHAL;
use sim::navigation::PathRisk;
use sim::predictive_cost::PredictiveCostConfig;
use sim::Episode;

use crate::complexity::{entropy, ComplexityConfig, ModeEffects, ModeSwitch, PressureMode};
use crate::gains::GainRole;
use crate::moving::{point_segment_distance, Predicted, Tracking};
use crate::Planner;

/// PADP's settings: the `[prediction]` table of the evaluation configuration. Every field is
/// optional in a TOML table; unknown keys are refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PadpConfig {
    /// `kappa_d` of Eq. 6 in the scale of the global path search's costs (see
    /// [`PathRisk`]): 5.0 keeps the paper's `kappa_d / kappa_s = 2.35 / 1.40` against the
    /// search's inflation weight of 3.0.
    pub predictive_cost_weight: f64,
    /// The predictive field (Eqs. 4-5).
    pub field: PredictiveCostConfig,
    /// The complexity score and its switch (Eqs. 7-8).
    pub complexity: ComplexityConfig,
    /// What each mode changes.
    pub modes: ModeEffects,
    /// The residual corrector file of the rows of `--prediction kf-res` (JSON,
    /// [`crate::residual::CorrectorFile`]; a relative path is taken from the working
    /// directory); `None`: the corrector embedded in the `adp` binary.
    pub residual: Option<std::path::PathBuf>,
}

impl Default for PadpConfig {
    fn default() -> Self {
        Self {
            predictive_cost_weight: 5.0,
            field: PredictiveCostConfig::default(),
            complexity: ComplexityConfig::default(),
            modes: ModeEffects::default(),
            residual: None,
        }
    }
}

/// A `[prediction]` setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[prediction{table}] {key}: {why}")]
pub struct PadpConfigError {
    /// The sub-table (`""`, `".field"`, `".complexity"` or `".modes"`).
    pub table: &'static str,
    /// The key.
    pub key: &'static str,
    /// What is wrong.
    pub why: String,
}

impl PadpConfig {
    /// Checks every field; the error names the table and the key.
    pub fn validate(&self) -> Result<(), PadpConfigError> {
        let w = self.predictive_cost_weight;
        if !(w.is_finite() && w >= 0.0) {
            return Err(PadpConfigError {
                table: "",
                key: "predictive_cost_weight",
                why: format!("{w}: must be finite and >= 0"),
            });
        }
        self.field.validate().map_err(|e| PadpConfigError {
            table: ".field",
            key: e.key,
            why: format!("{}: {}", e.value, e.why),
        })?;
        self.complexity.validate().map_err(|e| PadpConfigError {
            table: ".complexity",
            key: e.key,
            why: e.why,
        })?;
        self.modes.validate().map_err(|e| PadpConfigError {
            table: ".modes",
            key: e.key,
            why: e.why,
        })
    }

    /// The predictive cost the global path search weighs.
    pub fn path_risk(&self) -> PathRisk {
        PathRisk {
            weight: self.predictive_cost_weight,
            field: self.field,
        }
    }
}

/// Which parts of PADP run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PadpParts {
    /// The predictive cost field in the global path search (Eqs. 4-6).
    pub path: bool,
    /// The complexity-adaptive weights and replanning interval (Eqs. 7-8).
    pub adapt: bool,
}

/// The terms of Eq. 7 in one cycle and their score.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pressure {
    /// Moving tracks within sensing range.
    pub moving: usize,
    /// Blocked share of the global path ahead, in [0, 1].
    pub blocked: f64,
    /// Normalized entropy of the local costs, in [0, 1].
    pub entropy: f64,
    /// The score `Phi`.
    pub phi: f64,
}

/// Measures the terms of Eq. 7 in the episode's current cycle, with `moving` the tracker's
/// moving obstacles (robot frame) and `horizon` how far ahead their forecast counts (s):
///
/// - `rho`: the moving obstacles within [`ComplexityConfig::range`] of the robot;
/// - `beta`: the share of the global path's points within [`ComplexityConfig::ahead`]
///   metres of arc length from the point nearest the robot that are blocked: in a lethal
///   cell of the robot's costmap, or within an obstacle's radius plus the costmap's lethal
///   radius of the segment its centre sweeps over `horizon`;
/// - `H`: the entropy of the costmap's cells within the range (each cost over 253, lethal
///   and obstacle cells 1) over [`ComplexityConfig::bins`] bins, normalized.
///
/// `costs` is scratch (its capacity is kept).
pub fn measure_pressure(
    ep: &Episode<'_>,
    moving: &[Predicted],
    cfg: &ComplexityConfig,
    horizon: f64,
    costs: &mut Vec<f64>,
) -> Pressure {
    let range = cfg.range;
    let count = moving.iter().filter(|o| o.position.norm() <= range).count();

    let believed = ep.believed_pose();
    let here = believed.position();
    let map = ep.costmap();
    let reach = ep.config().costmap.lethal_radius;
    let path = ep.global_path();
    let nearest = path
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.dist(here).total_cmp(&b.1.dist(here)))
        .map_or(0, |(i, _)| i);
    let (mut points, mut blocked, mut arc) = (0usize, 0usize, 0.0);
    for (k, p) in path.iter().enumerate().skip(nearest) {
        if k > nearest {
            arc += p.dist(path[k - 1]);
            if arc > cfg.ahead {
                break;
            }
        }
        points += 1;
        let lethal = map.cell_of(*p).is_some_and(|(x, y)| map.cost(x, y) >= LETHAL);
        let local = believed.to_local(*p);
        let crossed = || {
            moving.iter().any(|o| {
                point_segment_distance(local, o.position, o.position + o.velocity * horizon)
                    <= o.radius + reach
            })
        };
        if lethal || crossed() {
            blocked += 1;
        }
    }
    let share = if points > 0 {
        blocked as f64 / points as f64
    } else {
        0.0
    };

    costs.clear();
    let (first, res) = (map.center(0, 0), map.resolution());
    let cells = |centre: f64, first: f64, n: usize| {
        let lo = ((centre - range - first) / res).ceil().max(0.0) as usize;
        let hi = ((centre + range - first) / res).floor().min(n as f64 - 1.0);
        (lo, if hi < 0.0 { None } else { Some(hi as usize) })
    };
    if let ((x0, Some(x1)), (y0, Some(y1))) =
        (cells(here.x, first.x, map.nx()), cells(here.y, first.y, map.ny()))
    {
        for iy in y0..=y1 {
            for ix in x0..=x1 {
                if map.center(ix, iy).dist(here) <= range {
                    costs.push(f64::from(map.cost(ix, iy).min(253)) / 253.0);
                }
            }
        }
    }
    let h = entropy(costs, cfg.bins);
    Pressure {
        moving: count,
        blocked: share,
        entropy: h,
        phi: cfg.score(count, share, h),
    }
}

/// The gain factors of `mode` for gains of `roles`, into `out` (one per role): the mode's
/// efficiency factor on efficiency gains, its risk factor on risk gains, 1 on the others.
pub fn mode_factors(roles: &[GainRole], effects: &ModeEffects, mode: PressureMode, out: &mut [f64]) {
    let i = mode.index();
    for (f, role) in out.iter_mut().zip(roles) {
        *f = match role {
            GainRole::Efficiency => effects.efficiency[i],
            GainRole::Risk => effects.risk[i],
            GainRole::Other => 1.0,
        };
    }
}

/// Most gains of any planner ([`crate::Gains`]).
const MAX_GAINS: usize = 8;

/// PADP in one episode: the mode switch, the last pressure and the scratch of its
/// measurement. One per episode.
#[derive(Clone, Debug)]
pub struct Padp {
    cfg: PadpConfig,
    parts: PadpParts,
    switch: ModeSwitch,
    /// The mode whose effects the planner and the episode have (none before the first cycle).
    applied: Option<PressureMode>,
    last: Pressure,
    costs: Vec<f64>,
}

impl Padp {
    /// PADP with `cfg` (validated by the caller: [`PadpConfig::validate`]) running `parts`.
    pub fn new(cfg: PadpConfig, parts: PadpParts) -> Self {
        Self {
            cfg,
            parts,
            switch: ModeSwitch::default(),
            applied: None,
            last: Pressure::default(),
            costs: Vec::new(),
        }
    }

    /// The parts that run.
    pub fn parts(&self) -> PadpParts {
        self.parts
    }

    /// The current mode (A until the adaptive part has seen pressure).
    pub fn mode(&self) -> PressureMode {
        self.switch.mode()
    }

    /// The pressure of the last cycle (zero without the adaptive part).
    pub fn pressure(&self) -> Pressure {
        self.last
    }

    /// One planning cycle, after `tracking` has taken the episode's scan and before `planner`
    /// plans: hands the forecast to the global path search (path), measures the pressure,
    /// updates the mode and, when it changed, applies its effects to `planner` and `ep`
    /// (adapt).
    pub fn cycle(&mut self, ep: &mut Episode<'_>, tracking: &Tracking, planner: &mut dyn Planner) {
        if self.parts.path {
            let now = ep.sim_time();
            ep.forecast_moving(
                self.cfg.path_risk(),
                now,
                tracking.moving_in_map().iter().copied(),
            );
        }
        if !self.parts.adapt {
            return;
        }
        let horizon = self.cfg.field.steps as f64 * self.cfg.field.step_s;
        self.last = measure_pressure(
            ep,
            tracking.moving(),
            &self.cfg.complexity,
            horizon,
            &mut self.costs,
        );
        self.apply_score(self.last.phi, ep, planner);
    }

    /// Feeds the score `phi` to the mode switch (Eq. 8) and, when the mode changed (or on the
    /// first call), applies its effects: `planner`'s gain factors by role ([`mode_factors`])
    /// and `ep`'s replanning interval. Returns the mode.
    pub fn apply_score(&mut self, phi: f64, ep: &mut Episode<'_>, planner: &mut dyn Planner) -> PressureMode {
        let mode = self.switch.update(phi, &self.cfg.complexity);
        if self.applied == Some(mode) {
            return mode;
        }
        self.applied = Some(mode);
        if let Some(gains) = planner.gains() {
            let mut factors = [1.0; MAX_GAINS];
            let n = gains.len();
            mode_factors(gains.roles(), &self.cfg.modes, mode, &mut factors[..n]);
            planner
                .set_gain_factors(&factors[..n])
                .expect("validated mode factors are finite and >= 0, one per gain");
        }
        let every = self.cfg.modes.replan_every(mode, ep.config().replan_every);
        ep.set_replan_every(every);
        mode
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Gains;
    use sim::geometry::{Pose, Vec2};
    use sim::{EpisodeConfig, World};

    #[test]
    fn each_mode_scales_the_gains_of_its_role() {
        let fx = ModeEffects::default();
        let mut f = [0.0; 4];
        mode_factors(Gains::Dwa.roles(), &fx, PressureMode::A, &mut f);
        assert_eq!(f, [1.25, 1.0, 0.8, 1.25], "w_goal, w_path, w_obstacle, w_speed");
        mode_factors(Gains::Dwa.roles(), &fx, PressureMode::B, &mut f);
        assert_eq!(f, [1.0; 4], "B is the configured planner");
        mode_factors(Gains::System.roles(), &fx, PressureMode::C, &mut f);
        assert_eq!(f, [0.8, 1.5, 1.0, 1.0], "goal, obstacle, heading, space");
    }

    #[test]
    fn bad_settings_name_their_table_and_key() {
        PadpConfig::default().validate().unwrap();
        let mut bad = PadpConfig {
            predictive_cost_weight: -1.0,
            ..PadpConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("[prediction] predictive_cost_weight: -1"));
        bad = PadpConfig::default();
        bad.field.gamma = 2.0;
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("[prediction.field] gamma: 2"));
        bad = PadpConfig::default();
        bad.complexity.bins = 1;
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("[prediction.complexity] bins"));
        bad = PadpConfig::default();
        bad.modes.risk[2] = -0.5;
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .starts_with("[prediction.modes] risk"));
    }

    /// An open 24 m x 10 m world with the robot at the origin facing +x and the goal 10 m
    /// ahead.
    fn open_world() -> World {
        World::new(0, vec![], Pose::default(), Vec2::new(10.0, 0.0), 5.0, vec![])
    }

    #[test]
    fn the_pressure_counts_near_tracks_and_the_path_they_cross() {
        let world = open_world();
        let ep = Episode::new(&world, EpisodeConfig::default(), 1);
        let cfg = ComplexityConfig::default();
        let mut costs = Vec::new();
        // Nothing around: no pressure (an empty map has one cost, zero entropy).
        let calm = measure_pressure(&ep, &[], &cfg, 2.8, &mut costs);
        assert_eq!(calm, Pressure::default());
        assert!(!costs.is_empty());
        // Two tracks within 6 m, one beyond. The first crosses the path 2 m ahead within its
        // horizon: its swept segment, widened by its radius and the lethal radius (0.5 +
        // 0.22), covers the path from x = 1.28 to 2.72. The 3 m ahead hold 30 points: the
        // robot's own, then the cell centres x = 0.15, 0.25, ..., 2.95; 14 are blocked
        // (1.35 ... 2.65).
        let moving = [
            Predicted {
                position: Vec2::new(2.0, -2.0),
                velocity: Vec2::new(0.0, 1.0),
                radius: 0.5,
                residual: None,
            },
            Predicted {
                position: Vec2::new(-3.0, 3.0),
                velocity: Vec2::new(1.0, 0.0),
                radius: 0.5,
                residual: None,
            },
            Predicted {
                position: Vec2::new(9.0, 0.0),
                velocity: Vec2::new(0.0, 1.0),
                radius: 0.5,
                residual: None,
            },
        ];
        let p = measure_pressure(&ep, &moving, &cfg, 2.8, &mut costs);
        assert_eq!(p.moving, 2);
        assert!((p.blocked - 14.0 / 30.0).abs() < 1e-12, "{}", p.blocked);
        assert_eq!(p.entropy, 0.0);
        assert!(
            (p.phi - (0.38 * 2.0 / 5.0 + 0.37 * 14.0 / 30.0)).abs() < 1e-12,
            "{}",
            p.phi
        );
        // Too short a horizon to reach the path: nothing blocked.
        let p = measure_pressure(&ep, &moving, &cfg, 0.5, &mut costs);
        assert_eq!(p.blocked, 0.0);
    }

    /// A planner with DWA's gains that records the factors it is given.
    #[derive(Default)]
    struct Recorder {
        trace: crate::Trace,
        factors: Vec<Vec<f64>>,
    }

    impl Planner for Recorder {
        fn name(&self) -> &'static str {
            "dwa"
        }

        fn plan(&mut self, _: &crate::PlanInput<'_>) -> sim::Twist {
            sim::Twist::default()
        }

        fn trace(&self) -> &crate::Trace {
            &self.trace
        }

        fn trace_mut(&mut self) -> &mut crate::Trace {
            &mut self.trace
        }

        fn gains(&self) -> Option<Gains> {
            Some(Gains::Dwa)
        }

        fn set_gain_factors(&mut self, factors: &[f64]) -> Result<(), crate::GainsError> {
            self.factors.push(factors.to_vec());
            Ok(())
        }
    }

    #[test]
    fn the_mode_follows_the_scores_with_hysteresis_and_sets_gains_and_replanning() {
        let world = open_world();
        let mut ep = Episode::new(&world, EpisodeConfig::default(), 1);
        let parts = PadpParts {
            path: false,
            adapt: true,
        };
        let mut padp = Padp::new(PadpConfig::default(), parts);
        let mut planner = Recorder::default();
        // theta_L = 0.38, theta_H = 0.64, delta = 0.05: up past 0.43 and 0.69, down below
        // 0.59 and 0.33.
        let scores = [0.10, 0.42, 0.44, 0.66, 0.70, 0.60, 0.58, 0.35, 0.32];
        use PressureMode::{A, B, C};
        let modes = [A, A, B, B, C, C, B, B, A];
        let (ea, eb, ec) = ([1.25, 1.0, 0.8, 1.25], [1.0; 4], [0.8, 1.0, 1.5, 0.8]);
        // The factors applied after each score: only on a change (and the first score).
        let applied: [Option<[f64; 4]>; 9] = [
            Some(ea),
            None,
            Some(eb),
            None,
            Some(ec),
            None,
            Some(eb),
            None,
            Some(ea),
        ];
        let every = [12, 12, 5, 5, 2, 2, 5, 5, 12];
        for (k, &phi) in scores.iter().enumerate() {
            let before = planner.factors.len();
            assert_eq!(
                padp.apply_score(phi, &mut ep, &mut planner),
                modes[k],
                "score {k}: {phi}"
            );
            assert_eq!(padp.mode(), modes[k]);
            match applied[k] {
                Some(f) => assert_eq!(planner.factors[before..], [f.to_vec()], "score {k}"),
                None => assert_eq!(planner.factors.len(), before, "score {k}: no change"),
            }
            assert_eq!(ep.replan_every(), every[k], "score {k}");
        }
        // A jump skips B.
        padp.apply_score(0.9, &mut ep, &mut planner);
        assert_eq!((padp.mode(), ep.replan_every()), (C, 2));
    }

    #[test]
    fn without_the_adaptive_part_nothing_changes() {
        let world = open_world();
        let mut ep = Episode::new(&world, EpisodeConfig::default(), 1);
        let parts = PadpParts {
            path: true,
            adapt: false,
        };
        let mut padp = Padp::new(PadpConfig::default(), parts);
        let mut planner = Recorder::default();
        let tracking = Tracking::new(crate::TrackingConfig::default());
        padp.cycle(&mut ep, &tracking, &mut planner);
        assert!(planner.factors.is_empty());
        assert_eq!(ep.replan_every(), 5);
        assert_eq!(padp.pressure(), Pressure::default());
    }
}
