//! Getting unstuck: the recovery behaviour of the DWA planner.
//!
//! A constant-command planner with a 2 s horizon can park in a pocket where every forward
//! rollout fails a check: it then creeps or stands until the run times out. Navigation stacks
//! do not stop there. move_base runs recovery behaviours (back up, rotate in place), and the
//! authors' DWA and MPPI planners have a RECOVERY mode that picks the best of 20-25 heading
//! offsets over [-pi, pi] and rotates toward it, after backing up at 0.3 m/s when the front
//! is blocked (`reference/adp-code-notes.md` section 4.4). This module is that behaviour as
//! a small state machine the planner consults at the start of every cycle (MPPI, whose
//! brake and explore samples already keep it from parking, does not use it):
//!
//! - **watch**: when the measured speed stays below `stuck_speed` for `stuck_time`, pick an
//!   escape heading: among `headings` directions within the lidar's view, the one whose
//!   straight run (footprint checked every `probe_step` up to `probe_distance`) is at least
//!   `min_free` long and ends nearest the local goal, and that the footprint can rotate to
//!   in place without touching anything. Found: rotate; not found: back up.
//! - **back up** at `backup_speed` for at most `backup_time` (the lidar sees nothing behind
//!   the robot, so only while the footprint a step back is clear of what it does see), then
//!   choose again.
//! - **rotate** in place at `rotate_w` toward the heading (tracked by integrating the
//!   measured yaw rate) until within `heading_tolerance`, then hand back to the planner.
//!
//! Pure logic over the planner's [`LocalMap`]: deterministic, no I/O, no clock beyond the
//! cycle count. One instance per episode, owned by its planner.

use serde::{Deserialize, Serialize};
use sim::episode::Perception;
use sim::geometry::{wrap_angle, Pose, Vec2};
use sim::robot::Twist;
use std::f64::consts::PI;

use crate::local_map::LocalMap;

/// Recovery parameters (the `[dwa.recovery]` table of `adp eval`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecoveryConfig {
    /// Off: the planner alone decides every cycle (its behaviour before recovery existed).
    pub enabled: bool,
    /// The robot counts as still below this measured speed (m/s).
    pub stuck_speed: f64,
    /// Recovery starts after the robot has been still this long (s).
    pub stuck_time: f64,
    /// Candidate escape headings spread over the full turn; those outside the lidar's
    /// field of view (`view_half_angle`) are skipped.
    pub headings: usize,
    /// Half the angle around the front in which escape headings are considered (rad).
    pub view_half_angle: f64,
    /// How far a straight run along a candidate heading is checked (m).
    pub probe_distance: f64,
    /// Spacing of the footprint checks along the run (m).
    pub probe_step: f64,
    /// A heading is an escape when its clear run is at least this long (m).
    pub min_free: f64,
    /// Smallest clearance a checked footprint must keep (m).
    pub margin: f64,
    /// Yaw rate of the in-place rotation (rad/s).
    pub rotate_w: f64,
    /// The rotation ends within this heading error (rad).
    pub heading_tolerance: f64,
    /// Reverse speed when no heading is free (m/s, positive).
    pub backup_speed: f64,
    /// Longest back-up before choosing again (s).
    pub backup_time: f64,
    /// One planning cycle (s): the recovery's clock.
    pub control_dt: f64,
}

impl Default for RecoveryConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            stuck_speed: 0.05,
            stuck_time: 1.5,
            headings: 24,
            view_half_angle: 0.75 * PI,
            probe_distance: 1.5,
            probe_step: 0.1,
            min_free: 0.5,
            margin: 0.02,
            rotate_w: 1.0,
            heading_tolerance: 0.1,
            backup_speed: 0.3,
            backup_time: 1.0,
            control_dt: 0.05,
        }
    }
}

/// Where the recovery state machine is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Phase {
    /// The planner drives; `still` is how long the robot has been still (s).
    Watch {
        /// Time spent below the stuck speed (s).
        still: f64,
    },
    /// Reversing; `left` is the back-up time remaining (s).
    Backup {
        /// Back-up time remaining (s).
        left: f64,
    },
    /// Turning in place; `remaining` is the signed yaw still to turn (rad), `left` the time
    /// allowed before giving the planner back control (s).
    Rotate {
        /// Signed yaw still to turn (rad).
        remaining: f64,
        /// Time allowed before handing back (s).
        left: f64,
    },
}

