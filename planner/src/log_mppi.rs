//! Log-MPPI (Mohamed, Yin and Liu, "Autonomous navigation of AGVs in unknown cluttered
//! environments: log-MPPI control strategy", RA-L 2022) over a fidelity schedule.
//!
//! MPPI whose control perturbations follow the normal log-normal (NLN) mixture: each noise
//! value is the product of a zero-mean normal and a log-normal variable, a heavy-tailed
//! distribution that explores further than a normal of the same variance. As in the paper,
//! obstacles come from a local occupancy costmap built from the current scan and enter the
//! cost only through a binary collision indicator; the running cost is the squared distance
//! to the (local) goal plus the path-integral control cost of the perturbation, and the
//! updated control sequence is smoothed by a Savitzky-Golay filter.
//!
//! The costmap has three levels: free, inflated (within `inflation_radius` of an obstacle)
//! and lethal (within `lethal_margin`). After every schedule step the robot centre is checked
//! against the inflated level and, the DDP hook, the schedule's `checks[k]` footprint
//! boundary points against the lethal level, so a decremental schedule checks fewer points
//! further along the rollout. The warm start, rollout model, parallel evaluation and weights
//! are those of [`crate::mppi`].

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use sim::geometry::{wrap_angle, Footprint, Pose, Vec2};
use sim::robot::Twist;

use crate::check_points::{CheckPoints, LevelView, LEVEL_PADDING};
use crate::compute::{admit, evaluation_order, Work};
use crate::local_map::LocalMap;
use crate::mppi::{mppi_weights, roll_all, Nominal, Unicycle};
use crate::{Integrator, PlanInput, Planner, Predicted, Rollouts, Trace};

/// Log-MPPI parameters (defaults used by `adp eval`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LogMppiConfig {
    /// Control sequences sampled per cycle.
    pub samples: usize,
    /// Standard deviation of the normal factor of the linear-velocity noise (m/s). The
    /// authors' (0.045, 0.047) suit their 6 s horizon at 50 Hz; with the 1-2 s horizons of
    /// the schedules here the sequence must move further per cycle, hence larger values.
    pub sigma_v: f64,
    /// Standard deviation of the normal factor of the angular-velocity noise (rad/s).
    pub sigma_w: f64,
    /// Mean of the normal whose exponential is the log-normal factor (the authors' 1.023
    /// and 0.222 below make the factor's second moment about 8.5).
    pub ln_mu: f64,
    /// Standard deviation of the normal whose exponential is the log-normal factor.
    pub ln_sigma: f64,
    /// Temperature of the weights `exp(-(J - J_min) / lambda)`; must be > 0.
    pub lambda: f64,
    /// Control-cost scale gamma: the cost matrix is R = gamma / sigma per control.
    pub control_weight: f64,
    /// Exploration variance nu of the path-integral control cost.
    pub exploration_variance: f64,
    /// Planner's yaw-rate cap (rad/s).
    pub max_w: f64,
    /// Linear acceleration assumed in rollouts (m/s^2).
    pub accel_v: f64,
    /// Angular acceleration assumed in rollouts (rad/s^2).
    pub accel_w: f64,
    /// One control period (s): the warm-start shift and the span the command averages over.
    pub control_dt: f64,
    /// The robot centre collides within this distance of an obstacle (m).
    pub inflation_radius: f64,
    /// A footprint boundary point collides within this distance of an obstacle (m).
    pub lethal_margin: f64,
    /// Costmap cell size (m).
    pub costmap_resolution: f64,
    /// Cost of each checked state in collision.
    pub collision_cost: f64,
    /// Weight of the squared distance to the local goal (per m^2 s).
    pub w_goal: f64,
    /// Savitzky-Golay filter: half the window (points); 0 turns smoothing off.
    pub sg_half_window: usize,
    /// Distance-field cell size (m), from which the costmap is sampled.
    pub map_resolution: f64,
}

impl Default for LogMppiConfig {
    fn default() -> Self {
        Self {
            samples: 550,
            sigma_v: 0.1,
            sigma_w: 0.3,
            ln_mu: 1.023,
            ln_sigma: 0.222,
            lambda: 1.0,
            control_weight: 0.169,
            exploration_variance: 1200.0,
            max_w: 2.0,
            accel_v: 20.0,
            accel_w: 25.0,
            control_dt: 0.05,
            inflation_radius: 0.23,
            lethal_margin: 0.03,
            costmap_resolution: 0.05,
            collision_cost: 1e6,
            w_goal: 25.0,
            sg_half_window: 2,
            map_resolution: 0.05,
        }
    }
}

