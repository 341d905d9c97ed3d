//! The standalone DDP/ADP navigation system: a noisy sampling planner inside a mode state
//! machine (normal, low-speed, brake, recovery with rotate-in-place and back-up).
//!
//! Each sampling cycle draws about 550 nominal commands around the dynamic window (a grid,
//! copies of the previous solution as a warm start, and mode-specific extras), perturbs every
//! rollout step with Gaussian noise, rolls the perturbed controls out over the schedule's
//! time grid with the acceleration limits, checks the footprint after every step with the
//! schedule's check density, scores goal distance, heading, obstacle proximity and (at low
//! speed) free space, and averages the controls of the ten cheapest collision-free samples
//! (weights `exp(-(J_k - J_min) / lambda) ((10 - k) / 10)^2`, each sample's controls
//! weighted by `dt_j / T`). With a fixed DDP schedule this is "DDP"; with a schedule chosen
//! by a policy every 0.25 s it is "ADP".
//!
//! The mode machine ([`ModeMachine`]) follows the authors' `velocityCallback`
//! (adp-code-notes §4.4-4.5) and keeps time by counting planning cycles. Where their code
//! relied on details this simulator lacks, the behaviour is kept and the mechanism adapted:
//!
//! - the clearance bound of each rollout step is the larger of its scheduled check and the
//!   previous step's bound minus how far the footprint moved, starting from an exact check
//!   of the current pose against the scan; slow rollouts keep the precision of their dense
//!   early checks instead of failing at their coarse late ones;
//! - in low-speed and recovery modes a rollout may stop (the robot brakes within
//!   centimetres at 20 m/s^2) before its first failed check once it has driven clear for
//!   `low_min_safe_time`; it then averages over the time it drives;
//! - the slow recovery motions (rotate in place, back up) are checked exactly against the
//!   scan points near the robot, plus remembered points in the lidar's blind sector behind
//!   it (dead-reckoned from the measured velocity);
//! - the front clearance that triggers the back-up is the free distance ahead of the bumper
//!   within the robot's width, so narrow gaps beside the robot do not trigger it; after
//!   backing up the robot turns toward the local path before driving on;
//! - brake commands a stop: the simulated controller decelerates at 20 m/s^2, so the
//!   authors' negative brake commands would drive backwards blind;
//! - among moving obstacles the fallbacks (brake, rotate, back up) are also checked against
//!   the forecast: each command, held from the measured velocity for `moving_hold_time`, must
//!   keep the footprint clear of every obstacle's swept forecast (`NavSystem::fallback_clear`).
//!   A rotation or back-up that fails counts as blocked (the mode machine moves on to the
//!   next behaviour); a stop that fails is replaced by a clear back-up, else a clear
//!   rotation, else the behaviours of the recovery cycle, and when nothing is clear the
//!   robot stops.
//!
//! Files: `config` (the parameters), `mode` (the mode machine), `sampling` (sample
//! weights, rollout and costs of one sample); this file holds the planner that drives them.

mod config;
mod mode;
mod sampling;

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use sim::episode::Perception;
use sim::geometry::{Pose, Vec2};
use sim::navigation::point_at_arc_length;
use sim::robot::{approach, integrate_arc, Twist};

pub use config::SystemConfig;
pub use mode::{Mode, ModeMachine, ModeObservation};
pub use sampling::top_weights;
use sampling::{
    chained_clearance, evaluate, front_clearance, path_bearing, yaw_rate_cap, ModeParams, RolloutCtx,
    SampleEval,
};

use crate::compute::{admit, evaluation_order, Budget, Work};
use crate::local_map::LocalMap;
use crate::{Gains, GainsError, Integrator, PlanInput, Planner, Trace};

/// Scan points this close to the robot centre are checked exactly by the recovery
/// motions (m): the circumscribed radius plus a back-up step, with room to spare.
const NEAR_RANGE: f64 = 1.0;

/// Half-angle of the sector behind the robot that the lidar (270 degrees) does not see, with
/// a margin (rad): remembered points there stand in for the missing returns.
const BLIND_HALF_ANGLE: f64 = 50.0 * std::f64::consts::PI / 180.0;

/// At most this many remembered blind-sector points; beyond it the oldest are forgotten.
/// Every cycle re-adds the scan's near points, so a robot that turns or waits near obstacles
/// accumulates copies of the same surfaces: the most seen on the 300 BARN worlds (vanilla and
/// DDP, 1.0 and 2.0 m/s) is 13,934. The bound keeps a stuck robot's cycle from growing without
/// end, and lets the buffers be allocated once.
const MAX_REMEMBERED: usize = 16_384;

/// Scan points the buffers are sized for up front (the Jackal's lidar has 720 beams); a
/// larger scan grows them once.
const SCAN_CAPACITY: usize = 1024;

#[derive(Clone, Debug)]
pub struct NavSystem {
    /// The configuration, its objective weights scaled by the gain factors.
    cfg: SystemConfig,
    /// The configured (hand-tuned) weights: `[normal, low]` per gain of [`Gains::System`].
    tuned: [[f64; 2]; 4],
    map: LocalMap,
    rng: Pcg64Mcg,
    machine: ModeMachine,
    /// Nominal command of every sample.
    nominal: Vec<Twist>,
    /// Perturbed per-step controls, sample after sample.
    controls: Vec<Twist>,
    evals: Vec<SampleEval>,
    /// Samples in evaluation order under a compute budget ([`crate::compute::even_order`]).
    eval_order: Vec<u32>,
    /// Whether the budget let each sample be evaluated.
    admitted: Vec<bool>,
    /// `trace.evaluated` when the current cycle started.
    points_at_start: u64,
    order: Vec<usize>,
    top_costs: Vec<f64>,
    weights: Vec<f64>,
    /// The last command (the warm start).
    prev: Twist,
    /// Direction of the current rotation in place (+1 left, -1 right, 0 none yet).
    rotate_dir: f64,
    /// The current rotation has already reversed once.
    rotate_flipped: bool,
    /// Clearance bound of the robot's current pose (all boundary points checked).
    start_clear: f64,
    /// The rollout integrator of this cycle (from the plan input's prediction).
    integrator: Integrator,
    /// Scan points within [`NEAR_RANGE`] of the robot, and remembered points in the
    /// lidar's blind sector behind it.
    near: Vec<Vec2>,
    /// The scan plus the remembered blind-sector points: what the distance field is built on.
    obstacles: Vec<Vec2>,
    /// Remembered blind-sector points (robot frame of this cycle).
    memory: Vec<Vec2>,
    /// Scratch for moving the memory into the new robot frame.
    scratch: Vec<Vec2>,
    /// Measured velocity of the previous cycle (dead reckoning of the memory).
    last_vel: Twist,
    trace: Trace,
}

