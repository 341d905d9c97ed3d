//! How planners predict the robot: the integrator of their rollouts and how the footprint is
//! collision-checked at the rollout's grid points.
//!
//! The papers' planners (the authors' C++ DWA, MPPI and DDP) integrate a unicycle with
//! forward Euler at each step of the schedule (heading first, then position along the new
//! heading) and check the footprint only at the grid points t_i, with the DDP check density
//! N_t: what lies between two grid points, or between two checked boundary points, is not
//! seen. That is the fidelity/computation trade-off DDP and ADP tune. [`Prediction::PAPERS`]
//! is that model; [`Prediction::IDEAL`] keeps the exact arcs and conservative clearance bounds
//! of the `ideal` simulator profile, where the robot does exactly what is predicted.

use serde::{Deserialize, Serialize};
use sim::geometry::{wrap_angle, Pose};
use sim::robot::{integrate_arc, Twist};
use sim::Profile;

/// How a rollout step moves the pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// The exact arc of constant (v, w) over the step.
    ExactArc,
    /// Forward Euler: yaw += w dt, then x += v cos(yaw) dt, y += v sin(yaw) dt.
    Euler,
}

/// How the footprint check at a grid point estimates clearance.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CheckMode {
    /// A lower bound: the circumscribed disk, tightened by the checked boundary points minus
    /// half the gap between them. Never misses an obstacle at a grid point.
    Conservative,
    /// Only what is checked counts: the inscribed disk around the centre and the checked
    /// boundary points; unchecked parts of the footprint are assumed free (optimistic), as in
    /// DDP.
    GridPoints,
}

/// A planner's model of the robot for rollouts. Plain data; `Copy`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Prediction {
    /// The rollout integrator.
    pub integrator: Integrator,
    /// The collision check at grid points.
    pub checks: CheckMode,
}

impl Prediction {
    /// Exact arcs and conservative checks (the `ideal` profile).
    pub const IDEAL: Prediction = Prediction {
        integrator: Integrator::ExactArc,
        checks: CheckMode::Conservative,
    };

    /// The papers' planners: forward Euler, checks at grid points only.
    pub const PAPERS: Prediction = Prediction {
        integrator: Integrator::Euler,
        checks: CheckMode::GridPoints,
    };

    /// The model planners use under a simulator profile.
    pub fn for_profile(profile: Profile) -> Prediction {
        match profile {
            Profile::Ideal => Prediction::IDEAL,
            Profile::GazeboJackal | Profile::Custom => Prediction::PAPERS,
        }
    }
}

impl Integrator {
    /// The pose after moving with velocity `vel` for `dt` seconds (heading wrapped).
    #[inline]
    pub fn step_pose(self, p: Pose, vel: Twist, dt: f64) -> Pose {
        match self {
            Integrator::ExactArc => integrate_arc(p, vel, dt),
            Integrator::Euler => {
                let yaw = p.yaw + vel.w * dt;
                let (s, c) = yaw.sin_cos();
                Pose::new(p.x + vel.v * dt * c, p.y + vel.v * dt * s, wrap_angle(yaw))
            }
        }
    }

    /// [`Integrator::step_pose`] with the heading's `(sin, cos)` carried along: `sc` holds
    /// those of `p.yaw` and becomes those of the returned pose's (wrapped) yaw. The pose is the
    /// same, bit for bit (`sin_cos` is `sin` and `cos`, and the wrapped yaw is the integrated one
    /// unless it crossed +-pi), with one `sin_cos` per step where the rollout and its collision
    /// check used up to four trigonometric calls.
    #[inline]
    pub fn step_pose_carried(self, p: Pose, sc: &mut (f64, f64), vel: Twist, dt: f64) -> Pose {
        let (yaw, (s1, c1), next) = match self {
            Integrator::ExactArc => {
                let dyaw = vel.w * dt;
                if dyaw.abs() < 1e-9 {
                    // The heading does not change: neither does `sc`.
                    return Pose::new(p.x + vel.v * dt * sc.1, p.y + vel.v * dt * sc.0, p.yaw);
                }
                let r = vel.v / vel.w;
                let yaw1 = p.yaw + dyaw;
                let (s1, c1) = yaw1.sin_cos();
                let next = Pose::new(p.x + r * (s1 - sc.0), p.y - r * (c1 - sc.1), wrap_angle(yaw1));
                (yaw1, (s1, c1), next)
            }
            Integrator::Euler => {
                let yaw = p.yaw + vel.w * dt;
                let (s, c) = yaw.sin_cos();
                let next = Pose::new(p.x + vel.v * dt * c, p.y + vel.v * dt * s, wrap_angle(yaw));
                (yaw, (s, c), next)
            }
        };
        *sc = if next.yaw == yaw {
            (s1, c1)
        } else {
            next.yaw.sin_cos()
        };
        next
    }

