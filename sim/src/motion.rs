//! Moving obstacles: cylinders whose centre follows a looped keyframe trajectory, interpolated
//! the way Gazebo's `PoseAnimation` moves a model (the DynaBARN worlds, see
//! `sim/data/dynabarn/README.md`).
//!
//! The position at a time τ on the animation clock:
//! 1. τ is wrapped into one loop, τ mod `period` (the animation loops; at the wrap the obstacle
//!    jumps back to its first keyframe);
//! 2. the segment is found as Gazebo does: the first keyframe whose time is at or after τ is
//!    k₂; when τ equals its time exactly the position is that keyframe's, otherwise the segment
//!    runs from the keyframe before it, k₁ = k₂ - 1, and s = (τ - t₁) / (t₂ - t₁);
//! 3. s within 1e-6 of 0 or 1 gives the keyframe itself; otherwise the position is the cubic
//!    Hermite curve p(s) = h₀₀ p₁ + h₁₀ m₁ + h₀₁ p₂ + h₁₁ m₂ (h₀₀ = 2s³ - 3s² + 1,
//!    h₁₀ = s³ - 2s² + s, h₀₁ = -2s³ + 3s², h₁₁ = s³ - s²) with Catmull-Rom tangents of tension
//!    0 in keyframe-index units: m_i = (p_{i+1} - p_{i-1}) / 2 inside; at the ends
//!    m₀ = (p₁ - p₀) / 2 and m_last = (p_last - p_{last-1}) / 2, unless the first and last
//!    keyframes coincide within 1 mm per coordinate (a closed curve), when
//!    m₀ = m_last = (p₁ - p_{last-1}) / 2.

use crate::geometry::{Circle, Vec2};

/// Tolerance of Gazebo's scalar comparisons (`math::equal`).
const EQUAL_EPS: f64 = 1e-6;
/// Tolerance of Gazebo's vector comparison that decides whether a curve is closed.
const CLOSED_EPS: f64 = 1e-3;

/// Why a keyframe list cannot make a trajectory (the message names the keyframe at fault).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TrajectoryError {
    /// Fewer than two keyframes.
    #[error("needs at least 2 keyframes, got {0}")]
    TooFew(usize),
    /// A keyframe with a non-finite value.
    #[error("keyframe {index} = {key:?} is not finite")]
    NotFinite {
        /// Index of the keyframe.
        index: usize,
        /// Its (t, x, y).
        key: [f64; 3],
    },
    /// The first keyframe is not at t = 0.
    #[error("the first keyframe is at t = {0}, not 0")]
    FirstTime(f64),
    /// A keyframe earlier than the one before it.
    #[error("keyframe {index} at t = {t} is earlier than the one before it")]
    Decreasing {
        /// Index of the keyframe.
        index: usize,
        /// Its time (s).
        t: f64,
    },
    /// The loop's period differs from the last keyframe's time, or is not positive.
    #[error("period {period} s must be positive and equal the last keyframe's time {last} s")]
    Period {
        /// The period given (s).
        period: f64,
        /// The last keyframe's time (s).
        last: f64,
    },
}

/// A looped keyframe trajectory of a point in the plane.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    period: f64,
    times: Vec<f64>,
    points: Vec<Vec2>,
    tangents: Vec<Vec2>,
}

impl Trajectory {
    /// Builds the trajectory from keyframes `[t, x, y]` (times from 0, non-decreasing, the
    /// last one equal to `period`, the loop's length in seconds).
    pub fn new(keyframes: &[[f64; 3]], period: f64) -> Result<Self, TrajectoryError> {
        let n = keyframes.len();
        if n < 2 {
            return Err(TrajectoryError::TooFew(n));
        }
        for (index, key) in keyframes.iter().enumerate() {
            if !key.iter().all(|v| v.is_finite()) {
                return Err(TrajectoryError::NotFinite { index, key: *key });
            }
            if index > 0 && key[0] < keyframes[index - 1][0] {
                return Err(TrajectoryError::Decreasing { index, t: key[0] });
            }
        }
        if keyframes[0][0] != 0.0 {
            return Err(TrajectoryError::FirstTime(keyframes[0][0]));
        }
        let last = keyframes[n - 1][0];
        if !(period > 0.0 && period == last) {
            return Err(TrajectoryError::Period { period, last });
        }
        let times = keyframes.iter().map(|k| k[0]).collect();
        let points: Vec<Vec2> = keyframes.iter().map(|k| Vec2::new(k[1], k[2])).collect();
        let (first, end) = (points[0], points[n - 1]);
        let closed = (first.x - end.x).abs() <= CLOSED_EPS && (first.y - end.y).abs() <= CLOSED_EPS;
        let tangents = (0..n)
            .map(|i| {
                let (before, after) = match i {
                    0 if closed => (points[n - 2], points[1]),
                    0 => (points[0], points[1]),
                    _ if i == n - 1 && closed => (points[n - 2], points[1]),
                    _ if i == n - 1 => (points[n - 2], points[n - 1]),
                    _ => (points[i - 1], points[i + 1]),
                };
                (after - before) * 0.5
            })
            .collect();
        Ok(Self {
            period,
            times,
            points,
            tangents,
        })
    }