impl NavSystem {
    /// A navigation system whose sampling noise is drawn from `seed`.
    pub fn new(cfg: SystemConfig, seed: u64) -> Self {
        Self {
            cfg,
            tuned: [
                [cfg.normal_goal, cfg.low_goal],
                [cfg.normal_obstacle, cfg.low_obstacle],
                [cfg.normal_heading, cfg.low_heading],
                [cfg.normal_space, cfg.low_space],
            ],
            map: LocalMap::jackal(cfg.map_resolution),
            rng: Pcg64Mcg::seed_from_u64(seed),
            machine: ModeMachine::new(cfg),
            nominal: Vec::new(),
            controls: Vec::new(),
            evals: Vec::new(),
            eval_order: Vec::new(),
            admitted: Vec::new(),
            points_at_start: 0,
            order: Vec::new(),
            top_costs: Vec::new(),
            weights: Vec::new(),
            prev: Twist::default(),
            rotate_dir: 0.0,
            rotate_flipped: false,
            start_clear: 0.0,
            integrator: Integrator::ExactArc,
            near: Vec::with_capacity(SCAN_CAPACITY + MAX_REMEMBERED),
            obstacles: Vec::with_capacity(SCAN_CAPACITY + MAX_REMEMBERED),
            memory: Vec::with_capacity(SCAN_CAPACITY + MAX_REMEMBERED),
            scratch: Vec::with_capacity(SCAN_CAPACITY + MAX_REMEMBERED),
            last_vel: Twist::default(),
            trace: Trace::default(),
        }
    }

    /// The current mode.
    pub fn mode(&self) -> Mode {
        self.machine.mode()
    }

    fn params(&self, mode: Mode, max_speed: f64) -> ModeParams {
        let c = &self.cfg;
        match mode {
            Mode::Normal => ModeParams {
                v_cap: max_speed,
                w_caps: c.normal_max_w,
                goal: c.normal_goal,
                obstacle: c.normal_obstacle,
                heading: c.normal_heading,
                space: c.normal_space,
                margin: c.normal_margin,
                min_travel: c.normal_min_travel,
                min_safe_time: None,
            },
            _ => ModeParams {
                v_cap: c.low_speed_scale * max_speed,
                w_caps: c.low_max_w,
                goal: c.low_goal,
                obstacle: c.low_obstacle,
                heading: c.low_heading,
                space: c.low_space,
                margin: c.low_margin,
                min_travel: if mode == Mode::Recovery {
                    c.recovery_min_travel
                } else {
                    c.low_min_travel
                },
                min_safe_time: Some(c.low_min_safe_time),
            },
        }
    }

    /// Dead-reckons the remembered points into this cycle's robot frame (the mean measured
    /// velocity over one control period), keeps those now in the lidar's blind sector behind
    /// the robot, and gathers the obstacle points of this cycle.
    fn remember(&mut self, per: &Perception<'_>) {
        let mean = Twist::new(
            0.5 * (self.last_vel.v + per.vel.v),
            0.5 * (self.last_vel.w + per.vel.w),
        );
        self.last_vel = per.vel;
        let moved = integrate_arc(Pose::default(), mean, self.cfg.control_dt);
        let tan_blind = BLIND_HALF_ANGLE.tan();
        self.scratch.clear();
        self.scratch.extend(
            self.memory
                .iter()
                .map(|p| moved.to_local(*p))
                .filter(|q| q.x < 0.0 && q.y.abs() <= -q.x * tan_blind && q.norm() < NEAR_RANGE),
        );
        std::mem::swap(&mut self.memory, &mut self.scratch);
        self.near.clear();
        self.near
            .extend(per.points.iter().filter(|p| p.norm() < NEAR_RANGE));
        self.memory.extend_from_slice(&self.near);
        if self.memory.len() > MAX_REMEMBERED {
            // The scan's points came last: the excess is the oldest memory.
            let excess = self.memory.len() - MAX_REMEMBERED;
            self.memory.drain(..excess);
        }
        self.near.extend(
            self.memory
                .iter()
                .filter(|q| q.x < 0.0 && q.y.abs() <= -q.x * tan_blind),
        );
        self.obstacles.clear();
        self.obstacles.extend_from_slice(per.points);
        self.obstacles.extend(
            self.memory
                .iter()
                .filter(|q| q.x < 0.0 && q.y.abs() <= -q.x * tan_blind),
        );
    }

    /// True when the footprint stays clear (by `margin`) of every nearby scan point at
    /// every pose of `poses`: an exact check for the slow recovery motions (counted as one
    /// evaluated point per pose).
    fn clear_at(&mut self, poses: impl Iterator<Item = Pose>, margin: f64) -> bool {
        for pose in poses {
            self.trace.evaluated += 1;
            if self.exact_clearance(&pose) < margin {
                return false;
            }
        }
        true
    }

    /// Exact clearance between the footprint at `pose` and the scan points within
    /// [`NEAR_RANGE`] (a lower bound on what lies farther when none is that close).
    fn exact_clearance(&self, pose: &Pose) -> f64 {
        let fp = self.map.footprint();
        let far = NEAR_RANGE - pose.position().norm() - fp.circumscribed_radius();
        self.near
            .iter()
            .map(|p| fp.signed_distance_local(pose.to_local(*p)))
            .fold(far, f64::min)
    }

