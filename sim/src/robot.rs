//! Jackal differential-drive kinematics with velocity and acceleration limits.

use serde::{Deserialize, Serialize};

use crate::geometry::{wrap_angle, Footprint, Pose};

/// Physical limits of the robot (the simulator's controller values for the Jackal).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotLimits {
    /// Largest forward speed (m/s).
    pub max_v: f64,
    /// Largest reverse speed, as a positive number (m/s).
    pub max_reverse_v: f64,
    /// Largest yaw rate magnitude (rad/s).
    pub max_w: f64,
    /// Linear acceleration limit (m/s^2).
    pub accel_v: f64,
    /// Angular acceleration limit (rad/s^2).
    pub accel_w: f64,
    /// Footprint used for collisions.
    pub footprint: Footprint,
}

impl RobotLimits {
    /// The Clearpath Jackal: v <= 2 m/s, |w| <= 4 rad/s, 20 m/s^2, 25 rad/s^2.
    pub const JACKAL: RobotLimits = RobotLimits {
        max_v: 2.0,
        max_reverse_v: 2.0,
        max_w: 4.0,
        accel_v: 20.0,
        accel_w: 25.0,
        footprint: Footprint::JACKAL,
    };
}

/// A velocity command or a measured velocity: forward speed and yaw rate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Forward speed (m/s).
    pub v: f64,
    /// Yaw rate (rad/s).
    pub w: f64,
}

impl Twist {
    /// Builds a twist.
    pub const fn new(v: f64, w: f64) -> Self {
        Self { v, w }
    }
}

/// Full robot state: pose and current velocity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RobotState {
    /// Pose in the world frame.
    pub pose: Pose,
    /// Current velocity.
    pub vel: Twist,
}

/// Moves `current` toward `target` by at most `max_step`.
pub fn approach(current: f64, target: f64, max_step: f64) -> f64 {
    current + (target - current).clamp(-max_step, max_step)
}

impl RobotState {
    /// Advances the state by `dt` seconds under command `cmd`: the velocity moves toward the
    /// (limit-clamped) command at the acceleration limits, then the unicycle is integrated
    /// with the exact arc for constant (v, w) over the step.
    pub fn step(&mut self, limits: &RobotLimits, cmd: Twist, dt: f64) {
        let target_v = cmd.v.clamp(-limits.max_reverse_v, limits.max_v);
        let target_w = cmd.w.clamp(-limits.max_w, limits.max_w);
        self.vel.v = approach(self.vel.v, target_v, limits.accel_v * dt);
        self.vel.w = approach(self.vel.w, target_w, limits.accel_w * dt);
        self.pose = integrate_arc(self.pose, self.vel, dt);
    }
}

/// Exact pose after moving with constant (v, w) for `dt` seconds.
pub fn integrate_arc(p: Pose, vel: Twist, dt: f64) -> Pose {
    let dyaw = vel.w * dt;
    if dyaw.abs() < 1e-9 {
        let (s, c) = p.yaw.sin_cos();
        return Pose::new(p.x + vel.v * dt * c, p.y + vel.v * dt * s, p.yaw);
    }
    let r = vel.v / vel.w;
    let yaw1 = p.yaw + dyaw;
    Pose::new(
        p.x + r * (yaw1.sin() - p.yaw.sin()),
        p.y - r * (yaw1.cos() - p.yaw.cos()),
        wrap_angle(yaw1),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_misspelt_limit_is_refused_by_name() {
        let good = toml::to_string(&RobotLimits::JACKAL).unwrap();
        let back: RobotLimits = toml::from_str(&good).unwrap();
        assert_eq!(back, RobotLimits::JACKAL);
        let typo = good.replace("max_w =", "max_yaw_rate =");
        let err = toml::from_str::<RobotLimits>(&typo).unwrap_err().to_string();
        assert!(err.contains("max_yaw_rate"), "{err}");
    }

    #[test]
    fn acceleration_limits_are_respected() {
        let mut s = RobotState::default();
        s.step(&RobotLimits::JACKAL, Twist::new(2.0, 4.0), 0.01);
        assert!((s.vel.v - 0.2).abs() < 1e-12);
        assert!((s.vel.w - 0.25).abs() < 1e-12);
        for _ in 0..100 {
            s.step(&RobotLimits::JACKAL, Twist::new(5.0, -9.0), 0.01);
        }
        assert_eq!(s.vel, Twist::new(2.0, -4.0));
    }

    #[test]
    fn arc_integration_closes_a_circle() {
        // v = 1, w = 1 for 2*pi seconds: back to the start.
        let mut p = Pose::new(1.0, 2.0, 0.3);
        for _ in 0..628 {
            p = integrate_arc(p, Twist::new(1.0, 1.0), std::f64::consts::TAU / 628.0);
        }
        assert!((p.x - 1.0).abs() < 1e-9 && (p.y - 2.0).abs() < 1e-9);
        let straight = integrate_arc(
            Pose::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            Twist::new(2.0, 0.0),
            0.5,
        );
        assert!(straight.x.abs() < 1e-12 && (straight.y - 1.0).abs() < 1e-12);
    }
}
