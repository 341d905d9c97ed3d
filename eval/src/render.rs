//! `adp render`: a picture of one episode — the world, the driven trajectory, the footprint
//! at intervals, and at chosen moments the sampled rollouts, each segment coloured by its
//! step length (short step = dark = high fidelity, long step = light), as in Fig. 2 of the
//! ADP paper. At the same moments the rollout the planner predicts for the command it chose
//! (its own model: nominal accelerations, the profile's integrator, dots at the grid points)
//! is drawn in purple beside the path the robot really drove (red), so the gap between the
//! planner's model and the robot shows. Samples the compute budget left out (rolled out for the
//! picture only) are grey. Walls are grey boxes; moving obstacles (DynaBARN) are drawn in teal
//! where they are when the episode ends, over the paths their centres swept during it (faint).
//! With `--prediction kf` (or any value of `adp eval --prediction`) the planner runs with the
//! tracker, as in `adp eval`, and the tracks of its last planning cycle are drawn in brown:
//! each estimated disc and the forecast of its centre every 0.4 s over 2.8 s (dots), mapped
//! from the robot's frame by its true pose like the rollouts, so that the gap to the teal
//! obstacle shows the tracker's error (and the localization drift).
//!
//! With `--frames N` the output is instead a frame strip: N pictures side by side of the world
//! at evenly spaced moments from the start to the end of the episode, each with the robot's
//! path so far, its footprint, the moving obstacles and their last two seconds of motion, and
//! with a tracker the tracks and forecasts of the last planning cycle. PNG or SVG by the
//! output's extension.

use std::path::Path;
use std::sync::Once;

use crate::error::{Error, Result};
use plotters::coord::Shift;
use plotters::prelude::*;

use planner::moving::Predicted;
use planner::{run::CycleDriver, Planner, Prediction, Schedule};
use sim::geometry::{Footprint, Pose, Vec2};
use sim::robot::{approach, RobotLimits, Twist};
use sim::{Episode, EpisodeConfig, EpisodeResult, Status, World};

/// DejaVu Sans (Bitstream Vera license, see `assets/fonts/LICENSE-DejaVu.txt`).
const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
/// The family name every figure asks for.
pub const FAMILY: &str = "sans-serif";

/// Registers the embedded font once per process (bitmap pictures need it for their text).
pub fn fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, FONT)
            .unwrap_or_else(|_| panic!("the embedded DejaVu Sans is a valid font"));
    });
}

/// Pixels per metre of a BARN picture.
const SCALE: f64 = 90.0;
/// Longest side of a single picture (px): larger worlds are drawn at a smaller scale.
const MAX_SIDE_PX: f64 = 1600.0;
/// Longest side of one frame of a strip (px).
const FRAME_SIDE_PX: f64 = 480.0;
/// Most frames in a strip.
const MAX_FRAMES: usize = 24;
/// The moving obstacles' recent motion drawn in each frame (s).
const FRAME_TAIL_S: f64 = 2.0;
/// A moving obstacle that moves farther than this in one sample (m) jumped back to the start
/// of its loop: its path is broken there.
const JUMP_M: f64 = 1.0;
/// Moving obstacles: outline, and the fill of their disc.
const MOVING: RGBColor = RGBColor(20, 120, 140);
/// Static obstacles.
const STATIC: RGBColor = RGBColor(90, 90, 90);
/// The tracker's tracks and their forecasts.
const TRACK: RGBColor = RGBColor(150, 80, 20);
/// Spacing (s) and count of the forecast points drawn per track (0 to 2.8 s, as far as
/// `adp eval` measures the forecast).
const FORECAST_STEP_S: f64 = 0.4;
const FORECAST_POINTS: usize = 8;

/// A moving obstacle the tracker reported at one planning cycle, in the world frame.
#[derive(Clone, Debug, PartialEq)]
struct TrackView {
    /// The estimated centre (m).
    centre: Vec2,
    /// The estimated radius (m).
    radius: f64,
    /// The forecast centre every [`FORECAST_STEP_S`] from now, starting now.
    forecast: Vec<Vec2>,
}

