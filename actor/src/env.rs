//! The RL environment: a BARN episode driven by a planner whose time-grid schedule is the
//! agent's action. Pure (no I/O) and deterministic given the seed and the actions.
//!
//! One agent step maps the policy's output through the [`planner::ActionMap`] to a schedule
//! (and, in the objective-weight spaces, the planner's gain factors, set before the step's
//! first cycle), applies it for `agent_period_cycles` planner cycles (0.25 s at the 0.05 s
//! control period), stopping early if the episode ends, then scores the step. In the velocity
//! space (pure RL) no planner runs: the step's command is issued every control period of the
//! step, as a planner's would be, with no modelled compute. Every reward below is multiplied by
//! `reward_scale`:
//!
//! * collision: `collision_reward` (replaces the shaping terms), [`End::Terminal`];
//! * success: shaping + `success_reward`, [`End::Terminal`];
//! * the simulator's own timeout or the agent step cap: shaping + `timeout_reward` (default
//!   0), [`End::Truncated`]. A time limit is not part of the task's state (the observation
//!   has no clock), so the learner bootstraps through it and it carries no penalty of its
//!   own: a stuck robot is already paying `step_penalty` and earning no progress;
//! * otherwise the shaping terms, [`End::Continue`]: `progress_scale * (d_prev - d)` with `d`
//!   the Euclidean distance of the robot to the global goal, plus `step_penalty`, plus the
//!   obstacle penalty of [`crate::reward::obstacle_penalty`] on the clearance between the
//!   robot's footprint and its lidar returns; plus, when `stuck_window` > 0, `stuck_reward`
//!   at every step after which the robot got less than `stuck_progress_m` closer to the goal
//!   over the last `stuck_window` agent steps ([`crate::stuck`]; off by default).
//!
//! The settings ([`EnvConfig`], with its [`Randomize`] and their errors) are plain data of
//! `settings::env`, re-exported here, so that the learner can hold them without the
//! simulator; drawing an episode's randomized lidar ([`RandomizeLidar`]) and the episode
//! itself are here.

use planner::action::ActionError;
use planner::run::CycleDriver;
use planner::{ActionSpace, ComputeTally, GainsError, Planner, Prediction, TrackingConfig};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use sim::episode::{Episode, EpisodeConfig, EpisodeResult, Status};
use sim::lidar::LidarConfig;
use sim::World;

pub use settings::env::{
    BeamChoices, EnvConfig, EnvConfigError, Randomize, RandomizeError, MAX_BEAM_CHOICES,
};

use crate::agent_action::{AgentAction, Applied, ApplyError};
use crate::observation::{self, LaserResampler};
use crate::reward::{footprint_clearance, obstacle_penalty};
use crate::stuck::{stuck_term, StuckWindow};

/// Seed offset of the domain-randomization stream (apart from the simulator's streams, so a
/// run without randomization draws nothing from it and changes nothing).
const RANDOMIZE_STREAM: u64 = 0x5eed_7a4d_7000_0005;

/// Draws an episode's lidar from the [`Randomize`] settings (which are plain data of
/// `settings::env`; drawing needs the simulator's [`LidarConfig`]).
pub trait RandomizeLidar {
    /// `lidar` with this episode's draws from the stream of `seed` (unchanged, and nothing
    /// drawn, when off): the beam count, then the noise fraction, then the dropout, each only
    /// when given.
    fn draw(&self, lidar: LidarConfig, seed: u64) -> LidarConfig;
}

impl RandomizeLidar for Randomize {
    fn draw(&self, lidar: LidarConfig, seed: u64) -> LidarConfig {
        if !self.is_on() {
            return lidar;
        }
        let mut rng = Pcg64Mcg::seed_from_u64(seed ^ RANDOMIZE_STREAM);
        let mut out = lidar;
        let choices = self.beams.as_slice();
        if !choices.is_empty() {
            out.beams = choices[rng.random_range(0..choices.len())];
        }
        let mut uniform = |[lo, hi]: [f64; 2]| lo + (hi - lo) * rng.random::<f64>();
        if let Some(range) = self.noise_fraction {
            out.noise_fraction = uniform(range);
            out.noise_sigma = 0.0;
        }
        if let Some(range) = self.dropout {
            out.dropout = uniform(range);
        }
        out
    }
}

/// What went wrong building or stepping an environment.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvError {
    /// A configuration value is out of range (the message names it; the settings' own
    /// [`EnvConfigError::Config`] becomes this).
    #[error("invalid environment configuration: {0}")]
    Config(String),
    /// A `[env.randomize]` value is out of range (the error names the field).
    #[error("invalid environment configuration: {0}")]
    Randomize(#[from] RandomizeError),
    /// The action was refused (wrong length or a non-finite value); nothing was simulated.
    #[error("action refused: {0}")]
    Action(#[from] ActionError),
    /// The planner refused the action's gain factors; nothing was simulated.
    #[error("action refused: {0}")]
    Gains(#[from] GainsError),
    /// The episode has already ended; build a new environment for the next one.
    #[error("the episode has ended ({status:?} after {agent_steps} agent steps); build a new environment to continue")]
    Finished {
        /// How it ended.
        status: Status,
        /// Agent steps taken.
        agent_steps: u32,
    },
}

impl From<ApplyError> for EnvError {
    /// The same message: a refused action or gain factors.
    fn from(e: ApplyError) -> Self {
        match e {
            ApplyError::Action(a) => EnvError::Action(a),
            ApplyError::Gains(g) => EnvError::Gains(g),
        }
    }
}

impl From<EnvConfigError> for EnvError {
    /// The same message: [`EnvConfigError::Config`] is [`EnvError::Config`],
    /// [`EnvConfigError::Randomize`] is [`EnvError::Randomize`].
    fn from(e: EnvConfigError) -> Self {
        match e {
            EnvConfigError::Config(msg) => EnvError::Config(msg),
            EnvConfigError::Randomize(r) => EnvError::Randomize(r),
        }
    }
}

/// How the episode stands after a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum End {
    /// The episode goes on.
    Continue,
    /// A true terminal (collision or success): no bootstrapping past it.
    Terminal,
    /// Cut by a time limit (step cap or the simulator's timeout): the learner bootstraps from
    /// the final observation.
    Truncated,
}

/// The result of one agent step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutcome {
    /// The step's reward.
    pub reward: f32,
    /// Whether and how the episode ended.
    pub end: End,
}

