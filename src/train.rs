//! `adp train`, `adp learner` and `adp actor`: the training service's command-line halves.
//!
//! `train` runs a learner in this process and N sandboxed actor processes (this executable's
//! `actor` subcommand) under the local supervisor; `learner` and `actor` are the two halves for
//! clusters and hand-made multi-host runs.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};

use learner::export::{record_trained_for, space_name, TrainedFor};
use learner::LearnerDevice;
use learner_service::{Learner, TrainSummary};
use proto::auth::{read_or_create_token_file, read_token_file};
use scheduler::{BackoffPolicy, Sandbox, Supervisor, SupervisorConfig, SupervisorEvent};

use crate::config::{error_line, TrainConfig};
use eval::greedy::GreedyMonitor;

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
    /// `--device`.
    pub device: Option<LearnerDevice>,
}

fn prepare(config: Option<&Path>, o: &Overrides, resume: bool) -> anyhow::Result<(TrainConfig, PathBuf)> {
    let mut cfg = TrainConfig::load(config)?;
    if let Some(s) = o.steps {
        cfg.run.steps = s;
    }
    if let Some(a) = o.actors {
        cfg.run.actors = a;
    }
    if let Some(d) = o.device {
        cfg.learner.device = d;
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

/// The actor processes `[run] actors = 0` starts: one per core.
pub fn default_actors() -> u32 {
    std::thread::available_parallelism().map_or(2, |n| n.get() as u32)
}

/// `adp train`.
pub fn train(config: Option<&Path>, o: &Overrides, resume: bool) -> anyhow::Result<()> {
    let (cfg, out) = prepare(config, o, resume)?;
    let (token_path, token) = run_token(&out)?;
    let actors = match cfg.run.actors {
        0 => default_actors(),
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
    if let (Some(g), Some((dims, weights))) = (greedy.as_mut(), learner.start_policy()) {
        // Held-out selection counts the start among its candidates (nothing without it).
        g.select_start(&dims, weights)?;
    }
    while !learner.finished() {
        std::thread::sleep(Duration::from_millis(250));
        for event in supervisor.poll(Instant::now()) {
            log_supervisor_event(&event);
        }
        let s = learner.status();
        if let Some(g) = greedy.as_mut() {
            match g.poll(s.inserts, s.updates, || learner.latest_policy()) {
                Some(Ok(r)) => bar.println(eval::greedy::describe(&r)),
                Some(Err(e)) => bar.println(error_line(&e.into())),
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
    let mut chosen = None;
    if let Some(mut g) = greedy {
        let s = learner.status();
        for r in g.finish(s.inserts, s.updates, || learner.latest_policy()) {
            eprintln!(
                "{}",
                r.map_or_else(|e| error_line(&e.into()), |r| eval::greedy::describe(&r))
            );
        }
        chosen = g.chosen();
    }
    let mut summary = learner.wait()?;
    supervisor.shutdown(Duration::from_secs(3));
    if let Some(c) = chosen {
        export_chosen(&c, &mut summary, &out, cfg.run.action_space);
    }
    record_run(&summary, &cfg);
    print_summary(&summary, &out, &space_name(cfg.run.action_space), "train");
    Ok(())
}

/// Records the run's planner and speed cap in its export's card, so the robot runtime can
/// refuse the policy under another planner or speed. A failure is logged: the export stays
/// usable by `adp eval`.
fn record_run(summary: &TrainSummary, cfg: &TrainConfig) {
    if let Some(dir) = &summary.export {
        let trained_for = TrainedFor {
            planner: cfg.run.planner,
            max_speed: cfg.run.max_speed,
        };
        if let Err(e) = record_trained_for(dir, trained_for) {
            tracing::error!("the export's card does not record the planner and speed: {e}");
        }
    }
}

/// Held-out selection's end: writes the chosen policy over the run's export (with
/// `selection.json` there and in the run directory) and logs which step it is and how it
/// compares with the start. A failure is logged and leaves no export in the summary: the
/// directory then holds no policy the selection vouches for.
fn export_chosen(
    c: &eval::selection::Chosen,
    summary: &mut TrainSummary,
    out: &Path,
    space: planner::ActionSpace,
) {
    match c.export(&summary.checkpoint, out, space) {
        Ok(dir) => {
            eprintln!("{}", eval::selection::describe(&c.report));
            summary.export = Some(dir);
        }
        Err(e) => {
            tracing::error!("held-out selection: the chosen policy could not be exported: {e}");
            summary.export = None;
        }
    }
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
    record_run(&summary, &cfg);
    print_summary(&summary, &out, &space_name(cfg.run.action_space), "learner");
    Ok(())
}

/// `adp train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Run configuration (default: the embedded configs/local.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Total agent steps of the run (overrides `[run]` steps).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Actor processes (overrides `[run]` actors; 0 = one per core).
    #[arg(long)]
    pub actors: Option<u32>,
    /// Run directory (default: `runs/<name>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the run in --out from its newest valid checkpoint up to --steps.
    #[arg(long)]
    pub resume: bool,
    /// Where the learner computes: cpu or wgpu (overrides `[learner]` device).
    #[arg(long)]
    pub device: Option<LearnerDevice>,
}

/// `adp learner`.
#[derive(clap::Args, Debug)]
pub struct LearnerArgs {
    /// Run configuration (default: the embedded configs/local.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Total agent steps of the run (overrides `[run]` steps).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Run directory (default: `runs/<name>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Address to listen on (overrides `[service]` listen), e.g. 0.0.0.0:50051.
    #[arg(long)]
    pub listen: Option<String>,
    /// Allow --listen on a non-loopback address without `[service.tls]` (the token then
    /// crosses the network in clear text); for trusted networks only.
    #[arg(long)]
    pub allow_insecure_listen: bool,
    /// The run's token file (mode 0600; default: `<out>/token`, created if missing).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Continue the run in --out from its newest valid checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Where the learner computes: cpu or wgpu (overrides `[learner]` device).
    #[arg(long)]
    pub device: Option<LearnerDevice>,
}

/// `adp train` with the options of `a`.
pub fn train_command(a: TrainArgs) -> anyhow::Result<()> {
    let o = Overrides {
        steps: a.steps,
        actors: a.actors,
        out: a.out,
        listen: None,
        allow_insecure_listen: false,
        device: a.device,
    };
    train(a.config.as_deref(), &o, a.resume)
}

/// `adp learner` with the options of `a`.
pub fn learner_command(a: LearnerArgs) -> anyhow::Result<()> {
    let o = Overrides {
        steps: a.steps,
        actors: None,
        out: a.out,
        listen: a.listen,
        allow_insecure_listen: a.allow_insecure_listen,
        device: a.device,
    };
    learner(a.config.as_deref(), &o, a.resume, a.token_file.as_deref())
}