impl TrackView {
    /// `p` (robot frame of the cycle) drawn from the robot's true pose `pose`.
    fn of(p: &Predicted, pose: &Pose) -> Self {
        Self {
            centre: pose.to_world(p.position),
            radius: p.radius,
            forecast: (0..FORECAST_POINTS)
                .map(|k| pose.to_world(p.at(k as f64 * FORECAST_STEP_S)))
                .collect(),
        }
    }
}

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
    /// The planning cycles' driver: the compute model, and the tracker when the planner
    /// predicts moving obstacles (`ObstaclePrediction::driver`).
    pub driver: CycleDriver,
    /// Rollouts are drawn every this many seconds of simulated time.
    pub rollout_every_s: f64,
    /// Footprints are drawn every this many seconds.
    pub footprint_every_s: f64,
    /// Draw a strip of this many frames (at least 2) instead of the single picture.
    pub frames: Option<usize>,
}

/// What the episode left to draw.
struct Record {
    /// `(simulated time, true pose)` at every planning cycle, and at the end.
    trail: Vec<(f64, Pose)>,
    /// Rollouts at the chosen moments.
    moments: Vec<Moment>,
    /// The obstacles' clock at the start (s).
    phase: f64,
    /// Simulated time at the end (s).
    end_s: f64,
    /// `(simulated time, tracks)` at every planning cycle, when the driver tracks.
    tracks: Vec<(f64, Vec<TrackView>)>,
}

impl Record {
    /// The tracks of the last planning cycle at or before `t` (none without a tracker).
    fn tracks_at(&self, t: f64) -> &[TrackView] {
        let k = self.tracks.partition_point(|(s, _)| *s <= t);
        k.checked_sub(1).map_or(&[], |k| &self.tracks[k].1)
    }
}

/// Runs the episode and writes the picture to `out`; returns the episode result.
pub fn render(mut job: RenderJob<'_>, out: &Path) -> Result<EpisodeResult> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if ext != "png" && ext != "svg" {
        return Err(Error::Refused(format!(
            "--out {}: the file name must end in .png or .svg",
            out.display()
        )));
    }
    if !(job.rollout_every_s > 0.0 && job.footprint_every_s > 0.0) {
        return Err(Error::Refused(
            "--rollouts-every and --footprint-every must be > 0 s".into(),
        ));
    }
    if let Some(n) = job.frames.filter(|n| !(2..=MAX_FRAMES).contains(n)) {
        return Err(Error::Refused(format!(
            "--frames {n}: a strip has 2 to {MAX_FRAMES} frames"
        )));
    }
    let dt = job.episode.control_dt;
    let prediction = Prediction::for_profile(job.episode.profile);
    let mut rec = Recorder {
        every: (job.rollout_every_s / dt).round().max(1.0) as u64,
        prediction,
        schedule: &job.schedule,
        cycle: 0,
        trail: Vec::new(),
        moments: Vec::new(),
    };
    let mut tracks = Vec::new();
    // The loop of `planner::run::run_episode`, kept here so that the end state is drawn too.
    let mut ep = Episode::new(job.world, job.episode, job.seed);
    while ep.status() == Status::Running {
        let cycles = rec.trail.len();
        job.driver.period(
            &mut ep,
            job.planner.as_mut(),
            &job.schedule,
            job.max_speed,
            prediction,
            &mut |ep: &Episode<'_>, planner: &mut dyn Planner, cmd: Twist| rec.on_cycle(ep, planner, cmd),
        );
        if let (Some(t), Some(&(time, pose))) = (job.driver.tracking(), rec.trail.last()) {
            if rec.trail.len() > cycles {
                tracks.push((time, t.moving().iter().map(|p| TrackView::of(p, &pose)).collect()));
            }
        }
    }
    rec.trail.push((ep.sim_time(), ep.state().pose));
    let record = Record {
        trail: rec.trail,
        moments: rec.moments,
        phase: ep.obstacle_phase(),
        end_s: ep.sim_time(),
        tracks,
    };
    let result = ep.result();
    let (view, size) = match job.frames {
        None => {
            let v = View::of(job.world, MAX_SIDE_PX);
            (v, v.size())
        }
        Some(n) => {
            let v = View::of(job.world, FRAME_SIDE_PX);
            let (w, h) = v.size();
            (v, (w * n as u32, h))
        }
    };
    if ext == "png" {
        fonts();
        let root = BitMapBackend::new(out, size).into_drawing_area();
        draw_any(&root, &job, &view, &record)?;
        root.present().map_err(|e| written(out, e))?;
    } else {
        let root = SVGBackend::new(out, size).into_drawing_area();
        draw_any(&root, &job, &view, &record)?;
        root.present().map_err(|e| written(out, e))?;
    }
    Ok(result)
}

