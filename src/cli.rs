//! The `adp` command line: one clap `Args` struct per subcommand (`Cmd::Eval(EvalArgs)`), the
//! options several commands share defined once ([`Setup`], [`EvalRunArgs`], [`WorldData`]),
//! and the dispatch to each command's code ([`run`]).

use planner::PlannerKind;
use std::borrow::Cow;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use planner::{ActionSpace, ComputeConfig, ComputeModel};
use sim::splits::SplitSet;
use sim::{Profile, World};

use crate::config::{EvalConfig, UnknownName};
use crate::eval::{AdpSetting, EvalPlan};
use crate::eval::{Fidelity, ObstaclePrediction};
use crate::{bench, calibrate, experiment, export, slurm, train};

/// `adp`.
#[derive(Parser)]
#[command(
    name = "adp",
    version,
    about = "Adaptive/decremental dynamics planning on BARN"
)]
pub struct Cli {
    /// The command.
    #[command(subcommand)]
    pub cmd: Cmd,
}

/// Where the worlds come from: the embedded BARN and DynaBARN worlds unless BARN files are
/// given.
#[derive(clap::Args, Clone, Debug)]
pub struct WorldData {
    /// Obstacles file in the BARN JSONL format (default: the embedded BARN and DynaBARN
    /// worlds; with files, only the worlds they hold).
    #[arg(long, requires = "paths")]
    pub obstacles: Option<PathBuf>,
    /// Paths file in the BARN JSONL format (default: the embedded BARN paths).
    #[arg(long, requires = "obstacles")]
    pub paths: Option<PathBuf>,
}

impl WorldData {
    /// The worlds by id: parsed from the files, or the embedded ones (BARN 0..299, DynaBARN
    /// 300..359).
    pub fn load(&self) -> anyhow::Result<Cow<'static, [World]>> {
        match (&self.obstacles, &self.paths) {
            (Some(o), Some(p)) => {
                let ot =
                    std::fs::read_to_string(o).with_context(|| format!("cannot read {}", o.display()))?;
                let pt =
                    std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
                Ok(sim::barn::parse(&o.display().to_string(), &ot, &p.display().to_string(), &pt)?.into())
            }
            _ => Ok(sim::catalog::worlds().into()),
        }
    }

    /// World `id` of `all`, or a one-line error.
    pub fn get(all: &[World], id: usize) -> anyhow::Result<&World> {
        all.get(id)
            .with_context(|| format!("world {id} does not exist ({} worlds)", all.len()))
    }
}

/// What the simulating commands (eval, calibrate, render) read: the planner configuration, the
/// simulator profile and the worlds.
#[derive(clap::Args, Clone, Debug)]
pub struct Setup {
    /// Configuration file (default: the embedded configs/eval.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Simulator profile (ideal, gazebo-jackal, custom): overrides [episode] profile.
    #[arg(long, value_parser = parse_profile)]
    pub profile: Option<Profile>,
    /// Onboard compute model (free, jackal-onboard-v2, jackal-onboard, custom): overrides [compute] model, for
    /// every row (a policy's own model otherwise applies to the rows of its evaluation).
    #[arg(long, value_parser = parse_compute)]
    pub compute: Option<ComputeModel>,
    /// Multiplies every planner's cycle budget: overrides [compute] budget_scale.
    #[arg(long)]
    pub budget_scale: Option<f64>,
    #[command(flatten)]
    pub data: WorldData,
}

impl Setup {
    /// The evaluation config (`--config` or the embedded one) with `--profile` applied.
    pub fn eval_config(&self) -> anyhow::Result<EvalConfig> {
        let mut cfg = EvalConfig::load(self.config.as_deref())?;
        if let Some(p) = self.profile {
            let custom = cfg.episode.dynamics.filter(|_| p == Profile::Custom);
            cfg.episode = cfg.episode.with_profile(p, custom);
            cfg.episode
                .validate()
                .map_err(|e| anyhow::anyhow!("--profile {}: {e}", p.name()))?;
        }
        self.apply_compute(&mut cfg.compute)?;
        Ok(cfg)
    }

    /// Whether `--compute` or `--budget-scale` was given.
    pub fn compute_given(&self) -> bool {
        self.compute.is_some() || self.budget_scale.is_some()
    }

    /// Applies `--compute` and `--budget-scale` to `compute`.
    pub fn apply_compute(&self, compute: &mut ComputeConfig) -> anyhow::Result<()> {
        if let Some(m) = self.compute {
            compute.model = m;
        }
        if let Some(k) = self.budget_scale {
            compute.budget_scale = k;
        }
        compute
            .validate()
            .map_err(|e| anyhow::anyhow!("--compute / --budget-scale: {e}"))
    }
}

