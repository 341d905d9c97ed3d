//! Dynamic Window Approach over a fidelity schedule.
//!
//! Each cycle samples a `v_samples x w_samples` grid of constant commands inside the window
//! reachable within one control period, rolls each out over the schedule's time grid (the
//! velocity approaching the command at the acceleration limits, then a forward-Euler or
//! exact-arc step, as the [`crate::Prediction`] says), checks the footprint after every step
//! with the schedule's check density, and returns the cheapest admissible command: one whose
//! rollout stays clear, or that the planner's model can stop before its first failed check
//! (the classic DWA admissibility); such a rollout ends at its last clear point with the
//! highest obstacle cost. A robot that stands still for too long hands over to the
//! [`crate::recovery`] behaviour (rotate toward a free heading, or back up).

use serde::{Deserialize, Serialize};
use sim::geometry::{Pose, Vec2};
use sim::robot::{approach, Twist};

use crate::compute::{evaluation_order, Work};
use crate::local_map::LocalMap;
use crate::moving;
use crate::path_distance::PathDistance;
use crate::recovery::{Recovery, RecoveryConfig};
use crate::{Gains, GainsError, Integrator, PlanInput, Planner, Schedule, Trace};

/// DWA parameters (defaults used by `adp eval`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DwaConfig {
    /// Linear-velocity samples across the window.
    pub v_samples: usize,
    /// Angular-velocity samples across the window.
    pub w_samples: usize,
    /// Planner's yaw-rate cap (rad/s).
    pub max_w: f64,
    /// Linear acceleration assumed in rollouts and the window (m/s^2).
    pub accel_v: f64,
    /// Angular acceleration assumed in rollouts and the window (rad/s^2).
    pub accel_w: f64,
    /// The window spans what is reachable in this time (s): one control period.
    pub window_dt: f64,
    /// A rollout whose estimated clearance drops below this is infeasible (m).
    pub margin: f64,
    /// Clearances above this cost nothing (m).
    pub clearance_cap: f64,
    /// Boundary points are evaluated only where the circumscribed-disk bound is below this
    /// (m); farther away the disk bound is the clearance estimate.
    pub detail_within: f64,
    /// Weight of the goal term: the mean distance to the local goal over the rollout's last
    /// `goal_tail` share of grid points.
    pub w_goal: f64,
    /// Share of the rollout's grid points, counted from its end, whose distance to the local
    /// goal the goal term averages (in (0, 1]; at least the end point). The authors' DWA sums
    /// steps 10 to N - 2 of 20, about the last half; the end point alone makes a long DDP
    /// horizon prefer commands that stop near the goal, i.e. slow ones.
    pub goal_tail: f64,
    /// Weight of the end point's distance to the local path.
    pub w_path: f64,
    /// Weight of the obstacle-proximity cost.
    pub w_obstacle: f64,
    /// Weight of the slowness cost.
    pub w_speed: f64,
    /// Distance-field cell size (m).
    pub map_resolution: f64,
    /// Getting unstuck after standing still (`[dwa.recovery]`).
    pub recovery: RecoveryConfig,
}

impl Default for DwaConfig {
    fn default() -> Self {
        Self {
            v_samples: 20,
            w_samples: 20,
            max_w: 2.0,
            accel_v: 20.0,
            accel_w: 25.0,
            window_dt: 0.05,
            margin: 0.02,
            clearance_cap: 0.5,
            detail_within: 0.1,
            w_goal: 1.0,
            goal_tail: 0.5,
            w_path: 0.4,
            w_obstacle: 0.8,
            w_speed: 0.3,
            map_resolution: 0.05,
            recovery: RecoveryConfig::default(),
        }
    }
}

