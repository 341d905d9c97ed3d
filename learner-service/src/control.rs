//! The gRPC control plane: register, next assignment, heartbeat, episode report, shutdown.

use std::sync::atomic::Ordering;
use std::sync::Arc;

use proto::pb::{self, control_server::Control};
use proto::validate::Refusal;
use scheduler::{Decision, RegistryError};
use tonic::{Request, Response, Status};

use crate::listen::{peer_name, Cause, Peer, PeerInfo};
use crate::shared::Shared;
use crate::state::Core;

/// The `adp.v1.Control` service over the learner's shared state.
pub struct ControlService {
    pub(super) shared: Arc<Shared>,
    /// The operator credential `Shutdown` needs (the contents of `operator.token`).
    pub(super) operator: Arc<str>,
}

/// The gRPC status for a refusal: stale runs are FAILED_PRECONDITION (the actor registers
/// again), everything else INVALID_ARGUMENT or NOT_FOUND.
pub fn refusal_status(why: &Refusal) -> Status {
    match why {
        Refusal::WrongRun { .. } | Refusal::StaleIncarnation { .. } => {
            Status::failed_precondition(why.to_string())
        }
        Refusal::UnknownActor(..) | Refusal::Lease(..) => Status::not_found(why.to_string()),
        Refusal::Unauthenticated(_) => Status::unauthenticated(why.to_string()),
        _ => Status::invalid_argument(why.to_string()),
    }
}

impl ControlService {
    fn check_run(&self, run: &Option<pb::RunRef>) -> Result<(), Status> {
        let run = run.clone().unwrap_or_default();
        self.shared
            .validator
            .check_run(&run.run_id, run.incarnation)
            .map_err(|why| {
                self.shared.refuse(&why, 1);
                refusal_status(&why)
            })
    }

    /// Refuses a request naming `actor_id` without that actor's credential (counting a wrong
    /// credential).
    fn check_secret(&self, actor_id: u64, secret: &[u8]) -> Result<(), Status> {
        self.shared.authenticate(actor_id, secret).map_err(|why| {
            // A wrong credential is counted; an id that is not (or no longer) registered is
            // the ordinary answer to an actor whose learner restarted or retired it.
            if matches!(why, Refusal::Unauthenticated(_)) {
                let _actor = tracing::info_span!("actor", actor_id).entered();
                self.shared.refuse(&why, 1);
            }
            refusal_status(&why)
        })
    }

    /// The registration a `Register` request proves to replace: `previous_actor_id` when
    /// `previous_actor_secret` is its credential and it is a registration of the same rank.
    /// Anything else (no claim, an id this learner does not know or retired, a wrong secret,
    /// another rank) proves nothing.
    fn replaced(core: &Core, r: &pb::RegisterRequest) -> Option<u64> {
        let proven = !r.previous_actor_secret.is_empty()
            && core
                .check_secret(r.previous_actor_id, &r.previous_actor_secret)
                .is_ok()
            && core.registry.rank_of(r.previous_actor_id) == Some(r.rank);
        proven.then_some(r.previous_actor_id)
    }

    fn run_ref(&self) -> pb::RunRef {
        pb::RunRef {
            run_id: self.shared.validator.run_id.clone(),
            incarnation: self.shared.validator.incarnation,
        }
    }
}

fn registry_status(e: RegistryError) -> Status {
    match e {
        RegistryError::UnknownActor { .. } | RegistryError::RetiredActor { .. } => {
            Status::not_found(e.to_string())
        }
        _ => Status::failed_precondition(e.to_string()),
    }
}

