//! The observation layout and its builder.
//!
//! One observation is `obs_dim(laser, space, k) = L + space.dim() + 6 + 4 k` floats, in this
//! order ([`segments`] gives the offsets), with `L` the size of the [`LaserLayout`] (720 for
//! `scan`, the default; `N` for `sectors:N`):
//!
//! | segment           | size          | encoding                                                  |
//! |-------------------|---------------|-----------------------------------------------------------|
//! | `laser`           | `L`           | lidar ranges in beam order (`scan`) or the least range per angular sector (`sectors:N`), `2 * min(r, clip) / clip - 1` |
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
//! The laser segment is built in the policy's own layout from whatever the lidar gives
//! ([`LaserResampler`]): a policy trained on the 720-beam scan runs on a 90-beam lidar (each of
//! its 720 values takes the nearest beam), and a `sectors:N` policy takes each sector's least
//! range from any beam count. A scan of the layout's own 720 beams passes unchanged.
//!
//! The layout itself (the laser layouts, the segments, their sizes and encodings) is defined
//! once, in the `layout` crate, which the learner also reads (network sizes, the exported
//! policy card); it is re-exported here, with [`segments`] and [`obs_dim`] taking the action
//! space. This module builds observations in it.

use planner::{ActionSpace, Predicted};
use sim::episode::Perception;
use sim::geometry::Vec2;

pub use layout::{
    LaserLayout, LayoutError, Segment, DEFAULT_LASER_CLIP_M, LASER_BEAMS, LASER_FIELD_DEG,
    MAX_OBSERVED_TRACKS, MAX_SECTORS, SEGMENT_NAMES, STATE_TAIL, TRACK_FLOATS,
};

/// Angles (rad) closer than this count as equal when placing beams in sectors: a beam at the
/// field's edge, computed with rounding, still falls in the field.
const ANGLE_EPS: f64 = 1e-9;

/// Builds a [`LaserLayout`]'s laser segment from the scans of one lidar, whatever its beam
/// count and field of view. Precomputed once per sensor; allocation-free per observation.
///
/// Every laser value is the least range over a run of consecutive beams:
///
/// * `scan`: layout beam k (at `-135 + k * 270/719` degrees) takes the one sensor beam nearest
///   its angle (ties: the lower index). A sensor of 720 beams over 270 degrees maps beam k to
///   beam k, so its scan passes bit for bit; a 90-beam scan repeats each beam about 8 times.
/// * `sectors:N`: sector i takes the least range of the sensor beams whose angle falls in
///   `[-135 + i 270/N, -135 + (i + 1) 270/N)` degrees (the last sector includes +135; beams
///   outside the 270-degree field are not used); a sector without a beam takes the beam
///   nearest its centre.
#[derive(Clone, Debug, PartialEq)]
pub struct LaserResampler {
    layout: LaserLayout,
    /// The sensor's beam count (the length of the scans it reads).
    beams: usize,
    /// Per laser value, the sensor beams `[start, end)` it is the minimum of.
    spans: Vec<(usize, usize)>,
}

impl LaserResampler {
    /// The resampler from a lidar whose beams point at `angles` (rad from the heading,
    /// counter-clockwise positive, increasing, as [`sim::lidar::Lidar::angles`]) into `layout`.
    ///
    /// # Panics
    /// If `angles` is empty or not increasing (no lidar makes such a scan).
    pub fn new(layout: LaserLayout, angles: &[f64]) -> Self {
        assert!(
            !angles.is_empty() && angles.windows(2).all(|w| w[0] < w[1]),
            "beam angles must be increasing"
        );
        let field = LASER_FIELD_DEG.to_radians();
        let one = |j: usize| (j, j + 1);
        let spans = match layout {
            LaserLayout::Scan => (0..LASER_BEAMS)
                .map(|k| {
                    one(nearest(
                        angles,
                        -field / 2.0 + field * k as f64 / (LASER_BEAMS - 1) as f64,
                    ))
                })
                .collect(),
            LaserLayout::Sectors(n) => {
                let (half, width) = (field / 2.0, field / n as f64);
                let mut spans = vec![(usize::MAX, 0); n];
                for (j, &a) in angles.iter().enumerate() {
                    if a < -half - ANGLE_EPS || a > half + ANGLE_EPS {
                        continue;
                    }
                    let i = (((a + half) / width).floor().max(0.0) as usize).min(n - 1);
                    let span = &mut spans[i];
                    if span.0 == usize::MAX {
                        *span = one(j);
                    } else {
                        span.1 = j + 1;
                    }
                }
                for (i, span) in spans.iter_mut().enumerate() {
                    if span.0 == usize::MAX {
                        *span = one(nearest(angles, -half + (i as f64 + 0.5) * width));
                    }
                }
                spans
            }
        };
        Self {
            layout,
            beams: angles.len(),
            spans,
        }
    }