const FREE: u8 = 0;
const INFLATED: u8 = 1;
const LETHAL: u8 = 2;

/// A robot-frame occupancy costmap with three levels, sampled from the distance field.
#[derive(Clone, Debug, Default)]
struct Costmap {
    res: f64,
    origin: Vec2,
    nx: usize,
    ny: usize,
    /// Row-major levels, then [`LEVEL_PADDING`] free bytes (see [`LevelView`]).
    cells: Vec<u8>,
}

impl Costmap {
    /// Samples `map` over x in [-back, reach], y in [-reach, reach]: as in a ROS costmap, a
    /// cell is lethal (inflated) when its centre lies within `lethal` (`inflation`) of an
    /// obstacle.
    fn build(&mut self, map: &LocalMap, res: f64, back: f64, reach: f64, inflation: f64, lethal: f64) {
        self.res = res;
        self.origin = Vec2::new(-back, -reach);
        self.nx = ((back + reach) / res).ceil() as usize;
        self.ny = ((2.0 * reach) / res).ceil() as usize;
        self.cells.clear();
        for iy in 0..self.ny {
            for ix in 0..self.nx {
                let c = self.origin + Vec2::new((ix as f64 + 0.5) * res, (iy as f64 + 0.5) * res);
                let d = map.distance(c);
                self.cells.push(if d < lethal {
                    LETHAL
                } else if d < inflation {
                    INFLATED
                } else {
                    FREE
                });
            }
        }
        self.cells.extend([FREE; LEVEL_PADDING]);
    }

    /// The grid as the footprint check reads it.
    fn view(&self) -> LevelView<'_> {
        LevelView {
            cells: &self.cells,
            nx: self.nx,
            ny: self.ny,
            origin: self.origin,
            res: self.res,
        }
    }

    /// Cells of the grid (the padding excluded).
    fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// The level at `p`; free outside the map.
    fn at(&self, p: Vec2) -> u8 {
        self.view().at(p).unwrap_or(FREE)
    }
}

/// The Log-MPPI planner. Owns its buffers and its random stream; one per episode.
#[derive(Clone, Debug)]
pub struct LogMppi {
    cfg: LogMppiConfig,
    rng: Pcg64Mcg,
    map: LocalMap,
    costmap: Costmap,
    /// `boundary[m]` = m footprint boundary points (robot frame).
    boundary: Vec<CheckPoints>,
    /// The warm-start sequence and its grid.
    nominal: Nominal,
    /// Sampled sequences, `samples x steps`, clamped to the limits.
    controls: Vec<Twist>,
    outcomes: Vec<Outcome>,
    costs: Vec<f64>,
    weights: Vec<f64>,
    times: Vec<f64>,
    /// Samples in evaluation order under a compute budget ([`crate::compute::even_order`]).
    eval_order: Vec<u32>,
    /// Whether the budget let each sample be evaluated.
    admitted: Vec<bool>,
    trace: Trace,
}

/// The Jackal's check sets for 0..=n boundary points.
fn check_sets(n: usize) -> Vec<CheckPoints> {
    (0..=n)
        .map(|m| CheckPoints::new(&Footprint::JACKAL.boundary_points(m)))
        .collect()
}

/// What one rollout cost.
#[derive(Clone, Copy, Debug, Default)]
struct Outcome {
    cost: f64,
    evaluated: u64,
}

/// The cycle's inputs shared by all rollouts.
struct Scene<'a> {
    cfg: &'a LogMppiConfig,
    costmap: &'a Costmap,
    boundary: &'a [CheckPoints],
    dts: &'a [f64],
    checks: &'a [u16],
    nominal: &'a [Twist],
    start: Twist,
    goal: Vec2,
    integrator: Integrator,
    /// Moving obstacles, checked where they will be ([`crate::moving`]).
    moving: &'a [Predicted],
}

impl LogMppi {
    /// A Log-MPPI planner whose sampling is driven by `seed`.
    pub fn new(cfg: LogMppiConfig, seed: u64) -> Self {
        let n = crate::schedule::DEFAULT_BOUNDARY_POINTS;
        Self {
            cfg,
            rng: Pcg64Mcg::seed_from_u64(seed),
            map: LocalMap::new(Footprint::JACKAL, cfg.map_resolution, n),
            costmap: Costmap::default(),
            boundary: check_sets(n),
            nominal: Nominal::default(),
            controls: Vec::new(),
            outcomes: Vec::new(),
            costs: Vec::new(),
            weights: Vec::new(),
            times: Vec::new(),
            eval_order: Vec::new(),
            admitted: Vec::new(),
            trace: Trace::default(),
        }
    }