#[tonic::async_trait]
impl Control for ControlService {
    async fn register(
        &self,
        request: Request<pb::RegisterRequest>,
    ) -> Result<Response<pb::RegisterReply>, Status> {
        let peer = peer_name(request.extensions());
        let address = match PeerInfo::of(request.extensions()).map(PeerInfo::peer) {
            Some(Peer::Tcp(addr)) => Some(addr.ip().to_canonical()),
            _ => None,
        };
        let r = request.into_inner();
        if !r.run_id.is_empty() && r.run_id != self.shared.validator.run_id {
            let why = Refusal::WrongRun {
                expected: self.shared.validator.run_id.clone(),
                got: r.run_id,
            };
            self.shared.refuse(&why, 1);
            return Err(refusal_status(&why));
        }
        let kind = match proto::validate::check_name("host", &r.host)
            .and_then(|()| proto::validate::actor_kind(&r.actor_kind))
        {
            Ok(kind) => kind,
            Err(why) => {
                self.shared.refuse(&why, 1);
                return Err(refusal_status(&why));
            }
        };
        let secret = proto::auth::new_actor_secret()
            .map_err(|e| Status::unavailable(format!("cannot make an actor secret: {e}")))?;
        let now = self.shared.now_ms();
        let (actor_id, replaced, kept) = {
            let mut core = self.shared.lock();
            let replaced = Self::replaced(&core, &r);
            if let Some(ip) = address {
                let mut by_address = self
                    .shared
                    .registrations_by_address
                    .lock()
                    .expect("registrations per address");
                let ids = by_address.entry(ip).or_default();
                ids.retain(|&id| Some(id) != replaced && core.registry.is_live(id));
                if ids.len() >= self.shared.registrations_per_address {
                    let why = format!(
                        "{ip} already has {} live registrations ([service] registrations_per_ip)",
                        ids.len()
                    );
                    self.shared.connections.refuse(
                        Cause::RegistrationsPerAddress,
                        &peer,
                        &format_args!("Register refused: {why}"),
                    );
                    return Err(Status::resource_exhausted(why));
                }
            }
            let id = core
                .registry
                .register(r.rank, r.host.clone(), r.pid, now, replaced);
            core.registered(id, r.rank, kind, secret);
            if let Some(ip) = address {
                self.shared
                    .registrations_by_address
                    .lock()
                    .expect("registrations per address")
                    .entry(ip)
                    .or_default()
                    .push(id);
            }
            // The rank's live registrations this request could not prove to be: they keep their
            // leases, and the new registration works beside them.
            let kept: Vec<(u64, u64)> = core
                .registry
                .live_actors_of_rank(r.rank)
                .into_iter()
                .filter(|&(other, _)| other != id)
                .map(|(other, seen)| (other, now.saturating_sub(seen)))
                .collect();
            (id, replaced, kept)
        };
        tracing::info!(
            actor_id,
            rank = r.rank,
            kind,
            host = %r.host,
            pid = r.pid,
            replaces = ?replaced,
            peer = %peer,
            "actor registered"
        );
        if !kept.is_empty() {
            self.shared
                .registrations_beside_live
                .fetch_add(1, Ordering::Relaxed);
            tracing::warn!(
                actor_id,
                rank = r.rank,
                peer = %peer,
                host = %r.host,
                pid = r.pid,
                "rank {} registered again without the secret of its live actor(s) {:?} \
                 (actor id, ms since heard from): they keep their leases, and this registration \
                 works beside them as actor {actor_id} (an actor restarted by its supervisor, or \
                 a second process claiming the rank); the older one is retired once it stops \
                 heartbeating",
                r.rank,
                kept
            );
        }
        Ok(Response::new(pb::RegisterReply {
            actor_id,
            run: Some(self.run_ref()),
            spec: Some(self.shared.spec.clone()),
            actor_secret: proto::Bytes::copy_from_slice(&secret),
        }))
    }

