//! One sampling cycle's pieces: the weights of the top samples, the per-mode sampling
//! parameters, and the rollout of one sample with its clearance checks and costs.

use sim::geometry::{wrap_angle, Pose, Vec2};
use sim::robot::{approach, Twist};

use crate::local_map::{LocalMap, FAR};
use crate::{Integrator, Predicted};

/// Normalized weights of the `costs` of the top samples, sorted ascending:
/// `exp(-(J_k - J_min) / lambda) * ((top_k - k) / top_k)^2` for rank `k`, summing to one.
pub fn top_weights(costs: &[f64], top_k: usize, lambda: f64, out: &mut Vec<f64>) {
    out.clear();
    let Some(&j_min) = costs.first() else {
        return;
    };
    let k_f = top_k.max(costs.len()) as f64;
    let lambda = lambda.max(1e-9);
    out.extend(costs.iter().enumerate().map(|(k, &j)| {
        let rank = (k_f - k as f64) / k_f;
        (-(j - j_min) / lambda).exp() * rank * rank
    }));
    let sum: f64 = out.iter().sum();
    for w in out.iter_mut() {
        *w /= sum;
    }
}

/// Yaw-rate cap of a mode from `caps` (slow and gentle, moderate, fast) given the mode's
/// speed cap and the measured velocity.
pub(super) fn yaw_rate_cap(caps: [f64; 3], v_cap: f64, vel: Twist) -> f64 {
    let (v, w) = (vel.v.abs(), vel.w.abs());
    if w <= 1.0 && v <= v_cap / 3.0 {
        caps[0]
    } else if w <= 2.0 && v <= 2.0 * v_cap / 3.0 {
        caps[1]
    } else {
        caps[2]
    }
}

/// Free distance ahead of the front of `fp` within its width plus `side` either side;
/// [`FAR`] when nothing is there.
pub(super) fn front_clearance(points: &[Vec2], fp: &sim::Footprint, side: f64) -> f64 {
    points
        .iter()
        .filter(|p| p.x > 0.0 && p.y.abs() <= fp.half_width + side)
        .map(|p| p.x - fp.half_length)
        .fold(FAR, f64::min)
}

/// Bearing of the local path: the direction of the mean of the unit vectors to its points
/// beyond `near`, or the bearing of `fallback` when there are none.
pub(super) fn path_bearing(path: &[Vec2], near: f64, fallback: Vec2) -> f64 {
    let mut acc = Vec2::default();
    for p in path {
        let n = p.norm();
        if n > near {
            acc = acc + *p * (1.0 / n);
        }
    }
    if acc.norm() > 1e-9 {
        acc.y.atan2(acc.x)
    } else {
        fallback.y.atan2(fallback.x)
    }
}

/// Free length along the ray from `from` in direction `dir` before a robot-wide corridor
/// (`half_width` either side) meets an obstacle, up to `cap` (sphere tracing on the field).
pub(super) fn free_length(map: &LocalMap, from: Vec2, dir: Vec2, half_width: f64, cap: f64) -> f64 {
    let mut s = 0.0;
    for _ in 0..24 {
        if s >= cap {
            return cap;
        }
        let d = map.distance(from + dir * s) - half_width;
        if d <= 0.0 {
            return s;
        }
        s += d.max(0.05);
    }
    s.min(cap)
}

/// A lower bound on the clearance at `pose`, reached from `prev` whose bound is known: the
/// larger of the check with `m` boundary points and the previous bound minus how far any
/// point of the footprint can have moved (centre displacement plus circumscribed radius
/// times rotation). Slow rollouts thus keep the bound of their dense early checks; the check
/// is skipped when the inherited bound already reaches `enough`. `heading` is the `(sin, cos)`
/// of `pose.yaw`.
pub(super) fn chained_clearance(
    map: &LocalMap,
    (prev, prev_clear): (&Pose, f64),
    (pose, heading): (&Pose, (f64, f64)),
    m: usize,
    enough: f64,
    evaluated: &mut u64,
) -> f64 {
    let moved = pose.position().dist(prev.position())
        + map.circumscribed_radius() * wrap_angle(pose.yaw - prev.yaw).abs();
    let inherited = prev_clear - moved;
    if inherited >= enough {
        return inherited;
    }
    map.clearance_at(pose.position(), || heading, m, enough, evaluated)
        .max(inherited)
}

/// Per-mode sampling parameters, derived from the config each cycle.
#[derive(Clone, Copy, Debug)]
pub(super) struct ModeParams {
    pub(super) v_cap: f64,
    pub(super) w_caps: [f64; 3],
    pub(super) goal: f64,
    pub(super) obstacle: f64,
    pub(super) heading: f64,
    pub(super) space: f64,
    pub(super) margin: f64,
    pub(super) min_travel: f64,
    /// Shortest collision-free prefix of a rollout that stops early; `None`: no early stop.
    pub(super) min_safe_time: Option<f64>,
}

/// One sample's evaluation (reused across cycles).
#[derive(Clone, Debug, Default)]
pub(super) struct SampleEval {
    pub(super) feasible: bool,
    pub(super) goal: f64,
    pub(super) heading: f64,
    pub(super) obstacle: f64,
    pub(super) space: f64,
    pub(super) cost: f64,
    /// Steps driven: the rollout stops (and stays) after this many steps.
    pub(super) driven: usize,
    pub(super) evaluated: u64,
    /// Integration steps rolled out.
    pub(super) steps: u64,
    pub(super) poses: Vec<Pose>,
}

