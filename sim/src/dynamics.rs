//! The robot's true response to velocity commands, which is not what the planners predict.
//!
//! Planners roll out a unicycle that reaches a commanded velocity at the controller's nominal
//! accelerations (20 m/s^2, 25 rad/s^2). A real Jackal, and its Gazebo model, does not: the
//! wheels track the command through a velocity loop (a first-order lag) bounded by what the
//! motors and tyre friction deliver, a skid-steer base turns less than its wheels ask for
//! (more so at speed and in tight turns), commands arrive a sense -> plan -> act latency after
//! the scan they were planned on, and the pose the robot believes in drifts from the truth as
//! it drives. [`Dynamics`] holds those parameters (each documented with its source);
//! [`Profile`] names the presets (both are plain settings of `settings::dynamics`, re-exported
//! here); [`Drive`] applies them to a [`RobotState`] one physics step at a time.
//!
//! Everything is deterministic: the only random draws (localization drift) come from the
//! episode's seed, on a stream separate from the sensor noise.

use std::collections::VecDeque;

use rand::Rng;
use rand_distr::StandardNormal;

pub use settings::dynamics::{Dynamics, Profile};

use crate::geometry::{wrap_angle, Pose, Vec2};
use crate::robot::{integrate_arc, RobotLimits, RobotState, Twist};

/// The share of [`Dynamics::gazebo_jackal`]'s latency that stands for the planning
/// computation itself (s): "half a 20 Hz planning period plus the planning itself (25 + ~25
/// ms)". When a compute model gives each cycle its own modelled compute time, the episode
/// replaces this share by that time ([`Drive::command_after`]), so planning is not counted
/// twice.
pub const PLANNING_LATENCY_S: f64 = 0.025;

/// The drive train between the planner's command and the robot's motion: latency queue,
/// wheel velocity loop, skid-steer slip. One per episode; stepping does not allocate once the
/// queue has reached its length (latency / physics step).
#[derive(Clone, Debug)]
pub struct Drive {
    dynamics: Dynamics,
    limits: RobotLimits,
    /// Physics steps between a command's issue and its effect.
    delay_ticks: u64,
    /// The physics step (s).
    physics_dt: f64,
    /// Physics steps taken.
    tick: u64,
    /// Commands waiting for their tick.
    queue: VecDeque<(u64, Twist)>,
    /// The command in effect.
    applied: Twist,
    /// Wheel-level velocity (what the wheels do, before the base slips).
    wheel: Twist,
}

impl Drive {
    /// A drive at rest for a physics step of `physics_dt` seconds.
    pub fn new(dynamics: Dynamics, limits: RobotLimits, physics_dt: f64) -> Self {
        let delay_ticks = (dynamics.latency_s / physics_dt).round() as u64;
        Self {
            dynamics,
            limits,
            delay_ticks,
            physics_dt,
            tick: 0,
            queue: VecDeque::with_capacity(delay_ticks as usize + 2),
            applied: Twist::default(),
            wheel: Twist::default(),
        }
    }

    /// The parameters.
    pub fn dynamics(&self) -> &Dynamics {
        &self.dynamics
    }

    /// Issues a command now; it takes effect after the latency.
    pub fn command(&mut self, cmd: Twist) {
        self.enqueue(cmd, self.delay_ticks);
    }

    /// Issues a command now that takes effect `compute_s` seconds of modelled planning
    /// after the profile's latency less its planning share ([`PLANNING_LATENCY_S`], at
    /// least 0), rounded to the physics step. Commands must be issued in order of their
    /// effect, which the episode drivers guarantee (a cycle starts after the previous one's
    /// compute ended).
    pub fn command_after(&mut self, cmd: Twist, compute_s: f64) {
        let latency = (self.dynamics.latency_s - PLANNING_LATENCY_S).max(0.0) + compute_s.max(0.0);
        self.enqueue(cmd, (latency / self.physics_dt).round() as u64);
    }

    /// Applies `cmd` now (`ticks` = 0) or queues it for `ticks` physics steps from now.
    fn enqueue(&mut self, cmd: Twist, ticks: u64) {
        if ticks == 0 {
            self.applied = cmd;
        } else {
            self.queue.push_back((self.tick + ticks, cmd));
        }
    }

    /// The command currently driving the wheels.
    pub fn applied(&self) -> Twist {
        self.applied
    }

