//! The actor process loop: register with the learner, take an assignment, wait for its policy
//! version, run the episodes with the run's planner and fidelity action space, stream every step,
//! report each episode, idle until the next cycle, repeat.
//!
//! The loop is written against [`StepSink`] and [`PolicySource`] only, so the same code runs
//! over shared memory (learner on this host) and gRPC (learner elsewhere). The control plane is
//! always gRPC. A lost learner (unreachable, or restarted: a new incarnation) ends the session;
//! the actor registers again with exponential back-off and never sends data of an old session
//! to a new learner.
//!
//! Every random stream is seeded from the assignment's per-episode seed, which the scheduler
//! derives from (run seed, actor rank, episode counter): the simulator noise and the planner's
//! sampling from the seed itself, exploration noise from a mix of it.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use planner::{ActionSpace, Planner, PlannerKind};
use proto::checksum::step_checksum;
use proto::grpc::{ControlClient, GrpcPolicySource, GrpcStepSink, LearnerAddress};
use proto::pb;
use proto::plane::{ActorSecret, LeaseHeader, PlaneError, PolicySource, SinkTally, StepSink};
use proto::shm::{ShmConfig, ShmPolicySource, ShmStepSink};
use proto::StepView;
use sim::episode::{EpisodeConfig, Status};
use sim::World;
use thiserror::Error;
use tracing::Instrument;

use crate::closed_loop::{self, Chooser, Explore, Run};
use crate::env::{End, EnvConfig, EnvError};
use crate::exploration::Exploration;
use crate::policy::MlpPolicy;

/// Which data plane the actor uses for steps and policies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneChoice {
    /// Shared memory when the learner offers it on this host, gRPC otherwise.
    Auto,
    /// Always gRPC.
    Grpc,
    /// Shared memory; an error when the learner does not offer it on this host.
    Shm,
}

/// A `--data-plane` that is not auto, grpc or shm.
#[derive(Debug, Error)]
#[error("unknown data plane `{0}` (expected auto, grpc or shm)")]
pub struct UnknownPlane(String);

impl std::str::FromStr for PlaneChoice {
    type Err = UnknownPlane;
    fn from_str(s: &str) -> Result<Self, UnknownPlane> {
        match s {
            "auto" => Ok(Self::Auto),
            "grpc" => Ok(Self::Grpc),
            "shm" => Ok(Self::Shm),
            _ => Err(UnknownPlane(s.into())),
        }
    }
}

/// Why a [`PlannerFactory`] could not build a planner.
/// Builds the run's planner for one episode from its kind and seed.
pub type PlannerFactory = dyn Fn(PlannerKind, u64) -> Box<dyn Planner> + Sync;