    /// The layout it builds.
    pub fn layout(&self) -> LaserLayout {
        self.layout
    }

    /// Writes the laser segment of `ranges` (one scan of the sensor) into `out`, ranges
    /// clipped at `clip` and encoded by [`encode_range`]. Allocation-free.
    ///
    /// # Panics
    /// If `ranges` is not one range per beam of the sensor or `out` is not the layout's size.
    pub fn write(&self, ranges: &[f64], clip: f64, out: &mut [f32]) {
        assert_eq!(
            ranges.len(),
            self.beams,
            "the resampler reads scans of {} beams, the scan has {}",
            self.beams,
            ranges.len()
        );
        assert_eq!(out.len(), self.spans.len(), "laser segment size");
        for (x, &(start, end)) in out.iter_mut().zip(&self.spans) {
            let r = ranges[start..end].iter().copied().fold(f64::INFINITY, f64::min);
            *x = encode_range(r, clip);
        }
    }
}

/// The index of the angle in `angles` (increasing) nearest `a`; ties go to the lower index.
fn nearest(angles: &[f64], a: f64) -> usize {
    let i = angles.partition_point(|&x| x < a);
    if i == 0 {
        0
    } else if i == angles.len() || a - angles[i - 1] <= angles[i] - a {
        i - 1
    } else {
        i
    }
}

/// The observation segments of the laser layout `laser` and `space` with `tracks` observed
/// tracks, in order, contiguous from offset 0 ([`layout::segments`] of `space.dim()`).
pub fn segments(laser: LaserLayout, space: ActionSpace, tracks: usize) -> Vec<Segment> {
    layout::segments(laser, space.dim(), tracks)
}

