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
//! - `control`, `data`, `policy_streams`, `listen`, `size_status`: the gRPC services and the
//!   connection handling around them.

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
mod policy_streams;
mod shared;
mod size_status;
mod state;
pub mod status;
mod totals;
mod trainer;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use proto::pb;
use proto::shm::ShmConfig;
use proto::validate::{Spaces, Validator};
use scheduler::{Registry, RegistryConfig, RegistrySnapshot};
use tokio::sync::watch;

pub use config::{LearnerOptions, ServiceConfig};
pub use error::ServiceError;
pub use status::{
    read_status, ExpiredLease, KindStatus, RankStatus, RefusedLease, ResumeStatus, Status, STATUS_FILE,
};
pub use trainer::TrainSummary;

use crate::shared::{Rates, Shared};
use crate::state::Core;
use crate::totals::Totals;
use learner::checkpoint;
use learner::ddp_init::FitOptions;
use learner::export::space_name;
use learner::rate::RateLimiter;
use learner::replay::ReplayBuffer;
use learner::retention;
use learner::td3::{seeded_rng, Td3};
use learner::tensorboard::EventWriter;
use learner::Device;

/// File in the run directory holding the learner's bound `host:port`.
pub const ADDR_FILE: &str = "learner.addr";

/// The learner's Unix socket in the run directory (same services as the TCP address).
pub const SOCKET_FILE: &str = "learner.sock";

/// File in the run directory (mode 0600) holding the operator credential that `Shutdown`
/// needs besides the run token; made at the first start and kept across resumes. Actors are
/// never given it.
pub const OPERATOR_TOKEN_FILE: &str = "operator.token";

/// HTTP/2 pings every this long on an idle connection; a peer that does not answer within
/// [`KEEPALIVE_TIMEOUT`] is dropped with its streams (a dead host, a cut network).
const KEEPALIVE_INTERVAL: Duration = Duration::from_secs(20);
/// See [`KEEPALIVE_INTERVAL`].
const KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(20);
/// Concurrent requests one connection may have in flight (an actor needs four: heartbeat,
/// assignment or report, the step stream and the policy stream); more wait.
const REQUESTS_PER_CONNECTION: usize = 16;

/// A gRPC server with the learner's connection limits.
fn server_builder() -> tonic::transport::Server {
    tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(KEEPALIVE_INTERVAL))
        .http2_keepalive_timeout(Some(KEEPALIVE_TIMEOUT))
        .tcp_keepalive(Some(KEEPALIVE_INTERVAL))
        .concurrency_limit_per_connection(REQUESTS_PER_CONNECTION)
        .max_concurrent_streams(REQUESTS_PER_CONNECTION as u32)
}

/// A running learner. Dropping it without [`Learner::wait`] aborts the process's threads at
/// exit; call `wait`.
pub struct Learner {
    shared: Arc<Shared>,
    runtime: tokio::runtime::Runtime,
    addr: SocketAddr,
    trainer: JoinHandle<Result<TrainSummary, ServiceError>>,
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
    /// Held while this learner serves the run directory (see [`lock_run_dir`]).
    _run_lock: std::fs::File,
}

/// What training continues from: a checkpoint's state, or a fresh one.
struct TrainingState {
    td3: Td3,
    run_id: String,
    rate: RateLimiter,
    sampler_rng: rand_pcg::Pcg64Mcg,
    policy_version: u64,
    registry: Registry,
    totals: Totals,
    replay: ReplayBuffer,
}

/// Loads everything a resume needs from checkpoint `ckpt`, verifying every file. Counters that
/// do not parse are reset (with a warning) rather than failing: they are statistics, not
/// training state.
fn load_resume_state(ckpt: &Path, registry_cfg: &RegistryConfig) -> Result<TrainingState, ServiceError> {
    let (td3, state) = checkpoint::load(ckpt, &Device::flex())?;
    let replay = checkpoint::load_replay(ckpt)?.unwrap_or_else(|| ReplayBuffer::new(td3.config()));
    let snapshot: RegistrySnapshot =
        serde_json::from_value(state.extra["registry"].clone()).map_err(|source| {
            ServiceError::RegistryState {
                checkpoint: ckpt.to_path_buf(),
                source,
            }
        })?;
    let totals: Totals = serde_json::from_value(state.extra["totals"].clone()).unwrap_or_else(|e| {
        tracing::warn!(
            checkpoint = %ckpt.display(),
            "the counters do not parse ({e}); they restart from zero"
        );
        Totals::default()
    });
    let registry = Registry::restore(*registry_cfg, snapshot)?;
    Ok(TrainingState {
        td3,
        run_id: state.run_id,
        rate: state.rate,
        sampler_rng: state.sampler_rng,
        policy_version: state.policy_version,
        registry,
        totals,
        replay,
    })
}