/// Why the actor process stopped with an error ([`run`]).
#[derive(Debug, Error)]
pub enum ActorError {
    /// The I/O runtime did not start.
    #[error("cannot start the tokio runtime")]
    Runtime(#[source] std::io::Error),
    /// The learner could not be reached, or sessions kept failing, for `give_up_after`.
    #[error("actor rank {rank}: learner at {addr} unreachable for {elapsed:?}")]
    GaveUp {
        /// The actor's rank.
        rank: u32,
        /// The learner's address.
        addr: String,
        /// How long it has been unreachable.
        elapsed: Duration,
        /// The last session's failure.
        #[source]
        last: Box<SessionError>,
    },
}

/// Why a session with the learner ended (the actor then registers again until it gives up).
/// The message is complete in itself (it is logged on reconnects).
#[derive(Debug, Error)]
pub enum SessionError {
    /// The learner went away or asked for a new session (restart, lost connection).
    #[error("{0}")]
    Lost(String),
    /// Connecting to the learner failed.
    #[error(transparent)]
    Connect(#[from] proto::grpc::ConnectError),
    /// The learner refused or failed the registration.
    #[error("register: {0}")]
    Register(String),
    /// The registration reply lacks a part.
    #[error("register: the reply {0}")]
    Reply(&'static str),
    /// The run spec names a planner, action space or environment settings this build cannot
    /// use (an unknown enum value, an out-of-range field).
    #[error("register: the learner's run spec: {0}")]
    Spec(#[from] crate::spec::SpecError),
    /// The actor asked for shared memory and the learner does not offer it on this host.
    #[error("--data-plane shm: the learner offers `{offered}`, not shared memory on this host ({host})")]
    NoSharedMemory {
        /// What the learner offers.
        offered: String,
        /// This host.
        host: String,
    },
    /// The shared-memory planes did not open.
    #[error(transparent)]
    Plane(#[from] PlaneError),
    /// A published policy does not fit the run's layer sizes.
    #[error("policy version {version}: {source}")]
    Policy {
        /// The policy version.
        version: u64,
        /// Why.
        source: crate::policy::PolicyError,
    },
    /// The assigned world does not exist or could not be generated.
    #[error(transparent)]
    World(#[from] sim::catalog::LoadError),
    /// The environment refused its settings or an action.
    #[error(transparent)]
    Environment(#[from] crate::env::EnvError),
}

/// What the actor process needs.
pub struct ActorSetup<'a> {
    /// The learner's address, token and TLS.
    pub learner: LearnerAddress,
    /// This actor's rank (seeds derive from it).
    pub rank: u32,
    /// Data plane choice.
    pub plane: PlaneChoice,
    /// Simulator settings.
    pub episode: EpisodeConfig,
    /// The run's planner by name.
    pub make_planner: &'a PlannerFactory,
    /// Give up (exit with an error) after the learner has been unreachable this long.
    pub give_up_after: Duration,
}

/// Why a session ended.
enum SessionEnd {
    /// The learner said the run is over.
    Shutdown,
    /// Register again (the learner restarted, or the connection broke).
    Reconnect(String),
}

fn status_text(s: &tonic::Status) -> String {
    format!("{:?}: {}", s.code(), s.message())
}

/// Runs the actor until the learner says the run is over (`Ok`) or it has been unreachable for
/// `give_up_after` (`Err`).
///
/// Each session with the learner runs in an `actor` span carrying the rank and, once
/// registered, the actor id the learner gave it, so every event of the session (and of its
/// heartbeat task) names the actor.
pub fn run(setup: &ActorSetup<'_>) -> Result<(), ActorError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .thread_name("adp-actor-io")
        .build()
        .map_err(ActorError::Runtime)?;
    let mut wait = Duration::from_millis(200);
    let mut down_since: Option<Instant> = None;
    // The registration of the previous session, which the next registration replaces.
    let mut previous: Option<Previous> = None;
    let mut tally = None;
    loop {
        let span = tracing::info_span!("actor", rank = setup.rank, actor_id = tracing::field::Empty);
        let ended = span.in_scope(|| session(&rt, setup, &mut down_since, &mut previous, &mut tally, &span));
        let why = match ended {
            Ok(SessionEnd::Shutdown) => {
                span.in_scope(|| tracing::info!("the learner ended the run"));
                log_tally(tally);
                return Ok(());
            }
            Ok(SessionEnd::Reconnect(why)) => SessionError::Lost(why),
            Err(e) => e,
        };
        let since = *down_since.get_or_insert_with(Instant::now);
        if since.elapsed() > setup.give_up_after {
            log_tally(tally);
            return Err(ActorError::GaveUp {
                rank: setup.rank,
                addr: setup.learner.addr.clone(),
                elapsed: since.elapsed(),
                last: Box::new(why),
            });
        }
        span.in_scope(|| tracing::warn!(retry_in = ?wait, "session ended: {why}; reconnecting"));
        std::thread::sleep(wait);
        wait = (wait * 2).min(Duration::from_secs(5));
    }
}

/// Logs what the learner said of this actor's step records over all its sessions (planes with
/// acknowledgements only): the actor's side of the learner's counters.
fn log_tally(tally: Option<SinkTally>) {
    if let Some(t) = tally {
        tracing::info!(
            sent = t.sent,
            accepted = t.accepted,
            duplicates = t.duplicates,
            refused = t.refused,
            unacknowledged = t.unacknowledged,
            resends = t.resends,
            "step records over the run"
        );
    }
}

/// Flags the heartbeat task ([`heartbeats`]) shares with the episode loop.
#[derive(Default)]
pub struct Flags {
    /// The lease being worked (0: none); the heartbeats renew it and set it to 0 when the
    /// learner says it is no longer valid.
    pub lease: AtomicU64,
    /// The learner ended the lease (finished, expired, dropped or cut).
    pub lease_lost: AtomicBool,
    /// The learner said the run is over.
    pub shutdown: AtomicBool,
    /// The learner no longer knows this session, or has not answered for a lease TTL: register
    /// again.
    pub gone: AtomicBool,
}

struct Planes {
    sink: Box<dyn StepSink>,
    policies: Box<dyn PolicySource>,
    /// The data plane of the steps (`shm` or `grpc`), for the log.
    name: &'static str,
    /// Whether policies come over shared memory (until a silent source is replaced).
    shm_policies: bool,
}

/// The data planes of a session: shared memory when the learner offers it on this host and
/// the actor allows it, else gRPC. With `--data-plane auto`, shared memory that cannot be
/// opened (all of the learner's ports taken, an unusable iceoryx2 directory) falls back to
/// gRPC with a warning; with `shm` it is the session's error.
fn open_planes(
    rt: &tokio::runtime::Runtime,
    setup: &ActorSetup<'_>,
    spec: &pb::RunSpec,
    data: proto::grpc::DataClient,
    run: &pb::RunRef,
    actor_id: u64,
    secret: &ActorSecret,
) -> Result<Planes, SessionError> {
    let shm = spec
        .data_plane
        .strip_prefix("shm:")
        .and_then(|s| s.rsplit_once('@'))
        .filter(|(_, host)| *host == proto::hostname())
        .map(|(prefix, _)| prefix.to_owned());
    match (setup.plane, shm) {
        (PlaneChoice::Shm, None) => Err(SessionError::NoSharedMemory {
            offered: spec.data_plane.clone(),
            host: proto::hostname(),
        }),
        (PlaneChoice::Auto | PlaneChoice::Shm, Some(prefix)) => match open_shm(setup.rank, prefix) {
            Ok(planes) => Ok(planes),
            Err(e) if setup.plane == PlaneChoice::Auto => {
                tracing::warn!(error = %e, "shared memory unavailable; streaming over gRPC");
                Ok(open_grpc(rt, setup, data, run, actor_id, secret))
            }
            Err(e) => Err(e.into()),
        },
        _ => Ok(open_grpc(rt, setup, data, run, actor_id, secret)),
    }
}

/// The shared-memory planes under the learner's service `prefix`. The learner created the
/// services with its port limit; the actor requires one port of each.
fn open_shm(rank: u32, prefix: String) -> Result<Planes, PlaneError> {
    let cfg = ShmConfig {
        service_prefix: prefix,
        max_actors: 1,
        ..ShmConfig::default()
    };
    let node = format!("adp-actor-{rank}-{}", std::process::id());
    Ok(Planes {
        sink: Box::new(ShmStepSink::open(&cfg, &node)?),
        policies: Box::new(ShmPolicySource::open(&cfg, &node)?),
        name: "shm",
        shm_policies: true,
    })
}

/// The gRPC planes; a broken step stream is resent for as long as the actor's patience with
/// the learner (`give_up_after`).
fn open_grpc(
    rt: &tokio::runtime::Runtime,
    setup: &ActorSetup<'_>,
    data: proto::grpc::DataClient,
    run: &pb::RunRef,
    actor_id: u64,
    secret: &ActorSecret,
) -> Planes {
    Planes {
        sink: Box::new(GrpcStepSink::new(
            rt.handle().clone(),
            data.clone(),
            &run.run_id,
            run.incarnation,
            setup.give_up_after,
        )),
        policies: grpc_policies(rt, data, run, actor_id, secret),
        name: "grpc",
        shm_policies: false,
    }
}

/// Policies streamed by the learner's `WatchPolicy`.
fn grpc_policies(
    rt: &tokio::runtime::Runtime,
    data: proto::grpc::DataClient,
    run: &pb::RunRef,
    actor_id: u64,
    secret: &ActorSecret,
) -> Box<dyn PolicySource> {
    Box::new(GrpcPolicySource::start(
        rt.handle(),
        data,
        &run.run_id,
        run.incarnation,
        actor_id,
        secret,
    ))
}

/// A registration this actor process held: its id and credential. Sent with the next
/// registration, it lets the learner retire it at once (a registration without it leaves a
/// live registration of the rank in place, lease and all).
struct Previous {
    actor_id: u64,
    secret: proto::Bytes,
}

/// One session with the learner, in `span` (whose `actor_id` it records once registered);
/// `previous` is the registration it replaces, and becomes this session's. What the learner
/// said of the session's step records is added to `tally`.
fn session(
    rt: &tokio::runtime::Runtime,
    setup: &ActorSetup<'_>,
    down_since: &mut Option<Instant>,
    previous: &mut Option<Previous>,
    tally: &mut Option<SinkTally>,
    span: &tracing::Span,
) -> Result<SessionEnd, SessionError> {
    let Registered {
        control,
        data,
        run,
        spec,
        actor_id,
        secret,
        wire_secret,
        space,
        planner,
        env_cfg,
        dims,
    } = register(rt, setup, down_since, previous.as_ref(), span)?;
    *previous = Some(Previous {
        actor_id,
        secret: wire_secret.clone(),
    });
    let planes = open_planes(rt, setup, &spec, data.clone(), &run, actor_id, &secret)?;
    tracing::info!(
        run_id = %run.run_id,
        planner = %planner,
        action_space = %space,
        plane = planes.name,
        "registered"
    );
    let flags = Arc::new(Flags::default());
    let lease_ttl = Duration::from_millis(u64::from(spec.lease_ttl_ms.max(spec.heartbeat_ms).max(10)));
    let heartbeat = rt.spawn(
        heartbeats(
            control.clone(),
            run.clone(),
            actor_id,
            wire_secret.clone(),
            Duration::from_millis(u64::from(spec.heartbeat_ms.max(10))),
            lease_ttl,
            flags.clone(),
        )
        .instrument(span.clone()),
    );
    let _stop_heartbeats = AbortOnDrop(heartbeat);
    let ctx = EpisodeCtx {
        setup,
        spec: &spec,
        planner,
        space,
        env_cfg: &env_cfg,
        flags: &flags,
    };
    let mut live = Live {
        rt,
        control,
        data,
        run,
        actor_id,
        secret,
        wire_secret,
        dims,
        lease_ttl,
        planes,
        policy: None,
    };
    // How long a finished run may take to drain this actor's last lease before it leaves: as
    // long as the learner keeps the lease valid, up to the actor's patience with the learner.
    let drain_limit = setup.give_up_after;
    let ended = live.assignments(&ctx, &flags, drain_limit);
    if let Some(t) = live.planes.sink.tally() {
        *tally.get_or_insert_default() += t;
    }
    ended
}

impl Live<'_> {
    /// Takes and runs assignments until the session ends.
    fn assignments(
        &mut self,
        ctx: &EpisodeCtx<'_>,
        flags: &Flags,
        drain_limit: Duration,
    ) -> Result<SessionEnd, SessionError> {
        loop {
            if flags.shutdown.load(Ordering::Acquire) {
                wait_for_lease_end(flags, drain_limit);
                return Ok(SessionEnd::Shutdown);
            }
            if flags.gone.load(Ordering::Acquire) {
                return Ok(SessionEnd::Reconnect(
                    "the learner no longer knows this session, or stopped answering heartbeats".into(),
                ));
            }
            let a = match self.next_assignment()? {
                Next::Assign(a) => a,
                Next::Idle(ms) => {
                    std::thread::sleep(Duration::from_millis(u64::from(ms.max(1))));
                    continue;
                }
                Next::Shutdown => {
                    wait_for_lease_end(flags, drain_limit);
                    return Ok(SessionEnd::Shutdown);
                }
                Next::End(end) => return Ok(end),
            };
            tracing::debug!(
                lease = a.lease_id,
                world = a.world,
                cycle = a.cycle,
                episodes = a.episodes,
                policy_version = a.policy_version,
                "assignment"
            );
            flags.lease.store(a.lease_id, Ordering::Release);
            flags.lease_lost.store(false, Ordering::Release);
            if let Some(end) = self.await_policy(&a, flags)? {
                return Ok(end);
            }
            if let Some(end) = self.run_assignment(ctx, &a, flags)? {
                return Ok(end);
            }
            // The lease stays in the heartbeats until the learner has received all its steps and
            // finished it (steps may still wait in the learner's queue behind its rate limiter).
        }
    }
}

/// What the learner told this actor at registration, decoded.
struct Registered {
    control: ControlClient,
    data: proto::grpc::DataClient,
    run: pb::RunRef,
    spec: pb::RunSpec,
    actor_id: u64,
    secret: ActorSecret,
    /// The secret as sent on the control plane.
    wire_secret: proto::Bytes,
    space: ActionSpace,
    planner: PlannerKind,
    env_cfg: EnvConfig,
    /// The policy network's layer sizes.
    dims: Vec<usize>,
}

/// Connects, registers this actor (replacing its `previous` registration) and decodes the
/// run's spec; records the actor id in `span`.
fn register(
    rt: &tokio::runtime::Runtime,
    setup: &ActorSetup<'_>,
    down_since: &mut Option<Instant>,
    previous: Option<&Previous>,
    span: &tracing::Span,
) -> Result<Registered, SessionError> {
    let (mut control, data) = rt.block_on(setup.learner.connect())?;
    let reply = rt
        .block_on(control.register(pb::RegisterRequest {
            rank: setup.rank,
            host: proto::hostname(),
            pid: std::process::id(),
            run_id: String::new(),
            actor_kind: "rust".into(),
            previous_actor_id: previous.map_or(0, |p| p.actor_id),
            previous_actor_secret: previous.map(|p| p.secret.clone()).unwrap_or_default(),
        }))
        .map_err(|s| SessionError::Register(status_text(&s)))?
        .into_inner();
    *down_since = None;
    let run = reply.run.ok_or(SessionError::Reply("names no run"))?;
    let spec = reply.spec.ok_or(SessionError::Reply("has no run spec"))?;
    let actor_id = reply.actor_id;
    let secret: ActorSecret = reply.actor_secret[..]
        .try_into()
        .map_err(|_| SessionError::Reply("has no 16-byte actor secret"))?;
    let wire_secret = reply.actor_secret.clone();
    span.record("actor_id", actor_id);
    let space = crate::spec::action_space_from_wire(
        spec.action_space
            .as_ref()
            .ok_or(SessionError::Reply("has no action space"))?,
    )?;
    let planner = crate::spec::planner_from_wire("spec.planner", spec.planner)?;
    let env_cfg = crate::spec::env_from_wire(
        spec.env
            .as_ref()
            .ok_or(SessionError::Reply("has no environment settings"))?,
    )?;
    let dims: Vec<usize> = spec.policy_dims.iter().map(|&d| d as usize).collect();
    Ok(Registered {
        control,
        data,
        run,
        spec,
        actor_id,
        secret,
        wire_secret,
        space,
        planner,
        env_cfg,
        dims,
    })
}

/// The learner's answer to a request for work.
enum Next {
    /// Run this assignment.
    Assign(pb::Assignment),
    /// Nothing to do yet: ask again after this many milliseconds.
    Idle(u32),
    /// The run is over.
    Shutdown,
    /// The session must end (and reconnect).
    End(SessionEnd),
}

/// A registered session: its connection, planes and newest policy.
struct Live<'a> {
    rt: &'a tokio::runtime::Runtime,
    control: ControlClient,
    data: proto::grpc::DataClient,
    run: pb::RunRef,
    actor_id: u64,
    secret: ActorSecret,
    wire_secret: proto::Bytes,
    dims: Vec<usize>,
    lease_ttl: Duration,
    planes: Planes,
    /// (version, exploration sigma, network) of the newest policy received.
    policy: Option<(u64, f64, MlpPolicy)>,
}

impl Live<'_> {
    /// Asks the learner for the next assignment.
    fn next_assignment(&mut self) -> Result<Next, SessionError> {
        let reply = self
            .rt
            .block_on(self.control.next_assignment(pb::AssignmentRequest {
                run: Some(self.run.clone()),
                actor_id: self.actor_id,
                actor_secret: self.wire_secret.clone(),
            }));
        let decision = match reply {
            Ok(r) => r.into_inner().decision,
            Err(s) => {
                return Ok(Next::End(SessionEnd::Reconnect(format!(
                    "next assignment: {}",
                    status_text(&s)
                ))))
            }
        };
        Ok(match decision {
            Some(pb::assignment_reply::Decision::Shutdown(_)) => Next::Shutdown,
            Some(pb::assignment_reply::Decision::IdleMs(ms)) => Next::Idle(ms),
            Some(pb::assignment_reply::Decision::Assign(a)) => Next::Assign(a),
            None => Next::End(SessionEnd::Reconnect("empty assignment reply".into())),
        })
    }

    /// Waits for the assignment's policy version (or a lost lease, or a gone learner). A
    /// shared-memory source that has not delivered it within a lease TTL is replaced by
    /// gRPC's WatchPolicy for the rest of the session (steps stay on shared memory), before
    /// the learner's no-progress bound would drop the lease. `Some` ends the session.
    fn await_policy(
        &mut self,
        a: &pb::Assignment,
        flags: &Flags,
    ) -> Result<Option<SessionEnd>, SessionError> {
        let waiting_since = Instant::now();
        loop {
            if self.planes.shm_policies && waiting_since.elapsed() >= self.lease_ttl {
                tracing::warn!(
                    wanted = a.policy_version,
                    have = self.policy.as_ref().map(|p| p.0),
                    waited_ms = waiting_since.elapsed().as_millis() as u64,
                    "no policy over shared memory; watching policies over gRPC"
                );
                self.planes.policies =
                    grpc_policies(self.rt, self.data.clone(), &self.run, self.actor_id, &self.secret);
                self.planes.shm_policies = false;
            }
            match self.planes.policies.poll(self.policy.as_ref().map(|p| p.0)) {
                Ok(Some(update)) => {
                    let net = MlpPolicy::from_flat(&self.dims, update.weights).map_err(|source| {
                        SessionError::Policy {
                            version: update.version,
                            source,
                        }
                    })?;
                    tracing::debug!(
                        version = update.version,
                        sigma = update.exploration_sigma,
                        "policy received"
                    );
                    self.policy = Some((update.version, update.exploration_sigma, net));
                }
                Ok(None) => {}
                Err(e) => return Ok(Some(SessionEnd::Reconnect(e.to_string()))),
            }
            if self.policy.as_ref().is_some_and(|p| p.0 >= a.policy_version) {
                return Ok(None);
            }
            if flags.lease_lost.load(Ordering::Acquire) || flags.gone.load(Ordering::Acquire) {
                return Ok(None);
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Runs the assignment's episodes with the newest policy, streaming their steps and
    /// reporting each; stops at a lost lease. `Some` ends the session.
    fn run_assignment(
        &mut self,
        ctx: &EpisodeCtx<'_>,
        a: &pb::Assignment,
        flags: &Flags,
    ) -> Result<Option<SessionEnd>, SessionError> {
        let Some((version, sigma, net)) = self.policy.as_ref() else {
            return Ok(None);
        };
        // Once per assignment: a generated world is made on this call.
        let world = sim::catalog::load(a.world as usize)?;
        let header = LeaseHeader {
            incarnation: self.run.incarnation,
            actor_id: self.actor_id,
            lease_id: a.lease_id,
            secret: self.secret,
        };
        for i in 0..a.episodes {
            if flags.lease_lost.load(Ordering::Acquire) {
                break;
            }
            let seed = a.seeds.get(i as usize).copied().unwrap_or(a.lease_id);
            let episode_id = a.first_episode_id + u64::from(i);
            let outcome = match ctx.episode(
                &world,
                episode_id,
                seed,
                (*version, *sigma, net),
                &header,
                self.planes.sink.as_mut(),
            ) {
                Ok(o) => o,
                Err(EpisodeError::Plane(e)) => return Ok(Some(SessionEnd::Reconnect(e.to_string()))),
                Err(EpisodeError::LeaseLost) => {
                    // Records of the lost lease may still wait in the sink (the gRPC sink
                    // batches them): send them now, to be refused and counted, rather than in
                    // front of the next lease's records, whose flush would then fail and throw
                    // away that lease's finished episode with a needless re-registration.
                    match self.planes.sink.flush() {
                        Ok(()) => {}
                        Err(PlaneError::Refused { refused, sent, .. }) => tracing::warn!(
                            lease = a.lease_id,
                            refused,
                            sent,
                            "lease lost; the learner refused step records of it"
                        ),
                        Err(e) => return Ok(Some(SessionEnd::Reconnect(e.to_string()))),
                    }
                    break;
                }
                Err(EpisodeError::Fatal(e)) => return Err(e),
            };
            match self.planes.sink.flush() {
                Ok(()) => {}
                // The learner answered: the lease is over (expired, broken, or the run ended),
                // the session is not. The next assignment (or the shutdown) comes from it.
                Err(PlaneError::Refused {
                    refused,
                    sent,
                    reason,
                }) => {
                    tracing::warn!(lease = a.lease_id, refused, sent, %reason, "the learner refused step records");
                    break;
                }
                Err(e) => return Ok(Some(SessionEnd::Reconnect(e.to_string()))),
            }
            tracing::debug!(
                lease = a.lease_id,
                episode_id,
                steps = outcome.steps,
                outcome = ?outcome.outcome(),
                episode_return = outcome.episode_return,
                "episode done"
            );
            let report = pb::EpisodeReport {
                run: Some(self.run.clone()),
                actor_id: self.actor_id,
                lease_id: a.lease_id,
                actor_secret: self.wire_secret.clone(),
                last_of_assignment: i + 1 == a.episodes,
                policy_version: *version,
                ..outcome
            };
            if let Err(s) = self.rt.block_on(self.control.report_episode(report)) {
                if s.code() == tonic::Code::NotFound {
                    // The lease expired meanwhile: the world was dealt again.
                    tracing::debug!(lease = a.lease_id, "report refused: {}", status_text(&s));
                    break;
                }
                return Ok(Some(SessionEnd::Reconnect(format!(
                    "episode report: {}",
                    status_text(&s)
                ))));
            }
        }
        Ok(None)
    }
}

/// Waits (at most `limit`) until the learner has finished or dropped this actor's lease: the
/// heartbeats keep it alive meanwhile. A data plane can accept a step before the learner has
/// stored it (shared memory queues it), so leaving earlier would let the lease expire with
/// steps still queued, and the learner would refuse them.
fn wait_for_lease_end(flags: &Flags, limit: Duration) {
    let start = Instant::now();
    while flags.lease.load(Ordering::Acquire) != 0
        && !flags.gone.load(Ordering::Acquire)
        && start.elapsed() < limit
    {
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Aborts a tokio task when dropped (the heartbeat task of a session).
pub struct AbortOnDrop(pub tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Renews the current lease every `every` and relays what the learner answers through `flags`.
///
/// Each call gets `every` (at least one second) to answer. When no heartbeat has succeeded for
/// longer than `ttl` the learner has expired the lease (or is gone): the session is marked gone
/// so that an actor waiting on the learner (for a policy, or to drain its last lease) leaves and
/// reconnects rather than waiting forever. Runs until aborted.
pub async fn heartbeats(
    mut control: ControlClient,
    run: pb::RunRef,
    actor_id: u64,
    secret: proto::Bytes,
    every: Duration,
    ttl: Duration,
    flags: Arc<Flags>,
) {
    let mut tick = tokio::time::interval(every);
    let mut last_ok = tokio::time::Instant::now();
    loop {
        tick.tick().await;
        let lease_id = flags.lease.load(Ordering::Acquire);
        let call = control.heartbeat(pb::HeartbeatRequest {
            run: Some(run.clone()),
            actor_id,
            lease_id,
            actor_secret: secret.clone(),
        });
        match tokio::time::timeout(every.max(Duration::from_secs(1)), call).await {
            Ok(Ok(r)) => {
                last_ok = tokio::time::Instant::now();
                let r = r.into_inner();
                // An invalid lease is either lost (expired: drop the assignment) or finished by
                // the learner once all its steps landed; either way stop heartbeating it.
                if !r.lease_valid
                    && lease_id != 0
                    && flags
                        .lease
                        .compare_exchange(lease_id, 0, Ordering::AcqRel, Ordering::Acquire)
                        .is_ok()
                {
                    flags.lease_lost.store(true, Ordering::Release);
                    // Refusals reach the actor this way whichever plane carried its steps.
                    if !r.lease_lost_reason.is_empty() {
                        tracing::warn!(
                            lease = lease_id,
                            reason = %r.lease_lost_reason,
                            "lease ended by the learner"
                        );
                    }
                }
                if r.shutdown {
                    flags.shutdown.store(true, Ordering::Release);
                }
            }
            Ok(Err(s)) if matches!(s.code(), tonic::Code::FailedPrecondition | tonic::Code::NotFound) => {
                flags.gone.store(true, Ordering::Release);
                flags.lease_lost.store(true, Ordering::Release);
            }
            // Transient failures (an error or no answer in time): the lease keeps running until
            // its TTL, after which the learner no longer honours it.
            Ok(Err(_)) | Err(_) => {
                if last_ok.elapsed() > ttl {
                    flags.gone.store(true, Ordering::Release);
                    flags.lease_lost.store(true, Ordering::Release);
                }
            }
        }
    }
}

enum EpisodeError {
    Plane(PlaneError),
    LeaseLost,
    Fatal(SessionError),
}

impl From<EnvError> for EpisodeError {
    fn from(e: EnvError) -> Self {
        EpisodeError::Fatal(e.into())
    }
}

/// What every episode of a session shares.
struct EpisodeCtx<'a> {
    setup: &'a ActorSetup<'a>,
    spec: &'a pb::RunSpec,
    /// The run's planner by name.
    planner: PlannerKind,
    space: ActionSpace,
    env_cfg: &'a EnvConfig,
    flags: &'a Flags,
}

/// Mixes an episode seed into the exploration stream's seed (splitmix64 finalizer).
fn exploration_seed(seed: u64) -> u64 {
    let mut z = seed ^ 0x9e37_79b9_7f4a_7c15;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl EpisodeCtx<'_> {
    /// Runs one episode of an assignment on its world `world`, streaming its steps; returns
    /// the report's outcome fields.
    fn episode(
        &self,
        world: &World,
        episode_id: u64,
        seed: u64,
        (version, sigma, net): (u64, f64, &MlpPolicy),
        header: &LeaseHeader,
        sink: &mut dyn StepSink,
    ) -> Result<pb::EpisodeReport, EpisodeError> {
        let planner = (self.setup.make_planner)(self.planner, seed);
        if self.flags.lease_lost.load(Ordering::Acquire) {
            return Err(EpisodeError::LeaseLost);
        }
        let run = Run {
            world,
            episode: self.setup.episode,
            planner,
            max_speed: self.spec.max_speed,
            seed,
        };
        let chooser = Chooser::Env {
            space: self.space,
            env: self.env_cfg,
            act: &mut Explore::new(net, Exploration::new(sigma, exploration_seed(seed))),
        };
        let mut checksum = 0u64;
        let r = closed_loop::run(run, chooser, |s| {
            let truncated = s.outcome.end == End::Truncated;
            let step = StepView {
                episode_id,
                step_index: s.index,
                policy_version: version,
                obs: s.obs,
                action: s.action,
                reward: s.outcome.reward,
                terminal: s.outcome.end == End::Terminal,
                truncated,
                final_obs: if truncated { s.next_obs } else { &[] },
            };
            sink.send(header, &step).map_err(EpisodeError::Plane)?;
            checksum = checksum.wrapping_add(step_checksum(&step));
            // As before every step: a lost lease ends the episode unreported.
            if s.outcome.end == End::Continue && self.flags.lease_lost.load(Ordering::Acquire) {
                return Err(EpisodeError::LeaseLost);
            }
            Ok(())
        })?;
        let outcome = match r.episode.status {
            Status::Succeeded => pb::Outcome::Success,
            Status::Collided => pb::Outcome::Collision,
            _ => pb::Outcome::Timeout,
        };
        Ok(pb::EpisodeReport {
            episode_id,
            // The world was loaded from the assignment's 32-bit id.
            world: world.id as u32,
            outcome: outcome as i32,
            time_s: r.episode.time_s,
            score: r.episode.score,
            episode_return: r.episode_return,
            steps: r.agent_steps,
            steps_checksum: checksum,
            ..Default::default()
        })
    }
}
