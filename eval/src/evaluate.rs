//! `adp eval`: planners x fidelities x speeds over a set of worlds, run in parallel, reduced
//! to the papers' table (success, time, score, collision, timeout).
//!
//! `Fidelity::Adp` runs either a constant action (one schedule for the whole episode, through
//! the plain episode driver) or a trained policy closed-loop through the RL environment
//! [`actor::AdpEnv`], exactly as the actors run it in training but without exploration noise:
//! every agent step (0.25 s) the policy sees the environment's observation and its action
//! picks the schedule of the next agent step. Both produce the same per-run
//! [`EpisodeResult`]s, so rows, table and JSON do not depend on which one ran.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;

use actor::closed_loop::{self, planner_seed, Chooser, Greedy, Run, Step};
use actor::{EnvConfig, MlpPolicy};
use planner::moving::FORECAST_HORIZONS;
use planner::residual::Corrector;
use planner::{
    run::CycleDriver, ActionSpace, ComputeConfig, ComputeModel, ComputeTally, ForecastErrors, PadpParts,
    PlanInput, Planner, PlannerKind, Schedule, Trace, TrackingConfig,
};
use sim::lidar::LidarConfig;
use sim::robot::Twist;
use sim::{EpisodeResult, Status, World};

use crate::config::EvalConfig;
use crate::error::{Error, Result};

/// Returns an [`Error::Refused`] with the formatted message.
macro_rules! refuse {
    ($($t:tt)*) => {
        return Err(Error::Refused(format!($($t)*)))
    };
}

/// Time charged to a failed run when averaging times (s), as in the ADP paper.
pub const FAILED_RUN_TIME: f64 = 50.0;

/// How a row's planner learns of moving obstacles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum ObstaclePrediction {
    /// None: moving obstacles are scan points like any other.
    #[default]
    Off,
    /// The tracker on the robot's scans (clusters, a constant-velocity Kalman filter per
    /// track) forecasts each moving obstacle; every rollout point is checked against the
    /// forecast at its time (`planner::moving`).
    Kf,
    /// kf, with PADP's residual corrector on the forecast (Eq. 3, `planner::residual`): a
    /// track whose recent motion bends by at least the corrector's threshold gets its
    /// learned correction wherever its forecast is checked (`[prediction] residual`, default
    /// the corrector embedded from `assets/kf-residual/`).
    KfRes,
    /// kf, and the global path search weighs PADP's predictive cost field of the forecast
    /// (Eqs. 4-6; `[prediction] predictive_cost_weight`, `[prediction.field]`).
    PadpPath,
    /// padp-path, and PADP's complexity score switches the planner's weights and the
    /// replanning interval between three modes (Eqs. 7-8; `[prediction.complexity]`,
    /// `[prediction.modes]`).
    Padp,
}

impl ObstaclePrediction {
    /// `driver` with the tracker, the residual `corrector` and PADP this value runs (`cfg`'s
    /// `[prediction]` settings). Panics for `kf-res` without a corrector: the caller loads it
    /// ([`crate::corrector::load_corrector`]).
    pub fn driver(
        self,
        driver: CycleDriver,
        cfg: &EvalConfig,
        corrector: Option<&Arc<Corrector>>,
    ) -> CycleDriver {
        match self {
            ObstaclePrediction::Off => driver,
            ObstaclePrediction::Kf => driver.with_tracking(TrackingConfig::default()),
            ObstaclePrediction::KfRes => {
                driver
                    .with_tracking(TrackingConfig::default())
                    .with_corrector(Arc::clone(
                        corrector.expect("the caller loads the corrector for kf-res"),
                    ))
            }
            ObstaclePrediction::PadpPath | ObstaclePrediction::Padp => driver
                .with_tracking(TrackingConfig::default())
                .with_padp(cfg.prediction.clone(), self.padp()),
        }
    }

    /// The parts of PADP the row runs.
    pub fn padp(self) -> PadpParts {
        PadpParts {
            path: matches!(self, ObstaclePrediction::PadpPath | ObstaclePrediction::Padp),
            adapt: self == ObstaclePrediction::Padp,
        }
    }

    /// The suffix of the row's fidelity label: none, `+kf`, `+kf-res`, `+padp-path`, `+padp`.
    pub fn label_suffix(self) -> String {
        match self {
            ObstaclePrediction::Off => String::new(),
            p => format!("+{}", kebab(&p)),
        }
    }
}

/// A fidelity strategy selectable on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Fidelity {
    /// Uniform 0.05 s x 20 steps, full collision checks.
    Vanilla,
    /// Decremental: p = 1.7, T = 2 s, N = 20, check points decaying as N_t.
    Ddp,
    /// Adaptive: the schedule chosen by a policy in an ADP action space.
    Adp,
}

/// How `--fidelity adp` chooses its schedule.
#[derive(Clone, Debug, PartialEq)]
pub struct AdpSetting {
    /// The action space.
    pub space: ActionSpace,
    /// The (constant) normalized action.
    pub action: Vec<f64>,
}

impl Fidelity {
    /// The schedule of this strategy (`adp` uses the given setting). Without a policy the
    /// planner runs with its configured gains, so a constant action of an objective-weight
    /// space must keep them (factors of 1); the velocity space has no schedule.
    pub fn schedule(self, adp: &AdpSetting) -> Result<Schedule> {
        Ok(match self {
            Fidelity::Vanilla => Schedule::vanilla(),
            Fidelity::Ddp => Schedule::ddp_default(),
            Fidelity::Adp => adp
                .space
                .schedule_only(&adp.action, planner::schedule::DEFAULT_BOUNDARY_POINTS)
                .map_err(|e| Error::component("the --fidelity adp action", e))?,
        })
    }
}

/// A sensing condition of `adp eval --lidar-beams/--lidar-noise-fraction/--lidar-dropout`: the
/// `[episode.lidar]` values it replaces (`None` keeps the configuration's).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LidarOverride {
    /// Beams over the field of view.
    pub beams: Option<usize>,
    /// Range noise as a fraction of each scan's mean range; replaces the absolute noise (its
    /// `noise_sigma` becomes 0).
    pub noise_fraction: Option<f64>,
    /// Probability that a beam returns nothing.
    pub dropout: Option<f64>,
}