/// Loads the newest of `candidates` (complete checkpoints, oldest first) that loads fully;
/// each one skipped is logged as a warning and returned with the reason.
fn newest_usable(
    dir: &Path,
    candidates: &[(u64, PathBuf)],
    registry_cfg: &RegistryConfig,
) -> Result<(PathBuf, TrainingState, Vec<String>), ServiceError> {
    let mut warnings = Vec::new();
    for (_, ckpt) in candidates.iter().rev() {
        match load_resume_state(ckpt, registry_cfg) {
            Ok(state) => return Ok((ckpt.clone(), state, warnings)),
            Err(e) => {
                let warning = format!(
                    "checkpoint {} is unusable ({e}); falling back to the previous one",
                    ckpt.display()
                );
                tracing::warn!("{warning}");
                warnings.push(warning);
            }
        }
    }
    Err(ServiceError::NoUsableCheckpoint {
        dir: dir.to_path_buf(),
        tried: candidates.len(),
        warnings,
    })
}

/// The lock file a learner holds in its run directory.
pub const LOCK_FILE: &str = "learner.lock";

/// Takes the run directory's lock (an exclusive `flock` on `learner.lock`, which also records
/// the holder's host and pid). Refused while another learner process holds it, so a second
/// learner can never remove the first one's socket or write into its checkpoints. The lock
/// goes away with the process, also when it is killed.
pub fn lock_run_dir(run_dir: &Path) -> Result<std::fs::File, ServiceError> {
    use std::io::{Read, Seek, Write};
    use std::os::unix::fs::OpenOptionsExt;
    let path = run_dir.join(LOCK_FILE);
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(0o600)
        .open(&path)
        .map_err(ServiceError::io(format!(
            "cannot open the lock file {}",
            path.display()
        )))?;
    match file.try_lock() {
        Ok(()) => {
            let holder = format!("{} pid {}\n", proto::hostname(), std::process::id());
            let _ = file
                .set_len(0)
                .and_then(|()| file.rewind())
                .and_then(|()| file.write_all(holder.as_bytes()));
            Ok(file)
        }
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            Err(ServiceError::InUse {
                run_dir: run_dir.to_path_buf(),
                holder: holder.trim().to_string(),
                lock: path,
            })
        }
        Err(std::fs::TryLockError::Error(e)) => {
            Err(ServiceError::io(format!("cannot lock {}", path.display()))(e))
        }
    }
}

/// Binds a Unix socket at `path` (replacing a stale one from an earlier learner of the run),
/// readable and writable by this user only.
fn bind_unix(
    runtime: &tokio::runtime::Runtime,
    path: &Path,
) -> Result<tokio::net::UnixListener, ServiceError> {
    use std::os::unix::fs::PermissionsExt;
    // sockaddr_un holds 108 bytes including the terminating NUL.
    if path.as_os_str().len() > 107 {
        return Err(ServiceError::SocketPath(path.to_path_buf()));
    }
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(ServiceError::io(format!(
                "cannot remove the old {}",
                path.display()
            ))(e))
        }
        _ => {}
    }
    let _guard = runtime.enter();
    let listener = tokio::net::UnixListener::bind(path)
        .map_err(ServiceError::io(format!("cannot bind {}", path.display())))?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))
        .map_err(ServiceError::io(format!("cannot chmod 600 {}", path.display())))?;
    Ok(listener)
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

/// Writes `text` to `path` atomically.
fn write_atomic(path: &Path, text: &str) -> Result<(), ServiceError> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text)
        .and_then(|_| std::fs::rename(&tmp, path))
        .map_err(ServiceError::io(format!("cannot write {}", path.display())))
}