/// The recovery state machine of one episode. Not shared between threads.
#[derive(Clone, Debug)]
pub struct Recovery {
    cfg: RecoveryConfig,
    phase: Phase,
    /// Recoveries started in this episode.
    started: u32,
}

impl Recovery {
    /// A recovery in the watch phase.
    pub fn new(cfg: RecoveryConfig) -> Self {
        Self {
            cfg,
            phase: Phase::Watch { still: 0.0 },
            started: 0,
        }
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// How many recoveries this episode has started.
    pub fn started(&self) -> u32 {
        self.started
    }

    /// Advances one cycle. `Some(command)` overrides the planner this cycle; `None` lets it
    /// plan. `map` must hold this cycle's scan; `evaluated` counts the check points used.
    pub fn step(&mut self, map: &LocalMap, per: &Perception<'_>, evaluated: &mut u64) -> Option<Twist> {
        let cfg = self.cfg;
        if !cfg.enabled {
            return None;
        }
        let dt = cfg.control_dt;
        match self.phase {
            Phase::Watch { still } => {
                let still = if per.vel.v.abs() < cfg.stuck_speed {
                    still + dt
                } else {
                    0.0
                };
                if still + 1e-9 < cfg.stuck_time {
                    self.phase = Phase::Watch { still };
                    return None;
                }
                self.started += 1;
                self.choose(map, per, evaluated)
            }
            Phase::Backup { left } => {
                let left = left - dt;
                let behind = Pose::new(-cfg.probe_step, 0.0, 0.0);
                let blocked = clearance(map, &behind, evaluated) < cfg.margin;
                if left <= 0.0 || blocked {
                    return self.choose_after_backup(map, per, evaluated);
                }
                self.phase = Phase::Backup { left };
                Some(Twist::new(-cfg.backup_speed, 0.0))
            }
            Phase::Rotate { remaining, left } => {
                let remaining = remaining - per.vel.w * dt;
                let left = left - dt;
                if remaining.abs() <= cfg.heading_tolerance || left <= 0.0 {
                    self.phase = Phase::Watch { still: 0.0 };
                    return None;
                }
                self.phase = Phase::Rotate { remaining, left };
                Some(Twist::new(0.0, cfg.rotate_w.copysign(remaining)))
            }
        }
    }

    /// Starts a rotation toward the best escape heading, or a back-up when there is none.
    fn choose(&mut self, map: &LocalMap, per: &Perception<'_>, evaluated: &mut u64) -> Option<Twist> {
        match escape_turn(&self.cfg, map, per.local_goal, evaluated) {
            Some(turn) => self.rotate(turn),
            None => {
                self.phase = Phase::Backup {
                    left: self.cfg.backup_time,
                };
                Some(Twist::new(-self.cfg.backup_speed, 0.0))
            }
        }
    }

    /// After a back-up: rotate when a heading is free now, else hand back to the planner.
    fn choose_after_backup(
        &mut self,
        map: &LocalMap,
        per: &Perception<'_>,
        evaluated: &mut u64,
    ) -> Option<Twist> {
        match escape_turn(&self.cfg, map, per.local_goal, evaluated) {
            Some(turn) => self.rotate(turn),
            None => {
                self.phase = Phase::Watch { still: 0.0 };
                None
            }
        }
    }

    fn rotate(&mut self, turn: f64) -> Option<Twist> {
        let cfg = self.cfg;
        if turn.abs() <= cfg.heading_tolerance {
            // Already facing the escape: let the planner drive it.
            self.phase = Phase::Watch { still: 0.0 };
            return None;
        }
        // Twice the nominal duration, then give up (a wedged robot does not turn).
        let left = 2.0 * turn.abs() / cfg.rotate_w + 1.0;
        self.phase = Phase::Rotate {
            remaining: turn,
            left,
        };
        Some(Twist::new(0.0, cfg.rotate_w.copysign(turn)))
    }
}

/// Clearance of the footprint at `pose` with every boundary point checked.
fn clearance(map: &LocalMap, pose: &Pose, evaluated: &mut u64) -> f64 {
    map.footprint_clearance(pose, map.boundary_points(), f64::INFINITY, evaluated)
}

/// The signed in-place turn (rad) toward the best escape heading, or `None` when no heading
/// in view has a clear run of `min_free` that the footprint can also turn to.
///
/// The threshold for a checked footprint is the margin, or the robot's own clearance where
/// that is already smaller, so a robot wedged closer than the margin may still leave.
pub fn escape_turn(
    cfg: &RecoveryConfig,
    map: &LocalMap,
    local_goal: Vec2,
    evaluated: &mut u64,
) -> Option<f64> {
    let here = clearance(map, &Pose::default(), evaluated);
    let limit = cfg.margin.min(here);
    let n = cfg.headings.max(1);
    let mut best: Option<(f64, f64)> = None;
    for k in 0..n {
        let heading = wrap_angle(-PI + 2.0 * PI * k as f64 / n as f64);
        if heading.abs() > cfg.view_half_angle {
            continue;
        }
        let free = clear_run(cfg, map, heading, limit, evaluated);
        if free + 1e-9 < cfg.min_free {
            continue;
        }
        let Some(turn) = turnable(cfg, map, heading, limit, evaluated) else {
            continue;
        };
        let end = Vec2::new(free * heading.cos(), free * heading.sin());
        let cost = end.dist(local_goal);
        if best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, turn));
        }
    }
    best.map(|(_, turn)| turn)
}

