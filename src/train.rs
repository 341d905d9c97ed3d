//! `adp train`, `adp learner` and `adp actor`: the training service's command-line halves.
//!
//! `train` runs a learner in this process and N sandboxed actor processes (this executable's
//! `actor` subcommand) under the local supervisor; `learner` and `actor` are the two halves for
//! clusters and hand-made multi-host runs.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use actor::run::{ActorSetup, PlaneChoice};
use actor::EnvConfig;
use learner::export::space_name;
use learner::Td3Config;
use learner_service::{Learner, LearnerOptions, ServiceConfig, TrainSummary};
use planner::ActionSpace;
use proto::auth::{read_or_create_token_file, read_token_file, TlsFiles};
use proto::grpc::LearnerAddress;
use scheduler::{
    BackoffPolicy, BwrapMode, Sandbox, SandboxConfig, Supervisor, SupervisorConfig, SupervisorEvent,
};

use crate::config::{error_line, one_line, EvalConfig};
use crate::eval::PlannerKind;
use crate::greedy::{GreedyMonitor, GreedySection};
use crate::slurm::SlurmSection;

/// The embedded default of `configs/local.toml`.
const LOCAL_TOML: &str = include_str!("../configs/local.toml");

/// `[run]`: what to train.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunSection {
    /// Run name (run directory `runs/<name>`).
    pub name: String,
    /// Agent-step budget.
    pub steps: u64,
    /// Actor processes (0 = one per core).
    pub actors: u32,
    /// Training worlds (split name, range or list).
    pub worlds: String,
    /// Planner the actors drive.
    pub planner: PlannerKind,
    /// ADP action space.
    pub action_space: ActionSpace,
    /// The planner's speed cap (m/s).
    pub max_speed: f64,
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            name: "local".into(),
            steps: 40_000,
            actors: 0,
            worlds: "fit".into(),
            planner: PlannerKind::Dwa,
            action_space: ActionSpace::Decremental,
            max_speed: 1.5,
        }
    }
}

/// `[sandbox]`: limits of the actor processes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SandboxSection {
    /// `auto`, `off` or `required`.
    pub bwrap: BwrapMode,
    /// Address-space limit per actor (MiB, 0 = inherited).
    pub address_space_mb: u64,
    /// Open-file limit per actor (0 = inherited).
    pub open_files: u64,
    /// With bubblewrap, actors run in a private network namespace (no network at all) and
    /// reach the learner over its Unix socket in the run directory.
    pub private_network: bool,
}

impl SandboxSection {
    /// The sandbox of one actor process; `private_network` only when the actor reaches the
    /// learner without the network (its Unix socket) and this section asks for it.
    pub fn sandbox_config(&self, private_network: bool) -> SandboxConfig {
        SandboxConfig {
            bwrap: self.bwrap,
            address_space_bytes: self.address_space_mb << 20,
            open_files: self.open_files,
            private_network: self.private_network && private_network,
            // Shared memory (the same-node data plane and iceoryx2's files) stays writable.
            writable_dirs: vec![PathBuf::from("/dev/shm"), PathBuf::from("/tmp")],
        }
    }
}

impl Default for SandboxSection {
    fn default() -> Self {
        Self {
            bwrap: BwrapMode::Auto,
            address_space_mb: 4096,
            open_files: 1024,
            private_network: true,
        }
    }
}

/// A training run's configuration (`configs/local.toml`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// What to train.
    pub run: RunSection,
    /// The actors' environment.
    pub env: EnvConfig,
    /// TD3.
    pub td3: Td3Config,
    /// The learner process.
    pub service: ServiceConfig,
    /// The actor sandbox.
    pub sandbox: SandboxSection,
    /// Greedy evaluation of the newest policy on held-out worlds during `adp train`.
    pub greedy: GreedySection,
    /// The shape of a cluster job (`adp slurm`; ignored by `adp train`).
    pub slurm: SlurmSection,
}

impl TrainConfig {
    /// Reads `path`, or the embedded `configs/local.toml` when `None`, and checks it.
    pub fn load(path: Option<&Path>) -> anyhow::Result<Self> {
        match path {
            Some(p) => Self::parse(
                &p.display().to_string(),
                &std::fs::read_to_string(p).with_context(|| format!("cannot read config {}", p.display()))?,
            ),
            None => Self::parse("configs/local.toml (embedded)", LOCAL_TOML),
        }
    }

