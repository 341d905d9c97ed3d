//! What a robot hands the runtime every control cycle, and the checks it passes first. Pure:
//! no state, no allocation.
//!
//! Units and frames: metres, radians, seconds, SI throughout. Poses, goals and paths are in
//! one fixed frame of the caller's (`map` or `odom`: the frame its localization reports);
//! yaw is counter-clockwise from that frame's x axis; velocities are in the robot's frame (v
//! forward, w counter-clockwise). The scan is in the robot's frame, its beams in the order of
//! increasing angle of the configured lidar (`[lidar]`: `beams` over `fov_deg`, centred on
//! the laser's heading; the laser at its mount, `[lidar] x, y, yaw_deg`). The scan's stamp
//! and the odometry's share one clock: odometry older than the scan by more than
//! `max_odometry_age_s`, or newer by more than `max_odometry_lead_s`, is refused.

use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;

use crate::config::RuntimeOptions;
use crate::envelope::{MAX_COORDINATE_M, MAX_PATH_POINTS, MAX_YAW_RAD};
use crate::error::RuntimeError;

/// The robot's localization and measured velocity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Odometry {
    /// The believed pose (fixed frame).
    pub pose: Pose,
    /// The measured velocity (robot frame).
    pub vel: Twist,
    /// When it was measured (s, the clock of [`CycleInput::stamp_s`]).
    pub stamp_s: f64,
}

/// One control cycle's inputs.
#[derive(Clone, Copy, Debug)]
pub struct CycleInput<'a> {
    /// When the scan was taken (s, any monotonic clock shared with the odometry).
    pub stamp_s: f64,
    /// One range per beam (m). Values past the lidar's range are read as its max range (no
    /// return), values under its min range as its min range. NaN and `±inf` read as no
    /// return (`nan_as_no_return`, the default); with it off, NaN is refused, `+inf` reads as
    /// no return and `-inf` as the min range.
    pub ranges: &'a [f64],
    /// The robot's pose and velocity: the pose inside the envelope
    /// ([`crate::envelope::MAX_COORDINATE_M`], [`crate::envelope::MAX_YAW_RAD`]), the
    /// velocity any finite value (the command is clamped to the limits whatever it is).
    pub odom: Odometry,
    /// The global goal (fixed frame), at most `max_goal_distance_m` from the robot. A new goal
    /// starts a new run.
    pub goal: Vec2,
    /// A global path to follow (fixed frame, from the robot towards the goal), replacing the
    /// runtime's own search on its costmap; `None` plans it. At most
    /// [`crate::envelope::MAX_PATH_POINTS`] points, each inside the envelope.
    pub global_path: Option<&'a [Vec2]>,
}