    /// The loop's length (s).
    pub fn period(&self) -> f64 {
        self.period
    }

    /// The keyframe positions, in time order.
    pub fn keyframes(&self) -> &[Vec2] {
        &self.points
    }

    /// The position at time `t` (s) of the animation clock (any real `t`; it loops).
    pub fn position(&self, t: f64) -> Vec2 {
        let tau = t.rem_euclid(self.period);
        // `rem_euclid` can round up to the period itself for a tiny negative `t`.
        let tau = if tau >= self.period { 0.0 } else { tau };
        let k2 = self.times.partition_point(|&k| k < tau);
        if k2 == 0 || self.times[k2] == tau {
            return self.points[k2];
        }
        let k1 = k2 - 1;
        let (t1, t2) = (self.times[k1], self.times[k2]);
        if (t2 - t1).abs() <= EQUAL_EPS {
            return self.points[k1];
        }
        let s = (tau - t1) / (t2 - t1);
        if s.abs() <= EQUAL_EPS {
            return self.points[k1];
        }
        if (s - 1.0).abs() <= EQUAL_EPS {
            return self.points[k2];
        }
        let (s2, s3) = (s * s, s * s * s);
        let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
        let h10 = s3 - 2.0 * s2 + s;
        let h01 = -2.0 * s3 + 3.0 * s2;
        let h11 = s3 - s2;
        self.points[k1] * h00 + self.tangents[k1] * h10 + self.points[k2] * h01 + self.tangents[k2] * h11
    }
}

/// A cylinder of fixed radius whose centre follows a [`Trajectory`].
#[derive(Clone, Debug, PartialEq)]
pub struct MovingCylinder {
    /// Radius (m).
    pub radius: f64,
    /// Where its centre is over time.
    pub trajectory: Trajectory,
}

