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
//! max_odometry_lead_s = 0.1    # odometry stamped after the scan by more is refused
//! max_goal_distance_m = 50.0   # a goal farther from the robot is refused (the envelope)
//! goal_tolerance_m = 0.3       # within this of the goal the run has arrived: stop
//! nan_as_no_return = true      # NaN and +-inf ranges read as no return; false refuses NaN
//! allow_policy_mismatch = false # true runs a policy under another planner or speed than
//!                              # its card records (a transfer experiment)
//! settings = "eval.toml"       # optional: [episode] (lidar, costmap, robot), planner tables,
//!                              # [compute]; the embedded configs/eval.toml when absent
//!
//! [lidar]                      # optional: the robot's laser (absent keys: [episode.lidar]'s)
//! beams = 1081                 # beams, evenly from -fov/2 to +fov/2 inclusive
//! fov_deg = 270.0              # degrees, centred on the laser's heading
//! min_range = 0.06             # m
//! max_range = 30.0             # m
//! x = 0.12                     # its mount in the base frame: m forward, m left,
//! y = 0.0
//! yaw_deg = 0.0                # degrees counter-clockwise (default 0, 0, 0: the base origin)
//! ```

use std::path::{Path, PathBuf};

use eval_config::EvalConfig;
use planner::PlannerKind;
use policy::LearnedPolicy;
use serde::Deserialize;
use sim::geometry::Pose;

use crate::envelope::{DEFAULT_MAX_GOAL_DISTANCE_M, MAX_LASER_OFFSET_M, MAX_SPEED_MPS};
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
    /// Odometry stamped after the scan by more than this (s) is refused: the two clocks
    /// disagree (odometry newer than the scan by a little is usual: it arrives more often).
    pub max_odometry_lead_s: f64,
    /// The laser's pose in the base frame (m, m, rad); the origin for a laser at the base
    /// origin facing the heading. Off the origin, each scan is re-projected to the base
    /// origin: each return moved into the base frame and kept in the base-centred beam
    /// nearest its bearing, the nearest winning.
    pub laser_pose: Pose,
    /// A goal farther than this from the robot (m) is refused: it bounds the costmap
    /// ([`crate::envelope`]).
    pub max_goal_distance_m: f64,
    /// Within this distance of the goal (m) the run has arrived: every cycle then commands
    /// a stop and says so ([`crate::CycleOutput::arrived`]) until a new goal is given.
    pub goal_tolerance_m: f64,
    /// Whether a NaN or infinite range reads as no return (the lidar's max range), as lidar
    /// drivers publish beams without one. `false` refuses a scan with a NaN range, reads
    /// `+inf` as no return and `-inf` as the lidar's min range.
    pub nan_as_no_return: bool,
    /// Whether a policy runs under a planner or speed cap other than those its card records
    /// (`trained_for`), or with a card that records none. `false` (the default) refuses
    /// them, naming both sides: a policy chose schedules for one planner at one speed, and
    /// is untested under others. `true` is for transfer experiments.
    pub allow_policy_mismatch: bool,
}

