//! `adp experiment` and `adp protocol`: the command lines of the `experiment` library.

use std::path::{Path, PathBuf};

use experiment::config::Restrict;
use experiment::record::EvalRecord;
use experiment::shard::Shard;
use experiment::{first_runs, protocol, Options, Trainer};
use planner::{ActionSpace, PlannerKind};

/// What `adp experiment` was asked.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// The experiment file.
    #[arg(long)]
    pub config: PathBuf,
    /// Experiment directory (default: `runs/experiments/<name>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the experiment in --out, skipping the stages whose results exist.
    #[arg(long)]
    pub resume: bool,
    /// The store of results shared by experiments (default: `[experiment] store`, else
    /// `runs/store`). A stage whose result the store holds, whichever experiment computed
    /// it, is read instead of computed.
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// List the stages still to compute with their estimated core-hours (from the rates the
    /// store measured), say which the store already holds, and stop.
    #[arg(long, conflicts_with_all = ["emit_slurm", "shard", "no_eval"])]
    pub plan: bool,
    /// Write the report from the results the store holds, computing nothing (a table cell
    /// whose stages are missing shows "–").
    #[arg(long, conflicts_with_all = ["emit_slurm", "shard", "no_eval", "plan"])]
    pub report_only: bool,
    /// Run only the stages of these kinds (comma-separated: train, search, ddp, vanilla,
    /// constant, untrained, adp, shuffled, sweep, sensing); the others wait for a later run.
    #[arg(long, value_delimiter = ',', value_parser = ["train", "search", "ddp", "vanilla", "constant", "untrained", "adp", "shuffled", "sweep", "sensing"])]
    pub only: Vec<String>,
    /// Adopt finished `adp train` run directories as this experiment's trainings: a run whose
    /// resolved `config.toml` is one of the experiment's trainings (the same recipe) and whose
    /// export holds its steps is copied into the store; the others are named with what differs.
    /// Computes nothing else.
    #[arg(long, num_args = 1.., conflicts_with_all = ["emit_slurm", "shard", "no_eval", "plan", "report_only"])]
    pub adopt: Vec<PathBuf>,
    /// Command-line restrictions.
    #[command(flatten)]
    pub restrict: RestrictArgs,
    /// Worker threads of the evaluations (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Evaluate only shard K of N of the test worlds (e.g. 0/8) of every pending
    /// evaluation, into `<stage file>.shard-K-of-N`; a later run without --shard merges a
    /// complete set. Training and constant searches must be finished.
    #[arg(long, conflicts_with_all = ["no_eval", "emit_slurm"])]
    pub shard: Option<Shard>,
    /// Run only the training and constant-search stages (no evaluation, no report).
    #[arg(long, conflicts_with = "emit_slurm")]
    pub no_eval: bool,
    /// Print a SLURM job script that runs this experiment (training, evaluation sharded over
    /// the `[slurm]` tasks, merge and report) and create --out with its experiment.toml.
    #[arg(long, conflicts_with = "resume")]
    pub emit_slurm: bool,
}

impl Args {
    /// The library's form of these options.
    fn options(&self) -> Options {
        Options {
            config: self.config.clone(),
            out: self.out.clone(),
            resume: self.resume,
            store: self.store.clone(),
            plan: self.plan,
            report_only: self.report_only,
            only: self.only.clone(),
            adopt: self.adopt.clone(),
            restrict: self.restrict.restrict(),
            jobs: self.jobs,
            shard: self.shard,
            no_eval: self.no_eval,
            emit_slurm: self.emit_slurm,
        }
    }
}

/// Trains an experiment's runs as `adp train` does, in this process with its actor processes.
struct LocalTrainer;

impl Trainer for LocalTrainer {
    fn train(&self, config: &Path, run_dir: &Path, resume: bool) -> anyhow::Result<()> {
        crate::train::train(
            Some(config),
            &crate::train::Overrides {
                steps: None,
                actors: None,
                out: Some(run_dir.to_owned()),
                listen: None,
                allow_insecure_listen: false,
                device: None,
            },
            resume,
        )
    }

    fn actors(&self) -> u32 {
        crate::train::default_actors()
    }
}

/// `adp experiment`: runs the experiment; returns the path of its report (`None` when this
/// process does not write one: `--plan`, `--emit-slurm`, `--shard`, `--no-eval`, `--adopt`).
pub fn run(args: &Args) -> anyhow::Result<Option<PathBuf>> {
    experiment::run(&args.options(), &LocalTrainer)
}

