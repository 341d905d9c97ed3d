//! One BARN run: robot, sensor, the robot's own map and global path, and the protocol
//! (start, goal radius, clock that starts after 0.1 m of motion, timeout, collision).
//!
//! The episode is stepped by its caller one control period at a time, so the same type
//! serves evaluation (a planner every 0.05 s) and RL (an agent every 0.25 s on top).

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::costmap::{Costmap, CostmapConfig};
use crate::dynamics::{Drive, Dynamics, Localization, Profile};
use crate::error::ConfigError;
use crate::geometry::{Pose, Vec2};
use crate::lidar::{Lidar, LidarConfig, LidarRng};
pub use crate::nav_stack::Perception;
use crate::nav_stack::{NavStack, Scan};
use crate::navigation::PathRisk;
use crate::predictive_cost::MovingObstacle;
use crate::robot::{RobotLimits, RobotState, Twist};
use crate::score::barn_score;
use crate::world::{Scene, World};

/// Seed offset of the localization-drift stream (kept apart from the sensor noise, so the
/// `ideal` profile draws exactly the noise it always did).
const DRIFT_STREAM: u64 = 0x5eed_d41f_7000_0001;
/// Seed offset of the start-jitter stream (apart from noise and drift, so a zero jitter draws
/// nothing and changes nothing).
const JITTER_STREAM: u64 = 0x5eed_517a_7000_0002;
/// Seed offset of the obstacle-phase stream (apart from the others; a static world draws
/// nothing from it).
const PHASE_STREAM: u64 = 0x5eed_0b57_7000_0003;
/// Largest accepted start-position jitter (m): the BARN start corridor leaves the Jackal's
/// footprint about this much room on each side.
pub const MAX_START_JITTER_M: f64 = 0.2;
/// Largest accepted start-heading jitter (rad).
pub const MAX_START_JITTER_YAW_RAD: f64 = 0.3;

/// The start pose of a run: `start` moved by the seeded jitter of `cfg` (unchanged without
/// jitter).
fn jittered_start(start: Pose, cfg: &EpisodeConfig, seed: u64) -> Pose {
    if cfg.start_jitter_m == 0.0 && cfg.start_jitter_yaw_rad == 0.0 {
        return start;
    }
    let mut rng = Pcg64Mcg::seed_from_u64(seed ^ JITTER_STREAM);
    let mut draw = |j: f64| if j > 0.0 { rng.random_range(-j..=j) } else { 0.0 };
    let (dx, dy) = (draw(cfg.start_jitter_m), draw(cfg.start_jitter_m));
    let dyaw = draw(cfg.start_jitter_yaw_rad);
    Pose::new(start.x + dx, start.y + dy, start.yaw + dyaw)
}

/// The obstacles' clock when the robot starts (s), drawn for the run with seed `seed`: uniform
/// in [0, longest loop of the world's moving obstacles), one value for all of them (they share
/// one clock, as Gazebo's animations share the simulation time). 0 for a world without moving
/// obstacles, which draws nothing.
///
/// The original DynaBARN challenge does not control this: its obstacles start moving when
/// Gazebo starts, not when the robot does, so where they are at the robot's departure depends
/// on how long the launch took. Here it is seeded, so a run repeats exactly and the runs of a
/// world see different phases.
pub fn obstacle_phase(world: &World, seed: u64) -> f64 {
    if world.moving.is_empty() {
        return 0.0;
    }
    let mut rng = Pcg64Mcg::seed_from_u64(seed ^ PHASE_STREAM);
    rng.random_range(0.0..world.longest_period())
}