    /// Draws every sample's control sequence (sequentially): the nominal plus NLN noise,
    /// clamped. Sample 0 is the noise-free nominal.
    fn sample(&mut self, max_speed: f64) {
        let cfg = self.cfg;
        let nln = |sigma: f64, rng: &mut Pcg64Mcg| {
            let z: f64 = rng.sample(StandardNormal);
            let l: f64 = rng.sample(StandardNormal);
            sigma * z * (cfg.ln_mu + cfg.ln_sigma * l).exp()
        };
        self.controls.clear();
        for i in 0..cfg.samples.max(1) {
            for u in &self.nominal.seq {
                let (dv, dw) = if i == 0 {
                    (0.0, 0.0)
                } else {
                    (nln(cfg.sigma_v, &mut self.rng), nln(cfg.sigma_w, &mut self.rng))
                };
                self.controls.push(Twist::new(
                    (u.v + dv).clamp(0.0, max_speed),
                    (u.w + dw).clamp(-cfg.max_w, cfg.max_w),
                ));
            }
        }
    }
}

/// Savitzky-Golay smoothing for a non-uniform grid: each value is replaced by the value at
/// its time of the least-squares quadratic through the `2 half + 1` nearest steps (the
/// window shifts inward at the ends). `times` are the steps' times; `half` = 0 copies.
pub fn savitzky_golay(seq: &[Twist], times: &[f64], half: usize, out: &mut Vec<Twist>) {
    out.clear();
    let n = seq.len().min(times.len());
    let win = 2 * half + 1;
    if half == 0 || n < 3 {
        out.extend_from_slice(&seq[..n]);
        return;
    }
    let win = win.min(n);
    for k in 0..n {
        let lo = k.saturating_sub(half).min(n - win);
        let (t0, scale) = (times[k], (times[lo + win - 1] - times[lo]).max(1e-12));
        // Normal equations of the fit in tau = (t - t_k) / scale; the value at t_k is c0.
        let mut s = [0.0f64; 5];
        let (mut bv, mut bw) = ([0.0f64; 3], [0.0f64; 3]);
        for j in lo..lo + win {
            let tau = (times[j] - t0) / scale;
            let mut p = 1.0;
            for (e, sp) in s.iter_mut().enumerate() {
                *sp += p;
                if e < 3 {
                    bv[e] += p * seq[j].v;
                    bw[e] += p * seq[j].w;
                }
                p *= tau;
            }
        }
        let det3 = |a: [[f64; 3]; 3]| {
            a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
                - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
                + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
        };
        let m = [[s[0], s[1], s[2]], [s[1], s[2], s[3]], [s[2], s[3], s[4]]];
        let det = det3(m);
        // Cramer's rule for the first coefficient.
        let c0 = |b: [f64; 3]| det3([[b[0], s[1], s[2]], [b[1], s[2], s[3]], [b[2], s[3], s[4]]]) / det;
        out.push(if det.abs() > 1e-12 {
            Twist::new(c0(bv), c0(bw))
        } else {
            seq[k]
        });
    }
}

/// Rolls `controls` out and scores it: squared goal distance and control cost integrated
/// over the steps, plus the collision cost of every checked state in collision.
fn rollout(scene: &Scene<'_>, controls: &[Twist], mut record: Option<&mut Rollouts>) -> Outcome {
    let cfg = scene.cfg;
    let mut robot = Unicycle::new(scene.start, scene.integrator);
    let (rv, rw) = (
        cfg.control_weight / cfg.sigma_v.max(1e-9),
        cfg.control_weight / cfg.sigma_w.max(1e-9),
    );
    let keep = 0.5 * (1.0 - 1.0 / cfg.exploration_variance.max(1e-9));
    let (mut cost, mut collisions, mut evaluated) = (0.0, 0u32, 0u64);
    let mut t = 0.0;
    if let Some(r) = record.as_deref_mut() {
        r.begin();
    }
    for (k, ((&cmd, &dt), u)) in controls.iter().zip(scene.dts).zip(scene.nominal).enumerate() {
        robot.step(cmd, dt, cfg.accel_v, cfg.accel_w);
        t += dt;
        let pose = robot.pose();
        if let Some(r) = record.as_deref_mut() {
            r.push(Pose::new(pose.x, pose.y, wrap_angle(pose.yaw)));
        }
        let centre = pose.position();
        // The path-integral control cost of the perturbation e around the nominal u:
        // (1 - 1/nu)/2 e'Re + u'Re (the u'Ru/2 term is the same for every sample).
        let (ev, ew) = (cmd.v - u.v, cmd.w - u.w);
        let control = keep * (rv * ev * ev + rw * ew * ew) + rv * u.v * ev + rw * u.w * ew;
        cost += dt * (cfg.w_goal * (scene.goal - centre).dot(scene.goal - centre) + control);
        evaluated += 1;
        let mut crash = scene.costmap.at(centre) != FREE;
        let m = (scene.checks[k] as usize).min(scene.boundary.len() - 1);
        if !crash && m > 0 {
            evaluated += m as u64;
            crash = scene.boundary[m].any_on_level(centre, pose.yaw.sin_cos(), &scene.costmap.view(), LETHAL);
        }
        if !crash && !scene.moving.is_empty() {
            // The costmap's lethal band is the inscribed radius: contact with a forecast
            // obstacle is what counts here.
            crash =
                crate::moving::clearance(&Footprint::JACKAL, &pose, t, scene.moving, &mut evaluated) <= 0.0;
        }
        if crash {
            collisions += 1;
            cost += cfg.collision_cost;
        }
    }
    if let Some(r) = record {
        r.end(collisions == 0);
    }
    Outcome { cost, evaluated }
}

