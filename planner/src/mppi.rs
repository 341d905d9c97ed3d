//! Model Predictive Path Integral control (Williams et al.) over a fidelity schedule.
//!
//! The planner keeps a nominal control sequence, one (v, w) command per schedule step,
//! warm-started from the previous cycle: the old sequence is read as piecewise constant in
//! time and resampled one control period later onto the current schedule's step grid. Each
//! cycle draws `samples` control sequences, most of them the nominal plus Gaussian noise per
//! step, a few around braking and a few around constant commands from the dynamic window (so
//! the warm start cannot trap the search), all clamped to the limits. Every sample is rolled
//! out over the schedule (the velocity approaching each command at the acceleration limits,
//! then exact arcs), the footprint is checked after every step with the schedule's check
//! density, and the rollout is scored on goal progress, distance to the local path, obstacle
//! clearance, heading and smoothness. A rollout collides when its estimated clearance drops
//! below the margin, or below the estimate at the robot's own pose at the same check density
//! when that is lower (the estimate is conservative, so the current, collision-free pose
//! calibrates it; without this the robot freezes in tight gaps). If every sample collides the
//! robot stops and turns toward the local goal. The nominal sequence becomes the importance-weighted
//! mean of the sampled sequences, weights `exp(-(J - J_min) / lambda)`, either over all
//! samples or (the papers' choice) over the `top_k` cheapest collision-free ones. The command
//! is the new sequence averaged over the first control period.
//!
//! Noise is drawn sequentially from one seeded generator, then the rollouts run in parallel
//! (rayon) into preallocated per-sample slots, so a seed gives the same commands whatever the
//! thread layout.

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sim::geometry::{wrap_angle, Pose, Vec2};
use sim::robot::{approach, Twist};

use crate::compute::{admit, evaluation_order, Work};
use crate::local_map::LocalMap;
use crate::path_distance::PathDistance;
use crate::{Gains, GainsError, Integrator, PlanInput, Planner, Predicted, Rollouts, Trace};

/// MPPI parameters (defaults used by `adp eval`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MppiConfig {
    /// Control sequences sampled per cycle.
    pub samples: usize,
    /// Standard deviation of the per-step linear-velocity noise (m/s).
    pub sigma_v: f64,
    /// Standard deviation of the per-step angular-velocity noise (rad/s).
    pub sigma_w: f64,
    /// Temperature of the weights `exp(-(J - J_min) / lambda)`; must be > 0.
    pub lambda: f64,
    /// Average only the `top_k` cheapest collision-free samples; 0 = all samples.
    pub top_k: usize,
    /// Share of the samples drawn around braking (v = 0, w = 0) instead of the nominal.
    pub brake_fraction: f64,
    /// Share of the samples drawn around a constant command from the dynamic window.
    pub explore_fraction: f64,
    /// Planner's yaw-rate cap (rad/s).
    pub max_w: f64,
    /// Linear acceleration assumed in rollouts and the window (m/s^2).
    pub accel_v: f64,
    /// Angular acceleration assumed in rollouts and the window (rad/s^2).
    pub accel_w: f64,
    /// One control period (s): the warm-start shift, the span the command averages over and
    /// the time the dynamic window is reachable in.
    pub control_dt: f64,
    /// A rollout whose estimated clearance drops below this collides (m). The estimate is
    /// conservative, more so with fewer check points; when at some check density it is
    /// already lower at the robot's own (collision-free) pose, the limit for that density
    /// becomes that estimate: the robot may stay or move away, but not closer.
    pub margin: f64,
    /// Clearances above this cost nothing (m).
    pub clearance_cap: f64,
    /// Cost of a collision (doubled for one at the start of the rollout).
    pub collision_cost: f64,
    /// Weight of the goal term: the mean distance to the local goal over the rollout's last
    /// `goal_tail` share of grid points (per m).
    pub w_goal: f64,
    /// Share of the rollout's grid points, counted from its end, whose distance to the local
    /// goal the goal term averages (at least the end point; 0 = the end point only). The
    /// authors' MPPI sums steps 15 to N - 2 of 20, about the last quarter; the end point alone
    /// makes a long DDP horizon prefer commands that stop near the goal, i.e. slow ones.
    pub goal_tail: f64,
    /// Weight of the end point's distance to the local path (per m).
    pub w_path: f64,
    /// Weight of the obstacle-proximity cost (0 at the clearance cap, 1 at contact).
    pub w_obstacle: f64,
    /// Weight of the end heading's error to the local goal's bearing (per pi rad).
    pub w_heading: f64,
    /// Weight of the squared command changes between steps (per (m/s)^2 and (rad/s)^2).
    pub w_smooth: f64,
    /// Distance-field cell size (m).
    pub map_resolution: f64,
}