    /// Parses and checks the TOML `text`; errors are one line and start with `name`.
    ///
    /// `[td3] obs_dim`, `act_dim` and `laser_dim` that the text leaves out are derived from
    /// `[run] action_space` and `[env] observation` / `observe_tracks`; values it gives are
    /// kept (and the learner refuses them if they do not fit, naming both sizes).
    pub fn parse(name: &str, text: &str) -> anyhow::Result<Self> {
        let mut cfg: Self =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{name}: {}", one_line(&e.to_string())))?;
        let raw: toml::Table =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{name}: {}", one_line(&e.to_string())))?;
        let given = |key: &str| {
            raw.get("td3")
                .and_then(toml::Value::as_table)
                .is_some_and(|t| t.contains_key(key))
        };
        let (obs_dim, act_dim, laser_dim) = cfg.td3_sizes();
        if !given("obs_dim") {
            cfg.td3.obs_dim = obs_dim;
        }
        if !given("act_dim") {
            cfg.td3.act_dim = act_dim;
        }
        if !given("laser_dim") {
            cfg.td3.laser_dim = laser_dim;
        }
        cfg.td3.validate().with_context(|| format!("{name}: [td3]"))?;
        cfg.env
            .validate()
            .map_err(|e| anyhow::anyhow!("{name}: [env]: {e}"))?;
        if !(cfg.run.max_speed.is_finite() && cfg.run.max_speed > 0.0) {
            bail!("{name}: [run] max_speed = {} must be positive", cfg.run.max_speed);
        }
        if let Some(g) = cfg.run.action_space.gains() {
            if g.planner() != cfg.run.planner.name() {
                bail!(
                    "{name}: [run] action_space = \"{}\" sets the gains of {}, but planner = \"{}\": \
                     the space must name the planner it drives",
                    cfg.run.action_space,
                    g.planner(),
                    cfg.run.planner.name()
                );
            }
        }
        Ok(cfg)
    }

    /// The `[td3]` sizes `(obs_dim, act_dim, laser_dim)` that `[run] action_space` and `[env]
    /// observation` / `observe_tracks` need.
    pub fn td3_sizes(&self) -> (usize, usize, usize) {
        let (space, env) = (self.run.action_space, &self.env);
        (
            actor::obs_dim(env.observation, space, env.observe_tracks),
            space.dim(),
            env.observation.size(),
        )
    }

    /// The training worlds of `[run] worlds`.
    pub(crate) fn worlds(&self) -> anyhow::Result<Vec<usize>> {
        sim::splits::select(&self.run.worlds)
            .map_err(|e| anyhow::anyhow!("[run] worlds = {:?}: {e}", self.run.worlds))
    }

    /// The learner options of this config for `run_dir`.
    fn learner_options(&self, run_dir: &Path, token: String, resume: bool) -> anyhow::Result<LearnerOptions> {
        let worlds = self.worlds()?;
        Ok(LearnerOptions {
            run_dir: run_dir.to_owned(),
            run_id: run_id(&self.run.name),
            td3: self.td3.clone(),
            service: self.service.clone(),
            planner: self.run.planner.name().into(),
            max_speed: self.run.max_speed,
            space: self.run.action_space,
            env: self.env,
            worlds,
            budget_steps: self.run.steps,
            token,
            resume,
            handle_signals: true,
        })
    }
}

/// A run id: the name plus the start time, unique per fresh run.
fn run_id(name: &str) -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!("{name}-{secs}-{}", std::process::id())
}

/// Creates `dir` (and missing parents) readable by this user only (mode 0700), as the learner
/// would: the run directory holds the run's token and the operator credential.
fn create_private_dir(dir: &Path) -> anyhow::Result<()> {
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .with_context(|| format!("cannot create {}", dir.display()))
}

/// The run directory's token: created (mode 0600) on a fresh run, read on a resumed one.
fn run_token(run_dir: &Path) -> anyhow::Result<(PathBuf, String)> {
    create_private_dir(run_dir)?;
    let path = run_dir.join("token");
    let token = read_or_create_token_file(&path)?;
    Ok((path, token))
}

/// Command-line overrides of a config.
pub struct Overrides {
    /// `--steps`.
    pub steps: Option<u64>,
    /// `--actors`.
    pub actors: Option<u32>,
    /// `--out`.
    pub out: Option<PathBuf>,
    /// `--listen` (learner only).
    pub listen: Option<String>,
    /// `--allow-insecure-listen` (learner only).
    pub allow_insecure_listen: bool,
}

