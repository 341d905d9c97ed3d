//! The observation layout and its builder.
//!
//! One observation is `obs_dim(space, k) = 720 + space.dim() + 6 + 4 k` floats, in this
//! order ([`segments`] gives the offsets):
//!
//! | segment           | size          | encoding                                                  |
//! |-------------------|---------------|-----------------------------------------------------------|
//! | `laser`           | 720           | lidar ranges in beam order, `2 * min(r, clip) / clip - 1` |
//! | `previous_action` | `space.dim()` | the previous (clamped) normalized action, in [-1, 1]      |
//! | `v`               | 1             | measured linear velocity (m/s), raw                       |
//! | `w`               | 1             | measured angular velocity (rad/s), raw                    |
//! | `local_goal`      | 2             | bearing (rad, in [-pi, pi]) and distance (m), robot frame |
//! | `global_goal`     | 2             | bearing (rad, in [-pi, pi]) and distance (m), robot frame |
//! | `tracks`          | `4 k`         | only when `k > 0` (`[env] observe_tracks = k`): the `k` nearest moving tracks, nearest first, each `x, y` (m) and `vx, vy` (m/s) in the robot frame, raw; empty slots are zeros |
//!
//! The tracks segment comes last, so the layouts without it (`k = 0`, the default) are the
//! layouts of every policy trained before it existed.
//!
//! This module is the one definition of the layout: the learner sizes its networks with
//! [`obs_dim`] and the exported policy card documents [`segments`] with [`Segment::encoding`]
//! (`learner::export::observation_layout`).

use planner::{ActionSpace, Predicted};
use sim::episode::Perception;
use sim::geometry::Vec2;

/// Lidar beams in the observation (the Hokuyo UST-10's 720 over 270 degrees).
pub const LASER_BEAMS: usize = 720;
/// Default laser clip (m): ranges beyond it read as the clip.
pub const DEFAULT_LASER_CLIP_M: f64 = 3.0;
/// Floats after the previous action: v, w, local goal (2), global goal (2).
pub const STATE_TAIL: usize = 6;

/// Floats per observed track: x, y, vx, vy.
pub const TRACK_FLOATS: usize = 4;
/// Most tracks an observation may hold (`[env] observe_tracks`).
pub const MAX_OBSERVED_TRACKS: usize = 16;

/// Names of the observation segments, in order (as in the policy card); `tracks` is present
/// only when tracks are observed.
pub const SEGMENT_NAMES: [&str; 7] = [
    "laser",
    "previous_action",
    "v",
    "w",
    "local_goal",
    "global_goal",
    "tracks",
];

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
            "tracks" => format!(
                "the {} nearest confirmed moving tracks of the obstacle tracker (as the planner is \
                 told of them), nearest first, each as x, y (m, robot frame: x ahead, y left) of \
                 its centre and vx, vy (m/s, robot frame) of its velocity, not normalized; slots \
                 without a track are 0, 0, 0, 0",
                self.size / TRACK_FLOATS
            ),
            other => unreachable!("segment names are SEGMENT_NAMES, not {other}"),
        }
    }
}

/// The observation segments of `space` with `tracks` observed tracks, in order, contiguous
/// from offset 0 (the `tracks` segment only when `tracks > 0`).
pub fn segments(space: ActionSpace, tracks: usize) -> Vec<Segment> {
    let sizes = [LASER_BEAMS, space.dim(), 1, 1, 2, 2, TRACK_FLOATS * tracks];
    let mut offset = 0;
    SEGMENT_NAMES
        .iter()
        .zip(sizes)
        .filter(|&(&name, _)| name != "tracks" || tracks > 0)
        .map(|(&name, size)| {
            let s = Segment { name, offset, size };
            offset += size;
            s
        })
        .collect()
}