impl Default for MppiConfig {
    fn default() -> Self {
        Self {
            samples: 550,
            sigma_v: 0.1,
            sigma_w: 0.05,
            lambda: 1.0,
            top_k: 10,
            brake_fraction: 0.05,
            explore_fraction: 0.2,
            max_w: 2.0,
            accel_v: 20.0,
            accel_w: 25.0,
            control_dt: 0.05,
            margin: 0.02,
            clearance_cap: 0.5,
            collision_cost: 100.0,
            w_goal: 4.0,
            goal_tail: 0.25,
            w_path: 4.0,
            w_obstacle: 2.0,
            w_heading: 1.0,
            w_smooth: 0.5,
            map_resolution: 0.05,
        }
    }
}

/// The MPPI planner. Owns its buffers and its random stream; one per episode.
#[derive(Clone, Debug)]
pub struct Mppi {
    /// The configuration, its objective weights scaled by the gain factors.
    cfg: MppiConfig,
    /// The configured (hand-tuned) weights, in [`Gains::Mppi`] order.
    tuned: [f64; 5],
    rng: Pcg64Mcg,
    map: LocalMap,
    /// The warm-start sequence and its grid.
    nominal: Nominal,
    /// Sampled sequences, `samples x steps`, clamped to the limits.
    controls: Vec<Twist>,
    outcomes: Vec<Outcome>,
    /// Collision threshold per check density (see [`MppiConfig::margin`]).
    margins: Vec<f64>,
    /// The cycle's local path, prepared for the samples' path cost.
    path: PathDistance,
    order: Vec<usize>,
    /// Samples in evaluation order under a compute budget ([`crate::compute::even_order`]).
    eval_order: Vec<u32>,
    /// Whether the budget let each sample be evaluated.
    admitted: Vec<bool>,
    selected_costs: Vec<f64>,
    weights: Vec<f64>,
    trace: Trace,
}

/// What one rollout cost.
#[derive(Clone, Copy, Debug, Default)]
struct Outcome {
    cost: f64,
    collision_free: bool,
    evaluated: u64,
    /// Integration steps rolled out.
    steps: u64,
}

/// The cycle's inputs shared by all rollouts.
struct Scene<'a> {
    cfg: &'a MppiConfig,
    map: &'a LocalMap,
    dts: &'a [f64],
    checks: &'a [u16],
    start: Twist,
    goal: Vec2,
    /// First grid point of the goal term's tail.
    tail_start: usize,
    /// The local path (path cost of the end point).
    path: &'a PathDistance,
    /// Collision threshold on the estimated clearance (m), per check density.
    margins: &'a [f64],
    /// The rollout integrator.
    integrator: Integrator,
    /// Moving obstacles, checked where they will be ([`crate::moving`]).
    moving: &'a [Predicted],
}

impl Mppi {
    /// An MPPI planner whose sampling is driven by `seed`.
    pub fn new(cfg: MppiConfig, seed: u64) -> Self {
        Self {
            cfg,
            tuned: [
                cfg.w_goal,
                cfg.w_path,
                cfg.w_obstacle,
                cfg.w_heading,
                cfg.w_smooth,
            ],
            rng: Pcg64Mcg::seed_from_u64(seed),
            map: LocalMap::jackal(cfg.map_resolution),
            nominal: Nominal::default(),
            controls: Vec::new(),
            outcomes: Vec::new(),
            margins: Vec::new(),
            path: PathDistance::default(),
            order: Vec::new(),
            eval_order: Vec::new(),
            admitted: Vec::new(),
            selected_costs: Vec::new(),
            weights: Vec::new(),
            trace: Trace::default(),
        }
    }

    /// Draws every sample's control sequence into `controls` (sequentially, so the stream
    /// does not depend on threads). Sample 0 is the nominal itself.
    fn sample(&mut self, start: Twist, max_speed: f64) {
        let cfg = self.cfg;
        let steps = self.nominal.seq.len();
        let n = cfg.samples.max(1);
        let n_brake = (cfg.brake_fraction * n as f64).round() as usize;
        let n_explore = (cfg.explore_fraction * n as f64).round() as usize;
        let v_lo = (start.v - cfg.accel_v * cfg.control_dt).max(0.0);
        let v_hi = (start.v + cfg.accel_v * cfg.control_dt).min(max_speed).max(v_lo);
        let w_lo = (start.w - cfg.accel_w * cfg.control_dt).max(-cfg.max_w);
        let w_hi = (start.w + cfg.accel_w * cfg.control_dt).min(cfg.max_w).max(w_lo);
        self.controls.clear();
        for i in 0..n {
            // The base each sample perturbs: nominal, braking, or a constant window command.
            let constant = if i == 0 || i > n_brake + n_explore {
                None
            } else if i <= n_brake {
                Some(Twist::default())
            } else {
                let a: f64 = self.rng.random();
                let b: f64 = self.rng.random();
                Some(Twist::new(v_lo + a * (v_hi - v_lo), w_lo + b * (w_hi - w_lo)))
            };
            for k in 0..steps {
                let base = constant.unwrap_or(self.nominal.seq[k]);
                let (dv, dw) = if i == 0 {
                    (0.0, 0.0)
                } else {
                    let a: f64 = self.rng.sample(StandardNormal);
                    let b: f64 = self.rng.sample(StandardNormal);
                    (cfg.sigma_v * a, cfg.sigma_w * b)
                };
                self.controls.push(Twist::new(
                    (base.v + dv).clamp(0.0, max_speed),
                    (base.w + dw).clamp(-cfg.max_w, cfg.max_w),
                ));
            }
        }
    }