impl LidarOverride {
    /// Every combination of the given values, in the order beams, then noise fraction, then
    /// dropout (an empty list keeps the configuration's value): one row each. No values at all
    /// give the one override that changes nothing.
    pub fn combinations(beams: &[usize], noise_fractions: &[f64], dropouts: &[f64]) -> Vec<Self> {
        fn or_keep<T: Copy>(values: &[T]) -> Vec<Option<T>> {
            if values.is_empty() {
                vec![None]
            } else {
                values.iter().copied().map(Some).collect()
            }
        }
        let mut out = Vec::new();
        for &beams in &or_keep(beams) {
            for &noise_fraction in &or_keep(noise_fractions) {
                for &dropout in &or_keep(dropouts) {
                    out.push(Self {
                        beams,
                        noise_fraction,
                        dropout,
                    });
                }
            }
        }
        out
    }

    /// Whether it replaces nothing.
    pub fn is_none(&self) -> bool {
        *self == Self::default()
    }

    /// `lidar` with these values, checked; the error names the flags that made it.
    pub fn apply(&self, lidar: LidarConfig) -> Result<LidarConfig> {
        let mut out = lidar;
        let mut flags = Vec::new();
        if let Some(b) = self.beams {
            out.beams = b;
            flags.push(format!("--lidar-beams {b}"));
        }
        if let Some(f) = self.noise_fraction {
            out.noise_fraction = f;
            out.noise_sigma = 0.0;
            flags.push(format!("--lidar-noise-fraction {f}"));
        }
        if let Some(d) = self.dropout {
            out.dropout = d;
            flags.push(format!("--lidar-dropout {d}"));
        }
        out.validate().map_err(|e| Error::Config {
            origin: flags.join(" "),
            message: e.to_string(),
        })?;
        Ok(out)
    }
}

/// A short label of a lidar's sensing condition: beams, noise and dropout.
pub fn lidar_label(l: &LidarConfig) -> String {
    // A share in percent, to 6 decimals (0.07 reads 7, not 7.000000000000001).
    let pct = |x: f64| (x * 1e8).round() / 1e6;
    let noise = if l.noise_fraction > 0.0 {
        format!("noise {}% of mean range", pct(l.noise_fraction))
    } else {
        format!("noise {} m", l.noise_sigma)
    };
    let dropout = if l.dropout > 0.0 {
        format!(", dropout {}%", pct(l.dropout))
    } else {
        String::new()
    };
    format!("{} beams, {noise}{dropout}", l.beams)
}

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct EvalPlan {
    /// Planners.
    pub planners: Vec<PlannerKind>,
    /// Fidelity strategies.
    pub fidelities: Vec<Fidelity>,
    /// Speed caps (m/s).
    pub speeds: Vec<f64>,
    /// World ids.
    pub worlds: Vec<usize>,
    /// Runs per world.
    pub runs: usize,
    /// Best and worst runs (by time) dropped per world.
    pub trim: usize,
    /// Base seed.
    pub seed: u64,
    /// The ADP action space and action for `Fidelity::Adp`.
    pub adp: AdpSetting,
    /// A trained policy for `Fidelity::Adp` in `adp.space`: when set, it chooses the schedule
    /// every agent step instead of the constant `adp.action`.
    pub policy: Option<MlpPolicy>,
    /// The environment settings `policy` was trained with (agent period, laser clip); its
    /// agent-step cap is lifted in evaluation.
    pub policy_env: EnvConfig,
    /// Obstacle predictions: one row per value.
    pub predictions: Vec<ObstaclePrediction>,
    /// Sensing conditions: one row per value (`[LidarOverride::default()]`: the configuration's
    /// `[episode.lidar]`).
    pub lidars: Vec<LidarOverride>,
}

/// One table row.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Planner.
    pub planner: PlannerKind,
    /// Fidelity strategy.
    pub fidelity: Fidelity,
    /// Fidelity as shown in the table (`adp` names its action space; `+kf` marks obstacle
    /// prediction).
    pub fidelity_label: String,
    /// How the planner learned of moving obstacles.
    pub prediction: ObstaclePrediction,
    /// Speed cap (m/s).
    pub max_speed: f64,
    /// The row's lidar, when `--lidar-*` set its sensing condition (absent otherwise: the
    /// configuration's `[episode.lidar]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar: Option<LidarConfig>,
    /// Successful runs (%).
    pub success_pct: f64,
    /// Mean time (s), failed runs counted as 50 s.
    pub avg_time_s: f64,
    /// Mean BARN score.
    pub avg_score: f64,
    /// Collided runs (%).
    pub collision_pct: f64,
    /// Timed-out runs (%).
    pub timeout_pct: f64,
    /// Runs counted (after trimming).
    pub episodes: usize,
    /// Mean collision-check points (robot centre + footprint boundary points) the planner
    /// evaluated per planning cycle, over every run of the row.
    pub check_points_per_cycle: f64,
    /// Mean wall-clock time of one planning call (ms), over every run of the row; measured
    /// on the thread that runs the episode while all cores run episodes.
    pub plan_ms_per_cycle: f64,
    /// The compute model the row ran under (`free`, or the platform and budget scale).
    pub compute_model: String,
    /// Mean work per planning cycle, per unit of [`planner::Work`].
    pub units_per_cycle: UnitsPerCycle,
    /// Mean modelled compute per planning cycle (ms; 0 under the free model).
    pub modelled_ms_per_cycle: f64,
    /// Candidate samples the budget let the planner evaluate (%).
    pub samples_evaluated_pct: f64,
    /// Planning cycles the budget stopped before their last sample (%).
    pub truncated_cycles_pct: f64,
    /// Planning cycles whose modelled compute ran past the control period, so that the next
    /// cycle started late and the robot kept its command meanwhile (%).
    pub late_cycles_pct: f64,
    /// Planning cycles in PADP's pressure modes A, B, C (%; rows of `--prediction padp`
    /// only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pressure_modes_pct: Option<[f64; 3]>,
    /// The tracker's forecast against the truth over the row's runs (rows that run the
    /// tracker with the plain planning loop: kf, padp-path, padp).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub forecast: Option<ForecastRmse>,
    /// Every run of every world, untrimmed.
    pub per_world: Vec<WorldRuns>,
}