/// The DWA planner. Owns its buffers; one per episode (`Send`, not shared).
#[derive(Clone, Debug)]
pub struct Dwa {
    /// The configuration, its objective weights scaled by the gain factors.
    cfg: DwaConfig,
    /// The configured (hand-tuned) weights, in [`Gains::Dwa`] order.
    tuned: [f64; 4],
    map: LocalMap,
    /// Per w sample and step: the yaw rate and the heading it has reached.
    w_prof: Vec<YawStep>,
    /// Per v sample and step: v.
    v_prof: Vec<f64>,
    cost: Vec<Candidate>,
    /// Infeasibility threshold per check density: the configured margin, or the clearance
    /// the robot already has when that is smaller (so a robot that ended up closer than the
    /// margin may still move away instead of being stuck).
    margins: Vec<f64>,
    /// Grid cells (`i * w_samples + j`) in evaluation order: the grid's own order, or
    /// [`crate::compute::even_order`] when a compute budget may stop the cycle early.
    order: Vec<u32>,
    /// The cycle's local path, prepared for the rollouts' path-cost queries.
    path: PathDistance,
    recovery: Recovery,
    trace: Trace,
}

/// One step of a yaw profile: everything about a rollout's heading that does not depend on its
/// speed sample, so the `v_samples` rollouts sharing it do not recompute it.
#[derive(Clone, Copy, Debug)]
struct YawStep {
    /// Yaw rate (rad/s).
    w: f64,
    /// `(sin, cos)` of the integrated yaw (the arc integration's terms).
    sin_cos: (f64, f64),
    /// The pose's yaw: the integrated yaw wrapped by `atan2`.
    yaw: f64,
    /// `(sin, cos)` of `yaw` (the footprint's rotation in the collision check).
    rot: (f64, f64),
}

#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// Grid cell (`i * w_samples + j`): ties between equal costs go to the lower cell.
    cell: u32,
    cmd: Twist,
    goal: f64,
    path: f64,
    obstacle: f64,
    speed: f64,
    /// Share of the horizon the rollout stays clear (1 = all of it).
    clear_share: f64,
}

/// Cost of a rollout that fails a check, scaled by the share of the horizon it does not stay
/// clear: a failure right ahead outweighs every normalized term, one at the end of the
/// horizon (where the grid is coarse and the check sparse) adds little to the obstacle term.
const HIT_COST: f64 = 4.0;

impl Dwa {
    /// A DWA planner.
    pub fn new(cfg: DwaConfig) -> Self {
        Self {
            cfg,
            tuned: [cfg.w_goal, cfg.w_path, cfg.w_obstacle, cfg.w_speed],
            map: LocalMap::jackal(cfg.map_resolution),
            w_prof: Vec::new(),
            v_prof: Vec::new(),
            cost: Vec::new(),
            margins: Vec::new(),
            order: Vec::new(),
            path: PathDistance::default(),
            recovery: Recovery::new(cfg.recovery),
            trace: Trace::default(),
        }
    }
}

fn sample(lo: f64, hi: f64, k: usize, i: usize) -> f64 {
    if k <= 1 {
        0.5 * (lo + hi)
    } else {
        lo + (hi - lo) * i as f64 / (k - 1) as f64
    }
}

impl Planner for Dwa {
    crate::planner_identity!("dwa");

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        let points_before = self.trace.evaluated;
        self.trace.cycle = Default::default();
        let cmd = self.cycle(input);
        self.trace.cycle.work.points = self.trace.evaluated - points_before;
        cmd
    }

    fn gains(&self) -> Option<Gains> {
        Some(Gains::Dwa)
    }

    fn set_gain_factors(&mut self, factors: &[f64]) -> Result<(), GainsError> {
        Gains::Dwa.check(factors)?;
        let t = self.tuned;
        let c = &mut self.cfg;
        (c.w_goal, c.w_path, c.w_obstacle, c.w_speed) = (
            t[0] * factors[0],
            t[1] * factors[1],
            t[2] * factors[2],
            t[3] * factors[3],
        );
        Ok(())
    }
}