impl RuntimeOptions {
    /// `planner` at `max_speed` on DDP, seed 0, odometry at most 0.1 s old, goals at most
    /// 50 m away and reached within 0.3 m, NaN and infinite ranges read as no return, a policy trained for another
    /// planner or speed refused, the laser at the base origin.
    pub fn new(planner: PlannerKind, max_speed: f64) -> Self {
        Self {
            planner,
            max_speed,
            fixed: FixedSchedule::Ddp,
            seed: 0,
            max_odometry_age_s: DEFAULT_MAX_ODOMETRY_AGE_S,
            max_odometry_lead_s: DEFAULT_MAX_ODOMETRY_AGE_S,
            laser_pose: Pose::new(0.0, 0.0, 0.0),
            max_goal_distance_m: DEFAULT_MAX_GOAL_DISTANCE_M,
            goal_tolerance_m: DEFAULT_GOAL_TOLERANCE_M,
            nan_as_no_return: true,
            allow_policy_mismatch: false,
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
        if !(self.goal_tolerance_m.is_finite() && self.goal_tolerance_m >= 0.0) {
            return Err(format!(
                "goal_tolerance_m = {} must be finite and >= 0",
                self.goal_tolerance_m
            ));
        }
        if self.max_odometry_age_s.is_nan() || self.max_odometry_age_s < 0.0 {
            return Err(format!(
                "max_odometry_age_s = {} must be >= 0",
                self.max_odometry_age_s
            ));
        }
        if self.max_odometry_lead_s.is_nan() || self.max_odometry_lead_s < 0.0 {
            return Err(format!(
                "max_odometry_lead_s = {} must be >= 0",
                self.max_odometry_lead_s
            ));
        }
        let l = self.laser_pose;
        if !(l.x.abs() <= MAX_LASER_OFFSET_M && l.y.abs() <= MAX_LASER_OFFSET_M) {
            return Err(format!(
                "[lidar] x = {}, y = {}: the laser's mount must be within {MAX_LASER_OFFSET_M} m \
                 of the base origin",
                l.x, l.y
            ));
        }
        if l.yaw.is_nan() || l.yaw.abs() > std::f64::consts::TAU {
            return Err(format!(
                "[lidar] yaw_deg = {}: must be within +-360",
                l.yaw.to_degrees()
            ));
        }
        Ok(())
    }
}

/// Two control periods at the default 0.05 s.
const DEFAULT_MAX_ODOMETRY_AGE_S: f64 = 0.1;

/// About the Jackal's half-length, and ROS 2 Nav2's default `xy_goal_tolerance` (0.25 m)
/// rounded up. Under BARN's 1 m success radius, so a simulated run ends before it applies.
const DEFAULT_GOAL_TOLERANCE_M: f64 = 0.3;

fn default_goal_tolerance_m() -> f64 {
    DEFAULT_GOAL_TOLERANCE_M
}

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
    #[serde(default = "default_max_odometry_age_s")]
    max_odometry_lead_s: f64,
    #[serde(default = "default_max_goal_distance_m")]
    max_goal_distance_m: f64,
    #[serde(default = "default_goal_tolerance_m")]
    goal_tolerance_m: f64,
    #[serde(default = "default_true")]
    nan_as_no_return: bool,
    #[serde(default)]
    allow_policy_mismatch: bool,
    settings: Option<PathBuf>,
    #[serde(default)]
    lidar: LidarTable,
}

/// The `[lidar]` table: the robot's laser.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct LidarTable {
    beams: Option<usize>,
    fov_deg: Option<f64>,
    min_range: Option<f64>,
    max_range: Option<f64>,
    #[serde(default)]
    x: f64,
    #[serde(default)]
    y: f64,
    #[serde(default)]
    yaw_deg: f64,
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
        toml::from_str(&text).map_err(|e| config(eval_config::one_line(&e.to_string())))?;
    let options = RuntimeOptions {
        planner: file.planner,
        max_speed: file.max_speed,
        fixed: file.fixed,
        seed: file.seed,
        max_odometry_age_s: file.max_odometry_age_s,
        max_odometry_lead_s: file.max_odometry_lead_s,
        laser_pose: Pose::new(file.lidar.x, file.lidar.y, file.lidar.yaw_deg.to_radians()),
        max_goal_distance_m: file.max_goal_distance_m,
        goal_tolerance_m: file.goal_tolerance_m,
        nan_as_no_return: file.nan_as_no_return,
        allow_policy_mismatch: file.allow_policy_mismatch,
    };
    options.validate().map_err(config)?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let settings_path = file.settings.map(|s| dir.join(s));
    let mut settings = EvalConfig::load(settings_path.as_deref()).map_err(|e| RuntimeError::Config {
        origin: origin.clone(),
        message: format!("settings: {e}"),
    })?;
    let (table, lidar) = (&file.lidar, &mut settings.episode.lidar);
    lidar.beams = table.beams.unwrap_or(lidar.beams);
    lidar.fov_deg = table.fov_deg.unwrap_or(lidar.fov_deg);
    lidar.min_range = table.min_range.unwrap_or(lidar.min_range);
    lidar.max_range = table.max_range.unwrap_or(lidar.max_range);
    let policy = file.policy.map(|p| load_policy(&dir.join(p))).transpose()?;
    Ok((settings, options, policy))
}

/// Loads the trained policy of the export directory (or `policy.json`) at `path`, checked as
/// `adp eval --policy` checks it.
pub fn load_policy(path: &Path) -> Result<LearnedPolicy, RuntimeError> {
    let refused = |e: policy::LoadError| RuntimeError::Policy(e.to_string());
    match policy::card_path(path).map_err(refused)? {
        Some(card) => policy::load(&card, None).map_err(refused),
        None => Err(RuntimeError::Policy(format!(
            "policy {}: not an export directory or its policy.json; give an export directory \
             of `adp export`",
            path.display()
        ))),
    }
}
