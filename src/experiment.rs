//! `adp experiment` and `adp protocol`: the command lines of the `experiment` library.

use std::path::{Path, PathBuf};

use experiment::record::EvalRecord;
use experiment::{first_runs, protocol, Options, Trainer};

/// What `adp experiment` was asked: the library's options, as command-line arguments.
pub type Args = Options;

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
    experiment::run(args, &LocalTrainer)
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