impl Dwa {
    /// One planning cycle; counts its work into `trace.cycle` (all but the points, which
    /// [`Planner::plan`] takes from `trace.evaluated`).
    fn cycle(&mut self, input: &PlanInput<'_>) -> Twist {
        let points_at_start = self.trace.evaluated;
        let cfg = self.cfg;
        let per = &input.perception;
        let sched = input.schedule;
        let steps = sched.len();
        let euler = input.prediction.integrator == Integrator::Euler;
        self.map.prepare(per.points, input, 1.0, cfg.clearance_cap);
        self.trace.cycle.work.cells = self.map.cells() as u64;
        if let Some(cmd) = self.recovery.step(&self.map, per, &mut self.trace.evaluated) {
            self.trace.rollouts.clear(sched.dts());
            return cmd;
        }

        let v0 = per.vel.v;
        let w0 = per.vel.w;
        let v_lo = (v0 - cfg.accel_v * cfg.window_dt).max(0.0);
        let v_hi = (v0 + cfg.accel_v * cfg.window_dt).min(input.max_speed).max(v_lo);
        let w_lo = (w0 - cfg.accel_w * cfg.window_dt).max(-cfg.max_w);
        let w_hi = (w0 + cfg.accel_w * cfg.window_dt).min(cfg.max_w).max(w_lo);
        let (nv, nw) = (cfg.v_samples.max(1), cfg.w_samples.max(1));
        // The profiles below: one step per sample and grid step of each axis.
        self.trace.cycle.work.steps = ((nv + nw) * steps) as u64;

        let window = Window {
            v: (v_lo, v_hi),
            w: (w_lo, w_hi),
            n: (nv, nw),
        };
        self.build_profiles(sched, (v0, w0), &window);
        self.path.prepare(per.local_path, per.local_goal);
        let horizon = sched.horizon();
        // First grid point of the goal term's tail (the end point at least).
        let tail = (cfg.goal_tail * steps as f64).ceil() as usize;
        let tail_start = steps.saturating_sub(tail.max(1));
        self.margins.clear();
        for m in 0..=self.map.boundary_points() {
            let here = self.map.footprint_clearance(
                &Pose::default(),
                m,
                cfg.detail_within,
                &mut self.trace.evaluated,
            );
            self.margins.push(cfg.margin.min(here));
        }

        self.trace.rollouts.clear(sched.dts());
        self.cost.clear();
        let budget = input.budget;
        evaluation_order(&budget, nv * nw, &mut self.order);
        self.trace.cycle.samples = self.order.len() as u32;
        // Counted in locals, written back after the loop (the hot loop stays in registers).
        let mut work = self.trace.cycle.work;
        let mut started = 0u32;
        for k in 0..self.order.len() {
            let cell = self.order[k];
            if budget.is_limited() {
                let spent = Work {
                    points: self.trace.evaluated - points_at_start,
                    ..work
                };
                if !budget.admits(&spent) {
                    break;
                }
            }
            work.samples += 1;
            started += 1;
            let rollout = RolloutSetup {
                window: &window,
                horizon,
                tail_start,
                euler,
            };
            if let Some(c) = self.roll_out(input, &rollout, cell, &mut work.steps) {
                self.cost.push(c);
            }
        }
        self.trace.cycle.work = work;
        self.trace.cycle.evaluated = started;
        if self.cost.is_empty() {
            // Nothing is safe: stop and turn toward the local goal.
            let bearing = per.local_goal.y.atan2(per.local_goal.x);
            return Twist::new(0.0, bearing.clamp(-1.0, 1.0));
        }
        self.choose()
    }