    /// Indices (into `outcomes`) of the samples that enter the average, cheapest first, and
    /// their weights in `weights`. False if no sample qualifies.
    fn select(&mut self) -> bool {
        let cfg = self.cfg;
        self.order.clear();
        let admitted = &self.admitted;
        if cfg.top_k == 0 {
            self.order
                .extend((0..self.outcomes.len()).filter(|&i| admitted[i]));
        } else {
            let outcomes = &self.outcomes;
            self.order
                .extend((0..outcomes.len()).filter(|&i| admitted[i] && outcomes[i].collision_free));
            self.order
                .sort_unstable_by(|&a, &b| outcomes[a].cost.total_cmp(&outcomes[b].cost).then(a.cmp(&b)));
            self.order.truncate(cfg.top_k);
        }
        if !self
            .outcomes
            .iter()
            .zip(admitted)
            .any(|(o, &a)| a && o.collision_free)
        {
            return false;
        }
        self.selected_costs.clear();
        self.selected_costs
            .extend(self.order.iter().map(|&i| self.outcomes[i].cost));
        mppi_weights(&self.selected_costs, cfg.lambda, &mut self.weights);
        true
    }
}

impl Mppi {
    /// Decides which of this cycle's samples the compute budget admits (see
    /// [`crate::compute::admit`]) and records the cycle's work in `trace.cycle` and its points
    /// in `trace.evaluated`. Sample `i` drew two normals per step, plus two uniforms for an
    /// exploring sample.
    fn budget_cycle(&mut self, input: &PlanInput<'_>, steps: usize, points_at_start: u64) {
        let n = self.outcomes.len();
        let cfg = &self.cfg;
        let n_brake = (cfg.brake_fraction * n as f64).round() as usize;
        let n_explore = (cfg.explore_fraction * n as f64).round() as usize;
        evaluation_order(&input.budget, n, &mut self.eval_order);
        self.admitted.resize(n, false);
        let spent = Work {
            cells: self.map.cells() as u64,
            points: self.trace.evaluated - points_at_start,
            ..Work::default()
        };
        let outcomes = &self.outcomes;
        let work_of = |i: usize| Work {
            samples: 1,
            draws: if i == 0 { 0 } else { 2 * steps as u64 }
                + if i > n_brake && i <= n_brake + n_explore {
                    2
                } else {
                    0
                },
            steps: outcomes[i].steps,
            points: outcomes[i].evaluated,
            cells: 0,
        };
        let cycle = admit(
            &input.budget,
            spent,
            &self.eval_order,
            work_of,
            &mut self.admitted,
        );
        self.trace.evaluated += cycle.work.points - spent.points;
        self.trace.cycle = cycle;
        self.trace.rollouts.mark_skipped(&self.admitted);
    }
}

/// Normalised path-integral weights: `out[i] = exp(-(costs[i] - min) / lambda) / sum`.
///
/// Subtracting the minimum keeps the exponentials in range and makes the weights invariant
/// to adding a constant to every cost. `out` is cleared first; empty costs give no weights.
pub fn mppi_weights(costs: &[f64], lambda: f64, out: &mut Vec<f64>) {
    out.clear();
    let min = costs.iter().copied().fold(f64::INFINITY, f64::min);
    let lambda = lambda.max(f64::MIN_POSITIVE);
    out.extend(costs.iter().map(|&j| (-(j - min) / lambda).exp()));
    // The cheapest sample contributes exp(0) = 1, so the sum is at least 1.
    let sum: f64 = out.iter().sum();
    for w in out.iter_mut() {
        *w /= sum;
    }
}

/// Warm start: reads `old` (step `j` lasting `old_dts[j]`) as a piecewise-constant control
/// signal, delays it by `shift` seconds (time t of the new sequence is time t + shift of the
/// old one), and samples it at the middle of each step of `new_dts` into `out`. Times past
/// the old horizon repeat its last command; an empty `old` gives zero commands.
pub fn shift_sequence(old: &[Twist], old_dts: &[f64], new_dts: &[f64], shift: f64, out: &mut Vec<Twist>) {
    out.clear();
    if old.is_empty() || old_dts.len() != old.len() {
        out.resize(new_dts.len(), Twist::default());
        return;
    }
    let (mut j, mut old_end, mut t) = (0, old_dts[0], 0.0);
    for &dt in new_dts {
        let q = t + 0.5 * dt + shift;
        while j + 1 < old.len() && q >= old_end {
            j += 1;
            old_end += old_dts[j];
        }
        out.push(old[j]);
        t += dt;
    }
}