/// Parses a split-file set name.
fn parse_split_set(s: &str) -> Result<SplitSet, String> {
    match s {
        "barn" => Ok(SplitSet::Barn),
        "dynabarn" => Ok(SplitSet::Dynabarn),
        _ => Err(format!("unknown world set {s:?} (barn, dynabarn)")),
    }
}

/// Parses a compute model name.
fn parse_compute(s: &str) -> Result<ComputeModel, String> {
    match s {
        "free" => Ok(ComputeModel::Free),
        "jackal-onboard" => Ok(ComputeModel::JackalOnboard),
        "jackal-onboard-v2" => Ok(ComputeModel::JackalOnboardV2),
        "custom" => Ok(ComputeModel::Custom),
        _ => Err(format!(
            "unknown compute model {s:?} (free, jackal-onboard-v2, jackal-onboard, custom)"
        )),
    }
}

/// The options of the commands that evaluate on many worlds (eval, calibrate).
#[derive(clap::Args, Clone, Debug)]
pub struct EvalRunArgs {
    /// Base seed of every run's noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Also write the results as JSON here (eval: the rows and per-world results; calibrate:
    /// the comparison, the checks and every eval row).
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub setup: Setup,
}

impl EvalRunArgs {
    /// The worker pool of `--jobs`.
    pub fn pool(&self) -> anyhow::Result<rayon::ThreadPool> {
        rayon::ThreadPoolBuilder::new()
            .num_threads(self.jobs.unwrap_or(0))
            .build()
            .context("cannot start worker threads")
    }

    /// Writes `value` as pretty JSON to `--out`, when given.
    pub fn write_json(&self, value: &impl serde::Serialize) -> anyhow::Result<()> {
        if let Some(path) = &self.out {
            std::fs::write(path, serde_json::to_string_pretty(value)?)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(())
    }
}

/// Parses a simulator profile name.
fn parse_profile(s: &str) -> Result<Profile, UnknownName> {
    serde_json::from_value(serde_json::Value::String(s.to_string())).map_err(|_| UnknownName {
        kind: "profile",
        name: s.to_string(),
        expected: "ideal, gazebo-jackal or custom",
    })
}

/// The subcommands.
#[derive(Subcommand)]
pub enum Cmd {
    /// Evaluate planners x fidelity x speeds on a set of worlds and print the table.
    Eval(EvalArgs),
    /// Run the DDP paper's Table I protocol (300 worlds x 3 runs x 1.0/1.5/2.0 m/s; DWA,
    /// DWA-DDP, MPPI, MPPI-DDP, Log-MPPI, Log-MPPI-DDP, the DDP system) and print our table
    /// beside the paper's with the difference per cell and the calibration checks.
    Calibrate(CalibrateArgs),
    /// Draw one episode: world, trajectory, footprints, fidelity-coloured rollouts and moving
    /// obstacles (or, with --frames, a strip of moments of it).
    Render(RenderArgs),
    /// Export a checkpoint's policy: policy.onnx, policy.safetensors and policy.json.
    Export(ExportArgs),
    /// Train an ADP policy on this machine: a learner and N sandboxed actor processes.
    Train(TrainArgs),
    /// The learner half of a distributed run: gRPC control and data planes, shared memory,
    /// replay, TD3, checkpoints.
    Learner(LearnerArgs),
    /// The actor half of a distributed run: connects to a learner and runs assignments.
    Actor(train::ActorArgs),
    /// Print the sbatch script of a cluster training job (learner on the first node, actors on
    /// every node, requeue resumes the run).
    Slurm(SlurmArgs),
    /// Stop a running learner cleanly (final checkpoint) with the operator credential of its
    /// run directory.
    Stop(crate::stop::StopArgs),
    /// Run an experiment (configs/experiments/NAME.toml): train S seeds per arm, evaluate
    /// every policy with the papers' protocol against DDP, the best constant schedule, the
    /// untrained policy and the state-shuffled policy, and write report.md with tables,
    /// paired statistics and figures. Resumable.
    Experiment(experiment::Args),
    /// List, inspect, generate or compare worlds and splits.
    Worlds {
        #[command(subcommand)]
        cmd: WorldsCmd,
    },
    /// Measure the DESIGN §8 figures on this machine (release build) next to their targets.
    Bench(bench::BenchArgs),
}

/// `adp eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Planner(s), comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "dwa")]
    pub planner: Vec<PlannerKind>,
    /// Fidelity strategy (or strategies), comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "ddp")]
    pub fidelity: Vec<Fidelity>,
    /// ADP action space (with --fidelity adp; default: the policy's, else decremental). When
    /// given, the policy's space must be the same.
    #[arg(long)]
    pub action: Option<ActionSpace>,
    /// ADP policy (with --fidelity adp): a trained policy, i.e. the export directory of
    /// `adp export` or `adp train` (or its policy.json), run closed-loop; or a TOML file
    /// with a constant normalized `action = [...]`. Default: the constant action that
    /// reproduces DDP, ADP's initialization.
    #[arg(long)]
    pub policy: Option<PathBuf>,
    /// Speed cap(s) in m/s, comma-separated: one row per value.
    #[arg(long, value_delimiter = ',', default_value = "1.5")]
    pub max_speed: Vec<f64>,
    /// Moving-obstacle prediction(s), comma-separated: one row per value (`off`: none; `kf`:
    /// the tracker's constant-velocity forecast; `padp-path`: kf and PADP's predictive cost in
    /// the global path; `padp`: that and PADP's complexity-adaptive weights, see the
    /// `[prediction]` table; with --fidelity adp and a learned policy, kf exactly when the policy observes tracks).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "off")]
    pub prediction: Vec<ObstaclePrediction>,
    /// Lidar beam count(s) over the field of view, comma-separated: one row per value
    /// (overrides [episode.lidar] beams). A trained policy reads any beam count, resampled to
    /// its own layout (README "Sensing conditions").
    #[arg(long, value_delimiter = ',')]
    pub lidar_beams: Vec<usize>,
    /// Lidar range noise as a fraction of each scan's mean range (replaces [episode.lidar]
    /// noise_sigma), comma-separated: one row per value, e.g. 0.05,0.1,0.2.
    #[arg(long, value_delimiter = ',')]
    pub lidar_noise_fraction: Vec<f64>,
    /// Probability that a lidar beam returns nothing (reads max range), comma-separated: one
    /// row per value (overrides [episode.lidar] dropout).
    #[arg(long, value_delimiter = ',')]
    pub lidar_dropout: Vec<f64>,
    /// Worlds: comma-separated splits (BARN: train, test, hardest50, all; DynaBARN: dynabarn,
    /// dynabarn-easy|medium|hard, dynabarn-train, dynabarn-test, ...), ranges (0..50, 300..320)
    /// and ids (3,7,305).
    #[arg(long, default_value = "test")]
    pub worlds: String,
    /// Runs per world.
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Drop this many best and worst runs (by time) of each world before averaging.
    #[arg(long, default_value_t = 0)]
    pub trim: usize,
    #[command(flatten)]
    pub run: EvalRunArgs,
}