fn prepare(config: Option<&Path>, o: &Overrides, resume: bool) -> anyhow::Result<(TrainConfig, PathBuf)> {
    let mut cfg = TrainConfig::load(config)?;
    if let Some(s) = o.steps {
        cfg.run.steps = s;
    }
    if let Some(a) = o.actors {
        cfg.run.actors = a;
    }
    if let Some(l) = &o.listen {
        cfg.service.listen = l.clone();
    }
    cfg.service.allow_insecure_listen |= o.allow_insecure_listen;
    // Refuse an unusable [service] before anything is created.
    cfg.service.check()?;
    let out = o
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(&cfg.run.name));
    if resume && !out.is_dir() {
        bail!("--resume: run directory {} does not exist", out.display());
    }
    create_private_dir(&out)?;
    let copy = out.join("config.toml");
    let text = toml::to_string_pretty(&cfg).expect("config serializes");
    std::fs::write(&copy, text).with_context(|| format!("cannot write {}", copy.display()))?;
    Ok((cfg, out))
}

/// Prints how the run ended; `command` (`train` or `learner`) is how to continue it.
fn print_summary(s: &TrainSummary, out: &Path, space: &str, command: &str) {
    eprintln!(
        "{} after {} agent steps and {} updates; checkpoint {}",
        if s.completed { "finished" } else { "stopped" },
        s.inserts,
        s.updates,
        s.checkpoint.display()
    );
    if let Some(e) = &s.export {
        eprintln!(
            "exported policy ({space} action space): {} (policy.onnx, policy.safetensors, policy.json)",
            e.display()
        );
    }
    if !s.completed {
        eprintln!("continue with: adp {command} --out {} --resume", out.display());
    }
}

/// `adp train`.
pub fn train(config: Option<&Path>, o: &Overrides, resume: bool) -> anyhow::Result<()> {
    let (cfg, out) = prepare(config, o, resume)?;
    let (token_path, token) = run_token(&out)?;
    let actors = match cfg.run.actors {
        0 => std::thread::available_parallelism().map_or(2, |n| n.get() as u32),
        n => n,
    };
    let learner = Learner::start(cfg.learner_options(&out, token, resume)?)?;
    let exe = std::env::current_exe().context("cannot find this executable to start actors")?;
    // Without the learner's Unix socket, actors need the network to reach it.
    let sandbox = Sandbox::new(cfg.sandbox.sandbox_config(learner.socket().is_some()))?;
    // Actors on this host talk to the learner over its Unix socket when it has one.
    let address = match learner.socket() {
        Some(p) => format!("unix:{}", p.display()),
        None => learner.addr().to_string(),
    };
    let args = vec![
        "actor".to_string(),
        "--learner".into(),
        address.clone(),
        "--token-file".into(),
        token_path.display().to_string(),
    ];
    let mut supervisor = Supervisor::start(
        SupervisorConfig {
            program: exe,
            args,
            actors,
            backoff: BackoffPolicy::default(),
        },
        sandbox,
        |rank| (vec!["--rank".into(), rank.to_string()], vec![]),
        Instant::now(),
    )?;
    tracing::info!(
        run_id = learner.run_id(),
        out = %out.display(),
        actors,
        bwrap = ?supervisor.bwrap_status(),
        learner = %address,
        "adp train started; Ctrl-C stops with a checkpoint"
    );
    let bar = indicatif::ProgressBar::new(cfg.run.steps);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} steps ({per_sec}) {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let mut last = (Instant::now(), 0u64);
    let mut updates_per_s = 0.0;
    let mut greedy = GreedyMonitor::new(
        &cfg.greedy,
        &out,
        cfg.run.planner,
        cfg.run.action_space,
        cfg.run.max_speed,
        cfg.env,
        cfg.td3.seed,
        learner.status().inserts,
    )?;
    while !learner.finished() {
        std::thread::sleep(Duration::from_millis(250));
        for event in supervisor.poll(Instant::now()) {
            log_supervisor_event(&event);
        }
        let s = learner.status();
        if let Some(g) = greedy.as_mut() {
            match g.poll(s.inserts, || learner.latest_policy()) {
                Some(Ok(r)) => bar.println(crate::greedy::describe(&r)),
                Some(Err(e)) => bar.println(error_line(&e)),
                None => {}
            }
        }
        let dt = last.0.elapsed().as_secs_f64();
        if dt >= 2.0 {
            updates_per_s = (s.updates - last.1) as f64 / dt;
            last = (Instant::now(), s.updates);
        }
        bar.set_position(s.inserts.min(cfg.run.steps));
        bar.set_message(format!(
            "| {} episodes, success {} | {:.1} updates/s | policy v{} | {} actors",
            s.episodes,
            s.success_rate
                .map_or("-".into(), |r| format!("{:.0}%", r * 100.0)),
            updates_per_s,
            s.policy_version,
            s.live_actors
        ));
    }
    bar.finish();
    if let Some(g) = greedy {
        let inserts = learner.status().inserts;
        for r in g.finish(inserts, || learner.latest_policy()) {
            eprintln!(
                "{}",
                r.map_or_else(|e| error_line(&e), |r| crate::greedy::describe(&r))
            );
        }
    }
    let summary = learner.wait()?;
    supervisor.shutdown(Duration::from_secs(3));
    print_summary(&summary, &out, &space_name(cfg.run.action_space), "train");
    Ok(())
}