/// Mean of the piecewise-constant sequence `seq` (step `k` lasting `dts[k]`) over the first
/// `span` seconds (the last command continues past the horizon).
pub fn average_over(seq: &[Twist], dts: &[f64], span: f64) -> Twist {
    let (mut v, mut w, mut t) = (0.0, 0.0, 0.0);
    for (u, &dt) in seq.iter().zip(dts) {
        let d = dt.min(span - t);
        if d <= 0.0 {
            break;
        }
        v += u.v * d;
        w += u.w * d;
        t += d;
    }
    if let Some(last) = seq.last() {
        if t < span {
            v += last.v * (span - t);
            w += last.w * (span - t);
            t = span;
        }
    }
    if t > 0.0 {
        Twist::new(v / t, w / t)
    } else {
        Twist::default()
    }
}

/// The warm-start control sequence of MPPI and log-MPPI: one command per step of the grid
/// `dts`, and scratch memory for updating it without allocation. Plain data, one per planner.
#[derive(Clone, Debug, Default)]
pub(crate) struct Nominal {
    /// The sequence.
    pub(crate) seq: Vec<Twist>,
    /// Its grid (step lengths, s).
    pub(crate) dts: Vec<f64>,
    /// Scratch for the shifted or updated sequence (swapped with `seq`).
    pub(crate) scratch: Vec<Twist>,
}

impl Nominal {
    /// Moves the sequence one control period `shift` later onto the new grid `dts`, and makes
    /// `dts` its grid.
    pub(crate) fn warm_start(&mut self, dts: &[f64], shift: f64) {
        shift_sequence(&self.seq, &self.dts, dts, shift, &mut self.scratch);
        std::mem::swap(&mut self.seq, &mut self.scratch);
        self.dts.clear();
        self.dts.extend_from_slice(dts);
    }

    /// Writes into `scratch` the weighted mean of `samples` (sequences of `steps` controls,
    /// each with its weight; the weights sum to one). `seq` is left unchanged: the caller
    /// makes the mean its new sequence, as it is or filtered.
    pub(crate) fn blend<'a>(&mut self, steps: usize, samples: impl Iterator<Item = (&'a [Twist], f64)>) {
        self.scratch.clear();
        self.scratch.resize(steps, Twist::default());
        for (seq, wt) in samples {
            for (acc, u) in self.scratch.iter_mut().zip(seq) {
                acc.v += wt * u.v;
                acc.w += wt * u.w;
            }
        }
    }

    /// The command of the updated sequence on its grid: its mean over the first control
    /// period `span`, clamped to forward speeds up to `max_speed` and turn rates up to `max_w`.
    pub(crate) fn command(&self, span: f64, max_speed: f64, max_w: f64) -> Twist {
        let cmd = average_over(&self.seq, &self.dts, span);
        Twist::new(cmd.v.clamp(0.0, max_speed), cmd.w.clamp(-max_w, max_w))
    }
}

/// Rolls out every sample of `controls` (one control per step of the grid `dts`) in parallel
/// into `outcomes`, then, when `trace` is recording, once more serially into its rollouts.
pub(crate) fn roll_all<O: Send>(
    controls: &[Twist],
    outcomes: &mut [O],
    trace: &mut Trace,
    dts: &[f64],
    roll: impl Fn(&[Twist], Option<&mut Rollouts>) -> O + Sync,
) {
    let steps = dts.len().max(1);
    controls
        .par_chunks(steps)
        .zip(outcomes.par_iter_mut())
        .with_min_len(16)
        .for_each(|(u, out)| *out = roll(u, None));
    if trace.recording {
        trace.rollouts.clear(dts);
        for u in controls.chunks(steps) {
            roll(u, Some(&mut trace.rollouts));
        }
    }
}

/// The rollout model: a unicycle whose velocity approaches each step's command at the
/// acceleration limits, then moves with that velocity for the step by the prediction's
/// integrator (robot frame, starting at the origin).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Unicycle {
    /// Forward position (m).
    pub(crate) x: f64,
    /// Leftward position (m).
    pub(crate) y: f64,
    /// Heading, not wrapped (rad).
    pub(crate) yaw: f64,
    /// `yaw.sin_cos()`, carried from step to step by the integrator.
    sin: f64,
    /// See `sin`.
    cos: f64,
    /// Current velocity.
    vel: Twist,
    integrator: Integrator,
}