    /// Advances `state` by one physics step of `dt` seconds.
    pub fn step(&mut self, state: &mut RobotState, dt: f64) {
        while let Some(&(due, cmd)) = self.queue.front() {
            if due > self.tick {
                break;
            }
            self.applied = cmd;
            self.queue.pop_front();
        }
        self.tick += 1;
        let d = &self.dynamics;
        let lim = &self.limits;
        let target_v = self.applied.v.clamp(-lim.max_reverse_v, lim.max_v);
        let target_w = self.applied.w.clamp(-lim.max_w, lim.max_w);
        let gain = if d.lag_s > 0.0 {
            1.0 - (-dt / d.lag_s).exp()
        } else {
            1.0
        };
        let v = self.wheel.v;
        let speeding_up = target_v * v >= 0.0 && target_v.abs() > v.abs();
        let max_dv = if speeding_up { d.accel_v } else { d.decel_v } * dt;
        self.wheel.v = v + ((target_v - v) * gain).clamp(-max_dv, max_dv);
        let w = self.wheel.w;
        let max_dw = d.accel_w * dt;
        self.wheel.w = w + ((target_w - w) * gain).clamp(-max_dw, max_dw);

        let slip = d.slip(self.wheel.v, self.wheel.w);
        state.vel = Twist::new(self.wheel.v, self.wheel.w * (1.0 - slip));
        let before = state.pose;
        state.pose = integrate_arc(before, state.vel, dt);
        if d.side_slip > 0.0 {
            let lateral = -d.side_slip * state.vel.v * state.vel.w * dt;
            let mid = before.yaw + 0.5 * state.vel.w * dt;
            state.pose.x -= lateral * mid.sin();
            state.pose.y += lateral * mid.cos();
        }
    }
}

/// The robot's belief about its own pose: the true pose plus a drift that random-walks with
/// the distance driven.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Localization {
    /// Heading error (rad).
    pub yaw: f64,
    /// Position error in the world frame (m).
    pub offset: Vec2,
}

impl Localization {
    /// Adds the drift of `distance` metres of driving.
    pub fn drift(&mut self, d: &Dynamics, distance: f64, rng: &mut impl Rng) {
        if distance <= 0.0 || (d.drift_yaw == 0.0 && d.drift_pos == 0.0) {
            return;
        }
        let s = distance.sqrt();
        let n: [f64; 3] = [
            rng.sample(StandardNormal),
            rng.sample(StandardNormal),
            rng.sample(StandardNormal),
        ];
        self.yaw += d.drift_yaw * s * n[0];
        self.offset = self.offset + Vec2::new(n[1], n[2]) * (d.drift_pos * s);
    }

