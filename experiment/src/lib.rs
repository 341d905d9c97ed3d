//! Experiments, as a library ([`run`]; the `adp experiment` command is its command line): train S
//! seeds per arm (planner x action space x speed x training worlds x observation layout),
//! evaluate every greedy policy with the papers' protocol against DDP and three controls (the
//! untrained DDP-initialized policy, the best constant schedule found on the training worlds,
//! the state-shuffled policy), optionally sweep compute budgets and lidar conditions, and
//! write `report.md` with paper-style tables, paired statistics and figures.
//!
//! The work is a list of stages ([`plan`]), each writing one result atomically into the store
//! of results under the key of what decides it ([`recipe`], [`store`]), so a stage that any
//! experiment finished is read, not computed again; `--plan` estimates what is left
//! ([`estimate`]). Evaluation runs in parallel over (world, run) on the local cores; training
//! goes through the caller's [`Trainer`] (the `adp` binary's runs `adp train`'s loop with the
//! configured actors). Errors are `anyhow` errors of one line naming the stage, the file or the
//! key; reading an experiment file fails with a typed [`config::ConfigError`].

pub mod adopt;
pub mod config;
pub mod controls;
pub mod estimate;
pub mod figures;
pub mod paper;
pub mod plan;
pub mod protocol;
pub mod recipe;
pub mod record;
pub mod report;
pub mod runner;
pub mod shard;
pub mod slurm;
pub mod spent;
pub mod stats;
pub mod store;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use serde::Serialize;

use actor::closed_loop::{self, Chooser, Greedy};
use planner::{ActionSpace, Schedule};
use sim::World;

use eval::policy::{EvalPolicy, LearnedPolicy};
use eval::EvalConfig;
use eval::{eval_run, run_seed};
use train_config::TrainConfig;

use config::{planner_name, space_label, speed_label, Arm, Experiment, Restrict};
use controls::{
    best_constant, candidates, halving, keep_best, search_pairs, shuffle_pool, write_untrained_export,
    Candidate, SearchResult,
};
use estimate::{progress_line, Rates};
use plan::{pending, stages, write_atomic, SensingPlan, Stage, SweepPlan, SweepWho, Sweeps};
use record::{EvalRecord, Summary};
use report::{comparisons, sensing_results, ArmData, Comparison, SensingResult};
use runner::{evaluate, observations, Controller, RunSpec};
use shard::Shard;
use spent::Spent;
use store::{Layout, StageMeta, Store};

/// The file in an experiment directory holding the experiment file it was started with.
const CONFIG_COPY: &str = "experiment.toml";

/// What an experiment run is asked: the options of `adp experiment`.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// The experiment file.
    pub config: PathBuf,
    /// Experiment directory (default: `runs/experiments/<name>`).
    pub out: Option<PathBuf>,
    /// Continue the experiment in --out, skipping the stages whose results exist.
    pub resume: bool,
    /// The store of results shared by experiments (default: `[experiment] store`, else
    /// `runs/store`). A stage whose result the store holds, whichever experiment computed
    /// it, is read instead of computed.
    pub store: Option<PathBuf>,
    /// List the stages still to compute with their estimated core-hours (from the rates the
    /// store measured), say which the store already holds, and stop.
    pub plan: bool,
    /// Write the report from the results the store holds, computing nothing (a table cell
    /// whose stages are missing shows "–").
    pub report_only: bool,
    /// Run only the stages of these kinds (comma-separated: train, search, ddp, vanilla,
    /// constant, untrained, adp, shuffled, sweep, sensing); the others wait for a later run.
    pub only: Vec<String>,
    /// Adopt finished `adp train` run directories as this experiment's trainings: a run whose
    /// resolved `config.toml` is one of the experiment's trainings (the same recipe) and whose
    /// export holds its steps is copied into the store; the others are named with what differs.
    /// Computes nothing else.
    pub adopt: Vec<PathBuf>,
    /// Command-line restrictions.
    pub restrict: Restrict,
    /// Worker threads of the evaluations (default: all cores).
    pub jobs: Option<usize>,
    /// Evaluate only shard K of N of the test worlds (e.g. 0/8) of every pending
    /// evaluation, into `<stage file>.shard-K-of-N`; a later run without --shard merges a
    /// complete set. Training and constant searches must be finished.
    pub shard: Option<Shard>,
    /// Run only the training and constant-search stages (no evaluation, no report).
    pub no_eval: bool,
    /// Print a SLURM job script that runs this experiment (training, evaluation sharded over
    /// the `[slurm]` tasks, merge and report) and create --out with its experiment.toml.
    pub emit_slurm: bool,
}

/// `rec` as if it had run the first `runs` runs of every world, trimmed by `trim`.
pub fn first_runs(mut rec: EvalRecord, runs: usize, trim: usize) -> anyhow::Result<EvalRecord> {
    if runs > rec.runs {
        bail!("--runs {runs}: the records hold {} runs per world", rec.runs);
    }
    for w in &mut rec.per_world {
        w.runs.truncate(runs);
    }
    rec.runs = runs;
    rec.trim = trim;
    Ok(rec)
}

/// How an experiment trains a seed of an arm: the caller's training loop. The `adp` binary
/// runs `adp train`'s loop in its own process, with the configured actor processes.
///
/// Called from the experiment's thread, one training at a time.
pub trait Trainer: Sync {
    /// Trains the run whose resolved training configuration is the file `config` into
    /// `run_dir`, or with `resume` continues the run there from its checkpoint; returns when
    /// the run ends (finished or stopped). A finished run holds its policy in `run_dir/export`.
    fn train(&self, config: &Path, run_dir: &Path, resume: bool) -> anyhow::Result<()>;
    /// The actor processes a training with `[run] actors = 0` starts: its cores.
    fn actors(&self) -> u32;
}

/// Everything a stage needs.
struct Ctx<'a> {
    ex: &'a Experiment,
    trainer: &'a dyn Trainer,
    layout: Layout,
    cfg: EvalConfig,
    worlds: &'a [World],
    /// The test worlds this process evaluates (a shard's, or all).
    test_worlds: Vec<usize>,
}

/// Whether a stage is an evaluation on the test worlds.
fn is_eval(s: &Stage) -> bool {
    !matches!(s, Stage::Train { .. } | Stage::Search { .. })
}

/// Refuses to go on when `copy` (an experiment directory's `experiment.toml`) is not `text`.
fn same_file(copy: &Path, text: &str, config: &Path, dir: &Path) -> anyhow::Result<()> {
    let before = std::fs::read_to_string(copy).with_context(|| format!("cannot read {}", copy.display()))?;
    if before != text {
        bail!(
            "{} differs from the experiment file {} was started with ({}); finished stages would \
             mix settings: restore it or choose another --out",
            config.display(),
            dir.display(),
            copy.display()
        );
    }
    Ok(())
}

/// Writes `dir`'s `experiment.toml` from `text` (the file `config`), or checks that the one
/// there is `text`.
fn keep_copy(dir: &Path, text: &str, config: &Path) -> anyhow::Result<()> {
    let copy = dir.join(CONFIG_COPY);
    if copy.exists() {
        same_file(&copy, text, config, dir)
    } else {
        write_atomic(&copy, text.as_bytes())
    }
}

/// `--emit-slurm`: creates the experiment directory (its `experiment.toml` and `logs/`) and
/// prints the job script.
fn emit_slurm(ex: &Experiment, text: &str, dir: &Path, store: &Store, args: &Options) -> anyhow::Result<()> {
    let dir = std::path::absolute(dir).with_context(|| format!("cannot resolve {}", dir.display()))?;
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;
    keep_copy(&dir, text, &args.config)?;
    let store =
        std::path::absolute(&store.dir).with_context(|| format!("cannot resolve {}", store.dir.display()))?;
    let mut step_args = slurm::restrict_args(&args.restrict);
    step_args.extend(["--store".to_string(), store.display().to_string()]);
    let adp = if ex.slurm.adp.is_empty() {
        std::env::current_exe().context("cannot find this executable for the job script")?
    } else {
        PathBuf::from(&ex.slurm.adp)
    };
    print!(
        "{}",
        slurm::script(&ex.section.name, &ex.slurm, &dir, &adp, &step_args)
    );
    Ok(())
}