/// An episode's outcome from the agent's point of view.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvResult {
    /// The simulator's result: world, status, time, BARN score. A run cut by the step cap
    /// reports `TimedOut`.
    pub episode: EpisodeResult,
    /// Sum of the rewards so far (undiscounted).
    pub episode_return: f64,
    /// Agent steps taken.
    pub agent_steps: u32,
}

/// One ADP training or evaluation episode as an RL environment.
///
/// Owns the episode, the planner and all buffers; after the first step, stepping allocates
/// only what building the action's schedule allocates in the planner crate. `Send` (the
/// world is shared read-only, the planner is `Send`), not meant to be shared between threads.
pub struct AdpEnv<'w> {
    episode: Episode<'w>,
    planner: Box<dyn Planner>,
    space: ActionSpace,
    max_speed: f64,
    prediction: Prediction,
    /// Plans each control period under the compute model.
    driver: CycleDriver,
    cfg: EnvConfig,
    /// Builds the laser segment in `cfg.observation`'s layout from the lidar's scans.
    laser: LaserResampler,
    /// The action map and the previous action.
    action: AgentAction,
    goal_distance: f64,
    /// The goal distances of the stuck term's window (`None` when `stuck_window` is 0).
    stuck: Option<StuckWindow>,
    agent_steps: u32,
    episode_return: f64,
    end: End,
}

impl<'w> AdpEnv<'w> {
    /// Starts an episode on `world` with `episode_cfg` under the profile of `cfg` (which
    /// replaces the episode settings' own); `seed` drives the sensor noise and drift. The
    /// previous action starts as the policy output that selects DDP under the action map. The
    /// lidar may have any beam count: the observation resamples its scans into the layout of
    /// `cfg.observation`. Refuses invalid configurations, a non-positive speed cap, and an
    /// objective-weight space whose gains are not the planner's. In the velocity space
    /// `planner` never plans (it only names the compute model's planner).
    pub fn new(
        world: &'w World,
        episode_cfg: EpisodeConfig,
        planner: Box<dyn Planner>,
        space: ActionSpace,
        max_speed: f64,
        cfg: EnvConfig,
        seed: u64,
    ) -> Result<Self, EnvError> {
        cfg.validate()?;
        let mut episode_cfg = episode_cfg.with_profile(cfg.profile, cfg.dynamics);
        episode_cfg.lidar = cfg.randomize.draw(episode_cfg.lidar, seed);
        episode_cfg
            .validate()
            .map_err(|e| EnvError::Config(format!("episode: {e}")))?;
        if !(max_speed.is_finite() && max_speed > 0.0) {
            return Err(EnvError::Config(format!(
                "max_speed = {max_speed} must be finite and > 0"
            )));
        }
        if let Some(g) = space.gains() {
            if planner.gains() != Some(g) {
                return Err(EnvError::Config(format!(
                    "the {space} action space sets the gains of {}; the planner is {} ({})",
                    g.planner(),
                    planner.name(),
                    planner.gains().map_or("no gains".to_string(), |h| format!(
                        "the gains of {}",
                        h.planner()
                    ))
                )));
            }
        }
        let compute = cfg
            .compute
            .resolve(planner.name())
            .map_err(|e| EnvError::Config(format!("env.{e}")))?;
        let mut driver = CycleDriver::new(compute, episode_cfg.control_dt);
        if cfg.observe_tracks > 0 {
            driver = driver.with_tracking(TrackingConfig::default());
        }
        let episode = Episode::new(world, episode_cfg, seed);
        let laser = LaserResampler::new(cfg.observation, episode.lidar().angles());
        let goal_distance = episode.state().pose.position().dist(world.goal);
        Ok(Self {
            episode,
            planner,
            space,
            max_speed,
            prediction: Prediction::for_profile(cfg.profile),
            driver,
            cfg,
            laser,
            action: AgentAction::new(space, cfg.action_map),
            goal_distance,
            stuck: (cfg.stuck_window > 0).then(|| StuckWindow::new(cfg.stuck_window as usize, goal_distance)),
            agent_steps: 0,
            episode_return: 0.0,
            end: End::Continue,
        })
    }

    /// The action space.
    pub fn space(&self) -> ActionSpace {
        self.space
    }

    /// Length of this environment's observations ([`observation::obs_dim`] of the laser
    /// layout, the space and the observed tracks).
    pub fn obs_dim(&self) -> usize {
        observation::obs_dim(self.cfg.observation, self.space, self.cfg.observe_tracks)
    }

    /// The configuration.
    pub fn config(&self) -> &EnvConfig {
        &self.cfg
    }