    /// True when the command `cmd`, held from the velocity `start` for `moving_hold_time`
    /// (the planner's acceleration limits, one pose per control period), keeps the footprint
    /// clear by `low_margin` of the forecast of every `moving` obstacle: each pose is checked
    /// against the segments the obstacles sweep over its period
    /// ([`crate::moving::hold_clearance`]). Always true without moving obstacles (nothing is
    /// checked or counted).
    fn fallback_clear(&mut self, cmd: Twist, start: Twist, moving: &[crate::Predicted]) -> bool {
        if moving.is_empty() {
            return true;
        }
        let c = self.cfg;
        let dt = c.control_dt;
        let periods = (c.moving_hold_time / dt).ceil().max(1.0) as usize;
        let (mut vel, mut pose) = (start, Pose::default());
        for k in 0..periods {
            vel.v = approach(vel.v, cmd.v, c.accel_v * dt);
            vel.w = approach(vel.w, cmd.w, c.accel_w * dt);
            pose = integrate_arc(pose, vel, dt);
            let (t0, t1) = (k as f64 * dt, (k + 1) as f64 * dt);
            let fp = self.map.footprint();
            if crate::moving::hold_clearance(fp, &pose, t0, t1, moving, &mut self.trace.evaluated)
                < c.low_margin
            {
                return false;
            }
        }
        true
    }

    /// Stop, where the stop stays clear of the moving obstacles' forecast; otherwise the
    /// next fallback that is clear: back up, or rotate toward `heading_error`. `None` when
    /// none is.
    fn brake(&mut self, heading_error: f64, vel: Twist, moving: &[crate::Predicted]) -> Option<Twist> {
        let stop = Twist::default();
        if self.fallback_clear(stop, vel, moving) {
            return Some(stop);
        }
        self.backup(vel, moving)
            .or_else(|| self.rotate(heading_error, vel, moving))
    }

    /// Rotate in place toward `heading_error`, or the other way round if that side is
    /// blocked (by the scan, or by the `moving` obstacles' forecast from the velocity
    /// `vel`); a rotation keeps its direction until that direction is blocked.
    fn rotate(&mut self, heading_error: f64, vel: Twist, moving: &[crate::Predicted]) -> Option<Twist> {
        let w = heading_error
            .abs()
            .clamp(self.cfg.rotate_min_w, self.cfg.rotate_max_w);
        let first = if self.rotate_dir != 0.0 {
            self.rotate_dir
        } else if heading_error >= 0.0 {
            1.0
        } else {
            -1.0
        };
        let margin = self.cfg.low_margin;
        for dir in [first, -first] {
            if self.clear_at(
                (1..=3).map(|i| Pose::new(0.0, 0.0, dir * 0.05 * i as f64)),
                margin,
            ) && self.fallback_clear(Twist::new(0.0, dir * w), vel, moving)
            {
                if self.rotate_dir != 0.0 && dir != self.rotate_dir {
                    // Blocked on both sides of the reachable arc: give up rotating.
                    if self.rotate_flipped {
                        break;
                    }
                    self.rotate_flipped = true;
                }
                self.rotate_dir = dir;
                return Some(Twist::new(0.0, dir * w));
            }
        }
        None
    }

    /// Back up straight if the (partly unseen) space behind looks clear and the back-up,
    /// from the velocity `vel`, stays clear of the `moving` obstacles' forecast.
    fn backup(&mut self, vel: Twist, moving: &[crate::Predicted]) -> Option<Twist> {
        let margin = self.cfg.low_margin;
        let cmd = Twist::new(-self.cfg.backup_speed, 0.0);
        (self.clear_at((1..=3).map(|i| Pose::new(-0.05 * i as f64, 0.0, 0.0)), margin)
            && self.fallback_clear(cmd, vel, moving))
        .then_some(cmd)
    }

    /// One sampling cycle in `mode`; `None` when no sample is collision-free.
    fn sample(&mut self, input: &PlanInput<'_>, mode: Mode) -> Option<Twist> {
        let cfg = self.cfg;
        let per = &input.perception;
        let steps = input.schedule.len();
        let mp = self.params(mode, input.max_speed);

        let (v0, w0) = (per.vel.v, per.vel.w);
        let w_max = yaw_rate_cap(mp.w_caps, mp.v_cap, per.vel);
        let v_lo = (v0 - cfg.accel_v * cfg.window_dt).max(0.0);
        let v_hi = (v0 + cfg.accel_v * cfg.window_dt).min(mp.v_cap).max(v_lo);
        let w_lo = (w0 - cfg.accel_w * cfg.window_dt).max(-w_max);
        let w_hi = (w0 + cfg.accel_w * cfg.window_dt).min(w_max).max(w_lo);
        self.nominal_commands(mode, steps, (v_lo, v_hi), (w_lo, w_hi));
        let n = self.nominal.len();
        if self.trace.recording {
            self.trace.rollouts.clear(input.schedule.dts());
        }
        let v_top = mp.v_cap.max(v_hi);
        self.draw_controls(steps, v_top, w_max);
        self.roll_out(input, mode, &mp, n);
        if !self.rank(&mp, n) {
            return None;
        }
        Some(self.command(input, &mp, n, v_top, w_max))
    }

    /// Fills `nominal` with the cycle's nominal commands in the window `v` x `w`: the grid, the
    /// warm start, the mode's extras.
    fn nominal_commands(
        &mut self,
        mode: Mode,
        steps: usize,
        (v_lo, v_hi): (f64, f64),
        (w_lo, w_hi): (f64, f64),
    ) {
        let cfg = self.cfg;
        let clamp_window = |t: Twist| Twist::new(t.v.clamp(v_lo, v_hi), t.w.clamp(w_lo, w_hi));
        self.nominal.clear();
        let (nv, nw) = (cfg.v_samples.max(1), cfg.w_samples.max(1));
        // The recovery mode's set (three extras) is the largest: sized for it once, a mode
        // switch does not grow the buffers mid-episode.
        self.reserve(nv * nw + cfg.warm_samples + 3 * cfg.extra_samples, steps);
        let grid = |lo: f64, hi: f64, n: usize, i: usize| {
            if n <= 1 {
                0.5 * (lo + hi)
            } else {
                lo + (hi - lo) * i as f64 / (n - 1) as f64
            }
        };
        for i in 0..nv {
            for j in 0..nw {
                self.nominal
                    .push(Twist::new(grid(v_lo, v_hi, nv, i), grid(w_lo, w_hi, nw, j)));
            }
        }
        let warm = clamp_window(self.prev);
        self.nominal.extend(std::iter::repeat_n(warm, cfg.warm_samples));
        let extras: &[Twist] = match mode {
            Mode::LowSpeed => &[Twist::new(cfg.low_creep_v, 0.0)],
            Mode::Recovery => &[
                Twist::new(cfg.recovery_creep_v, 0.0),
                Twist::new(cfg.recovery_turn_v, -cfg.recovery_turn_w),
                Twist::new(cfg.recovery_turn_v, cfg.recovery_turn_w),
            ],
            _ => &[],
        };
        for &x in extras {
            self.nominal
                .extend(std::iter::repeat_n(clamp_window(x), cfg.extra_samples));
        }
    }