/// Episode parameters. Defaults follow the BARN protocol (DESIGN §3).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EpisodeConfig {
    /// Physics integration step (s); at most 0.01.
    pub physics_dt: f64,
    /// Control period: one planner cycle (s).
    pub control_dt: f64,
    /// Timeout on the run clock (s).
    pub timeout_s: f64,
    /// The run clock starts once the robot is this far from its start (m).
    pub clock_start_distance: f64,
    /// Replan the global path every this many control periods (and whenever none exists).
    pub replan_every: u32,
    /// Window of the moving average that smooths the global path (points).
    pub smoothing_window: usize,
    /// Sensor.
    pub lidar: LidarConfig,
    /// The robot's map.
    pub costmap: CostmapConfig,
    /// Robot limits.
    pub robot: RobotLimits,
    /// How the robot really responds to commands (and how planners predict it): `ideal`,
    /// `gazebo-jackal` (default) or `custom`.
    pub profile: Profile,
    /// The response parameters of `profile = "custom"` (must be absent otherwise).
    pub dynamics: Option<Dynamics>,
    /// Start-pose jitter (m): the robot starts at the world's start moved by an offset drawn
    /// uniformly from [-j, j] along x and along y (its own seeded stream, so runs of one world
    /// start at different poses). 0 (the default) keeps the world's exact start.
    pub start_jitter_m: f64,
    /// Start-heading jitter (rad): the start yaw is moved by an angle drawn uniformly from
    /// [-j, j]. 0 (the default) keeps the world's start heading.
    pub start_jitter_yaw_rad: f64,
}

impl Default for EpisodeConfig {
    fn default() -> Self {
        Self {
            physics_dt: 0.01,
            control_dt: 0.05,
            timeout_s: 100.0,
            clock_start_distance: 0.1,
            replan_every: 5,
            smoothing_window: 9,
            lidar: LidarConfig::default(),
            costmap: CostmapConfig::default(),
            robot: RobotLimits::JACKAL,
            profile: Profile::default(),
            dynamics: None,
            start_jitter_m: 0.0,
            start_jitter_yaw_rad: 0.0,
        }
    }
}

impl EpisodeConfig {
    /// Checks the values.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(self.physics_dt > 0.0 && self.physics_dt <= 0.01) {
            return Err(ConfigError::value(
                "physics_dt",
                self.physics_dt,
                "must be in (0, 0.01]",
            ));
        }
        if self.control_dt.is_nan() || self.control_dt < self.physics_dt {
            return Err(ConfigError::value(
                "control_dt",
                self.control_dt,
                "must be >= physics_dt",
            ));
        }
        if self.timeout_s.is_nan() || self.timeout_s <= 0.0 {
            return Err(ConfigError::value("timeout_s", self.timeout_s, "must be > 0"));
        }
        if self.replan_every == 0 {
            return Err(ConfigError::ReplanEvery);
        }
        if !(0.0..=MAX_START_JITTER_M).contains(&self.start_jitter_m) {
            return Err(ConfigError::value(
                "start_jitter_m",
                self.start_jitter_m,
                format!("must be in [0, {MAX_START_JITTER_M}] m"),
            ));
        }
        if !(0.0..=MAX_START_JITTER_YAW_RAD).contains(&self.start_jitter_yaw_rad) {
            return Err(ConfigError::value(
                "start_jitter_yaw_rad",
                self.start_jitter_yaw_rad,
                format!("must be in [0, {MAX_START_JITTER_YAW_RAD}] rad"),
            ));
        }
        self.resolved_dynamics()?;
        self.costmap.validate()?;
        self.lidar.validate()
    }

    /// The robot's response parameters: the profile's preset, or the `dynamics` table of a
    /// custom profile.
    pub fn resolved_dynamics(&self) -> Result<Dynamics, ConfigError> {
        self.profile.resolve(self.dynamics.as_ref(), "episode.dynamics")
    }

    /// This configuration with another profile (and custom parameters, for
    /// [`Profile::Custom`]).
    pub fn with_profile(mut self, profile: Profile, dynamics: Option<Dynamics>) -> Self {
        self.profile = profile;
        self.dynamics = dynamics;
        self
    }
}

/// How a run stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Still going.
    Running,
    /// Reached the goal radius.
    Succeeded,
    /// The footprint touched an obstacle.
    Collided,
    /// The clock passed the timeout.
    TimedOut,
}

