#![warn(missing_docs)]
//! The learner process (`adp learner`, and the learner half of `adp train`): hosts the gRPC
//! control plane and both data planes, the replay buffer and TD3 (the `learner` crate),
//! publishes a new policy version at each scheduler cycle, checkpoints on a timer, on
//! SIGTERM/SIGINT and at the end, and resumes from the newest valid checkpoint of its run
//! directory.
//!
//! Threads: a tokio runtime (gRPC server, lease expiry, signals), one shared-memory intake
//! thread, and the training thread (`trainer`) which owns the networks. They share the state
//! of `shared` ([`Status`] is its snapshot in `status.json`):
//!
//! - `state`: the mutable core behind its one mutex (registry, replay buffer, rate limiter,
//!   registrations), `leases`: the open leases and their episodes, `totals`: the counters a
//!   resume keeps;
//! - `ingest`: what enters the replay buffer (steps from both data planes, episode reports),
//!   `expiry`: leases that expire or are dropped;
//! - `control`, `data`, `policy_streams`, `listen`, `authority`, `wire_status`: the gRPC
//!   services and the connection handling around them (budgets and deadlines per listener,
//!   grpc-core's authorities on the Unix socket, the status codes of refused requests);
//!   `servers`: the servers on their runtime, `planes`: the shared-memory data plane;
//! - `run_dir`: the run directory (its files and lock, fresh or resumed), `resume`: the state a
//!   checkpoint continues.

mod authority;
mod budget;
mod config;
mod control;
mod data;
mod error;
mod expiry;
#[cfg(test)]
mod fixture;
mod ingest;
mod leases;
mod listen;
mod planes;
mod policy_streams;
mod resume;
mod run_dir;
mod servers;
mod shared;
mod state;
pub mod status;
mod totals;
mod trainer;
mod wire_status;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use learner::export::space_name;
use learner::tensorboard::EventWriter;
use learner::Td3Config;
use proto::pb;
use proto::validate::{Spaces, Validator};
use scheduler::RegistryConfig;
use tokio::sync::watch;

pub use config::{LearnerOptions, ServiceConfig, StartAction};
pub use error::{
    FileError, PolicyError, ResumeError, SettingsError, StartError, StatusFileError, TrainError,
};
pub use run_dir::{lock_run_dir, read_addr, ADDR_FILE, LOCK_FILE, OPERATOR_TOKEN_FILE, SOCKET_FILE};
pub use status::{
    read_status, ExpiredLease, KindStatus, RankStatus, RefusedLease, ResumeStatus, Status, STATUS_FILE,
};
pub use trainer::TrainSummary;

use crate::planes::DataPlanes;
use crate::resume::TrainingState;
use crate::run_dir::RunDir;
use crate::servers::ControlPlane;
use crate::shared::{Rates, Shared};
use crate::state::Core;

/// A running learner. Dropping it without [`Learner::wait`] aborts the process's threads at
/// exit; call `wait`.
pub struct Learner {
    shared: Arc<Shared>,
    runtime: tokio::runtime::Runtime,
    addr: SocketAddr,
    trainer: JoinHandle<Result<TrainSummary, TrainError>>,
    intake: Option<JoinHandle<()>>,
    intake_stop: Arc<AtomicBool>,
    server_stop: watch::Sender<bool>,
    server: tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
    unix_server: Option<(
        PathBuf,
        tokio::task::JoinHandle<Result<(), tonic::transport::Error>>,
    )>,
    heartbeat_ms: u32,
    /// The newest published policy (what `WatchPolicy` streams).
    policy: watch::Receiver<Arc<pb::PolicySnapshot>>,
    /// The flat weights of the actor as initialized, on a fresh run ([`Learner::start_policy`]).
    start_policy: Option<Vec<f32>>,
    /// Held while this learner serves the run directory (see [`lock_run_dir`]).
    _run_lock: std::fs::File,
}

fn fresh_incarnation() -> u64 {
    let mut raw = [0u8; 8];
    let random =
        std::fs::File::open("/dev/urandom").and_then(|mut f| std::io::Read::read_exact(&mut f, &mut raw));
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    match random {
        Ok(()) => u64::from_le_bytes(raw) | 1,
        Err(_) => (nanos ^ (u64::from(std::process::id()) << 32)) | 1,
    }
}