    /// Draws every sample's per-step controls around its nominal command (sequentially, so the
    /// result does not depend on threads), within `[0, v_top]` x `[-w_max, w_max]`.
    fn draw_controls(&mut self, steps: usize, v_top: f64, w_max: f64) {
        let cfg = self.cfg;
        self.controls.clear();
        for nom in &self.nominal {
            for _ in 0..steps {
                let ev: f64 = self.rng.sample(StandardNormal);
                let ew: f64 = self.rng.sample(StandardNormal);
                self.controls.push(Twist::new(
                    (nom.v + cfg.noise_v * ev).clamp(0.0, v_top),
                    (nom.w + cfg.noise_w * ew).clamp(-w_max, w_max),
                ));
            }
        }
    }

    /// Rolls out and scores the `n` samples in parallel, applies the cycle's budget, and records
    /// the rollouts when recording.
    fn roll_out(&mut self, input: &PlanInput<'_>, mode: Mode, mp: &ModeParams, n: usize) {
        let cfg = self.cfg;
        let per = &input.perception;
        let sched = input.schedule;
        let dts = sched.dts();
        let steps = dts.len();
        let horizon = sched.horizon();
        // The local goal: the episode's in normal mode, a closer one along the path otherwise.
        let goal = if mode == Mode::Normal || per.local_path.len() < 2 {
            per.local_goal
        } else {
            point_at_arc_length(per.local_path, mp.v_cap * horizon + cfg.low_goal_offset).0
        };
        let fp = *self.map.footprint();
        let quarter = steps - (steps / 4).max(1);
        let space_dirs = (mp.space > 0.0).then(|| {
            let a = cfg.space_half_angle_deg.to_radians();
            [(0.0, 1.0), a.sin_cos(), (-a).sin_cos()]
        });
        if self.evals.len() < n {
            self.evals.resize_with(n, SampleEval::default);
        }
        let start_clear = self.start_clear;
        let ctx = RolloutCtx {
            map: &self.map,
            dts,
            checks: sched.checks(),
            start: per.vel,
            accel_v: cfg.accel_v,
            accel_w: cfg.accel_w,
            integrator: self.integrator,
            margin: mp.margin,
            min_travel: mp.min_travel,
            min_safe_time: mp.min_safe_time,
            clearance_cap: cfg.clearance_cap,
            start_clear,
            goal,
            quarter,
            space_dirs,
            space_cap: cfg.space_cap,
            half_width: fp.half_width,
            record: self.trace.recording,
            moving: input.moving,
            hold_time: cfg.moving_hold_time,
        };
        let controls = &self.controls;
        self.evals[..n]
            .par_iter_mut()
            .enumerate()
            .with_min_len(32)
            .for_each(|(i, e)| evaluate(&ctx, &controls[i * steps..(i + 1) * steps], e));
        self.admit(&input.budget, n, steps);
        let evals = &mut self.evals[..n];
        if self.trace.recording {
            for e in evals.iter() {
                self.trace.rollouts.begin();
                for p in &e.poses {
                    self.trace.rollouts.push(*p);
                }
                self.trace.rollouts.end(e.feasible);
            }
            let skipped = &mut self.trace.rollouts.skipped;
            let first = skipped.len() - n;
            for (s, &a) in skipped[first..].iter_mut().zip(&self.admitted) {
                *s = !a;
            }
        }
    }