/// The outcome of a finished (or abandoned) run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    /// World id.
    pub world: usize,
    /// Final status.
    pub status: Status,
    /// Run-clock time at the end (s): from the first 0.1 m of motion.
    pub time_s: f64,
    /// Simulated time since reset (s).
    pub sim_time_s: f64,
    /// BARN score.
    pub score: f64,
    /// Distance driven (m).
    pub distance_m: f64,
}

/// A running BARN episode. Owns all its buffers; stepping does not allocate once warm.
pub struct Episode<'w> {
    world: &'w World,
    /// The world at the current time (the obstacles' clock is `phase + sim_time`).
    scene: Scene<'w>,
    /// The obstacles' clock at the start ([`obstacle_phase`]).
    phase: f64,
    cfg: EpisodeConfig,
    lidar: Lidar,
    lidar_rng: LidarRng,
    drift_rng: Pcg64Mcg,
    drive: Drive,
    localization: Localization,
    /// Distance driven since the last drift update (m).
    undrifted: f64,
    /// Where this run started (the world's start, jittered when configured).
    start: Pose,
    state: RobotState,
    sim_time: f64,
    clock_start: Option<f64>,
    distance: f64,
    status: Status,
    end_time: f64,
    ranges: Vec<f64>,
    /// The robot's costmap, global path and local goal.
    nav: NavStack,
}

impl<'w> Episode<'w> {
    /// Resets the robot to the world's start; the seed drives the sensor noise and (on
    /// separate streams) the localization drift, the start jitter and the moving obstacles'
    /// phase ([`obstacle_phase`]).
    ///
    /// # Panics
    /// If the profile does not resolve ([`EpisodeConfig::validate`] reports that first).
    pub fn new(world: &'w World, cfg: EpisodeConfig, seed: u64) -> Self {
        let dynamics = cfg
            .resolved_dynamics()
            .unwrap_or_else(|e| panic!("invalid episode configuration: {e}"));
        let lidar = Lidar::new(cfg.lidar);
        let start = jittered_start(world.start, &cfg, seed);
        let clearing = cfg.costmap.clearing.enabled(!world.moving.is_empty());
        let phase = obstacle_phase(world, seed);
        let mut ep = Self {
            world,
            scene: world.at(phase),
            phase,
            cfg,
            lidar,
            lidar_rng: LidarRng::new(seed),
            drift_rng: Pcg64Mcg::seed_from_u64(seed ^ DRIFT_STREAM),
            drive: Drive::new(dynamics, cfg.robot, cfg.physics_dt),
            localization: Localization::default(),
            undrifted: 0.0,
            start,
            state: RobotState {
                pose: start,
                vel: Twist::default(),
            },
            sim_time: 0.0,
            clock_start: None,
            distance: 0.0,
            status: Status::Running,
            end_time: 0.0,
            ranges: Vec::new(),
            nav: NavStack::new(
                cfg.costmap,
                cfg.replan_every,
                cfg.smoothing_window,
                clearing,
                start.position(),
                world.goal,
            ),
        };
        ep.sense();
        ep
    }