/// The tracker's forecast error against the truth ([`planner::ForecastErrors`]).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ForecastRmse {
    /// Forecast horizons (s; 0: the estimate now).
    pub horizons_s: [f64; 5],
    /// Root mean square error per horizon (m; null where nothing was compared).
    pub rmse_m: [Option<f64>; 5],
    /// The same for a forecast that each obstacle stands still where it is estimated (m).
    pub still_rmse_m: [Option<f64>; 5],
    /// Forecasts compared per horizon.
    pub forecasts: [u64; 5],
}

/// One run's outcome: its row, world and run index, result, what its planning cycles did and
/// cost, the wall time they took, and the tracker's forecast errors (rows with a tracker).
type RunOut = (
    usize,
    usize,
    usize,
    EpisodeResult,
    ComputeTally,
    Arc<PlanCost>,
    Option<ForecastErrors>,
);

/// Mean work per planning cycle, by unit ([`planner::Work`]).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct UnitsPerCycle {
    /// Distance-field cells built.
    pub cells: f64,
    /// Samples scored.
    pub samples: f64,
    /// Random numbers drawn.
    pub draws: f64,
    /// Integration steps.
    pub steps: f64,
    /// Check points.
    pub points: f64,
}

impl UnitsPerCycle {
    /// The per-cycle means of `t`.
    pub fn of(t: &ComputeTally) -> Self {
        let n = t.cycles.max(1) as f64;
        let [cells, samples, draws, steps, points] = t.work.as_array().map(|u| u as f64 / n);
        Self {
            cells,
            samples,
            draws,
            steps,
            points,
        }
    }
}

/// A short label of a compute model: `free`, or the platform and its budget scale.
pub fn compute_label(c: &ComputeConfig) -> String {
    match c.model {
        ComputeModel::Free => "free".into(),
        _ if c.budget_scale == 1.0 => kebab(&c.model),
        _ => format!("{} x{}", kebab(&c.model), c.budget_scale),
    }
}

/// All runs of one world in one row.
#[derive(Clone, Debug, Serialize)]
pub struct WorldRuns {
    /// World id.
    pub world: usize,
    /// Runs in seed order.
    pub runs: Vec<EpisodeResult>,
}

/// Seed of one run: a SplitMix64 mix of the base seed, world and run index, so every run
/// has its own reproducible noise stream whatever the thread layout.
pub fn run_seed(base: u64, world: usize, run: usize) -> u64 {
    let mut z = base
        ^ (world as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (run as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Run `seed` of `world` at speed cap `speed` with a fresh `planner` seeded from the run seed
/// ([`planner_seed`]): how every evaluation path (eval, greedy evaluation, experiment stages
/// and figures) sets up a run.
pub fn eval_run<'w>(
    cfg: &EvalConfig,
    world: &'w World,
    planner: PlannerKind,
    speed: f64,
    seed: u64,
) -> Run<'w> {
    Run {
        world,
        episode: cfg.episode,
        planner: planner.build(&cfg.planners(), planner_seed(seed)),
        max_speed: speed,
        seed,
    }
}

/// The wall time one episode's planning calls took (ns); the work they did is in the run's
/// [`ComputeTally`].
#[derive(Debug, Default)]
struct PlanCost {
    nanos: AtomicU64,
}

/// A planner wrapped to meter its wall time into a shared [`PlanCost`] (shared because a
/// policy episode moves its planner into the environment). `Send`, like the planner it
/// wraps.
struct Metered {
    inner: Box<dyn Planner>,
    cost: Arc<PlanCost>,
}

impl Planner for Metered {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        let t0 = Instant::now();
        let cmd = self.inner.plan(input);
        let nanos = t0.elapsed().as_nanos() as u64;
        self.cost.nanos.fetch_add(nanos, Ordering::Relaxed);
        cmd
    }

    fn trace(&self) -> &Trace {
        self.inner.trace()
    }

    fn trace_mut(&mut self) -> &mut Trace {
        self.inner.trace_mut()
    }

    fn gains(&self) -> Option<planner::Gains> {
        self.inner.gains()
    }

    fn set_gain_factors(&mut self, factors: &[f64]) -> Result<(), planner::GainsError> {
        self.inner.set_gain_factors(factors)
    }
}

/// The environment settings of an evaluation run with a trained policy: the ones it was
/// trained with (agent period, laser clip and layout: the observation its card documents) with
/// no agent-step cap, so runs end by the BARN protocol of `[episode]` like every other row, no
/// domain randomization, so every row runs its own lidar ([`EnvConfig::for_evaluation`]), and
/// the evaluation's compute model, so every row runs on the same computer.
fn eval_env_config(trained: EnvConfig, compute: ComputeConfig) -> EnvConfig {
    EnvConfig {
        compute,
        ..trained.for_evaluation()
    }
}

fn charged_time(r: &EpisodeResult) -> f64 {
    if r.status == Status::Succeeded {
        r.time_s
    } else {
        FAILED_RUN_TIME
    }
}

/// Reduces the runs of one row: per world, sort by charged time, drop `trim` best and worst,
/// then average over everything kept.
pub fn summarize(per_world: &[WorldRuns], trim: usize) -> (f64, f64, f64, f64, f64, usize) {
    let mut kept: Vec<&EpisodeResult> = Vec::new();
    for w in per_world {
        let mut runs: Vec<&EpisodeResult> = w.runs.iter().collect();
        runs.sort_by(|a, b| charged_time(a).total_cmp(&charged_time(b)));
        kept.extend(&runs[trim..runs.len() - trim]);
    }
    let n = kept.len().max(1) as f64;
    let pct = |s: Status| 100.0 * kept.iter().filter(|r| r.status == s).count() as f64 / n;
    (
        pct(Status::Succeeded),
        kept.iter().map(|r| charged_time(r)).sum::<f64>() / n,
        kept.iter().map(|r| r.score).sum::<f64>() / n,
        pct(Status::Collided),
        pct(Status::TimedOut),
        kept.len(),
    )
}

