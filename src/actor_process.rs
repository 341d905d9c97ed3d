//! `adp actor`: one actor process of a run, connected to its learner ([`command`]).
//!
//! With `--sandbox CONFIG`, an actor that somebody else started (a SLURM task, a user's own
//! launcher) puts itself in the sandbox that `adp train` gives its local actors ([`run`]).
//!
//! The process reads `[sandbox]` of the training configuration `CONFIG`, re-executes this
//! executable as a plain `adp actor` (same options, the rank made explicit, no `--sandbox`)
//! under [`scheduler::Sandbox`] (resource limits, no new privileges, its own process group,
//! bubblewrap when available or required), forwards `SIGTERM` and `SIGINT` to the child's
//! process group, and ends as the child ends. The child dies with this process
//! (`PR_SET_PDEATHSIG`), so a task killed outright leaves nothing behind.
//!
//! The network stays shared: an actor started outside `adp train` reaches its learner over
//! TCP, which a private network namespace would cut.

use crate::config::EvalConfig;
use actor::run::ActorSetup;
use planner::PlannerKind;
use proto::auth::{read_token_file, TlsFiles};
use proto::grpc::LearnerAddress;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context};
use tokio::signal::unix::{signal, SignalKind};

use actor::run::PlaneChoice;
use scheduler::{BwrapStatus, Sandbox};

use crate::config::TrainConfig;

/// Options of `adp actor`.
#[derive(clap::Args, Debug)]
pub struct ActorArgs {
    /// The learner's host:port, or unix:PATH for its Unix socket (`<run dir>/learner.sock`)
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

/// `adp actor`: runs one actor process (in the sandbox of `--sandbox CONFIG` when given).
pub fn command(a: ActorArgs) -> anyhow::Result<()> {
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
        return run(&a, rank, config);
    }
    let planners = EvalConfig::load(None)?.planners();
    let factory = move |kind: PlannerKind, seed: u64| kind.build(&planners, seed);
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

/// The `adp actor` options of the sandboxed child: `a` without `--sandbox`, with `rank`.
pub fn child_args(a: &ActorArgs, rank: u32) -> Vec<String> {
    let mut args = vec![
        "actor".to_owned(),
        "--learner".into(),
        a.learner.clone(),
        "--token-file".into(),
        a.token_file.display().to_string(),
        "--rank".into(),
        rank.to_string(),
        "--data-plane".into(),
        match a.data_plane {
            PlaneChoice::Auto => "auto",
            PlaneChoice::Grpc => "grpc",
            PlaneChoice::Shm => "shm",
        }
        .into(),
        "--give-up-after".into(),
        a.give_up_after_s.to_string(),
    ];
    let files: [(&str, &Option<PathBuf>); 3] = [
        ("--tls-ca", &a.tls_ca),
        ("--tls-cert", &a.tls_cert),
        ("--tls-key", &a.tls_key),
    ];
    for (flag, file) in files {
        if let Some(f) = file {
            args.extend([flag.to_owned(), f.display().to_string()]);
        }
    }
    if let Some(domain) = &a.tls_domain {
        args.extend(["--tls-domain".to_owned(), domain.clone()]);
    }
    args
}

/// Runs the actor `a` of `rank` in the sandbox of `config`'s `[sandbox]` and waits for it.
pub fn run(a: &ActorArgs, rank: u32, config: &Path) -> anyhow::Result<()> {
    let cfg = TrainConfig::load(Some(config)).context("--sandbox")?;
    let sandbox = Sandbox::new(cfg.sandbox.sandbox_config(false))?;
    let exe = std::env::current_exe().context("cannot find this executable to sandbox the actor")?;
    let mut command = sandbox.command(&exe, &child_args(a, rank));
    let bwrap = match sandbox.bwrap_status() {
        BwrapStatus::Used(path) => format!("under {}", path.display()),
        BwrapStatus::Off => "without bubblewrap ([sandbox] bwrap = \"off\")".to_owned(),
        BwrapStatus::Unavailable(why) => format!("without bubblewrap ({why})"),
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the signal handler of the sandboxed actor")?;
    // The child is spawned on this (the main) thread: PR_SET_PDEATHSIG follows the thread.
    let status = runtime.block_on(async move {
        let mut term = signal(SignalKind::terminate()).context("cannot handle SIGTERM")?;
        let mut int = signal(SignalKind::interrupt()).context("cannot handle SIGINT")?;
        let mut child = command
            .spawn()
            .with_context(|| format!("cannot start the sandboxed actor {}", exe.display()))?;
        let pid = child.id();
        tracing::info!(rank, pid, sandbox = %bwrap, "actor sandboxed");
        let (tx, mut done) = tokio::sync::oneshot::channel();
        std::thread::Builder::new()
            .name("adp-actor-wait".into())
            .spawn(move || {
                let _ = tx.send(child.wait());
            })
            .context("cannot start the thread that waits for the sandboxed actor")?;
        loop {
            tokio::select! {
                status = &mut done => {
                    return status
                        .context("the waiting thread ended")?
                        .context("cannot wait for the sandboxed actor");
                }
                _ = term.recv() => forward(pid, libc::SIGTERM),
                _ = int.recv() => forward(pid, libc::SIGINT),
            }
        }
    })?;
    if !status.success() {
        bail!("the sandboxed actor of rank {rank} ended with {status}");
    }
    Ok(())
}

/// Sends `sig` to the process group that `pid` leads.
fn forward(pid: u32, sig: libc::c_int) {
    // SAFETY: plain system call; a group that is already gone makes it fail harmlessly.
    unsafe {
        libc::kill(-(pid as libc::pid_t), sig);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        actor: ActorArgs,
    }

    fn parse(args: &[&str]) -> ActorArgs {
        Cli::parse_from(std::iter::once("adp").chain(args.iter().copied())).actor
    }

    #[test]
    fn the_child_gets_every_option_but_the_sandbox_and_an_explicit_rank() {
        let a = parse(&[
            "--learner",
            "node7:5555",
            "--token-file",
            "/run/token",
            "--rank-offset",
            "4",
            "--data-plane",
            "grpc",
            "--tls-ca",
            "/pki/ca.pem",
            "--tls-cert",
            "/pki/c.pem",
            "--tls-key",
            "/pki/c.key",
            "--tls-domain",
            "learner.example",
            "--give-up-after",
            "30",
            "--sandbox",
            "/run/job-config.toml",
        ]);
        let args = child_args(&a, 9);
        assert!(
            !args.iter().any(|s| s.contains("sandbox") || s == "--rank-offset"),
            "{args:?}"
        );
        // The child parses to the same actor, rank 9, no sandbox.
        let child = parse(&args.iter().skip(1).map(String::as_str).collect::<Vec<_>>());
        assert_eq!(child.rank, Some(9));
        assert_eq!(child.sandbox, None);
        assert_eq!(
            (
                child.learner,
                child.token_file,
                child.data_plane,
                child.give_up_after_s
            ),
            (a.learner, a.token_file, a.data_plane, 30)
        );
        assert_eq!(
            (child.tls_ca, child.tls_cert, child.tls_key, child.tls_domain),
            (a.tls_ca, a.tls_cert, a.tls_key, a.tls_domain)
        );
    }
}
