//! `adp render`: a picture of one episode — the world, the driven trajectory, the footprint
//! at intervals, and at chosen moments the sampled rollouts, each segment coloured by its
//! step length (short step = dark = high fidelity, long step = light), as in Fig. 2 of the
//! ADP paper. At the same moments the rollout the planner predicts for the command it chose
//! (its own model: nominal accelerations, the profile's integrator, dots at the grid points)
//! is drawn in purple beside the path the robot really drove (red), so the gap between the
//! planner's model and the robot shows. Samples the compute budget left out (rolled out for the
//! picture only) are grey. PNG or SVG by the output's extension.

use std::path::Path;

use anyhow::{bail, Context};
use plotters::coord::Shift;
use plotters::prelude::*;

use planner::{run::run_episode, Planner, Prediction, Schedule};
use sim::geometry::{Footprint, Pose, Vec2};
use sim::robot::{approach, RobotLimits, Twist};
use sim::{EpisodeConfig, EpisodeResult, World};

/// Pixels per metre.
const SCALE: f64 = 90.0;

/// Rollouts recorded at one moment, in the world frame.
struct Moment {
    /// `(poses, collision_free)` per rollout the planner considered.
    rollouts: Vec<(Vec<Pose>, bool)>,
    /// Rollouts the compute budget left out, drawn grey.
    skipped: Vec<Vec<Pose>>,
    origin: Pose,
    dts: Vec<f64>,
    /// The predicted rollout of the chosen command (world frame), one point per grid step.
    predicted: Vec<Vec2>,
}

/// The rollout a planner predicts for holding `cmd` from velocity `vel` over `schedule`: the
/// velocity approaches the command at the nominal controller accelerations (what every
/// planner assumes) and the pose moves by the prediction's integrator. Robot frame.
fn predicted_rollout(prediction: Prediction, schedule: &Schedule, mut vel: Twist, cmd: Twist) -> Vec<Pose> {
    let nominal = RobotLimits::JACKAL;
    let mut pose = Pose::default();
    schedule
        .dts()
        .iter()
        .map(|&dt| {
            vel.v = approach(vel.v, cmd.v, nominal.accel_v * dt);
            vel.w = approach(vel.w, cmd.w, nominal.accel_w * dt);
            pose = prediction.integrator.step_pose(pose, vel, dt);
            pose
        })
        .collect()
}

/// What to draw.
pub struct RenderJob<'a> {
    /// The world.
    pub world: &'a World,
    /// Episode settings.
    pub episode: EpisodeConfig,
    /// The planner (fresh).
    pub planner: Box<dyn Planner>,
    /// The schedule.
    pub schedule: Schedule,
    /// Speed cap (m/s).
    pub max_speed: f64,
    /// Noise seed.
    pub seed: u64,
    /// The compute model the planner runs under (`None`: free).
    pub compute: Option<planner::Compute>,
    /// Rollouts are drawn every this many seconds of simulated time.
    pub rollout_every_s: f64,
    /// Footprints are drawn every this many seconds.
    pub footprint_every_s: f64,
}