    async fn next_assignment(
        &self,
        request: Request<pb::AssignmentRequest>,
    ) -> Result<Response<pb::AssignmentReply>, Status> {
        let r = request.into_inner();
        self.check_run(&r.run)?;
        self.check_secret(r.actor_id, &r.actor_secret)?;
        let now = self.shared.now_ms();
        let mut core = self.shared.lock();
        let decision = if core.stopping {
            pb::assignment_reply::Decision::Shutdown(true)
        } else {
            let version = core.policy_version;
            match core
                .registry
                .next_assignment(r.actor_id, now, version)
                .map_err(registry_status)?
            {
                Decision::Idle => pb::assignment_reply::Decision::IdleMs(self.shared.idle_retry_ms),
                // The actor already works on (or has finished) this lease and its last steps are
                // still landing: not a lost reply, so do not hand the same episodes out again.
                Decision::Assign(a) if core.lease_started(a.lease_id) => {
                    pb::assignment_reply::Decision::IdleMs(self.shared.idle_retry_ms)
                }
                Decision::Assign(a) => {
                    let first = core.open_lease(a.lease_id, r.actor_id, a.episodes, now);
                    tracing::debug!(
                        actor_id = r.actor_id,
                        rank = core.registry.rank_of(r.actor_id),
                        lease = a.lease_id,
                        world = a.world,
                        cycle = a.cycle,
                        episodes = a.episodes,
                        "lease granted"
                    );
                    pb::assignment_reply::Decision::Assign(pb::Assignment {
                        lease_id: a.lease_id,
                        world: a.world as u32,
                        episodes: a.episodes,
                        cycle: a.cycle,
                        // Policy version k is published when cycle k starts; the actor waits for it.
                        policy_version: a.cycle,
                        seeds: a.seeds,
                        first_episode_id: first,
                    })
                }
            }
        };
        drop(core);
        self.shared.wake.notify_all();
        Ok(Response::new(pb::AssignmentReply {
            decision: Some(decision),
        }))
    }

    async fn heartbeat(
        &self,
        request: Request<pb::HeartbeatRequest>,
    ) -> Result<Response<pb::HeartbeatReply>, Status> {
        let r = request.into_inner();
        self.check_run(&r.run)?;
        self.check_secret(r.actor_id, &r.actor_secret)?;
        let now = self.shared.now_ms();
        let mut core = self.shared.lock();
        let lease = (r.lease_id != 0).then_some(r.lease_id);
        let lease_valid = match core.registry.heartbeat(r.actor_id, lease, now) {
            Ok(()) => true,
            Err(e @ (RegistryError::UnknownActor { .. } | RegistryError::RetiredActor { .. })) => {
                return Err(registry_status(e))
            }
            Err(_) => false,
        };
        let lease_lost_reason = match lease {
            Some(id) if !lease_valid => core.dropped_reason(id).unwrap_or_default().to_owned(),
            _ => String::new(),
        };
        if let (Some(id), false) = (lease, lease_valid) {
            tracing::debug!(
                actor_id = r.actor_id,
                lease = id,
                dropped_because = %lease_lost_reason,
                "heartbeat names a lease that has ended (finished, expired or dropped)"
            );
        }
        Ok(Response::new(pb::HeartbeatReply {
            lease_valid,
            shutdown: core.stopping,
            lease_lost_reason,
        }))
    }

    async fn report_episode(&self, request: Request<pb::EpisodeReport>) -> Result<Response<pb::Ack>, Status> {
        let r = request.into_inner();
        match self.shared.report(&r) {
            Ok(()) => Ok(Response::new(pb::Ack {
                accepted: 1,
                ..pb::Ack::default()
            })),
            Err(why) => {
                let _actor =
                    tracing::info_span!("actor", actor_id = r.actor_id, lease = r.lease_id).entered();
                self.shared.refuse(&why, 1);
                Err(refusal_status(&why))
            }
        }
    }

    async fn shutdown(&self, request: Request<pb::ShutdownRequest>) -> Result<Response<pb::Ack>, Status> {
        if !proto::auth::carries_operator_token(request.metadata(), &self.operator) {
            return Err(Status::permission_denied(format!(
                "Shutdown needs the operator credential: the `{}` header with the contents of \
                 <run dir>/{} (the run token that actors hold is not enough); `adp stop --run-dir \
                 DIR` sends it",
                proto::auth::OPERATOR_METADATA,
                crate::run_dir::OPERATOR_TOKEN_FILE
            )));
        }
        let r = request.into_inner();
        self.check_run(&r.run)?;
        tracing::info!("shutdown requested over gRPC");
        self.shared.request_stop(true);
        Ok(Response::new(pb::Ack::default()))
    }
}