/// Checks `input` against a lidar of `beams` beams over `[min_range, max_range]` and the
/// envelope and limits of `options` ([`crate::envelope`]); writes the ranges, clamped, into
/// `ranges` (resized once).
pub(crate) fn check(
    input: &CycleInput<'_>,
    beams: usize,
    (min_range, max_range): (f64, f64),
    options: &RuntimeOptions,
    ranges: &mut Vec<f64>,
) -> Result<(), RuntimeError> {
    if input.ranges.len() != beams {
        return Err(RuntimeError::Scan(format!(
            "{} ranges, but the configured lidar has {beams} beams ([lidar] beams)",
            input.ranges.len()
        )));
    }
    if !options.nan_as_no_return {
        if let Some(k) = input.ranges.iter().position(|r| r.is_nan()) {
            return Err(RuntimeError::Scan(format!(
                "range {k} is NaN (nan_as_no_return = false)"
            )));
        }
    }
    if !input.stamp_s.is_finite() {
        return Err(RuntimeError::Scan(format!(
            "stamp {} is not finite",
            input.stamp_s
        )));
    }
    let o = &input.odom;
    let values = [
        ("pose.x", o.pose.x),
        ("pose.y", o.pose.y),
        ("pose.yaw", o.pose.yaw),
        ("vel.v", o.vel.v),
        ("vel.w", o.vel.w),
        ("stamp", o.stamp_s),
    ];
    if let Some((name, v)) = values.iter().find(|(_, v)| !v.is_finite()) {
        return Err(RuntimeError::Odometry(format!("{name} = {v} is not finite")));
    }
    if beyond(o.pose.position()) {
        return Err(RuntimeError::Odometry(outside("pose ", o.pose.position())));
    }
    if o.pose.yaw.abs() > MAX_YAW_RAD {
        return Err(RuntimeError::Odometry(format!(
            "pose.yaw = {:e} rad is outside the envelope: |yaw| at most {MAX_YAW_RAD:e} rad",
            o.pose.yaw
        )));
    }
    let age = input.stamp_s - o.stamp_s;
    if age > options.max_odometry_age_s {
        return Err(RuntimeError::Odometry(format!(
            "{age:.3} s older than the scan; at most {} s (max_odometry_age_s)",
            options.max_odometry_age_s
        )));
    }
    if -age > options.max_odometry_lead_s {
        return Err(RuntimeError::Odometry(format!(
            "stamped {:.3} s after the scan; at most {} s (max_odometry_lead_s): the scan's and \
             the odometry's clocks disagree",
            -age, options.max_odometry_lead_s
        )));
    }
    if !(input.goal.x.is_finite() && input.goal.y.is_finite()) {
        return Err(RuntimeError::Goal(format!(
            "({}, {}) is not finite",
            input.goal.x, input.goal.y
        )));
    }
    if beyond(input.goal) {
        return Err(RuntimeError::Goal(outside("", input.goal)));
    }
    let distance = input.goal.dist(o.pose.position());
    if distance > options.max_goal_distance_m {
        return Err(RuntimeError::Goal(format!(
            "({}, {}) is {distance:.1} m from the robot; at most {} m (max_goal_distance_m): \
             give a nearer goal, e.g. a waypoint of a global plan",
            input.goal.x, input.goal.y, options.max_goal_distance_m
        )));
    }
    if let Some(path) = input.global_path {
        if path.is_empty() {
            return Err(RuntimeError::Path("empty (pass None to plan it)".into()));
        }
        if path.len() > MAX_PATH_POINTS {
            return Err(RuntimeError::Path(format!(
                "{} points; at most {MAX_PATH_POINTS} (the envelope)",
                path.len()
            )));
        }
        if let Some(k) = path.iter().position(|p| !(p.x.is_finite() && p.y.is_finite())) {
            return Err(RuntimeError::Path(format!("point {k} is not finite")));
        }
        if let Some(k) = path.iter().position(|p| beyond(*p)) {
            return Err(RuntimeError::Path(outside(&format!("point {k} "), path[k])));
        }
    }
    ranges.clear();
    if options.nan_as_no_return {
        ranges.extend(input.ranges.iter().map(|&r| {
            if r.is_finite() {
                r.clamp(min_range, max_range)
            } else {
                max_range
            }
        }));
    } else {
        ranges.extend(input.ranges.iter().map(|&r| r.clamp(min_range, max_range)));
    }
    Ok(())
}

/// Whether the point `p` is outside the envelope's coordinates.
fn beyond(p: Vec2) -> bool {
    p.x.abs() > MAX_COORDINATE_M || p.y.abs() > MAX_COORDINATE_M
}