impl Planner for LogMppi {
    crate::planner_identity!("log-mppi");

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        let cfg = self.cfg;
        let per = &input.perception;
        let sched = input.schedule;
        let steps = sched.len().max(1);
        let n = sched.boundary_points();
        if self.boundary.len() != n + 1 {
            self.boundary = check_sets(n);
        }
        let reach = input.max_speed * sched.horizon()
            + self.map.footprint().circumscribed_radius()
            + cfg.inflation_radius;
        self.map.build(per.points, 1.0, reach);
        self.costmap.build(
            &self.map,
            cfg.costmap_resolution,
            1.0,
            reach,
            cfg.inflation_radius,
            cfg.lethal_margin,
        );

        self.nominal.warm_start(sched.dts(), cfg.control_dt);

        self.sample(input.max_speed);
        self.outcomes
            .resize(self.controls.len() / steps, Outcome::default());
        let scene = Scene {
            cfg: &self.cfg,
            costmap: &self.costmap,
            boundary: &self.boundary,
            dts: sched.dts(),
            checks: sched.checks(),
            nominal: &self.nominal.seq,
            start: per.vel,
            goal: per.local_goal,
            integrator: input.prediction.integrator,
            moving: input.moving,
        };
        let roll = |u: &[Twist], record: Option<&mut Rollouts>| rollout(&scene, u, record);
        let dts = sched.dts();
        roll_all(&self.controls, &mut self.outcomes, &mut self.trace, dts, roll);

        // What the compute budget admits: every sample drew two NLN factors (two normals
        // each) per step, but the noise-free nominal; each rolls out every step.
        let n = self.outcomes.len();
        evaluation_order(&input.budget, n, &mut self.eval_order);
        self.admitted.resize(n, false);
        let outcomes = &self.outcomes;
        let work_of = |i: usize| Work {
            samples: 1,
            draws: if i == 0 { 0 } else { 4 * steps as u64 },
            steps: steps as u64,
            points: outcomes[i].evaluated,
            cells: 0,
        };
        let spent = Work {
            cells: (self.map.cells() + self.costmap.len()) as u64,
            ..Work::default()
        };
        let cycle = admit(
            &input.budget,
            spent,
            &self.eval_order,
            work_of,
            &mut self.admitted,
        );
        self.trace.evaluated += cycle.work.points;
        self.trace.cycle = cycle;
        self.trace.rollouts.mark_skipped(&self.admitted);