    /// Fills the speed profiles (one per v sample) and the yaw profiles (one per w sample)
    /// of the schedule `sched` from the measured velocity `(v0, w0)` over the `window`'s grid.
    fn build_profiles(&mut self, sched: &Schedule, (v0, w0): (f64, f64), window: &Window) {
        let cfg = self.cfg;
        let ((v_lo, v_hi), (w_lo, w_hi), (nv, nw)) = (window.v, window.w, window.n);
        // Separable: v depends only on the v command, yaw only on w.
        self.v_prof.clear();
        for i in 0..nv {
            let cmd = sample(v_lo, v_hi, nv, i);
            let mut v = v0;
            for &dt in sched.dts() {
                v = approach(v, cmd, cfg.accel_v * dt);
                self.v_prof.push(v);
            }
        }
        self.w_prof.clear();
        for j in 0..nw {
            let cmd = sample(w_lo, w_hi, nw, j);
            let (mut w, mut yaw) = (w0, 0.0f64);
            for &dt in sched.dts() {
                w = approach(w, cmd, cfg.accel_w * dt);
                yaw += w * dt;
                let (s, c) = yaw.sin_cos();
                let wrapped = s.atan2(c);
                // Within (-pi, pi] the wrap usually gives the yaw back bit for bit, and then
                // its sine and cosine are the ones just computed.
                let rot = if wrapped.to_bits() == yaw.to_bits() {
                    (s, c)
                } else {
                    wrapped.sin_cos()
                };
                self.w_prof.push(YawStep {
                    w,
                    sin_cos: (s, c),
                    yaw: wrapped,
                    rot,
                });
            }
        }
    }

    /// Rolls out grid cell `cell` (speed sample `cell / nw`, yaw sample `cell % nw`) over the
    /// profiles and scores it; `None` when the rollout is not admissible. Adds its integration
    /// steps to `work_steps` and its check points to `trace.evaluated`.
    fn roll_out(
        &mut self,
        input: &PlanInput<'_>,
        setup: &RolloutSetup<'_>,
        cell: u32,
        work_steps: &mut u64,
    ) -> Option<Candidate> {
        let cfg = self.cfg;
        let per = &input.perception;
        let sched = input.schedule;
        let steps = sched.len();
        let v0 = per.vel.v;
        let RolloutSetup {
            window,
            horizon,
            tail_start,
            euler,
        } = *setup;
        let ((v_lo, v_hi), (w_lo, w_hi), (nv, nw)) = (window.v, window.w, window.n);
        let (i, j) = (cell as usize / nw, cell as usize % nw);

        let (mut x, mut y, mut s0, mut c0) = (0.0, 0.0, 0.0, 1.0);
        let mut min_clear = cfg.clearance_cap;
        // Distance driven up to the last clear grid point, and that point.
        let (mut driven, mut last_clear) = (0.0, (0.0, 0.0));
        // The rollout's point halfway through its steps (path cost).
        let mut mid = Vec2::default();
        // Sum and count of the tail's clear points' distances to the local goal.
        let (mut goal_sum, mut goal_n) = (0.0, 0usize);
        let mut hit = false;
        let mut admissible = true;
        let mut clear_time = horizon;
        // Time at the end of step k (the moving obstacles' forecast).
        let mut t = 0.0;
        if self.trace.recording {
            self.trace.rollouts.begin();
        }
        for k in 0..steps {
            *work_steps += 1;
            let v = self.v_prof[i * steps + k];
            let step = self.w_prof[j * steps + k];
            let (w, (s1, c1)) = (step.w, step.sin_cos);
            let dt = sched.dts()[k];
            if euler {
                // Forward Euler along the heading after the step (the authors' motion()).
                x += v * dt * c1;
                y += v * dt * s1;
            } else if (w * dt).abs() > 1e-9 {
                x += v / w * (s1 - s0);
                y -= v / w * (c1 - c0);
            } else {
                x += v * dt * c0;
                y += v * dt * s0;
            }
            (s0, c0) = (s1, c1);
            if self.trace.recording {
                self.trace.rollouts.push(Pose::new(x, y, step.yaw));
            }
            let m = sched.checks()[k] as usize;
            let mut clear = self.map.clearance_at(
                Vec2::new(x, y),
                || step.rot,
                m,
                cfg.detail_within,
                &mut self.trace.evaluated,
            );
            t += dt;
            if !input.moving.is_empty() {
                clear = clear.min(moving::clearance(
                    self.map.footprint(),
                    &Pose::new(x, y, step.yaw),
                    t,
                    input.moving,
                    &mut self.trace.evaluated,
                ));
            }
            if clear < self.margins[m.min(self.margins.len() - 1)] {
                // Admissible (Fox et al. 1997) when the planner's model can still stop
                // before the obstacle: the rollout then ends at its last clear point.
                let v_before = if k > 0 { self.v_prof[i * steps + k - 1] } else { v0 };
                hit = true;
                clear_time = sched.dts()[..k].iter().sum();
                admissible = k > 0 && v_before * v_before <= 2.0 * cfg.accel_v * driven;
                (x, y) = last_clear;
                min_clear = 0.0;
                break;
            }
            driven += v.abs() * dt;
            last_clear = (x, y);
            if k < steps.div_ceil(2) {
                mid = Vec2::new(x, y);
            }
            if k >= tail_start {
                goal_sum += Vec2::new(x, y).dist(per.local_goal);
                goal_n += 1;
            }
            min_clear = min_clear.min(clear);
        }
        if self.trace.recording {
            self.trace.rollouts.end(!hit);
        }
        if !admissible {
            return None;
        }
        let end = Vec2::new(x, y);
        // A rollout that failed a check waits at its last clear point for the rest.
        let tail_len = steps - tail_start;
        goal_sum += end.dist(per.local_goal) * (tail_len - goal_n) as f64;
        let cmd = Twist::new(sample(v_lo, v_hi, nv, i), sample(w_lo, w_hi, nw, j));
        Some(Candidate {
            cell,
            cmd,
            goal: goal_sum / tail_len.max(1) as f64,
            path: 0.5 * (self.path.distance(mid) + self.path.distance(end)),
            obstacle: (cfg.clearance_cap - min_clear) / cfg.clearance_cap,
            speed: if input.max_speed > 0.0 {
                (input.max_speed - cmd.v) / input.max_speed
            } else {
                0.0
            },
            clear_share: clear_time / horizon,
        })
    }

