//! [`Navigator`]: one robot's planner, navigation state and (optionally) trained policy,
//! stepped one control cycle per call.

use eval_config::EvalConfig;
use planner::run::CycleDriver;
use planner::{ActionSpace, CycleWork, Planner, PlannerKind, Prediction, Schedule};
use policy::agent_action::{AgentAction, Applied};
use policy::observation::{self, LaserResampler};
use policy::{LearnedPolicy, MlpPolicy, Scratch};
use sim::episode::EpisodeConfig;
use sim::geometry::Vec2;
use sim::lidar::Lidar;
use sim::nav_stack::{NavStack, Scan};
use sim::robot::Twist;

use crate::config::{FixedSchedule, RuntimeOptions};
use crate::envelope::{self, CommandLimits};
use crate::error::{guarded, RuntimeError};
use crate::input::{check, CycleInput};
use crate::laser::Reprojection;

/// What one control cycle decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CycleOutput {
    /// The velocity command to issue now (robot frame), inside [`Navigator::limits`].
    pub command: Twist,
    /// Whether this cycle decided a new command, issued at once (under the free compute
    /// model) or after `compute_s`: the planner ran, or the run has arrived (`arrived`, a
    /// stop, issued at once). `false`: under a compute model the last cycle's modelled
    /// compute still runs, and `command` repeats the last command.
    pub planned: bool,
    /// The planning cycle's modelled compute time (s) under a compute model (`None` under
    /// the free model, and for a cycle that did not plan).
    pub compute_s: Option<f64>,
    /// Whether the policy chose a new action this cycle (every agent period; never without a
    /// policy).
    pub agent_step: bool,
    /// The schedule the planner ran (or holds): its steps, horizon (s) and first step (s);
    /// `None` in the velocity action space, where no planner runs.
    pub schedule: Option<ScheduleSummary>,
    /// The work this cycle's planning counted (zero for a cycle that did not plan).
    pub work: CycleWork,
    /// Whether the run has arrived: the robot came within `goal_tolerance_m` of the goal
    /// (this cycle or an earlier one of the run). The command is then a stop, issued at once
    /// (`planned`, no `compute_s`, no work: the planner does not run), and every cycle says
    /// so until a new goal starts a new run.
    pub arrived: bool,
}

/// The shape of a rollout schedule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScheduleSummary {
    /// Rollout steps.
    pub steps: usize,
    /// Total horizon (s).
    pub horizon_s: f64,
    /// The first (finest) step (s).
    pub first_dt_s: f64,
}

impl ScheduleSummary {
    fn of(s: &Schedule) -> Self {
        Self {
            steps: s.len(),
            horizon_s: s.horizon(),
            first_dt_s: s.dts().first().copied().unwrap_or(0.0),
        }
    }
}

/// A trained policy and what it needs each agent step.
struct Agent {
    net: MlpPolicy,
    scratch: Scratch,
    action: AgentAction,
    laser: LaserResampler,
    laser_clip_m: f64,
    agent_period: u64,
    obs: Vec<f32>,
    out: Vec<f32>,
}

/// Refuses `policy` when its card records another planner or speed cap than `options`', or
/// none (see [`RuntimeOptions::allow_policy_mismatch`]); the message names both sides.
fn check_trained_for(policy: &LearnedPolicy, options: &RuntimeOptions) -> Result<(), RuntimeError> {
    let card = policy.card_path.display();
    let runtime = format!(
        "{} at max_speed = {} m/s",
        options.planner.name(),
        options.max_speed
    );
    let allow = "(allow_policy_mismatch = true runs it anyway, for a transfer experiment)";
    let Some(t) = policy.card.trained_for else {
        return Err(RuntimeError::Policy(format!(
            "policy {card}: its card does not record the planner and speed it was trained for \
             (exported before they were recorded), so it cannot be checked against the \
             runtime's {runtime}: re-export it with `adp export --planner P --max-speed S`, \
             the [run] planner and max_speed of the run's config.toml {allow}"
        )));
    };
    let trained = format!("{} at max_speed = {} m/s", t.planner.name(), t.max_speed);
    if t.planner != options.planner || (t.max_speed - options.max_speed).abs() > 1e-9 {
        return Err(RuntimeError::Policy(format!(
            "policy {card}: trained for {trained}, but the runtime runs {runtime}: run the \
             planner and speed it was trained for {allow}"
        )));
    }
    Ok(())
}