    /// Moves a pose (heading not wrapped) with forward speed `v` and yaw rate `w` for `dt`
    /// seconds; `sc` holds (sin, cos) of the heading before the step and is updated to the
    /// heading after it (so rollouts compute one `sin_cos` per step).
    #[inline]
    pub fn advance(self, pose: &mut Pose, sc: &mut (f64, f64), v: f64, w: f64, dt: f64) {
        pose.yaw += w * dt;
        let (s1, c1) = pose.yaw.sin_cos();
        match self {
            Integrator::Euler => {
                pose.x += v * dt * c1;
                pose.y += v * dt * s1;
            }
            Integrator::ExactArc => {
                if (w * dt).abs() > 1e-9 {
                    pose.x += v / w * (s1 - sc.0);
                    pose.y -= v / w * (c1 - sc.1);
                } else {
                    pose.x += v * dt * sc.1;
                    pose.y += v * dt * sc.0;
                }
            }
        }
        *sc = (s1, c1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::local_map::LocalMap;
    use crate::Schedule;
    use sim::geometry::{Footprint, Vec2};

    fn end_point(integrator: Integrator, v: f64, w: f64, dt: f64, steps: usize) -> Pose {
        let mut p = Pose::default();
        let mut sc = (0.0, 1.0);
        for _ in 0..steps {
            integrator.advance(&mut p, &mut sc, v, w, dt);
        }
        p
    }

    /// Carrying the heading's (sin, cos) gives the poses of `step_pose` bit for bit, through
    /// turns that cross +-pi and straight steps, and `sc` stays the (sin, cos) of the yaw.
    #[test]
    fn carried_heading_steps_are_the_plain_steps() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        for integrator in [Integrator::ExactArc, Integrator::Euler] {
            for _ in 0..200 {
                let start = Pose::new(
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-2.0..2.0),
                    rng.random_range(-3.1..3.1),
                );
                let (mut a, mut b) = (start, start);
                let mut sc = start.yaw.sin_cos();
                for _ in 0..60 {
                    let w = if rng.random_bool(0.2) {
                        0.0
                    } else {
                        rng.random_range(-2.5..2.5)
                    };
                    let vel = Twist::new(rng.random_range(0.0..2.0), w);
                    let dt = rng.random_range(0.02..0.2);
                    a = integrator.step_pose(a, vel, dt);
                    b = integrator.step_pose_carried(b, &mut sc, vel, dt);
                    assert_eq!(
                        (a.x.to_bits(), a.y.to_bits(), a.yaw.to_bits()),
                        (b.x.to_bits(), b.y.to_bits(), b.yaw.to_bits())
                    );
                    assert_eq!(sc, b.yaw.sin_cos());
                }
            }
        }
    }

    #[test]
    fn euler_one_step_against_hand_computed_values() {
        // v = 1, w = 1, dt = 0.5 from the origin: Euler turns first, then moves 0.5 m along
        // heading 0.5 rad; the exact arc ends at (sin 0.5, 1 - cos 0.5).
        let e = end_point(Integrator::Euler, 1.0, 1.0, 0.5, 1);
        assert!(
            (e.x - 0.438_791).abs() < 1e-6 && (e.y - 0.239_713).abs() < 1e-6,
            "{e:?}"
        );
        let a = end_point(Integrator::ExactArc, 1.0, 1.0, 0.5, 1);
        assert!(
            (a.x - 0.479_426).abs() < 1e-6 && (a.y - 0.122_417).abs() < 1e-6,
            "{a:?}"
        );
        assert!((e.yaw - 0.5).abs() < 1e-15 && (a.yaw - 0.5).abs() < 1e-15);
        let err = (e.x - a.x).hypot(e.y - a.y);
        assert!((err - 0.124_136).abs() < 1e-5, "{err}");
    }