    /// The believed pose for a true pose.
    pub fn estimate(&self, truth: &Pose) -> Pose {
        Pose::new(
            truth.x + self.offset.x,
            truth.y + self.offset.y,
            wrap_angle(truth.yaw + self.yaw),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(d: Dynamics) -> (Drive, RobotState) {
        (Drive::new(d, RobotLimits::JACKAL, 0.01), RobotState::default())
    }

    #[test]
    fn ideal_drive_is_the_old_kinematics() {
        // Same arithmetic as RobotState::step: the ideal profile changes nothing.
        let (mut dr, mut a) = drive(Dynamics::IDEAL);
        let mut b = RobotState::default();
        for k in 0..300 {
            let cmd = Twist::new(1.5 * ((k / 40) % 2) as f64, -2.0 + (k % 7) as f64 * 0.7);
            dr.command(cmd);
            dr.step(&mut a, 0.01);
            b.step(&RobotLimits::JACKAL, cmd, 0.01);
            assert_eq!(a, b, "step {k}");
        }
    }

    #[test]
    fn step_response_matches_the_closed_form() {
        // Lag only (acceleration limits out of reach): v(t) = 1 - exp(-t / tau) exactly at
        // the physics steps.
        let d = Dynamics {
            accel_v: 1e6,
            decel_v: 1e6,
            accel_w: 1e6,
            lag_s: 0.2,
            ..Dynamics::IDEAL
        };
        let (mut dr, mut s) = drive(d);
        dr.command(Twist::new(1.0, 0.0));
        for k in 1..=100 {
            dr.step(&mut s, 0.01);
            let t = k as f64 * 0.01;
            assert!((s.vel.v - (1.0 - (-t / 0.2f64).exp())).abs() < 1e-12, "t = {t}");
        }
        // Acceleration limit only: a ramp at 2.5 m/s^2 up to the command, then braking at 4.
        let d = Dynamics {
            accel_v: 2.5,
            decel_v: 4.0,
            ..Dynamics::IDEAL
        };
        let (mut dr, mut s) = drive(d);
        dr.command(Twist::new(2.0, 0.0));
        for k in 1..=100 {
            dr.step(&mut s, 0.01);
            let want = (2.5 * k as f64 * 0.01).min(2.0);
            assert!((s.vel.v - want).abs() < 1e-12, "k = {k}: {} vs {want}", s.vel.v);
        }
        dr.command(Twist::new(0.0, 0.0));
        for k in 1..=60 {
            dr.step(&mut s, 0.01);
            let want = (2.0 - 4.0 * k as f64 * 0.01).max(0.0);
            assert!((s.vel.v - want).abs() < 1e-12, "braking k = {k}");
        }
        // Both: the lag's demand is cut by the limit early, the exponential tail remains.
        let d = Dynamics {
            lag_s: 0.15,
            ..Dynamics::gazebo_jackal()
        };
        let (mut dr, mut s) = drive(Dynamics { latency_s: 0.0, ..d });
        dr.command(Twist::new(2.0, 0.0));
        dr.step(&mut s, 0.01);
        let lag_step = 2.0 * (1.0 - (-0.01f64 / 0.15).exp());
        assert!(lag_step > 0.025, "the lag alone would ask for {lag_step}");
        assert!((s.vel.v - 0.025).abs() < 1e-12, "limited to 2.5 m/s^2 x 0.01 s");
    }

    #[test]
    fn latency_delays_the_command_by_exactly_the_configured_time() {
        let d = Dynamics {
            latency_s: 0.1,
            ..Dynamics::IDEAL
        };
        let (mut dr, mut s) = drive(d);
        dr.command(Twist::new(1.0, 0.0));
        for _ in 0..10 {
            dr.step(&mut s, 0.01);
            assert_eq!(s.vel.v, 0.0, "nothing happens during the first 0.1 s");
        }
        dr.step(&mut s, 0.01);
        assert!(
            (s.vel.v - 0.2).abs() < 1e-12,
            "then the ideal 20 m/s^2 ramp starts"
        );
        // A later command replaces it exactly 10 steps after its issue.
        dr.command(Twist::new(0.0, 0.0));
        for _ in 0..10 {
            dr.step(&mut s, 0.01);
        }
        assert_eq!(dr.applied(), Twist::new(1.0, 0.0));
        dr.step(&mut s, 0.01);
        assert_eq!(dr.applied(), Twist::new(0.0, 0.0));
    }

    /// With a modelled compute time the command acts after the profile's latency less its
    /// planning share plus that time: 0.075 - 0.025 + 0.03 = 0.08 s, 8 physics steps.
    #[test]
    fn modelled_compute_replaces_the_planning_share_of_the_latency() {
        let d = Dynamics {
            latency_s: 0.075,
            ..Dynamics::IDEAL
        };
        let (mut dr, mut s) = drive(d);
        dr.command_after(Twist::new(1.0, 0.0), 0.03);
        for _ in 0..8 {
            assert_eq!(dr.applied(), Twist::default());
            dr.step(&mut s, 0.01);
        }
        assert_eq!(dr.applied(), Twist::default(), "due at the start of step 9");
        dr.step(&mut s, 0.01);
        assert_eq!(dr.applied(), Twist::new(1.0, 0.0));
        // A profile without latency: the compute time alone (0.02 s, 2 steps).
        let (mut dr, mut s) = drive(Dynamics::IDEAL);
        dr.command_after(Twist::new(1.0, 0.0), 0.02);
        dr.step(&mut s, 0.01);
        dr.step(&mut s, 0.01);
        assert_eq!(dr.applied(), Twist::default());
        dr.step(&mut s, 0.01);
        assert_eq!(dr.applied(), Twist::new(1.0, 0.0));
    }

    #[test]
    fn slip_makes_the_base_turn_less_the_faster_and_tighter() {
        let d = Dynamics::gazebo_jackal();
        assert_eq!(d.slip(0.0, 0.0), 0.0);
        assert!(d.slip(2.0, 1.0) > d.slip(1.0, 1.0));
        assert!(d.slip(1.0, 2.0) > d.slip(1.0, 1.0));
        assert_eq!(d.slip(2.0, 5.0), d.max_slip);
        let (mut dr, mut s) = drive(Dynamics { latency_s: 0.0, ..d });
        dr.command(Twist::new(1.0, 1.0));
        for _ in 0..200 {
            dr.step(&mut s, 0.01);
        }
        let expect = 1.0 * (1.0 - d.slip(1.0, 1.0));
        assert!((s.vel.w - expect).abs() < 1e-9, "{} vs {expect}", s.vel.w);
    }

    #[test]
    fn the_ideal_profile_is_the_controllers_nominal_accelerations() {
        let j = RobotLimits::JACKAL;
        let d = Dynamics::IDEAL;
        assert_eq!(
            (d.accel_v, d.decel_v, d.accel_w),
            (j.accel_v, j.accel_v, j.accel_w)
        );
    }

    #[test]
    fn drift_is_a_seeded_random_walk_with_distance() {
        use rand::SeedableRng;
        let d = Dynamics::gazebo_jackal();
        let walk = |seed| {
            let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
            let mut l = Localization::default();
            for _ in 0..100 {
                l.drift(&d, 0.1, &mut rng);
            }
            l
        };
        assert_eq!(walk(3), walk(3));
        assert_ne!(walk(3), walk(4));
        // Standing still never drifts.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
        let mut l = Localization::default();
        l.drift(&d, 0.0, &mut rng);
        assert_eq!(l, Localization::default());
        // The spread after 10 m is about drift * sqrt(10): check it over many walks.
        let n = 2000;
        let var: f64 = (0..n).map(|s| walk(s).yaw.powi(2)).sum::<f64>() / n as f64;
        let want = d.drift_yaw.powi(2) * 10.0;
        assert!((var / want - 1.0).abs() < 0.15, "variance {var} vs {want}");
    }
}