    /// Costs the feasible samples of the `n` and weighs the best `top_k` (`order`, `weights`);
    /// false when no sample is feasible.
    fn rank(&mut self, mp: &ModeParams, n: usize) -> bool {
        let cfg = self.cfg;
        let evals = &mut self.evals[..n];
        // Costs: goal and heading normalized over the feasible samples, the rest in [0, 1].
        let span = |f: fn(&SampleEval) -> f64, es: &[SampleEval]| {
            let (lo, hi) = es
                .iter()
                .filter(|e| e.feasible)
                .map(f)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(x), b.max(x))
                });
            (lo, if hi - lo > 1e-9 { hi - lo } else { 1.0 })
        };
        let (g_lo, g_span) = span(|e| e.goal, evals);
        let (h_lo, h_span) = span(|e| e.heading, evals);
        self.order.clear();
        for (i, e) in evals.iter_mut().enumerate() {
            if e.feasible {
                e.cost = mp.goal * (e.goal - g_lo) / g_span
                    + mp.heading * (e.heading - h_lo) / h_span
                    + mp.obstacle * e.obstacle
                    + mp.space * e.space;
                self.order.push(i);
            }
        }
        if self.order.is_empty() {
            return false;
        }
        let evals = &self.evals[..n];
        let by_cost = |a: &usize, b: &usize| evals[*a].cost.total_cmp(&evals[*b].cost).then(a.cmp(b));
        let k = cfg.top_k.max(1).min(self.order.len());
        if self.order.len() > k {
            self.order.select_nth_unstable_by(k - 1, by_cost);
            self.order.truncate(k);
        }
        self.order.sort_unstable_by(by_cost);
        self.top_costs.clear();
        self.top_costs.extend(self.order.iter().map(|&i| evals[i].cost));
        top_weights(&self.top_costs, cfg.top_k, cfg.lambda, &mut self.weights);

        true
    }

    /// The command of a ranked cycle: the weighted mean of the top samples' controls, else the
    /// best sample's mean, whichever passes the verification first; else the best sample's
    /// first control.
    fn command(&mut self, input: &PlanInput<'_>, mp: &ModeParams, n: usize, v_top: f64, w_max: f64) -> Twist {
        let per = &input.perception;
        let sched = input.schedule;
        let dts = sched.dts();
        let steps = dts.len();
        let controls = &self.controls;
        let evals = &self.evals[..n];
        // Each sample's controls averaged over the schedule, step j weighing dt_j / T with T
        // the horizon (or, for a rollout that stops early, the time it drives).
        let mean_control = |i: usize| {
            let mut acc = Twist::default();
            let mut time = 0.0;
            let driven = evals[i].driven;
            for (u, &dt) in controls[i * steps..i * steps + driven].iter().zip(dts) {
                acc.v += u.v * dt;
                acc.w += u.w * dt;
                time += dt;
            }
            if time > 0.0 {
                Twist::new(acc.v / time, acc.w / time)
            } else {
                Twist::default()
            }
        };
        let mut cmd = Twist::default();
        for (&i, &w) in self.order.iter().zip(&self.weights) {
            let m = mean_control(i);
            cmd.v += w * m.v;
            cmd.w += w * m.w;
        }
        let best = self.order[0];
        let candidates = [cmd, mean_control(best)];
        let first = self.controls[best * steps];
        for c in candidates {
            let c = Twist::new(c.v.clamp(0.0, v_top), c.w.clamp(-w_max, w_max));
            if self.verify(c, per.vel, (dts, sched.checks()), mp.margin, input.moving) {
                return c;
            }
        }
        first
    }

    /// Sizes the per-sample buffers for `most` samples of `steps` steps (no-op once they are).
    fn reserve(&mut self, most: usize, steps: usize) {
        let grow = |len: usize, need: usize| need.saturating_sub(len);
        self.nominal.reserve(grow(self.nominal.len(), most));
        self.controls.reserve(grow(self.controls.len(), most * steps));
        if self.evals.len() < most {
            self.evals.resize_with(most, SampleEval::default);
        }
        self.eval_order.reserve(grow(self.eval_order.len(), most));
        self.admitted.reserve(grow(self.admitted.len(), most));
        self.order.reserve(grow(self.order.len(), most));
    }

    /// Decides which of the `n` samples just evaluated the compute budget admits (see
    /// [`crate::compute::admit`]; each drew two normals per step), marks the others
    /// infeasible (not considered), and adds the admitted samples' work to `trace.cycle` and
    /// their points to `trace.evaluated`.
    fn admit(&mut self, budget: &Budget, n: usize, steps: usize) {
        evaluation_order(budget, n, &mut self.eval_order);
        self.admitted.resize(n, false);
        let spent = Work {
            points: self.trace.evaluated - self.points_at_start,
            ..self.trace.cycle.work
        };
        let evals = &self.evals;
        let work_of = |i: usize| Work {
            samples: 1,
            draws: 2 * steps as u64,
            steps: evals[i].steps,
            points: evals[i].evaluated,
            cells: 0,
        };
        let c = admit(budget, spent, &self.eval_order, work_of, &mut self.admitted[..n]);
        self.trace.evaluated += c.work.points - spent.points;
        self.trace.cycle.work = c.work;
        self.trace.cycle.samples += c.samples;
        self.trace.cycle.evaluated += c.evaluated;
        for (e, &a) in self.evals[..n].iter_mut().zip(&self.admitted) {
            e.feasible &= a;
        }
    }

    /// True when the constant command `cmd` stays collision-free over the first
    /// `verify_time` seconds of the schedule (`dts` with their `checks`), against the scan
    /// and against the forecast of the `moving` obstacles.
    fn verify(
        &mut self,
        cmd: Twist,
        start: Twist,
        (dts, checks): (&[f64], &[u16]),
        margin: f64,
        moving: &[crate::Predicted],
    ) -> bool {
        let (mut vel, mut pose, mut t) = (start, Pose::default(), 0.0);
        let mut heading = (0.0, 1.0);
        let mut clear = self.start_clear;
        for (&dt, &m) in dts.iter().zip(checks) {
            if t >= self.cfg.verify_time {
                break;
            }
            let before = pose;
            vel.v = approach(vel.v, cmd.v, self.cfg.accel_v * dt);
            vel.w = approach(vel.w, cmd.w, self.cfg.accel_w * dt);
            pose = self.integrator.step_pose_carried(pose, &mut heading, vel, dt);
            t += dt;
            clear = chained_clearance(
                &self.map,
                (&before, clear),
                (&pose, heading),
                m as usize,
                self.cfg.clearance_cap,
                &mut self.trace.evaluated,
            );
            let ahead = if moving.is_empty() {
                f64::INFINITY
            } else {
                crate::moving::clearance(self.map.footprint(), &pose, t, moving, &mut self.trace.evaluated)
            };
            if clear.min(ahead) < margin {
                return false;
            }
        }
        true
    }
}

impl Planner for NavSystem {
    crate::planner_identity!("system");

    fn gains(&self) -> Option<Gains> {
        Some(Gains::System)
    }

    fn set_gain_factors(&mut self, factors: &[f64]) -> Result<(), GainsError> {
        Gains::System.check(factors)?;
        let [g, o, h, s] = self.tuned;
        let c = &mut self.cfg;
        (c.normal_goal, c.low_goal) = (g[0] * factors[0], g[1] * factors[0]);
        (c.normal_obstacle, c.low_obstacle) = (o[0] * factors[1], o[1] * factors[1]);
        (c.normal_heading, c.low_heading) = (h[0] * factors[2], h[1] * factors[2]);
        (c.normal_space, c.low_space) = (s[0] * factors[3], s[1] * factors[3]);
        Ok(())
    }

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        self.points_at_start = self.trace.evaluated;
        self.trace.cycle = Default::default();
        let cmd = self.cycle(input);
        self.trace.cycle.work.points = self.trace.evaluated - self.points_at_start;
        cmd
    }
}