    /// The world being driven.
    pub fn world(&self) -> &'w World {
        self.world
    }

    /// The world as it is now (the moving obstacles where they are at this moment). Ground
    /// truth, like [`Episode::state`]: for the harness and drawing, not for planners.
    pub fn scene(&self) -> &Scene<'w> {
        &self.scene
    }

    /// The obstacles' clock when the run started (s): [`obstacle_phase`] of its seed.
    pub fn obstacle_phase(&self) -> f64 {
        self.phase
    }

    /// Where this run started: the world's start, moved by the configured start jitter.
    pub fn start(&self) -> Pose {
        self.start
    }

    /// The configuration.
    pub fn config(&self) -> &EpisodeConfig {
        &self.cfg
    }

    /// The robot's lidar (its beam angles order [`Perception::ranges`]).
    pub fn lidar(&self) -> &Lidar {
        &self.lidar
    }

    /// Ground-truth robot state (world frame). Planners must not use it; it is for the
    /// harness, rewards and drawing.
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// Current status.
    pub fn status(&self) -> Status {
        self.status
    }

    /// Simulated time since reset (s).
    pub fn sim_time(&self) -> f64 {
        self.sim_time
    }

    /// The smoothed global path (world frame).
    pub fn global_path(&self) -> &[Vec2] {
        self.nav.global_path()
    }

    /// The local goal (world frame).
    pub fn local_goal_world(&self) -> Vec2 {
        self.nav.local_goal_world()
    }

    /// The robot's costmap.
    pub fn costmap(&self) -> &Costmap {
        self.nav.costmap()
    }

    /// The robot's navigation state: costmap, global path and local goal.
    pub fn nav(&self) -> &NavStack {
        &self.nav
    }

    /// Replans the global path every `periods` control periods from now on (instead of
    /// `[episode] replan_every`): the next replan comes `periods` after the last one.
    ///
    /// # Panics
    /// If `periods` is 0.
    pub fn set_replan_every(&mut self, periods: u32) {
        self.nav.set_replan_every(periods);
    }

    /// The current replanning interval (control periods).
    pub fn replan_every(&self) -> u32 {
        self.nav.replan_every()
    }

    /// Makes the global path search weigh PADP's predictive cost `risk` of the `moving`
    /// obstacles (their positions at simulated time `time` and their velocities, in the
    /// believed frame of the costmap) from the next replan on ([`NavStack::forecast_moving`]).
    /// No obstacle (the default) plans on the costmap alone.
    pub fn forecast_moving(
        &mut self,
        risk: PathRisk,
        time: f64,
        moving: impl IntoIterator<Item = MovingObstacle>,
    ) {
        self.nav.forecast_moving(risk, time, moving);
    }

    /// The pose the robot believes it has (world frame): the truth plus localization drift.
    pub fn believed_pose(&self) -> Pose {
        self.localization.estimate(&self.state.pose)
    }

    /// The robot's response parameters.
    pub fn dynamics(&self) -> &Dynamics {
        self.drive.dynamics()
    }

    /// What the planner sees now.
    pub fn perception(&self) -> Perception<'_> {
        self.nav
            .perception(&self.ranges, self.state.vel, &self.believed_pose())
    }

    /// Issues `cmd` (it takes effect after the profile's latency) and simulates one control
    /// period (several physics steps), then senses and updates the map and path. Does nothing
    /// once the run has ended.
    pub fn step(&mut self, cmd: Twist) -> Status {
        if self.status != Status::Running {
            return self.status;
        }
        self.drive.command(cmd);
        self.advance()
    }

    /// Issues `cmd`, planned with `compute_s` seconds of modelled computation: it takes effect
    /// after the profile's latency with its planning share replaced by `compute_s` (see
    /// [`crate::dynamics::PLANNING_LATENCY_S`]); then simulates one control period like
    /// [`Episode::step`].
    pub fn step_after(&mut self, cmd: Twist, compute_s: f64) -> Status {
        if self.status != Status::Running {
            return self.status;
        }
        self.drive.command_after(cmd, compute_s);
        self.advance()
    }

    /// Simulates one control period without a new command (the planner is still computing:
    /// the robot keeps the command it has), then senses.
    pub fn hold(&mut self) -> Status {
        if self.status != Status::Running {
            return self.status;
        }
        self.advance()
    }

    /// One control period of physics, then sensing.
    fn advance(&mut self) -> Status {
        let n = (self.cfg.control_dt / self.cfg.physics_dt).round().max(1.0) as usize;
        let dt = self.cfg.control_dt / n as f64;
        let fp = self.cfg.robot.footprint;
        for _ in 0..n {
            let before = self.state.pose.position();
            self.drive.step(&mut self.state, dt);
            self.sim_time += dt;
            let pos = self.state.pose.position();
            let moved = pos.dist(before);
            self.distance += moved;
            self.undrifted += moved;
            if self.clock_start.is_none() && pos.dist(self.start.position()) >= self.cfg.clock_start_distance
            {
                self.clock_start = Some(self.sim_time);
            }
            self.scene.set_time(self.phase + self.sim_time);
            if self.scene.collides(&fp, &self.state.pose) {
                return self.finish(Status::Collided);
            }
            if pos.dist(self.world.goal) <= self.world.goal_radius {
                return self.finish(Status::Succeeded);
            }
            if self.run_time() >= self.cfg.timeout_s {
                return self.finish(Status::TimedOut);
            }
        }
        self.sense();
        self.status
    }

    /// Ends the run early as a timeout (used by callers with their own step cap).
    pub fn abandon(&mut self) {
        if self.status == Status::Running {
            self.finish(Status::TimedOut);
        }
    }

    /// The run clock: since the robot first moved 0.1 m (or since reset if it never did, so
    /// a robot that never moves still times out).
    pub fn run_time(&self) -> f64 {
        self.sim_time - self.clock_start.unwrap_or(0.0)
    }

    /// The result so far (final once the status is not `Running`).
    pub fn result(&self) -> EpisodeResult {
        let time_s = if self.status == Status::Running {
            self.run_time()
        } else {
            self.end_time
        };
        EpisodeResult {
            world: self.world.id,
            status: self.status,
            time_s,
            sim_time_s: self.sim_time,
            score: barn_score(
                self.status == Status::Succeeded,
                self.world.optimal_time_s,
                time_s,
            ),
            distance_m: self.distance,
        }
    }

    fn finish(&mut self, status: Status) -> Status {
        self.status = status;
        self.end_time = self.run_time();
        status
    }

    /// Scan (from the true pose), then, from the believed pose: mark the map, replan when due,
    /// and recompute the local goal.
    fn sense(&mut self) {
        self.lidar.scan(
            &self.scene,
            &self.state.pose,
            &mut self.lidar_rng,
            &mut self.ranges,
        );
        let dynamics = *self.drive.dynamics();
        self.localization
            .drift(&dynamics, self.undrifted, &mut self.drift_rng);
        self.undrifted = 0.0;
        let scan = Scan {
            ranges: &self.ranges,
            pose: self.believed_pose(),
            speed: self.state.vel.v,
            time: self.sim_time,
        };
        self.nav.update(&self.lidar, &scan, None);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Circle, Pose};

    /// The protocol tests drive the ideal robot, whose motion is known in closed form.
    fn ideal() -> EpisodeConfig {
        EpisodeConfig::default().with_profile(Profile::Ideal, None)
    }

    fn corridor(with_wall: bool) -> World {
        // Two walls of cylinders 2 m apart along +y; optionally a wall across at y = 4.
        let wall: Vec<Circle> = (0..14)
            .filter(|_| with_wall)
            .map(|i| Circle {
                c: Vec2::new(-1.0 + 0.15 * i as f64, 4.0),
                r: 0.075,
            })
            .collect();
        World::corridor(1.0, &wall)
    }

    #[test]
    fn straight_drive_into_wall_collides() {
        let w = corridor(true);
        let mut ep = Episode::new(&w, ideal(), 1);
        let mut status = Status::Running;
        for _ in 0..400 {
            status = ep.step(Twist::new(1.0, 0.0));
            if status != Status::Running {
                break;
            }
        }
        assert_eq!(status, Status::Collided);
        // Contact happens when the front (0.254 ahead) reaches the wall surface at y = 3.925.
        let y = ep.state().pose.y;
        assert!((y + 0.254 - 3.925).abs() < 0.02, "collided at y = {y}");
        let r = ep.result();
        assert_eq!(r.score, 0.0);
        // After the result, stepping does nothing.
        assert_eq!(ep.step(Twist::new(1.0, 0.0)), Status::Collided);
        assert_eq!(ep.result(), r);
    }

    #[test]
    fn clear_corridor_succeeds_and_scores() {
        let w = corridor(false);
        let mut ep = Episode::new(&w, ideal(), 1);
        while ep.step(Twist::new(2.0, 0.0)) == Status::Running {}
        let r = ep.result();
        assert_eq!(r.status, Status::Succeeded);
        // 9 m to the goal radius at 2 m/s after a 0.1 s ramp: about 4.5 s.
        assert!((r.time_s - 4.5).abs() < 0.1, "{}", r.time_s);
        assert!((r.score - barn_score(true, 5.0, r.time_s)).abs() < 1e-12);
        // The local goal is ahead and the path runs up the corridor.
        assert!(ep.global_path().iter().all(|p| p.x.abs() < 0.5));
    }

    #[test]
    fn standing_still_times_out_and_clock_waits_for_motion() {
        let w = corridor(false);
        let cfg = EpisodeConfig {
            timeout_s: 2.0,
            ..ideal()
        };
        let mut ep = Episode::new(&w, cfg, 1);
        let mut steps = 0;
        while ep.step(Twist::new(0.0, 0.0)) == Status::Running {
            steps += 1;
        }
        assert_eq!(ep.status(), Status::TimedOut);
        assert_eq!(steps, 39);
        // Moving slowly: the clock starts only after 0.1 m.
        let mut ep = Episode::new(&w, ideal(), 1);
        for _ in 0..20 {
            ep.step(Twist::new(0.05, 0.0));
        }
        // 1 s at 0.05 m/s = 0.05 m: the clock has not started, run time = sim time.
        assert!((ep.run_time() - ep.sim_time()).abs() < 1e-12);
        for _ in 0..60 {
            ep.step(Twist::new(0.05, 0.0));
        }
        assert!(ep.run_time() < ep.sim_time() - 1.5);
    }

    #[test]
    fn same_seed_same_trajectory() {
        let w = crate::catalog::world(10).unwrap();
        let run = |seed| {
            let mut ep = Episode::new(w, EpisodeConfig::default(), seed);
            let mut out = Vec::new();
            for k in 0..100 {
                let p = ep.perception();
                // A simple reactive controller that depends on the noisy scan.
                let w_cmd = (p.local_goal.y.atan2(p.local_goal.x)).clamp(-1.0, 1.0) + p.ranges[k] * 1e-3;
                ep.step(Twist::new(0.5, w_cmd));
                out.push(ep.state().pose);
            }
            out
        };
        assert_eq!(run(5), run(5));
        assert_ne!(run(5), run(6));
    }

    #[test]
    fn the_jackal_profile_lags_and_drifts_where_the_ideal_one_does_not() {
        let w = corridor(false);
        let drive = |cfg: EpisodeConfig| {
            let mut ep = Episode::new(&w, cfg, 9);
            for _ in 0..40 {
                ep.step(Twist::new(1.5, 0.3));
            }
            (ep.state().pose, ep.believed_pose(), ep.state().vel)
        };
        let (truth, belief, vel) = drive(ideal());
        assert_eq!(truth, belief, "no drift on the ideal robot");
        assert!((vel.v - 1.5).abs() < 1e-12 && (vel.w - 0.3).abs() < 1e-12);
        let (truth_j, belief_j, vel_j) = drive(EpisodeConfig::default());
        assert_ne!(truth_j, belief_j, "the believed pose drifts");
        assert!(truth_j.position().dist(belief_j.position()) < 0.2);
        // 2 s of driving: slower to start (lag, 2.5 m/s^2, latency), and the base turns less
        // than commanded (skid-steer slip).
        assert!(truth_j.y < truth.y - 0.05, "{} vs {}", truth_j.y, truth.y);
        assert!(vel_j.w < 0.3 && vel_j.w > 0.2, "yaw rate {}", vel_j.w);
        // A config naming a custom profile without its table is refused.
        let bad = EpisodeConfig::default().with_profile(Profile::Custom, None);
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("[episode.dynamics]"));
    }
    #[test]
    fn start_jitter_is_seeded_bounded_and_off_by_default() {
        let w = crate::catalog::world(0).unwrap();
        let exact = Episode::new(w, EpisodeConfig::default(), 3);
        assert_eq!(exact.start(), w.start);
        assert_eq!(exact.state().pose, w.start);
        let cfg = EpisodeConfig {
            start_jitter_m: 0.1,
            start_jitter_yaw_rad: 0.1,
            ..EpisodeConfig::default()
        };
        let a = Episode::new(w, cfg, 3).start();
        assert_eq!(a, Episode::new(w, cfg, 3).start(), "same seed, same start");
        assert_ne!(a, Episode::new(w, cfg, 4).start(), "another seed, another start");
        assert!((a.x - w.start.x).abs() <= 0.1 && (a.y - w.start.y).abs() <= 0.1);
        assert!((a.yaw - w.start.yaw).abs() <= 0.1 && a != w.start);
        let bad = EpisodeConfig {
            start_jitter_m: 0.5,
            ..EpisodeConfig::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("start_jitter_m"));
        // The largest accepted jitter keeps the footprint free in every BARN world.
        let (j, jy) = (MAX_START_JITTER_M, MAX_START_JITTER_YAW_RAD);
        for world in crate::catalog::barn_worlds() {
            for (sx, sy, sa) in [
                (1.0, 1.0, 1.0),
                (-1.0, 1.0, -1.0),
                (1.0, -1.0, -1.0),
                (-1.0, -1.0, 1.0),
            ] {
                let s = world.start;
                let p = Pose::new(s.x + sx * j, s.y + sy * j, s.yaw + sa * jy);
                assert!(
                    !world.at(0.0).collides(&crate::geometry::Footprint::JACKAL, &p),
                    "world {}",
                    world.id
                );
            }
        }
    }

    #[test]
    fn a_moving_obstacle_collides_when_it_reaches_the_robot() {
        use crate::motion::{MovingCylinder, Trajectory};
        // A cylinder of radius 0.5 driving along -x through the robot's position, one key
        // per second from (3, 0) to (-1, 0), looping every 4 s. Evenly spaced collinear keys
        // have Catmull-Rom tangents equal to the step inside, so from t = 2 s to 3 s the centre
        // is exactly at x = 1 - (t - 2). It touches the standing robot's front (x = 0.254) when
        // its centre is at 0.754: t = 2.246 s on the obstacles' clock.
        let keys: Vec<[f64; 3]> = (0..5).map(|k| [k as f64, 3.0 - k as f64, 0.0]).collect();
        let w = World::new(0, vec![], Pose::default(), Vec2::new(-9.0, 5.0), 9.0, vec![]).with_moving(vec![
            MovingCylinder {
                radius: 0.5,
                trajectory: Trajectory::new(&keys, 4.0).unwrap(),
            },
        ]);
        assert_eq!(w.at(2.5).moving()[0].c, Vec2::new(0.5, 0.0));
        // The run's phase decides when that is on the run's clock; take a seed whose phase
        // starts the obstacle before the contact.
        let seed = (0..).find(|&s| obstacle_phase(&w, s) < 2.0).unwrap();
        let phase = obstacle_phase(&w, seed);
        let mut ep = Episode::new(&w, ideal(), seed);
        assert_eq!(ep.obstacle_phase(), phase);
        while ep.step(Twist::new(0.0, 0.0)) == Status::Running {}
        assert_eq!(ep.status(), Status::Collided);
        // Collision is checked every 0.01 s physics step.
        let expected = 2.246 - phase;
        assert!(
            ep.sim_time() >= expected - 1e-9 && ep.sim_time() < expected + 0.01 + 1e-9,
            "collided at {} s, expected {expected} s",
            ep.sim_time()
        );
        assert!((ep.scene().time() - (phase + ep.sim_time())).abs() < 1e-12);
        // The phase is the seed's: repeatable, different across seeds, in [0, 4).
        assert_eq!(obstacle_phase(&w, 7), obstacle_phase(&w, 7));
        assert_ne!(obstacle_phase(&w, 7), obstacle_phase(&w, 8));
        assert!((0..50).all(|s| (0.0..4.0).contains(&obstacle_phase(&w, s))));
        // A static world has no phase.
        assert_eq!(obstacle_phase(&corridor(false), 7), 0.0);
    }

    #[test]
    fn a_forecast_bends_the_global_path_from_the_next_replan_on() {
        use crate::predictive_cost::PredictiveCostConfig;
        // Open space, the goal 8 m ahead along +x; an obstacle (as a tracker would report it)
        // 1.6 m right of the route at x = 4, moving left at 1 m/s.
        let w = World::new(0, vec![], Pose::default(), Vec2::new(8.0, 0.0), 8.0, vec![]);
        let mut ep = Episode::new(&w, ideal(), 1);
        let crossing = |ep: &Episode<'_>| {
            ep.global_path()
                .iter()
                .min_by(|a, b| (a.x - 4.0).abs().total_cmp(&(b.x - 4.0).abs()))
                .unwrap()
                .y
        };
        assert!(crossing(&ep).abs() < 0.1, "straight at first");
        assert_eq!(ep.replan_every(), 5);
        let risk = PathRisk {
            weight: 5.0,
            field: PredictiveCostConfig::default(),
        };
        let obstacle = MovingObstacle {
            position: Vec2::new(4.0, -1.6),
            velocity: Vec2::new(0.0, 1.0),
        };
        ep.forecast_moving(risk, ep.sim_time(), [obstacle]);
        for _ in 0..4 {
            ep.step(Twist::default());
            assert!(crossing(&ep).abs() < 0.1, "not before the replan");
        }
        // The replan at period 5 moves the obstacle on by 0.25 s: at y = -1.35 it sweeps
        // the route; the path passes behind it.
        ep.step(Twist::default());
        assert!(crossing(&ep) < -1.35, "{}", crossing(&ep));
        // A shorter interval replans sooner; an empty forecast plans straight again.
        ep.set_replan_every(2);
        ep.forecast_moving(risk, ep.sim_time(), []);
        ep.step(Twist::default());
        assert!(crossing(&ep) < -1.35, "one period after the last replan");
        ep.step(Twist::default());
        assert!(crossing(&ep).abs() < 0.1, "{}", crossing(&ep));
    }

    #[test]
    fn the_costmap_forgets_an_obstacle_that_moved_on_only_where_the_world_moves() {
        use crate::costmap::{Clearing, OBSTACLE};
        use crate::motion::{MovingCylinder, Trajectory};
        // A cylinder of radius 0.5 m shuttling along x = 2 between y = -4 and y = 4 (16 s
        // loop), across the view of a robot standing at the origin facing +x: each pass
        // shows the robot its near side around (1.5, 0).
        let keys: Vec<[f64; 3]> = (0..=16)
            .map(|k| {
                [
                    k as f64,
                    2.0,
                    if k <= 8 { k as f64 - 4.0 } else { 12.0 - k as f64 },
                ]
            })
            .collect();
        let w = World::new(0, vec![], Pose::default(), Vec2::new(-9.0, 5.0), 9.0, vec![]).with_moving(vec![
            MovingCylinder {
                radius: 0.5,
                trajectory: Trajectory::new(&keys, 16.0).unwrap(),
            },
        ]);
        // The largest cost in the 0.2 m square around (1.5, 0) once the cylinder has passed
        // y = 0 (it does every 8 s) and is 3 m or more away from it.
        let trace = |clearing: Clearing| {
            let mut cfg = ideal();
            cfg.costmap.clearing = clearing;
            let mut ep = Episode::new(&w, cfg, 3);
            assert_eq!(ep.costmap().clears(), clearing != Clearing::Off);
            while ep.sim_time() < 20.0 || ep.scene().moving()[0].c.y.abs() < 3.0 {
                assert_eq!(ep.step(Twist::new(0.0, 0.0)), Status::Running);
            }
            let m = ep.costmap();
            let (x0, y0) = m.cell_of(Vec2::new(1.4, -0.1)).unwrap();
            let (x1, y1) = m.cell_of(Vec2::new(1.6, 0.1)).unwrap();
            (y0..=y1)
                .flat_map(|y| (x0..=x1).map(move |x| (x, y)))
                .map(|(x, y)| m.cost(x, y))
                .max()
                .unwrap()
        };
        assert_eq!(
            trace(Clearing::Off),
            OBSTACLE,
            "never cleared: the pass left its trace"
        );
        assert_eq!(
            trace(Clearing::Auto),
            0,
            "cleared by the beams that see past it now"
        );
        // A static world keeps a costmap that never clears under `auto`.
        assert!(!Episode::new(&corridor(false), ideal(), 3).costmap().clears());
    }
}
