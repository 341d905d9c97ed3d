//! The observation layout and its builder.
//!
//! One observation is `obs_dim(space) = 720 + space.dim() + 6` floats, in this order
//! ([`segments`] gives the offsets):
//!
//! | segment           | size          | encoding                                                  |
//! |-------------------|---------------|-----------------------------------------------------------|
//! | `laser`           | 720           | lidar ranges in beam order, `2 * min(r, clip) / clip - 1` |
//! | `previous_action` | `space.dim()` | the previous (clamped) normalized action, in [-1, 1]      |
//! | `v`               | 1             | measured linear velocity (m/s), raw                       |
//! | `w`               | 1             | measured angular velocity (rad/s), raw                    |
//! | `local_goal`      | 2             | bearing (rad, in [-pi, pi]) and distance (m), robot frame |
//! | `global_goal`     | 2             | bearing (rad, in [-pi, pi]) and distance (m), robot frame |
//!
//! This module is the one definition of the layout: the learner sizes its networks with
//! [`obs_dim`] and the exported policy card documents [`segments`] with [`Segment::encoding`]
//! (`learner::export::observation_layout`).

use planner::ActionSpace;
use sim::episode::Perception;
use sim::geometry::Vec2;

/// Lidar beams in the observation (the Hokuyo UST-10's 720 over 270 degrees).
pub const LASER_BEAMS: usize = 720;
/// Default laser clip (m): ranges beyond it read as the clip.
pub const DEFAULT_LASER_CLIP_M: f64 = 3.0;
/// Floats after the previous action: v, w, local goal (2), global goal (2).
pub const STATE_TAIL: usize = 6;

/// Names of the observation segments, in order (as in the policy card).
pub const SEGMENT_NAMES: [&str; 6] = ["laser", "previous_action", "v", "w", "local_goal", "global_goal"];

/// One contiguous part of the observation vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    /// Name, one of [`SEGMENT_NAMES`].
    pub name: &'static str,
    /// Index of its first float.
    pub offset: usize,
    /// Number of floats.
    pub size: usize,
}

impl Segment {
    /// How the segment's values are computed from the robot's state and sensors, for lidar
    /// ranges clipped at `laser_clip_m`: the `encoding` the exported policy card states.
    pub fn encoding(&self, laser_clip_m: f64) -> String {
        match self.name {
            "laser" => format!(
                "lidar ranges r (m) in beam order, beam k at -135 + k * 270/{} degrees from the \
                 heading (counter-clockwise positive); x = 2 * min(r, {laser_clip_m}) / \
                 {laser_clip_m} - 1, in [-1, 1]",
                LASER_BEAMS - 1
            ),
            "previous_action" => "the policy's previous action, normalized to [-1, 1] like its output".into(),
            "v" => "measured linear velocity (m/s), not normalized".into(),
            "w" => "measured angular velocity (rad/s, counter-clockwise positive), not normalized".into(),
            "local_goal" => {
                "bearing (rad, in [-pi, pi], relative to the heading) and distance (m) of the local \
                             goal, not normalized"
                    .into()
            }
            "global_goal" => "bearing (rad, in [-pi, pi], relative to the heading) and distance (m) of the \
                              global goal, not normalized"
                .into(),
            other => unreachable!("segment names are SEGMENT_NAMES, not {other}"),
        }
    }
}

/// The observation segments of `space`, in order, contiguous from offset 0.
pub fn segments(space: ActionSpace) -> [Segment; 6] {
    let sizes = [LASER_BEAMS, space.dim(), 1, 1, 2, 2];
    let mut offset = 0;
    std::array::from_fn(|k| {
        let s = Segment {
            name: SEGMENT_NAMES[k],
            offset,
            size: sizes[k],
        };
        offset += sizes[k];
        s
    })
}

/// Length of an observation for `space`: `720 + space.dim() + 6` (730 for the decremental space).
pub fn obs_dim(space: ActionSpace) -> usize {
    LASER_BEAMS + space.dim() + STATE_TAIL
}

/// Beams closer than this (m) count as clutter ([`clutter`]).
pub const CLUTTER_RADIUS_M: f64 = 1.0;

/// Local clutter: the share of lidar `ranges` below [`CLUTTER_RADIUS_M`] (0 when empty). The
/// experiment's and the greedy evaluation's schedule-against-clutter statistics both use it.
pub fn clutter(ranges: &[f64]) -> f64 {
    if ranges.is_empty() {
        return 0.0;
    }
    ranges.iter().filter(|&&r| r < CLUTTER_RADIUS_M).count() as f64 / ranges.len() as f64
}