/// Runs the whole plan on `worlds` (indexed by id) and returns one row per
/// (planner, fidelity, speed, prediction, sensing condition).
pub fn run(plan: &EvalPlan, cfg: &EvalConfig, worlds: &[World]) -> Result<Vec<Row>> {
    let lidars = check_plan(plan, cfg, worlds)?;
    let policy = plan
        .policy
        .as_ref()
        .filter(|_| plan.fidelities.contains(&Fidelity::Adp));
    let mut jobs = Vec::new();
    for (ri, (p, f, s, pr, li)) in combos(plan).enumerate() {
        for &w in &plan.worlds {
            for r in 0..plan.runs {
                jobs.push(Job {
                    row: ri,
                    combo: (p, f, s, pr, li),
                    world: w,
                    run: r,
                });
            }
        }
    }
    let bar = ProgressBar::new(jobs.len() as u64).with_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} episodes (eta {eta})",
        )
        .expect("static template"),
    );
    let corrector = plan
        .predictions
        .contains(&ObstaclePrediction::KfRes)
        .then(|| crate::corrector::load_corrector(cfg.prediction.residual.as_deref()))
        .transpose()?;
    let t0 = Instant::now();
    let results: Vec<RunOut> = jobs
        .par_iter()
        .map(|job| {
            let out = run_one(plan, cfg, worlds, &lidars, policy, corrector.as_ref(), job);
            bar.inc(1);
            out
        })
        .collect::<Result<_>>()?;
    bar.finish_and_clear();
    let cycles: u64 = results.iter().map(|x| x.4.cycles).sum();
    let secs = t0.elapsed().as_secs_f64();
    tracing::info!(
        episodes = results.len(),
        planner_cycles = cycles,
        seconds = format_args!("{secs:.1}"),
        cycles_per_s = format_args!("{:.0}", cycles as f64 / secs),
        real_time_per_thread = format_args!(
            "{:.0}x",
            cycles as f64 * cfg.episode.control_dt / secs / rayon::current_num_threads() as f64
        ),
        "evaluation done"
    );

    Ok(combos(plan)
        .enumerate()
        .map(|(ri, combo)| row(plan, cfg, &lidars, ri, combo, &results))
        .collect())
}

/// Checks `plan` against `cfg` and `worlds` (runs and trim, speeds, the policy's layout and
/// profile, the predictions and sensing conditions a learned policy can run); returns the
/// lidar of each sensing condition.
fn check_plan(plan: &EvalPlan, cfg: &EvalConfig, worlds: &[World]) -> Result<Vec<LidarConfig>> {
    if plan.runs == 0 {
        refuse!("--runs must be at least 1");
    }
    if 2 * plan.trim >= plan.runs {
        refuse!(
            "--trim {} drops every run: it must be less than half of --runs {}",
            plan.trim,
            plan.runs
        );
    }
    for &s in &plan.speeds {
        if !(s > 0.0 && s <= cfg.episode.robot.max_v) {
            refuse!("--max-speed {s} must be in (0, {}] m/s", cfg.episode.robot.max_v);
        }
    }
    // A learned policy runs in its own environment, which runs the tracker exactly when the
    // policy observes tracks; the rows it makes must say so.
    if plan.fidelities.contains(&Fidelity::Adp) && plan.policy.is_some() {
        let tracks = plan.policy_env.observe_tracks;
        if plan
            .predictions
            .iter()
            .any(|&p| p.padp() != PadpParts::default() || p == ObstaclePrediction::KfRes)
        {
            refuse!(
                "--prediction kf-res, padp-path and padp run with the planning loop of --fidelity \
                 vanilla, ddp or a constant adp action, not with a learned policy (its environment \
                 runs the tracker alone): use --prediction kf"
            );
        }
        if tracks == 0 && plan.predictions.contains(&ObstaclePrediction::Kf) {
            refuse!(
                "--prediction kf with --fidelity adp needs a policy that observes tracks ([env] \
                 observe_tracks > 0): this policy's environment runs no tracker"
            );
        }
        if tracks > 0 && plan.predictions.contains(&ObstaclePrediction::Off) {
            refuse!(
                "this policy observes {tracks} moving tracks ([env] observe_tracks), so its \
                 environment always runs the tracker: evaluate it with --prediction kf"
            );
        }
    }
    if plan.predictions.is_empty() {
        refuse!("--prediction needs at least one value (off, kf)");
    }
    if plan.lidars.is_empty() {
        refuse!("an evaluation needs at least one sensing condition");
    }
    let lidars: Vec<LidarConfig> = plan
        .lidars
        .iter()
        .map(|o| o.apply(cfg.episode.lidar))
        .collect::<Result<_>>()?;
    for &w in &plan.worlds {
        if worlds.get(w).is_none() {
            return Err(Error::Refused(missing_world(worlds, w)));
        }
    }
    let policy = plan
        .policy
        .as_ref()
        .filter(|_| plan.fidelities.contains(&Fidelity::Adp));
    if let Some(net) = policy {
        let space = plan.adp.space;
        let laser = plan.policy_env.observation;
        let obs_dim = actor::obs_dim(laser, space, plan.policy_env.observe_tracks);
        if (net.obs_dim(), net.act_dim()) != (obs_dim, space.dim()) {
            refuse!(
                "the policy maps {} observation values to {} actions; the {} action space with the \
                 {laser} laser layout needs {} to {}",
                net.obs_dim(),
                net.act_dim(),
                kebab(&space),
                obs_dim,
                space.dim()
            );
        }
        if plan.policy_env.profile != cfg.episode.profile {
            refuse!(
                "the policy was trained on the {} simulator profile but this evaluation runs {}: \
                 pass --profile {} (or set [episode] profile) so every row runs the same robot",
                plan.policy_env.profile.name(),
                cfg.episode.profile.name(),
                plan.policy_env.profile.name()
            );
        }
    }
    Ok(lidars)
}

/// One episode of an evaluation.
#[derive(Clone, Copy)]
struct Job {
    /// Index of its row in [`combos`] order.
    row: usize,
    /// The row's planner, fidelity, speed cap, prediction and sensing condition (index).
    combo: Combo,
    /// World id.
    world: usize,
    /// Run index within the world.
    run: usize,
}