impl MovingCylinder {
    /// The cylinder at time `t` (s) of the animation clock.
    pub fn at(&self, t: f64) -> Circle {
        Circle {
            c: self.trajectory.position(t),
            r: self.radius,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec2, b: Vec2) -> bool {
        (a.x - b.x).abs() < 1e-12 && (a.y - b.y).abs() < 1e-12
    }

    /// World 300's second obstacle (`easylibobs_110`): 8 keyframes on a straight line,
    /// period 39.05 s.
    fn obstacle_110() -> Trajectory {
        let keys = [
            [0.0, 10.0, 8.0],
            [5.79, 7.78, 5.33],
            [11.57, 5.56, 2.67],
            [17.36, 3.33, 0.0],
            [23.14, 1.11, -2.67],
            [28.93, -1.11, -5.33],
            [34.71, -3.33, -8.0],
            [39.05, -5.0, -10.0],
        ];
        Trajectory::new(&keys, 39.05).unwrap()
    }

    #[test]
    fn interpolation_matches_hand_computation() {
        let tr = obstacle_110();
        // At keyframe times the position is the keyframe.
        assert_eq!(tr.position(0.0), Vec2::new(10.0, 8.0));
        assert_eq!(tr.position(17.36), Vec2::new(3.33, 0.0));
        // Halfway through segment 2 -> 3 (t = 14.465 s, s = 0.5): the Hermite weights are
        // h00 = h01 = 0.5, h10 = 0.125, h11 = -0.125, with tangents
        // m2 = (p3 - p1) / 2 = (-2.225, -2.665) and m3 = (p4 - p2) / 2 = (-2.225, -2.67):
        // x = 0.5 (5.56 + 3.33) + 0.125 (-2.225 + 2.225) = 4.445,
        // y = 0.5 (2.67 + 0) + 0.125 (-2.665 + 2.67) = 1.335625.
        let mid = tr.position((11.57 + 17.36) / 2.0);
        assert!(close(mid, Vec2::new(4.445, 1.335625)), "{mid:?}");
        // A quarter into the first segment (s = 0.25, t = 1.4475 s): the start tangent is
        // m0 = (p1 - p0) / 2 = (-1.11, -1.335), m1 = (p2 - p0) / 2 = (-2.22, -2.665);
        // h00 = 0.84375, h10 = 0.140625, h01 = 0.15625, h11 = -0.046875:
        // x = 0.84375 * 10 + 0.140625 * -1.11 + 0.15625 * 7.78 - 0.046875 * -2.22
        //   = 8.4375 - 0.15609375 + 1.215625 + 0.1040625 = 9.60109375,
        // y = 0.84375 * 8 + 0.140625 * -1.335 + 0.15625 * 5.33 - 0.046875 * -2.665
        //   = 6.75 - 0.187734375 + 0.8328125 + 0.124921875 = 7.52.
        let q = tr.position(5.79 * 0.25);
        assert!(close(q, Vec2::new(9.60109375, 7.52)), "{q:?}");
    }

    #[test]
    fn the_loop_wraps_and_jumps_back() {
        let tr = obstacle_110();
        // One period later, the same place; just before the wrap near the last keyframe,
        // at the wrap the first keyframe again.
        let a = tr.position(14.465);
        let b = tr.position(14.465 + 39.05);
        assert!(close(a, b) || a.dist(b) < 1e-9, "{a:?} vs {b:?}");
        assert!(tr.position(39.049).dist(Vec2::new(-5.0, -10.0)) < 0.01);
        assert_eq!(tr.position(39.05), Vec2::new(10.0, 8.0));
        assert_eq!(tr.position(2.0 * 39.05), Vec2::new(10.0, 8.0));
        // Negative times run the loop backwards.
        assert!(tr.position(-39.05 + 17.36).dist(Vec2::new(3.33, 0.0)) < 1e-9);
    }

    #[test]
    fn closed_curves_share_the_wrap_tangent() {
        // A unit-square loop, p4 = p0: m0 = m4 = (p1 - p3) / 2 = ((1, 0) - (0, 1)) / 2 = (0.5, -0.5).
        let keys = [
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [2.0, 1.0, 1.0],
            [3.0, 0.0, 1.0],
            [4.0, 0.0, 0.0],
        ];
        let tr = Trajectory::new(&keys, 4.0).unwrap();
        // s = 0.5 in segment 0: 0.5 p0 + 0.5 p1 + 0.125 (m0 - m1), m0 = (0.5, -0.5),
        // m1 = (p2 - p0) / 2 = (0.5, 0.5): (0.5, 0) + 0.125 (0, -1) = (0.5, -0.125).
        assert!(close(tr.position(0.5), Vec2::new(0.5, -0.125)));
        // The last segment ends with the same tangent: s = 0.5 in segment 3,
        // 0.5 p3 + 0.5 p4 + 0.125 (m3 - m4), m3 = (p4 - p2) / 2 = (-0.5, -0.5):
        // (0, 0.5) + 0.125 (-1, 0) = (-0.125, 0.5).
        assert!(close(tr.position(3.5), Vec2::new(-0.125, 0.5)));
    }

    #[test]
    fn bad_keyframes_are_named() {
        let e = Trajectory::new(&[[0.0, 0.0, 0.0], [2.0, 1.0, 1.0], [1.0, 0.0, 0.0]], 1.0)
            .unwrap_err()
            .to_string();
        assert_eq!(e, "keyframe 2 at t = 1 is earlier than the one before it");
        let e = Trajectory::new(&[[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]], 3.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("period 3 s"), "{e}");
        assert_eq!(
            Trajectory::new(&[[0.5, 0.0, 0.0], [2.0, 1.0, 1.0]], 2.0).unwrap_err(),
            TrajectoryError::FirstTime(0.5)
        );
        assert_eq!(
            Trajectory::new(&[[0.0, 0.0, 0.0]], 2.0).unwrap_err(),
            TrajectoryError::TooFew(1)
        );
        assert!(matches!(
            Trajectory::new(&[[0.0, f64::NAN, 0.0], [1.0, 0.0, 0.0]], 1.0),
            Err(TrajectoryError::NotFinite { index: 0, .. })
        ));
    }
}
