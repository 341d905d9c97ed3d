//! The envelope: the inputs and settings the runtime accepts, and the limits every command it
//! returns is kept inside.
//!
//! Outside the envelope a call is refused with an error naming the value and the limit, so no
//! input can make a cycle's memory or time unbounded, or abort the process:
//!
//! * **The goal** is at most `max_goal_distance_m` (runtime configuration, default
//!   [`DEFAULT_MAX_GOAL_DISTANCE_M`]) from the robot. The runtime's costmap is not a rolling
//!   window: it covers the box spanned by the robot's pose at the run's start and the goal,
//!   plus `[episode.costmap] margin`, as in the simulator. Bounding the goal's distance bounds
//!   the costmap and the global search on it. A goal farther away is refused with the advice
//!   to give a nearer one (a waypoint of a global plan), and the configuration is refused when
//!   the largest costmap this distance allows would exceed [`MAX_COSTMAP_CELLS`].
//! * **Coordinates** of poses, goals and path points are at most [`MAX_COORDINATE_M`] from
//!   the frame's origin, yaw at most [`MAX_YAW_RAD`]; a global path has at most
//!   [`MAX_PATH_POINTS`] points.
//! * **Speeds**: `max_speed` is at most the robot's `[episode.robot] max_v`, which is at most
//!   [`MAX_SPEED_MPS`]; the planners' local maps scale with it. A measured velocity of any
//!   finite size is accepted: the command is clamped (below).
//! * **The lidar** has at most [`MAX_BEAMS`] beams, mounted at most [`MAX_LASER_OFFSET_M`]
//!   from the base origin in x and y, its yaw at most 2 pi.
//!
//! The planner tables of the settings file (sample counts, map resolutions) are trusted as
//! `adp eval` trusts them.
//!
//! **Commands** are clamped to [`CommandLimits`]: forward speed up to `max_speed`, reverse
//! speed up to `[episode.robot] max_reverse_v` (and never faster than `max_speed`), yaw rate
//! up to `[episode.robot] max_w`, whatever the planner or the measured state. With the
//! planner tables of `configs/eval.toml`, a planner given a measured state inside these
//! limits already commands inside them, so the clamp changes nothing there (the closed-loop
//! test's episodes are bit for bit `adp eval`'s); it acts when the measured velocity is
//! outside them (a wheel slipping, an odometry fault).

use sim::costmap::CostmapConfig;
use sim::robot::{RobotLimits, Twist};

/// Largest |x| or |y| of a pose, goal or path point (m): 10,000 km, enough for UTM
/// coordinates, where an `f64` still resolves nanometres.
pub const MAX_COORDINATE_M: f64 = 1.0e7;

/// Largest |yaw| of a pose (rad): an unwrapped odometry yaw after 150,000 turns.
pub const MAX_YAW_RAD: f64 = 1.0e6;

/// Most points of a given global path.
pub const MAX_PATH_POINTS: usize = 100_000;

/// Largest `max_speed` and `[episode.robot] max_v` (m/s).
pub const MAX_SPEED_MPS: f64 = 5.0;

/// Largest `[episode.robot] max_w` (rad/s).
pub const MAX_TURN_RATE_RADPS: f64 = 10.0;

/// Most lidar beams.
pub const MAX_BEAMS: usize = 20_000;

/// Most steps of a schedule given from outside ([`crate::Navigator::set_schedule`]): three
/// times the ADP action spaces' largest (22), so a rollout's work stays bounded.
pub const MAX_SCHEDULE_STEPS: usize = 64;

/// Longest horizon of a schedule given from outside (s): over twice the ADP action spaces'
/// longest (2.2 s).
pub const MAX_SCHEDULE_HORIZON_S: f64 = 5.0;

/// Largest |x| or |y| of the laser's mount on the base (m).
pub const MAX_LASER_OFFSET_M: f64 = 5.0;

/// Most cells of the robot's costmap (about 60 MB with the global search's buffers).
pub const MAX_COSTMAP_CELLS: f64 = 4_194_304.0;

/// The default largest distance from the robot to the goal (m): five BARN runs end to end.
/// The default costmap (0.1 m cells, 4 m margin) then has at most 189,225 cells.
pub const DEFAULT_MAX_GOAL_DISTANCE_M: f64 = 50.0;

/// The most cells the costmap of a run can have when the goal is at most `goal_distance` m
/// from the robot's start: the box of the two points plus the margin is largest when the
/// goal lies on a diagonal.
pub fn costmap_cells(cfg: &CostmapConfig, goal_distance: f64) -> f64 {
    let side = goal_distance / std::f64::consts::SQRT_2 + 2.0 * cfg.margin;
    let cells = (side / cfg.resolution).ceil() + 1.0;
    cells * cells
}

/// The limits every command is clamped to (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandLimits {
    /// Largest forward speed (m/s): `max_speed`.
    pub max_v: f64,
    /// Largest reverse speed, positive (m/s): `[episode.robot] max_reverse_v`, at most
    /// `max_speed`.
    pub max_reverse_v: f64,
    /// Largest yaw-rate magnitude (rad/s): `[episode.robot] max_w`.
    pub max_w: f64,
}

impl CommandLimits {
    /// The limits of a robot of `robot` limits driven at most at `max_speed`.
    pub fn new(robot: &RobotLimits, max_speed: f64) -> Self {
        Self {
            max_v: max_speed,
            max_reverse_v: robot.max_reverse_v.min(max_speed),
            max_w: robot.max_w,
        }
    }