/// Runs `job`: the planner (metered) on its world with its schedule, or closed-loop with the
/// learned `policy` for an ADP row.
fn run_one(
    plan: &EvalPlan,
    cfg: &EvalConfig,
    worlds: &[World],
    lidars: &[LidarConfig],
    policy: Option<&MlpPolicy>,
    corrector: Option<&Arc<Corrector>>,
    job: &Job,
) -> Result<RunOut> {
    let Job {
        row: ri,
        combo: (p, f, s, pr, li),
        world: w,
        run: r,
    } = *job;
    let seed = run_seed(plan.seed, w, r);
    let cost = Arc::new(PlanCost::default());
    let mut run = eval_run(cfg, &worlds[w], p, s, seed);
    run.episode.lidar = lidars[li];
    run.planner = Box::new(Metered {
        inner: run.planner,
        cost: Arc::clone(&cost),
    });
    let no_steps = |_: &Step<'_>| Ok::<(), actor::EnvError>(());
    let episode_error = |source| Error::Episode {
        world: w,
        run: r,
        source,
    };
    let (out, forecast) = match policy.filter(|_| f == Fidelity::Adp) {
        Some(net) => {
            let chooser = Chooser::Env {
                space: plan.adp.space,
                env: &eval_env_config(plan.policy_env, cfg.compute),
                act: &mut Greedy::new(net),
            };
            let out = closed_loop::run(run, chooser, no_steps).map_err(episode_error)?;
            (out, None)
        }
        None => {
            let compute = cfg
                .compute
                .resolve(p.name())
                .map_err(|e| Error::component(format!("the compute model of {}", p.name()), e))?;
            let driver = CycleDriver::new(compute, cfg.episode.control_dt);
            let mut driver = pr.driver(driver, cfg, corrector).with_forecast_errors();
            let schedule = f.schedule(&plan.adp)?;
            let chooser = Chooser::Fixed {
                schedule: &schedule,
                driver: &mut driver,
            };
            let out = closed_loop::run(run, chooser, no_steps).map_err(episode_error)?;
            let forecast = driver.tracking().and(driver.forecast_errors().copied());
            (out, forecast)
        }
    };
    let (res, tally) = (out.episode, out.compute);
    Ok((ri, w, r, res, tally, cost, forecast))
}

/// The row of combination `ri` of `plan` from every run's result.
fn row(
    plan: &EvalPlan,
    cfg: &EvalConfig,
    lidars: &[LidarConfig],
    ri: usize,
    (p, f, s, pr, li): Combo,
    results: &[RunOut],
) -> Row {
    let per_world: Vec<WorldRuns> = plan
        .worlds
        .iter()
        .map(|&w| {
            let mut runs: Vec<(usize, EpisodeResult)> = results
                .iter()
                .filter(|x| x.0 == ri && x.1 == w)
                .map(|x| (x.2, x.3))
                .collect();
            runs.sort_by_key(|x| x.0);
            WorldRuns {
                world: w,
                runs: runs.into_iter().map(|x| x.1).collect(),
            }
        })
        .collect();
    let (success_pct, avg_time_s, avg_score, collision_pct, timeout_pct, episodes) =
        summarize(&per_world, plan.trim);
    let mut tally = ComputeTally::default();
    let mut nanos = 0;
    let mut forecast: Option<ForecastErrors> = None;
    for x in results.iter().filter(|x| x.0 == ri) {
        tally += x.4;
        nanos += x.5.nanos.load(Ordering::Relaxed);
        if let Some(e) = x.6 {
            *forecast.get_or_insert_default() += e;
        }
    }
    let cycles = tally.cycles.max(1) as f64;
    Row {
        planner: p,
        fidelity: f,
        fidelity_label: match f {
            Fidelity::Adp => format!("adp-{}", kebab(&plan.adp.space)),
            _ => format!("{}{}", kebab(&f), pr.label_suffix()),
        },
        prediction: pr,
        max_speed: s,
        lidar: (!plan.lidars[li].is_none()).then_some(lidars[li]),
        success_pct,
        avg_time_s,
        avg_score,
        collision_pct,
        timeout_pct,
        episodes,
        check_points_per_cycle: tally.work.points as f64 / cycles,
        plan_ms_per_cycle: nanos as f64 / cycles / 1e6,
        compute_model: compute_label(&cfg.compute),
        units_per_cycle: UnitsPerCycle::of(&tally),
        modelled_ms_per_cycle: tally.ms_per_cycle(),
        samples_evaluated_pct: 100.0 * tally.evaluated_share(),
        truncated_cycles_pct: 100.0 * tally.truncated_cycles as f64 / cycles,
        late_cycles_pct: 100.0 * tally.late_cycles as f64 / cycles,
        pressure_modes_pct: pr
            .padp()
            .adapt
            .then(|| tally.pressure_cycles.map(|n| 100.0 * n as f64 / cycles)),
        forecast: forecast.map(|e| ForecastRmse {
            horizons_s: FORECAST_HORIZONS,
            rmse_m: e.rmse(),
            still_rmse_m: e.rmse_still(),
            forecasts: e.count,
        }),
        per_world,
    }
}

/// One row's planner, fidelity, speed cap (m/s), prediction and sensing condition (its index
/// in `plan.lidars`).
type Combo = (PlannerKind, Fidelity, f64, ObstaclePrediction, usize);

/// The rows of `plan` in table order: planner, then fidelity, then speed, then prediction,
/// then sensing condition.
fn combos(plan: &EvalPlan) -> impl Iterator<Item = Combo> + '_ {
    plan.planners.iter().flat_map(move |&p| {
        plan.fidelities.iter().flat_map(move |&f| {
            plan.speeds.iter().flat_map(move |&s| {
                plan.predictions
                    .iter()
                    .flat_map(move |&pr| (0..plan.lidars.len()).map(move |li| (p, f, s, pr, li)))
            })
        })
    })
}

/// The kebab-case name of a serializable unit enum value.
fn kebab<T: Serialize>(v: &T) -> String {
    serde_json::to_value(v)
        .ok()
        .and_then(|j| j.as_str().map(str::to_string))
        .unwrap_or_default()
}