/// The message for the point `p` outside the envelope's coordinates, its name `what` (with
/// a trailing space, or empty) first.
fn outside(what: &str, p: Vec2) -> String {
    format!(
        "{what}({:e}, {:e}) is outside the envelope: |x| and |y| at most {MAX_COORDINATE_M:e} m",
        p.x, p.y
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(ranges: &[f64]) -> CycleInput<'_> {
        CycleInput {
            stamp_s: 10.0,
            ranges,
            odom: Odometry {
                pose: Pose::new(1.0, 2.0, 0.5),
                vel: Twist::new(0.3, 0.1),
                stamp_s: 9.98,
            },
            goal: Vec2::new(5.0, 5.0),
            global_path: None,
        }
    }

    fn options(nan_as_no_return: bool) -> RuntimeOptions {
        RuntimeOptions {
            nan_as_no_return,
            ..RuntimeOptions::new(planner::PlannerKind::Dwa, 1.5)
        }
    }

    fn checked_with(input: &CycleInput<'_>, options: &RuntimeOptions) -> Result<Vec<f64>, String> {
        let mut out = Vec::new();
        check(input, 3, (0.1, 30.0), options, &mut out)
            .map(|()| out)
            .map_err(|e| e.to_string())
    }

    fn checked(input: &CycleInput<'_>) -> Result<Vec<f64>, String> {
        checked_with(input, &options(true))
    }

    #[test]
    fn good_input_is_clamped_into_the_lidars_range() {
        let ranges = [f64::INFINITY, 0.01, 2.5];
        assert_eq!(checked(&input(&ranges)).unwrap(), [30.0, 0.1, 2.5]);
    }

    #[test]
    fn nan_and_infinite_ranges_read_as_no_return_unless_turned_off() {
        let ranges = [f64::NAN, f64::NEG_INFINITY, f64::INFINITY];
        assert_eq!(checked(&input(&ranges)).unwrap(), [30.0, 30.0, 30.0]);
        // Off: today's reading, NaN refused, -inf the min range.
        assert_eq!(
            checked_with(&input(&ranges), &options(false)).unwrap_err(),
            "scan: range 0 is NaN (nan_as_no_return = false)"
        );
        let ranges = [1.0, f64::NEG_INFINITY, f64::INFINITY];
        assert_eq!(
            checked_with(&input(&ranges), &options(false)).unwrap(),
            [1.0, 0.1, 30.0]
        );
    }

    #[test]
    fn input_outside_the_envelope_is_refused_naming_the_limit() {
        let ranges = [1.0, 1.0, 1.0];
        let with_odom = |pose: Pose| CycleInput {
            odom: Odometry {
                pose,
                ..input(&ranges).odom
            },
            ..input(&ranges)
        };
        let with_goal = |goal: Vec2| CycleInput {
            goal,
            ..input(&ranges)
        };
        let far_path = [Vec2::new(1.0, 2.0), Vec2::new(2e7, 0.0)];
        let long_path = vec![Vec2::new(1.0, 2.0); MAX_PATH_POINTS + 1];
        let cases: Vec<(CycleInput<'_>, &str)> = vec![
            (
                with_goal(Vec2::new(14_001.0, 2.0)),
                "goal: (14001, 2) is 14000.0 m from the robot; at most 50 m (max_goal_distance_m): \
                 give a nearer goal, e.g. a waypoint of a global plan",
            ),
            (
                with_goal(Vec2::new(1e300, -1e300)),
                "goal: (1e300, -1e300) is outside the envelope: |x| and |y| at most 1e7 m",
            ),
            (
                with_odom(Pose::new(1e6, 2.0, 0.0)),
                "goal: (5, 5) is 999995.0 m from the robot; at most 50 m (max_goal_distance_m): \
                 give a nearer goal, e.g. a waypoint of a global plan",
            ),
            (
                with_odom(Pose::new(3e7, 2.0, 0.0)),
                "odometry: pose (3e7, 2e0) is outside the envelope: |x| and |y| at most 1e7 m",
            ),
            (
                with_odom(Pose::new(1.0, 2.0, -2e6)),
                "odometry: pose.yaw = -2e6 rad is outside the envelope: |yaw| at most 1e6 rad",
            ),
            (
                CycleInput {
                    global_path: Some(&far_path),
                    ..input(&ranges)
                },
                "global path: point 1 (2e7, 0e0) is outside the envelope: |x| and |y| at most 1e7 m",
            ),
            (
                CycleInput {
                    global_path: Some(&long_path),
                    ..input(&ranges)
                },
                "global path: 100001 points; at most 100000 (the envelope)",
            ),
        ];
        for (case, want) in cases {
            assert_eq!(checked(&case).unwrap_err(), want);
        }
        // The edge itself is inside.
        let edge = Vec2::new(31.0, 42.0);
        assert!(checked(&with_goal(edge)).is_ok());
        // A measured velocity of any finite size is accepted (the command is clamped).
        let fast = CycleInput {
            odom: Odometry {
                vel: Twist::new(1e6, -50.0),
                ..input(&ranges).odom
            },
            ..input(&ranges)
        };
        assert!(checked(&fast).is_ok());
    }

    #[test]
    fn each_fault_is_named() {
        let ranges = [1.0, 1.0, 1.0];
        let cases: Vec<(CycleInput<'_>, &str)> = vec![
            (
                input(&[1.0, 1.0]),
                "scan: 2 ranges, but the configured lidar has 3 beams ([lidar] beams)",
            ),
            (
                CycleInput {
                    odom: Odometry {
                        vel: Twist::new(f64::NAN, 0.0),
                        ..input(&ranges).odom
                    },
                    ..input(&ranges)
                },
                "odometry: vel.v = NaN is not finite",
            ),
            (
                CycleInput {
                    stamp_s: 10.5,
                    ..input(&ranges)
                },
                "odometry: 0.520 s older than the scan; at most 0.1 s (max_odometry_age_s)",
            ),
            (
                CycleInput {
                    stamp_s: 9.0,
                    ..input(&ranges)
                },
                "odometry: stamped 0.980 s after the scan; at most 0.1 s (max_odometry_lead_s): \
                 the scan's and the odometry's clocks disagree",
            ),
            (
                CycleInput {
                    goal: Vec2::new(f64::NAN, 1.0),
                    ..input(&ranges)
                },
                "goal: (NaN, 1) is not finite",
            ),
            (
                CycleInput {
                    global_path: Some(&[]),
                    ..input(&ranges)
                },
                "global path: empty (pass None to plan it)",
            ),
        ];
        for (case, want) in cases {
            assert_eq!(checked(&case).unwrap_err(), want);
        }
    }
}