/// One robot's local planner, costmap, global path and policy.
///
/// Each [`Navigator::cycle`] takes one scan and odometry and returns the command: the cycle
/// the simulator's closed loop runs ([`sim::Episode`]'s sensing, [`CycleDriver`]'s planning,
/// [`AgentAction`]'s policy step), so a world driven through a navigator repeats `adp eval`'s
/// episode exactly. A new goal starts a new run (a fresh costmap around the robot and the
/// goal, a fresh planner and policy state).
///
/// Contract: call it once per control period (`[episode] control_dt`, 0.05 s by default),
/// in order. Inputs outside the envelope ([`crate::envelope`]) are refused, so a cycle's
/// memory and time are bounded; every command is clamped to [`Navigator::limits`]; a panic
/// inside a cycle is caught and returned as [`RuntimeError::Internal`]. Once warm a cycle
/// allocates nothing on a fixed schedule; a policy step builds
/// its schedule (four small vectors) and a new goal reallocates. Inside a rayon pool, the
/// planners' parallel rollouts allocate nothing either (outside one, rayon's global queue
/// may). `Send`: a robot may move it to its control thread; share it
/// behind a mutex, never call it from two threads at once (it takes `&mut self`).
pub struct Navigator {
    kind: PlannerKind,
    settings: EvalConfig,
    options: RuntimeOptions,
    episode: EpisodeConfig,
    prediction: Prediction,
    lidar: Lidar,
    planner: Box<dyn Planner>,
    driver: CycleDriver,
    nav: Option<NavStack>,
    agent: Option<Agent>,
    /// The policy's space (or the fixed schedule's), and what the current agent step runs.
    space: Option<ActionSpace>,
    applied: Applied,
    /// Control periods of this run so far (set to 1 when a panic drops the run, so that the
    /// next run rebuilds the planner, driver and policy state).
    periods: u64,
    /// The last command issued.
    last: Twist,
    /// The checked scan of the current cycle.
    ranges: Vec<f64>,
    /// The re-projection of a laser mounted off the base origin, and its output (the scan
    /// at the base origin); `None` for a laser at the base origin.
    mount: Option<(Reprojection, Vec<f64>)>,
    /// What every command is clamped to.
    limits: CommandLimits,
    /// Whether the current run has arrived at its goal.
    arrived: bool,
}

impl Navigator {
    /// A navigator for the planner and speed of `options`, with the episode, planner and
    /// compute settings of `settings` (an evaluation configuration: `configs/eval.toml`'s
    /// tables), and `policy` choosing the schedule (the fixed schedule of `options` without
    /// one). With a policy the robot's profile is the policy's (its planner predicts with
    /// the model it was trained with), as in `adp eval --policy`.
    ///
    /// Settings outside the envelope ([`crate::envelope`]) are refused; a panic while
    /// building is returned as [`RuntimeError::Internal`].
    pub fn new(
        settings: &EvalConfig,
        options: RuntimeOptions,
        policy: Option<LearnedPolicy>,
    ) -> Result<Self, RuntimeError> {
        guarded(|| Self::build(settings, options, policy))
    }

    fn build(
        settings: &EvalConfig,
        options: RuntimeOptions,
        policy: Option<LearnedPolicy>,
    ) -> Result<Self, RuntimeError> {
        let config = |message: String| RuntimeError::Config {
            origin: "runtime configuration".into(),
            message,
        };
        options.validate().map_err(config)?;
        let mut episode = settings.episode;
        let mut agent = None;
        let mut space = None;
        if let Some(p) = &policy {
            if p.env.observe_tracks > 0 {
                return Err(RuntimeError::Policy(format!(
                    "policy {}: it observes {} tracked obstacles; the runtime does not run \
                     the obstacle tracker",
                    p.card_path.display(),
                    p.env.observe_tracks
                )));
            }
            if !options.allow_policy_mismatch {
                check_trained_for(p, &options)?;
            }
            episode = episode.with_profile(p.env.profile, p.env.dynamics);
        }
        episode.validate().map_err(|e| config(format!("[episode] {e}")))?;
        envelope::check_settings(
            &episode.robot,
            &episode.costmap,
            episode.lidar.beams,
            options.max_speed,
            options.max_goal_distance_m,
        )
        .map_err(config)?;
        let lidar = Lidar::new(episode.lidar);
        let mount = (options.laser_pose != sim::geometry::Pose::default())
            .then(|| (Reprojection::new(&lidar, options.laser_pose), Vec::new()));
        let compute = settings
            .compute
            .resolve(options.planner.name())
            .map_err(|e| config(e.to_string()))?;
        let planner = options.planner.build(&settings.planners(), options.seed);
        if let Some(p) = policy {
            if let Some(g) = p.space.gains() {
                if planner.gains() != Some(g) {
                    return Err(RuntimeError::Policy(format!(
                        "policy {}: the {} action space sets the gains of {}; the planner is {}",
                        p.card_path.display(),
                        p.space,
                        g.planner(),
                        planner.name()
                    )));
                }
            }
            let obs_dim = observation::obs_dim(p.env.observation, p.space, 0);
            space = Some(p.space);
            agent = Some(Agent {
                scratch: Scratch::default(),
                action: AgentAction::new(p.space, p.env.action_map),
                laser: LaserResampler::new(p.env.observation, lidar.angles()),
                laser_clip_m: p.env.laser_clip_m,
                agent_period: u64::from(p.env.agent_period_cycles),
                obs: vec![0.0; obs_dim],
                out: vec![0.0; p.space.dim()],
                net: p.net,
            });
        }
        let applied = Applied::Schedule(match options.fixed {
            FixedSchedule::Ddp => Schedule::ddp_default(),
            FixedSchedule::Vanilla => Schedule::vanilla(),
        });
        Ok(Self {
            kind: options.planner,
            settings: settings.clone(),
            driver: CycleDriver::new(compute, episode.control_dt),
            prediction: Prediction::for_profile(episode.profile),
            options,
            episode,
            lidar,
            planner,
            nav: None,
            agent,
            space,
            applied,
            periods: 0,
            last: Twist::default(),
            ranges: Vec::new(),
            mount,
            limits: CommandLimits::new(&episode.robot, options.max_speed),
            arrived: false,
        })
    }