        // The path-integral update over the admitted samples, then the Savitzky-Golay filter.
        let admitted = &self.admitted;
        self.costs.clear();
        self.costs.extend(
            self.outcomes
                .iter()
                .zip(admitted)
                .filter(|(_, &a)| a)
                .map(|(o, _)| o.cost),
        );
        mppi_weights(&self.costs, cfg.lambda, &mut self.weights);
        let samples = self
            .controls
            .chunks(steps)
            .zip(admitted)
            .filter(|(_, &a)| a)
            .map(|(u, _)| u)
            .zip(self.weights.iter().copied());
        self.nominal.blend(steps, samples);
        self.times.clear();
        let mut t = 0.0;
        for &dt in sched.dts() {
            self.times.push(t + 0.5 * dt);
            t += dt;
        }
        savitzky_golay(
            &self.nominal.scratch,
            &self.times,
            cfg.sg_half_window,
            &mut self.nominal.seq,
        );
        self.nominal.command(cfg.control_dt, input.max_speed, cfg.max_w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mppi::tests::{commands, drive_around};
    use crate::Schedule;
    use sim::Status;

    #[test]
    fn nln_noise_is_a_heavy_tailed_product() {
        // The same draws as `LogMppi::sample`: sigma * z * exp(mu + s l).
        let cfg = LogMppiConfig::default();
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let n = 200_000;
        let draws: Vec<f64> = (0..n)
            .map(|_| {
                let z: f64 = rng.sample(StandardNormal);
                let l: f64 = rng.sample(StandardNormal);
                z * (cfg.ln_mu + cfg.ln_sigma * l).exp()
            })
            .collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n as f64;
        // E[z^2] E[exp(2(mu + s l))] = exp(2 mu + 2 s^2).
        let expect = (2.0 * cfg.ln_mu + 2.0 * cfg.ln_sigma.powi(2)).exp();
        assert!(mean.abs() < 0.05, "zero mean: {mean}");
        assert!((var / expect - 1.0).abs() < 0.03, "variance {var} vs {expect}");
        // Heavier tails than a normal of the same variance (kurtosis above 3).
        let kurt = draws.iter().map(|d| (d - mean).powi(4)).sum::<f64>() / n as f64 / (var * var);
        assert!(kurt > 3.3, "kurtosis {kurt}");
    }

    #[test]
    fn savitzky_golay_keeps_quadratics_and_damps_noise() {
        let sched = Schedule::ddp_default();
        let mut t = 0.0;
        let times: Vec<f64> = sched
            .dts()
            .iter()
            .map(|&d| {
                t += d;
                t - 0.5 * d
            })
            .collect();
        let quad: Vec<Twist> = times
            .iter()
            .map(|&t| Twist::new(0.3 + 1.2 * t - 0.4 * t * t, -0.7 * t * t))
            .collect();
        let mut out = Vec::new();
        savitzky_golay(&quad, &times, 2, &mut out);
        for (a, b) in quad.iter().zip(&out) {
            assert!(
                (a.v - b.v).abs() < 1e-9 && (a.w - b.w).abs() < 1e-9,
                "{a:?} vs {b:?}"
            );
        }
        // Alternating noise is damped; half = 0 copies.
        let zigzag: Vec<Twist> = (0..20)
            .map(|k| Twist::new(if k % 2 == 0 { 1.0 } else { -1.0 }, 0.0))
            .collect();
        savitzky_golay(&zigzag, &times, 2, &mut out);
        assert!(out[5..15].iter().all(|u| u.v.abs() < 0.9));
        savitzky_golay(&zigzag, &times, 0, &mut out);
        assert_eq!(out, zigzag);
    }

    #[test]
    fn costmap_levels_follow_the_distance_field() {
        let pts: Vec<Vec2> = (0..40).map(|i| Vec2::new(1.0, -1.0 + 0.05 * i as f64)).collect();
        let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 20);
        map.build(&pts, 1.0, 3.0);
        let mut cm = Costmap::default();
        cm.build(&map, 0.05, 1.0, 3.0, 0.22, 0.02);
        assert_eq!(cm.at(Vec2::new(1.0, 0.0)), LETHAL);
        assert_eq!(cm.at(Vec2::new(0.85, 0.0)), INFLATED);
        assert_eq!(cm.at(Vec2::new(0.5, 0.0)), FREE);
        assert_eq!(cm.at(Vec2::new(-5.0, 0.0)), FREE);
    }

    /// Under its own model (the ideal robot): Log-MPPI's binary costmap and full-softmax
    /// averaging make it the weakest planner on the realistic robot, as in the DDP paper.
    #[test]
    fn avoids_a_cylinder_on_the_straight_route() {
        for schedule in [Schedule::vanilla(), Schedule::ddp_default()] {
            let mut planner = LogMppi::new(LogMppiConfig::default(), 11);
            let (status, closest) = drive_around(&mut planner, &schedule, sim::Profile::Ideal);
            assert_eq!(status, Status::Succeeded);
            assert!(closest > 0.35 + 0.215, "closest approach {closest}");
            assert!(planner.evaluated_points() > 0);
        }
    }

    #[test]
    fn same_seed_same_commands() {
        let sched = Schedule::ddp_default();
        let a = commands(&mut LogMppi::new(LogMppiConfig::default(), 5), &sched, 40);
        let b = commands(&mut LogMppi::new(LogMppiConfig::default(), 5), &sched, 40);
        let c = commands(&mut LogMppi::new(LogMppiConfig::default(), 6), &sched, 40);
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.iter().any(|u| u.v > 0.5), "it drives");
    }
}