/// Runs the experiment; returns the path of its report (`None` when this process does not
/// write one: `--emit-slurm`, `--shard`, `--no-eval`).
pub fn run(args: &Options, trainer: &dyn Trainer) -> anyhow::Result<Option<PathBuf>> {
    let ex = Experiment::load(&args.config, &args.restrict)?;
    let text = std::fs::read_to_string(&args.config)
        .with_context(|| format!("cannot read {}", args.config.display()))?;
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs/experiments").join(&ex.section.name));
    let store = Store {
        dir: args
            .store
            .clone()
            .or_else(|| ex.section.store.clone())
            .unwrap_or_else(|| PathBuf::from("runs/store")),
    };
    if args.emit_slurm {
        return emit_slurm(&ex, &text, &dir, &store, args).map(|()| None);
    }
    let cfg = eval_config(&ex)?;
    let layout = Layout::new(dir.clone(), store, &ex, &cfg, trainer.actors());
    if args.plan {
        print_plan(&ex, &layout, &args.config, &args.only, trainer.actors());
        return Ok(None);
    }
    if args.report_only || !args.adopt.is_empty() {
        keep_copy(&dir, &text, &args.config)?;
    } else {
        claim_dir(args, &dir, &text)?;
    }
    let ctx = Ctx {
        ex: &ex,
        trainer,
        layout,
        cfg,
        worlds: sim::catalog::worlds(),
        test_worlds: args
            .shard
            .map_or_else(|| ex.test_worlds.clone(), |s| s.worlds(&ex.test_worlds)),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.jobs.unwrap_or(0))
        .build()
        .context("cannot start worker threads")?;
    if !args.adopt.is_empty() {
        let n = adopt::adopt(&ctx, &args.adopt, trainer.actors())?;
        tracing::info!("adopted {n} of {} run(s)", args.adopt.len());
        return Ok(None);
    }
    if args.report_only {
        let report = pool.install(|| write_report(&ctx))?;
        tracing::info!("report: {}", report.display());
        return Ok(Some(report));
    }
    let all = stages(&ex.arms, ex.seeds, &sweeps(&ex));
    let todo: Vec<Stage> = pending(&all, |s| ctx.layout.done(s))
        .into_iter()
        .filter(|s| args.only.is_empty() || args.only.iter().any(|k| k == stage_kind(s)))
        .collect();
    tracing::info!(
        "adp experiment {}: {} arm(s) x {} seed(s), {} stage(s), {} in the store, {} to run; \
         report in {}, results in the store {}",
        ex.section.name,
        ex.arms.len(),
        ex.seeds,
        all.len(),
        all.iter().filter(|s| ctx.layout.done(s)).count(),
        todo.len(),
        dir.display(),
        ctx.layout.store.dir.display()
    );
    if let (Some(sh), Some(first)) = (args.shard, todo.iter().find(|s| !is_eval(s))) {
        bail!(
            "--shard {}/{}: `{}` has not run yet; run the experiment with --no-eval first",
            sh.index,
            sh.count,
            describe(first, &ex.arms)
        );
    }
    run_stages(&ctx, args, &pool, &todo)?;
    if args.no_eval || args.shard.is_some() {
        return Ok(None);
    }
    let report = pool.install(|| write_report(&ctx))?;
    tracing::info!("report: {}", report.display());
    Ok(Some(report))
}

/// Starts the experiment in `dir` (writes its `experiment.toml`), or with `--resume` or
/// `--shard` continues the one there, which must have been started with `text`.
fn claim_dir(args: &Options, dir: &Path, text: &str) -> anyhow::Result<()> {
    let copy = dir.join(CONFIG_COPY);
    match (copy.exists(), args.resume || args.shard.is_some()) {
        (true, false) => bail!(
            "{} already holds an experiment: pass --resume to continue it or choose another --out",
            dir.display()
        ),
        (false, true) => bail!(
            "--resume: {} holds no experiment ({CONFIG_COPY} is missing)",
            dir.display()
        ),
        (true, true) => {
            let before =
                std::fs::read_to_string(&copy).with_context(|| format!("cannot read {}", copy.display()))?;
            if before != text {
                bail!(
                    "--resume: {} differs from the experiment file {} was started with ({}); \
                     finished stages would mix settings: restore it or choose another --out",
                    args.config.display(),
                    dir.display(),
                    copy.display()
                );
            }
        }
        (false, false) => write_atomic(&copy, text.as_bytes())?,
    }
    Ok(())
}

/// The evaluation configuration of `ex`: `[eval] config` on the training environment's
/// simulator profile, dynamics and compute model, with `[eval]`'s start jitter.
fn eval_config(ex: &Experiment) -> anyhow::Result<EvalConfig> {
    let mut cfg = EvalConfig::load(ex.eval.config.as_deref().map(Path::new))?;
    cfg.episode = cfg
        .episode
        .with_profile(ex.train.env.profile, ex.train.env.dynamics);
    // Every controller runs on the computer the policies train for.
    cfg.compute = ex.train.env.compute;
    cfg.episode.start_jitter_m = ex.eval.start_jitter_m;
    cfg.episode.start_jitter_yaw_rad = ex.eval.start_jitter_yaw_rad;
    cfg.episode
        .validate()
        .map_err(|e| anyhow::anyhow!("[eval] with [train.env] profile: {e}"))?;
    Ok(cfg)
}

/// Runs the pending stages `todo` in order (training outside `pool`, the others in it):
/// with `--no-eval` no evaluation, with `--shard` this shard's part of each evaluation, and
/// without it an evaluation whose shards are all there is merged instead of run.
fn run_stages(ctx: &Ctx<'_>, args: &Options, pool: &rayon::ThreadPool, todo: &[Stage]) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let rates = Rates::measured(&ctx.layout.store.all_meta());
    let estimates: Vec<f64> = todo.iter().map(|s| rates.cost(ex, s).0).collect();
    let started = Instant::now();
    let threads = pool.current_num_threads();
    // The estimates of the stages this run computed: the rate of progress. A stage skipped
    // (in the store, waiting for its policy, left to another shard) counts on neither side.
    let mut worked_est = 0.0;
    for (i, stage) in todo.iter().enumerate() {
        let t0 = Instant::now();
        let step = format!("[{}/{}]", i + 1, todo.len());
        let out = ctx.layout.output(stage);
        if i > 0 {
            tracing::info!(
                "{}{}",
                progress_line(
                    i,
                    todo.len(),
                    worked_est,
                    estimates[i..].iter().sum(),
                    started.elapsed().as_secs_f64(),
                    threads
                ),
                eta_clock(
                    worked_est,
                    estimates[i..].iter().sum(),
                    started.elapsed().as_secs_f64()
                )
            );
        }
        if out.exists() {
            // Another experiment sharing the store finished it meanwhile.
            tracing::info!("{step} {}: in the store", describe(stage, &ex.arms));
            continue;
        }
        if let Some((arm, seed)) = policy_of(stage) {
            if !ctx.layout.done(&Stage::Train { arm, seed }) {
                // Only with --only or a training that failed: the policy is not there yet.
                tracing::warn!(
                    "{step} {}: waits for `{}`",
                    describe(stage, &ex.arms),
                    describe(&Stage::Train { arm, seed }, &ex.arms)
                );
                continue;
            }
        }
        if is_eval(stage) {
            if args.no_eval {
                continue;
            }
            if let Some(sh) = args.shard {
                let file = sh.file(&out);
                if file.exists() {
                    tracing::info!(
                        "{step} shard {}/{} of `{}` exists",
                        sh.index,
                        sh.count,
                        describe(stage, &ex.arms)
                    );
                    continue;
                }
                tracing::info!(
                    "{step} {} (shard {}/{})",
                    describe(stage, &ex.arms),
                    sh.index,
                    sh.count
                );
                pool.install(|| run_stage(ctx, stage, &file))?;
                worked_est += estimates[i];
                tracing::info!("{step} done in {:.0} s", t0.elapsed().as_secs_f64());
                continue;
            }
            if let Some(files) = shard::complete_set(&out) {
                let records = files
                    .iter()
                    .map(|f| EvalRecord::load(f))
                    .collect::<anyhow::Result<Vec<_>>>()?;
                shard::merge(records, &ex.test_worlds)
                    .with_context(|| format!("merging the shards of {}", out.display()))?
                    .save(&out)?;
                // Merged from shards computed elsewhere: no time of its own to record.
                record_meta(ctx, stage, (0.0, None, None), threads)?;
                tracing::info!(
                    "{step} {}: merged {} shards",
                    describe(stage, &ex.arms),
                    files.len()
                );
                continue;
            }
        }
        tracing::info!("{step} {}", describe(stage, &ex.arms));
        let cpu0 = cpu_seconds();
        let (used, trained) = match stage {
            Stage::Train { arm, seed } => (ctx.trainer.actors() as usize, Some(train(ctx, *arm, *seed)?)),
            _ => {
                pool.install(|| run_stage(ctx, stage, &out))?;
                (threads, None)
            }
        };
        let seconds = t0.elapsed().as_secs_f64();
        let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
        // A training's time is that of every run that worked on it.
        let (total, total_cpu, timed) = match trained {
            Some((spent, timed)) => (spent.seconds, spent.cpu_s, timed),
            None => (seconds, cpu, None),
        };
        record_meta(ctx, stage, (total, total_cpu, timed), used)?;
        worked_est += estimates[i];
        tracing::info!("{step} done in {seconds:.0} s");
    }
    Ok(())
}