/// Logs what the actor supervisor reports: a crash as a warning, a failed restart as an error.
fn log_supervisor_event(e: &SupervisorEvent) {
    match e {
        SupervisorEvent::Exited {
            rank,
            pid,
            exit,
            restart_in_ms: Some(ms),
        } => tracing::warn!(rank, pid, ?exit, restart_in_ms = ms, "actor process crashed"),
        SupervisorEvent::Exited { rank, pid, exit, .. } => {
            tracing::debug!(rank, pid, ?exit, "actor process ended")
        }
        SupervisorEvent::Restarted { rank, pid } => tracing::info!(rank, pid, "actor process restarted"),
        SupervisorEvent::RestartFailed {
            rank,
            error,
            restart_in_ms,
        } => tracing::error!(rank, restart_in_ms, "cannot restart the actor process: {error}"),
    }
}

/// `adp learner`.
pub fn learner(
    config: Option<&Path>,
    o: &Overrides,
    resume: bool,
    token_file: Option<&Path>,
) -> anyhow::Result<()> {
    let (cfg, out) = prepare(config, o, resume)?;
    let token = match token_file {
        Some(p) => read_token_file(p)?,
        None => run_token(&out)?.1,
    };
    let learner = Learner::start(cfg.learner_options(&out, token, resume)?)?;
    let summary = learner.wait()?;
    print_summary(&summary, &out, &space_name(cfg.run.action_space), "learner");
    Ok(())
}

/// Options of `adp actor`.
#[derive(clap::Args, Debug)]
pub struct ActorArgs {
    /// The learner's host:port, or unix:PATH for its Unix socket (<run dir>/learner.sock)
    /// on the same host.
    #[arg(long)]
    pub learner: String,
    /// The run's token file (mode 0600).
    #[arg(long)]
    pub token_file: PathBuf,
    /// This actor's rank (default: --rank-offset + $SLURM_PROCID); seeds derive from it.
    #[arg(long)]
    pub rank: Option<u32>,
    /// Added to $SLURM_PROCID to make the rank (for a second `srun` step of actors).
    #[arg(long, default_value_t = 0, conflicts_with = "rank")]
    pub rank_offset: u32,
    /// Data plane: auto (shared memory when the learner is on this host), grpc or shm.
    #[arg(long, default_value = "auto")]
    pub data_plane: PlaneChoice,
    /// CA certificate of the learner (PEM); enables TLS.
    #[arg(long)]
    pub tls_ca: Option<PathBuf>,
    /// Server name in the learner's certificate (default: the host of --learner).
    #[arg(long, requires = "tls_ca")]
    pub tls_domain: Option<String>,
    /// Client certificate for mutual TLS (PEM).
    #[arg(long, requires_all = ["tls_ca", "tls_key"])]
    pub tls_cert: Option<PathBuf>,
    /// Client key for mutual TLS (PEM).
    #[arg(long, requires_all = ["tls_ca", "tls_cert"])]
    pub tls_key: Option<PathBuf>,
    /// Give up after the learner has been unreachable this many seconds.
    #[arg(long = "give-up-after", default_value_t = 600)]
    pub give_up_after_s: u64,
    /// Run in the sandbox of this training config's `[sandbox]` (limits, bubblewrap), as
    /// `adp train` runs its actors: the process re-executes itself sandboxed and forwards
    /// SIGTERM/SIGINT to it. `adp slurm` sets it.
    #[arg(long, value_name = "CONFIG")]
    pub sandbox: Option<PathBuf>,
}