/// The error of writing the picture `out`.
fn written<E: std::error::Error + Send + Sync>(out: &Path, err: DrawingAreaErrorKind<E>) -> Error {
    Error::Draw(format!("cannot write {}: {err:?}", out.display()))
}

/// What the planning cycles of an episode leave to draw, gathered as they happen.
struct Recorder<'a> {
    /// Rollouts are recorded every this many cycles.
    every: u64,
    prediction: Prediction,
    schedule: &'a Schedule,
    /// Planning cycles so far.
    cycle: u64,
    trail: Vec<(f64, Pose)>,
    moments: Vec<Moment>,
}

impl Recorder<'_> {
    /// After each planning call: the pose, and at the chosen moments the rollouts.
    fn on_cycle(&mut self, ep: &Episode<'_>, planner: &mut dyn Planner, cmd: Twist) {
        let pose = ep.state().pose;
        self.trail.push((ep.sim_time(), pose));
        if self.cycle > 0 && self.cycle.is_multiple_of(self.every) {
            let predicted = predicted_rollout(self.prediction, self.schedule, ep.perception().vel, cmd)
                .iter()
                .map(|p| pose.to_world(p.position()))
                .collect();
            let r = planner.rollouts();
            let world = |&(a, b, _): &(usize, usize, bool)| -> Vec<Pose> {
                r.poses[a..b].iter().map(|p| compose(&pose, p)).collect()
            };
            let skipped = |i: usize| r.skipped.get(i).copied().unwrap_or(false);
            self.moments.push(Moment {
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
        self.cycle += 1;
        // Record only during the planning call of each chosen moment.
        planner.set_recording(self.cycle.is_multiple_of(self.every));
    }
}

/// A pose given in the frame of `base`, expressed in the world frame.
fn compose(base: &Pose, p: &Pose) -> Pose {
    let q = base.to_world(Vec2::new(p.x, p.y));
    Pose::new(q.x, q.y, base.yaw + p.yaw)
}

/// The drawn region of a world (world frame, m) and its scale (px/m).
#[derive(Clone, Copy, Debug, PartialEq)]
struct View {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    scale: f64,
}

impl View {
    /// BARN's field and start corridor for a world of static cylinders only; otherwise the box
    /// around the walls, every keyframe, the start and the goal, with a margin. The scale is
    /// BARN's 90 px/m, or less so that the longest side fits in `max_side` pixels.
    fn of(world: &World, max_side: f64) -> Self {
        let (x0, x1, y0, y1) = if world.walls.is_empty() && world.moving.is_empty() {
            (-5.0, 0.5, 1.5, 14.2)
        } else {
            let points = world
                .walls
                .iter()
                .flat_map(|b| [b.min, b.max])
                .chain(world.moving.iter().flat_map(|m| {
                    let r = Vec2::new(m.radius, m.radius);
                    m.trajectory.keyframes().iter().flat_map(move |&k| [k - r, k + r])
                }))
                .chain([world.start.position(), world.goal]);
            let (mut lo, mut hi) = (
                Vec2::new(f64::INFINITY, f64::INFINITY),
                Vec2::new(f64::NEG_INFINITY, f64::NEG_INFINITY),
            );
            for p in points {
                lo = Vec2::new(lo.x.min(p.x), lo.y.min(p.y));
                hi = Vec2::new(hi.x.max(p.x), hi.y.max(p.y));
            }
            let margin = 0.8;
            (lo.x - margin, hi.x + margin, lo.y - margin, hi.y + margin)
        };
        let scale = SCALE.min(max_side / (x1 - x0).max(y1 - y0));
        Self {
            x0,
            x1,
            y0,
            y1,
            scale,
        }
    }

    /// Width and height in pixels.
    fn size(&self) -> (u32, u32) {
        (
            ((self.x1 - self.x0) * self.scale) as u32,
            ((self.y1 - self.y0) * self.scale) as u32,
        )
    }

    /// The pixel of a world point.
    fn px(&self, p: Vec2) -> (i32, i32) {
        (
            ((p.x - self.x0) * self.scale) as i32,
            ((self.y1 - p.y) * self.scale) as i32,
        )
    }

    /// A length in pixels.
    fn len(&self, m: f64) -> i32 {
        (m * self.scale).round() as i32
    }
}

/// Colour of a rollout segment by its step length: dark blue for short steps, pale for long.
fn fidelity_colour(dt: f64) -> RGBColor {
    let f = ((dt - 0.01) / (0.17 - 0.01)).clamp(0.0, 1.0);
    let mix = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
    RGBColor(mix(10.0, 175.0), mix(30.0, 215.0), mix(110.0, 250.0))
}

/// The paths of the moving obstacles' centres from `from` to `to` seconds after the start
/// (obstacle clock `phase` + time), sampled every `dt`: per obstacle, its pieces (broken where
/// the loop jumps back).
fn moving_paths(world: &World, phase: f64, from: f64, to: f64, dt: f64) -> Vec<Vec<Vec<Vec2>>> {
    let samples = ((to - from) / dt).ceil().max(0.0) as usize;
    let times = (0..=samples).map(|k| (from + k as f64 * dt).min(to));
    let mut out: Vec<Vec<Vec<Vec2>>> = vec![vec![Vec::new()]; world.moving.len()];
    for t in times {
        let scene = world.at(phase + t);
        for (pieces, c) in out.iter_mut().zip(scene.moving()) {
            let piece = pieces.last_mut().expect("one piece at least");
            if piece.last().is_some_and(|p| p.dist(c.c) > JUMP_M) {
                pieces.push(vec![c.c]);
            } else {
                piece.push(c.c);
            }
        }
    }
    out
}

/// What every drawing step returns.
type DrawResult = Result<()>;

/// The error of a plotters drawing call, as a one-line error.
fn drawing_error<E: std::error::Error + Send + Sync>(err: DrawingAreaErrorKind<E>) -> Error {
    Error::Draw(format!("{err:?}"))
}

/// The goal region, the walls and the static cylinders.
fn draw_static<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, world: &World, view: &View) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let e = drawing_error::<DB::ErrorType>;
    let goal = view.px(world.goal);
    let gr = view.len(world.goal_radius);
    root.draw(&Circle::new(goal, gr, RGBColor(200, 240, 200).filled()))
        .map_err(e)?;
    root.draw(&Circle::new(goal, gr, RGBColor(40, 140, 40).stroke_width(2)))
        .map_err(e)?;
    for b in &world.walls {
        root.draw(&Rectangle::new(
            [
                view.px(Vec2::new(b.min.x, b.max.y)),
                view.px(Vec2::new(b.max.x, b.min.y)),
            ],
            STATIC.filled(),
        ))
        .map_err(e)?;
    }
    for c in &world.cylinders {
        root.draw(&Circle::new(view.px(c.c), view.len(c.r), STATIC.filled()))
            .map_err(e)?;
    }
    Ok(())
}