impl NavSystem {
    /// One planning cycle; counts its work into `trace.cycle` (the points at the end, by
    /// [`Planner::plan`]).
    fn cycle(&mut self, input: &PlanInput<'_>) -> Twist {
        let cfg = self.cfg;
        let per = &input.perception;
        let sched = input.schedule;
        self.remember(per);
        self.integrator = input.prediction.integrator;
        self.map
            .prepare(&self.obstacles, input, NEAR_RANGE, cfg.clearance_cap);
        self.trace.cycle.work.cells = self.map.cells() as u64;
        if self.trace.recording {
            self.trace.rollouts.clear(sched.dts());
        }
        self.start_clear = self.exact_clearance(&Pose::default());
        self.trace.evaluated += 1;

        let heading_error = path_bearing(per.local_path, 0.3, per.local_goal);
        let obs = ModeObservation {
            speed: per.vel.v,
            max_speed: input.max_speed,
            front_clearance: front_clearance(per.points, self.map.footprint(), cfg.front_side_margin),
            heading_error,
        };
        if self.machine.update(&obs) != Mode::Rotate {
            self.rotate_dir = 0.0;
            self.rotate_flipped = false;
        }
        // Try the mode's action; on failure the machine moves on and the next mode acts (a
        // failed brake stays in brake: then the robot stops).
        let mut cmd = Twist::default();
        let (vel, moving) = (per.vel, input.moving);
        for _ in 0..3 {
            let mode = self.machine.mode();
            let action = match mode {
                Mode::Normal | Mode::LowSpeed | Mode::Recovery => self.sample(input, mode),
                Mode::Brake => self.brake(heading_error, vel, moving),
                Mode::Rotate => self.rotate(heading_error, vel, moving),
                Mode::Backup => self.backup(vel, moving),
            };
            if let Some(a) = action {
                self.machine.report(true);
                cmd = a;
                break;
            }
            if self.machine.report(false) == mode {
                break;
            }
        }
        self.prev = cmd;
        cmd
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::run_episode;
    use crate::Schedule;
    use sim::episode::{Episode, EpisodeConfig, Status};
    use sim::geometry::Circle;
    use sim::World;

    fn machine() -> ModeMachine {
        ModeMachine::new(SystemConfig::default())
    }

    fn at(speed: f64) -> ModeObservation {
        ModeObservation {
            speed,
            max_speed: 1.5,
            front_clearance: 5.0,
            heading_error: 1.0,
        }
    }

    /// Feeds one cycle per speed; returns the mode after each.
    fn drive(m: &mut ModeMachine, speeds: &[f64]) -> Vec<Mode> {
        speeds.iter().map(|&v| m.update(&at(v))).collect()
    }

    /// Normal -> low-speed -> brake -> recovery, standing still.
    fn into_recovery(m: &mut ModeMachine) {
        into_brake(m);
        assert_eq!(m.update(&at(0.0)), Mode::Recovery);
    }

    /// Normal -> low-speed -> brake, standing still.
    fn into_brake(m: &mut ModeMachine) {
        drive(m, &[0.0; 10]);
        assert_eq!(m.mode(), Mode::LowSpeed);
        drive(m, &[0.0; 11]);
        assert_eq!(m.mode(), Mode::Brake);
    }

    #[test]
    fn normal_to_low_speed_after_half_a_second_below_threshold() {
        // Threshold 0.5 * 1.5 + 0.1 = 0.85 m/s; 10 cycles of 0.05 s = 0.5 s.
        let mut m = machine();
        let modes = drive(&mut m, &[0.84; 10]);
        assert!(modes[..9].iter().all(|&x| x == Mode::Normal));
        assert_eq!(modes[9], Mode::LowSpeed);
        // An interruption restarts the clock.
        let mut m = machine();
        drive(&mut m, &[0.8; 9]);
        drive(&mut m, &[0.86]);
        assert!(drive(&mut m, &[0.8; 9]).iter().all(|&x| x == Mode::Normal));
        assert_eq!(m.update(&at(0.8)), Mode::LowSpeed);
    }

    #[test]
    fn low_speed_to_normal_after_half_a_second_fast() {
        // Low-speed cap 0.75 m/s: threshold 0.8 * 0.75 + 0.1 = 0.7 m/s.
        let mut m = machine();
        drive(&mut m, &[0.5; 10]);
        assert_eq!(m.mode(), Mode::LowSpeed);
        assert!(drive(&mut m, &[0.69; 30]).iter().all(|&x| x == Mode::LowSpeed));
        let modes = drive(&mut m, &[0.71; 10]);
        assert!(modes[..9].iter().all(|&x| x == Mode::LowSpeed));
        assert_eq!(modes[9], Mode::Normal);
    }

    #[test]
    fn low_speed_to_brake_after_more_than_half_a_second_below_min_speed_then_recovery() {
        let mut m = machine();
        drive(&mut m, &[0.5; 10]);
        // Exactly 0.5 s below 0.2 m/s is not enough; the 11th cycle is.
        let modes = drive(&mut m, &[0.19; 11]);
        assert!(modes[..10].iter().all(|&x| x == Mode::LowSpeed));
        assert_eq!(modes[10], Mode::Brake);
        // Brake until stopped.
        assert_eq!(m.update(&at(0.15)), Mode::Brake);
        assert_eq!(m.update(&at(0.05)), Mode::Recovery);
    }

    #[test]
    fn recovery_returns_to_low_speed_after_successes_and_needs_more_each_time() {
        let mut m = machine();
        into_recovery(&mut m);
        for _ in 0..4 {
            assert_eq!(m.report(true), Mode::Recovery);
        }
        assert_eq!(m.report(true), Mode::LowSpeed);
        // Second recovery: level 2, ten successes.
        drive(&mut m, &[0.0; 11]);
        assert_eq!(m.update(&at(0.0)), Mode::Recovery);
        for _ in 0..9 {
            assert_eq!(m.report(true), Mode::Recovery);
        }
        assert_eq!(m.report(true), Mode::LowSpeed);
        // Back in normal mode the level resets to one.
        drive(&mut m, &[0.75; 10]);
        assert_eq!(m.mode(), Mode::Normal);
        into_recovery(&mut m);
        for _ in 0..4 {
            m.report(true);
        }
        assert_eq!(m.report(true), Mode::LowSpeed);
    }

    #[test]
    fn recovery_backs_up_when_blocked_then_rotates_toward_the_path() {
        let mut m = machine();
        into_recovery(&mut m);
        let blocked = |front| ModeObservation {
            front_clearance: front,
            ..at(0.0)
        };
        assert_eq!(m.update(&blocked(0.05)), Mode::Backup);
        // At least one second (20 cycles) of backing up, then until the front is clear.
        for _ in 0..19 {
            assert_eq!(m.update(&blocked(0.25)), Mode::Backup);
        }
        assert_eq!(m.update(&blocked(0.15)), Mode::Backup, "hysteresis");
        assert_eq!(m.update(&blocked(0.25)), Mode::Rotate);
        // Rotate until facing the local path, then low-speed.
        let facing = |err| ModeObservation {
            heading_error: err,
            ..at(0.0)
        };
        assert_eq!(m.update(&facing(-0.6)), Mode::Rotate);
        assert_eq!(m.update(&facing(0.3)), Mode::Rotate);
        assert_eq!(m.update(&facing(-0.15)), Mode::LowSpeed);
        // A back-up that never clears the front ends after two seconds.
        let mut m = machine();
        into_recovery(&mut m);
        let modes: Vec<Mode> = (0..41).map(|_| m.update(&blocked(0.0))).collect();
        assert!(modes[..40].iter().all(|&x| x == Mode::Backup));
        assert_eq!(modes[40], Mode::Rotate);
    }

    #[test]
    fn failures_degrade_and_cycle_through_the_recovery_behaviours() {
        let mut m = machine();
        assert_eq!(m.report(true), Mode::Normal);
        assert_eq!(m.report(false), Mode::LowSpeed, "nothing feasible at full speed");
        assert_eq!(m.report(false), Mode::Brake, "nothing feasible at low speed");
        let mut m = machine();
        into_recovery(&mut m);
        assert_eq!(m.report(false), Mode::Rotate, "recovery sampling failed");
        assert_eq!(m.report(true), Mode::Rotate);
        assert_eq!(m.report(false), Mode::Backup, "rotation blocked");
        assert_eq!(m.report(false), Mode::Recovery, "back-up blocked");
    }

    #[test]
    fn top_weights_sum_to_one_and_ignore_a_constant_shift() {
        let costs = [0.10, 0.12, 0.3, 0.31, 0.5, 0.9, 1.0, 1.2, 1.25, 2.0];
        let mut w = Vec::new();
        top_weights(&costs, 10, 1.0, &mut w);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(
            w.windows(2).all(|p| p[1] < p[0]),
            "cheaper and better ranked weigh more"
        );
        let shifted: Vec<f64> = costs.iter().map(|c| c + 37.5).collect();
        let mut w2 = Vec::new();
        top_weights(&shifted, 10, 1.0, &mut w2);
        for (a, b) in w.iter().zip(&w2) {
            assert!((a - b).abs() < 1e-12);
        }
        // Equal costs: pure rank weights ((10 - k) / 10)^2, normalized.
        top_weights(&[1.0; 10], 10, 1.0, &mut w);
        let total: f64 = (1..=10).map(|k| (k * k) as f64).sum();
        assert!((w[0] - 100.0 / total).abs() < 1e-12 && (w[9] - 1.0 / total).abs() < 1e-12);
        // Fewer feasible samples than ten still sum to one.
        top_weights(&[0.2, 0.4], 10, 1.0, &mut w);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    /// A standing robot (nothing scanned near it) checks its fallbacks against hand-built
    /// forecasts: each meets the forecast or not as worked out from the footprint (0.508 x
    /// 0.430 m) and the obstacle's sweep, and a stop that would be hit gives way to the next
    /// fallback that stays clear.
    #[test]
    fn the_fallbacks_give_way_to_a_forecast_obstacle() {
        let obstacle = |x: f64, y: f64, vx: f64, vy: f64, radius: f64| crate::Predicted {
            position: Vec2::new(x, y),
            velocity: Vec2::new(vx, vy),
            radius,
            residual: None,
        };
        let still = Twist::default();
        let mut sys = NavSystem::new(SystemConfig::default(), 1);
        let backup = Twist::new(-0.1, 0.0);
        // Without a forecast every fallback is clear, and nothing is counted.
        assert_eq!(sys.backup(still, &[]), Some(backup));
        assert!(sys.rotate(0.5, still, &[]).is_some());
        assert_eq!(sys.brake(0.5, still, &[]), Some(still));
        let counted = sys.trace.evaluated;
        assert!(sys.fallback_clear(still, still, &[]));
        assert_eq!(sys.trace.evaluated, counted);

        // An obstacle (r = 0.3) coming from behind at 1 m/s, 1.5 m away: within the second
        // of the check it reaches the rear (x = -0.254) of a robot backing up at 0.1 m/s.
        let chaser = [obstacle(-1.5, 0.0, 1.0, 0.0, 0.3)];
        assert_eq!(sys.backup(still, &chaser), None);
        assert!(sys.trace.evaluated > counted, "each checked period counts");
        // The same obstacle moving away: clear.
        let leaving = [obstacle(-1.5, 0.0, -1.0, 0.0, 0.3)];
        assert_eq!(sys.backup(still, &leaving), Some(backup));

        // An obstacle (r = 0.02) sliding along the left side 0.268 m from the centre line:
        // 0.033 m clear of the standing footprint, but a rotation either way lifts a left
        // corner across its line (by 0.3 rad the front-left one is at y = 0.280).
        let sliding = [obstacle(-1.0, 0.268, 1.0, 0.0, 0.02)];
        assert!(sys.fallback_clear(still, still, &sliding), "standing is clear");
        assert_eq!(sys.rotate(0.5, still, &sliding), None);
        assert_eq!(sys.rotate(-0.5, still, &sliding), None);

        // An obstacle (r = 0.2) crossing 0.005 m in front of the bumper at 2 m/s: a stop is
        // within the margin (0.01 m) when it passes at t = 0.5 s, so brake backs up instead
        // (by then 0.05 m further from it); a rotation would swing a front corner into it.
        let grazing = [obstacle(0.254 + 0.2 + 0.005, -1.0, 0.0, 2.0, 0.2)];
        assert!(!sys.fallback_clear(still, still, &grazing));
        assert_eq!(sys.rotate(0.5, still, &grazing), None);
        assert_eq!(sys.brake(0.5, still, &grazing), Some(backup));
        // Head-on at 1 m/s from 1.2 m: nothing is clear, and brake has nothing to give.
        let head_on = [obstacle(1.2, 0.0, -1.0, 0.0, 0.2)];
        assert_eq!(sys.brake(0.0, still, &head_on), None);
    }

    /// In brake mode with nothing clear the cycle stops the robot (a failed brake stays in
    /// brake instead of trying it again); with a clear back-up it backs up.
    #[test]
    fn a_braking_robot_backs_up_out_of_a_crossing_or_stops() {
        let world = World::new(
            0,
            vec![],
            sim::geometry::Pose::default(),
            Vec2::new(8.0, 0.0),
            8.0,
            vec![],
        );
        let ep = Episode::new(&world, EpisodeConfig::default(), 1);
        let sched = Schedule::ddp_default();
        let plan = |sys: &mut NavSystem, moving: &[crate::Predicted]| {
            sys.machine = machine();
            into_brake(&mut sys.machine);
            // Moving at 0.15 m/s: brake holds (the robot has not stopped).
            let mut per = ep.perception();
            per.vel = Twist::new(0.15, 0.0);
            sys.cycle(&PlanInput {
                perception: per,
                schedule: &sched,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving,
            })
        };
        let mut sys = NavSystem::new(SystemConfig::default(), 1);
        assert_eq!(plan(&mut sys, &[]), Twist::default());
        let grazing = [crate::Predicted {
            position: Vec2::new(0.254 + 0.2 + 0.005, -1.0),
            velocity: Vec2::new(0.0, 2.0),
            radius: 0.2,
            residual: None,
        }];
        assert_eq!(plan(&mut sys, &grazing), Twist::new(-0.1, 0.0));
        assert_eq!(sys.mode(), Mode::Brake);
        let head_on = [crate::Predicted {
            position: Vec2::new(1.2, 0.0),
            velocity: Vec2::new(-1.0, 0.0),
            radius: 0.2,
            residual: None,
        }];
        assert_eq!(plan(&mut sys, &head_on), Twist::default());
        assert_eq!(sys.mode(), Mode::Brake);
    }

    /// Walls 2 m apart along +y and a 0.25 m cylinder on the centre line.
    fn corridor_with_cylinder() -> World {
        World::corridor(
            1.0,
            &[Circle {
                c: Vec2::new(0.0, 4.0),
                r: 0.25,
            }],
        )
    }

    #[test]
    fn drives_around_a_cylinder_on_the_straight_route() {
        let world = corridor_with_cylinder();
        let mut sys = NavSystem::new(SystemConfig::default(), 3);
        let mut beside: f64 = 0.0;
        let (res, cycles) = run_episode(
            &world,
            EpisodeConfig::default(),
            &mut sys,
            &Schedule::ddp_default(),
            1.5,
            3,
            None,
            |ep, _, _| {
                let p = ep.state().pose;
                if (p.y - 4.0).abs() < 0.3 {
                    beside = beside.max(p.x.abs());
                }
            },
        );
        assert_eq!(res.status, Status::Succeeded, "{res:?}");
        // Passing beside the cylinder needs |x| >= 0.25 + 0.215 (its radius + half width).
        assert!(beside > 0.465, "went around: |x| = {beside}");
        assert!(sys.evaluated_points() > cycles.cycles);
    }

    #[test]
    fn follows_a_schedule_that_changes_every_quarter_second() {
        // ADP: the policy picks a new (p, T, N, alpha) every 5 cycles.
        let world = corridor_with_cylinder();
        let schedules = [
            Schedule::decremental(1.0, 1.6, 15, 0.6, 20).unwrap(),
            Schedule::decremental(1.7, 2.2, 22, 0.0, 20).unwrap(),
            Schedule::decremental(1.4, 1.9, 18, 0.3, 20).unwrap(),
        ];
        let mut ep = Episode::new(&world, EpisodeConfig::default(), 5);
        let mut sys = NavSystem::new(SystemConfig::default(), 5);
        let mut cycle = 0;
        while ep.status() == Status::Running {
            let sched = &schedules[(cycle / 5) % schedules.len()];
            let cmd = sys.plan(&PlanInput {
                perception: ep.perception(),
                schedule: sched,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving: &[],
            });
            ep.step(cmd);
            cycle += 1;
        }
        assert_eq!(ep.status(), Status::Succeeded, "{:?}", ep.result());
    }

    /// Commands of the first `n` cycles on a BARN world.
    fn commands(seed: u64, n: usize, record: bool) -> (Vec<Twist>, u64, usize) {
        let world = sim::catalog::world(120).unwrap();
        let mut ep = Episode::new(world, EpisodeConfig::default(), 1);
        let mut sys = NavSystem::new(SystemConfig::default(), seed);
        sys.set_recording(record);
        let sched = Schedule::ddp_default();
        let mut out = Vec::new();
        let mut spans = 0;
        for _ in 0..n {
            let cmd = sys.plan(&PlanInput {
                perception: ep.perception(),
                schedule: &sched,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving: &[],
            });
            spans = spans.max(sys.rollouts().spans.len());
            out.push(cmd);
            if ep.step(cmd) != Status::Running {
                break;
            }
        }
        (out, sys.evaluated_points(), spans)
    }

    #[test]
    fn same_seed_same_commands() {
        let (a, pa, _) = commands(7, 60, false);
        let (b, pb, spans) = commands(7, 60, true);
        assert_eq!(a, b, "recording does not change the plan");
        assert_eq!(pa, pb);
        assert!(spans >= 550, "one recorded rollout per sample: {spans}");
        let (c, _, _) = commands(8, 60, false);
        assert_ne!(a, c, "the noise comes from the seed");
    }

    #[test]
    fn previous_solution_is_among_the_samples() {
        let world = sim::catalog::world(120).unwrap();
        let ep = Episode::new(world, EpisodeConfig::default(), 1);
        let cfg = SystemConfig::default();
        let mut sys = NavSystem::new(cfg, 1);
        let sched = Schedule::ddp_default();
        let input = PlanInput {
            perception: ep.perception(),
            schedule: &sched,
            max_speed: 1.5,
            prediction: crate::Prediction::PAPERS,
            budget: crate::Budget::UNLIMITED,
            moving: &[],
        };
        let first = sys.plan(&input);
        sys.plan(&input);
        let grid = cfg.v_samples * cfg.w_samples;
        // The robot has not moved: the window is the same, and the first command lies in it.
        assert!(sys.nominal[grid..grid + cfg.warm_samples]
            .iter()
            .all(|&t| t == first));
        assert!(first.v > 0.0);
    }
}