impl Unicycle {
    /// At the origin, heading +x, moving with `vel`, integrated by `integrator`.
    pub(crate) fn new(vel: Twist, integrator: Integrator) -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            yaw: 0.0,
            sin: 0.0,
            cos: 1.0,
            vel,
            integrator,
        }
    }

    /// Applies `cmd` for `dt` seconds under the acceleration limits.
    pub(crate) fn step(&mut self, cmd: Twist, dt: f64, accel_v: f64, accel_w: f64) {
        let v = approach(self.vel.v, cmd.v, accel_v * dt);
        let w = approach(self.vel.w, cmd.w, accel_w * dt);
        self.vel = Twist::new(v, w);
        let mut pose = self.pose();
        let mut sc = (self.sin, self.cos);
        self.integrator.advance(&mut pose, &mut sc, v, w, dt);
        (self.x, self.y, self.yaw) = (pose.x, pose.y, pose.yaw);
        (self.sin, self.cos) = sc;
    }

    /// The pose (heading not wrapped).
    pub(crate) fn pose(&self) -> Pose {
        Pose::new(self.x, self.y, self.yaw)
    }
}

/// Rolls `controls` out from the robot (origin, velocity `scene.start`) and scores it;
/// records the poses when `record` is given.
fn rollout(scene: &Scene<'_>, controls: &[Twist], mut record: Option<&mut Rollouts>) -> Outcome {
    let cfg = scene.cfg;
    let mut robot = Unicycle::new(scene.start, scene.integrator);
    let mut prev = scene.start;
    let (mut min_clear, mut smooth, mut evaluated) = (cfg.clearance_cap, 0.0, 0u64);
    let (mut t, mut hit) = (0.0, None);
    // Sum and count of the tail's clear points' distances to the local goal.
    let (mut goal_sum, mut goal_n) = (0.0, 0u32);
    let mut steps = 0u64;
    if let Some(r) = record.as_deref_mut() {
        r.begin();
    }
    for (k, (&cmd, &dt)) in controls.iter().zip(scene.dts).enumerate() {
        steps += 1;
        smooth += (cmd.v - prev.v).powi(2) + (cmd.w - prev.w).powi(2);
        prev = cmd;
        robot.step(cmd, dt, cfg.accel_v, cfg.accel_w);
        t += dt;
        let pose = robot.pose();
        if let Some(r) = record.as_deref_mut() {
            r.push(Pose::new(pose.x, pose.y, wrap_angle(pose.yaw)));
        }
        let m = (scene.checks[k] as usize).min(scene.margins.len() - 1);
        // Only a clearance below the running minimum or the margin changes the outcome (a
        // moving obstacle's clearance enters through the same `min`). The robot carries the
        // (sin, cos) of its unwrapped yaw, the value `pose.yaw.sin_cos()` gives.
        let mut clear = scene.map.clearance_above(
            pose.position(),
            || (robot.sin, robot.cos),
            scene.checks[k] as usize,
            cfg.clearance_cap,
            min_clear.max(scene.margins[m]),
            &mut evaluated,
        );
        if !scene.moving.is_empty() {
            let fp = scene.map.footprint();
            clear = clear.min(crate::moving::clearance(
                fp,
                &pose,
                t,
                scene.moving,
                &mut evaluated,
            ));
        }
        if clear < scene.margins[m] {
            hit = Some(t);
            break;
        }
        min_clear = min_clear.min(clear);
        if k >= scene.tail_start {
            goal_sum += (scene.goal - Vec2::new(pose.x, pose.y)).norm();
            goal_n += 1;
        }
    }
    if let Some(r) = record {
        r.end(hit.is_none());
    }
    let end = Vec2::new(robot.x, robot.y);
    let to_goal = scene.goal - end;
    // A rollout that collides before its tail is scored on the point where it stopped.
    let goal_dist = if goal_n > 0 {
        goal_sum / f64::from(goal_n)
    } else {
        to_goal.norm()
    };
    let heading = if to_goal.norm() > 0.3 {
        wrap_angle(to_goal.y.atan2(to_goal.x) - robot.yaw).abs() / std::f64::consts::PI
    } else {
        0.0
    };
    let mut cost = cfg.w_goal * goal_dist
        + cfg.w_path * scene.path.distance(end)
        + cfg.w_obstacle * (cfg.clearance_cap - min_clear) / cfg.clearance_cap
        + cfg.w_heading * heading
        + cfg.w_smooth * smooth;
    if let Some(t_hit) = hit {
        let horizon: f64 = scene.dts.iter().sum();
        cost += cfg.collision_cost * (2.0 - t_hit / horizon.max(1e-9));
    }
    Outcome {
        cost,
        collision_free: hit.is_none(),
        evaluated,
        steps,
    }
}

impl Planner for Mppi {
    crate::planner_identity!("mppi");

    fn gains(&self) -> Option<Gains> {
        Some(Gains::Mppi)
    }

