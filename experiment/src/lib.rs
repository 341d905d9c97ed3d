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
mod execute;
pub mod figures;
pub mod paper;
pub mod plan;
pub mod protocol;
pub mod recipe;
pub mod record;
mod render;
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

use sim::World;

use eval::EvalConfig;

use config::{Experiment, Restrict};
use estimate::{progress_line, Rates};
use plan::{pending, stages, write_atomic, Stage, Sweeps};
use record::EvalRecord;
use shard::Shard;
use store::{Layout, StageMeta, Store};

use execute::{run_stage, train};
use render::write_report;

/// The file in an experiment directory holding the experiment file it was started with.
const CONFIG_COPY: &str = "experiment.toml";

/// What an experiment run is asked: the options of `adp experiment`.
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Options {
    /// The experiment file.
    #[cfg_attr(feature = "clap", arg(long))]
    pub config: PathBuf,
    /// Experiment directory (default: `runs/experiments/<name>`).
    #[cfg_attr(feature = "clap", arg(long))]
    pub out: Option<PathBuf>,
    /// Continue the experiment in --out, skipping the stages whose results exist.
    #[cfg_attr(feature = "clap", arg(long))]
    pub resume: bool,
    /// The store of results shared by experiments (default: `[experiment] store`, else
    /// `runs/store`). A stage whose result the store holds, whichever experiment computed
    /// it, is read instead of computed.
    #[cfg_attr(feature = "clap", arg(long))]
    pub store: Option<PathBuf>,
    /// List the stages still to compute with their estimated core-hours (from the rates the
    /// store measured), say which the store already holds, and stop.
    #[cfg_attr(feature = "clap", arg(long, conflicts_with_all = ["emit_slurm", "shard", "no_eval"]))]
    pub plan: bool,
    /// Write the report from the results the store holds, computing nothing (a table cell
    /// whose stages are missing shows "–").
    #[cfg_attr(feature = "clap", arg(long, conflicts_with_all = ["emit_slurm", "shard", "no_eval", "plan"]))]
    pub report_only: bool,
    /// Run only the stages of these kinds (comma-separated: train, search, ddp, vanilla,
    /// constant, untrained, adp, shuffled, sweep, sensing); the others wait for a later run.
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ',', value_parser = ["train", "search", "ddp", "vanilla", "constant", "untrained", "adp", "shuffled", "sweep", "sensing"]))]
    pub only: Vec<String>,
    /// Adopt finished `adp train` run directories as this experiment's trainings: a run whose
    /// resolved `config.toml` is one of the experiment's trainings (the same recipe) and whose
    /// export holds its steps is copied into the store; the others are named with what differs.
    /// Computes nothing else.
    #[cfg_attr(feature = "clap", arg(long, num_args = 1.., conflicts_with_all = ["emit_slurm", "shard", "no_eval", "plan", "report_only"]))]
    pub adopt: Vec<PathBuf>,
    /// Command-line restrictions.
    #[cfg_attr(feature = "clap", command(flatten))]
    pub restrict: Restrict,
    /// Worker threads of the evaluations (default: all cores).
    #[cfg_attr(feature = "clap", arg(long))]
    pub jobs: Option<usize>,
    /// Evaluate only shard K of N of the test worlds (e.g. 0/8) of every pending
    /// evaluation, into `<stage file>.shard-K-of-N`; a later run without --shard merges a
    /// complete set. Training and constant searches must be finished.
    #[cfg_attr(feature = "clap", arg(long, conflicts_with_all = ["no_eval", "emit_slurm"]))]
    pub shard: Option<Shard>,
    /// Run only the training and constant-search stages (no evaluation, no report).
    #[cfg_attr(feature = "clap", arg(long, conflicts_with = "emit_slurm"))]
    pub no_eval: bool,
    /// Print a SLURM job script that runs this experiment (training, evaluation sharded over
    /// the `[slurm]` tasks, merge and report) and create --out with its experiment.toml.
    #[cfg_attr(feature = "clap", arg(long, conflicts_with = "resume"))]
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
        estimate::print_plan(&ex, &layout, &args.config, &args.only, trainer.actors());
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
    let all = stages(&ex.arms, ex.seeds, &Sweeps::of(&ex));
    let todo: Vec<Stage> = pending(&all, |s| ctx.layout.done(s))
        .into_iter()
        .filter(|s| args.only.is_empty() || args.only.iter().any(|k| k == s.kind_name()))
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
            first.describe(&ex.arms)
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
            tracing::info!("{step} {}: in the store", stage.describe(&ex.arms));
            continue;
        }
        if let Some((arm, seed)) = stage.policy() {
            if !ctx.layout.done(&Stage::Train { arm, seed }) {
                // Only with --only or a training that failed: the policy is not there yet.
                tracing::warn!(
                    "{step} {}: waits for `{}`",
                    stage.describe(&ex.arms),
                    (Stage::Train { arm, seed }).describe(&ex.arms)
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
                        stage.describe(&ex.arms)
                    );
                    continue;
                }
                tracing::info!(
                    "{step} {} (shard {}/{})",
                    stage.describe(&ex.arms),
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
                    stage.describe(&ex.arms),
                    files.len()
                );
                continue;
            }
        }
        tracing::info!("{step} {}", stage.describe(&ex.arms));
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
        description: stage.describe(&ctx.ex.arms),
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