    #[test]
    fn euler_error_grows_with_the_step_on_a_known_turn() {
        // A 2 s turn at v = 1.5 m/s, w = 1.2 rad/s: the exact arc is the same for any step.
        let exact = end_point(Integrator::ExactArc, 1.5, 1.2, 2.0 / 80.0, 80);
        let r = 1.5 / 1.2;
        assert!((exact.x - r * 2.4f64.sin()).abs() < 1e-9);
        assert!((exact.y - r * (1.0 - 2.4f64.cos())).abs() < 1e-9);
        let errors: Vec<f64> = [80, 40, 20, 10, 5]
            .iter()
            .map(|&n| {
                let e = end_point(Integrator::Euler, 1.5, 1.2, 2.0 / n as f64, n);
                (e.x - exact.x).hypot(e.y - exact.y)
            })
            .collect();
        assert!(errors.windows(2).all(|w| w[1] > w[0]), "{errors:?}");
        // First order: halving the step about halves the error.
        assert!((errors[0] / errors[1] - 0.5).abs() < 0.05, "{errors:?}");
        assert!(
            errors[4] > 0.3,
            "a 0.4 s step misplaces the end by {} m",
            errors[4]
        );
    }

    /// Whether a straight rollout at `v` over `schedule` passes every grid-point check.
    fn straight_rollout_is_free(map: &LocalMap, schedule: &Schedule, v: f64) -> bool {
        let mut pose = Pose::default();
        let mut sc = (0.0, 1.0);
        let mut evaluated = 0;
        schedule.dts().iter().zip(schedule.checks()).all(|(&dt, &m)| {
            Integrator::Euler.advance(&mut pose, &mut sc, v, 0.0, dt);
            map.footprint_clearance(&pose, m as usize, 0.1, &mut evaluated) > 0.0
        })
    }

    #[test]
    fn a_thin_cylinder_between_coarse_grid_points_is_missed_and_a_fine_grid_catches_it() {
        // A 0.15 m cylinder 1.0 m ahead, seen by the lidar as points on its near half.
        let c = Vec2::new(1.0, 0.0);
        let pts: Vec<Vec2> = (0..12)
            .map(|k| {
                let a = std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * k as f64 / 11.0;
                c + Vec2::new(a.cos(), a.sin()) * 0.075
            })
            .collect();
        let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 20);
        map.build(&pts, 1.0, 3.0);
        map.set_check_mode(CheckMode::GridPoints);
        // Driving at 2 m/s for 1.4 s: with 0.7 s steps the footprint is checked at 1.4 m and
        // 2.8 m, past the cylinder; with 0.05 s steps it is checked every 0.1 m.
        let coarse = Schedule::uniform(0.7, 2, 20).unwrap();
        let fine = Schedule::uniform(0.05, 28, 20).unwrap();
        assert!(
            straight_rollout_is_free(&map, &coarse, 2.0),
            "coarse grid misses it"
        );
        assert!(
            !straight_rollout_is_free(&map, &fine, 2.0),
            "fine grid catches it"
        );
    }

    #[test]
    fn grid_point_checks_see_only_the_checked_boundary_points() {
        // An obstacle 0.016 m off the front face, 0.12 m left of the centre line.
        let pts = [
            Vec2::new(0.27, 0.12),
            Vec2::new(0.27, 0.11),
            Vec2::new(0.27, 0.13),
        ];
        let mut map = LocalMap::new(Footprint::JACKAL, 0.02, 20);
        map.build(&pts, 1.0, 2.0);
        let pose = Pose::default();
        let mut n = 0;
        map.set_check_mode(CheckMode::GridPoints);
        let fine = map.footprint_clearance(&pose, 20, 1.0, &mut n);
        let coarse = map.footprint_clearance(&pose, 4, 1.0, &mut n);
        let centre_only = map.footprint_clearance(&pose, 0, 1.0, &mut n);
        assert!(fine < 0.02, "a front-face point is next to it: {fine}");
        // The 4 points sit near the corners and the inscribed disk ends 0.08 m short of it:
        // the coarse check reports several times the true 0.016 m.
        assert!(coarse > 0.04, "4 points do not see it: {coarse}");
        let disk = 0.27f64.hypot(0.12) - 0.215;
        assert!(
            (centre_only - disk).abs() < 0.03,
            "inscribed disk: {centre_only} vs {disk}"
        );
        // The conservative bound never claims more clearance than there is.
        map.set_check_mode(CheckMode::Conservative);
        for m in [0, 4, 20] {
            assert!(
                map.footprint_clearance(&pose, m, 1.0, &mut n) <= 0.016 + 0.02,
                "m = {m}"
            );
        }
    }

    #[test]
    fn profiles_map_to_models() {
        assert_eq!(Prediction::for_profile(Profile::Ideal), Prediction::IDEAL);
        assert_eq!(Prediction::for_profile(Profile::GazeboJackal), Prediction::PAPERS);
        assert_eq!(Prediction::for_profile(Profile::Custom), Prediction::PAPERS);
    }
}