/// Length of the clear straight run along `heading` (m), up to the probe distance.
fn clear_run(cfg: &RecoveryConfig, map: &LocalMap, heading: f64, limit: f64, evaluated: &mut u64) -> f64 {
    let (s, c) = heading.sin_cos();
    let steps = (cfg.probe_distance / cfg.probe_step).floor() as usize;
    let mut free = 0.0;
    for i in 1..=steps {
        let d = i as f64 * cfg.probe_step;
        if clearance(map, &Pose::new(d * c, d * s, heading), evaluated) < limit {
            break;
        }
        free = d;
    }
    free
}

/// The signed in-place turn to `heading` that keeps the footprint clear all the way (checked
/// every 0.1 rad): the short way if possible, else the long way; `None` if neither.
fn turnable(
    cfg: &RecoveryConfig,
    map: &LocalMap,
    heading: f64,
    limit: f64,
    evaluated: &mut u64,
) -> Option<f64> {
    let long = heading - 2.0 * PI * heading.signum();
    [heading, long].into_iter().find(|&turn| {
        let steps = (turn.abs() / 0.1).ceil() as usize;
        (1..=steps).all(|i| {
            let yaw = turn * i as f64 / steps as f64;
            clearance(map, &Pose::new(0.0, 0.0, yaw), evaluated) >= limit
        }) && turn.abs() <= 2.0 * PI - cfg.heading_tolerance
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::Footprint;

    fn map_of(points: &[Vec2]) -> LocalMap {
        let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 32);
        map.build(points, 2.0, 3.0);
        map
    }

    /// A wall of points across x = `x`, from y = `y0` to `y1`.
    fn wall_x(x: f64, y0: f64, y1: f64) -> Vec<Vec2> {
        let n = ((y1 - y0) / 0.02).round() as usize;
        (0..=n)
            .map(|i| Vec2::new(x, y0 + (y1 - y0) * i as f64 / n as f64))
            .collect()
    }

    fn perception<'a>(v: f64, w: f64, goal: Vec2) -> Perception<'a> {
        Perception {
            ranges: &[],
            points: &[],
            vel: Twist::new(v, w),
            local_goal: goal,
            local_path: &[],
            goal,
        }
    }

    #[test]
    fn a_moving_robot_is_left_to_its_planner() {
        let map = map_of(&wall_x(0.6, -0.6, 0.6));
        let mut r = Recovery::new(RecoveryConfig::default());
        let mut ev = 0;
        for _ in 0..200 {
            assert_eq!(
                r.step(&map, &perception(0.3, 0.0, Vec2::new(3.0, 0.0)), &mut ev),
                None
            );
        }
        assert_eq!(r.started(), 0);
    }

    #[test]
    fn a_robot_still_for_the_stuck_time_turns_toward_the_open_side() {
        // A wall ahead and to the left: the escape is on the right (negative yaw).
        let mut pts = wall_x(0.5, -0.4, 1.5);
        pts.extend((0..60).map(|i| Vec2::new(-0.5 + i as f64 * 0.02, 0.7)));
        let map = map_of(&pts);
        let cfg = RecoveryConfig::default();
        let mut r = Recovery::new(cfg);
        let mut ev = 0;
        let still = perception(0.0, 0.0, Vec2::new(3.0, 0.5));
        // 1.5 s at 0.05 s per cycle: 29 cycles of watching, the 30th starts the recovery.
        for _ in 0..29 {
            assert_eq!(r.step(&map, &still, &mut ev), None);
        }
        let cmd = r.step(&map, &still, &mut ev).expect("recovery starts");
        assert_eq!(r.started(), 1);
        assert_eq!(cmd.v, 0.0);
        assert!(cmd.w < 0.0, "turns right, away from the walls: {cmd:?}");
        let Phase::Rotate { remaining, .. } = r.phase() else {
            panic!("rotating: {:?}", r.phase());
        };
        assert!(remaining < -0.5, "a real turn: {remaining}");
        // Turning at the commanded rate ends the rotation within the tolerance.
        let turning = perception(0.0, -cfg.rotate_w, Vec2::new(3.0, 0.5));
        let mut cycles = 0;
        while r.step(&map, &turning, &mut ev).is_some() {
            cycles += 1;
            assert!(cycles < 200);
        }
        let expect = ((remaining.abs() - cfg.heading_tolerance) / (cfg.rotate_w * cfg.control_dt)).ceil();
        assert!((cycles as f64 - expect).abs() <= 1.0, "{cycles} vs {expect}");
        assert_eq!(r.phase(), Phase::Watch { still: 0.0 });
    }

    #[test]
    fn boxed_in_ahead_and_on_both_sides_backs_up() {
        // A U around the front: no heading in view has a clear run of min_free.
        let mut pts = wall_x(0.45, -0.5, 0.5);
        pts.extend((0..40).map(|i| Vec2::new(-0.35 + i as f64 * 0.02, 0.45)));
        pts.extend((0..40).map(|i| Vec2::new(-0.35 + i as f64 * 0.02, -0.45)));
        let map = map_of(&pts);
        let cfg = RecoveryConfig::default();
        let mut ev = 0;
        assert_eq!(escape_turn(&cfg, &map, Vec2::new(3.0, 0.0), &mut ev), None);
        let mut r = Recovery::new(cfg);
        let still = perception(0.0, 0.0, Vec2::new(3.0, 0.0));
        let mut first = None;
        for _ in 0..40 {
            if let Some(cmd) = r.step(&map, &still, &mut ev) {
                first = Some(cmd);
                break;
            }
        }
        assert_eq!(first, Some(Twist::new(-cfg.backup_speed, 0.0)));
        // The back-up lasts backup_time, then (still boxed in) hands back to the planner.
        let mut backing = 1;
        while r.step(&map, &still, &mut ev).is_some() {
            backing += 1;
            assert!(backing < 100);
        }
        assert_eq!(backing, (cfg.backup_time / cfg.control_dt).round() as usize);
    }

    #[test]
    fn the_escape_ends_nearest_the_local_goal() {
        let map = map_of(&[]);
        let cfg = RecoveryConfig::default();
        let mut ev = 0;
        // Open space: the goal's own bearing (on the 15-degree grid) wins.
        let goal = Vec2::new(0.0, 2.0);
        let turn = escape_turn(&cfg, &map, goal, &mut ev).unwrap();
        assert!((turn - PI / 2.0).abs() < 1e-9, "{turn}");
        assert!(ev > 0);
    }

    #[test]
    fn disabled_never_overrides() {
        let map = map_of(&wall_x(0.45, -1.0, 1.0));
        let mut r = Recovery::new(RecoveryConfig {
            enabled: false,
            ..RecoveryConfig::default()
        });
        let mut ev = 0;
        for _ in 0..100 {
            assert_eq!(
                r.step(&map, &perception(0.0, 0.0, Vec2::new(3.0, 0.0)), &mut ev),
                None
            );
        }
    }
}