/// `adp calibrate`.
#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// Rows to run, comma-separated labels (default: all seven).
    #[arg(long, value_delimiter = ',')]
    pub rows: Vec<String>,
    /// Speed caps, comma-separated (default: the paper's 1.0, 1.5, 2.0).
    #[arg(long, value_delimiter = ',', default_value = "1.0,1.5,2.0")]
    pub max_speed: Vec<f64>,
    /// Worlds: comma-separated splits, ranges and ids, as for `adp eval`.
    #[arg(long, default_value = "all")]
    pub worlds: String,
    /// Runs per world.
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    #[command(flatten)]
    pub run: EvalRunArgs,
}

/// `adp render`.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// World id.
    #[arg(long)]
    pub world: usize,
    /// Planner.
    #[arg(long, value_enum, default_value = "dwa")]
    pub planner: PlannerKind,
    /// Fidelity strategy.
    #[arg(long, value_enum, default_value = "ddp")]
    pub fidelity: Fidelity,
    /// ADP action space (with --fidelity adp).
    #[arg(long, default_value = "decremental")]
    pub action: ActionSpace,
    /// ADP constant-action policy file (see `adp eval --help`).
    #[arg(long)]
    pub policy: Option<PathBuf>,
    /// Speed cap (m/s).
    #[arg(long, default_value_t = 1.5)]
    pub max_speed: f64,
    /// Noise seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Draw the sampled rollouts every this many seconds.
    #[arg(long, default_value_t = 2.0)]
    pub rollouts_every: f64,
    /// Draw the footprint every this many seconds.
    #[arg(long, default_value_t = 0.5)]
    pub footprint_every: f64,
    /// Draw a frame strip instead of one picture: this many frames (2 to 24) side by side,
    /// the world at evenly spaced moments from the start to the end of the episode.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Output picture (.png or .svg).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub setup: Setup,
}