    /// A navigator from the configuration file `path` ([`crate::config`]): its paths are
    /// relative to its directory. Every error names the file and the key, or the policy file
    /// at fault.
    pub fn from_file(path: &std::path::Path) -> Result<Self, RuntimeError> {
        let (settings, options, policy) = crate::config::read(path)?;
        Self::new(&settings, options, policy)
    }

    /// The planner.
    pub fn planner(&self) -> PlannerKind {
        self.kind
    }

    /// The action space of the policy, when one chooses the schedule.
    pub fn space(&self) -> Option<ActionSpace> {
        self.space
    }

    /// The lidar the scans must come from (beam count, angles, range limits).
    pub fn lidar(&self) -> &Lidar {
        &self.lidar
    }

    /// The episode settings in force (control period, costmap, robot, the profile the
    /// planner predicts with).
    pub fn episode(&self) -> &EpisodeConfig {
        &self.episode
    }

    /// The limits every command is clamped to: `max_speed` forward, the robot's reverse
    /// speed and yaw rate ([`crate::envelope`]).
    pub fn limits(&self) -> CommandLimits {
        self.limits
    }

    /// The navigation state of the current run (costmap, global path, local goal); `None`
    /// before the first cycle.
    pub fn nav(&self) -> Option<&NavStack> {
        self.nav.as_ref()
    }

    /// The current run's local goal in the fixed frame: the point of the global path the
    /// planner steers to (what a policy's observation reads, in the robot frame); `None`
    /// before the first cycle.
    pub fn local_goal(&self) -> Option<Vec2> {
        self.nav.as_ref().map(NavStack::local_goal_world)
    }

    /// Plans on `schedule` from the next cycle on, in place of the fixed schedule, until the
    /// next call (across runs too): for a training actor, whose learner's policy chooses a
    /// schedule every agent step outside the runtime (from its action with the run's action
    /// space and map). A cycle whose modelled compute still runs keeps the last command, as
    /// ever. Refused when the navigator's own policy chooses the schedules, and for a
    /// schedule outside the envelope ([`envelope::MAX_SCHEDULE_STEPS`] steps,
    /// [`envelope::MAX_SCHEDULE_HORIZON_S`] seconds); a refusal changes nothing.
    pub fn set_schedule(&mut self, schedule: Schedule) -> Result<(), RuntimeError> {
        let refuse = |message: String| RuntimeError::Config {
            origin: "set_schedule".into(),
            message,
        };
        if self.agent.is_some() {
            return Err(refuse(
                "the navigator's policy chooses the schedules; configure it without `policy` to \
                 give them from outside"
                    .into(),
            ));
        }
        let (steps, horizon) = (schedule.len(), schedule.horizon());
        if steps > envelope::MAX_SCHEDULE_STEPS {
            return Err(refuse(format!(
                "{steps} steps: at most {} (the envelope)",
                envelope::MAX_SCHEDULE_STEPS
            )));
        }
        if !(horizon.is_finite() && horizon <= envelope::MAX_SCHEDULE_HORIZON_S) {
            return Err(refuse(format!(
                "a {horizon} s horizon: at most {} s (the envelope)",
                envelope::MAX_SCHEDULE_HORIZON_S
            )));
        }
        self.applied = Applied::Schedule(schedule);
        Ok(())
    }