/// The run directory of a starting learner: created, locked, aborted checkpoint saves removed.
struct RunDir {
    /// The run directory.
    path: PathBuf,
    /// Held while this learner serves the run directory (see [`lock_run_dir`]).
    lock: std::fs::File,
    /// Its `checkpoints` directory.
    checkpoints: PathBuf,
    /// The complete checkpoints in it, oldest first.
    candidates: Vec<(u64, PathBuf)>,
}

impl RunDir {
    /// Checks the service settings, then creates (if needed) and locks the run directory of
    /// `opts`, removes checkpoint saves an earlier learner aborted and lists the complete ones.
    fn open(opts: &LearnerOptions) -> Result<Self, ServiceError> {
        let path = opts.run_dir.clone();
        opts.service.check()?;
        trainer::create_private_dir(&path)?;
        // Before anything in the run directory is touched: one learner per run directory.
        let lock = lock_run_dir(&path)?;
        let checkpoints = path.join("checkpoints");
        match retention::remove_aborted_saves(&checkpoints) {
            Ok(removed) => {
                for dir in removed {
                    tracing::info!(dir = %dir.display(), "removed a directory left by an aborted checkpoint save");
                }
            }
            Err(e) => tracing::warn!("cannot clean aborted checkpoint saves: {e}"),
        }
        let candidates = if checkpoints.exists() {
            retention::complete_checkpoints(&checkpoints)?
        } else {
            Vec::new()
        };
        Ok(Self {
            path,
            lock,
            checkpoints,
            candidates,
        })
    }

    /// What training starts from: the newest usable checkpoint with `--resume` (and the
    /// warnings about the newer ones skipped), or a fresh state (the actor fitted to the DDP
    /// schedule with `ddp_init`, except in the velocity space). Refuses `--resume` without a
    /// checkpoint and a fresh run in a directory that holds one.
    fn training_state(
        &self,
        opts: &LearnerOptions,
        registry_cfg: &RegistryConfig,
    ) -> Result<(TrainingState, Vec<String>, Option<ResumeStatus>), ServiceError> {
        match (opts.resume, self.candidates.last()) {
            (true, None) => Err(ServiceError::NothingToResume {
                dir: self.checkpoints.clone(),
            }),
            (false, Some((_, c))) => Err(ServiceError::RunExists {
                run_dir: self.path.clone(),
                checkpoint: c.clone(),
            }),
            (true, Some(_)) => {
                let (ckpt, state, warnings) =
                    newest_usable(&self.checkpoints, &self.candidates, registry_cfg)?;
                let resumed = ResumeStatus {
                    checkpoint: ckpt.display().to_string(),
                    inserts: state.rate.inserts(),
                    updates: state.rate.updates(),
                };
                tracing::info!(
                    run_id = %state.run_id,
                    checkpoint = %resumed.checkpoint,
                    inserts = resumed.inserts,
                    updates = resumed.updates,
                    "resuming run"
                );
                Ok((state, warnings, Some(resumed)))
            }
            (false, None) => {
                let mut td3 = Td3::new(opts.td3.clone(), &Device::flex())?;
                if opts.service.ddp_init && opts.space == planner::ActionSpace::Velocity {
                    // The velocity space drives the robot itself: there is no DDP to start
                    // from, and a constant fitted action would only be a fixed command.
                    tracing::info!(
                        "ddp_init skipped: the velocity action space has no DDP schedule; the actor \
                         starts from its random initialization (outputs near 0: about half the \
                         speed cap, straight ahead)"
                    );
                } else if opts.service.ddp_init {
                    let target: Vec<f32> = action_map(&opts.env_toml)?
                        .ddp_policy_action(opts.space)
                        .iter()
                        .map(|&a| a as f32)
                        .collect();
                    let report = td3
                        .init_actor_to_action(&target, &FitOptions::default())
                        .map_err(ServiceError::DdpInit)?;
                    tracing::info!("actor initialized to the DDP schedule ({report:?})");
                }
                let registry = Registry::new(*registry_cfg, opts.worlds.clone())?;
                let cfg = td3.config().clone();
                let state = TrainingState {
                    td3,
                    run_id: opts.run_id.clone(),
                    rate: RateLimiter::new(&cfg),
                    sampler_rng: seeded_rng(cfg.seed, 4),
                    policy_version: 0,
                    registry,
                    totals: Totals::default(),
                    replay: ReplayBuffer::new(&cfg),
                };
                Ok((state, Vec::new(), None))
            }
        }
    }
}