/// `adp export`.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// Checkpoint directory written by the learner (verified before use).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Output directory (created if needed; existing policy files are replaced).
    #[arg(long)]
    pub out: PathBuf,
    /// Action space the run trained in.
    #[arg(long, default_value = "decremental")]
    pub action: ActionSpace,
}

/// `adp train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Run configuration (default: the embedded configs/local.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Total agent steps of the run (overrides [run] steps).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Actor processes (overrides [run] actors; 0 = one per core).
    #[arg(long)]
    pub actors: Option<u32>,
    /// Run directory (default: runs/<name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the run in --out from its newest valid checkpoint up to --steps.
    #[arg(long)]
    pub resume: bool,
}

/// `adp learner`.
#[derive(clap::Args, Debug)]
pub struct LearnerArgs {
    /// Run configuration (default: the embedded configs/local.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Total agent steps of the run (overrides [run] steps).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Run directory (default: runs/<name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Address to listen on (overrides [service] listen), e.g. 0.0.0.0:50051.
    #[arg(long)]
    pub listen: Option<String>,
    /// Allow --listen on a non-loopback address without [service.tls] (the token then
    /// crosses the network in clear text); for trusted networks only.
    #[arg(long)]
    pub allow_insecure_listen: bool,
    /// The run's token file (mode 0600; default: <out>/token, created if missing).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Continue the run in --out from its newest valid checkpoint.
    #[arg(long)]
    pub resume: bool,
}

/// `adp slurm`.
#[derive(clap::Args, Debug)]
pub struct SlurmArgs {
    /// Run configuration with a [slurm] table (default: the embedded configs/slurm.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Overrides of the config's [slurm] and [run] values.
    #[command(flatten)]
    pub overrides: slurm::SlurmOverrides,
    /// Run directory (default: runs/<name>; made absolute; its logs/ is created now).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// The adp executable on the compute nodes (default: [slurm] adp, else this one).
    #[arg(long)]
    pub adp: Option<PathBuf>,
}

#[derive(Subcommand)]
pub enum WorldsCmd {
    /// Print the world ids of a selection, one per line.
    List {
        /// Comma-separated splits, ranges and ids, as for `adp eval --worlds`.
        #[arg(long, default_value = "all")]
        split: String,
    },
    /// Print one world's facts.
    Show {
        /// World id.
        id: usize,
        #[command(flatten)]
        data: WorldData,
    },
    /// Print a split file drawn with another seed (the format of configs/splits/barn.toml, or
    /// of configs/splits/dynabarn.toml with --set dynabarn).
    Splits {
        /// Seed for the training-world draw.
        #[arg(long)]
        seed: u64,
        /// Which worlds: barn or dynabarn.
        #[arg(long, default_value = "barn", value_parser = parse_split_set)]
        set: SplitSet,
    },
    /// Generate procedural BARN worlds (the BARN paper's cellular automaton, solvable worlds
    /// only, each with its A* path and five difficulty metrics) into DIR/obstacles.jsonl and
    /// DIR/paths.jsonl, for `adp eval --obstacles DIR/obstacles.jsonl --paths DIR/paths.jsonl`.
    Generate(crate::worlds::GenerateArgs),
    /// Print the difficulty metrics of generated worlds beside the 300 BARN worlds' (text
    /// histograms, quantiles, Kolmogorov-Smirnov distance); nothing is written.
    Compare(crate::worlds::CompareArgs),
}

impl WorldsCmd {
    fn run(self) -> anyhow::Result<()> {
        match self {
            WorldsCmd::List { split } => {
                for id in sim::splits::select(&split)? {
                    println!("{id}");
                }
            }
            WorldsCmd::Show { id, data } => {
                let all = data.load()?;
                let w = WorldData::get(&all, id)?;
                println!("world {}", w.id);
                println!("cylinders {}", w.cylinders.len());
                if !w.walls.is_empty() || !w.moving.is_empty() {
                    println!("walls {}", w.walls.len());
                    println!(
                        "moving {} (longest loop {:.2} s)",
                        w.moving.len(),
                        w.longest_period()
                    );
                }
                println!("start {:.3} {:.3} {:.4}", w.start.x, w.start.y, w.start.yaw);
                println!(
                    "goal {:.3} {:.3} (radius {} m)",
                    w.goal.x, w.goal.y, w.goal_radius
                );
                println!("path_length_m {:.6}", w.path_length_m);
                println!("optimal_time_s {:.6}", w.optimal_time_s);
            }
            WorldsCmd::Splits { seed, set } => print!("{}", set.render_toml(seed)),
            WorldsCmd::Generate(args) => crate::worlds::generate(&args)?,
            WorldsCmd::Compare(args) => crate::worlds::compare(&args)?,
        }
        Ok(())
    }
}