/// CPU seconds (user and system) used so far by this process and by the child processes it
/// has waited for (a training's actors and learner threads); `None` where the system does not
/// say.
fn cpu_seconds() -> Option<f64> {
    let used = |who| {
        // SAFETY: getrusage writes one rusage into the zeroed struct it is given.
        let mut r: libc::rusage = unsafe { std::mem::zeroed() };
        (unsafe { libc::getrusage(who, &mut r) } == 0).then(|| {
            let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
            t(r.ru_utime) + t(r.ru_stime)
        })
    };
    Some(used(libc::RUSAGE_SELF)? + used(libc::RUSAGE_CHILDREN)?)
}

/// The wall-clock time (UTC) at which the remaining stages should finish, as ` (ETA HH:MM
/// UTC)`, from how long the finished ones took against their estimate.
fn eta_clock(done_est: f64, left_est: f64, elapsed_s: f64) -> String {
    if done_est <= 0.0 || elapsed_s <= 0.0 {
        return String::new();
    }
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64());
    let at = (now + left_est * elapsed_s / done_est) as u64 % 86_400;
    format!(" (ETA {:02}:{:02} UTC)", at / 3600, at % 3600 / 60)
}

/// Records in the store how `stage` was computed: by this experiment, on `threads` cores,
/// in `(seconds, cpu_s, timed_units)` ([`StageMeta`]'s fields of those names).
fn record_meta(
    ctx: &Ctx<'_>,
    stage: &Stage,
    (seconds, cpu_s, timed_units): (f64, Option<f64>, Option<f64>),
    threads: usize,
) -> anyhow::Result<()> {
    let recipe = ctx.layout.recipe(stage);
    let (units, class) = estimate::units(ctx.ex, stage);
    let meta = StageMeta {
        description: describe(stage, &ctx.ex.arms),
        experiment: ctx.ex.section.name.clone(),
        class,
        units,
        seconds,
        threads,
        cpu_s,
        timed_units,
        finished_unix_s: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs()),
        recipe: serde_json::to_value(&recipe).expect("recipes serialize"),
    };
    ctx.layout.store.write_meta(&recipe, &meta)
}

/// `--plan`: every stage still to compute with its estimated core-hours, and what the store
/// already holds.
fn print_plan(ex: &Experiment, layout: &Layout, config: &Path, only: &[String], cores: u32) {
    let all: Vec<Stage> = stages(&ex.arms, ex.seeds, &sweeps(ex))
        .into_iter()
        .filter(|s| only.is_empty() || only.iter().any(|k| k == stage_kind(s)))
        .collect();
    let rates = Rates::measured(&layout.store.all_meta());
    let mut held: std::collections::BTreeMap<String, usize> = Default::default();
    let mut todo = Vec::new();
    for s in &all {
        if layout.done(s) {
            let by = layout
                .store
                .meta(&layout.recipe(s))
                .map_or_else(|| "an unrecorded run".to_string(), |m| m.experiment);
            *held.entry(by).or_default() += 1;
        } else {
            todo.push(s.clone());
        }
    }
    println!(
        "adp experiment --config {}: {} arm(s) x {} seed(s), {} stage(s); store {}",
        config.display(),
        ex.arms.len(),
        ex.seeds,
        all.len(),
        layout.store.dir.display()
    );
    let in_store = all.len() - todo.len();
    if in_store > 0 {
        let by: Vec<String> = held.iter().map(|(e, n)| format!("{n} by {e}")).collect();
        println!("already in the store: {in_store} stage(s) ({})", by.join(", "));
    }
    if todo.is_empty() {
        println!("nothing left to compute");
        return;
    }
    println!("\nto compute: {} stage(s)", todo.len());
    println!("| stage | units | core-s per unit | est. core-h |");
    println!("|---|---:|---:|---:|");
    let mut total = 0.0;
    let mut defaults = 0;
    for s in &todo {
        let (units, class) = estimate::units(ex, s);
        let (rate, measured) = rates.rate(&class);
        defaults += usize::from(!measured);
        total += units * rate;
        println!(
            "| {} | {units:.0} | {rate:.3}{} | {:.2} |",
            describe(s, &ex.arms),
            if measured { "" } else { " (default)" },
            units * rate / 3600.0
        );
    }
    let cores = cores.max(1) as f64;
    println!(
        "\ntotal: {:.1} core-h, about {:.1} h on this machine's {cores:.0} core(s)",
        total / 3600.0,
        total / 3600.0 / cores
    );
    if defaults > 0 {
        println!(
            "{defaults} estimate(s) use a default rate: the store has measured no stage of their \
             class yet (units: agent steps of a training, episodes otherwise)"
        );
    }
}

/// The trained policy (arm, seed) a stage evaluates, if any.
fn policy_of(stage: &Stage) -> Option<(usize, usize)> {
    match *stage {
        Stage::EvalAdp { arm, seed }
        | Stage::EvalShuffled { arm, seed }
        | Stage::Sweep {
            arm,
            who: SweepWho::Adp { seed },
            ..
        }
        | Stage::Sensing {
            arm,
            who: SweepWho::Adp { seed },
            ..
        } => Some((arm, seed)),
        _ => None,
    }
}

/// A stage's kind, as `--only` names it.
fn stage_kind(stage: &Stage) -> &'static str {
    match stage {
        Stage::Train { .. } => "train",
        Stage::Search { .. } => "search",
        Stage::EvalDdp { .. } => "ddp",
        Stage::EvalVanilla { .. } => "vanilla",
        Stage::EvalConstant { .. } => "constant",
        Stage::EvalUntrained { .. } => "untrained",
        Stage::EvalAdp { .. } => "adp",
        Stage::EvalShuffled { .. } => "shuffled",
        Stage::Sweep { .. } => "sweep",
        Stage::Sensing { .. } => "sensing",
    }
}

/// A stage in words.
fn describe(stage: &Stage, arms: &[Arm]) -> String {
    match *stage {
        Stage::Train { arm, seed } => format!("train {} seed {seed}", arms[arm].id()),
        Stage::Search { arm } => format!(
            "search the best constant of {} on the training worlds",
            arms[arm].id()
        ),
        Stage::EvalDdp { planner, speed } => {
            format!(
                "evaluate DDP ({} at {} m/s)",
                planner_name(planner),
                speed_label(speed)
            )
        }
        Stage::EvalVanilla { planner, speed } => format!(
            "evaluate vanilla ({} at {} m/s)",
            planner_name(planner),
            speed_label(speed)
        ),
        Stage::EvalConstant { arm } => format!("evaluate the best constant of {}", arms[arm].id()),
        Stage::EvalUntrained { arm } => format!("evaluate the untrained policy of {}", arms[arm].id()),
        Stage::EvalAdp { arm, seed } => format!("evaluate {} seed {seed}", arms[arm].id()),
        Stage::EvalShuffled { arm, seed } => {
            format!("evaluate the state-shuffled {} seed {seed}", arms[arm].id())
        }
        Stage::Sweep { arm, point, who } => {
            format!("budget sweep point {point} of {}: {who:?}", arms[arm].id())
        }
        Stage::Sensing { arm, condition, who } => {
            format!("sensing condition {condition} of {}: {who:?}", arms[arm].id())
        }
    }
}

/// The budget sweep of `ex`, if it has one.
fn sweep_plan(ex: &Experiment) -> Option<SweepPlan> {
    let points = ex.sweep_points().len();
    (points > 0).then_some(SweepPlan {
        arm: ex.sweep.arm,
        points,
    })
}

/// The sensing sweep of `ex`, if it has one.
fn sensing_plan(ex: &Experiment) -> Option<SensingPlan> {
    let conditions = ex.sensing_conditions().len();
    (conditions > 0).then(|| SensingPlan {
        arms: ex.sensing_arms(),
        conditions,
    })
}

/// The sweeps of `ex`.
fn sweeps(ex: &Experiment) -> Sweeps {
    let shuffled_speeds = &ex.shuffle.speeds;
    Sweeps {
        vanilla: ex.eval.vanilla,
        unshuffled: (0..ex.arms.len())
            .filter(|&i| {
                !shuffled_speeds.is_empty()
                    && !shuffled_speeds
                        .iter()
                        .any(|v| (v - ex.arms[i].speed).abs() < 1e-9)
            })
            .collect(),
        budget: sweep_plan(ex),
        sensing: sensing_plan(ex),
    }
}