    /// The command of the cheapest admissible rollout: goal and path terms normalized over the
    /// candidates, plus the obstacle, speed and hit terms (ties to the lower cell).
    fn choose(&self) -> Twist {
        let cfg = self.cfg;
        let span = |f: fn(&Candidate) -> f64, cs: &[Candidate]| {
            let (lo, hi) = cs
                .iter()
                .map(f)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(x), b.max(x))
                });
            (lo, if hi - lo > 1e-9 { hi - lo } else { 1.0 })
        };
        let (g_lo, g_span) = span(|c| c.goal, &self.cost);
        let (p_lo, p_span) = span(|c| c.path, &self.cost);
        let total = |c: &Candidate| {
            cfg.w_goal * (c.goal - g_lo) / g_span
                + cfg.w_path * (c.path - p_lo) / p_span
                + cfg.w_obstacle * c.obstacle
                + cfg.w_speed * c.speed
                + if c.clear_share < 1.0 {
                    HIT_COST * (1.0 - c.clear_share)
                } else {
                    0.0
                }
        };
        self.cost
            .iter()
            .min_by(|a, b| total(a).total_cmp(&total(b)).then(a.cell.cmp(&b.cell)))
            .map(|c| c.cmd)
            .unwrap_or_default()
    }
}

/// The dynamic window of a cycle: the speed and yaw-rate ranges and their sample counts.
struct Window {
    v: (f64, f64),
    w: (f64, f64),
    n: (usize, usize),
}