/// The moving obstacles' centre paths from `from` to `to` seconds after the start (faint), and
/// the obstacles where they are at `to`.
fn draw_moving<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    world: &World,
    view: &View,
    record: &Record,
    (from, to): (f64, f64),
    dt: f64,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let e = drawing_error::<DB::ErrorType>;
    let faint = MOVING.mix(0.3).stroke_width(2);
    for pieces in moving_paths(world, record.phase, from, to, dt) {
        for piece in pieces.iter().filter(|p| p.len() > 1) {
            let line: Vec<(i32, i32)> = piece.iter().map(|&p| view.px(p)).collect();
            root.draw(&PathElement::new(line, faint)).map_err(e)?;
        }
    }
    for c in world.at(record.phase + to).moving() {
        let (at, r) = (view.px(c.c), view.len(c.r));
        root.draw(&Circle::new(at, r, MOVING.mix(0.55).filled()))
            .map_err(e)?;
        root.draw(&Circle::new(at, r, MOVING.stroke_width(2)))
            .map_err(e)?;
    }
    Ok(())
}

/// The tracker's `tracks`: each estimated disc (outline) and its forecast centre, a line
/// with a dot every [`FORECAST_STEP_S`] and the disc's outline at the last one (faint).
fn draw_tracks<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    tracks: &[TrackView],
    view: &View,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let e = drawing_error::<DB::ErrorType>;
    for tr in tracks {
        let r = view.len(tr.radius);
        root.draw(&Circle::new(view.px(tr.centre), r, TRACK.stroke_width(2)))
            .map_err(e)?;
        let line: Vec<(i32, i32)> = tr.forecast.iter().map(|&p| view.px(p)).collect();
        root.draw(&PathElement::new(line, TRACK.stroke_width(2)))
            .map_err(e)?;
        for &p in &tr.forecast {
            root.draw(&Circle::new(view.px(p), 3, TRACK.filled()))
                .map_err(e)?;
        }
        if let Some(&last) = tr.forecast.last() {
            root.draw(&Circle::new(view.px(last), r, TRACK.mix(0.4).stroke_width(1)))
                .map_err(e)?;
        }
    }
    Ok(())
}