/// The best constant action of arm `arm`, from its search's file.
fn best_action(ctx: &Ctx<'_>, arm: usize) -> anyhow::Result<Vec<f64>> {
    let search_file = ctx.layout.output(&Stage::Search { arm });
    let text = std::fs::read_to_string(&search_file)
        .with_context(|| format!("cannot read {}", search_file.display()))?;
    let search: SearchResult = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a search result", search_file.display()))?;
    Ok(search.candidates[search.best].action.clone())
}

/// Whether a run directory has a checkpoint to resume from.
fn has_checkpoint(run_dir: &Path) -> bool {
    std::fs::read_dir(run_dir.join("checkpoints")).is_ok_and(|entries| {
        entries
            .flatten()
            .any(|e| !e.file_name().to_string_lossy().contains("tmp"))
    })
}

/// The marker of a finished training run.
#[derive(Serialize)]
struct Trained {
    arm: String,
    seed_index: usize,
    td3_seed: u64,
    steps: u64,
    agent_steps: u64,
    updates: u64,
    export: PathBuf,
}

/// Trains one seed of one arm with `adp train` in its run directory (resuming a run that
/// stopped), then checks its export and writes the marker. Returns the time of every run
/// that worked on it ([`Spent`]) and, when some run's time is missing, the agent steps that
/// time covers ([`spent::timed_units`]). A run that stops before the end adds its time to the
/// run directory's account and fails, saying to resume.
fn train(ctx: &Ctx<'_>, arm: usize, seed: usize) -> anyhow::Result<(Spent, Option<f64>)> {
    let a = &ctx.ex.arms[arm];
    let cfg = run_train_config(ctx, arm, seed)?;
    let run_dir = ctx.layout.run_dir(arm, seed);
    let file = run_dir.join("experiment-train.toml");
    write_atomic(
        &file,
        toml::to_string_pretty(&cfg)
            .expect("configs serialize")
            .as_bytes(),
    )?;
    let resume = has_checkpoint(&run_dir);
    // The steps this run starts from; `None` when the checkpoint cannot be read here (the
    // trainer then says why, or this run's steps go untimed).
    let resumed_from = if resume {
        checkpoint_steps(&run_dir)
    } else {
        Some(0.0)
    };
    let before = Spent::load(&run_dir).unwrap_or_else(|e| {
        tracing::warn!("{e:#}; timing this training from this run on");
        Spent::default()
    });
    let (t0, cpu0) = (Instant::now(), cpu_seconds());
    ctx.trainer
        .train(&file, &run_dir, resume)
        .with_context(|| format!("training {} seed {seed} in {}", a.id(), run_dir.display()))?;
    let seconds = t0.elapsed().as_secs_f64();
    let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
    let export = run_dir.join("export");
    let policy = load_policy(&export, a.space)?;
    // The run's steps: its final checkpoint's (with `[greedy] select` the export may be an
    // earlier policy, whose card counts its own steps).
    let inserts = checkpoint_steps(&run_dir).map_or(policy.card.source.inserts, |s| s as u64);
    let this_run = resumed_from.map_or(0.0, |from| (inserts as f64 - from).max(0.0));
    let spent = before.plus(seconds, cpu, this_run);
    if inserts < cfg.run.steps {
        if let Err(e) = spent.save(&run_dir) {
            tracing::warn!("{e:#}: this run's time will be missing from the training's record");
        }
        bail!(
            "training {} seed {seed} stopped after {} of {} agent steps; run the experiment again \
             with --resume to continue it",
            a.id(),
            inserts,
            cfg.run.steps
        );
    }
    let timed = spent::timed_units(&before, resumed_from.unwrap_or(f64::INFINITY), this_run);
    write_trained(ctx, arm, seed, &cfg, &policy, export)?;
    Ok((spent, timed))
}

/// The training configuration of arm `arm`'s seed `seed` as it runs:
/// [`Experiment::train_config`], and for an arm that starts from its best constant
/// ([`config::Start::BestConstant`]) that action, read from its constant search's result, as
/// `[service] init_action`.
fn run_train_config(ctx: &Ctx<'_>, arm: usize, seed: usize) -> anyhow::Result<TrainConfig> {
    let a = &ctx.ex.arms[arm];
    let mut cfg = ctx.ex.train_config(a, seed);
    if a.start == config::Start::BestConstant {
        let action = best_action(ctx, arm).with_context(|| {
            format!(
                "{} starts from its best constant: its constant search must be in the store first",
                a.id()
            )
        })?;
        cfg.service.init_action = Some(action);
    }
    Ok(cfg)
}

/// The agent steps of the newest checkpoint of `run_dir` (where a resumed run starts).
fn checkpoint_steps(run_dir: &Path) -> Option<f64> {
    let dir = learner::retention::latest(&run_dir.join("checkpoints")).ok()??;
    Some(learner::checkpoint::read_manifest(&dir).ok()?.inserts as f64)
}

/// Writes the marker of arm `arm`'s finished training `seed` (configuration `cfg`, exported
/// `policy` in `export`): the stage's result.
fn write_trained(
    ctx: &Ctx<'_>,
    arm: usize,
    seed: usize,
    cfg: &TrainConfig,
    policy: &LearnedPolicy,
    export: PathBuf,
) -> anyhow::Result<()> {
    let src = &policy.card.source;
    let marker = Trained {
        arm: ctx.ex.arms[arm].id(),
        seed_index: seed,
        td3_seed: cfg.td3.seed,
        steps: cfg.run.steps,
        agent_steps: src.inserts,
        updates: src.updates,
        export,
    };
    write_atomic(
        &ctx.layout.output(&Stage::Train { arm, seed }),
        &serde_json::to_vec_pretty(&marker).expect("serializes"),
    )
}

/// The trained (or untrained) policy of an export directory, in `space`.
fn load_policy(dir: &Path, space: ActionSpace) -> anyhow::Result<LearnedPolicy> {
    match eval::policy::load(dir, Some(space))? {
        EvalPolicy::Learned(p) => Ok(*p),
        EvalPolicy::Constant { .. } => bail!("{}: not an export directory", dir.display()),
    }
}

/// The run settings of an arm on the test worlds.
fn test_spec<'a>(ctx: &'a Ctx<'_>, a: &Arm, trace: bool) -> RunSpec<'a> {
    RunSpec {
        cfg: &ctx.cfg,
        worlds: ctx.worlds,
        planner: a.planner,
        speed: a.speed,
        world_ids: &ctx.test_worlds,
        runs: ctx.ex.eval.runs,
        pairs: &[],
        seed: ctx.ex.eval.seed,
        trace,
        track: ctx.ex.train.env.observe_tracks > 0,
    }
}

/// A record of `ev` for arm `a`.
fn record(ctx: &Ctx<'_>, a: &Arm, controller: &str, ev: runner::Evaluation) -> EvalRecord {
    EvalRecord {
        controller: controller.into(),
        planner: planner_name(a.planner),
        space: (controller != "ddp").then(|| space_label(a.space)),
        speed: a.speed,
        seed_index: None,
        action: None,
        policy: None,
        runs: ctx.ex.eval.runs,
        trim: ctx.ex.eval.trim,
        seed: ctx.ex.eval.seed,
        per_world: ev.per_world,
        trace: ev.trace,
        compute: ev.compute,
        lidar: None,
    }
}

/// Runs an evaluation or search stage and writes its result to `out`.
fn run_stage(ctx: &Ctx<'_>, stage: &Stage, out: &Path) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let points = planner::schedule::DEFAULT_BOUNDARY_POINTS;
    match *stage {
        Stage::Train { .. } => unreachable!("training runs outside the pool"),
        Stage::Search { arm } => search_stage(ctx, arm, out),
        Stage::EvalDdp { planner, speed } | Stage::EvalVanilla { planner, speed } => {
            let a = ex
                .arms
                .iter()
                .find(|a| a.planner == planner && a.speed == speed)
                .expect("a DDP or vanilla stage comes from an arm");
            let (name, schedule) = match stage {
                Stage::EvalDdp { .. } => ("ddp", Schedule::ddp_default()),
                _ => ("vanilla", Schedule::vanilla()),
            };
            let ev = evaluate(&test_spec(ctx, a, false), &Controller::Schedule(schedule))?;
            record(ctx, a, name, ev).save(out)
        }
        Stage::Sweep { arm, point, who } => sweep_stage(ctx, arm, point, who, out),
        Stage::Sensing { arm, condition, who } => sensing_stage(ctx, arm, condition, who, out),
        Stage::EvalConstant { arm } => {
            let a = &ex.arms[arm];
            let action = best_action(ctx, arm)?;
            let ev = evaluate(
                &test_spec(ctx, a, false),
                &Controller::constant(a.space, &action, points, ctx.ex.train.env)?,
            )?;
            let mut rec = record(ctx, a, "constant", ev);
            rec.action = Some(action);
            rec.save(out)
        }
        Stage::EvalUntrained { arm } => {
            let a = &ex.arms[arm];
            let dir = ctx.layout.untrained_export(arm);
            if !dir.join(learner::export::JSON_FILE).exists() {
                write_untrained_export(&run_train_config(ctx, arm, 0)?, a.space, &dir)?;
            }
            let p = load_policy(&dir, a.space)?;
            let ctrl = Controller::of(&p);
            let mut rec = record(ctx, a, "untrained", evaluate(&test_spec(ctx, a, false), &ctrl)?);
            rec.policy = Some(dir.display().to_string());
            rec.save(out)
        }
        Stage::EvalAdp { arm, seed } | Stage::EvalShuffled { arm, seed } => {
            let a = &ex.arms[arm];
            let dir = ctx.layout.run_dir(arm, seed).join("export");
            let p = load_policy(&dir, a.space)?;
            let policy = Controller::of(&p);
            let (name, ev) = if matches!(stage, Stage::EvalAdp { .. }) {
                ("adp", evaluate(&test_spec(ctx, a, true), &policy)?)
            } else {
                let pool = shuffle_observations(ctx, a, &p)?;
                let ctrl = Controller::Shuffled {
                    net: &p.net,
                    env: p.env,
                    space: p.space,
                    pool: &pool,
                    seed: ex.shuffle.seed,
                };
                ("shuffled", evaluate(&test_spec(ctx, a, false), &ctrl)?)
            };
            let mut rec = record(ctx, a, name, ev);
            rec.seed_index = Some(seed);
            rec.policy = Some(dir.display().to_string());
            rec.save(out)
        }
    }
}