    fn set_gain_factors(&mut self, factors: &[f64]) -> Result<(), GainsError> {
        Gains::Mppi.check(factors)?;
        let t = self.tuned;
        let c = &mut self.cfg;
        (c.w_goal, c.w_path, c.w_obstacle, c.w_heading, c.w_smooth) = (
            t[0] * factors[0],
            t[1] * factors[1],
            t[2] * factors[2],
            t[3] * factors[3],
            t[4] * factors[4],
        );
        Ok(())
    }

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        let cfg = self.cfg;
        let per = &input.perception;
        let sched = input.schedule;
        let steps = sched.len();
        let points_at_start = self.trace.evaluated;
        self.map.prepare(per.points, input, 1.0, cfg.clearance_cap);

        // Warm start: the last nominal, one control period later, on this schedule's grid.
        self.nominal.warm_start(sched.dts(), cfg.control_dt);

        let start = per.vel;
        self.path.prepare(per.local_path, per.local_goal);
        self.margins.clear();
        for m in 0..=self.map.boundary_points() {
            let here = self.map.footprint_clearance(
                &Pose::default(),
                m,
                cfg.clearance_cap,
                &mut self.trace.evaluated,
            );
            self.margins.push(cfg.margin.min(here));
        }
        self.sample(start, input.max_speed);
        let n = self.controls.len() / steps.max(1);
        self.outcomes.resize(n, Outcome::default());
        let scene = Scene {
            cfg: &self.cfg,
            map: &self.map,
            dts: sched.dts(),
            checks: sched.checks(),
            start,
            goal: per.local_goal,
            tail_start: steps.saturating_sub(((self.cfg.goal_tail * steps as f64).ceil() as usize).max(1)),
            path: &self.path,
            margins: &self.margins,
            integrator: input.prediction.integrator,
            moving: input.moving,
        };
        let roll = |u: &[Twist], record: Option<&mut Rollouts>| rollout(&scene, u, record);
        let dts = sched.dts();
        roll_all(&self.controls, &mut self.outcomes, &mut self.trace, dts, roll);
        self.budget_cycle(input, steps, points_at_start);

        if !self.select() {
            // Every sample collides: stop, turn toward the local goal, and restart the
            // search from turning in place.
            let bearing = per.local_goal.y.atan2(per.local_goal.x);
            let cmd = Twist::new(0.0, bearing.clamp(-1.0, 1.0));
            self.nominal.seq.iter_mut().for_each(|u| *u = cmd);
            return cmd;
        }
        let controls = &self.controls;
        let best = self.order.iter().map(|&i| &controls[i * steps..(i + 1) * steps]);
        self.nominal.blend(steps, best.zip(self.weights.iter().copied()));
        std::mem::swap(&mut self.nominal.seq, &mut self.nominal.scratch);
        self.nominal.command(cfg.control_dt, input.max_speed, cfg.max_w)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::run::run_episode;
    use crate::Schedule;
    use sim::geometry::Circle;
    use sim::{EpisodeConfig, Status, World};