/// Length of an observation for `space` with `tracks` observed tracks:
/// `720 + space.dim() + 6 + 4 tracks` (730 for the decremental space without tracks).
pub fn obs_dim(space: ActionSpace, tracks: usize) -> usize {
    LASER_BEAMS + space.dim() + STATE_TAIL + TRACK_FLOATS * tracks
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

/// Writes the observation of `perception`, `previous_action` and the moving obstacles
/// `tracks` (robot frame) into `out`; the tracks segment holds `(out.len() - 726 -
/// previous_action.len()) / 4` slots. Allocation-free.
///
/// # Panics
/// If `out.len()` is not `LASER_BEAMS + previous_action.len() + STATE_TAIL` plus a whole
/// number of track slots, or the perception does not have [`LASER_BEAMS`] ranges: both are
/// wiring errors the environment rules out.
pub fn write(
    perception: &Perception<'_>,
    previous_action: &[f32],
    laser_clip_m: f64,
    tracks: &[Predicted],
    out: &mut [f32],
) {
    let base = LASER_BEAMS + previous_action.len() + STATE_TAIL;
    assert!(
        out.len() >= base && (out.len() - base).is_multiple_of(TRACK_FLOATS),
        "observation buffer has {} floats, the layout needs {base} plus {TRACK_FLOATS} per track",
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
    let (prev, rest) = rest.split_at_mut(previous_action.len());
    prev.copy_from_slice(previous_action);
    let (tail, slots) = rest.split_at_mut(STATE_TAIL);
    let (lb, ld) = bearing_distance(perception.local_goal);
    let (gb, gd) = bearing_distance(perception.goal);
    tail.copy_from_slice(&[perception.vel.v as f32, perception.vel.w as f32, lb, ld, gb, gd]);
    write_tracks(tracks, slots);
}

/// Fills `slots` (4 floats per slot) with the tracks nearest the robot, nearest first (ties
/// in list order), then zeros. Allocation-free: each slot takes the nearest track after the
/// previous slot's in (distance, index) order.
fn write_tracks(tracks: &[Predicted], slots: &mut [f32]) {
    let mut last: Option<(f64, usize)> = None;
    for slot in slots.chunks_exact_mut(TRACK_FLOATS) {
        let after = |key: (f64, usize)| last.is_none_or(|l| key.0 > l.0 || (key.0 == l.0 && key.1 > l.1));
        let next = tracks
            .iter()
            .enumerate()
            .map(|(i, t)| (t.position.norm(), i))
            .filter(|&key| after(key))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        match next {
            Some(key) => {
                let t = &tracks[key.1];
                slot.copy_from_slice(&[
                    t.position.x as f32,
                    t.position.y as f32,
                    t.velocity.x as f32,
                    t.velocity.y as f32,
                ]);
                last = Some(key);
            }
            None => slot.fill(0.0),
        }
    }
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
            for tracks in [0, 4] {
                let segs = segments(space, tracks);
                let mut offset = 0;
                for s in &segs {
                    assert_eq!(s.offset, offset, "{space:?} {}", s.name);
                    offset += s.size;
                }
                assert_eq!(offset, obs_dim(space, tracks));
                assert_eq!(segs[1].size, space.dim());
                assert_eq!(segs.len(), if tracks > 0 { 7 } else { 6 });
            }
        }
        assert_eq!(obs_dim(ActionSpace::Decremental, 0), 730);
        assert_eq!(obs_dim(ActionSpace::Unconstrained, 0), 746);
        assert_eq!(obs_dim(ActionSpace::Decremental, 4), 746);
        let last = segments(ActionSpace::Decremental, 4)[6];
        assert_eq!((last.name, last.offset, last.size), ("tracks", 730, 16));
        assert!(last.encoding(3.0).starts_with("the 4 nearest"));
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
        write(&p, &[0.1, 0.2, 0.3, 0.4], 3.0, &[], &mut out);
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

    #[test]
    fn tracks_fill_their_slots_nearest_first_then_zeros() {
        let ranges = vec![1.0; LASER_BEAMS];
        let p = Perception {
            ranges: &ranges,
            points: &[],
            vel: Twist::new(0.0, 0.0),
            local_goal: Vec2::new(1.0, 0.0),
            local_path: &[],
            goal: Vec2::new(1.0, 0.0),
        };
        let track = |x: f64, y: f64, vx: f64, vy: f64| Predicted {
            position: Vec2::new(x, y),
            velocity: Vec2::new(vx, vy),
            radius: 0.5,
        };
        // Three tracks at 5 m, 2 m and 5 m (a tie: list order), in 2 slots, then in 4.
        let tracks = [
            track(3.0, 4.0, 1.0, 0.0),
            track(0.0, -2.0, 0.0, 1.5),
            track(-5.0, 0.0, -0.5, 0.25),
        ];
        let mut out = vec![f32::NAN; 730 + 8];
        write(&p, &[0.0; 4], 3.0, &tracks, &mut out);
        assert_eq!(&out[730..], &[0.0, -2.0, 0.0, 1.5, 3.0, 4.0, 1.0, 0.0]);
        let mut out = vec![f32::NAN; 730 + 16];
        write(&p, &[0.0; 4], 3.0, &tracks, &mut out);
        assert_eq!(
            &out[730..],
            &[0.0, -2.0, 0.0, 1.5, 3.0, 4.0, 1.0, 0.0, -5.0, 0.0, -0.5, 0.25, 0.0, 0.0, 0.0, 0.0]
        );
        // No tracks: all zeros; the rest of the observation is as without the segment.
        let mut without = vec![f32::NAN; 730];
        write(&p, &[0.0; 4], 3.0, &tracks, &mut without);
        write(&p, &[0.0; 4], 3.0, &[], &mut out);
        assert_eq!(&out[..730], &without[..]);
        assert!(out[730..].iter().all(|&x| x == 0.0));
    }
}