/// Runs the command `cmd`.
pub fn run(cmd: Cmd) -> anyhow::Result<()> {
    match cmd {
        Cmd::Bench(args) => bench::run(&args),
        Cmd::Train(a) => train::train(
            a.config.as_deref(),
            &train::Overrides {
                steps: a.steps,
                actors: a.actors,
                out: a.out,
                listen: None,
                allow_insecure_listen: false,
            },
            a.resume,
        ),
        Cmd::Learner(a) => train::learner(
            a.config.as_deref(),
            &train::Overrides {
                steps: a.steps,
                actors: None,
                out: a.out,
                listen: a.listen,
                allow_insecure_listen: a.allow_insecure_listen,
            },
            a.resume,
            a.token_file.as_deref(),
        ),
        Cmd::Actor(args) => train::actor(args),
        Cmd::Stop(args) => crate::stop::command(&args),
        Cmd::Slurm(a) => {
            let script = slurm::generate(
                a.config.as_deref(),
                &a.overrides,
                a.run_dir.as_deref(),
                a.adp.as_deref(),
            )?;
            print!("{script}");
            Ok(())
        }
        Cmd::Eval(args) => crate::eval::command(&args),
        Cmd::Calibrate(args) => calibrate(&args),
        Cmd::Render(args) => crate::render::command(&args),
        Cmd::Export(a) => export::run(&a.checkpoint, &a.out, a.action),
        Cmd::Experiment(args) => {
            if let Some(report) = experiment::run(&args)? {
                println!("{}", report.display());
            }
            Ok(())
        }
        Cmd::Worlds { cmd } => cmd.run(),
    }
}

/// `adp calibrate` (its tables and checks are in [`calibrate`]).
fn calibrate(a: &CalibrateArgs) -> anyhow::Result<()> {
    let cfg = a.run.setup.eval_config()?;
    let ids = sim::splits::select(&a.worlds)?;
    let chosen: Vec<&calibrate::PaperRow> = if a.rows.is_empty() {
        calibrate::TABLE_I.iter().collect()
    } else {
        a.rows
            .iter()
            .map(|r| {
                calibrate::paper_row(r).with_context(|| {
                    let labels: Vec<&str> = calibrate::TABLE_I.iter().map(|p| p.label).collect();
                    format!("--rows: unknown row `{r}` (expected {})", labels.join(", "))
                })
            })
            .collect::<anyhow::Result<_>>()?
    };
    let all = a.run.setup.data.load()?;
    let space = ActionSpace::Decremental;
    let pool = a.run.pool()?;
    let t0 = std::time::Instant::now();
    let mut eval_rows = Vec::new();
    // One eval per row keeps the work to exactly the rows asked for.
    for row in &chosen {
        let plan = EvalPlan {
            adp: AdpSetting {
                space,
                action: space.ddp_action(),
            },
            policy: None,
            policy_env: actor::EnvConfig::default(),
            planners: vec![row.planner],
            fidelities: vec![row.fidelity],
            speeds: a.max_speed.clone(),
            worlds: ids.clone(),
            runs: a.runs,
            trim: 0,
            seed: a.run.seed,
            predictions: vec![crate::eval::ObstaclePrediction::Off],
            lidars: vec![crate::eval::LidarOverride::default()],
        };
        eprintln!("{}:", row.label);
        eval_rows.extend(pool.install(|| crate::eval::run(&plan, &cfg, &all))?);
    }
    let cells = calibrate::compare(&eval_rows);
    let report = calibrate::Report {
        checks: calibrate::checks(&cells),
        cells,
    };
    println!(
        "Table I protocol on the {} profile: {} worlds x {} runs, {:.0} s",
        cfg.episode.profile.name(),
        ids.len(),
        a.runs,
        t0.elapsed().as_secs_f64()
    );
    print!("{}", calibrate::render(&report));
    println!("\nour rows with their cost:\n");
    print!("{}", crate::eval::table(&eval_rows));
    if a.run.out.is_some() {
        a.run.write_json(&serde_json::json!({
            "profile": cfg.episode.profile.name(),
            "dynamics": cfg.episode.resolved_dynamics()?,
            "worlds": ids.len(),
            "runs": a.runs,
            "report": report,
            "rows": eval_rows,
        }))?;
    }
    Ok(())
}