impl Learner {
    /// Prepares the run (fresh or resumed), binds the server and starts every thread. Returns
    /// once actors can connect (the bound address is in [`Learner::addr`] and `learner.addr`).
    pub fn start(opts: LearnerOptions) -> Result<Self, StartError> {
        let svc = opts.service.clone();
        opts.env.validate().map_err(StartError::Env)?;
        // Before the run directory is touched: the run must be expressible on the wire.
        let planner = proto::spec::planner_to_wire(opts.planner);
        let run = RunDir::open(&opts)?;
        let registry_cfg = RegistryConfig {
            lease_ttl_ms: u64::from(svc.lease_ttl_ms),
            episodes_per_assignment: svc.episodes_per_assignment,
            run_seed: opts.td3.seed,
            deadline: svc.deadline_rule(),
        };
        let (state, resume_warnings, resumed_from) = run.training_state(&opts, &registry_cfg)?;
        let cfg = state.td3.config().clone();
        check_sizes(&cfg, &opts)?;
        let incarnation = fresh_incarnation();
        let planes = DataPlanes::start(&svc, &state.run_id, incarnation)?;
        // Recorded in checkpoints, so exports document the observation the policy was trained on.
        let environment = serde_json::to_value(opts.env).expect("EnvConfig serializes");
        let TrainingState {
            td3,
            run_id,
            rate,
            sampler_rng,
            policy_version,
            registry,
            totals,
            replay,
        } = state;
        let validator = Validator {
            run_id: run_id.clone(),
            incarnation,
            spaces: Spaces {
                obs_dim: cfg.obs_dim,
                act_dim: cfg.act_dim,
                laser_dim: cfg.laser_dim,
            },
        };
        let (dims, start_weights) = td3.policy().flat_weights();
        // The policy training starts from, for a run that starts here (not a resumed one).
        let start_policy = resumed_from.is_none().then_some(start_weights);
        let spec = run_spec(&opts, &cfg, planner, &dims, &planes);
        let core = Core::new(registry, replay, rate, totals, policy_version);
        let mut shared = shared_state(&opts, validator, spec, core, &run_id);
        shared.resume_warnings = resume_warnings;
        shared.resumed_from = resumed_from;
        *shared.shm_unavailable.get_mut().expect("shm note lock") = planes.shm_unavailable;
        let shared = Arc::new(shared);
        let tensorboard_dir = run.path.join("tensorboard");
        let inserts = shared.lock().rate.inserts();
        let tensorboard = if opts.resume {
            EventWriter::resume(&tensorboard_dir, inserts)
        } else {
            EventWriter::create(&tensorboard_dir)
        }?;
        let control = ControlPlane::start(&opts, &run.path, &shared)?;
        if planes.intake.is_some() {
            let _ = planes.shared_tx.send(shared.clone());
        }
        let trainer = trainer::Trainer {
            shared: shared.clone(),
            td3,
            sampler_rng,
            run_dir: run.path.clone(),
            service: svc.clone(),
            space: opts.space,
            policy_tx: control.policy_tx,
            shm: planes.shm,
            tensorboard,
            environment,
        };
        let trainer = std::thread::Builder::new()
            .name("adp-train".into())
            .spawn(move || trainer.run())
            .map_err(FileError::at("cannot start the training thread"))?;
        let addr = control.addr;
        tracing::info!(
            run_id = %run_id,
            incarnation = %format_args!("{incarnation:016x}"),
            %addr,
            "serving"
        );
        Ok(Self {
            shared,
            runtime: control.runtime,
            addr,
            trainer,
            intake: planes.intake,
            intake_stop: planes.intake_stop,
            server_stop: control.server_stop,
            server: control.server,
            unix_server: control.unix_server,
            heartbeat_ms: svc.heartbeat_ms,
            policy: control.policy,
            start_policy,
            _run_lock: run.lock,
        })
    }

    /// The bound gRPC address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The Unix socket actors on this host may use instead (`unix:PATH` as their learner
    /// address), if it could be bound.
    pub fn socket(&self) -> Option<&Path> {
        self.unix_server.as_ref().map(|(p, _)| p.as_path())
    }

    /// The run id.
    pub fn run_id(&self) -> &str {
        &self.shared.validator.run_id
    }

    /// The newest published policy: its version (0 before the first publish), exploration
    /// sigma and flat weights (decoded), with the layer sizes of the run's actor, as
    /// `MlpPolicy::from_flat` takes them. For in-process evaluation of the greedy policy.
    pub fn latest_policy(&self) -> Result<(u64, Vec<usize>, Vec<f32>), PolicyError> {
        let snapshot = self.policy.borrow().clone();
        let dims = self.shared.spec.policy_dims.iter().map(|&d| d as usize).collect();
        let mut weights = Vec::new();
        proto::floats::decode_into("weights", &snapshot.weights, &mut weights).map_err(|source| {
            PolicyError {
                version: snapshot.version,
                source,
            }
        })?;
        Ok((snapshot.version, dims, weights))
    }

    /// The policy a fresh run starts from (the actor before any update: fitted to DDP or to
    /// `[service] init_action`, or as randomly initialized), as the layer sizes and flat
    /// weights [`Learner::latest_policy`] gives; `None` on a resumed run, whose start is gone.
    /// For held-out selection, which counts the start among its candidates.
    pub fn start_policy(&self) -> Option<(Vec<usize>, Vec<f32>)> {
        let dims = self.shared.spec.policy_dims.iter().map(|&d| d as usize).collect();
        self.start_policy.clone().map(|w| (dims, w))
    }

    /// Current counters.
    pub fn status(&self) -> Status {
        let core = self.shared.lock();
        self.shared.status(&core, Rates::default())
    }