/// The footprint outline at `pose`.
fn footprint<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    fp: &Footprint,
    pose: &Pose,
    view: &View,
    width: u32,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let corners = [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
        .map(|(sx, sy)| view.px(pose.to_world(Vec2::new(sx * fp.half_length, sy * fp.half_width))));
    root.draw(&PathElement::new(
        corners.to_vec(),
        RGBColor(230, 120, 20).stroke_width(width),
    ))
    .map_err(drawing_error::<DB::ErrorType>)
}

/// Draws the picture or the strip the job asks for.
fn draw_any<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    job: &RenderJob<'_>,
    view: &View,
    record: &Record,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    match job.frames {
        None => draw(root, job, view, record),
        Some(n) => draw_strip(root, job, view, record, n),
    }
}

/// The single picture: the world, the moving obstacles at the end over their swept paths, the
/// rollouts at the chosen moments, the footprints, the driven path and the predicted rollouts.
fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    job: &RenderJob<'_>,
    view: &View,
    record: &Record,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let e = drawing_error::<DB::ErrorType>;
    root.fill(&WHITE).map_err(e)?;
    let px = |p: Vec2| view.px(p);
    draw_static(root, job.world, view)?;
    let dt = job.episode.control_dt;
    draw_moving(root, job.world, view, record, (0.0, record.end_s), dt)?;
    // Rollouts at the chosen moments, segment by segment; first those the compute budget
    // left out, in grey.
    for m in &record.moments {
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
    let step = (job.footprint_every_s / dt).round().max(1.0) as usize;
    let trail = &record.trail;
    for (_, pose) in trail.iter().step_by(step).chain(trail.last()) {
        footprint(root, &fp, pose, view, 2)?;
    }
    let line: Vec<(i32, i32)> = trail.iter().map(|(_, p)| px(p.position())).collect();
    root.draw(&PathElement::new(line, RGBColor(200, 30, 30).stroke_width(3)))
        .map_err(e)?;
    // The tracks of the last planning cycle (beside the obstacles where they are at the end),
    // then the chosen command's predicted rollout, over the driven path.
    draw_tracks(root, record.tracks_at(record.end_s), view)?;
    let purple = RGBColor(120, 40, 170);
    for m in &record.moments {
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

/// The moments of the `n` frames of a strip: evenly spaced from 0 to `end_s`.
fn frame_times(n: usize, end_s: f64) -> Vec<f64> {
    (0..n).map(|k| end_s * k as f64 / (n - 1) as f64).collect()
}

/// `n` frames side by side: at each moment the world, the moving obstacles with their last
/// [`FRAME_TAIL_S`] seconds, the robot's path so far and its footprint, and the time.
fn draw_strip<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    job: &RenderJob<'_>,
    view: &View,
    record: &Record,
    n: usize,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let e = drawing_error::<DB::ErrorType>;
    root.fill(&WHITE).map_err(e)?;
    let dt = job.episode.control_dt;
    let fp: Footprint = job.episode.robot.footprint;
    let (w, h) = view.size();
    for (area, t) in root.split_evenly((1, n)).iter().zip(frame_times(n, record.end_s)) {
        draw_static(area, job.world, view)?;
        draw_moving(
            area,
            job.world,
            view,
            record,
            ((t - FRAME_TAIL_S).max(0.0), t),
            dt,
        )?;
        // The trail up to `t`; the pose at `t` is its last point.
        let upto = record.trail.partition_point(|(s, _)| *s <= t).max(1);
        let trail = &record.trail[..upto];
        let line: Vec<(i32, i32)> = trail.iter().map(|(_, p)| view.px(p.position())).collect();
        area.draw(&PathElement::new(line, RGBColor(200, 30, 30).stroke_width(2)))
            .map_err(e)?;
        footprint(area, &fp, &trail[upto - 1].1, view, 2)?;
        draw_tracks(area, record.tracks_at(t), view)?;
        area.draw(&Text::new(
            format!("t = {t:.1} s"),
            (8, 8),
            (FAMILY, 18).into_font().color(&BLACK),
        ))
        .map_err(e)?;
        area.draw(&Rectangle::new(
            [(0, 0), (w as i32 - 1, h as i32 - 1)],
            RGBColor(160, 160, 160).stroke_width(1),
        ))
        .map_err(e)?;
    }
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
    fn views_fit_the_world_and_paths_break_where_the_loop_jumps() {
        // BARN keeps its field and 90 px/m.
        let barn = View::of(sim::catalog::world(3).unwrap(), MAX_SIDE_PX);
        assert_eq!((barn.size(), barn.scale), ((495, 1143), 90.0));
        // DynaBARN: the walls (x from -10.25), the start (x = 11) and every keyframe, scaled
        // so that the longest side is 1600 px.
        let w = sim::catalog::world(300).unwrap();
        let v = View::of(w, MAX_SIDE_PX);
        assert!(v.x0 <= -10.25 - 0.8 && v.x1 >= 11.0 + 0.8 && v.y0 <= -10.25 - 0.8 && v.y1 >= 10.25 + 0.8);
        assert!(v.scale < SCALE && v.size().0.max(v.size().1) <= 1600);
        // Obstacle 1 of world 300 loops every 39.05 s: from 38.5 s to 39.5 s (phase 0, 21
        // samples 0.05 s apart) its path has two pieces, before and after the jump back to its
        // first keyframe (10, 8).
        let record_paths = moving_paths(w, 0.0, 38.5, 39.5, 0.05);
        assert_eq!(record_paths.len(), w.moving.len());
        let pieces = &record_paths[1];
        assert_eq!(pieces.len(), 2);
        assert!(pieces[0].last().unwrap().dist(Vec2::new(-5.0, -10.0)) < 0.1);
        assert!(pieces[1][0].dist(Vec2::new(10.0, 8.0)) < 0.1);
        assert_eq!(pieces.iter().map(Vec::len).sum::<usize>(), 21);
        assert_eq!(frame_times(5, 4.0), vec![0.0, 1.0, 2.0, 3.0, 4.0]);
    }

    /// A track is drawn where the robot's true pose puts its robot-frame estimate, its
    /// forecast every 0.4 s along its velocity; the strip's frames take the tracks of the
    /// last cycle at or before their time.
    #[test]
    fn tracks_are_drawn_in_the_world_frame_at_their_cycle() {
        let seen = Predicted {
            position: Vec2::new(1.0, 0.0),
            velocity: Vec2::new(1.0, 0.5),
            radius: 0.5,
            residual: None,
        };
        // Robot at (2, 3) facing +y: its x axis is the world's +y, its y axis the world's -x.
        let pose = Pose::new(2.0, 3.0, std::f64::consts::FRAC_PI_2);
        let v = TrackView::of(&seen, &pose);
        let near = |a: Vec2, b: Vec2| a.dist(b) < 1e-12;
        assert!(near(v.centre, Vec2::new(2.0, 4.0)), "{:?}", v.centre);
        assert_eq!((v.radius, v.forecast.len()), (0.5, 8));
        assert!(near(v.forecast[0], v.centre));
        // 2.8 s ahead: (1 + 2.8, 0 + 1.4) in the robot frame.
        assert!(
            near(v.forecast[7], Vec2::new(2.0 - 1.4, 3.0 + 3.8)),
            "{:?}",
            v.forecast[7]
        );
        let record = Record {
            trail: Vec::new(),
            moments: Vec::new(),
            phase: 0.0,
            end_s: 3.0,
            tracks: vec![(0.05, Vec::new()), (1.0, vec![v.clone()]), (2.0, Vec::new())],
        };
        assert!(record.tracks_at(0.0).is_empty());
        assert_eq!(record.tracks_at(1.0), std::slice::from_ref(&v));
        assert_eq!(record.tracks_at(1.99), &[v]);
        assert!(record.tracks_at(2.5).is_empty());
    }

    #[test]
    fn fidelity_colours_darken_with_shorter_steps() {
        let short = fidelity_colour(0.0123);
        let long = fidelity_colour(0.167);
        assert!(short.0 < long.0 && short.1 < long.1 && short.2 < long.2);
    }
}