/// What `adp protocol` was asked.
#[derive(Clone, Debug, clap::Args)]
pub struct ProtocolArgs {
    /// DDP's evaluation record (an `eval/KEY.json` of the store).
    #[arg(long)]
    pub ddp: PathBuf,
    /// The trained policy's evaluation records, one per seed (same worlds and runs).
    #[arg(long, required = true, num_args = 1..)]
    pub adp: Vec<PathBuf>,
    /// Bootstrap resamples.
    #[arg(long, default_value_t = 10_000)]
    pub resamples: usize,
    /// Interval confidence.
    #[arg(long, default_value_t = 0.95)]
    pub confidence: f64,
    /// Resampling seed.
    #[arg(long, default_value_t = 3)]
    pub seed: u64,
    /// Study only the first R runs of every world (default: all), as if the evaluation had
    /// run R per world.
    #[arg(long)]
    pub runs: Option<usize>,
    /// With `--runs`: the runs trimmed from each end of a world (default: the records').
    #[arg(long, requires = "runs")]
    pub trim: Option<usize>,
    /// Also write the markdown here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// `adp protocol`: prints the study of the records (markdown).
pub fn protocol_command(args: &ProtocolArgs) -> anyhow::Result<()> {
    let mut ddp = EvalRecord::load(&args.ddp)?;
    let mut seeds = args
        .adp
        .iter()
        .map(|p| EvalRecord::load(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if let Some(runs) = args.runs {
        let trim = args.trim.unwrap_or(ddp.trim);
        ddp = first_runs(ddp, runs, trim)?;
        seeds = seeds
            .into_iter()
            .map(|r| first_runs(r, runs, trim))
            .collect::<anyhow::Result<_>>()?;
    }
    let text = protocol::study(&ddp, &seeds, args.resamples, args.confidence, args.seed)?.markdown(None);
    if let Some(out) = &args.out {
        experiment::plan::write_atomic(out, text.as_bytes())?;
    }
    print!("{text}");
    Ok(())
}

/// Command-line restrictions of an experiment (each must be a subset of the file's).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct RestrictArgs {
    /// Only these planners (comma-separated; a subset of the file's).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub planners: Vec<PlannerKind>,
    /// Only these action spaces (comma-separated; a subset of the file's).
    #[arg(long, value_delimiter = ',')]
    pub spaces: Vec<ActionSpace>,
    /// Only these speed caps (comma-separated; a subset of the file's).
    #[arg(long, value_delimiter = ',')]
    pub speeds: Vec<f64>,
    /// Only the first this many training seeds of each arm.
    #[arg(long)]
    pub seeds: Option<usize>,
    /// Agent steps per training run (overrides `[train.run]` steps).
    #[arg(long)]
    pub steps: Option<u64>,
}

impl RestrictArgs {
    /// The library's form.
    fn restrict(&self) -> Restrict {
        Restrict {
            planners: self.planners.clone(),
            spaces: self.spaces.clone(),
            speeds: self.speeds.clone(),
            seeds: self.seeds,
            steps: self.steps,
        }
    }
}

/// What `adp compact-records` was asked.
#[derive(Clone, Debug, clap::Args)]
pub struct CompactArgs {
    /// Directories (searched recursively) or files of evaluation records.
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
}

/// `adp compact-records`: rewrites every format-1 evaluation record under `paths` in the
/// compact format 2 after checking that its statistics are unchanged; compact records and
/// other JSON files are left alone. Prints what it did per path.
pub fn compact_command(args: &CompactArgs) -> anyhow::Result<()> {
    use experiment::record::compact::{compact_file, Compacted};
    use rayon::prelude::*;
    for root in &args.paths {
        let mut files = Vec::new();
        json_files(root, &mut files)?;
        files.sort();
        let done = files
            .par_iter()
            .map(|f| compact_file(f))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let (mut n, mut before, mut after, mut compact, mut other) = (0, 0u64, 0u64, 0, 0);
        for d in done {
            match d {
                Compacted::Converted(b, a) => (n, before, after) = (n + 1, before + b, after + a),
                Compacted::AlreadyCompact => compact += 1,
                Compacted::NotARecord => other += 1,
            }
        }
        println!(
            "{}: {n} records compacted, {:.1} MB -> {:.1} MB; {compact} already compact; {other} other JSON files left alone",
            root.display(),
            before as f64 / 1e6,
            after as f64 / 1e6
        );
    }
    Ok(())
}

/// Every `.json` file at or under `path`.
fn json_files(path: &Path, out: &mut Vec<PathBuf>) -> anyhow::Result<()> {
    use anyhow::Context;
    let meta = std::fs::metadata(path).with_context(|| format!("cannot read {}", path.display()))?;
    if meta.is_file() {
        out.push(path.to_path_buf());
        return Ok(());
    }
    for entry in std::fs::read_dir(path).with_context(|| format!("cannot list {}", path.display()))? {
        let p = entry?.path();
        if p.is_dir() {
            json_files(&p, out)?;
        } else if p.extension().is_some_and(|e| e == "json") {
            out.push(p);
        }
    }
    Ok(())
}
