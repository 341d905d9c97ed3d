//! What a robot hands the runtime every control cycle, and the checks it passes first. Pure:
//! no state, no allocation.
//!
//! Units and frames: metres, radians, seconds, SI throughout. Poses, goals and paths are in
//! one fixed frame of the caller's (`map` or `odom`: the frame its localization reports);
//! yaw is counter-clockwise from that frame's x axis; velocities are in the robot's frame (v
//! forward, w counter-clockwise). The scan is in the robot's frame, its beams in the order of
//! increasing angle of the configured lidar (`[episode.lidar]`: `beams` over `fov_deg`,
//! centred on the heading).

use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;

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
    /// One range per beam (m). `+inf` (no return) and values past the lidar's range are read
    /// as its max range, values under its min range as its min range; NaN is refused.
    pub ranges: &'a [f64],
    /// The robot's pose and velocity.
    pub odom: Odometry,
    /// The global goal (fixed frame). A new goal starts a new run.
    pub goal: Vec2,
    /// A global path to follow (fixed frame, from the robot towards the goal), replacing the
    /// runtime's own search on its costmap; `None` plans it.
    pub global_path: Option<&'a [Vec2]>,
}

/// Checks `input` against a lidar of `beams` beams over `[min_range, max_range]` and an
/// odometry age limit; writes the ranges, clamped, into `ranges` (resized once).
pub(crate) fn check(
    input: &CycleInput<'_>,
    beams: usize,
    (min_range, max_range): (f64, f64),
    max_odometry_age_s: f64,
    ranges: &mut Vec<f64>,
) -> Result<(), RuntimeError> {
    if input.ranges.len() != beams {
        return Err(RuntimeError::Scan(format!(
            "{} ranges, but the configured lidar has {beams} beams ([episode.lidar] beams)",
            input.ranges.len()
        )));
    }
    if let Some(k) = input.ranges.iter().position(|r| r.is_nan()) {
        return Err(RuntimeError::Scan(format!("range {k} is NaN")));
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
    let age = input.stamp_s - o.stamp_s;
    if age > max_odometry_age_s {
        return Err(RuntimeError::Odometry(format!(
            "{age:.3} s older than the scan; at most {max_odometry_age_s} s (max_odometry_age_s)"
        )));
    }
    if !(input.goal.x.is_finite() && input.goal.y.is_finite()) {
        return Err(RuntimeError::Goal(format!(
            "({}, {}) is not finite",
            input.goal.x, input.goal.y
        )));
    }
    if let Some(path) = input.global_path {
        if path.is_empty() {
            return Err(RuntimeError::Path("empty (pass None to plan it)".into()));
        }
        if let Some(k) = path.iter().position(|p| !(p.x.is_finite() && p.y.is_finite())) {
            return Err(RuntimeError::Path(format!("point {k} is not finite")));
        }
    }
    ranges.clear();
    ranges.extend(input.ranges.iter().map(|&r| r.clamp(min_range, max_range)));
    Ok(())
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

    fn checked(input: &CycleInput<'_>) -> Result<Vec<f64>, String> {
        let mut out = Vec::new();
        check(input, 3, (0.1, 30.0), 0.1, &mut out)
            .map(|()| out)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn good_input_is_clamped_into_the_lidars_range() {
        let ranges = [f64::INFINITY, 0.01, 2.5];
        assert_eq!(checked(&input(&ranges)).unwrap(), [30.0, 0.1, 2.5]);
    }

    #[test]
    fn each_fault_is_named() {
        let ranges = [1.0, 1.0, 1.0];
        let cases: Vec<(CycleInput<'_>, &str)> = vec![
            (
                input(&[1.0, 1.0]),
                "scan: 2 ranges, but the configured lidar has 3 beams ([episode.lidar] beams)",
            ),
            (input(&[1.0, f64::NAN, 1.0]), "scan: range 1 is NaN"),
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