/// The constant search of arm `arm`: successive halving of the candidate constant actions
/// over (world, run) pairs of the constant-search worlds; writes the [`SearchResult`] to
/// `out`.
fn search_stage(ctx: &Ctx<'_>, arm: usize, out: &Path) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let points = planner::schedule::DEFAULT_BOUNDARY_POINTS;
    let a = &ex.arms[arm];
    let s = &ex.search;
    let mut found = candidates(a.space, s.candidates, s.seed)
        .into_iter()
        .map(|action| {
            Ok(Candidate {
                params: a.space.to_params(&action)?,
                action,
                score: 0.0,
                success_pct: 0.0,
                pairs: 0,
                compute_ms_per_cycle: 0.0,
                compute: Default::default(),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    // Successive halving over (world, run) pairs shared by every candidate, so the
    // candidates pair by seed at every rung.
    let pairs = search_pairs(&ex.search_worlds, s.runs, s.seed);
    let rungs = halving(found.len(), s.eta, s.first_pairs, pairs.len());
    let mut sums = vec![(0.0, 0usize); found.len()];
    let mut alive: Vec<usize> = (0..found.len()).collect();
    let mut done = 0;
    for (k, &(keep, upto)) in rungs.iter().enumerate() {
        alive = keep_best(&found, &alive, keep);
        for &i in &alive {
            let spec = RunSpec {
                cfg: &ctx.cfg,
                worlds: ctx.worlds,
                planner: a.planner,
                speed: a.speed,
                world_ids: &[],
                runs: 0,
                pairs: &pairs[done..upto],
                seed: s.seed,
                trace: false,
                track: ctx.ex.train.env.observe_tracks > 0,
            };
            let ctrl = Controller::constant(a.space, &found[i].action, points, ctx.ex.train.env)?;
            let ev = evaluate(&spec, &ctrl)?;
            let c = &mut found[i];
            for r in ev.per_world.iter().flat_map(|w| w.runs.iter()) {
                sums[i].0 += r.score;
                sums[i].1 += usize::from(r.status == sim::Status::Succeeded);
            }
            c.pairs = upto;
            c.score = sums[i].0 / upto as f64;
            c.success_pct = 100.0 * sums[i].1 as f64 / upto as f64;
            c.compute += ev.compute;
            c.compute_ms_per_cycle = c.compute.ms_per_cycle();
        }
        let top = &found[keep_best(&found, &alive, 1)[0]];
        tracing::info!(
            "  rung {k}: {} candidates x {upto} (world, run) pairs; best score {:.4}, success \
             {:.1} %, {:.1} ms per cycle",
            alive.len(),
            top.score,
            top.success_pct,
            top.compute_ms_per_cycle
        );
        done = upto;
    }
    let result = SearchResult {
        space: a.space,
        worlds: ex.search_worlds.clone(),
        runs: s.runs,
        rungs,
        best: best_constant(&found),
        candidates: found,
    };
    write_atomic(out, &serde_json::to_vec_pretty(&result).expect("serializes"))
}

/// One controller (`who`) of arm `arm` at budget-sweep point `point` on the test worlds;
/// writes its record to `out`.
fn sweep_stage(ctx: &Ctx<'_>, arm: usize, point: usize, who: SweepWho, out: &Path) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let mut cfg = ctx.cfg.clone();
    cfg.compute = ex.sweep_points()[point];
    sweep_record(ctx, arm, who, &cfg, (ex.sweep.runs, ex.sweep.trim))?.save(out)
}

/// One controller (`who`) of arm `arm` under sensing condition `condition` on the test
/// worlds (the condition replaces the evaluation's lidar, so the planner's costmap and the
/// policy's observation both see its scans); writes its record, with the lidar, to `out`.
fn sensing_stage(
    ctx: &Ctx<'_>,
    arm: usize,
    condition: usize,
    who: SweepWho,
    out: &Path,
) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let mut cfg = ctx.cfg.clone();
    cfg.episode.lidar = sensing_lidar(ctx, condition)?;
    let mut rec = sweep_record(ctx, arm, who, &cfg, (ex.sensing.runs, ex.sensing.trim))?;
    rec.lidar = Some(cfg.episode.lidar);
    rec.save(out)
}

/// The lidar of sensing condition `condition`: the evaluation configuration's with the
/// condition's values.
fn sensing_lidar(ctx: &Ctx<'_>, condition: usize) -> anyhow::Result<sim::lidar::LidarConfig> {
    ctx.ex.sensing_conditions()[condition]
        .apply(ctx.cfg.episode.lidar)
        .with_context(|| format!("[sensing_sweep] condition {condition}"))
}

/// The record of one controller (`who`) of arm `arm` of a sweep on the test worlds, run
/// with `cfg` and `(runs, trim)`; every controller's run r of world w has the same seed.
fn sweep_record(
    ctx: &Ctx<'_>,
    arm: usize,
    who: SweepWho,
    cfg: &EvalConfig,
    (runs, trim): (usize, usize),
) -> anyhow::Result<EvalRecord> {
    let points = planner::schedule::DEFAULT_BOUNDARY_POINTS;
    let a = &ctx.ex.arms[arm];
    let spec = RunSpec {
        cfg,
        runs,
        ..test_spec(ctx, a, false)
    };
    let (name, ev, action, policy) = match who {
        SweepWho::Ddp => (
            "ddp",
            evaluate(&spec, &Controller::Schedule(Schedule::ddp_default()))?,
            None,
            None,
        ),
        SweepWho::Constant => {
            let action = best_action(ctx, arm)?;
            let ctrl = Controller::constant(a.space, &action, points, ctx.ex.train.env)?;
            ("constant", evaluate(&spec, &ctrl)?, Some(action), None)
        }
        SweepWho::Adp { seed } => {
            let dir = ctx.layout.run_dir(arm, seed).join("export");
            let p = load_policy(&dir, a.space)?;
            let ctrl = Controller::of(&p);
            (
                "adp",
                evaluate(&spec, &ctrl)?,
                None,
                Some(dir.display().to_string()),
            )
        }
    };
    let mut rec = record(ctx, a, name, ev);
    rec.runs = runs;
    rec.trim = trim;
    rec.action = action;
    rec.policy = policy;
    if let SweepWho::Adp { seed } = who {
        rec.seed_index = Some(seed);
    }
    Ok(rec)
}

/// The observation pool of the state-shuffled control: the policy's own observations on the
/// pool worlds (training worlds, one run each), reservoir-sampled.
fn shuffle_observations(ctx: &Ctx<'_>, a: &Arm, p: &LearnedPolicy) -> anyhow::Result<Vec<Vec<f32>>> {
    let spec = RunSpec {
        cfg: &ctx.cfg,
        worlds: ctx.worlds,
        planner: a.planner,
        speed: a.speed,
        world_ids: &ctx.ex.pool_worlds,
        runs: 1,
        pairs: &[],
        seed: ctx.ex.shuffle.seed,
        trace: false,
        track: ctx.ex.train.env.observe_tracks > 0,
    };
    let ctrl = Controller::of(p);
    let seen = observations(&spec, &ctrl)?.observations;
    Ok(shuffle_pool(&seen, ctx.ex.shuffle.pool, ctx.ex.shuffle.seed))
}

/// Reads what the stages of arm `arm` wrote (a missing file is a stage not run yet).
fn arm_data(ctx: &Ctx<'_>, arm: usize) -> anyhow::Result<ArmData> {
    let ex = ctx.ex;
    let a = &ex.arms[arm];
    let read = |stage: Stage| -> anyhow::Result<Option<EvalRecord>> {
        let path = ctx.layout.output(&stage);
        if path.exists() {
            EvalRecord::load(&path).map(Some)
        } else {
            Ok(None)
        }
    };
    let search_file = ctx.layout.output(&Stage::Search { arm });
    let search = if search_file.exists() {
        let text = std::fs::read_to_string(&search_file)?;
        Some(
            serde_json::from_str(&text)
                .with_context(|| format!("{}: not a search result", search_file.display()))?,
        )
    } else {
        None
    };
    let mut adp = Vec::new();
    let mut shuffled = Vec::new();
    for seed in 0..ex.seeds {
        adp.extend(read(Stage::EvalAdp { arm, seed })?);
        shuffled.extend(read(Stage::EvalShuffled { arm, seed })?);
    }
    let mut sweep = Vec::new();
    if sweep_plan(ex).is_some_and(|s| s.arm == arm) {
        for (point, compute) in ex.sweep_points().iter().enumerate() {
            let at = |who| read(Stage::Sweep { arm, point, who });
            let mut adp = Vec::new();
            for seed in 0..ex.seeds {
                adp.extend(at(SweepWho::Adp { seed })?);
            }
            sweep.push(report::SweepPoint {
                label: eval::compute_label(compute),
                ddp: at(SweepWho::Ddp)?,
                constant: at(SweepWho::Constant)?,
                adp,
            });
        }
    }
    let mut sensing = Vec::new();
    if ex.sensing_arms().contains(&arm) {
        for condition in 0..ex.sensing_conditions().len() {
            let at = |who| read(Stage::Sensing { arm, condition, who });
            let mut adp = Vec::new();
            for seed in 0..ex.seeds {
                adp.extend(at(SweepWho::Adp { seed })?);
            }
            sensing.push(report::SweepPoint {
                label: eval::lidar_label(&sensing_lidar(ctx, condition)?),
                ddp: at(SweepWho::Ddp)?,
                constant: at(SweepWho::Constant)?,
                adp,
            });
        }
    }
    Ok(ArmData {
        arm: a.clone(),
        ddp: read(Stage::EvalDdp {
            planner: a.planner,
            speed: a.speed,
        })?,
        vanilla: if ex.eval.vanilla {
            read(Stage::EvalVanilla {
                planner: a.planner,
                speed: a.speed,
            })?
        } else {
            None
        },
        constant: read(Stage::EvalConstant { arm })?,
        search,
        untrained: read(Stage::EvalUntrained { arm })?,
        adp,
        shuffled,
        sweep,
        sensing,
    })
}

/// The machine-readable summary beside the report (`results.json`).
#[derive(Serialize)]
struct ArmResults {
    arm: String,
    /// (method, seed index or none, table values).
    methods: Vec<(String, Option<usize>, Summary)>,
    comparisons: Vec<Comparison>,
    /// The sensing sweep, per condition (absent for an arm it does not cover).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    sensing: Vec<SensingResult>,
}

/// Drives `policy` once on `world` (run 0's seed) and records where the robot was and what
/// schedule it chose at every agent step.
fn drive(ctx: &Ctx<'_>, a: &Arm, p: &LearnedPolicy, world: usize) -> anyhow::Result<figures::Drive> {
    let seed = run_seed(ctx.ex.eval.seed, world, 0);
    let run = eval_run(&ctx.cfg, &ctx.worlds[world], a.planner, a.speed, seed);
    let chooser = Chooser::Env {
        space: p.space,
        env: &p.env.for_evaluation(),
        act: &mut Greedy::new(&p.net),
    };
    let mut steps = Vec::new();
    let mut end = Default::default();
    let out = closed_loop::run(run, chooser, |step| {
        let params = step.env.chosen_params().context("a step without its schedule")?;
        steps.push((step.position, params));
        end = step.env.episode().state().pose.position();
        anyhow::Ok(())
    })?;
    if let Some(last) = steps.last().map(|s| s.1.clone()) {
        steps.push((end, last));
    }
    let r = out.episode;
    Ok(figures::Drive {
        steps,
        outcome: format!("world {world}: {:?} after {:.1} s", r.status, r.time_s),
    })
}

/// One stage's result as `stages.json` lists it.
#[derive(Serialize)]
struct StageEntry {
    /// The stage in words.
    stage: String,
    /// Its recipe's key.
    key: String,
    /// Its result in the store.
    result: PathBuf,
    /// The experiment that computed it (`None`: not finished).
    computed_by: Option<String>,
    /// Wall-clock seconds it took there.
    seconds: Option<f64>,
}

/// Writes `stages.json` (every stage, its key, its result in the store and who computed
/// it) and returns the report's line on where the results came from.
fn provenance(ctx: &Ctx<'_>) -> anyhow::Result<String> {
    let ex = ctx.ex;
    let mut entries = Vec::new();
    let mut by: std::collections::BTreeMap<String, usize> = Default::default();
    for s in stages(&ex.arms, ex.seeds, &sweeps(ex)) {
        let recipe = ctx.layout.recipe(&s);
        let meta = ctx
            .layout
            .done(&s)
            .then(|| ctx.layout.store.meta(&recipe))
            .flatten();
        if ctx.layout.done(&s) {
            let who = meta
                .as_ref()
                .map_or_else(|| "an unrecorded run".to_string(), |m| m.experiment.clone());
            *by.entry(who).or_default() += 1;
        }
        entries.push(StageEntry {
            stage: describe(&s, &ex.arms),
            key: recipe.key.0.clone(),
            result: ctx.layout.store.path(&recipe),
            computed_by: meta.as_ref().map(|m| m.experiment.clone()),
            seconds: meta.as_ref().map(|m| m.seconds),
        });
    }
    write_atomic(
        &ctx.layout.dir.join("stages.json"),
        &serde_json::to_vec_pretty(&entries).expect("serializes"),
    )?;
    let own = by.remove(&ex.section.name).unwrap_or(0);
    let others: Vec<String> = by.iter().map(|(e, n)| format!("{n} computed by `{e}`")).collect();
    Ok(format!(
        "results: {} stage(s), {own} computed by this experiment{}; every result lives in the \
         store `{}` under the key of what decides it (`stages.json` lists them)",
        entries.len(),
        if others.is_empty() {
            String::new()
        } else {
            format!(", reused from the store: {}", others.join(", "))
        },
        ctx.layout.store.dir.display()
    ))
}

/// Writes the figures, `results.json` and `report.md`; returns the report's path.
fn write_report(ctx: &Ctx<'_>) -> anyhow::Result<PathBuf> {
    let ex = ctx.ex;
    let data: Vec<ArmData> = (0..ex.arms.len())
        .map(|i| arm_data(ctx, i))
        .collect::<anyhow::Result<_>>()?;
    let fig_dir = ctx.layout.dir.join("figures");
    std::fs::create_dir_all(&fig_dir).with_context(|| format!("cannot create {}", fig_dir.display()))?;
    let mut figs: Vec<(String, String)> = Vec::new();
    let mut notes: Vec<String> = Vec::new();
    let mut rendered = false;
    for (arm, d) in data.iter().enumerate() {
        let id = d.arm.id();
        learning_figure(ctx, arm, d, &fig_dir, &mut figs, &mut notes)?;
        scatter_figure(d, &fig_dir, &mut figs)?;
        compute_figure(d, &fig_dir, &mut figs)?;
        clutter_figure(d, &fig_dir, &mut figs)?;
        // One rendered episode, of the first arm with a trained policy.
        if !rendered && !d.adp.is_empty() {
            episode_figure(ctx, arm, d, &fig_dir, &mut figs)?;
            rendered = true;
        }
        let missing = pending(&stages(&ex.arms, ex.seeds, &sweeps(ex)), |s| ctx.layout.done(s))
            .into_iter()
            .filter(|s| stage_arm(s, &ex.arms) == Some(arm))
            .count();
        if missing > 0 {
            notes.push(format!(
                "{id}: {missing} stage(s) not finished yet; their rows are missing"
            ));
        }
    }
    notes.push(provenance(ctx)?);
    let results = arm_results(&data, ex);
    let mut text = report::render(ex, &data, &figs, &notes);
    let json = if ex.report.paper_tables {
        let t = paper::tables(ex, &data, &ex.report.hardest, &ex.hardest_worlds);
        write_atomic(
            &ctx.layout.dir.join("table1.md"),
            paper::summary_table(&t).as_bytes(),
        )?;
        // The paper's tables lead; the per-arm report follows under its own title.
        let (title, rest) = text.split_once('\n').unwrap_or((&text, ""));
        text = format!("{title}\n\n{}{rest}", paper::render(&t));
        serde_json::to_vec_pretty(&serde_json::json!({"paper": t, "arms": results}))
    } else {
        serde_json::to_vec_pretty(&results)
    };
    write_atomic(&ctx.layout.dir.join("results.json"), &json.expect("serializes"))?;
    // Where the width of the intervals comes from, on the first arm with two seeds or more.
    if let Some(d) = data.iter().find(|d| d.ddp.is_some() && d.adp.len() > 1) {
        let st = &ex.stats;
        let ddp = d.ddp.as_ref().expect("found with DDP");
        match protocol::study(ddp, &d.adp, st.resamples, st.confidence, st.seed) {
            Ok(s) => {
                text += &format!("\n{}", s.markdown(Some(&d.arm.id())));
            }
            Err(e) => text += &format!("\nNo protocol study on `{}`: {e:#}\n", d.arm.id()),
        }
    }
    let path = ctx.layout.dir.join("report.md");
    write_atomic(&path, text.as_bytes())?;
    Ok(path)
}

/// The learning-curve figure of `d` (each seed's greedy evaluations during training), or a
/// note that no finished training wrote them.
fn learning_figure(
    ctx: &Ctx<'_>,
    arm: usize,
    d: &ArmData,
    fig_dir: &Path,
    figs: &mut Vec<(String, String)>,
    notes: &mut Vec<String>,
) -> anyhow::Result<()> {
    let id = d.arm.id();
    // Finished trainings only: a training still running (or stopped to resume) has a curve
    // that ends early, and its directory is not committed with the report.
    let curves: Vec<(String, Vec<figures::GreedyPoint>)> = (0..ctx.ex.seeds)
        .filter(|&s| ctx.layout.done(&Stage::Train { arm, seed: s }))
        .filter_map(|s| figures::read_greedy(&ctx.layout.run_dir(arm, s)).map(|g| (format!("seed {s}"), g)))
        .filter(|(_, g)| !g.is_empty())
        .collect();
    if curves.is_empty() {
        notes.push(format!(
            "{id}: no finished training wrote greedy_eval.jsonl (the learner's periodic greedy evaluation), so \
             there is no learning-curve figure"
        ));
    } else {
        let file = format!("learning-{id}.png");
        figures::learning_curves(
            &curves,
            &format!("{id}: greedy evaluation during training"),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!("{id}: greedy-evaluation learning curves"),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of `d`'s per-world scores, ADP's (mean over seeds) against DDP's (none without
/// DDP or ADP records).
fn scatter_figure(d: &ArmData, fig_dir: &Path, figs: &mut Vec<(String, String)>) -> anyhow::Result<()> {
    let id = d.arm.id();
    if let (Some(ddp), false) = (&d.ddp, d.adp.is_empty()) {
        let base = ddp.per_world_values();
        let seeds: Vec<Vec<(usize, f64, f64)>> = d.adp.iter().map(EvalRecord::per_world_values).collect();
        let points: Vec<(usize, f64, f64)> = base
            .iter()
            .enumerate()
            .map(|(i, &(w, _, s))| {
                (
                    w,
                    s,
                    stats::mean(&seeds.iter().map(|v| v[i].2).collect::<Vec<_>>()),
                )
            })
            .collect();
        let file = format!("scatter-{id}.png");
        figures::world_scatter(
            &points,
            &format!("{id}: score per test world"),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!("{id}: per-world ADP against DDP score"),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of success and score against modelled compute per cycle: `d`'s search
/// candidates on the training worlds and its controls on the test worlds (none without a
/// search).
fn compute_figure(d: &ArmData, fig_dir: &Path, figs: &mut Vec<(String, String)>) -> anyhow::Result<()> {
    let id = d.arm.id();
    if let Some(search) = &d.search {
        let most = search.candidates.iter().map(|c| c.pairs).max().unwrap_or(0);
        let points: Vec<figures::ComputePoint> = (search.candidates.iter().enumerate())
            .map(|(i, c)| figures::ComputePoint {
                label: match i {
                    0 => "DDP".into(),
                    _ if i == search.best => "best constant".into(),
                    _ => String::new(),
                },
                ms: c.compute_ms_per_cycle,
                score: c.score,
                success_pct: c.success_pct,
            })
            .collect();
        let finalists: Vec<bool> = search.candidates.iter().map(|c| c.pairs == most).collect();
        let named = |label: String, r: &EvalRecord| {
            let s = r.summary();
            figures::ComputePoint {
                label,
                ms: s.compute_ms,
                score: s.score,
                success_pct: s.success_pct,
            }
        };
        let mut test: Vec<figures::ComputePoint> = Vec::new();
        test.extend(d.ddp.iter().map(|r| named("DDP".into(), r)));
        test.extend(d.constant.iter().map(|r| named("best constant".into(), r)));
        test.extend(d.untrained.iter().map(|r| named("untrained".into(), r)));
        test.extend(
            d.adp
                .iter()
                .enumerate()
                .map(|(k, r)| named(format!("ADP seed {k}"), r)),
        );
        let file = format!("compute-{id}.png");
        figures::compute_pareto(
            &points,
            &finalists,
            &test,
            &format!("{id}: success and score against modelled compute per cycle"),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!(
                "{id}: success and score against modelled compute per planning cycle (left: the {} \
                 search candidates on the training worlds, finalists dark; right: the controls on \
                 the test worlds)",
                search.candidates.len()
            ),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of the schedules `d`'s ADP seeds chose against local clutter (none without
/// traces).
fn clutter_figure(d: &ArmData, fig_dir: &Path, figs: &mut Vec<(String, String)>) -> anyhow::Result<()> {
    let id = d.arm.id();
    let trace: Vec<runner::TracePoint> = d.adp.iter().flat_map(|r| r.trace.iter().cloned()).collect();
    if !trace.is_empty() {
        let file = format!("clutter-{id}.png");
        figures::schedule_vs_clutter(
            &trace,
            d.arm.space,
            &format!(
                "{id}: chosen schedule vs local clutter ({} agent steps)",
                trace.len()
            ),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!("{id}: the chosen schedule's parameters against local clutter (run 0 of every test world, every seed)"),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of one episode of `d`'s seed 0 on the render world, its path coloured by the
/// chosen rollout horizon.
fn episode_figure(
    ctx: &Ctx<'_>,
    arm: usize,
    d: &ArmData,
    fig_dir: &Path,
    figs: &mut Vec<(String, String)>,
) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let id = d.arm.id();
    let p = load_policy(&ctx.layout.run_dir(arm, 0).join("export"), d.arm.space)?;
    let dr = drive(ctx, &d.arm, &p, ex.render_world)?;
    let file = format!("episode-{id}.png");
    figures::episode(
        &ctx.worlds[ex.render_world],
        &dr,
        d.arm.space,
        &format!("{id} seed 0, world {}", ex.render_world),
        &fig_dir.join(&file),
    )?;
    figs.push((
        format!(
            "{id} seed 0 on test world {}: the path coloured by the chosen rollout horizon",
            ex.render_world
        ),
        format!("figures/{file}"),
    ));
    Ok(())
}

/// The machine-readable summary of every arm (`results.json`): its methods' table values and
/// ADP's comparisons with the controls, and the sensing sweep.
fn arm_results(data: &[ArmData], ex: &Experiment) -> Vec<ArmResults> {
    data.iter()
        .map(|d| {
            let mut methods = Vec::new();
            for (name, r) in [
                ("ddp", &d.ddp),
                ("constant", &d.constant),
                ("untrained", &d.untrained),
            ] {
                if let Some(r) = r {
                    methods.push((name.to_string(), None, r.summary()));
                }
            }
            for r in d.adp.iter().chain(&d.shuffled) {
                methods.push((r.controller.clone(), r.seed_index, r.summary()));
            }
            ArmResults {
                arm: d.arm.id(),
                methods,
                comparisons: comparisons(d, ex),
                sensing: sensing_results(d, ex),
            }
        })
        .collect()
}

/// The arm a stage belongs to (a DDP stage to the first arm of its planner and speed).
fn stage_arm(s: &Stage, arms: &[Arm]) -> Option<usize> {
    match *s {
        Stage::Train { arm, .. }
        | Stage::Search { arm }
        | Stage::EvalConstant { arm }
        | Stage::EvalUntrained { arm }
        | Stage::EvalAdp { arm, .. }
        | Stage::EvalShuffled { arm, .. }
        | Stage::Sweep { arm, .. }
        | Stage::Sensing { arm, .. } => Some(arm),
        Stage::EvalDdp { planner, speed } | Stage::EvalVanilla { planner, speed } => {
            arms.iter().position(|a| a.planner == planner && a.speed == speed)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::PlannerKind;

    /// A trainer for tests that train nothing.
    struct NoTraining;

    impl Trainer for NoTraining {
        fn train(&self, _: &Path, _: &Path, _: bool) -> anyhow::Result<()> {
            anyhow::bail!("this test trains nothing")
        }

        fn actors(&self) -> u32 {
            2
        }
    }

    fn shipped(file: &str) -> Experiment {
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .join("configs/experiments")
            .join(file);
        Experiment::load(&path, &Restrict::default()).unwrap()
    }

    /// The shipped experiments keep their arms and stages: table1 (9 arms x 3 seeds, the
    /// budget sweep of arm 0 at 4 points) and rl-dwa (4 arms x 3 seeds, no sweep).
    #[test]
    fn existing_experiments_keep_their_stages_and_ids() {
        let ex = shipped("table1.toml");
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.0-fit",
                "dwa-decremental-1.5-fit",
                "dwa-decremental-2.0-fit",
                "mppi-decremental-1.0-fit",
                "mppi-decremental-1.5-fit",
                "mppi-decremental-2.0-fit",
                "system-decremental-1.0-fit",
                "system-decremental-1.5-fit",
                "system-decremental-2.0-fit"
            ]
        );
        assert_eq!(sweeps(&ex).sensing, None);
        let all = stages(&ex.arms, ex.seeds, &sweeps(&ex));
        // Training 27, searches 9, DDP 9, per arm constant, untrained, 3 ADP and 3 shuffled
        // (72), the budget sweep 4 x (DDP, constant, 3 seeds).
        assert_eq!(all.len(), 27 + 9 + 9 + 72 + 20);
        assert_eq!(all[27], Stage::Search { arm: 0 });
        assert_eq!(
            all[36],
            Stage::EvalDdp {
                planner: PlannerKind::Dwa,
                speed: 1.0
            }
        );
        assert_eq!(all[45], Stage::EvalConstant { arm: 0 });
        assert_eq!(
            all.last(),
            Some(&Stage::Sweep {
                arm: 0,
                point: 3,
                who: SweepWho::Adp { seed: 2 }
            })
        );
        let ex = shipped("rl-dwa.toml");
        assert_eq!(sweeps(&ex), Sweeps::default());
        let all = stages(&ex.arms, ex.seeds, &sweeps(&ex));
        assert_eq!(all.len(), 12 + 4 + 1 + 4 * 8);
        assert_eq!(
            all.iter().filter(|s| matches!(s, Stage::Search { .. })).count(),
            4
        );
    }

    /// The paper's file: Table I's 12 cells, then Table II's arms (the incremental and
    /// unconstrained spaces on the system and DWA; 4 training-world selections on the system),
    /// 20 arms x 3 seeds; the vanilla row per planner and speed; the state-shuffled control on
    /// the 1.5 m/s arms only; 10 runs per world trimmed by 2; the hardest 50 test worlds.
    #[test]
    fn the_paper_experiment_plans_its_tables() {
        let ex = shipped("paper.toml");
        assert_eq!(ex.arms.len(), 20);
        assert_eq!(
            ex.arms[..12]
                .iter()
                .filter(|a| a.space == ActionSpace::Decremental)
                .count(),
            12
        );
        assert_eq!((ex.eval.runs, ex.eval.trim, ex.seeds), (10, 2, 3));
        assert_eq!(ex.hardest_worlds.len(), 50);
        assert!(ex.hardest_worlds.iter().all(|w| ex.test_worlds.contains(w)));
        let all = stages(&ex.arms, ex.seeds, &sweeps(&ex));
        let count = |kind: &str| all.iter().filter(|s| stage_kind(s) == kind).count();
        assert_eq!(count("train"), 60);
        assert_eq!((count("ddp"), count("vanilla")), (12, 12));
        // Training-world arms share the system's 1.5 m/s search; the others search their own.
        assert_eq!(count("search"), 16);
        assert_eq!(count("adp"), 60);
        let shuffled_arms: Vec<f64> = all
            .iter()
            .filter_map(|s| match *s {
                Stage::EvalShuffled { arm, .. } => Some(ex.arms[arm].speed),
                _ => None,
            })
            .collect();
        assert!(!shuffled_arms.is_empty() && shuffled_arms.iter().all(|&v| v == 1.5));
    }

    /// The sensing experiment: 4 layouts x 3 seeds trained, one search and one best constant
    /// shared by the layouts, and per condition DDP, the constant and 12 policies.
    #[test]
    fn the_sensing_experiment_plans_its_sweep() {
        let ex = shipped("sensing.toml");
        let all = stages(&ex.arms, ex.seeds, &sweeps(&ex));
        let main = 12 + 1 + 1 + 1 + 4 * (1 + 3 + 3);
        assert_eq!(all.len(), main + 4 * (1 + 1 + 12));
        assert!(all[main..].iter().all(|s| matches!(s, Stage::Sensing { .. })));
    }

    /// The training-worlds experiment: 5 selections x 3 seeds trained; the arms differ only in
    /// training worlds, so one search, one DDP, one best constant and one untrained policy
    /// (the first arm's) serve them all.
    #[test]
    fn the_worlds_experiment_shares_its_controls() {
        let ex = shipped("worlds.toml");
        assert_eq!(ex.arms.len(), 5);
        let all = stages(&ex.arms, ex.seeds, &sweeps(&ex));
        assert_eq!(all.len(), 15 + 1 + 1 + 1 + 1 + 5 * (3 + 3));
        let cfg = eval_config(&ex).unwrap();
        let layout = Layout::new("/e".into(), Store { dir: "/s".into() }, &ex, &cfg, 2);
        for arm in 1..5 {
            for stage in [Stage::EvalConstant { arm }, Stage::EvalUntrained { arm }] {
                let first = match stage {
                    Stage::EvalConstant { .. } => Stage::EvalConstant { arm: 0 },
                    _ => Stage::EvalUntrained { arm: 0 },
                };
                assert_eq!(layout.output(&stage), layout.output(&first), "{stage:?}");
            }
            assert_ne!(layout.run_dir(arm, 0), layout.run_dir(0, 0));
        }
    }

    /// A sensing-sweep evaluation runs under its condition's lidar: on two worlds, a
    /// noiseless condition over a noiseless configuration reproduces the main DDP evaluation
    /// bit for bit, run by run; heavy noise drives other episodes. Both record their lidar.
    #[test]
    fn a_sensing_evaluation_applies_its_lidar_condition() {
        let dir = std::env::temp_dir().join(format!("adp-sensing-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let eval_toml = dir.join("eval.toml");
        let base = include_str!("../../configs/eval.toml");
        assert!(base.contains("noise_sigma = 0.001 "));
        std::fs::write(
            &eval_toml,
            base.replace("noise_sigma = 0.001 ", "noise_sigma = 0.0 "),
        )
        .unwrap();
        let text = format!(
            "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\ntest_worlds = \
             \"0,1\"\n[eval]\nruns = 2\ntrim = 0\nconfig = {:?}\n[sensing_sweep]\n\
             noise_fractions = [0.0, 0.5]\nruns = 2\ntrim = 0\n",
            eval_toml.display().to_string()
        );
        let ex = Experiment::parse("t.toml", &text, &Restrict::default()).unwrap();
        let cfg = eval_config(&ex).unwrap();
        let ctx = Ctx {
            ex: &ex,
            trainer: &NoTraining,
            layout: Layout::new(
                dir.clone(),
                Store {
                    dir: dir.join("store"),
                },
                &ex,
                &cfg,
                2,
            ),
            cfg,
            worlds: sim::catalog::worlds(),
            test_worlds: ex.test_worlds.clone(),
        };
        let run = |stage: Stage| {
            let out = ctx.layout.output(&stage);
            run_stage(&ctx, &stage, &out).unwrap();
            EvalRecord::load(&out).unwrap()
        };
        let main = run(Stage::EvalDdp {
            planner: PlannerKind::Dwa,
            speed: 1.5,
        });
        let sensing = |condition| {
            run(Stage::Sensing {
                arm: 0,
                condition,
                who: SweepWho::Ddp,
            })
        };
        let (clean, noisy) = (sensing(0), sensing(1));
        assert_eq!(main.lidar, None);
        assert_eq!(clean.per_world, main.per_world);
        assert_eq!(clean.lidar, Some(ctx.cfg.episode.lidar));
        assert_eq!(noisy.lidar.unwrap().noise_fraction, 0.5);
        assert_eq!(noisy.per_world.len(), 2);
        assert!(noisy.per_world.iter().all(|w| w.runs.len() == 2));
        assert_ne!(noisy.per_world, main.per_world);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