/// Laser encoding: `2 * min(r, clip) / clip - 1`, in [-1, 1] for `r >= 0`.
pub fn encode_range(r: f64, clip: f64) -> f32 {
    (2.0 * r.min(clip) / clip - 1.0) as f32
}

/// (bearing, distance) of a robot-frame point: `atan2(y, x)` in [-pi, pi] and its norm.
pub fn bearing_distance(p: Vec2) -> (f32, f32) {
    (p.y.atan2(p.x) as f32, p.norm() as f32)
}

/// Writes the observation of `perception` and `previous_action` into `out`. Allocation-free.
///
/// # Panics
/// If `out.len() != LASER_BEAMS + previous_action.len() + STATE_TAIL` or the perception does
/// not have [`LASER_BEAMS`] ranges: both are wiring errors the environment rules out.
pub fn write(perception: &Perception<'_>, previous_action: &[f32], laser_clip_m: f64, out: &mut [f32]) {
    let dim = LASER_BEAMS + previous_action.len() + STATE_TAIL;
    assert_eq!(
        out.len(),
        dim,
        "observation buffer has {} floats, the layout needs {dim}",
        out.len()
    );
    assert_eq!(
        perception.ranges.len(),
        LASER_BEAMS,
        "the observation needs {LASER_BEAMS} lidar ranges, the scan has {}",
        perception.ranges.len()
    );
    let (laser, rest) = out.split_at_mut(LASER_BEAMS);
    for (x, &r) in laser.iter_mut().zip(perception.ranges) {
        *x = encode_range(r, laser_clip_m);
    }
    let (prev, tail) = rest.split_at_mut(previous_action.len());
    prev.copy_from_slice(previous_action);
    let (lb, ld) = bearing_distance(perception.local_goal);
    let (gb, gd) = bearing_distance(perception.goal);
    tail.copy_from_slice(&[perception.vel.v as f32, perception.vel.w as f32, lb, ld, gb, gd]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::robot::Twist;

    #[test]
    fn clutter_is_the_share_of_close_beams() {
        assert_eq!(clutter(&[0.5, 2.0, 0.99, 3.0]), 0.5);
        assert_eq!(clutter(&[]), 0.0);
    }

    #[test]
    fn segments_are_contiguous_and_sum_to_obs_dim() {
        for space in [
            ActionSpace::Decremental,
            ActionSpace::Incremental,
            ActionSpace::Unconstrained,
            ActionSpace::Fixed,
        ] {
            let segs = segments(space);
            let mut offset = 0;
            for s in segs {
                assert_eq!(s.offset, offset, "{space:?} {}", s.name);
                offset += s.size;
            }
            assert_eq!(offset, obs_dim(space));
            assert_eq!(segs[1].size, space.dim());
        }
        assert_eq!(obs_dim(ActionSpace::Decremental), 730);
        assert_eq!(obs_dim(ActionSpace::Unconstrained), 746);
    }

    #[test]
    fn encodes_laser_goals_and_velocity() {
        assert_eq!(encode_range(0.0, 3.0), -1.0);
        assert_eq!(encode_range(1.5, 3.0), 0.0);
        assert_eq!(encode_range(3.0, 3.0), 1.0);
        assert_eq!(encode_range(30.0, 3.0), 1.0);
        let ranges: Vec<f64> = (0..LASER_BEAMS).map(|k| k as f64 * 0.01).collect();
        let p = Perception {
            ranges: &ranges,
            points: &[],
            vel: Twist::new(0.7, -0.3),
            local_goal: Vec2::new(0.0, 2.0),
            local_path: &[],
            goal: Vec2::new(-3.0, -4.0),
        };
        let mut out = vec![f32::NAN; 730];
        write(&p, &[0.1, 0.2, 0.3, 0.4], 3.0, &mut out);
        assert_eq!(out[0], -1.0);
        assert!((out[150] - 0.0).abs() < 1e-6, "1.5 m reads 0");
        assert_eq!(out[719], 1.0, "7.19 m is clipped to 3 m");
        assert_eq!(&out[720..724], &[0.1, 0.2, 0.3, 0.4]);
        assert_eq!(&out[724..726], &[0.7, -0.3]);
        assert!((out[726] - std::f32::consts::FRAC_PI_2).abs() < 1e-6 && out[727] == 2.0);
        let behind_right = (-4.0f64).atan2(-3.0) as f32;
        assert!((out[728] - behind_right).abs() < 1e-6 && out[728] < -std::f32::consts::FRAC_PI_2);
        assert_eq!(out[729], 5.0);
    }
}