/// Runs the episode and writes the picture to `out`; returns the episode result.
pub fn render(mut job: RenderJob<'_>, out: &Path) -> anyhow::Result<EpisodeResult> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if ext != "png" && ext != "svg" {
        bail!("--out {}: the file name must end in .png or .svg", out.display());
    }
    if !(job.rollout_every_s > 0.0 && job.footprint_every_s > 0.0) {
        bail!("--rollouts-every and --footprint-every must be > 0 s");
    }
    let dt = job.episode.control_dt;
    let every = (job.rollout_every_s / dt).round().max(1.0) as u64;
    let mut trail: Vec<Pose> = Vec::new();
    let mut moments: Vec<Moment> = Vec::new();
    let mut cycle = 0u64;
    let prediction = Prediction::for_profile(job.episode.profile);
    let schedule = &job.schedule;
    let (result, _) = run_episode(
        job.world,
        job.episode,
        job.planner.as_mut(),
        schedule,
        job.max_speed,
        job.seed,
        job.compute,
        |ep, planner, cmd| {
            let pose = ep.state().pose;
            trail.push(pose);
            if cycle > 0 && cycle.is_multiple_of(every) {
                let predicted = predicted_rollout(prediction, schedule, ep.perception().vel, cmd)
                    .iter()
                    .map(|p| pose.to_world(p.position()))
                    .collect();
                let r = planner.rollouts();
                let world = |&(a, b, _): &(usize, usize, bool)| -> Vec<Pose> {
                    r.poses[a..b].iter().map(|p| compose(&pose, p)).collect()
                };
                let skipped = |i: usize| r.skipped.get(i).copied().unwrap_or(false);
                moments.push(Moment {
                    rollouts: (r.spans.iter().enumerate())
                        .filter(|&(i, _)| !skipped(i))
                        .map(|(_, s)| (world(s), s.2))
                        .collect(),
                    skipped: (r.spans.iter().enumerate())
                        .filter(|&(i, _)| skipped(i))
                        .map(|(_, s)| world(s))
                        .collect(),
                    origin: pose,
                    dts: r.dts.clone(),
                    predicted,
                });
            }
            cycle += 1;
            // Record only during the planning call of each chosen moment.
            planner.set_recording(cycle.is_multiple_of(every));
        },
    );
    let (w, h) = picture_size();
    if ext == "png" {
        let root = BitMapBackend::new(out, (w, h)).into_drawing_area();
        draw(&root, &job, &trail, &moments)?;
        root.present()
            .with_context(|| format!("cannot write {}", out.display()))?;
    } else {
        let root = SVGBackend::new(out, (w, h)).into_drawing_area();
        draw(&root, &job, &trail, &moments)?;
        root.present()
            .with_context(|| format!("cannot write {}", out.display()))?;
    }
    Ok(result)
}

/// A pose given in the frame of `base`, expressed in the world frame.
fn compose(base: &Pose, p: &Pose) -> Pose {
    let q = base.to_world(Vec2::new(p.x, p.y));
    Pose::new(q.x, q.y, base.yaw + p.yaw)
}

/// Drawn region (world frame, m).
const X0: f64 = -5.0;
const X1: f64 = 0.5;
const Y0: f64 = 1.5;
const Y1: f64 = 14.2;

fn picture_size() -> (u32, u32) {
    (((X1 - X0) * SCALE) as u32, ((Y1 - Y0) * SCALE) as u32)
}