/// Everything a rollout needs, shared read-only by the parallel evaluation.
pub(super) struct RolloutCtx<'a> {
    pub(super) map: &'a LocalMap,
    pub(super) dts: &'a [f64],
    pub(super) checks: &'a [u16],
    pub(super) start: Twist,
    pub(super) accel_v: f64,
    pub(super) accel_w: f64,
    pub(super) integrator: Integrator,
    pub(super) margin: f64,
    pub(super) min_travel: f64,
    pub(super) min_safe_time: Option<f64>,
    pub(super) clearance_cap: f64,
    /// Clearance bound of the robot's current pose (full check).
    pub(super) start_clear: f64,
    pub(super) goal: Vec2,
    pub(super) quarter: usize,
    pub(super) space_dirs: Option<[(f64, f64); 3]>,
    pub(super) space_cap: f64,
    pub(super) half_width: f64,
    pub(super) record: bool,
    /// Moving obstacles, checked where they will be ([`crate::moving`]).
    pub(super) moving: &'a [Predicted],
    /// Among moving obstacles, how long the robot must be able to stand where a rollout
    /// ends (or stops) and stay clear of their forecast (s).
    pub(super) hold_time: f64,
}

/// Rolls `controls` out from the robot's pose and scores the rollout into `e`.
///
/// A rollout is infeasible when a check fails, unless early stops are allowed and it has
/// driven collision-free for `min_safe_time`: then it stops at its last clear pose (the
/// acceleration limits stop the robot within a few centimetres) and stays there.
///
/// Among moving obstacles (a non-empty forecast) a rollout must also end where the robot
/// could stop and stay clear of the forecast from the end of its driving (the horizon, or
/// the early stop) for `hold_time` more (past the horizon; [`crate::moving::hold_clearance`]):
/// a passive-safety check, without which the sampler keeps choosing rollouts that outrun an
/// obstacle over the horizon but leave the robot in its path, where nothing is feasible a
/// few cycles later and the mode machine stops it.
pub(super) fn evaluate(ctx: &RolloutCtx<'_>, controls: &[Twist], e: &mut SampleEval) {
    e.poses.clear();
    e.evaluated = 0;
    e.steps = 0;
    e.feasible = false;
    e.driven = controls.len();
    let (mut vel, mut pose) = (ctx.start, Pose::default());
    // (sin, cos) of `pose.yaw`, carried from step to step.
    let mut yaw_sc = (0.0, 1.0);
    let (mut travel, mut obstacle, mut time) = (0.0, 0.0, 0.0);
    let (mut goal, mut heading, mut space, mut n_q) = (0.0, 0.0, 0.0, 0usize);
    let mut last_clear = ctx.start_clear;
    // Clearance to the moving obstacles' forecast at the last driven step (infinite: none).
    let mut moving_clear = f64::INFINITY;
    // When the rollout stops driving (the horizon, unless it stops early).
    let mut stopped_at = None;
    for (k, (&dt, u)) in ctx.dts.iter().zip(controls).enumerate() {
        if k < e.driven {
            e.steps += 1;
            let before = (vel, pose, yaw_sc);
            vel.v = approach(vel.v, u.v, ctx.accel_v * dt);
            vel.w = approach(vel.w, u.w, ctx.accel_w * dt);
            pose = ctx.integrator.step_pose_carried(pose, &mut yaw_sc, vel, dt);
            let clear = chained_clearance(
                ctx.map,
                (&before.1, last_clear),
                (&pose, yaw_sc),
                ctx.checks[k] as usize,
                ctx.clearance_cap,
                &mut e.evaluated,
            );
            // The chain above bounds the static clearance only; the forecast is checked on
            // its own, at the end of this step.
            let ahead = if ctx.moving.is_empty() {
                f64::INFINITY
            } else {
                let fp = ctx.map.footprint();
                crate::moving::clearance(fp, &pose, time + dt, ctx.moving, &mut e.evaluated)
            };
            if clear.min(ahead) < ctx.margin {
                match ctx.min_safe_time {
                    Some(t) if time >= t => {
                        e.driven = k;
                        (vel, pose, yaw_sc) = before;
                        stopped_at = Some(time);
                    }
                    _ => {
                        if ctx.record {
                            e.poses.push(pose);
                        }
                        return;
                    }
                }
            } else {
                travel += vel.v.abs() * dt;
                last_clear = clear;
                moving_clear = ahead;
            }
        }
        time += dt;
        if ctx.record {
            e.poses.push(pose);
        }
        let x = (ctx.clearance_cap - last_clear.min(moving_clear)).max(0.0) / ctx.clearance_cap;
        obstacle += dt * x * x;
        if k >= ctx.quarter {
            let p = pose.position();
            let to_goal = ctx.goal - p;
            goal += to_goal.norm();
            heading += wrap_angle(to_goal.y.atan2(to_goal.x) - pose.yaw).abs();
            if let Some(dirs) = ctx.space_dirs {
                let (s, c) = yaw_sc;
                let free = dirs
                    .iter()
                    .map(|&(ds, dc)| {
                        let dir = Vec2::new(c * dc - s * ds, s * dc + c * ds);
                        free_length(ctx.map, p, dir, ctx.half_width, ctx.space_cap)
                    })
                    .fold(ctx.space_cap, f64::min);
                space += (ctx.space_cap - free) / ctx.space_cap;
            }
            n_q += 1;
        }
    }
    if travel < ctx.min_travel {
        return;
    }
    if !ctx.moving.is_empty() {
        let fp = ctx.map.footprint();
        let from = stopped_at.unwrap_or(time);
        let t1 = time + ctx.hold_time;
        if crate::moving::hold_clearance(fp, &pose, from, t1, ctx.moving, &mut e.evaluated) < ctx.margin {
            return;
        }
    }
    let n_q = n_q.max(1) as f64;
    e.feasible = true;
    e.goal = goal / n_q;
    e.heading = heading / n_q;
    e.space = space / n_q;
    e.obstacle = obstacle / time.max(1e-9);
}