/// What every rollout of a cycle shares besides the input.
#[derive(Clone, Copy)]
struct RolloutSetup<'a> {
    window: &'a Window,
    horizon: f64,
    /// First grid point of the goal term's tail.
    tail_start: usize,
    /// Forward Euler (the authors' motion model) instead of exact arcs.
    euler: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::run_episode;
    use crate::Schedule;
    use sim::geometry::Circle;
    use sim::{EpisodeConfig, Status, World};

    /// A 3 m wide corridor along +y with one cylinder of radius 0.3 m on the straight route.
    fn blocked_corridor() -> World {
        World::corridor(
            1.5,
            &[Circle {
                c: Vec2::new(0.0, 4.0),
                r: 0.3,
            }],
        )
    }

    /// BARN world 264 at 1.0 m/s with the DDP schedule on the Jackal profile: the robot
    /// drives into a pocket between obstacle clusters where every 2 s forward arc fails a
    /// check. Without recovery it stands there until the run times out.
    #[test]
    fn recovery_gets_a_parked_robot_out_of_a_pocket() {
        let world = sim::catalog::world(264).unwrap();
        let outcomes = |enabled: bool| -> Vec<Status> {
            (0..4)
                .map(|seed| {
                    let mut cfg = DwaConfig::default();
                    cfg.recovery.enabled = enabled;
                    let mut dwa = Dwa::new(cfg);
                    let (r, _) = run_episode(
                        world,
                        EpisodeConfig::default(),
                        &mut dwa,
                        &Schedule::ddp_default(),
                        1.0,
                        seed,
                        None,
                        |_, _, _| {},
                    );
                    r.status
                })
                .collect()
        };
        let without = outcomes(false);
        assert!(without.contains(&Status::TimedOut), "{without:?}");
        let with = outcomes(true);
        assert!(!with.contains(&Status::TimedOut), "{with:?}");
        assert!(
            with.iter().filter(|s| **s == Status::Succeeded).count() >= 3,
            "{with:?}"
        );
    }

    #[test]
    fn avoids_a_cylinder_on_the_straight_route() {
        let w = blocked_corridor();
        for sched in [Schedule::vanilla(), Schedule::ddp_default()] {
            let mut dwa = Dwa::new(DwaConfig::default());
            let mut passing_x = None;
            let (r, _) = run_episode(
                &w,
                EpisodeConfig::default(),
                &mut dwa,
                &sched,
                1.5,
                1,
                None,
                |ep, _, _| {
                    let p = ep.state().pose;
                    if (p.y - 4.0).abs() < 0.1 {
                        passing_x = Some(p.x);
                    }
                },
            );
            assert_eq!(r.status, Status::Succeeded, "{r:?}");
            let x = passing_x.expect("drove past the cylinder");
            // Footprint half-width 0.215 + cylinder 0.3: the centre must pass > 0.515 aside.
            assert!(x.abs() > 0.515, "passed the cylinder at x = {x}");
        }
    }

    /// The real robot can end up closer to an obstacle than the planner's margin (it does not
    /// follow the predicted arc); the planner must still drive on, away from it, not freeze.
    #[test]
    fn a_robot_closer_than_the_margin_still_drives_away() {
        // A wall along the robot's left side, 0.01 m from the footprint (margin 0.02).
        let pts: Vec<Vec2> = (0..40)
            .map(|i| Vec2::new(-1.0 + 0.05 * i as f64, 0.225))
            .collect();
        let path = [Vec2::new(0.0, 0.0), Vec2::new(3.0, -0.3)];
        let perception = sim::Perception {
            ranges: &[],
            points: &pts,
            vel: Twist::new(0.5, 0.0),
            local_goal: Vec2::new(3.0, -0.3),
            local_path: &path,
            goal: Vec2::new(8.0, -0.3),
        };
        for schedule in [Schedule::vanilla(), Schedule::ddp_default()] {
            let mut dwa = Dwa::new(DwaConfig::default());
            let cmd = dwa.plan(&PlanInput {
                perception,
                schedule: &schedule,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving: &[],
            });
            assert!(cmd.v > 0.3, "drives on: {cmd:?}");
            assert!(cmd.w <= 0.0, "not toward the wall: {cmd:?}");
        }
    }

    /// One cycle of a 2 x 2 grid on 5 steps of 0.1 s with 4 boundary points, in open space
    /// at 1 m/s. The field spans x in [-1, reach] and y in [-reach, reach], where reach is
    /// 1.0 x 0.5 plus the circumscribed radius 0.33278 plus the clearance cap 0.5, i.e.
    /// 1.33278 m: at 0.05 m that is 48 x 55 = 2,640 cells. Steps: the v and w profiles,
    /// (2 + 2) x 5 = 20, and the 4 rollouts, 4 x 5 = 20. Points: the margins at the robot's
    /// pose for 0..=4 boundary points (5 checks) and one check per rollout step (20), each
    /// only the centre (nothing within reach). No draws.
    #[test]
    fn one_cycle_counts_its_units_and_a_budget_stops_it_in_the_even_order() {
        let perception = sim::Perception {
            ranges: &[],
            points: &[],
            vel: Twist::default(),
            local_goal: Vec2::new(2.0, 0.0),
            local_path: &[],
            goal: Vec2::new(5.0, 0.0),
        };
        let schedule = Schedule::uniform(0.1, 5, 4).unwrap();
        let cfg = DwaConfig {
            v_samples: 2,
            w_samples: 2,
            ..DwaConfig::default()
        };
        let plan = |budget| {
            let mut dwa = Dwa::new(cfg);
            dwa.set_recording(true);
            dwa.plan(&PlanInput {
                perception,
                schedule: &schedule,
                max_speed: 1.0,
                prediction: crate::Prediction::PAPERS,
                budget,
                moving: &[],
            });
            (
                dwa.trace().cycle,
                dwa.rollouts().spans.len(),
                dwa.evaluated_points(),
            )
        };
        let (c, rollouts, points) = plan(crate::Budget::UNLIMITED);
        let want = Work {
            cells: 2640,
            samples: 4,
            draws: 0,
            steps: 40,
            points: 25,
        };
        assert_eq!(
            (c.work, c.samples, c.evaluated, rollouts, points),
            (want, 4, 4, 4, 25)
        );
        // 1 ns per step, point and sample: 25 ns spent before the first rollout, 11 per
        // rollout; a 50 ns budget starts rollouts at 25, 36 and 47 ns: 3 of 4, the first
        // three of the even order (0, 3, 2, 1).
        let costs = crate::compute::UnitCosts {
            sample_ns: 1.0,
            step_ns: 1.0,
            point_ns: 1.0,
            ..crate::compute::UnitCosts::ZERO
        };
        let budget = crate::Budget::of(Some(&crate::Compute {
            costs,
            budget_ns: 50.0,
        }));
        let (c, rollouts, _) = plan(budget);
        assert_eq!((c.samples, c.evaluated, rollouts), (4, 3, 3));
        assert_eq!(c.work.samples, 3);
        assert_eq!(c.work.steps, 20 + 15);
        let mut order = Vec::new();
        crate::compute::even_order(4, &mut order);
        assert_eq!(order, [0, 3, 2, 1]);
    }

    #[test]
    fn ddp_checks_fewer_points_than_uniform_at_equal_horizon() {
        // Same scene, same 2 s horizon and 20 steps: uniform (full checks) vs DDP.
        let w = sim::catalog::world(250).unwrap();
        let mut ep = sim::Episode::new(w, EpisodeConfig::default(), 1);
        let mut driver = Dwa::new(DwaConfig::default());
        let ddp = Schedule::ddp_default();
        for _ in 0..40 {
            let cmd = driver.plan(&PlanInput {
                perception: ep.perception(),
                schedule: &ddp,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving: &[],
            });
            ep.step(cmd);
        }
        let uniform = Schedule::uniform(0.1, 20, ddp.boundary_points()).unwrap();
        assert!((uniform.horizon() - ddp.horizon()).abs() < 1e-12);
        let count = |s: &Schedule| {
            let mut dwa = Dwa::new(DwaConfig::default());
            dwa.plan(&PlanInput {
                perception: ep.perception(),
                schedule: s,
                max_speed: 1.5,
                prediction: crate::Prediction::PAPERS,
                budget: crate::Budget::UNLIMITED,
                moving: &[],
            });
            dwa.evaluated_points()
        };
        let (u, d) = (count(&uniform), count(&ddp));
        eprintln!("collision-check points, one DWA cycle at a 2 s horizon: uniform {u}, DDP {d}");
        assert!(d < u, "DDP evaluated {d} points, uniform {u}");
    }
}