/// The shared-memory data plane (when configured and it opened) and its intake thread.
struct DataPlanes {
    /// The step and policy services actors use, when shared memory is offered.
    shm: Option<ShmConfig>,
    /// Why shared memory is not offered although configured.
    shm_unavailable: Option<String>,
    /// The intake thread, when shared memory is offered.
    intake: Option<JoinHandle<()>>,
    /// Tells the intake thread to stop.
    intake_stop: Arc<AtomicBool>,
    /// Hands the intake thread the shared state once it exists.
    shared_tx: std::sync::mpsc::SyncSender<Arc<Shared>>,
}

impl DataPlanes {
    /// Opens the shared-memory step service of run `run_id`'s `incarnation` (when
    /// `[service] shared_memory`) on its intake thread.
    ///
    /// The intake opens its step service before actors are told which plane to use: if that
    /// fails, the run offers gRPC only (the reason is logged and shown in status.json) rather
    /// than sending actors to a plane nobody drains.
    fn start(svc: &ServiceConfig, run_id: &str, incarnation: u64) -> Result<Self, ServiceError> {
        let shm = svc.shared_memory.then(|| ShmConfig {
            service_prefix: format!("adp/{run_id}/{incarnation:016x}"),
            max_actors: svc.shm_max_actors as usize,
            ..ShmConfig::default()
        });
        let intake_stop = Arc::new(AtomicBool::new(false));
        let (shared_tx, shared_rx) = std::sync::mpsc::sync_channel::<Arc<Shared>>(1);
        let (shm, shm_unavailable, intake) = match shm {
            Some(cfg) => {
                let (opened_tx, opened_rx) = std::sync::mpsc::sync_channel(1);
                let (c, stop) = (cfg.clone(), intake_stop.clone());
                let handle = std::thread::Builder::new()
                    .name("adp-shm-intake".into())
                    .spawn(move || data::shm_intake(c, opened_tx, shared_rx, stop))
                    .map_err(ServiceError::io("cannot start the shared-memory intake thread"))?;
                match opened_rx.recv() {
                    Ok(Ok(())) => (Some(cfg), None, Some(handle)),
                    Ok(Err(why)) => {
                        tracing::warn!("shared-memory data plane unavailable ({why}); actors use gRPC");
                        let _ = handle.join();
                        (None, Some(why.to_string()), None)
                    }
                    Err(_) => {
                        let _ = handle.join();
                        (None, Some("the intake thread ended".to_owned()), None)
                    }
                }
            }
            None => (None, None, None),
        };
        Ok(Self {
            shm,
            shm_unavailable,
            intake,
            intake_stop,
            shared_tx,
        })
    }
}

/// A server task of the control plane.
type ServerTask = tokio::task::JoinHandle<Result<(), tonic::transport::Error>>;

/// The gRPC control plane (and the gRPC data plane): the runtime, the TCP and Unix-socket
/// servers, the policy channel they stream from, lease expiry and the signal handlers.
struct ControlPlane {
    /// The runtime running the servers.
    runtime: tokio::runtime::Runtime,
    /// The bound TCP address.
    addr: SocketAddr,
    /// Where the training thread publishes policies.
    policy_tx: watch::Sender<Arc<pb::PolicySnapshot>>,
    /// The newest published policy.
    policy: watch::Receiver<Arc<pb::PolicySnapshot>>,
    /// Stops the servers.
    server_stop: watch::Sender<bool>,
    /// The TCP server.
    server: ServerTask,
    /// The Unix socket and its server, when the socket could be bound.
    unix_server: Option<(PathBuf, ServerTask)>,
}