    #[test]
    fn weights_sum_to_one_and_ignore_a_constant_offset() {
        let costs = [3.0, 1.5, 7.25, 1.5, 40.0, 2.0];
        let mut w = Vec::new();
        mppi_weights(&costs, 1.0, &mut w);
        assert_eq!(w.len(), costs.len());
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // Cheaper is heavier; equal costs weigh the same.
        assert!(w[1] > w[5] && w[5] > w[0] && w[0] > w[2] && w[2] > w[4]);
        assert_eq!(w[1], w[3]);
        assert!((w[0] / w[1] - (-1.5f64).exp()).abs() < 1e-12);
        let mut shifted = Vec::new();
        let offset: Vec<f64> = costs.iter().map(|c| c + 1234.5).collect();
        mppi_weights(&offset, 1.0, &mut shifted);
        for (a, b) in w.iter().zip(&shifted) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        // A lower temperature concentrates the weight on the cheapest samples.
        mppi_weights(&costs, 0.1, &mut shifted);
        assert!(shifted[1] > w[1] && (shifted.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        mppi_weights(&[], 1.0, &mut shifted);
        assert!(shifted.is_empty());
    }

    #[test]
    fn warm_start_shift_resamples_in_time() {
        let seq: Vec<Twist> = (0..20).map(|k| Twist::new(k as f64, -(k as f64))).collect();
        let vanilla = Schedule::vanilla();
        let mut out = Vec::new();
        // Uniform grid: one control period drops the first step and repeats the last.
        shift_sequence(&seq, vanilla.dts(), vanilla.dts(), 0.05, &mut out);
        let expect: Vec<Twist> = (1..20).chain([19]).map(|k| seq[k]).collect();
        assert_eq!(out, expect);
        // No shift on the same grid is the identity.
        shift_sequence(&seq, vanilla.dts(), vanilla.dts(), 0.0, &mut out);
        assert_eq!(out, seq);
        // Onto the DDP grid: each new step takes the old step covering its middle + 0.05 s.
        let ddp = Schedule::ddp_default();
        shift_sequence(&seq, vanilla.dts(), ddp.dts(), 0.05, &mut out);
        let mut t = 0.0;
        for (k, &dt) in ddp.dts().iter().enumerate() {
            let q = t + 0.5 * dt + 0.05;
            let j = ((q / 0.05).floor() as usize).min(19);
            assert_eq!(out[k], seq[j], "step {k} at {q}");
            t += dt;
        }
        // Back from DDP onto vanilla: vanilla step k (middle 0.05k + 0.025) reads the DDP
        // step covering 0.05(k + 1) + 0.025.
        let ddp_seq: Vec<Twist> = (0..20).map(|k| Twist::new(k as f64, 0.0)).collect();
        shift_sequence(&ddp_seq, ddp.dts(), vanilla.dts(), 0.05, &mut out);
        let ends: Vec<f64> = ddp
            .dts()
            .iter()
            .scan(0.0, |s, d| {
                *s += d;
                Some(*s)
            })
            .collect();
        for (k, u) in out.iter().enumerate() {
            let q = 0.05 * (k + 1) as f64 + 0.025;
            let j = ends.iter().position(|&e| q < e).unwrap_or(19);
            assert_eq!(u.v, j as f64, "step {k}");
        }
        // Cold start: zeros.
        shift_sequence(&[], &[], ddp.dts(), 0.05, &mut out);
        assert!(out.len() == 20 && out.iter().all(|u| *u == Twist::default()));
        // The command averages the first control period.
        let avg = average_over(&ddp_seq, ddp.dts(), 0.05);
        let d = ddp.dts();
        let expect_v = (d[1] * 1.0 + (0.05 - d[0] - d[1]) * 2.0) / 0.05;
        assert!((avg.v - expect_v).abs() < 1e-12, "{avg:?} vs {expect_v}");
    }

    /// A 3 m wide corridor along +y with one cylinder in the middle of the straight route.
    pub(crate) fn corridor_with_cylinder() -> (World, Circle) {
        let block = Circle {
            c: Vec2::new(0.0, 4.0),
            r: 0.35,
        };
        (World::corridor(1.5, &[block]), block)
    }

    /// Runs `planner` through [`corridor_with_cylinder`]; returns the status and the
    /// closest approach of the robot centre to the cylinder's centre.
    pub(crate) fn drive_around(
        planner: &mut dyn Planner,
        schedule: &Schedule,
        profile: sim::Profile,
    ) -> (Status, f64) {
        let (world, block) = corridor_with_cylinder();
        let mut closest = f64::INFINITY;
        let (res, _) = run_episode(
            &world,
            EpisodeConfig::default().with_profile(profile, None),
            planner,
            schedule,
            1.5,
            3,
            None,
            |ep, _, _| {
                closest = closest.min(ep.state().pose.position().dist(block.c));
            },
        );
        (res.status, closest)
    }

    /// The first `n` commands of `planner` in [`corridor_with_cylinder`].
    pub(crate) fn commands(planner: &mut dyn Planner, schedule: &Schedule, n: usize) -> Vec<Twist> {
        let (world, _) = corridor_with_cylinder();
        let mut ep = sim::Episode::new(&world, EpisodeConfig::default(), 3);
        let mut out = Vec::new();
        for _ in 0..n {
            let cmd = planner.plan(&PlanInput {
                perception: ep.perception(),
                schedule,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving: &[],
            });
            out.push(cmd);
            ep.step(cmd);
        }
        out
    }

    #[test]
    fn avoids_a_cylinder_on_the_straight_route() {
        for schedule in [Schedule::vanilla(), Schedule::ddp_default()] {
            let mut mppi = Mppi::new(MppiConfig::default(), 11);
            let (status, closest) = drive_around(&mut mppi, &schedule, sim::Profile::GazeboJackal);
            assert_eq!(status, Status::Succeeded);
            // The centre stayed further from the cylinder than its radius plus half the robot.
            assert!(closest > 0.35 + 0.215, "closest approach {closest}");
            assert!(mppi.evaluated_points() > 0);
        }
    }

    /// One cycle of 5 samples over 4 steps with 4 boundary points in open space. Sample 0 is
    /// the noise-free nominal (no draws); sample 1 explores, since round(0.2 x 5) is 1 and
    /// round(0.05 x 5) is 0 (no braking sample): 2 uniforms and 2 normals per step, 10 draws;
    /// samples 2..4 draw 8 each: 34 draws. 20 steps; the margins (5 checks) and one centre
    /// check per step (20).
    #[test]
    fn one_cycle_counts_its_units() {
        let perception = sim::Perception {
            ranges: &[],
            points: &[],
            vel: Twist::default(),
            local_goal: Vec2::new(2.0, 0.0),
            local_path: &[],
            goal: Vec2::new(5.0, 0.0),
        };
        let schedule = Schedule::uniform(0.1, 4, 4).unwrap();
        let mut mppi = Mppi::new(
            MppiConfig {
                samples: 5,
                ..MppiConfig::default()
            },
            3,
        );
        mppi.plan(&PlanInput {
            perception,
            schedule: &schedule,
            max_speed: 1.0,
            prediction: crate::Prediction::PAPERS,
            budget: crate::Budget::UNLIMITED,
            moving: &[],
        });
        let c = mppi.trace().cycle;
        // Field: reach = 1.0 x 0.4 + 0.33278 + 0.5 = 1.23278 m: 46 x 51 cells at 0.05 m.
        let want = crate::Work {
            cells: 46 * 51,
            samples: 5,
            draws: 34,
            steps: 20,
            points: 25,
        };
        assert_eq!((c.work, c.samples, c.evaluated), (want, 5, 5));
        assert_eq!(mppi.evaluated_points(), 25);
    }

    #[test]
    fn same_seed_same_commands() {
        let sched = Schedule::ddp_default();
        let a = commands(&mut Mppi::new(MppiConfig::default(), 5), &sched, 40);
        let b = commands(&mut Mppi::new(MppiConfig::default(), 5), &sched, 40);
        let c = commands(&mut Mppi::new(MppiConfig::default(), 6), &sched, 40);
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.iter().any(|u| u.v > 0.5), "it drives");
    }

    /// The goal term of a rollout that reaches the goal early and waits there is 0 over any
    /// tail; one that creeps and arrives only at the end pays for its tail's distances.
    #[test]
    fn goal_term_averages_the_tail() {
        let mut map = LocalMap::new(sim::Footprint::JACKAL, 0.05, 0);
        map.build(&[], 1.0, 3.0);
        let dts = [0.1; 20];
        let checks = [0u16; 20];
        let mut path = PathDistance::default();
        path.prepare(&[], Vec2::new(1.0, 0.0));
        let cost = |goal_tail: f64, v: &dyn Fn(usize) -> f64| {
            let cfg = MppiConfig {
                goal_tail,
                ..Default::default()
            };
            let tail_start = 20 - ((goal_tail * 20.0).ceil() as usize).max(1);
            let scene = Scene {
                cfg: &cfg,
                map: &map,
                dts: &dts,
                checks: &checks,
                start: Twist::new(0.0, 0.0),
                goal: Vec2::new(1.0, 0.0),
                tail_start,
                path: &path,
                margins: &[cfg.margin],
                integrator: Integrator::Euler,
                moving: &[],
            };
            let controls: Vec<Twist> = (0..20).map(|k| Twist::new(v(k), 0.0)).collect();
            let out = rollout(&scene, &controls, None);
            assert!(out.collision_free);
            out.cost
        };
        // 1 m/s for 1 s, then stopped at the goal; 0.5 m/s for 2 s, at the goal at the end.
        let early = |k: usize| if k < 10 { 1.0 } else { 0.0 };
        let creep = |_: usize| 0.5;
        assert!((cost(0.5, &early) - cost(0.0, &early)).abs() < 1e-9);
        // Tail = steps 10..19 at 0.55, 0.60, ..., 1.00 m: mean distance 0.225 m, x w_goal 4.
        let extra = cost(0.5, &creep) - cost(0.0, &creep);
        assert!((extra - 0.9).abs() < 1e-9, "{extra}");
        assert!(cost(0.5, &early) - cost(0.5, &creep) < cost(0.0, &early) - cost(0.0, &creep));
    }

    #[test]
    fn recording_stores_every_sample() {
        let (world, _) = corridor_with_cylinder();
        let ep = sim::Episode::new(&world, EpisodeConfig::default(), 3);
        let sched = Schedule::vanilla();
        let cfg = MppiConfig {
            samples: 50,
            ..Default::default()
        };
        let mut mppi = Mppi::new(cfg, 1);
        mppi.set_recording(true);
        mppi.plan(&PlanInput {
            perception: ep.perception(),
            schedule: &sched,
            max_speed: 1.5,
            prediction: crate::Prediction::PAPERS,
            budget: crate::Budget::UNLIMITED,
            moving: &[],
        });
        let r = mppi.rollouts();
        assert_eq!(r.spans.len(), 50);
        assert_eq!(r.dts, sched.dts());
        assert!(r.spans.iter().all(|s| s.1 - s.0 <= 20 && s.1 > s.0));
        let evaluated = mppi.evaluated_points();
        // Recording does not count its re-evaluation.
        assert!(evaluated > 0 && evaluated <= 50 * sched.points_per_rollout() as u64);
    }
}