/// The markdown table of the rows; a `lidar` column after the speed when a row has its own
/// sensing condition.
pub fn table(rows: &[Row]) -> String {
    let lidar_column = rows.iter().any(|r| r.lidar.is_some());
    let mut out = format!(
        "| planner | fidelity | max speed (m/s) |{} success (%) | avg time (s) | avg score | collision (%) | timeout (%) | episodes | check points / cycle | plan ms / cycle | compute | model ms / cycle | samples evaluated (%) | late cycles (%) |\n\
         |---|---|---|{}---|---|---|---|---|---|---|---|---|---|---|---|\n",
        if lidar_column { " lidar |" } else { "" },
        if lidar_column { "---|" } else { "" },
    );
    for r in rows {
        let lidar = match (&r.lidar, lidar_column) {
            (_, false) => String::new(),
            (Some(l), true) => format!(" {} |", lidar_label(l)),
            (None, true) => " [episode.lidar] |".into(),
        };
        out.push_str(&format!(
            "| {} | {} | {:.1} |{lidar} {:.2} | {:.2} | {:.3} | {:.2} | {:.2} | {} | {:.0} | {:.3} | {} | {:.2} | {:.1} | {:.2} |\n",
            serde_json::to_value(r.planner)
                .expect("enum")
                .as_str()
                .unwrap_or("?"),
            kebab(&r.fidelity) + &r.prediction.label_suffix(),
            r.max_speed,
            r.success_pct,
            r.avg_time_s,
            r.avg_score,
            r.collision_pct,
            r.timeout_pct,
            r.episodes,
            r.check_points_per_cycle,
            r.plan_ms_per_cycle,
            r.compute_model,
            r.modelled_ms_per_cycle,
            r.samples_evaluated_pct,
            r.late_cycles_pct
        ));
    }
    out
}