impl ControlPlane {
    /// Binds `[service] listen` (with TLS when configured) and the Unix socket in `run_dir`,
    /// serves the control and data services on both, writes `learner.addr`, and starts lease
    /// expiry and (with `handle_signals`) the SIGTERM/SIGINT handlers.
    fn start(opts: &LearnerOptions, run_dir: &Path, shared: &Arc<Shared>) -> Result<Self, ServiceError> {
        let svc = &opts.service;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .thread_name("adp-learner-io")
            .build()
            .map_err(ServiceError::io("cannot start the tokio runtime"))?;
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(&svc.listen))
            .map_err(ServiceError::io(format!("cannot listen on {}", svc.listen)))?;
        let addr = listener
            .local_addr()
            .map_err(ServiceError::io("cannot read the bound address"))?;
        let (policy_tx, policy_rx) = watch::channel(Arc::new(pb::PolicySnapshot::default()));
        let auth = proto::auth::ServerAuth::new(&opts.token, shared.refusals.clone());
        let operator: Arc<str> =
            proto::auth::read_or_create_token_file(&run_dir.join(OPERATOR_TOKEN_FILE))?.into();
        let mut builder = server_builder();
        if let Some(tls) = &svc.tls {
            builder = builder
                .tls_config(tls.server_config()?)
                .map_err(ServiceError::Tls)?;
        }
        let control = tonic::service::interceptor::InterceptedService::new(
            // Oversized requests are refused with RESOURCE_EXHAUSTED.
            size_status::SizeStatus(
                pb::control_server::ControlServer::new(control::ControlService {
                    shared: shared.clone(),
                    operator,
                })
                .max_decoding_message_size(proto::grpc::MAX_CONTROL_REQUEST_BYTES),
            ),
            auth.clone(),
        );
        let policy = policy_rx.clone();
        let data = tonic::service::interceptor::InterceptedService::new(
            size_status::SizeStatus(policy_streams::DataRoutes {
                // Requests are step batches (bounded).
                inner: pb::data_server::DataServer::new(data::DataService {
                    shared: shared.clone(),
                })
                .max_decoding_message_size(proto::grpc::MAX_REQUEST_BYTES),
                streams: Arc::new(policy_streams::PolicyStreams::new(
                    shared.clone(),
                    policy_rx,
                    svc.max_policy_streams,
                    svc.policy_streams_per_actor,
                )),
            }),
            auth,
        );
        // One cap over both servers, fitted to the open-file limit so that connections can
        // never take the descriptors a checkpoint needs.
        let limits = listen::ConnectionLimits::new(
            listen::fit_connections_to_fd_limit(svc.max_connections as usize),
            Duration::from_millis(u64::from(svc.handshake_timeout_ms)),
        );
        let _in_runtime = runtime.enter();
        let (server_stop, stop_rx) = watch::channel(false);
        let stopped = |mut rx: watch::Receiver<bool>| async move {
            let _ = rx.wait_for(|s| *s).await;
        };
        // The same services on a Unix socket in the run directory, for actors on this host
        // (sandboxed actors without a network reach the learner only this way). Plain HTTP/2:
        // the socket (mode 0600) never leaves the host; the token is still checked.
        let socket = run_dir.join(SOCKET_FILE);
        let unix_server = match bind_unix(&runtime, &socket) {
            Ok(unix) => Some((
                socket,
                runtime.spawn(
                    server_builder()
                        .add_service(control.clone())
                        .add_service(data.clone())
                        .serve_with_incoming_shutdown(
                            listen::incoming(unix, limits.clone(), "unix"),
                            stopped(stop_rx.clone()),
                        ),
                ),
            )),
            Err(why) => {
                tracing::warn!("no Unix socket for local actors ({why}); they use {addr}");
                None
            }
        };
        let router = builder.add_service(control).add_service(data);
        let server = runtime.spawn(
            router.serve_with_incoming_shutdown(listen::incoming(listener, limits, "tcp"), stopped(stop_rx)),
        );
        write_atomic(&run_dir.join(ADDR_FILE), &format!("{addr}\n"))?;

        // Lease expiry.
        let ticker = shared.clone();
        runtime.spawn(async move {
            let mut every = tokio::time::interval(Duration::from_millis(100));
            loop {
                every.tick().await;
                ticker.expire_leases();
            }
        });
        if opts.handle_signals {
            let s = shared.clone();
            runtime.spawn(async move {
                use tokio::signal::unix::{signal, SignalKind};
                let (Ok(mut term), Ok(mut int)) =
                    (signal(SignalKind::terminate()), signal(SignalKind::interrupt()))
                else {
                    tracing::error!("cannot install signal handlers");
                    return;
                };
                tokio::select! {
                    _ = term.recv() => tracing::info!("SIGTERM: checkpointing and stopping"),
                    _ = int.recv() => tracing::info!("SIGINT: checkpointing and stopping"),
                }
                s.request_stop(true);
            });
        }
        Ok(Self {
            runtime,
            addr,
            policy_tx,
            policy,
            server_stop,
            server,
            unix_server,
        })
    }
}