    /// Runs one control cycle on `input`: checks it (a refused input changes nothing and
    /// the robot must issue [`crate::STOP`]), updates the costmap and path, lets the policy
    /// choose the schedule when an agent period begins, and plans. The command is clamped
    /// to [`Navigator::limits`], whatever the planner or the measured velocity. A panic is
    /// returned as [`RuntimeError::Internal`] and drops the run: the next cycle starts afresh,
    /// as for a new goal.
    pub fn cycle(&mut self, input: &CycleInput<'_>) -> Result<CycleOutput, RuntimeError> {
        let decided = guarded(|| self.cycle_unguarded(input));
        if matches!(decided, Err(RuntimeError::Internal(_))) {
            // The state a panic left half-updated is not trusted: a fresh run next cycle.
            self.nav = None;
            self.periods = 1;
        }
        decided
    }

    fn cycle_unguarded(&mut self, input: &CycleInput<'_>) -> Result<CycleOutput, RuntimeError> {
        let cfg = &self.episode.lidar;
        check(
            input,
            self.lidar.angles().len(),
            (cfg.min_range, cfg.max_range),
            &self.options,
            &mut self.ranges,
        )?;
        if self.nav.as_ref().is_none_or(|n| n.goal() != input.goal) {
            self.start_run(input);
        }
        let odom = input.odom;
        self.arrived |= odom.pose.position().dist(input.goal) <= self.options.goal_tolerance_m;
        if self.arrived {
            self.last = crate::STOP;
            return Ok(CycleOutput {
                command: crate::STOP,
                planned: true,
                compute_s: None,
                agent_step: false,
                schedule: None,
                work: CycleWork::default(),
                arrived: true,
            });
        }
        let ranges = match &mut self.mount {
            Some((reprojection, base)) => {
                reprojection.apply(&self.ranges, base);
                base
            }
            None => &self.ranges,
        };
        let nav = self.nav.as_mut().expect("a run has started");
        nav.update(
            &self.lidar,
            &Scan {
                ranges,
                pose: odom.pose,
                speed: odom.vel.v,
                time: input.stamp_s,
            },
            input.global_path,
        );
        let perception = nav.perception(ranges, odom.vel, &odom.pose);
        let mut agent_step = false;
        if let Some(a) = &mut self.agent {
            if self.periods.is_multiple_of(a.agent_period) {
                observation::write(
                    &perception,
                    &a.laser,
                    a.action.previous(),
                    a.laser_clip_m,
                    &[],
                    &mut a.obs,
                );
                a.net.act(&a.obs, &mut a.out, &mut a.scratch);
                self.applied = a
                    .action
                    .apply(&a.out, self.planner.as_mut(), self.options.max_speed)
                    .map_err(|e| RuntimeError::Policy(format!("the policy's action: {e}")))?;
                agent_step = true;
            }
        }
        let (command, planned, compute_s, schedule) = match &self.applied {
            Applied::Velocity(cmd) => (*cmd, true, self.driver.charge_command(), None),
            Applied::Schedule(s) => {
                let summary = Some(ScheduleSummary::of(s));
                if self.driver.holds() {
                    (self.last, false, None, summary)
                } else {
                    let (cmd, compute_s) = self.driver.plan_cycle(
                        self.planner.as_mut(),
                        perception,
                        s,
                        self.options.max_speed,
                        self.prediction,
                    );
                    (cmd, true, compute_s, summary)
                }
            }
        };
        // Planners command inside the limits from a measured state inside them (the clamp
        // leaves those commands bit for bit); from one outside (wheel slip, an odometry fault)
        // they may not.
        let command = self.limits.clamp(command);
        let work = match (&self.applied, planned) {
            (Applied::Schedule(_), true) => self.planner.trace().cycle,
            _ => CycleWork::default(),
        };
        self.periods += 1;
        self.last = command;
        Ok(CycleOutput {
            command,
            planned,
            compute_s,
            agent_step,
            schedule,
            work,
            arrived: false,
        })
    }

    /// Starts a run towards `input.goal` from the robot's pose: a fresh costmap, planner,
    /// cycle driver and policy state (the planner, driver and policy state are rebuilt when
    /// the last run planned at least once, or was dropped by a panic).
    fn start_run(&mut self, input: &CycleInput<'_>) {
        let world_moves = false;
        let clearing = self.episode.costmap.clearing.enabled(world_moves);
        let e = &self.episode;
        self.nav = Some(NavStack::new(
            e.costmap,
            e.replan_every,
            e.smoothing_window,
            clearing,
            input.odom.pose.position(),
            input.goal,
        ));
        if self.periods > 0 {
            self.planner = self.kind.build(&self.settings.planners(), self.options.seed);
            let compute = self.driver.compute().cloned();
            self.driver = CycleDriver::new(compute, self.episode.control_dt);
            if let Some(a) = &mut self.agent {
                a.action = AgentAction::new(a.action.space(), a.action.map());
            }
        }
        self.periods = 0;
        self.last = Twist::default();
        self.arrived = false;
    }
}
