//! The runtime's own settings ([`RuntimeOptions`]) and its configuration file, which adds
//! where the policy and the evaluation settings are:
//!
//! ```toml
//! planner = "dwa"              # dwa | mppi | log-mppi | system
//! max_speed = 1.5              # m/s
//! policy = "policy"            # optional: an `adp export` directory, relative to this file
//! fixed = "ddp"                # the schedule without a policy: ddp (default) | vanilla
//! seed = 0                     # the planner's sampling stream (MPPI, Log-MPPI)
//! max_odometry_age_s = 0.1     # odometry older than the scan by more is refused
//! max_goal_distance_m = 50.0   # a goal farther from the robot is refused (the envelope)
//! nan_as_no_return = true      # NaN and +-inf ranges read as no return; false refuses NaN
//! settings = "eval.toml"       # optional: [episode] (lidar, costmap, robot), planner tables,
//!                              # [compute]; the embedded configs/eval.toml when absent
//! ```

use std::path::{Path, PathBuf};

use eval::policy::{self, EvalPolicy, LearnedPolicy};
use eval::EvalConfig;
use planner::PlannerKind;
use serde::Deserialize;

use crate::envelope::{DEFAULT_MAX_GOAL_DISTANCE_M, MAX_SPEED_MPS};
use crate::error::RuntimeError;

/// The schedule the planner runs without a policy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FixedSchedule {
    /// Decremental: p = 1.7, T = 2 s, N = 20 (the DDP paper's).
    #[default]
    Ddp,
    /// Uniform 0.05 s x 20 steps.
    Vanilla,
}

/// What the runtime itself needs to know.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RuntimeOptions {
    /// The local planner.
    pub planner: PlannerKind,
    /// The speed cap (m/s): at most the robot's `[episode.robot] max_v`
    /// ([`crate::envelope`]); every command's forward speed is clamped to it.
    pub max_speed: f64,
    /// The schedule without a policy.
    pub fixed: FixedSchedule,
    /// The planner's sampling seed.
    pub seed: u64,
    /// Odometry older than the scan by more than this (s) is refused.
    pub max_odometry_age_s: f64,
    /// A goal farther than this from the robot (m) is refused: it bounds the costmap
    /// ([`crate::envelope`]).
    pub max_goal_distance_m: f64,
    /// Whether a NaN or infinite range reads as no return (the lidar's max range), as lidar
    /// drivers publish beams without one. `false` refuses a scan with a NaN range, reads
    /// `+inf` as no return and `-inf` as the lidar's min range.
    pub nan_as_no_return: bool,
}

impl RuntimeOptions {
    /// `planner` at `max_speed` on DDP, seed 0, odometry at most 0.1 s old, goals at most
    /// 50 m away, NaN and infinite ranges read as no return.
    pub fn new(planner: PlannerKind, max_speed: f64) -> Self {
        Self {
            planner,
            max_speed,
            fixed: FixedSchedule::Ddp,
            seed: 0,
            max_odometry_age_s: DEFAULT_MAX_ODOMETRY_AGE_S,
            max_goal_distance_m: DEFAULT_MAX_GOAL_DISTANCE_M,
            nan_as_no_return: true,
        }
    }

    /// Checks the values; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.max_speed.is_finite() && self.max_speed > 0.0) {
            return Err(format!("max_speed = {} must be finite and > 0", self.max_speed));
        }
        if self.max_speed > MAX_SPEED_MPS {
            return Err(format!(
                "max_speed = {} m/s exceeds the runtime's limit of {MAX_SPEED_MPS} m/s",
                self.max_speed
            ));
        }
        if !(self.max_goal_distance_m.is_finite() && self.max_goal_distance_m > 0.0) {
            return Err(format!(
                "max_goal_distance_m = {} must be finite and > 0",
                self.max_goal_distance_m
            ));
        }
        if self.max_odometry_age_s.is_nan() || self.max_odometry_age_s < 0.0 {
            return Err(format!(
                "max_odometry_age_s = {} must be >= 0",
                self.max_odometry_age_s
            ));
        }
        Ok(())
    }
}

/// Two control periods at the default 0.05 s.
const DEFAULT_MAX_ODOMETRY_AGE_S: f64 = 0.1;

fn default_max_odometry_age_s() -> f64 {
    DEFAULT_MAX_ODOMETRY_AGE_S
}

fn default_max_goal_distance_m() -> f64 {
    DEFAULT_MAX_GOAL_DISTANCE_M
}

fn default_true() -> bool {
    true
}

/// The configuration file (see the module docs).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RuntimeFile {
    planner: PlannerKind,
    max_speed: f64,
    policy: Option<PathBuf>,
    #[serde(default)]
    fixed: FixedSchedule,
    #[serde(default)]
    seed: u64,
    #[serde(default = "default_max_odometry_age_s")]
    max_odometry_age_s: f64,
    #[serde(default = "default_max_goal_distance_m")]
    max_goal_distance_m: f64,
    #[serde(default = "default_true")]
    nan_as_no_return: bool,
    settings: Option<PathBuf>,
}

/// What a configuration file (see the module docs) sets: the evaluation settings, the
/// runtime's options and the policy, loaded and checked. Paths in it are relative to its
/// directory; every error names the file and the key, or the policy file at fault.
pub fn read(path: &Path) -> Result<(EvalConfig, RuntimeOptions, Option<LearnedPolicy>), RuntimeError> {
    let origin = path.display().to_string();
    let config = |message: String| RuntimeError::Config {
        origin: origin.clone(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| config(format!("cannot read: {e}")))?;
    let file: RuntimeFile =
        toml::from_str(&text).map_err(|e| config(eval::config::one_line(&e.to_string())))?;
    let options = RuntimeOptions {
        planner: file.planner,
        max_speed: file.max_speed,
        fixed: file.fixed,
        seed: file.seed,
        max_odometry_age_s: file.max_odometry_age_s,
        max_goal_distance_m: file.max_goal_distance_m,
        nan_as_no_return: file.nan_as_no_return,
    };
    options.validate().map_err(config)?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let settings_path = file.settings.map(|s| dir.join(s));
    let settings = EvalConfig::load(settings_path.as_deref()).map_err(|e| RuntimeError::Config {
        origin: origin.clone(),
        message: format!("settings: {e}"),
    })?;
    let policy = file.policy.map(|p| load_policy(&dir.join(p))).transpose()?;
    Ok((settings, options, policy))
}

/// Loads the trained policy of the export directory (or `policy.json`) at `path`, checked as
/// `adp eval --policy` checks it.
pub fn load_policy(path: &Path) -> Result<LearnedPolicy, RuntimeError> {
    match policy::load(path, None).map_err(|e| RuntimeError::Policy(e.to_string()))? {
        EvalPolicy::Learned(p) => Ok(*p),
        EvalPolicy::Constant { .. } => Err(RuntimeError::Policy(format!(
            "policy {}: a constant-action file; give an export directory of `adp export`",
            path.display()
        ))),
    }
}