    /// The underlying episode (for drawing and diagnostics).
    pub fn episode(&self) -> &Episode<'w> {
        &self.episode
    }

    /// What the planning cycles so far did and cost under the compute model.
    pub fn compute(&self) -> &ComputeTally {
        self.driver.tally()
    }

    /// Agent steps taken.
    pub fn agent_steps(&self) -> u32 {
        self.agent_steps
    }

    /// How the last step left the episode ([`End::Continue`] before the first step).
    pub fn end(&self) -> End {
        self.end
    }

    /// Writes the current observation into `out` (layout in [`crate::observation`]). After a
    /// terminal or truncating step it is the final observation. Allocation-free.
    ///
    /// # Panics
    /// If `out.len() != self.obs_dim()`.
    pub fn observation(&self, out: &mut [f32]) {
        let tracks = self.driver.tracking().map_or(&[][..], |t| t.moving());
        observation::write(
            &self.episode.perception(),
            &self.laser,
            self.action.previous(),
            self.cfg.laser_clip_m,
            tracks,
            out,
        );
    }

    /// Applies `action` (normalized; values are clamped to [-1, 1]) for one agent period and
    /// returns the reward and whether the episode ended. Refuses an action of the wrong
    /// length or with a non-finite value (nothing is simulated then), and any step after the
    /// episode has ended.
    pub fn step(&mut self, action: &[f32]) -> Result<StepOutcome, EnvError> {
        if self.end != End::Continue {
            return Err(EnvError::Finished {
                status: self.episode.status(),
                agent_steps: self.agent_steps,
            });
        }
        match self.action.apply(action, self.planner.as_mut(), self.max_speed)? {
            Applied::Velocity(cmd) => {
                for _ in 0..self.cfg.agent_period_cycles {
                    if self.driver.command(&mut self.episode, cmd) != Status::Running {
                        break;
                    }
                }
            }
            Applied::Schedule(schedule) => {
                for _ in 0..self.cfg.agent_period_cycles {
                    let status = self.driver.period(
                        &mut self.episode,
                        self.planner.as_mut(),
                        &schedule,
                        self.max_speed,
                        self.prediction,
                        &mut |_, _, _| {},
                    );
                    if status != Status::Running {
                        break;
                    }
                }
            }
        }
        self.agent_steps += 1;
        let distance = self
            .episode
            .state()
            .pose
            .position()
            .dist(self.episode.world().goal);
        let progress = self.goal_distance - distance;
        self.goal_distance = distance;
        let cfg = &self.cfg;
        let stuck = match self.stuck.as_mut() {
            Some(window) => stuck_term(window.push(distance), cfg.stuck_progress_m, cfg.stuck_reward),
            None => 0.0,
        };
        let shaping = || {
            let clearance = footprint_clearance(
                self.episode.perception().points,
                &self.episode.config().robot.footprint,
            );
            cfg.progress_scale * progress
                + cfg.step_penalty
                + obstacle_penalty(clearance, cfg.obstacle_threshold_m, cfg.obstacle_scale)
                + stuck
        };
        let (reward, end) = match self.episode.status() {
            Status::Collided => (cfg.collision_reward, End::Terminal),
            Status::Succeeded => (shaping() + cfg.success_reward, End::Terminal),
            Status::TimedOut => (shaping() + cfg.timeout_reward, End::Truncated),
            Status::Running if self.agent_steps >= cfg.max_agent_steps => {
                (shaping() + cfg.timeout_reward, End::Truncated)
            }
            Status::Running => (shaping(), End::Continue),
        };
        let reward = reward * cfg.reward_scale;
        if end == End::Truncated {
            // Marks a step-cap cut as a timeout in the result; no-op after the sim's own.
            self.episode.abandon();
        }
        self.end = end;
        self.episode_return += reward;
        Ok(StepOutcome {
            reward: reward as f32,
            end,
        })
    }

    /// The physical parameters of the last step's action ([`ActionSpace::to_params`] of the
    /// box action the action map made of it: the schedule's p, T, N, alpha, then gain factors
    /// or the velocity command, per the space), or `None` before the first step.
    pub fn chosen_params(&self) -> Option<Vec<f64>> {
        if self.agent_steps == 0 {
            return None;
        }
        // The step refused any action its space cannot map, so this cannot fail here.
        self.action.params()
    }

    /// The outcome so far (final once a step returned [`End::Terminal`] or [`End::Truncated`]).
    pub fn result(&self) -> EnvResult {
        EnvResult {
            episode: self.episode.result(),
            episode_return: self.episode_return,
            agent_steps: self.agent_steps,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observation::LaserLayout;
    use planner::{ActionMap, ComputeConfig, Dwa, DwaConfig, PlanInput, Trace};
    use sim::geometry::{Circle, Pose, Vec2};
    use sim::robot::Twist;

    /// A planner that always sends the same command.
    struct Constant {
        cmd: Twist,
        trace: Trace,
    }

    impl Planner for Constant {
        fn name(&self) -> &'static str {
            "constant"
        }
        fn plan(&mut self, _: &PlanInput<'_>) -> Twist {
            self.cmd
        }
        fn trace(&self) -> &Trace {
            &self.trace
        }
        fn trace_mut(&mut self) -> &mut Trace {
            &mut self.trace
        }
    }

    fn constant(v: f64) -> Box<dyn Planner> {
        Box::new(Constant {
            cmd: Twist::new(v, 0.0),
            trace: Trace::default(),
        })
    }

    fn dwa() -> Box<dyn Planner> {
        Box::new(Dwa::new(DwaConfig::default()))
    }

    /// Start at the origin facing +y, goal 10 m ahead; optionally a wall across at y = 1.5.
    fn open_field(wall: bool) -> World {
        let cylinders = if wall {
            (0..21)
                .map(|i| Circle {
                    c: Vec2::new(-1.5 + 0.15 * i as f64, 1.5),
                    r: 0.075,
                })
                .collect()
        } else {
            Vec::new()
        };
        World::new(
            0,
            cylinders,
            Pose::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            Vec2::new(0.0, 10.0),
            10.0,
            vec![],
        )
    }

    /// An environment on the free compute model: these tests pin the reward and episode
    /// logic, which the compute model does not touch (and `Constant` has no budget).
    fn env<'w>(world: &'w World, planner: Box<dyn Planner>, cfg: EnvConfig, seed: u64) -> AdpEnv<'w> {
        AdpEnv::new(
            world,
            EpisodeConfig::default(),
            planner,
            ActionSpace::Decremental,
            1.5,
            EnvConfig {
                compute: ComputeConfig::FREE,
                ..cfg
            },
            seed,
        )
        .unwrap()
    }

    /// The policy output that selects DDP under the default (DDP-centred) action map.
    fn ddp() -> Vec<f32> {
        vec![0.0; 4]
    }

    /// Default rewards in the configured units, before `reward_scale`.
    fn unscaled() -> EnvConfig {
        EnvConfig {
            reward_scale: 1.0,
            ..EnvConfig::default()
        }
    }

    #[test]
    fn observed_tracks_show_a_crossing_obstacle_in_the_robot_frame() {
        use sim::motion::{MovingCylinder, Trajectory};
        // A cylinder of radius 0.5 m moving along +x at 1 m/s, 3 m ahead of a robot that
        // stands at the origin facing +y: in the robot frame it is at x = 3 and moves along
        // -y at 1 m/s. A seed whose phase starts it between x = -3 and 0 keeps it on its
        // 12 s loop (x from -6 to 6) for the 3 s the test runs.
        let keys: Vec<[f64; 3]> = (0..=12).map(|k| [k as f64, k as f64 - 6.0, 3.0]).collect();
        let mut world = open_field(false);
        world = world.with_moving(vec![MovingCylinder {
            radius: 0.5,
            trajectory: Trajectory::new(&keys, 12.0).unwrap(),
        }]);
        let seed = (0..)
            .find(|&s| (3.0..6.0).contains(&sim::episode::obstacle_phase(&world, s)))
            .unwrap();
        let cfg = EnvConfig {
            observe_tracks: 2,
            ..EnvConfig::default()
        };
        let mut e = env(&world, constant(0.0), cfg, seed);
        assert_eq!(e.obs_dim(), 738);
        let mut obs = vec![f32::NAN; 738];
        e.observation(&mut obs);
        assert!(
            obs[730..].iter().all(|&x| x == 0.0),
            "no track before the first cycle"
        );
        for _ in 0..12 {
            e.step(&ddp()).unwrap();
        }
        e.observation(&mut obs);
        let (x, y, vx, vy) = (obs[730], obs[731], obs[732], obs[733]);
        assert!((x - 3.0).abs() < 0.2 && y.abs() < 3.5, "position {x}, {y}");
        assert!(vx.abs() < 0.2 && (vy + 1.0).abs() < 0.2, "velocity {vx}, {vy}");
        assert!(obs[734..].iter().all(|&x| x == 0.0), "one track, one empty slot");
        // Without the setting the layout is the old one, and too many slots are refused.
        assert_eq!(
            env(&world, constant(0.0), EnvConfig::default(), seed).obs_dim(),
            730
        );
        let too_many = EnvConfig {
            observe_tracks: 17,
            ..EnvConfig::default()
        };
        let err = too_many.validate().unwrap_err().to_string();
        assert!(err.contains("observe_tracks = 17"), "{err}");
    }

    #[test]
    fn is_send() {
        fn send<T: Send>() {}
        send::<AdpEnv<'static>>();
    }

    #[test]
    fn initial_observation_layout_and_ranges() {
        let world = sim::catalog::world(0).unwrap();
        let e = env(world, dwa(), EnvConfig::default(), 7);
        assert_eq!(e.obs_dim(), 730);
        let mut obs = vec![f32::NAN; 730];
        e.observation(&mut obs);
        assert!(obs[..720].iter().all(|x| (-1.0..=1.0).contains(x)));
        assert!(
            obs[..720].iter().any(|&x| x < 1.0),
            "obstacles within 3 m are seen"
        );
        assert_eq!(&obs[720..724], ddp().as_slice(), "previous action starts as DDP");
        assert_eq!(&obs[724..726], &[0.0, 0.0], "standing still");
        // The BARN goal is 10 m straight ahead of the start.
        assert!(
            obs[728].abs() < 1e-6 && (obs[729] - 10.0).abs() < 1e-5,
            "{:?}",
            &obs[728..]
        );
        assert!(obs[727] > 0.0 && obs[726].abs() <= std::f32::consts::PI);
    }

    #[test]
    fn progress_reward_in_the_open() {
        let world = open_field(false);
        let mut e = env(&world, dwa(), EnvConfig::default(), 1);
        let mut obs = vec![0.0; 730];
        for _ in 0..4 {
            let before = e.episode().state().pose.position().dist(world.goal);
            let out = e.step(&ddp()).unwrap();
            let after = e.episode().state().pose.position().dist(world.goal);
            assert_eq!(out.end, End::Continue);
            assert!(after < before, "DWA drives toward the goal");
            // Scaled by the default reward_scale 0.01.
            let want = 0.1 * (before - after) - 0.005;
            assert!(
                (f64::from(out.reward) - want).abs() < 1e-5,
                "{} vs {want}",
                out.reward
            );
        }
        e.observation(&mut obs);
        assert!(obs[724] > 0.0, "moving forward");
        assert!(obs[..720].iter().all(|&x| x == 1.0), "nothing within 3 m");
    }

    #[test]
    fn collision_is_terminal_and_final() {
        let world = open_field(true);
        // The ideal robot: from the first step on, driving at the goal gains more than the
        // step penalty (the Jackal profile's latency and acceleration make the first step
        // slower).
        let ideal = EnvConfig {
            profile: sim::Profile::Ideal,
            ..unscaled()
        };
        let mut e = env(&world, constant(1.0), ideal, 1);
        let action = [0.3, -0.2, 0.5, 0.9];
        let last = loop {
            let out = e.step(&action).unwrap();
            if out.end != End::Continue {
                break out;
            }
            assert!(out.reward > 0.0, "driving straight at the goal makes progress");
        };
        assert_eq!(
            last,
            StepOutcome {
                reward: -100.0,
                end: End::Terminal
            }
        );
        let r = e.result();
        assert_eq!(r.episode.status, Status::Collided);
        let mut obs = vec![0.0; 730];
        e.observation(&mut obs);
        assert_eq!(&obs[720..724], &action, "previous action recorded");
        assert!(matches!(
            e.step(&action),
            Err(EnvError::Finished {
                status: Status::Collided,
                ..
            })
        ));
        assert_eq!(e.result(), r, "a refused step changes nothing");
    }

    #[test]
    fn obstacle_penalty_fires_by_footprint_clearance() {
        // Creeping at the wall (its near surface at y = 1.425): once the front bumper is
        // within 0.2 m the step's reward drops below progress + step penalty, by the
        // quadratic penalty of the footprint's clearance.
        let world = open_field(true);
        let cfg = EnvConfig {
            profile: sim::Profile::Ideal,
            ..unscaled()
        };
        let mut e = env(&world, constant(0.3), cfg, 1);
        let mut penalized = Vec::new();
        while e.end() == End::Continue {
            let before = e.episode().state().pose.position().dist(world.goal);
            let out = e.step(&ddp()).unwrap();
            if out.end != End::Continue {
                break;
            }
            let after = e.episode().state().pose.position().dist(world.goal);
            let front = e.episode().state().pose.y + 0.254;
            let shortfall = 10.0 * (before - after) - 0.5 - f64::from(out.reward);
            let gap = 1.425 - front;
            if gap > 0.25 {
                assert!(shortfall.abs() < 1e-4, "gap {gap}: shortfall {shortfall}");
            } else if gap < 0.1 {
                assert!(shortfall > 0.1, "gap {gap}: shortfall {shortfall}");
            }
            if shortfall > 1e-4 {
                penalized.push(shortfall);
            }
        }
        assert!(penalized.len() >= 2, "{penalized:?}");
        assert!(
            penalized.windows(2).all(|w| w[1] > w[0]),
            "grows as the robot closes in: {penalized:?}"
        );
    }

    #[test]
    fn step_cap_truncates_with_the_shaping_and_timeout_reward() {
        let world = open_field(false);
        let cfg = EnvConfig {
            max_agent_steps: 3,
            timeout_reward: -100.0,
            ..unscaled()
        };
        let mut e = env(&world, constant(0.0), cfg, 1);
        let rewards: Vec<_> = (0..3).map(|_| e.step(&ddp()).unwrap()).collect();
        let cont = StepOutcome {
            reward: -0.5,
            end: End::Continue,
        };
        assert_eq!(
            rewards[..2],
            [cont, cont],
            "standing still: only the step penalty"
        );
        assert_eq!(
            rewards[2],
            StepOutcome {
                reward: -100.5,
                end: End::Truncated
            },
            "the cut step keeps its shaping and adds timeout_reward"
        );
        let r = e.result();
        assert_eq!(
            (r.episode.status, r.agent_steps, r.episode_return),
            (Status::TimedOut, 3, -101.5)
        );
        assert!(e.step(&ddp()).is_err());
    }

    #[test]
    fn a_robot_that_stands_still_pays_the_stuck_term_once_its_window_is_full() {
        let world = open_field(false);
        let cfg = EnvConfig {
            stuck_window: 3,
            stuck_progress_m: 0.5,
            stuck_reward: -5.0,
            ..unscaled()
        };
        let mut still = env(&world, constant(0.0), cfg, 1);
        let rewards: Vec<f32> = (0..5).map(|_| still.step(&ddp()).unwrap().reward).collect();
        assert_eq!(
            rewards,
            [-0.5, -0.5, -5.5, -5.5, -5.5],
            "the step penalty, then the stuck term from the window's third step on"
        );
        // Driving at 1 m/s toward the goal (0.25 m a step at speed; more than 0.2 m over every
        // window of 3 steps, the first one included): no stuck term, the rewards without it.
        let moving_cfg = EnvConfig {
            stuck_progress_m: 0.2,
            ..cfg
        };
        let mut moving = env(&world, constant(1.0), moving_cfg, 1);
        let mut plain = env(&world, constant(1.0), unscaled(), 1);
        for k in 0..8 {
            let (a, b) = (moving.step(&ddp()).unwrap(), plain.step(&ddp()).unwrap());
            assert_eq!(a, b, "step {k}");
        }
        // A stuck robot that collides gets the collision reward alone.
        let walled = open_field(true);
        let mut crash = env(
            &walled,
            constant(1.0),
            EnvConfig {
                stuck_window: 1,
                stuck_progress_m: 10.0,
                ..cfg
            },
            1,
        );
        let last = loop {
            let out = crash.step(&ddp()).unwrap();
            if out.end != End::Continue {
                break out;
            }
        };
        assert_eq!(
            last,
            StepOutcome {
                reward: -100.0,
                end: End::Terminal
            }
        );
    }

    #[test]
    fn sim_timeout_truncates_without_a_penalty_by_default() {
        let world = open_field(false);
        let ep = EpisodeConfig {
            timeout_s: 0.3,
            ..EpisodeConfig::default()
        };
        let mut e = AdpEnv::new(
            &world,
            ep,
            constant(0.0),
            ActionSpace::Decremental,
            1.5,
            EnvConfig {
                compute: ComputeConfig::FREE,
                ..EnvConfig::default()
            },
            1,
        )
        .unwrap();
        assert_eq!(e.step(&ddp()).unwrap().end, End::Continue);
        assert_eq!(
            e.step(&ddp()).unwrap(),
            StepOutcome {
                reward: (-0.5f64 * 0.01) as f32,
                end: End::Truncated
            },
            "standing still: the step penalty only, scaled"
        );
        let r = e.result().episode;
        assert_eq!(r.status, Status::TimedOut);
        assert!(
            (r.sim_time_s - 0.3).abs() < 1e-9,
            "stopped early at the timeout: {}",
            r.sim_time_s
        );
    }

    #[test]
    fn bad_actions_are_refused_without_simulating() {
        let world = open_field(false);
        let mut e = env(&world, dwa(), EnvConfig::default(), 1);
        let err = e.step(&[0.0, f32::NAN, 0.0, 0.0]).unwrap_err();
        assert!(err.to_string().contains("(T) is NaN"), "{err}");
        let err = e.step(&[0.0; 3]).unwrap_err();
        assert!(err.to_string().contains("needs 4 values, got 3"), "{err}");
        assert_eq!(e.agent_steps(), 0);
        assert_eq!(e.episode().sim_time(), 0.0);
        // Out-of-range values are clamped, also in the observation.
        e.step(&[5.0, -5.0, 0.0, 0.0]).unwrap();
        let mut obs = vec![0.0; 730];
        e.observation(&mut obs);
        assert_eq!(&obs[720..724], &[1.0, -1.0, 0.0, 0.0]);
    }

    /// The observation is built in the configured layout from any lidar: a 90-beam scan
    /// fills the 720 values of the `scan` layout, a `sectors:25` layout makes 25.
    #[test]
    fn any_lidar_makes_the_observation_of_the_layout() {
        let world = open_field(true);
        for (beams, layout, dim) in [
            (90, LaserLayout::Scan, 730),
            (720, LaserLayout::Sectors(25), 35),
            (90, LaserLayout::Sectors(50), 60),
        ] {
            let mut ep = EpisodeConfig::default();
            ep.lidar.beams = beams;
            let cfg = EnvConfig {
                observation: layout,
                ..EnvConfig::default()
            };
            let mut e = AdpEnv::new(&world, ep, dwa(), ActionSpace::Decremental, 1.5, cfg, 1).unwrap();
            assert_eq!(e.obs_dim(), dim, "{beams} beams, {layout}");
            e.step(&ddp()).unwrap();
            let mut obs = vec![f32::NAN; dim];
            e.observation(&mut obs);
            let laser = &obs[..layout.size()];
            assert!(laser.iter().all(|x| (-1.0..=1.0).contains(x)), "{laser:?}");
            // The wall 1.5 m ahead across the heading: the values ahead read it (below the 3 m
            // clip), the ones behind the robot's shoulders do not.
            let ahead = laser[laser.len() / 2];
            assert!(
                ahead < 0.0 && laser[0] == 1.0,
                "{beams} beams, {layout}: {laser:?}"
            );
        }
    }

    /// `[env.randomize]` draws every episode's lidar from its seed, within the given choices
    /// and ranges, repeatably; off (the default) it draws nothing; evaluation turns it off.
    #[test]
    fn randomized_sensing_is_drawn_per_episode_from_the_seed() {
        let lidar = EpisodeConfig::default().lidar;
        let off = Randomize::default();
        assert!(!off.is_on());
        assert_eq!(off.draw(lidar, 3), lidar);
        let on = Randomize {
            beams: vec![90, 360, 720].try_into().unwrap(),
            noise_fraction: Some([0.05, 0.2]),
            dropout: Some([0.0, 0.1]),
        };
        let mut seen = std::collections::BTreeSet::new();
        for seed in 0..200 {
            let l = on.draw(lidar, seed);
            assert_eq!(l, on.draw(lidar, seed), "seed {seed} repeats");
            seen.insert(l.beams);
            assert!(
                (0.05..=0.2).contains(&l.noise_fraction) && l.noise_sigma == 0.0,
                "{l:?}"
            );
            assert!((0.0..=0.1).contains(&l.dropout), "{l:?}");
            l.validate().unwrap();
        }
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), [90, 360, 720]);
        assert_ne!(on.draw(lidar, 1), on.draw(lidar, 2));
        // Only what is given is drawn: a beams-only randomization keeps the episode's noise.
        let beams_only = Randomize {
            beams: vec![360].try_into().unwrap(),
            ..Randomize::default()
        };
        assert_eq!(beams_only.draw(lidar, 9), LidarConfig { beams: 360, ..lidar });
        // The environment runs the drawn lidar, in the layout of its observation.
        let world = open_field(true);
        let cfg = EnvConfig {
            randomize: on,
            ..EnvConfig::default()
        };
        for seed in [4, 5] {
            let e = AdpEnv::new(
                &world,
                EpisodeConfig::default(),
                dwa(),
                ActionSpace::Decremental,
                1.5,
                cfg,
                seed,
            )
            .unwrap();
            assert_eq!(e.episode().config().lidar, on.draw(lidar, seed));
            assert_eq!(e.obs_dim(), 730);
            let mut obs = vec![f32::NAN; 730];
            e.observation(&mut obs);
            assert!(obs[..720].iter().all(|x| (-1.0..=1.0).contains(x)));
        }
        let eval = cfg.for_evaluation();
        assert_eq!(
            (eval.randomize, eval.max_agent_steps),
            (Randomize::default(), u32::MAX)
        );
        // The settings travel to the actors as TOML.
        let text = toml::to_string(&cfg).unwrap();
        assert!(
            text.contains("[randomize]") && text.contains("beams = [90, 360, 720]"),
            "{text}"
        );
        assert_eq!(toml::from_str::<EnvConfig>(&text).unwrap(), cfg);
        let default = EnvConfig::default();
        assert_eq!(
            toml::from_str::<EnvConfig>(&toml::to_string(&default).unwrap()).unwrap(),
            default
        );
    }

    #[test]
    fn invalid_configurations_are_refused() {
        let world = open_field(false);
        let cfg = EnvConfig {
            agent_period_cycles: 0,
            ..EnvConfig::default()
        };
        let err = AdpEnv::new(
            &world,
            EpisodeConfig::default(),
            dwa(),
            ActionSpace::Decremental,
            1.5,
            cfg,
            1,
        )
        .err()
        .unwrap();
        assert!(err.to_string().contains("agent_period_cycles"), "{err}");
        let err = AdpEnv::new(
            &world,
            EpisodeConfig::default(),
            dwa(),
            ActionSpace::Decremental,
            f64::NAN,
            EnvConfig::default(),
            1,
        )
        .err()
        .unwrap();
        assert!(err.to_string().contains("max_speed"), "{err}");
    }

    #[test]
    fn same_seed_same_rewards() {
        let world = sim::catalog::world(20).unwrap();
        let run = |seed: u64| {
            let mut e = env(world, dwa(), EnvConfig::default(), seed);
            let mut rewards = Vec::new();
            let mut obs = vec![0.0; 730];
            for k in 0..30 {
                let x = k as f32 * 0.37;
                let out = e.step(&[x.sin(), x.cos(), (2.0 * x).sin(), -x.cos()]).unwrap();
                e.observation(&mut obs);
                rewards.push((out, obs.clone()));
                if out.end != End::Continue {
                    break;
                }
            }
            rewards
        };
        let a = run(3);
        assert_eq!(a, run(3));
        assert_ne!(a[0].1, run(4)[0].1, "another seed draws other sensor noise");
    }

    #[test]
    fn ddp_with_dwa_reaches_the_goal_on_an_easy_world() {
        // World 1: DWA with the DDP grid at 1.5 m/s succeeds in about 7.5 s. (World 0 is not
        // usable here: DWA gets stuck in it and times out with any schedule driver.)
        let world = sim::catalog::world(1).unwrap();
        let cfg = EnvConfig {
            obstacle_scale: 0.0,
            ..unscaled()
        };
        let mut e = env(world, dwa(), cfg, 11);
        let action = ddp();
        let mut last = None;
        while e.end() == End::Continue {
            last = Some(e.step(&action).unwrap());
        }
        let last = last.unwrap();
        let r = e.result();
        assert_eq!(last.end, End::Terminal);
        assert_eq!(r.episode.status, Status::Succeeded);
        assert!(
            last.reward > 45.0,
            "success reward added to the shaping: {}",
            last.reward
        );
        assert!(r.episode.score > 0.0 && r.agent_steps < 200);
        // Shaping telescopes: the return is 10 x the distance covered toward the goal, minus
        // 0.5 per step, plus 50 (the obstacle term is off here).
        let start = world.start.position().dist(world.goal);
        let end = e.episode().state().pose.position().dist(world.goal);
        let want = 10.0 * (start - end) - 0.5 * f64::from(r.agent_steps) + 50.0;
        assert!(
            (r.episode_return - want).abs() < 1e-9,
            "{} vs {want}",
            r.episode_return
        );
        // The same run as the plain episode driver with the fixed DDP schedule.
        let (plain, cycles) = planner::run::run_episode(
            world,
            EpisodeConfig::default(),
            &mut Dwa::new(DwaConfig::default()),
            &planner::Schedule::ddp_default(),
            1.5,
            11,
            e.config().compute.resolve("dwa").unwrap(),
            |_, _, _| {},
        );
        assert_eq!(r.episode, plain);
        assert_eq!(&cycles, e.compute());
        assert_eq!(u64::from(r.agent_steps), cycles.cycles.div_ceil(5));
    }

    /// Pose and velocity bits after each of `steps` agent steps of `output` (or until the
    /// episode ends) in `space` on BARN world 120 under the default settings (compute model on).
    fn run_space(
        space: ActionSpace,
        planner: Box<dyn Planner>,
        output: &[f32],
        steps: usize,
    ) -> Vec<[u64; 5]> {
        let world = sim::catalog::world(120).unwrap();
        let mut e = AdpEnv::new(
            world,
            EpisodeConfig::default(),
            planner,
            space,
            1.5,
            EnvConfig::default(),
            7,
        )
        .unwrap();
        let mut out = Vec::new();
        for _ in 0..steps {
            let end = e.step(output).unwrap().end;
            let s = e.episode().state();
            out.push([s.pose.x, s.pose.y, s.pose.yaw, s.vel.v, s.vel.w].map(f64::to_bits));
            if end != End::Continue {
                break;
            }
        }
        out
    }

    #[test]
    fn the_weight_spaces_start_at_todays_ddp_bit_for_bit() {
        use planner::{Gains, Mppi, MppiConfig, NavSystem, Schedule, SystemConfig};
        let build = |g: Gains| -> Box<dyn Planner> {
            match g {
                Gains::Dwa => dwa(),
                Gains::Mppi => Box::new(Mppi::new(MppiConfig::default(), 3)),
                Gains::System => Box::new(NavSystem::new(SystemConfig::default(), 3)),
            }
        };
        let world = sim::catalog::world(120).unwrap();
        for g in Gains::ALL {
            // Today's DDP row: the plain driver on the DDP schedule, 5 periods an agent step.
            let cfg = EnvConfig::default();
            let ep_cfg = EpisodeConfig::default().with_profile(cfg.profile, cfg.dynamics);
            let mut ep = Episode::new(world, ep_cfg, 7);
            let mut driver = CycleDriver::new(cfg.compute.resolve(g.planner()).unwrap(), ep_cfg.control_dt);
            let mut planner = build(g);
            let mut ddp_row = Vec::new();
            for _ in 0..40 {
                for _ in 0..5 {
                    driver.period(
                        &mut ep,
                        planner.as_mut(),
                        &Schedule::ddp_default(),
                        1.5,
                        Prediction::for_profile(cfg.profile),
                        &mut |_, _, _| {},
                    );
                }
                let s = ep.state();
                ddp_row.push([s.pose.x, s.pose.y, s.pose.yaw, s.vel.v, s.vel.w].map(f64::to_bits));
                if ep.status() != Status::Running {
                    break;
                }
            }
            for map in [ActionMap::DdpCentred, ActionMap::Affine] {
                let first = |space: ActionSpace| -> Vec<f32> {
                    map.ddp_policy_action(space).iter().map(|&a| a as f32).collect()
                };
                let weights = ActionSpace::Weights(g);
                let got = run_space(weights, build(g), &first(weights), 40);
                assert_eq!(got, ddp_row, "{weights} {map:?}");
                // With the schedule too: today's decremental space at its DDP start.
                let both = ActionSpace::DecrementalWeights(g);
                let dec = run_space(
                    ActionSpace::Decremental,
                    build(g),
                    &first(ActionSpace::Decremental),
                    40,
                );
                assert_eq!(run_space(both, build(g), &first(both), 40), dec, "{both} {map:?}");
            }
        }
    }

    #[test]
    fn the_weight_spaces_set_the_gains_and_refuse_another_planner() {
        use planner::{Gains, LogMppi, LogMppiConfig, Mppi, MppiConfig};
        let space = ActionSpace::Weights(Gains::Dwa);
        // Gains away from the hand-tuned ones change what DWA does.
        let tuned = run_space(space, dwa(), &[0.0; 4], 10);
        let changed = run_space(space, dwa(), &[0.0, 0.0, 1.0, -1.0], 10);
        assert_ne!(tuned, changed);
        let world = open_field(false);
        let make = |space, planner| {
            AdpEnv::new(
                &world,
                EpisodeConfig::default(),
                planner,
                space,
                1.5,
                EnvConfig::default(),
                1,
            )
        };
        let e = make(space, Box::new(Mppi::new(MppiConfig::default(), 1)))
            .err()
            .unwrap();
        assert_eq!(
            e.to_string(),
            "invalid environment configuration: the weights:dwa action space sets the gains of dwa; \
             the planner is mppi (the gains of mppi)"
        );
        let e = make(
            ActionSpace::DecrementalWeights(Gains::Mppi),
            Box::new(LogMppi::new(LogMppiConfig::default(), 1)),
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("the planner is log-mppi"), "{e}");
        let mut e = make(space, dwa()).unwrap();
        assert_eq!(e.obs_dim(), 730);
        let err = e.step(&[0.0, f32::INFINITY, 0.0, 0.0]).unwrap_err();
        assert_eq!(
            err.to_string(),
            "action refused: action value 1 (w_path) is inf: must be finite"
        );
        assert_eq!(e.agent_steps(), 0);
    }

    #[test]
    fn the_velocity_space_runs_exactly_the_clamped_command_without_a_planner() {
        // Output (0.5, 7): v = 0.75 of the 1 m/s cap, w clamped to 2 rad/s. The planner panics
        // if asked to plan.
        struct Never(Trace);
        impl Planner for Never {
            fn name(&self) -> &'static str {
                "dwa"
            }
            fn plan(&mut self, _: &PlanInput<'_>) -> Twist {
                panic!("the velocity space must not plan")
            }
            fn trace(&self) -> &Trace {
                &self.0
            }
            fn trace_mut(&mut self) -> &mut Trace {
                &mut self.0
            }
        }
        let world = open_field(false);
        let cfg = EnvConfig::default();
        let mut e = AdpEnv::new(
            &world,
            EpisodeConfig::default(),
            Box::new(Never(Trace::default())),
            ActionSpace::Velocity,
            1.0,
            cfg,
            3,
        )
        .unwrap();
        assert_eq!(e.obs_dim(), 728);
        // The reference: the command issued every control period, with no modelled compute.
        let ep_cfg = EpisodeConfig::default().with_profile(cfg.profile, cfg.dynamics);
        let mut reference = Episode::new(&world, ep_cfg, 3);
        for _ in 0..3 {
            e.step(&[0.5, 7.0]).unwrap();
            for _ in 0..5 {
                reference.step_after(Twist::new(0.75, 2.0), 0.0);
            }
            assert_eq!(e.episode().state(), reference.state());
        }
        let t = e.compute();
        assert_eq!((t.cycles, t.modelled_ms, t.samples), (15, 0.0, 0));
        assert_eq!(t.work, planner::Work::default());
        let mut obs = vec![0.0; 728];
        e.observation(&mut obs);
        assert_eq!(&obs[720..722], &[0.5, 1.0], "the previous action, clamped");
        let err = e.step(&[0.0, 0.0, 0.0, 0.0]).unwrap_err();
        assert_eq!(
            err.to_string(),
            "action refused: velocity action needs 2 values, got 4"
        );
    }
}
