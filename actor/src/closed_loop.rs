//! One run of a planner on a world, whatever chooses its schedule: the single definition of
//! the closed-loop episode that evaluation, the greedy evaluation during training, the
//! experiment's stages and figures, and the training actor all call.
//!
//! A run is a [`Run`] (world, episode protocol, planner, speed cap, seed) and a [`Chooser`]:
//! either one fixed schedule for the whole run (the planner's cycle driver alone, no agent
//! steps), or the ADP environment ([`AdpEnv`]) with an [`Act`] choosing each agent step's
//! action from the step's observation (a constant, a network run greedily, a network fed
//! other observations, a network plus exploration noise). An observer sees every agent step
//! ([`Step`]: the observation, the action, the schedule parameters the environment ran, the
//! clutter and position it was chosen at, the reward and the next observation) and may stop
//! the run with an error.

use planner::run::{drive_episode, CycleDriver};
use planner::{ActionSpace, ComputeTally, Planner, Schedule};
use sim::geometry::Vec2;
use sim::{EpisodeConfig, EpisodeResult, World};

use crate::env::{AdpEnv, End, EnvConfig, EnvError, StepOutcome};
use crate::exploration::Exploration;
use crate::observation::clutter;
use crate::policy::{MlpPolicy, Scratch};

/// The planner seed of the run whose seed is `run_seed`: every evaluation path (eval, greedy
/// evaluation, experiment stages, figures) builds its planner with it, so a (world, run)
/// pair samples the same way wherever it runs. (The training actor seeds its planner with
/// the episode seed itself.)
pub fn planner_seed(run_seed: u64) -> u64 {
    run_seed ^ 0x5eed_91a2
}

/// Where one run happens.
pub struct Run<'w> {
    /// The world.
    pub world: &'w World,
    /// The simulator and the episode protocol (an environment run replaces its profile and
    /// lidar with the environment's, see [`AdpEnv::new`]).
    pub episode: EpisodeConfig,
    /// The planner, fresh for this run.
    pub planner: Box<dyn Planner>,
    /// Speed cap (m/s).
    pub max_speed: f64,
    /// The run seed (sensor noise, start jitter, the environment's draws).
    pub seed: u64,
}

/// What chooses a run's schedule.
pub enum Chooser<'a> {
    /// One schedule for the whole run, through the planner's cycle driver (its compute model,
    /// tracking and PADP settings are the caller's, and so are its tally and forecast errors
    /// after the run). No agent steps: the observer is never called.
    Fixed {
        /// The schedule.
        schedule: &'a Schedule,
        /// The cycle driver.
        driver: &'a mut CycleDriver,
    },
    /// The ADP environment: every agent step, `act` chooses an action of `space` from the
    /// step's observation, and the environment of `env` turns it into the planner's schedule
    /// (and gains, or the velocity command) for the step's planner cycles.
    Env {
        /// The action space.
        space: ActionSpace,
        /// The environment settings.
        env: &'a EnvConfig,
        /// What chooses the actions.
        act: &'a mut dyn Act,
    },
}

/// Chooses an agent step's action from its observation (a pluggable part of [`Chooser::Env`]).
/// Implementations may keep state between steps (a random stream, scratch buffers); one
/// value serves one run at a time.
pub trait Act {
    /// Writes the action for observation `obs` into `action` (its length is the space's).
    fn act(&mut self, obs: &[f32], action: &mut [f32]);
}

/// The same action at every step.
pub struct Constant<'a>(pub &'a [f32]);

impl Act for Constant<'_> {
    fn act(&mut self, _obs: &[f32], action: &mut [f32]) {
        action.copy_from_slice(self.0);
    }
}

/// A network run greedily (no noise) on each step's own observation.
pub struct Greedy<'a> {
    net: &'a MlpPolicy,
    scratch: Scratch,
}

impl<'a> Greedy<'a> {
    /// `net`, greedy.
    pub fn new(net: &'a MlpPolicy) -> Self {
        Self {
            net,
            scratch: Scratch::default(),
        }
    }
}