/// Length of an observation for the laser layout `laser` and `space` with `tracks` observed
/// tracks ([`layout::obs_dim`] of `space.dim()`: 730 for the `scan` layout and the decremental
/// space without tracks).
pub fn obs_dim(laser: LaserLayout, space: ActionSpace, tracks: usize) -> usize {
    layout::obs_dim(laser, space.dim(), tracks)
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

/// Writes the observation of `perception` (its scan through `laser` into the laser layout),
/// `previous_action` and the moving obstacles `tracks` (robot frame) into `out`; the tracks
/// segment holds `(out.len() - laser size - previous_action.len() - 6) / 4` slots.
/// Allocation-free.
///
/// # Panics
/// If `out.len()` is not the laser layout's size plus `previous_action.len() + STATE_TAIL`
/// plus a whole number of track slots, or the perception's scan is not of `laser`'s sensor:
/// both are wiring errors the environment rules out.
pub fn write(
    perception: &Perception<'_>,
    laser: &LaserResampler,
    previous_action: &[f32],
    laser_clip_m: f64,
    tracks: &[Predicted],
    out: &mut [f32],
) {
    let laser_size = laser.layout().size();
    let base = laser_size + previous_action.len() + STATE_TAIL;
    assert!(
        out.len() >= base && (out.len() - base).is_multiple_of(TRACK_FLOATS),
        "observation buffer has {} floats, the layout needs {base} plus {TRACK_FLOATS} per track",
        out.len()
    );
    let (laser_out, rest) = out.split_at_mut(laser_size);
    laser.write(perception.ranges, laser_clip_m, laser_out);
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
    use sim::lidar::{Lidar, LidarConfig};
    use sim::robot::Twist;

    /// The resampler of a lidar of `beams` beams over 270 degrees into `layout`.
    fn resampler(layout: LaserLayout, beams: usize) -> LaserResampler {
        let lidar = Lidar::new(LidarConfig {
            beams,
            ..LidarConfig::default()
        });
        LaserResampler::new(layout, lidar.angles())
    }

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
                let segs = segments(LaserLayout::Scan, space, tracks);
                let mut offset = 0;
                for s in &segs {
                    assert_eq!(s.offset, offset, "{space:?} {}", s.name);
                    offset += s.size;
                }
                assert_eq!(offset, obs_dim(LaserLayout::Scan, space, tracks));
                assert_eq!(segs[1].size, space.dim());
                assert_eq!(segs.len(), if tracks > 0 { 7 } else { 6 });
            }
        }
        let scan = LaserLayout::Scan;
        assert_eq!(obs_dim(scan, ActionSpace::Decremental, 0), 730);
        assert_eq!(obs_dim(scan, ActionSpace::Unconstrained, 0), 746);
        assert_eq!(obs_dim(scan, ActionSpace::Decremental, 4), 746);
        let last = segments(scan, ActionSpace::Decremental, 4)[6];
        assert_eq!((last.name, last.offset, last.size), ("tracks", 730, 16));
        assert!(last.encoding(scan, 3.0).starts_with("the 4 nearest"));
        // A sectors layout shrinks the laser segment only.
        let sectors = LaserLayout::Sectors(25);
        assert_eq!(obs_dim(sectors, ActionSpace::Decremental, 0), 35);
        let segs = segments(sectors, ActionSpace::Decremental, 4);
        assert_eq!((segs[0].size, segs[1].offset, segs[6].offset), (25, 25, 35));
        assert!(segs[0]
            .encoding(sectors, 3.0)
            .starts_with("the 270-degree field split into 25"));
        assert!(segs[0]
            .encoding(scan, 3.0)
            .starts_with("lidar ranges r (m) in beam order"));
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
        let scan = resampler(LaserLayout::Scan, LASER_BEAMS);
        write(&p, &scan, &[0.1, 0.2, 0.3, 0.4], 3.0, &[], &mut out);
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
            residual: None,
        };
        // Three tracks at 5 m, 2 m and 5 m (a tie: list order), in 2 slots, then in 4.
        let tracks = [
            track(3.0, 4.0, 1.0, 0.0),
            track(0.0, -2.0, 0.0, 1.5),
            track(-5.0, 0.0, -0.5, 0.25),
        ];
        let mut out = vec![f32::NAN; 730 + 8];
        let scan = resampler(LaserLayout::Scan, LASER_BEAMS);
        write(&p, &scan, &[0.0; 4], 3.0, &tracks, &mut out);
        assert_eq!(&out[730..], &[0.0, -2.0, 0.0, 1.5, 3.0, 4.0, 1.0, 0.0]);
        let mut out = vec![f32::NAN; 730 + 16];
        write(&p, &scan, &[0.0; 4], 3.0, &tracks, &mut out);
        assert_eq!(
            &out[730..],
            &[0.0, -2.0, 0.0, 1.5, 3.0, 4.0, 1.0, 0.0, -5.0, 0.0, -0.5, 0.25, 0.0, 0.0, 0.0, 0.0]
        );
        // No tracks: all zeros; the rest of the observation is as without the segment.
        let mut without = vec![f32::NAN; 730];
        write(&p, &scan, &[0.0; 4], 3.0, &tracks, &mut without);
        write(&p, &scan, &[0.0; 4], 3.0, &[], &mut out);
        assert_eq!(&out[..730], &without[..]);
        assert!(out[730..].iter().all(|&x| x == 0.0));
    }

    #[test]
    fn sectors_take_the_least_range_of_their_beams() {
        // 12 beams over 270 degrees: beam k at -135 + k * 270/11 = -135 + 24.55 k degrees. Three
        // sectors of 90 degrees: [-135, -45) holds beams 0..=3 (up to -61.4), [-45, 45) beams
        // 4..=7 (-36.8 to 36.8), [45, 135] beams 8..=11.
        let ranges = [
            5.0, 0.7, 2.0, 9.0, // sector 0: least 0.7
            1.2, 1.1, 4.0, 2.5, // sector 1: least 1.1
            3.5, 6.0, 3.4, 8.0, // sector 2: least 3.4, past the 3 m clip
        ];
        let r = resampler(LaserLayout::Sectors(3), 12);
        let mut out = [f32::NAN; 3];
        r.write(&ranges, 3.0, &mut out);
        assert_eq!(
            out,
            [encode_range(0.7, 3.0), encode_range(1.1, 3.0), 1.0],
            "2 * 0.7 / 3 - 1, 2 * 1.1 / 3 - 1, clipped"
        );
        // 3 beams (-135, 0, +135 degrees) in 5 sectors of 54 degrees: sectors 0, 2 and 4 hold
        // one beam each; sector 1 (centre -54) is nearest the middle beam (54 degrees away, the
        // first is 81), and so is sector 3 (centre +54).
        let r = resampler(LaserLayout::Sectors(5), 3);
        let mut out = [f32::NAN; 5];
        r.write(&[0.3, 1.5, 2.7], 3.0, &mut out);
        let [a, b, c] = [0.3, 1.5, 2.7].map(|x| encode_range(x, 3.0));
        assert_eq!(out, [a, b, b, b, c]);
        // Beams outside the 270-degree field are not used: a 360-degree lidar of 5 beams
        // (-180, -90, 0, 90, 180) in one sector sees only the 3 inside.
        let wide = Lidar::new(LidarConfig {
            beams: 5,
            fov_deg: 360.0,
            ..LidarConfig::default()
        });
        let r = LaserResampler::new(LaserLayout::Sectors(1), wide.angles());
        let mut out = [f32::NAN; 1];
        r.write(&[0.2, 1.0, 2.0, 1.5, 0.1], 3.0, &mut out);
        assert_eq!(out, [encode_range(1.0, 3.0)]);
    }

    #[test]
    fn a_scan_of_the_layouts_own_beams_passes_unchanged_and_others_take_the_nearest_beam() {
        let ranges: Vec<f64> = (0..LASER_BEAMS)
            .map(|k| 0.1 + (k as f64 * 0.37).sin().abs() * 2.9)
            .collect();
        let direct: Vec<f32> = ranges.iter().map(|&r| encode_range(r, 3.0)).collect();
        let mut out = vec![f32::NAN; LASER_BEAMS];
        resampler(LaserLayout::Scan, LASER_BEAMS).write(&ranges, 3.0, &mut out);
        assert_eq!(
            out.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            direct.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
        // 360 beams over the same field: layout beam k is at fraction k/719 of it, beam j of the
        // sensor at j/359, so the nearest is j = round(k * 359/719) (no ties: 719 is odd).
        let ranges: Vec<f64> = (0..360).map(|j| 0.1 + j as f64 * 0.008).collect();
        resampler(LaserLayout::Scan, 360).write(&ranges, 3.0, &mut out);
        for (k, &x) in out.iter().enumerate() {
            let j = (k as f64 * 359.0 / 719.0).round() as usize;
            assert_eq!(x, encode_range(ranges[j], 3.0), "layout beam {k}");
        }
        // A sectors layout of 720 sectors on the 720-beam scan is the scan itself.
        let ranges: Vec<f64> = (0..LASER_BEAMS).map(|k| 0.2 + k as f64 * 0.004).collect();
        let mut sectors = vec![f32::NAN; LASER_BEAMS];
        resampler(LaserLayout::Sectors(LASER_BEAMS), LASER_BEAMS).write(&ranges, 3.0, &mut sectors);
        resampler(LaserLayout::Scan, LASER_BEAMS).write(&ranges, 3.0, &mut out);
        assert_eq!(sectors, out);
    }
}