/// Colour of a rollout segment by its step length: dark blue for short steps, pale for long.
fn fidelity_colour(dt: f64) -> RGBColor {
    let f = ((dt - 0.01) / (0.17 - 0.01)).clamp(0.0, 1.0);
    let mix = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
    RGBColor(mix(10.0, 175.0), mix(30.0, 215.0), mix(110.0, 250.0))
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    job: &RenderJob<'_>,
    trail: &[Pose],
    moments: &[Moment],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let e = |err: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("drawing failed: {err:?}");
    root.fill(&WHITE).map_err(e)?;
    let px = |p: Vec2| -> (i32, i32) { (((p.x - X0) * SCALE) as i32, ((Y1 - p.y) * SCALE) as i32) };
    // Goal region.
    let goal = px(job.world.goal);
    let gr = (job.world.goal_radius * SCALE) as i32;
    root.draw(&Circle::new(goal, gr, RGBColor(200, 240, 200).filled()))
        .map_err(e)?;
    root.draw(&Circle::new(goal, gr, RGBColor(40, 140, 40).stroke_width(2)))
        .map_err(e)?;
    // Obstacles.
    for c in &job.world.cylinders {
        let r = (c.r * SCALE).round() as i32;
        root.draw(&Circle::new(px(c.c), r, RGBColor(90, 90, 90).filled()))
            .map_err(e)?;
    }
    // Rollouts at the chosen moments, segment by segment; first those the compute budget
    // left out, in grey.
    for m in moments {
        for poses in &m.skipped {
            let line: Vec<(i32, i32)> = std::iter::once(m.origin.position())
                .chain(poses.iter().map(|p| p.position()))
                .map(px)
                .collect();
            root.draw(&PathElement::new(line, RGBColor(200, 200, 200).stroke_width(1)))
                .map_err(e)?;
        }
        for (poses, ok) in &m.rollouts {
            let mut prev = m.origin.position();
            for (k, p) in poses.iter().enumerate() {
                let colour = if *ok {
                    fidelity_colour(m.dts.get(k).copied().unwrap_or(0.05))
                } else {
                    RGBColor(240, 170, 170)
                };
                root.draw(&PathElement::new(
                    vec![px(prev), px(p.position())],
                    colour.stroke_width(1),
                ))
                .map_err(e)?;
                prev = p.position();
            }
        }
    }
    // Footprints at intervals and the driven trajectory.
    let fp: Footprint = job.episode.robot.footprint;
    let step = (job.footprint_every_s / job.episode.control_dt).round().max(1.0) as usize;
    for pose in trail.iter().step_by(step).chain(trail.last()) {
        let corners = [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
            .map(|(sx, sy)| px(pose.to_world(Vec2::new(sx * fp.half_length, sy * fp.half_width))));
        root.draw(&PathElement::new(
            corners.to_vec(),
            RGBColor(230, 120, 20).stroke_width(2),
        ))
        .map_err(e)?;
    }
    let line: Vec<(i32, i32)> = trail.iter().map(|p| px(p.position())).collect();
    root.draw(&PathElement::new(line, RGBColor(200, 30, 30).stroke_width(3)))
        .map_err(e)?;
    // The chosen command's predicted rollout, over the driven path.
    let purple = RGBColor(120, 40, 170);
    for m in moments {
        let line: Vec<(i32, i32)> = std::iter::once(m.origin.position())
            .chain(m.predicted.iter().copied())
            .map(px)
            .collect();
        root.draw(&PathElement::new(line, purple.stroke_width(2)))
            .map_err(e)?;
        for &p in &m.predicted {
            root.draw(&Circle::new(px(p), 3, purple.filled())).map_err(e)?;
        }
    }
    Ok(())
}

/// `adp render`: draws the episode the arguments describe and prints its outcome.
pub fn command(a: &crate::cli::RenderArgs) -> anyhow::Result<()> {
    let cfg = a.setup.eval_config()?;
    let all = a.setup.data.load()?;
    let w = crate::cli::WorldData::get(&all, a.world)?;
    let adp = crate::eval::AdpSetting {
        space: a.action,
        action: match &a.policy {
            Some(p) => crate::policy::load_constant_action(p, a.action)?,
            None => a.action.ddp_action(),
        },
    };
    let job = RenderJob {
        world: w,
        episode: cfg.episode,
        planner: a.planner.build(&cfg, a.seed),
        schedule: a.fidelity.schedule(&adp)?,
        max_speed: a.max_speed,
        seed: a.seed,
        compute: cfg.compute.resolve(a.planner.name())?,
        rollout_every_s: a.rollouts_every,
        footprint_every_s: a.footprint_every,
    };
    let r = render(job, &a.out)?;
    println!(
        "world {} {:?}: time {:.2} s, score {:.3}; picture written to {}",
        r.world,
        r.status,
        r.time_s,
        r.score,
        a.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_predicted_rollout_follows_the_planners_model() {
        // From rest, a constant (1.5, 0) command: the nominal 20 m/s^2 give 1 m/s in the first
        // 0.05 s step and 1.5 m/s from the second: 0.05 + 19 x 0.075 = 1.475 m.
        let s = Schedule::uniform(0.05, 20, 0).unwrap();
        let p = predicted_rollout(Prediction::PAPERS, &s, Twist::default(), Twist::new(1.5, 0.0));
        assert_eq!(p.len(), 20);
        assert!(
            (p[19].x - 1.475).abs() < 1e-9 && p[19].y.abs() < 1e-12,
            "{:?}",
            p[19]
        );
        // Euler and exact arcs part on a turn.
        let turn = Twist::new(1.0, 1.5);
        let e = predicted_rollout(Prediction::PAPERS, &Schedule::ddp_default(), turn, turn);
        let a = predicted_rollout(Prediction::IDEAL, &Schedule::ddp_default(), turn, turn);
        assert!(e[19].position().dist(a[19].position()) > 0.05);
    }

    #[test]
    fn fidelity_colours_darken_with_shorter_steps() {
        let short = fidelity_colour(0.0123);
        let long = fidelity_colour(0.167);
        assert!(short.0 < long.0 && short.1 < long.1 && short.2 < long.2);
    }
}