    /// `cmd` clamped into the limits (a command inside them is returned unchanged, bit for
    /// bit; a NaN component, which no planner should give, becomes 0).
    pub fn clamp(&self, cmd: Twist) -> Twist {
        let nan_to_stop = |x: f64| if x.is_nan() { 0.0 } else { x };
        Twist::new(
            nan_to_stop(cmd.v).clamp(-self.max_reverse_v, self.max_v),
            nan_to_stop(cmd.w).clamp(-self.max_w, self.max_w),
        )
    }

    /// Whether `cmd` is inside the limits.
    pub fn contains(&self, cmd: Twist) -> bool {
        (-self.max_reverse_v..=self.max_v).contains(&cmd.v) && (-self.max_w..=self.max_w).contains(&cmd.w)
    }
}

/// Checks the settings against the envelope for a runtime driven at most at `max_speed` with
/// goals at most `max_goal_distance_m` away; the message names the key and the limit.
pub(crate) fn check_settings(
    robot: &RobotLimits,
    costmap: &CostmapConfig,
    beams: usize,
    max_speed: f64,
    max_goal_distance_m: f64,
) -> Result<(), String> {
    if !(robot.max_v > 0.0 && robot.max_v <= MAX_SPEED_MPS) {
        return Err(format!(
            "[episode.robot] max_v = {} must be in (0, {MAX_SPEED_MPS}] m/s",
            robot.max_v
        ));
    }
    if !(robot.max_reverse_v >= 0.0 && robot.max_reverse_v <= MAX_SPEED_MPS) {
        return Err(format!(
            "[episode.robot] max_reverse_v = {} must be in [0, {MAX_SPEED_MPS}] m/s",
            robot.max_reverse_v
        ));
    }
    if !(robot.max_w > 0.0 && robot.max_w <= MAX_TURN_RATE_RADPS) {
        return Err(format!(
            "[episode.robot] max_w = {} must be in (0, {MAX_TURN_RATE_RADPS}] rad/s",
            robot.max_w
        ));
    }
    if max_speed > robot.max_v {
        return Err(format!(
            "max_speed = {max_speed} m/s exceeds the robot's [episode.robot] max_v = {} m/s",
            robot.max_v
        ));
    }
    if beams > MAX_BEAMS {
        return Err(format!(
            "[lidar] beams = {beams} exceeds the runtime's limit of {MAX_BEAMS}"
        ));
    }
    let cells = costmap_cells(costmap, max_goal_distance_m);
    if cells > MAX_COSTMAP_CELLS {
        return Err(format!(
            "max_goal_distance_m = {max_goal_distance_m} m with [episode.costmap] resolution = {} m \
             and margin = {} m allows a costmap of {cells:.0} cells, over the runtime's limit of \
             {MAX_COSTMAP_CELLS:.0}",
            costmap.resolution, costmap.margin
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_costmap_is_small_and_its_cells_are_counted_exactly() {
        let cfg = CostmapConfig::default();
        // 50 m on the diagonal: 35.36 + 8 m = 434 cells of 0.1 m, plus one.
        assert_eq!(costmap_cells(&cfg, DEFAULT_MAX_GOAL_DISTANCE_M), 435.0 * 435.0);
        let built = sim::costmap::Costmap::around(
            cfg,
            sim::geometry::Vec2::new(0.0, 0.0),
            sim::geometry::Vec2::new(50.0 / 2f64.sqrt(), 50.0 / 2f64.sqrt()),
        );
        assert!((built.nx() * built.ny()) as f64 <= costmap_cells(&cfg, 50.0));
    }

    #[test]
    fn commands_are_clamped_and_commands_inside_are_untouched() {
        let limits = CommandLimits::new(&RobotLimits::JACKAL, 1.5);
        assert_eq!(
            limits,
            CommandLimits {
                max_v: 1.5,
                max_reverse_v: 1.5,
                max_w: 4.0
            }
        );
        assert_eq!(limits.clamp(Twist::new(999_999.0, 48.75)), Twist::new(1.5, 4.0));
        assert_eq!(limits.clamp(Twist::new(-9.0, -50.0)), Twist::new(-1.5, -4.0));
        assert_eq!(limits.clamp(Twist::new(f64::NAN, f64::NAN)), Twist::new(0.0, 0.0));
        let inside = Twist::new(1.234_567_890_123, -3.999_999_999);
        assert_eq!(limits.clamp(inside), inside);
        assert!(limits.contains(inside) && !limits.contains(Twist::new(1.5000001, 0.0)));
    }

    #[test]
    fn settings_outside_the_envelope_are_named() {
        let robot = RobotLimits::JACKAL;
        let costmap = CostmapConfig::default();
        assert_eq!(check_settings(&robot, &costmap, 720, 2.0, 50.0), Ok(()));
        assert_eq!(
            check_settings(&robot, &costmap, 720, 1e9, 50.0).unwrap_err(),
            "max_speed = 1000000000 m/s exceeds the robot's [episode.robot] max_v = 2 m/s"
        );
        let fast = RobotLimits { max_v: 1e9, ..robot };
        assert_eq!(
            check_settings(&fast, &costmap, 720, 1.5, 50.0).unwrap_err(),
            "[episode.robot] max_v = 1000000000 must be in (0, 5] m/s"
        );
        assert!(check_settings(&robot, &costmap, 20_001, 1.5, 50.0)
            .unwrap_err()
            .contains("beams = 20001"));
        let fine = CostmapConfig {
            resolution: 0.001,
            ..costmap
        };
        assert!(check_settings(&robot, &fine, 720, 1.5, 50.0)
            .unwrap_err()
            .contains("resolution = 0.001 m"));
        assert!(check_settings(&robot, &costmap, 720, 1.5, 1e4)
            .unwrap_err()
            .starts_with("max_goal_distance_m = 10000 m"));
    }
}