/// Why world `id` is not in `all` (a generated id says how to evaluate generated worlds).
pub fn missing_world(all: &[World], id: usize) -> String {
    if sim::catalog::is_generated(id) {
        format!(
            "world {id} is a generated world, made on demand for training only: to evaluate \
             generated worlds, write them with `adp worlds generate` and pass --obstacles \
             and --paths"
        )
    } else {
        format!("world {id} does not exist ({} worlds)", all.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use actor::LaserLayout;

    /// One DWA row at 1.5 m/s: one run of `world`, seed 1, the decremental space at DDP's
    /// action, no prediction, the configured lidar; each test overrides what it tests.
    fn dwa_plan(
        world: usize,
        fidelities: Vec<Fidelity>,
        policy: Option<MlpPolicy>,
        policy_env: EnvConfig,
    ) -> EvalPlan {
        let space = ActionSpace::Decremental;
        EvalPlan {
            planners: vec![PlannerKind::Dwa],
            fidelities,
            speeds: vec![1.5],
            worlds: vec![world],
            runs: 1,
            trim: 0,
            seed: 1,
            adp: AdpSetting {
                space,
                action: space.ddp_action(),
            },
            policy,
            policy_env,
            predictions: vec![ObstaclePrediction::Off],
            lidars: vec![LidarOverride::default()],
        }
    }

    fn res(status: Status, time_s: f64, score: f64) -> EpisodeResult {
        EpisodeResult {
            world: 0,
            status,
            time_s,
            sim_time_s: time_s,
            score,
            distance_m: 0.0,
        }
    }

    #[test]
    fn trimming_drops_best_and_worst_per_world() {
        let w = WorldRuns {
            world: 0,
            runs: vec![
                res(Status::Succeeded, 10.0, 0.4),
                res(Status::Succeeded, 8.0, 0.5),
                res(Status::Collided, 3.0, 0.0),
                res(Status::Succeeded, 12.0, 0.3),
            ],
        };
        // Charged times: 10, 8, 50 (collision), 12. Trim 1 drops 8 and 50.
        let (succ, time, score, coll, to, n) = summarize(std::slice::from_ref(&w), 1);
        assert_eq!((succ, coll, to, n), (100.0, 0.0, 0.0, 2));
        assert!((time - 11.0).abs() < 1e-12 && (score - 0.35).abs() < 1e-12);
        let (succ, time, _, coll, _, n) = summarize(&[w], 0);
        assert_eq!((succ, coll, n), (75.0, 25.0, 4));
        assert!((time - 20.0).abs() < 1e-12);
    }

    /// A policy that observes 4 tracks (746 inputs) runs in an environment with the tracker:
    /// its rows need `--prediction kf`, and they run on a DynaBARN world.
    #[test]
    fn a_policy_that_observes_tracks_runs_with_the_tracker() {
        let cfg = EvalConfig::load(None).unwrap();
        let mut flat = vec![0.0; 746 * 4];
        flat.extend([0.0f32; 4]);
        let plan = |prediction| EvalPlan {
            predictions: vec![prediction],
            ..dwa_plan(
                300,
                vec![Fidelity::Adp],
                Some(MlpPolicy::from_flat(&[746, 4], flat.clone()).unwrap()),
                EnvConfig {
                    observe_tracks: 4,
                    ..EnvConfig::default()
                },
            )
        };
        let worlds = sim::catalog::worlds();
        let err = run(&plan(ObstaclePrediction::Off), &cfg, worlds)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--prediction kf") && err.contains("4 moving tracks"),
            "{err}"
        );
        let rows = run(&plan(ObstaclePrediction::Kf), &cfg, worlds).unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].episodes, 1);
    }

    /// Every row of one evaluation runs the same robot: a policy trained on another profile
    /// is refused with the flag that fixes it; rows report the cost of their fidelity.
    #[test]
    fn policy_rows_run_the_policys_profile_and_rows_report_their_cost() {
        let cfg = EvalConfig::load(None).unwrap();
        assert_eq!(cfg.episode.profile, sim::Profile::GazeboJackal, "the default");
        let mut flat = vec![0.0; 730 * 4];
        flat.extend([0.0f32; 4]);
        let plan = |profile| {
            dwa_plan(
                0,
                vec![Fidelity::Vanilla, Fidelity::Adp],
                Some(MlpPolicy::from_flat(&[730, 4], flat.clone()).unwrap()),
                EnvConfig {
                    profile,
                    ..EnvConfig::default()
                },
            )
        };
        let worlds = sim::catalog::barn_worlds();
        let err = run(&plan(sim::Profile::Ideal), &cfg, worlds)
            .unwrap_err()
            .to_string();
        assert!(err.contains("--profile ideal"), "{err}");
        let rows = run(&plan(sim::Profile::GazeboJackal), &cfg, worlds).unwrap();
        assert_eq!(rows.len(), 2);
        for r in &rows {
            // At least the centre of every rollout step is checked, and planning takes time.
            assert!(r.check_points_per_cycle >= 400.0, "{r:?}");
            assert!(r.plan_ms_per_cycle > 0.0);
        }
    }

    /// A policy with a constant output, run closed-loop, gives the plain driver's result and
    /// cycle count with that action's schedule, for a run that succeeds and one that times out
    /// (on a shortened clock).
    #[test]
    fn closed_loop_constant_policy_equals_the_plain_driver() {
        let cfg = EvalConfig::load(None).unwrap();
        let space = ActionSpace::Decremental;
        let bias = [0.2f32, -0.3, 0.1, -0.6];
        let mut flat = vec![0.0; 730 * 4];
        flat.extend(bias);
        let net = MlpPolicy::from_flat(&[730, 4], flat).unwrap();
        // The policy's output, mapped to the box by the environment's (DDP-centred) map.
        let output: Vec<f64> = bias.iter().map(|b| f64::from(b.tanh())).collect();
        let mut action = vec![0.0; 4];
        EnvConfig::default()
            .action_map
            .map_into(&output, &space.ddp_action(), &mut action);
        let schedule = space
            .schedule(&action, planner::schedule::DEFAULT_BOUNDARY_POINTS)
            .unwrap();
        let mut statuses = Vec::new();
        for (w, timeout_s) in [(1, 100.0), (2, 3.33)] {
            let world = sim::catalog::world(w).unwrap();
            let episode = sim::EpisodeConfig {
                timeout_s,
                ..cfg.episode
            };
            let seed = run_seed(5, w, 0);
            let planner = PlannerKind::Dwa.build(&cfg.planners(), seed);
            let run = Run {
                world,
                episode,
                planner,
                max_speed: 1.5,
                seed,
            };
            let chooser = Chooser::Env {
                space,
                env: &eval_env_config(EnvConfig::default(), cfg.compute),
                act: &mut Greedy::new(&net),
            };
            let out = closed_loop::run(run, chooser, |_| Ok::<(), actor::EnvError>(())).unwrap();
            let closed = (out.episode, out.compute);
            let mut planner = PlannerKind::Dwa.build(&cfg.planners(), seed);
            let plain = planner::run::run_episode(
                world,
                episode,
                planner.as_mut(),
                &schedule,
                1.5,
                seed,
                cfg.compute.resolve("dwa").unwrap(),
                |_, _, _| {},
            );
            assert_eq!(closed, plain, "world {w}");
            statuses.push(plain.0.status);
        }
        assert_eq!(statuses, [Status::Succeeded, Status::TimedOut]);
    }

    /// `--lidar-*` lists make one row per combination, each recording its lidar; the
    /// default condition adds nothing to a row's JSON; a bad value names its flag.
    #[test]
    fn sensing_conditions_make_rows() {
        let combos = LidarOverride::combinations(&[720, 90], &[], &[0.0, 0.1]);
        let got: Vec<_> = combos
            .iter()
            .map(|o| (o.beams, o.noise_fraction, o.dropout))
            .collect();
        assert_eq!(
            got,
            [
                (Some(720), None, Some(0.0)),
                (Some(720), None, Some(0.1)),
                (Some(90), None, Some(0.0)),
                (Some(90), None, Some(0.1))
            ]
        );
        assert_eq!(
            LidarOverride::combinations(&[], &[], &[]),
            [LidarOverride::default()]
        );
        let cfg = EvalConfig::load(None).unwrap();
        let fraction = LidarOverride {
            noise_fraction: Some(0.1),
            ..LidarOverride::default()
        }
        .apply(cfg.episode.lidar)
        .unwrap();
        assert_eq!((fraction.noise_sigma, fraction.noise_fraction), (0.0, 0.1));
        let err = LidarOverride {
            beams: Some(1),
            dropout: Some(0.5),
            ..LidarOverride::default()
        }
        .apply(cfg.episode.lidar)
        .unwrap_err()
        .to_string();
        assert_eq!(
            err,
            "--lidar-beams 1 --lidar-dropout 0.5: lidar.beams = 1 must be at least 2"
        );
        let plan = |lidars: Vec<LidarOverride>| EvalPlan {
            lidars,
            ..dwa_plan(1, vec![Fidelity::Ddp], None, EnvConfig::default())
        };
        let worlds = sim::catalog::barn_worlds();
        let rows = run(
            &plan(LidarOverride::combinations(&[90], &[0.07], &[])),
            &cfg,
            worlds,
        )
        .unwrap();
        let lidar = rows[0].lidar.unwrap();
        assert_eq!(
            (lidar.beams, lidar.noise_sigma, lidar.noise_fraction),
            (90, 0.0, 0.07)
        );
        assert!(
            table(&rows).contains("| 90 beams, noise 7% of mean range |"),
            "{}",
            table(&rows)
        );
        let rows = run(&plan(vec![LidarOverride::default()]), &cfg, worlds).unwrap();
        assert!(rows[0].lidar.is_none());
        let json = serde_json::to_value(&rows[0]).unwrap();
        assert!(json.get("lidar").is_none(), "the default rows' JSON is as before");
        assert!(!table(&rows).contains("lidar"));
    }

    /// PADP's rows run the tracker and their parts of PADP on a DynaBARN world: labelled by
    /// their prediction, only the adaptive one reports its mode shares; a learned policy
    /// cannot run them, and a bad `[prediction]` setting is named.
    #[test]
    fn padp_rows_run_their_parts_and_report_their_modes() {
        let cfg = EvalConfig::load(None).unwrap();
        let plan = EvalPlan {
            planners: vec![PlannerKind::Dwa],
            fidelities: vec![Fidelity::Ddp],
            speeds: vec![1.5],
            worlds: vec![330],
            runs: 1,
            trim: 0,
            seed: 1,
            adp: AdpSetting {
                space: ActionSpace::Decremental,
                action: ActionSpace::Decremental.ddp_action(),
            },
            policy: None,
            policy_env: EnvConfig::default(),
            predictions: vec![
                ObstaclePrediction::Kf,
                ObstaclePrediction::KfRes,
                ObstaclePrediction::PadpPath,
                ObstaclePrediction::Padp,
            ],
            lidars: vec![LidarOverride::default()],
        };
        let rows = run(&plan, &cfg, sim::catalog::worlds()).unwrap();
        let labels: Vec<&str> = rows.iter().map(|r| r.fidelity_label.as_str()).collect();
        assert_eq!(labels, ["ddp+kf", "ddp+kf-res", "ddp+padp-path", "ddp+padp"]);
        assert!(rows[..3].iter().all(|r| r.pressure_modes_pct.is_none()));
        // Every row runs the tracker and measures its forecast.
        for r in &rows {
            let f = r.forecast.expect("a tracker row measures its forecast");
            assert!(f.forecasts[0] > 0 && f.rmse_m[0].unwrap() < 1.0, "{f:?}");
        }
        let shares = rows[3].pressure_modes_pct.expect("padp reports its modes");
        assert!((shares.iter().sum::<f64>() - 100.0).abs() < 1e-9, "{shares:?}");
        assert!(
            table(&rows).contains("| dwa | ddp+padp-path |"),
            "{}",
            table(&rows)
        );
        let json = serde_json::to_value(&rows[2]).unwrap();
        assert_eq!(json["prediction"], "padp-path");
        assert_eq!(serde_json::to_value(&rows[1]).unwrap()["prediction"], "kf-res");
        assert!(json.get("pressure_modes_pct").is_none());
        // A learned policy runs the tracker alone.
        let space = ActionSpace::Decremental;
        let mut flat = vec![0.0; 746 * 4];
        flat.extend([0.0f32; 4]);
        let with_policy = EvalPlan {
            fidelities: vec![Fidelity::Adp],
            policy: Some(MlpPolicy::from_flat(&[746, 4], flat).unwrap()),
            policy_env: EnvConfig {
                observe_tracks: 4,
                ..EnvConfig::default()
            },
            adp: AdpSetting {
                space,
                action: space.ddp_action(),
            },
            predictions: vec![ObstaclePrediction::Padp],
            ..plan.clone()
        };
        let err = run(&with_policy, &cfg, sim::catalog::worlds())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--prediction kf-res, padp-path and padp") && err.contains("use --prediction kf"),
            "{err}"
        );
        // A bad setting of the table is refused with its table and key.
        let dir = std::env::temp_dir().join(format!("adp-padp-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("eval.toml");
        std::fs::write(&file, "[prediction.complexity]\nlow = 0.7\n").unwrap();
        let err = EvalConfig::load(Some(&file)).unwrap_err().to_string();
        assert!(err.contains("[prediction.complexity] low: low 0.7"), "{err}");
        // A corrector file that is not there is named when a kf-res row needs it.
        let missing = dir.join("missing.json");
        std::fs::write(&file, format!("[prediction]\nresidual = {:?}\n", missing)).unwrap();
        let cfg = EvalConfig::load(Some(&file)).unwrap();
        let kf_res = EvalPlan {
            predictions: vec![ObstaclePrediction::KfRes],
            ..plan.clone()
        };
        let err = run(&kf_res, &cfg, sim::catalog::worlds())
            .unwrap_err()
            .to_string();
        assert!(err.contains("missing.json: cannot read"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A trained policy evaluates under any lidar: its observation is built in its own
    /// layout from whatever the sensor gives. A `scan` policy and a `sectors:25` policy each run
    /// on 720-, 360- and 90-beam lidars, noisy and dropping beams; a policy whose input does not
    /// fit its recorded layout is refused by name.
    #[test]
    fn a_policy_runs_under_every_sensing_condition() {
        let cfg = EvalConfig::load(None).unwrap();
        let net = |inputs: usize| {
            let mut flat = vec![0.0; inputs * 4];
            flat.extend([0.2f32, -0.3, 0.1, -0.6]);
            MlpPolicy::from_flat(&[inputs, 4], flat).unwrap()
        };
        let plan = |net: MlpPolicy, observation, lidars| EvalPlan {
            lidars,
            ..dwa_plan(
                1,
                vec![Fidelity::Adp],
                Some(net),
                EnvConfig {
                    observation,
                    ..EnvConfig::default()
                },
            )
        };
        let worlds = sim::catalog::barn_worlds();
        let conditions = [
            LidarOverride::combinations(&[720, 360, 90], &[], &[]),
            LidarOverride::combinations(&[360], &[0.1], &[0.05]),
        ]
        .concat();
        for (inputs, layout) in [(730, LaserLayout::Scan), (35, LaserLayout::Sectors(25))] {
            let rows = run(&plan(net(inputs), layout, conditions.clone()), &cfg, worlds).unwrap();
            let beams: Vec<usize> = rows.iter().map(|r| r.lidar.unwrap().beams).collect();
            assert_eq!(beams, [720, 360, 90, 360], "{layout}");
            assert!(rows.iter().all(|r| r.episodes == 1), "{layout}");
        }
        let err = run(
            &plan(net(730), LaserLayout::Sectors(25), vec![LidarOverride::default()]),
            &cfg,
            worlds,
        )
        .unwrap_err()
        .to_string();
        assert_eq!(
            err,
            "the policy maps 730 observation values to 4 actions; the decremental action space with \
             the sectors:25 laser layout needs 35 to 4"
        );
    }

    #[test]
    fn run_seeds_differ_and_repeat() {
        assert_eq!(run_seed(1, 2, 3), run_seed(1, 2, 3));
        assert_ne!(run_seed(1, 2, 3), run_seed(1, 3, 2));
        assert_ne!(run_seed(1, 2, 3), run_seed(2, 2, 3));
    }
}