/// `adp actor`.
pub fn actor(a: ActorArgs) -> anyhow::Result<()> {
    let token = read_token_file(&a.token_file)?;
    let rank = match a.rank {
        Some(r) => r,
        None => {
            let procid: u32 = match std::env::var("SLURM_PROCID") {
                Ok(v) => v
                    .parse()
                    .map_err(|_| anyhow::anyhow!("SLURM_PROCID = {v:?} is not a task number"))?,
                Err(_) => 0,
            };
            a.rank_offset
                .checked_add(procid)
                .context("--rank-offset + SLURM_PROCID overflows")?
        }
    };
    if let Some(config) = &a.sandbox {
        return crate::actor_sandbox::run(&a, rank, config);
    }
    let eval_cfg = EvalConfig::load(None)?;
    let factory =
        move |name: &str, seed: u64| -> Result<Box<dyn planner::Planner>, actor::run::FactoryError> {
            Ok(name.parse::<PlannerKind>()?.build(&eval_cfg, seed))
        };
    let tls = a.tls_ca.is_some().then(|| TlsFiles {
        cert: a.tls_cert.clone(),
        key: a.tls_key.clone(),
        ca: a.tls_ca.clone(),
        domain: a.tls_domain.clone(),
    });
    let setup = ActorSetup {
        learner: LearnerAddress {
            addr: a.learner.clone(),
            token: Some(token),
            tls,
        },
        rank,
        plane: a.data_plane,
        episode: EvalConfig::load(None)?.episode,
        make_planner: &factory,
        give_up_after: Duration::from_secs(a.give_up_after_s),
    };
    Ok(actor::run::run(&setup)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objective_weight_spaces_name_the_run_planner() {
        let parse = |planner: &str, space: &str| {
            TrainConfig::parse(
                "t.toml",
                &format!("[run]\nplanner = \"{planner}\"\naction_space = \"{space}\"\n"),
            )
        };
        let cfg = parse("dwa", "decremental+weights:dwa").unwrap();
        assert_eq!(
            cfg.run.action_space,
            ActionSpace::DecrementalWeights(planner::Gains::Dwa)
        );
        assert_eq!(
            parse("dwa", "velocity").unwrap().run.action_space,
            ActionSpace::Velocity
        );
        let e = parse("mppi", "weights:dwa").unwrap_err().to_string();
        assert_eq!(
            e,
            "t.toml: [run] action_space = \"weights:dwa\" sets the gains of dwa, but planner = \"mppi\": \
             the space must name the planner it drives"
        );
        let e = parse("dwa", "weights").unwrap_err().to_string();
        assert!(e.contains("needs the planner: write `weights:dwa`"), "{e}");
        let e = parse("log-mppi", "weights:log-mppi").unwrap_err().to_string();
        assert!(e.contains("`log-mppi` has no objective gains"), "{e}");
    }

    /// The network sizes follow the action space and the observation layout unless the file
    /// gives them; a given size that does not fit is kept for the learner to refuse.
    #[test]
    fn td3_sizes_follow_the_space_and_the_layout_unless_given() {
        let dims = |text: &str| {
            let c = TrainConfig::parse("t.toml", text).unwrap();
            (c.td3.obs_dim, c.td3.act_dim, c.td3.laser_dim)
        };
        // 720 laser values + the previous action + v, w and two goal pairs.
        assert_eq!(dims(""), (730, 4, 720));
        assert_eq!(dims("[run]\naction_space = \"velocity\"\n"), (728, 2, 720));
        assert_eq!(dims("[env]\nobservation = \"sectors:25\"\n"), (35, 4, 25));
        // Four tracks of four floats each.
        assert_eq!(dims("[env]\nobserve_tracks = 4\n"), (746, 4, 720));
        // DWA's four gains after the four schedule values.
        assert_eq!(
            dims("[run]\nplanner = \"dwa\"\naction_space = \"decremental+weights:dwa\"\n"),
            (734, 8, 720)
        );
        assert_eq!(dims("[td3]\nobs_dim = 731\n"), (731, 4, 720));
    }
}
