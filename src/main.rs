//! `adp`: train and ship adaptive-dynamics navigation planners on BARN.

mod bench;
mod calibrate;
mod config;
mod eval;
mod experiment;
mod export;
mod greedy;
mod policy;
mod render;
mod slurm;
mod train;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

use config::EvalConfig;
use eval::{AdpSetting, EvalPlan, Fidelity, PlannerKind};
use planner::ActionSpace;
use sim::splits::SplitFile;
use sim::{Profile, World};

#[derive(Parser)]
#[command(
    name = "adp",
    version,
    about = "Adaptive/decremental dynamics planning on BARN"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

/// Where the worlds come from: the embedded BARN data unless files are given.
#[derive(clap::Args, Clone)]
struct WorldData {
    /// Obstacles file in the BARN JSONL format (default: the embedded BARN worlds).
    #[arg(long, requires = "paths")]
    obstacles: Option<PathBuf>,
    /// Paths file in the BARN JSONL format (default: the embedded BARN paths).
    #[arg(long, requires = "obstacles")]
    paths: Option<PathBuf>,
}

impl WorldData {
    fn load(&self) -> anyhow::Result<std::borrow::Cow<'static, [World]>> {
        match (&self.obstacles, &self.paths) {
            (Some(o), Some(p)) => {
                let ot =
                    std::fs::read_to_string(o).with_context(|| format!("cannot read {}", o.display()))?;
                let pt =
                    std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
                Ok(sim::barn::parse(&o.display().to_string(), &ot, &p.display().to_string(), &pt)?.into())
            }
            _ => Ok(sim::barn::worlds().into()),
        }
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// Evaluate planners x fidelity x speeds on a set of worlds and print the table.
    Eval {
        /// Planner(s), comma-separated.
        #[arg(long, value_enum, value_delimiter = ',', default_value = "dwa")]
        planner: Vec<PlannerKind>,
        /// Fidelity strategy (or strategies), comma-separated.
        #[arg(long, value_enum, value_delimiter = ',', default_value = "ddp")]
        fidelity: Vec<Fidelity>,
        /// ADP action space (with --fidelity adp; default: the policy's, else decremental). When
        /// given, the policy's space must be the same.
        #[arg(long)]
        action: Option<ActionSpace>,
        /// ADP policy (with --fidelity adp): a trained policy, i.e. the export directory of
        /// `adp export` or `adp train` (or its policy.json), run closed-loop; or a TOML file
        /// with a constant normalized `action = [...]`. Default: the constant action that
        /// reproduces DDP, ADP's initialization.
        #[arg(long)]
        policy: Option<PathBuf>,
        /// Speed cap(s) in m/s, comma-separated: one row per value.
        #[arg(long, value_delimiter = ',', default_value = "1.5")]
        max_speed: Vec<f64>,
        /// Worlds: a split (train, test, hardest50, all), a range 0..50, or a list 3,7,9.
        #[arg(long, default_value = "test")]
        worlds: String,
        /// Runs per world.
        #[arg(long, default_value_t = 1)]
        runs: usize,
        /// Drop this many best and worst runs (by time) of each world before averaging.
        #[arg(long, default_value_t = 0)]
        trim: usize,
        /// Base seed of every run's noise.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Worker threads (default: all cores).
        #[arg(long)]
        jobs: Option<usize>,
        /// Also write the rows and per-world results as JSON here.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Configuration file (default: the embedded configs/eval.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Simulator profile (ideal, gazebo-jackal, custom): overrides [episode] profile.
        #[arg(long, value_parser = parse_profile)]
        profile: Option<Profile>,
        #[command(flatten)]
        data: WorldData,
    },
    /// Run the DDP paper's Table I protocol (300 worlds x 3 runs x 1.0/1.5/2.0 m/s; DWA,
    /// DWA-DDP, MPPI, MPPI-DDP, Log-MPPI, Log-MPPI-DDP, the DDP system) and print our table
    /// beside the paper's with the difference per cell and the calibration checks.
    Calibrate {
        /// Rows to run, comma-separated labels (default: all seven).
        #[arg(long, value_delimiter = ',')]
        rows: Vec<String>,
        /// Speed caps, comma-separated (default: the paper's 1.0, 1.5, 2.0).
        #[arg(long, value_delimiter = ',', default_value = "1.0,1.5,2.0")]
        max_speed: Vec<f64>,
        /// Worlds: a split (train, test, hardest50, all), a range 0..50, or a list 3,7,9.
        #[arg(long, default_value = "all")]
        worlds: String,
        /// Runs per world.
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Base seed of every run's noise.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Worker threads (default: all cores).
        #[arg(long)]
        jobs: Option<usize>,
        /// Also write the comparison, the checks and every eval row as JSON here.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Configuration file (default: the embedded configs/eval.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Simulator profile (ideal, gazebo-jackal, custom): overrides [episode] profile.
        #[arg(long, value_parser = parse_profile)]
        profile: Option<Profile>,
        #[command(flatten)]
        data: WorldData,
    },
    /// Draw one episode: world, trajectory, footprints and fidelity-coloured rollouts.
    Render {
        /// World id.
        #[arg(long)]
        world: usize,
        /// Planner.
        #[arg(long, value_enum, default_value = "dwa")]
        planner: PlannerKind,
        /// Fidelity strategy.
        #[arg(long, value_enum, default_value = "ddp")]
        fidelity: Fidelity,
        /// ADP action space (with --fidelity adp).
        #[arg(long, default_value = "decremental")]
        action: ActionSpace,
        /// ADP constant-action policy file (see `adp eval --help`).
        #[arg(long)]
        policy: Option<PathBuf>,
        /// Speed cap (m/s).
        #[arg(long, default_value_t = 1.5)]
        max_speed: f64,
        /// Noise seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Draw the sampled rollouts every this many seconds.
        #[arg(long, default_value_t = 2.0)]
        rollouts_every: f64,
        /// Draw the footprint every this many seconds.
        #[arg(long, default_value_t = 0.5)]
        footprint_every: f64,
        /// Output picture (.png or .svg).
        #[arg(long)]
        out: PathBuf,
        /// Configuration file (default: the embedded configs/eval.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Simulator profile (ideal, gazebo-jackal, custom): overrides [episode] profile.
        #[arg(long, value_parser = parse_profile)]
        profile: Option<Profile>,
        #[command(flatten)]
        data: WorldData,
    },
    /// Export a checkpoint's policy: policy.onnx, policy.safetensors and policy.json.
    Export {
        /// Checkpoint directory written by the learner (verified before use).
        #[arg(long)]
        checkpoint: PathBuf,
        /// Output directory (created if needed; existing policy files are replaced).
        #[arg(long)]
        out: PathBuf,
        /// Action space the run trained in.
        #[arg(long, default_value = "decremental")]
        action: ActionSpace,
    },
    /// Train an ADP policy on this machine: a learner and N sandboxed actor processes.
    Train {
        /// Run configuration (default: the embedded configs/local.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Total agent steps of the run (overrides [run] steps).
        #[arg(long)]
        steps: Option<u64>,
        /// Actor processes (overrides [run] actors; 0 = one per core).
        #[arg(long)]
        actors: Option<u32>,
        /// Run directory (default: runs/<name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Continue the run in --out from its newest valid checkpoint up to --steps.
        #[arg(long)]
        resume: bool,
    },
    /// The learner half of a distributed run: gRPC control and data planes, shared memory,
    /// replay, TD3, checkpoints.
    Learner {
        /// Run configuration (default: the embedded configs/local.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Total agent steps of the run (overrides [run] steps).
        #[arg(long)]
        steps: Option<u64>,
        /// Run directory (default: runs/<name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Address to listen on (overrides [service] listen), e.g. 0.0.0.0:50051.
        #[arg(long)]
        listen: Option<String>,
        /// Allow --listen on a non-loopback address without [service.tls] (the token then
        /// crosses the network in clear text); for trusted networks only.
        #[arg(long)]
        allow_insecure_listen: bool,
        /// The run's token file (mode 0600; default: <out>/token, created if missing).
        #[arg(long)]
        token_file: Option<PathBuf>,
        /// Continue the run in --out from its newest valid checkpoint.
        #[arg(long)]
        resume: bool,
    },
    /// The actor half of a distributed run: connects to a learner and runs assignments.
    Actor {
        /// The learner's host:port, or unix:PATH for its Unix socket (<run dir>/learner.sock)
        /// on the same host.
        #[arg(long)]
        learner: String,
        /// The run's token file (mode 0600).
        #[arg(long)]
        token_file: PathBuf,
        /// This actor's rank (default: --rank-offset + $SLURM_PROCID); seeds derive from it.
        #[arg(long)]
        rank: Option<u32>,
        /// Added to $SLURM_PROCID to make the rank (for a second `srun` step of actors).
        #[arg(long, default_value_t = 0, conflicts_with = "rank")]
        rank_offset: u32,
        /// Data plane: auto (shared memory when the learner is on this host), grpc or shm.
        #[arg(long, default_value = "auto")]
        data_plane: actor::run::PlaneChoice,
        /// CA certificate of the learner (PEM); enables TLS.
        #[arg(long)]
        tls_ca: Option<PathBuf>,
        /// Server name in the learner's certificate (default: the host of --learner).
        #[arg(long, requires = "tls_ca")]
        tls_domain: Option<String>,
        /// Client certificate for mutual TLS (PEM).
        #[arg(long, requires_all = ["tls_ca", "tls_key"])]
        tls_cert: Option<PathBuf>,
        /// Client key for mutual TLS (PEM).
        #[arg(long, requires_all = ["tls_ca", "tls_cert"])]
        tls_key: Option<PathBuf>,
        /// Give up after the learner has been unreachable this many seconds.
        #[arg(long, default_value_t = 600)]
        give_up_after: u64,
    },
    /// Print the sbatch script of a cluster training job (learner on the first node, actors on
    /// every node, requeue resumes the run).
    Slurm {
        /// Run configuration with a [slurm] table (default: the embedded configs/slurm.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Nodes (overrides [slurm] nodes).
        #[arg(long)]
        nodes: Option<u32>,
        /// Actor tasks per node (overrides [slurm] actors_per_node).
        #[arg(long)]
        actors_per_node: Option<u32>,
        /// Time limit [D-]HH:MM:SS (overrides [slurm] time).
        #[arg(long)]
        time: Option<String>,
        /// Partition (overrides [slurm] partition).
        #[arg(long)]
        partition: Option<String>,
        /// Account (overrides [slurm] account).
        #[arg(long)]
        account: Option<String>,
        /// Total agent steps (overrides [run] steps).
        #[arg(long)]
        steps: Option<u64>,
        /// Run directory (default: runs/<name>; made absolute; its logs/ is created now).
        #[arg(long)]
        run_dir: Option<PathBuf>,
        /// The adp executable on the compute nodes (default: [slurm] adp, else this one).
        #[arg(long)]
        adp: Option<PathBuf>,
    },
    /// Run an experiment (configs/experiments/NAME.toml): train S seeds per arm, evaluate
    /// every policy with the papers' protocol against DDP, the best constant schedule, the
    /// untrained policy and the state-shuffled policy, and write report.md with tables,
    /// paired statistics and figures. Resumable.
    Experiment {
        /// The experiment file.
        #[arg(long)]
        config: PathBuf,
        /// Experiment directory (default: runs/experiments/<name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Continue the experiment in --out, skipping the stages whose results exist.
        #[arg(long)]
        resume: bool,
        /// Only these planners (comma-separated; a subset of the file's).
        #[arg(long, value_enum, value_delimiter = ',')]
        planners: Vec<PlannerKind>,
        /// Only these action spaces (comma-separated; a subset of the file's).
        #[arg(long, value_delimiter = ',')]
        spaces: Vec<ActionSpace>,
        /// Only these speed caps (comma-separated; a subset of the file's).
        #[arg(long, value_delimiter = ',')]
        speeds: Vec<f64>,
        /// Only the first this many training seeds of each arm.
        #[arg(long)]
        seeds: Option<usize>,
        /// Agent steps per training run (overrides [train.run] steps).
        #[arg(long)]
        steps: Option<u64>,
        /// Worker threads of the evaluations (default: all cores).
        #[arg(long)]
        jobs: Option<usize>,
        /// Evaluate only shard K of N of the test worlds (e.g. 0/8) of every pending
        /// evaluation, into `<stage file>.shard-K-of-N`; a later run without --shard merges a
        /// complete set. Training and constant searches must be finished.
        #[arg(long, conflicts_with_all = ["no_eval", "emit_slurm"])]
        shard: Option<experiment::shard::Shard>,
        /// Run only the training and constant-search stages (no evaluation, no report).
        #[arg(long, conflicts_with = "emit_slurm")]
        no_eval: bool,
        /// Print a SLURM job script that runs this experiment (training, evaluation sharded over
        /// the [slurm] tasks, merge and report) and create --out with its experiment.toml.
        #[arg(long, conflicts_with = "resume")]
        emit_slurm: bool,
    },
    /// List or inspect worlds and splits.
    Worlds {
        #[command(subcommand)]
        cmd: WorldsCmd,
    },
    /// Measure the DESIGN §8 figures on this machine (release build) next to their targets.
    Bench {
        /// Parts to run (default: all, in this order).
        #[arg(value_enum)]
        parts: Vec<bench::Part>,
        /// Timed TD3 updates (learner).
        #[arg(long, default_value_t = 200)]
        updates: usize,
        /// A Python with torch and numpy: also time the same update in PyTorch and print the
        /// ratio (learner).
        #[arg(long)]
        python: Option<PathBuf>,
        /// Step records through shared memory; a quarter of them through gRPC (transport).
        #[arg(long, default_value_t = 400_000)]
        records: usize,
        /// Agent steps per collecting thread (collect).
        #[arg(long, default_value_t = 2000)]
        collect_steps: u64,
        /// Agent-step budget of the end-to-end `adp train` run (train).
        #[arg(long, default_value_t = 4000)]
        train_steps: u64,
        /// Actor processes of the end-to-end run (default: one per core).
        #[arg(long, default_value_t = 0)]
        train_actors: u32,
        /// Also write the figures as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum WorldsCmd {
    /// Print the world ids of a selection, one per line.
    List {
        /// A split (train, test, hardest50, all), a range 0..50, or a list 3,7,9.
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
    /// Print a split file drawn with another seed (the format of configs/splits/barn.toml).
    Splits {
        /// Seed for the training-world draw.
        #[arg(long)]
        seed: u64,
    },
}

/// Parses a simulator profile name.
fn parse_profile(s: &str) -> Result<Profile, String> {
    serde_json::from_value(serde_json::Value::String(s.to_string()))
        .map_err(|_| format!("unknown profile `{s}` (expected ideal, gazebo-jackal or custom)"))
}

/// The evaluation config at `path` (or the embedded one) with `profile` applied.
fn eval_config(path: Option<&std::path::Path>, profile: Option<Profile>) -> anyhow::Result<EvalConfig> {
    let mut cfg = EvalConfig::load(path)?;
    if let Some(p) = profile {
        let custom = cfg.episode.dynamics.filter(|_| p == Profile::Custom);
        cfg.episode = cfg.episode.with_profile(p, custom);
        cfg.episode
            .validate()
            .map_err(|e| anyhow::anyhow!("--profile {}: {e}", p.name()))?;
    }
    Ok(cfg)
}

fn main() -> ExitCode {
    keep_freed_memory();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", config::one_line(&format!("{e:#}")));
            ExitCode::FAILURE
        }
    }
}

/// Tells glibc's allocator to keep freed memory for reuse. A TD3 update allocates and frees
/// several megabytes of tensors (activations, gradients, weight copies of up to 1.5 MB); with
/// glibc's defaults part of that goes back to the kernel after every update (blocks above the
/// mmap threshold, and heap tops above the trim threshold), so the next update page-faults it
/// in again: about 1000 faults per update measured with `perf stat -e page-faults` on
/// `adp bench learner`. Blocks up to 32 MiB now come from the heap, and a heap keeps up to
/// 256 MiB of free space at its top.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets allocator parameters; it is called before any other thread
    // exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.cmd {
        Cmd::Bench {
            parts,
            updates,
            python,
            records,
            collect_steps,
            train_steps,
            train_actors,
            json,
        } => bench::run(&bench::BenchArgs {
            parts,
            updates,
            python,
            records,
            collect_steps,
            train_steps,
            train_actors,
            json,
        }),
        Cmd::Train {
            config,
            steps,
            actors,
            out,
            resume,
        } => train::train(
            config.as_deref(),
            &train::Overrides {
                steps,
                actors,
                out,
                listen: None,
                allow_insecure_listen: false,
            },
            resume,
        ),
        Cmd::Learner {
            config,
            steps,
            out,
            listen,
            allow_insecure_listen,
            token_file,
            resume,
        } => train::learner(
            config.as_deref(),
            &train::Overrides {
                steps,
                actors: None,
                out,
                listen,
                allow_insecure_listen,
            },
            resume,
            token_file.as_deref(),
        ),
        Cmd::Actor {
            learner,
            token_file,
            rank,
            rank_offset,
            data_plane,
            tls_ca,
            tls_domain,
            tls_cert,
            tls_key,
            give_up_after,
        } => train::actor(train::ActorArgs {
            learner,
            token_file,
            rank,
            rank_offset,
            data_plane,
            tls_ca,
            tls_domain,
            tls_cert,
            tls_key,
            give_up_after_s: give_up_after,
        }),
        Cmd::Slurm {
            config,
            nodes,
            actors_per_node,
            time,
            partition,
            account,
            steps,
            run_dir,
            adp,
        } => {
            let o = slurm::SlurmOverrides {
                nodes,
                actors_per_node,
                time,
                partition,
                account,
                steps,
            };
            print!(
                "{}",
                slurm::generate(config.as_deref(), &o, run_dir.as_deref(), adp.as_deref())?
            );
            Ok(())
        }
        Cmd::Eval {
            planner,
            fidelity,
            action,
            policy,
            max_speed,
            worlds,
            runs,
            trim,
            seed,
            jobs,
            out,
            config,
            profile,
            data,
        } => {
            let cfg = eval_config(config.as_deref(), profile)?;
            let ids = SplitFile::embedded().select(&worlds)?;
            if runs == 0 {
                anyhow::bail!("--runs must be at least 1");
            }
            if policy.is_some() && !fidelity.contains(&Fidelity::Adp) {
                anyhow::bail!("--policy applies to --fidelity adp, which is not among the fidelities");
            }
            let all = data.load()?;
            let ddp = |space: ActionSpace| AdpSetting {
                space,
                action: space.ddp_action(),
            };
            // The source of a trained policy is reported after the run, so that errors stay
            // one line.
            let (adp, net, source) = match &policy {
                None => (ddp(action.unwrap_or(ActionSpace::Decremental)), None, None),
                Some(p) => match policy::load(p, action)? {
                    policy::EvalPolicy::Constant { space, action } => {
                        (AdpSetting { space, action }, None, None)
                    }
                    policy::EvalPolicy::Learned(l) => {
                        let s = &l.card.source;
                        let source = format!(
                            "policy {}: run {}, {} updates, {} action space, layers {:?}, an action \
                             every {} planner cycles, laser clipped at {} m",
                            l.card_path.display(),
                            s.run_id,
                            s.updates,
                            learner::export::space_name(l.space),
                            l.net.dims(),
                            l.env.agent_period_cycles,
                            l.env.laser_clip_m
                        );
                        (ddp(l.space), Some((l.net, l.env)), Some(source))
                    }
                },
            };
            let plan = EvalPlan {
                adp,
                policy_env: net
                    .as_ref()
                    .map_or_else(actor::EnvConfig::default, |(_, env)| *env),
                policy: net.map(|(net, _)| net),
                planners: planner,
                fidelities: fidelity,
                speeds: max_speed,
                worlds: ids,
                runs,
                trim,
                seed,
            };
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(jobs.unwrap_or(0))
                .build()
                .context("cannot start worker threads")?;
            let rows = pool.install(|| eval::run(&plan, &cfg, &all))?;
            if let Some(source) = source {
                eprintln!("{source}");
            }
            print!("{}", eval::table(&rows));
            if let Some(path) = out {
                let json = serde_json::to_string_pretty(&rows)?;
                std::fs::write(&path, json).with_context(|| format!("cannot write {}", path.display()))?;
            }
            Ok(())
        }
        Cmd::Calibrate {
            rows,
            max_speed,
            worlds,
            runs,
            seed,
            jobs,
            out,
            config,
            profile,
            data,
        } => {
            let cfg = eval_config(config.as_deref(), profile)?;
            let ids = SplitFile::embedded().select(&worlds)?;
            let chosen: Vec<&calibrate::PaperRow> = if rows.is_empty() {
                calibrate::TABLE_I.iter().collect()
            } else {
                rows.iter()
                    .map(|r| {
                        calibrate::paper_row(r).with_context(|| {
                            let labels: Vec<&str> = calibrate::TABLE_I.iter().map(|p| p.label).collect();
                            format!("--rows: unknown row `{r}` (expected {})", labels.join(", "))
                        })
                    })
                    .collect::<anyhow::Result<_>>()?
            };
            let all = data.load()?;
            let space = ActionSpace::Decremental;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(jobs.unwrap_or(0))
                .build()
                .context("cannot start worker threads")?;
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
                    speeds: max_speed.clone(),
                    worlds: ids.clone(),
                    runs,
                    trim: 0,
                    seed,
                };
                eprintln!("{}:", row.label);
                eval_rows.extend(pool.install(|| eval::run(&plan, &cfg, &all))?);
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
                runs,
                t0.elapsed().as_secs_f64()
            );
            print!("{}", calibrate::render(&report));
            println!("\nour rows with their cost:\n");
            print!("{}", eval::table(&eval_rows));
            if let Some(path) = out {
                let json = serde_json::json!({
                    "profile": cfg.episode.profile.name(),
                    "dynamics": cfg.episode.resolved_dynamics().map_err(anyhow::Error::msg)?,
                    "worlds": ids.len(),
                    "runs": runs,
                    "report": report,
                    "rows": eval_rows,
                });
                std::fs::write(&path, serde_json::to_string_pretty(&json)?)
                    .with_context(|| format!("cannot write {}", path.display()))?;
            }
            Ok(())
        }
        Cmd::Render {
            world,
            planner,
            fidelity,
            action,
            policy,
            max_speed,
            seed,
            rollouts_every,
            footprint_every,
            out,
            config,
            profile,
            data,
        } => {
            let cfg = eval_config(config.as_deref(), profile)?;
            let all = data.load()?;
            let w = all
                .get(world)
                .with_context(|| format!("world {world} does not exist ({} worlds)", all.len()))?;
            let adp = AdpSetting {
                space: action,
                action: match &policy {
                    Some(p) => policy::load_constant_action(p, action)?,
                    None => action.ddp_action(),
                },
            };
            let job = render::RenderJob {
                world: w,
                episode: cfg.episode,
                planner: planner.build(&cfg, seed),
                schedule: fidelity.schedule(&adp)?,
                max_speed,
                seed,
                rollout_every_s: rollouts_every,
                footprint_every_s: footprint_every,
            };
            let r = render::render(job, &out)?;
            println!(
                "world {} {:?}: time {:.2} s, score {:.3}; picture written to {}",
                r.world,
                r.status,
                r.time_s,
                r.score,
                out.display()
            );
            Ok(())
        }
        Cmd::Export {
            checkpoint,
            out,
            action,
        } => export::run(&checkpoint, &out, action),
        Cmd::Experiment {
            config,
            out,
            resume,
            planners,
            spaces,
            speeds,
            seeds,
            steps,
            jobs,
            shard,
            no_eval,
            emit_slurm,
        } => {
            let report = experiment::run(&experiment::Args {
                config,
                out,
                resume,
                restrict: experiment::config::Restrict {
                    planners,
                    spaces,
                    speeds,
                    seeds,
                    steps,
                },
                jobs,
                shard,
                no_eval,
                emit_slurm,
            })?;
            if let Some(report) = report {
                println!("{}", report.display());
            }
            Ok(())
        }
        Cmd::Worlds { cmd } => match cmd {
            WorldsCmd::List { split } => {
                for id in SplitFile::embedded().select(&split)? {
                    println!("{id}");
                }
                Ok(())
            }
            WorldsCmd::Show { id, data } => {
                let all = data.load()?;
                let w = all
                    .get(id)
                    .with_context(|| format!("world {id} does not exist ({} worlds)", all.len()))?;
                println!("world {}", w.id);
                println!("cylinders {}", w.cylinders.len());
                println!("start {:.3} {:.3} {:.4}", w.start.x, w.start.y, w.start.yaw);
                println!(
                    "goal {:.3} {:.3} (radius {} m)",
                    w.goal.x, w.goal.y, w.goal_radius
                );
                println!("path_length_m {:.6}", w.path_length_m);
                println!("optimal_time_s {:.6}", w.optimal_time_s);
                Ok(())
            }
            WorldsCmd::Splits { seed } => {
                print!("{}", sim::splits::render_toml(seed));
                Ok(())
            }
        },
    }
}