impl Act for Greedy<'_> {
    fn act(&mut self, obs: &[f32], action: &mut [f32]) {
        self.net.act(obs, action, &mut self.scratch);
    }
}

/// A network plus seeded Gaussian exploration noise (data collection).
pub struct Explore<'a> {
    greedy: Greedy<'a>,
    noise: Exploration,
}

impl<'a> Explore<'a> {
    /// `net` perturbed by `noise`.
    pub fn new(net: &'a MlpPolicy, noise: Exploration) -> Self {
        Self {
            greedy: Greedy::new(net),
            noise,
        }
    }
}

impl Act for Explore<'_> {
    fn act(&mut self, obs: &[f32], action: &mut [f32]) {
        self.greedy.act(obs, action);
        self.noise.perturb(action);
    }
}

/// One agent step, as the observer sees it.
pub struct Step<'s> {
    /// The step's index in the run (0 first).
    pub index: u32,
    /// The observation the action was chosen on.
    pub obs: &'s [f32],
    /// The action as [`Act`] gave it (network output, [-1, 1]).
    pub action: &'s [f32],
    /// Local clutter of the scan the action was chosen on ([`clutter`]).
    pub clutter: f64,
    /// Where the robot was when the action was chosen.
    pub position: Vec2,
    /// The reward and whether the run ended.
    pub outcome: StepOutcome,
    /// The observation after the step (the final one when the step ended the run).
    pub next_obs: &'s [f32],
    /// The environment after the step ([`AdpEnv::chosen_params`]: the schedule it ran).
    pub env: &'s AdpEnv<'s>,
}

/// What a run returns.
#[derive(Clone, Copy, Debug)]
pub struct RunResult {
    /// The episode's result.
    pub episode: EpisodeResult,
    /// What its planning cycles did and cost.
    pub compute: ComputeTally,
    /// Sum of the rewards (0 for a fixed schedule).
    pub episode_return: f64,
    /// Agent steps taken (0 for a fixed schedule).
    pub agent_steps: u32,
}

/// Runs `run` to its end with `chooser` choosing the schedule; `on_step` sees every agent
/// step after it is taken and stops the run by returning an error. Refuses an environment
/// that [`AdpEnv::new`] refuses. Allocates its observation and action buffers once per run.
pub fn run<E: From<EnvError>>(
    run: Run<'_>,
    chooser: Chooser<'_>,
    mut on_step: impl FnMut(&Step<'_>) -> Result<(), E>,
) -> Result<RunResult, E> {
    let Run {
        world,
        episode,
        mut planner,
        max_speed,
        seed,
    } = run;
    let (space, env, act) = match chooser {
        Chooser::Fixed { schedule, driver } => {
            let result = drive_episode(
                world,
                episode,
                planner.as_mut(),
                schedule,
                max_speed,
                seed,
                driver,
                |_, _, _| {},
            );
            return Ok(RunResult {
                episode: result,
                compute: *driver.tally(),
                episode_return: 0.0,
                agent_steps: 0,
            });
        }
        Chooser::Env { space, env, act } => (space, env, act),
    };
    let mut env = AdpEnv::new(world, episode, planner, space, max_speed, *env, seed)?;
    let n = env.obs_dim();
    let (mut obs, mut next) = (vec![0.0f32; n], vec![0.0f32; n]);
    let mut action = vec![0.0f32; space.dim()];
    env.observation(&mut obs);
    let mut index = 0u32;
    while env.end() == End::Continue {
        act.act(&obs, &mut action);
        let before = env.episode();
        let (position, clutter) = (
            before.state().pose.position(),
            clutter(before.perception().ranges),
        );
        let outcome = env.step(&action)?;
        env.observation(&mut next);
        on_step(&Step {
            index,
            obs: &obs,
            action: &action,
            clutter,
            position,
            outcome,
            next_obs: &next,
            env: &env,
        })?;
        index += 1;
        std::mem::swap(&mut obs, &mut next);
    }
    let r = env.result();
    Ok(RunResult {
        episode: r.episode,
        compute: *env.compute(),
        episode_return: r.episode_return,
        agent_steps: r.agent_steps,
    })
}