    /// Whether the training thread has stopped.
    pub fn finished(&self) -> bool {
        self.trainer.is_finished()
    }

    /// Asks for a graceful stop: no more assignments, a final checkpoint, no further updates.
    pub fn request_stop(&self) {
        self.shared.request_stop(true);
    }

    /// Waits for the training thread (budget reached or stop requested), tells actors to shut
    /// down, stops the planes and returns the summary.
    pub fn wait(self) -> Result<TrainSummary, TrainError> {
        let summary = self.trainer.join().map_err(|_| TrainError::Panicked)?;
        self.shared.finished.store(true, Ordering::Release);
        // Training is over: nothing may wait for updates any more (the intake would hang).
        self.shared.request_stop(true);
        // Let actors hear `shutdown` on their next heartbeat before the server goes away.
        std::thread::sleep(Duration::from_millis(u64::from(self.heartbeat_ms) * 2));
        self.intake_stop.store(true, Ordering::Release);
        if let Some(t) = self.intake {
            let _ = t.join();
        }
        let _ = self.server_stop.send(true);
        let _ = self
            .runtime
            .block_on(async { tokio::time::timeout(Duration::from_secs(5), self.server).await });
        if let Some((socket, server)) = self.unix_server {
            let _ = self
                .runtime
                .block_on(async { tokio::time::timeout(Duration::from_secs(5), server).await });
            let _ = std::fs::remove_file(socket);
        }
        self.runtime.shutdown_timeout(Duration::from_secs(1));
        summary
    }
}

/// Refuses TD3 sizes that do not fit the run's action space and observation layout.
fn check_sizes(cfg: &Td3Config, opts: &LearnerOptions) -> Result<(), StartError> {
    let laser = opts.env.observation;
    let space_obs_dim = layout::obs_dim(laser, opts.space.dim(), opts.env.observe_tracks);
    if cfg.obs_dim != space_obs_dim || cfg.act_dim != opts.space.dim() || cfg.laser_dim > laser.size() {
        return Err(StartError::SpaceMismatch {
            obs_dim: cfg.obs_dim,
            act_dim: cfg.act_dim,
            laser_dim: cfg.laser_dim,
            space: space_name(opts.space),
            laser,
            space_obs_dim,
            space_act_dim: opts.space.dim(),
            laser_size: laser.size(),
        });
    }
    Ok(())
}

/// The run spec every actor receives at registration.
fn run_spec(
    opts: &LearnerOptions,
    cfg: &Td3Config,
    planner: pb::Planner,
    dims: &[usize],
    planes: &DataPlanes,
) -> pb::RunSpec {
    pb::RunSpec {
        obs_dim: cfg.obs_dim as u32,
        act_dim: cfg.act_dim as u32,
        action_space: Some(proto::spec::action_space_to_wire(opts.space)),
        planner: planner as i32,
        max_speed: opts.max_speed,
        run_seed: cfg.seed,
        policy_dims: dims.iter().map(|&d| d as u32).collect(),
        data_plane: match &planes.shm {
            Some(s) => format!("shm:{}@{}", s.service_prefix, proto::hostname()),
            None => "grpc".into(),
        },
        heartbeat_ms: opts.service.heartbeat_ms,
        lease_ttl_ms: opts.service.lease_ttl_ms,
        env: Some(proto::spec::env_to_wire(&opts.env)),
    }
}

/// The state the service threads share, around `core` (its leases dropped: no actor of an
/// earlier incarnation holds one), with the refusal counters of a resumed run restored.
fn shared_state(
    opts: &LearnerOptions,
    validator: Validator,
    spec: pb::RunSpec,
    mut core: Core,
    run_id: &str,
) -> Shared {
    core.drop_all_leases();
    if core.rate.inserts() >= opts.budget_steps {
        // A finished run resumed with the same budget: nothing to collect. Say so and end
        // (final checkpoint, export) instead of waiting for steps nobody will be asked for.
        tracing::warn!(
            run_id = %run_id,
            inserts = core.rate.inserts(),
            budget = opts.budget_steps,
            "the run already stored its budget; nothing to collect (pass a larger --steps to train it further)"
        );
        core.stopping = true;
    }
    let mut shared = Shared::new(
        validator,
        spec,
        core,
        opts.budget_steps,
        opts.service.idle_retry_ms,
        opts.service.progress_timeout(),
    );
    shared.rank_forget_ms = opts.service.rank_forget_ms;
    shared.dead_ranks_kept = opts.service.dead_ranks_kept as usize;
    shared.registrations_per_address = opts.service.registrations_per_ip as usize;
    shared.max_episode_steps = opts.env.max_agent_steps;
    // Refusal counters continue across a resume like every other counter.
    let restored = std::mem::take(&mut shared.core.get_mut().expect("core lock").totals.refusals);
    for (name, n) in restored {
        if !shared.refusals.add_named(&name, n) {
            tracing::warn!("the checkpoint counts refusals of an unknown kind `{name}` ({n}); not restored");
        }
    }
    shared
}