impl Learner {
    /// Prepares the run (fresh or resumed), binds the server and starts every thread. Returns
    /// once actors can connect (the bound address is in [`Learner::addr`] and `learner.addr`).
    pub fn start(opts: LearnerOptions) -> Result<Self, ServiceError> {
        let svc = opts.service.clone();
        let run = RunDir::open(&opts)?;
        let registry_cfg = RegistryConfig {
            lease_ttl_ms: u64::from(svc.lease_ttl_ms),
            episodes_per_assignment: svc.episodes_per_assignment,
            run_seed: opts.td3.seed,
        };
        let (state, resume_warnings, resumed_from) = run.training_state(&opts, &registry_cfg)?;
        let cfg = state.td3.config().clone();
        let laser = laser_layout(&opts.env_toml)?;
        let space_obs_dim = layout::obs_dim(laser, opts.space.dim(), observe_tracks(&opts.env_toml)?);
        if cfg.obs_dim != space_obs_dim || cfg.act_dim != opts.space.dim() || cfg.laser_dim > laser.size() {
            return Err(ServiceError::SpaceMismatch {
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
        let incarnation = fresh_incarnation();
        let planes = DataPlanes::start(&svc, &state.run_id, incarnation)?;
        // Recorded in checkpoints, so exports document the observation the policy was trained on.
        let environment: serde_json::Value = toml::from_str(&opts.env_toml).map_err(ServiceError::EnvToml)?;
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
        let (dims, _) = td3.policy().flat_weights();
        let spec = pb::RunSpec {
            obs_dim: cfg.obs_dim as u32,
            act_dim: cfg.act_dim as u32,
            action_space: space_name(opts.space),
            planner: opts.planner.clone(),
            max_speed: opts.max_speed,
            run_seed: cfg.seed,
            policy_dims: dims.iter().map(|&d| d as u32).collect(),
            data_plane: match &planes.shm {
                Some(s) => format!("shm:{}@{}", s.service_prefix, proto::hostname()),
                None => "grpc".into(),
            },
            heartbeat_ms: svc.heartbeat_ms,
            lease_ttl_ms: svc.lease_ttl_ms,
            env_toml: opts.env_toml.clone(),
        };
        let mut core = Core::new(registry, replay, rate, totals, policy_version);
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
            svc.idle_retry_ms,
            svc.progress_timeout(),
        );
        shared.resume_warnings = resume_warnings;
        shared.rank_forget_ms = svc.rank_forget_ms;
        shared.dead_ranks_kept = svc.dead_ranks_kept as usize;
        shared.max_episode_steps = match toml::from_str::<actor::EnvConfig>(&opts.env_toml) {
            Ok(env) => env.max_agent_steps,
            Err(e) => {
                tracing::warn!("the environment settings do not parse ({e}); episode lengths are not capped");
                u32::MAX
            }
        };
        // Refusal counters continue across a resume like every other counter.
        let restored = std::mem::take(&mut shared.core.get_mut().expect("core lock").totals.refusals);
        for (name, n) in restored {
            if !shared.refusals.add_named(&name, n) {
                tracing::warn!(
                    "the checkpoint counts refusals of an unknown kind `{name}` ({n}); not restored"
                );
            }
        }
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
            .map_err(ServiceError::io("cannot start the training thread"))?;
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
    pub fn latest_policy(&self) -> Result<(u64, Vec<usize>, Vec<f32>), ServiceError> {
        let snapshot = self.policy.borrow().clone();
        let dims = self.shared.spec.policy_dims.iter().map(|&d| d as usize).collect();
        let mut weights = Vec::new();
        proto::floats::decode_into("weights", &snapshot.weights, &mut weights).map_err(|source| {
            ServiceError::Policy {
                version: snapshot.version,
                source,
            }
        })?;
        Ok((snapshot.version, dims, weights))
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
    pub fn wait(self) -> Result<TrainSummary, ServiceError> {
        let summary = self.trainer.join().map_err(|_| ServiceError::TrainerPanicked)?;
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

/// The action map of the environment settings (`action_map` in `env_toml`; the environment's
/// default, DDP-centred, when absent): it decides which policy output is the DDP schedule.
fn action_map(env_toml: &str) -> Result<planner::ActionMap, ServiceError> {
    let table: toml::Table = toml::from_str(env_toml).map_err(ServiceError::EnvToml)?;
    match table.get("action_map") {
        None => Ok(planner::ActionMap::default()),
        Some(v) => v
            .as_str()
            .ok_or_else(|| ServiceError::ActionMapType(v.clone()))?
            .parse()
            .map_err(ServiceError::ActionMap),
    }
}

/// The moving tracks the actors' observations hold (`observe_tracks` in `env_toml`; 0 when
/// absent), which size the observation with the action space.
fn observe_tracks(env_toml: &str) -> Result<usize, ServiceError> {
    let table: toml::Table = toml::from_str(env_toml).map_err(ServiceError::EnvToml)?;
    match table.get("observe_tracks") {
        None => Ok(0),
        Some(v) => v
            .as_integer()
            .and_then(|k| usize::try_from(k).ok())
            .filter(|&k| k <= layout::MAX_OBSERVED_TRACKS)
            .ok_or_else(|| ServiceError::ObserveTracks(v.clone())),
    }
}

/// The laser layout of the actors' observations (`observation` in `env_toml`; `scan` when
/// absent), which sizes the observation with the action space.
fn laser_layout(env_toml: &str) -> Result<layout::LaserLayout, ServiceError> {
    let table: toml::Table = toml::from_str(env_toml).map_err(ServiceError::EnvToml)?;
    match table.get("observation") {
        None => Ok(layout::LaserLayout::Scan),
        Some(v) => v
            .as_str()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| ServiceError::Observation(v.clone())),
    }
}

/// Reads the learner address a running learner wrote into `run_dir`.
pub fn read_addr(run_dir: &Path) -> Result<String, ServiceError> {
    let p: PathBuf = run_dir.join(ADDR_FILE);
    std::fs::read_to_string(&p)
        .map(|s| s.trim().to_owned())
        .map_err(ServiceError::io(format!("cannot read {}", p.display())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use learner::bench::random_batch;
    use learner::Td3Config;
    use testkit::fresh_dir as temp_dir;

    #[test]
    fn a_corrupt_newest_checkpoint_falls_back_to_the_previous_one() {
        let config = Td3Config {
            obs_dim: 3,
            act_dim: 1,
            laser_dim: 0,
            actor_hidden: vec![16],
            critic_hidden: vec![16],
            batch_size: 4,
            replay_capacity: 64,
            ..Td3Config::default()
        };
        let registry_cfg = RegistryConfig {
            lease_ttl_ms: 1000,
            episodes_per_assignment: 2,
            run_seed: 1,
        };
        let registry = Registry::new(registry_cfg, vec![1, 2]).unwrap();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let run = checkpoint::RunState {
            run_id: "r".into(),
            rate: RateLimiter::new(&config),
            sampler_rng: seeded_rng(0, 2),
            policy_version: 0,
            extra: serde_json::json!({ "registry": registry.snapshot(), "totals": Totals::default() }),
            environment: serde_json::Value::Null,
        };
        let root = temp_dir("resume-fallback");
        let mut rng = seeded_rng(0, 0);
        for name in ["ckpt-1", "ckpt-2"] {
            td3.update(&random_batch(&config, 4, &mut rng)).unwrap();
            checkpoint::save(&root.join(name), &td3, &run).unwrap();
        }
        // One flipped byte in a network file (the manifest still verifies).
        let flip = |file: &Path| {
            let mut bytes = std::fs::read(file).unwrap();
            let mid = bytes.len() / 2;
            bytes[mid] ^= 0xff;
            std::fs::write(file, bytes).unwrap();
        };
        flip(&root.join("ckpt-2").join("actor.bpk"));
        let candidates = retention::complete_checkpoints(&root).unwrap();
        assert_eq!(candidates.len(), 2, "the damage is only found by a full load");
        let (ckpt, state, warnings) = newest_usable(&root, &candidates, &registry_cfg).unwrap();
        assert_eq!(ckpt, root.join("ckpt-1"));
        assert_eq!(state.td3.updates(), 1);
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].contains("ckpt-2"), "{warnings:?}");
        // Nothing usable: the error names every checkpoint tried.
        flip(&root.join("ckpt-1").join("critic.bpk"));
        let e = newest_usable(
            &root,
            &retention::complete_checkpoints(&root).unwrap(),
            &registry_cfg,
        )
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("ckpt-1") && e.contains("ckpt-2"), "{e}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
