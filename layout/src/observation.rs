//! The observation vector's segments and size.
//!
//! One observation is `obs_dim(laser, act_dim, k) = L + act_dim + 6 + 4 k` floats: the laser
//! segment (`L` = [`LaserLayout::size`]), the previous action, v, w, the local and the global
//! goal, and, when `k > 0`, the `k` nearest moving tracks ([`segments`] gives the offsets).

use crate::laser::{LaserLayout, LASER_BEAMS};

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
    /// How the segment's values are computed from the robot's state and sensors, for the
    /// laser layout `laser` with ranges clipped at `laser_clip_m`: the `encoding` the exported
    /// policy card states.
    pub fn encoding(&self, laser: LaserLayout, laser_clip_m: f64) -> String {
        match (self.name, laser) {
            ("laser", LaserLayout::Scan) => format!(
                "lidar ranges r (m) in beam order, beam k at -135 + k * 270/{} degrees from the \
                 heading (counter-clockwise positive); x = 2 * min(r, {laser_clip_m}) / \
                 {laser_clip_m} - 1, in [-1, 1]",
                LASER_BEAMS - 1
            ),
            ("laser", LaserLayout::Sectors(n)) => format!(
                "the 270-degree field split into {n} equal sectors, sector i spanning -135 + i * \
                 270/{n} to -135 + (i + 1) * 270/{n} degrees from the heading (counter-clockwise \
                 positive); r (m) is the least lidar range of the beams in the sector (a sector \
                 without a beam takes the beam nearest its centre); x = 2 * min(r, \
                 {laser_clip_m}) / {laser_clip_m} - 1, in [-1, 1]"
            ),
            (name, _) => self.state_encoding(name),
        }
    }

    /// The encoding of a segment other than the laser's.
    fn state_encoding(&self, name: &str) -> String {
        match name {
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

/// The observation segments of the laser layout `laser` and an action of `act_dim` values with
/// `tracks` observed tracks, in order, contiguous from offset 0 (the `tracks` segment only when
/// `tracks > 0`).
pub fn segments(laser: LaserLayout, act_dim: usize, tracks: usize) -> Vec<Segment> {
    let sizes = [laser.size(), act_dim, 1, 1, 2, 2, TRACK_FLOATS * tracks];
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

/// Length of an observation for the laser layout `laser` and an action of `act_dim` values with
/// `tracks` observed tracks: `laser.size() + act_dim + 6 + 4 tracks` (730 for the `scan`
/// layout and the 4-value decremental action without tracks; 35 for `sectors:25`).
pub fn obs_dim(laser: LaserLayout, act_dim: usize, tracks: usize) -> usize {
    laser.size() + act_dim + STATE_TAIL + TRACK_FLOATS * tracks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_are_contiguous_and_sum_to_obs_dim() {
        for laser in [LaserLayout::Scan, LaserLayout::Sectors(25)] {
            for act_dim in [2, 4, 20] {
                for tracks in [0, 4] {
                    let segs = segments(laser, act_dim, tracks);
                    let mut offset = 0;
                    for s in &segs {
                        assert_eq!(s.offset, offset, "{laser} {act_dim} {}", s.name);
                        offset += s.size;
                    }
                    assert_eq!(offset, obs_dim(laser, act_dim, tracks));
                    assert_eq!((segs[0].size, segs[1].size), (laser.size(), act_dim));
                    assert_eq!(segs.len(), if tracks > 0 { 7 } else { 6 });
                }
            }
        }
        assert_eq!(obs_dim(LaserLayout::Scan, 4, 0), 730);
        assert_eq!(obs_dim(LaserLayout::Sectors(25), 4, 0), 35);
    }
}
