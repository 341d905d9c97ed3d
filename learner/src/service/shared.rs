//! The learner's shared state: registry, replay buffer, rate limiter and the episode/lease
//! bookkeeping that decides what enters the buffer. Both data planes and the control plane go
//! through [`Shared`]; the training thread samples from it.
//!
//! Locking: one mutex ([`Shared::core`]) guards everything mutable; it is held for
//! bookkeeping and buffer copies only, never across a gradient update or network I/O. The
//! condition variable [`Shared::wake`] is notified after every insert, update, cycle change and
//! stop request.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use proto::checksum::step_checksum;
use proto::plane::{ActorSecret, LeaseHeader};
use proto::validate::{Refusal, RefusalCounts, Validator};
use proto::{pb, StepView};
use scheduler::{Registry, RegistryError};
use serde::{Deserialize, Serialize};

use super::status::{
    ExpiredLease, RankStatus, RefusedLease, ResumeStatus, LEASES_REMEMBERED, RANK_IDS_REMEMBERED,
};
use crate::rate::RateLimiter;
use crate::replay::{ReplayBuffer, Step, StepEnd};

/// The data plane a step record arrived on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// The shared-memory step service (actors on the learner's host).
    Shm,
    /// The gRPC `Data` service.
    Grpc,
}

/// Recent episodes kept for the success rate and mean return shown in progress and TensorBoard.
const RECENT_EPISODES: usize = 100;

/// Per-episode bookkeeping while its steps arrive.
#[derive(Debug, Default)]
struct EpisodeTrack {
    next_index: u32,
    checksum: u64,
    ended: bool,
    /// What the actor reported: (steps, checksum).
    reported: Option<(u32, u64)>,
}

/// Per-lease bookkeeping.
#[derive(Debug)]
struct LeaseTrack {
    actor: u64,
    rank: u32,
    first_episode: u64,
    episodes: u32,
    /// When the lease last made progress (opened, a step stored, a report accepted), in the
    /// registry's clock.
    progress_ms: u64,
    /// Why the lease can no longer finish (a step of one of its episodes was refused), if so.
    broken: Option<String>,
    /// The actor's kind (`rust`, `python`, ...).
    kind: String,
}

/// Counters of one actor kind (checkpointed with [`Totals`]).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct KindTotals {
    /// Registrations (a re-registration after a learner restart counts again).
    pub registered: u64,
    /// Episodes reported and accepted.
    pub episodes: u64,
    /// Step records stored.
    pub steps: u64,
}

/// Dropped leases remembered with the reason (told to their actors on their next heartbeat).
const DROPPED_REMEMBERED: usize = 4096;

/// Accepts a missing or `null` number (a counter written before reports were validated, when
/// serde_json turned NaN into `null`) as 0, so that counters can never make a checkpoint
/// unreadable.
fn finite_or_zero<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?
        .filter(|v| v.is_finite())
        .unwrap_or(0.0))
}

/// One reported episode, for the recent-episode statistics.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct EpisodeStat {
    /// Reached the goal.
    pub success: bool,
    /// Undiscounted return.
    #[serde(deserialize_with = "finite_or_zero")]
    pub episode_return: f64,
    /// BARN score.
    #[serde(deserialize_with = "finite_or_zero")]
    pub score: f64,
}

/// Counters that survive a resume (checkpointed in the run state's `extra`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Totals {
    /// Step records stored.
    pub steps_received: u64,
    /// Episodes reported by actors.
    pub episodes_reported: u64,
    /// Reported episodes whose received steps matched the actor's count and checksum.
    pub episodes_verified: u64,
    /// Reported episodes whose received steps did not match (should stay 0).
    pub episodes_mismatched: u64,
    /// Episodes left unfinished by an expired lease (their tail is never sampled; they are never
    /// marked terminal).
    pub episodes_abandoned: u64,
    /// Leases that expired (no heartbeat within their TTL).
    pub leases_expired: u64,
    /// Leases the learner dropped although their actor kept heartbeating: a step of one of their
    /// episodes was refused (the episode can never complete), or they made no progress for
    /// `[service] progress_timeout_ms`. Their worlds are dealt again.
    #[serde(default)]
    pub leases_dropped: u64,
    /// Recent episodes, oldest first.
    pub recent: VecDeque<EpisodeStat>,
    /// Successes among all reported episodes.
    pub successes: u64,
    /// Step records stored per actor rank (every task of a cluster job shows up here).
    #[serde(default)]
    pub rank_steps: BTreeMap<u32, u64>,
    /// Counters per actor kind (`rust`, `python`, `unknown`, ...).
    #[serde(default)]
    pub kinds: BTreeMap<String, KindTotals>,
    /// Refused records by reason (`RefusalKind` names), as of the checkpoint; a resumed
    /// learner continues counting from them.
    #[serde(default)]
    pub refusals: BTreeMap<String, u64>,
    /// The ranks forgotten so far (dead, see `[service] rank_forget_ms`), in aggregate.
    #[serde(default)]
    pub pruned_ranks: PrunedRanks,
}

/// Counters of forgotten ranks, in aggregate (checkpointed with [`Totals`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PrunedRanks {
    /// Ranks forgotten.
    pub ranks: u64,
    /// Their step records stored (their entries left [`Totals::rank_steps`]).
    pub steps: u64,
    /// Their registrations in the learner processes that forgot them.
    pub registrations: u64,
}

impl Totals {
    /// Success rate, mean return and mean score over the recent episodes.
    pub fn recent_means(&self) -> Option<(f64, f64, f64)> {
        let n = self.recent.len();
        (n > 0).then(|| {
            let n = n as f64;
            (
                self.recent.iter().filter(|e| e.success).count() as f64 / n,
                self.recent.iter().map(|e| e.episode_return).sum::<f64>() / n,
                self.recent.iter().map(|e| e.score).sum::<f64>() / n,
            )
        })
    }
}

/// Everything mutable, behind [`Shared::core`].
pub struct Core {
    /// Actors, leases, cycles.
    pub registry: Registry,
    /// The n-step replay buffer.
    pub replay: ReplayBuffer,
    /// Inserts vs updates.
    pub rate: RateLimiter,
    /// Counters.
    pub totals: Totals,
    /// Sum of (newest version - step's version) over steps since the last status, and count.
    pub lag: (u64, u64),
    /// The policy version published last.
    pub policy_version: u64,
    episodes: HashMap<u64, EpisodeTrack>,
    leases: HashMap<u64, LeaseTrack>,
    /// Recently dropped leases and why, oldest first (bounded by [`DROPPED_REMEMBERED`]).
    dropped: VecDeque<(u64, String)>,
    /// The kind of every actor registered with this learner process, by actor id.
    actor_kinds: HashMap<u64, String>,
    /// The credential of every current registration, by actor id (a retired or forgotten id
    /// has none: requests naming it are refused).
    secrets: HashMap<u64, ActorSecret>,
    /// Counters per rank over this learner process.
    ranks: BTreeMap<u32, RankStatus>,
    /// Leases that expired in this learner process, oldest first (bounded by
    /// [`LEASES_REMEMBERED`]).
    expired_recent: VecDeque<ExpiredLease>,
    /// No more assignments: the budget is stored or a stop was requested.
    pub stopping: bool,
    /// Stop now (signal, shutdown call) rather than after the owed updates.
    pub abort: bool,
}

/// The state shared by the planes, the control service and the training thread.
pub struct Shared {
    /// Run identity and spaces.
    pub validator: Validator,
    /// What actors are told at registration.
    pub spec: pb::RunSpec,
    /// Refused records by reason.
    pub refusals: Arc<RefusalCounts>,
    /// The mutable state.
    pub core: Mutex<Core>,
    /// Notified on inserts, updates, cycle changes and stop requests.
    pub wake: Condvar,
    /// Agent-step budget of the run.
    pub budget: u64,
    /// Episodes per assignment.
    pub episodes_per_assignment: u32,
    /// Idle retry hint for actors (ms).
    pub idle_retry_ms: u32,
    /// A lease that makes no progress for this long (ms) is dropped (see
    /// [`Shared::expire_leases`]).
    pub progress_timeout_ms: u64,
    /// Checkpoints a resume skipped and why (shown in `status.json`).
    pub resume_warnings: Vec<String>,
    /// Ranks whose actor has been dead this long (ms) are forgotten (`[service]
    /// rank_forget_ms`; never until the learner sets it).
    pub rank_forget_ms: u64,
    /// Most dead ranks remembered (`[service] dead_ranks_kept`; no bound until the learner
    /// sets it).
    pub dead_ranks_kept: usize,
    /// The longest episode actors make (`max_agent_steps` of the environment settings): a step
    /// with a higher index is refused. `u32::MAX` (no cap) until the learner sets it.
    pub max_episode_steps: u32,
    /// Why the shared-memory data plane is not in use, when it was offered but failed.
    pub shm_unavailable: Mutex<Option<String>>,
    started: Instant,
    /// Set once the training thread has finished (final checkpoint written).
    pub finished: AtomicBool,
    /// The checkpoint this learner resumed from, if it did (shown in `status.json`).
    pub resumed_from: Option<ResumeStatus>,
    /// Leases named by refusals and how many records each had refused, in the order first
    /// refused (bounded by [`LEASES_REMEMBERED`]).
    refused_leases: Mutex<VecDeque<RefusedLease>>,
    log_budget: Mutex<u32>,
}

/// First episode id of a lease: episode ids are `lease * episodes + i`, unique within a run
/// because lease ids are (they survive resumes in the registry snapshot).
pub fn first_episode_id(lease_id: u64, episodes: u32) -> u64 {
    lease_id * u64::from(episodes)
}

fn lease_refusal(e: RegistryError) -> Refusal {
    match e {
        RegistryError::UnknownActor { actor } => Refusal::UnknownActor(actor, "not registered".into()),
        RegistryError::RetiredActor { actor } => {
            Refusal::UnknownActor(actor, "retired (its rank registered again)".into())
        }
        RegistryError::UnknownLease { lease, .. }
        | RegistryError::ExpiredLease { lease, .. }
        | RegistryError::LeaseOfOtherActor { lease, .. }
        | RegistryError::AlreadyFinished { lease, .. }
        | RegistryError::EpisodeOverflow { lease, .. } => Refusal::Lease(lease, e.to_string()),
        other => Refusal::Lease(0, other.to_string()),
    }
}

impl Shared {
    /// Shared state over a fresh or restored core.
    pub fn new(
        validator: Validator,
        spec: pb::RunSpec,
        core: Core,
        budget: u64,
        episodes_per_assignment: u32,
        idle_retry_ms: u32,
        progress_timeout_ms: u64,
    ) -> Self {
        Self {
            validator,
            spec,
            refusals: Arc::new(RefusalCounts::default()),
            core: Mutex::new(core),
            wake: Condvar::new(),
            budget,
            episodes_per_assignment,
            idle_retry_ms,
            progress_timeout_ms,
            resume_warnings: Vec::new(),
            max_episode_steps: u32::MAX,
            rank_forget_ms: u64::MAX,
            dead_ranks_kept: usize::MAX,
            shm_unavailable: Mutex::new(None),
            started: Instant::now(),
            finished: AtomicBool::new(false),
            resumed_from: None,
            refused_leases: Mutex::new(VecDeque::new()),
            log_budget: Mutex::new(50),
        }
    }

    /// Milliseconds since the learner started (the registry's clock).
    pub fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    /// Locks the core.
    pub fn lock(&self) -> MutexGuard<'_, Core> {
        self.core.lock().expect("learner state lock poisoned")
    }

    /// Counts a refusal (by kind, and by lease when it names one) and logs it (the first 50
    /// in full, then every 1000th).
    pub fn refuse(&self, why: &Refusal, n: u64) {
        self.refusals.record(why, n);
        if let Refusal::Lease(lease, _) = why {
            if *lease != 0 {
                self.record_refused_lease(*lease, n);
            }
        }
        let mut left = self.log_budget.lock().expect("log budget");
        let total = self.refusals.total();
        if *left > 0 || total.is_multiple_of(1000) {
            *left = left.saturating_sub(1);
            tracing::warn!(
                records = n,
                kind = why.kind().name(),
                refused_total = total,
                "refused: {why}"
            );
        }
    }

    fn record_refused_lease(&self, lease: u64, n: u64) {
        let mut leases = self.refused_leases.lock().expect("refused leases lock");
        if let Some(l) = leases.iter_mut().rev().find(|l| l.lease == lease) {
            l.records += n;
            return;
        }
        leases.push_back(RefusedLease { lease, records: n });
        if leases.len() > LEASES_REMEMBERED {
            leases.pop_front();
        }
    }

    /// The leases named by refusals (see [`RefusedLease`]), oldest first.
    pub fn refused_leases(&self) -> Vec<RefusedLease> {
        self.refused_leases
            .lock()
            .expect("refused leases lock")
            .iter()
            .copied()
            .collect()
    }

    /// Asks the service to stop: no more assignments; with `abort`, the training thread stops
    /// without finishing the owed updates (signals, shutdown calls).
    pub fn request_stop(&self, abort: bool) {
        let mut core = self.lock();
        core.stopping = true;
        core.abort |= abort;
        drop(core);
        self.wake.notify_all();
    }

    /// Validates one step that arrived on `plane` and stores it, blocking while the rate
    /// limiter holds inserts back. Returns the refusal when the step was refused (counted and
    /// logged).
    pub fn ingest(&self, plane: Plane, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), Refusal> {
        let result = self.ingest_inner(plane, header, step);
        if let Err(why) = &result {
            let _actor =
                tracing::info_span!("actor", actor_id = header.actor_id, lease = header.lease_id).entered();
            self.refuse(why, 1);
        }
        result
    }

    fn ingest_inner(&self, plane: Plane, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), Refusal> {
        if header.incarnation != self.validator.incarnation {
            return Err(Refusal::StaleIncarnation {
                current: self.validator.incarnation,
                got: header.incarnation,
            });
        }
        if let Err(why) = self.validator.check_step(step) {
            // The episode can never complete: end its lease (the actor is told), unless the
            // sender is not the lease's actor.
            let now = self.now_ms();
            self.lock().break_lease(header, &why, now);
            return Err(why);
        }
        let mut core = self.lock();
        core.check_secret(header.actor_id, &header.secret)?;
        // Hold inserts back while the learner lags, but only while an update can run: with
        // nothing ready to sample no update can make room, and waiting would deadlock.
        while core.rate.inserts_allowed() == 0 && core.replay.ready_len() > 0 && !core.abort {
            core = self
                .wake
                .wait_timeout(core, Duration::from_millis(50))
                .expect("learner state lock poisoned")
                .0;
        }
        let now = self.now_ms();
        if step.step_index >= self.max_episode_steps {
            let why = Refusal::Episode(
                step.episode_id,
                format!(
                    "step {} beyond the episode cap of {} agent steps (max_agent_steps)",
                    step.step_index, self.max_episode_steps
                ),
            );
            core.break_lease(header, &why, now);
            return Err(why);
        }
        let ended = core.store(plane, header, step, now)?;
        if core.rate.inserts() >= self.budget {
            core.stopping = true;
        }
        if ended {
            core.verify_episode(step.episode_id);
            core.try_finish(header.lease_id, now);
        }
        drop(core);
        self.wake.notify_all();
        Ok(())
    }

    /// Records an assignment's lease so its steps can be admitted.
    pub fn open_lease(core: &mut Core, lease_id: u64, actor: u64, episodes: u32, now_ms: u64) -> u64 {
        let first = first_episode_id(lease_id, episodes);
        let rank = core.registry.rank_of(actor).unwrap_or(u32::MAX);
        let kind = core.kind_of(actor).to_owned();
        core.leases.insert(
            lease_id,
            LeaseTrack {
                actor,
                rank,
                first_episode: first,
                episodes,
                progress_ms: now_ms,
                broken: None,
                kind,
            },
        );
        first
    }

    /// Refuses a request naming `actor_id` that does not carry that actor's credential
    /// (see [`Core::check_secret`]).
    pub fn authenticate(&self, actor_id: u64, secret: &[u8]) -> Result<(), Refusal> {
        self.lock().check_secret(actor_id, secret)
    }

    /// Marks the lease of a step that could not be decoded as broken (see
    /// [`Core::break_lease`]): every malformed step ends its lease.
    pub fn break_lease(&self, header: &LeaseHeader, why: &Refusal) {
        let now = self.now_ms();
        self.lock().break_lease(header, why, now);
    }

    /// Handles an episode report: statistics, verification against the received steps, and the
    /// end of the lease once all its episodes are reported and complete.
    pub fn report(&self, r: &pb::EpisodeReport) -> Result<(), Refusal> {
        let run = r.run.clone().unwrap_or_default();
        self.validator.check_run(&run.run_id, run.incarnation)?;
        let now = self.now_ms();
        let mut core = self.lock();
        core.check_secret(r.actor_id, &r.actor_secret)?;
        core.registry
            .check_lease(r.actor_id, r.lease_id, now)
            .map_err(lease_refusal)?;
        // Nothing that could make the counters (and so a checkpoint) unreadable gets in.
        proto::validate::check_report(r)?;
        if r.policy_version > core.policy_version {
            return Err(Refusal::FutureVersion {
                got: r.policy_version,
                newest: core.policy_version,
            });
        }
        let in_lease = core.leases.get(&r.lease_id).is_some_and(|l| {
            l.actor == r.actor_id
                && (l.first_episode..l.first_episode + u64::from(l.episodes)).contains(&r.episode_id)
        });
        if !in_lease {
            return Err(Refusal::Episode(
                r.episode_id,
                format!("not an episode of lease {}", r.lease_id),
            ));
        }
        let track = core.episodes.entry(r.episode_id).or_default();
        if track.reported.is_some() {
            return Err(Refusal::Episode(r.episode_id, "reported twice".into()));
        }
        track.reported = Some((r.steps, r.steps_checksum));
        // A report is proof of life: extend the lease like a heartbeat.
        core.registry
            .heartbeat(r.actor_id, Some(r.lease_id), now)
            .map_err(lease_refusal)?;
        core.registry
            .episode_done(r.actor_id, r.lease_id, now)
            .map_err(lease_refusal)?;
        let success = r.outcome == pb::Outcome::Success as i32;
        let t = &mut core.totals;
        t.episodes_reported += 1;
        t.successes += u64::from(success);
        t.recent.push_back(EpisodeStat {
            success,
            episode_return: r.episode_return,
            score: r.score,
        });
        if t.recent.len() > RECENT_EPISODES {
            t.recent.pop_front();
        }
        if let Some(lease) = core.leases.get_mut(&r.lease_id) {
            lease.progress_ms = now;
        }
        let core = &mut *core;
        if let Some(kind) = core
            .leases
            .get(&r.lease_id)
            .and_then(|l| core.totals.kinds.get_mut(l.kind.as_str()))
        {
            kind.episodes += 1;
        }
        core.verify_episode(r.episode_id);
        core.try_finish(r.lease_id, now);
        Ok(())
    }

    /// Expires overdue leases: their worlds go back to the pool and their unfinished episodes
    /// are abandoned in the replay buffer (never marked terminal).
    ///
    /// Also drops leases that cannot or do not finish although their actor keeps heartbeating:
    /// a lease with a refused step (its episode can never complete) at once, and a lease whose
    /// episodes made no progress (no step stored, no report accepted) for
    /// [`Shared::progress_timeout_ms`]. The clock of the latter stands still while the learner
    /// itself holds the actors up (its rate limiter blocks inserts, or the current cycle's
    /// policy is not published yet). A dropped lease's actor learns it on its next heartbeat
    /// (`lease_valid: false`, with the reason).
    pub fn expire_leases(&self) {
        self.expire_leases_at(self.now_ms());
    }

    fn expire_leases_at(&self, now: u64) {
        let mut core = self.lock();
        let learner_holds = core.rate.inserts_allowed() == 0 || core.policy_version < core.registry.cycle();
        let timeout = self.progress_timeout_ms;
        let mut drop_now: Vec<(u64, String)> = Vec::new();
        for (&id, lease) in core.leases.iter_mut() {
            if learner_holds {
                lease.progress_ms = now;
            }
            if let Some(why) = &lease.broken {
                drop_now.push((id, format!("a step was refused ({why})")));
            } else if now.saturating_sub(lease.progress_ms) >= timeout {
                drop_now.push((
                    id,
                    format!(
                        "no progress for {} ms (progress_timeout_ms {timeout})",
                        now - lease.progress_ms
                    ),
                ));
            }
        }
        let mut revoked = Vec::new();
        for (id, why) in drop_now {
            if core.registry.revoke(id) {
                let (actor_id, rank) = core.leases.get(&id).map_or((0, u32::MAX), |l| (l.actor, l.rank));
                tracing::warn!(
                    lease = id,
                    actor_id,
                    rank,
                    "lease dropped: {why}; its world is dealt again"
                );
                core.totals.leases_dropped += 1;
                core.remember_dropped(id, why);
                revoked.push(id);
            }
            core.drop_lease(id);
        }
        let forgotten = core
            .registry
            .forget_dead_ranks(now, self.rank_forget_ms, self.dead_ranks_kept);
        for (rank, actor) in forgotten {
            core.forget_rank(rank, actor);
        }
        for expired in core.registry.tick(now) {
            if revoked.contains(&expired.lease_id) {
                continue;
            }
            let rank = core.registry.rank_of(expired.actor).unwrap_or(u32::MAX);
            tracing::warn!(
                lease = expired.lease_id,
                actor_id = expired.actor,
                rank,
                world = expired.world,
                "lease expired; the world is dealt again"
            );
            core.totals.leases_expired += 1;
            core.expired_recent.push_back(ExpiredLease {
                lease: expired.lease_id,
                actor_id: expired.actor,
                rank,
                world: expired.world,
            });
            if core.expired_recent.len() > LEASES_REMEMBERED {
                core.expired_recent.pop_front();
            }
            core.drop_lease(expired.lease_id);
        }
        drop(core);
        self.wake.notify_all();
    }
}

impl Core {
    /// A core over the given parts.
    pub fn new(
        registry: Registry,
        replay: ReplayBuffer,
        rate: RateLimiter,
        totals: Totals,
        policy_version: u64,
    ) -> Self {
        Self {
            registry,
            replay,
            rate,
            totals,
            lag: (0, 0),
            policy_version,
            episodes: HashMap::new(),
            leases: HashMap::new(),
            dropped: VecDeque::new(),
            actor_kinds: HashMap::new(),
            secrets: HashMap::new(),
            ranks: BTreeMap::new(),
            expired_recent: VecDeque::new(),
            stopping: false,
            abort: false,
        }
    }

    /// Stores one validated step under its lease. Returns whether it ended its episode. A
    /// refusal after the lease was found valid breaks the lease (its episode cannot complete).
    fn store(
        &mut self,
        plane: Plane,
        header: &LeaseHeader,
        step: &StepView<'_>,
        now: u64,
    ) -> Result<bool, Refusal> {
        self.registry
            .check_lease(header.actor_id, header.lease_id, now)
            .map_err(lease_refusal)?;
        let lease = self.leases.get(&header.lease_id).ok_or_else(|| {
            Refusal::Lease(
                header.lease_id,
                "no assignment was handed out under this lease".into(),
            )
        })?;
        if lease.actor != header.actor_id {
            return Err(Refusal::Lease(
                header.lease_id,
                format!("belongs to actor {}", lease.actor),
            ));
        }
        let result = self.store_in_lease(plane, header.lease_id, step, now);
        if let Err(why) = &result {
            self.break_lease(header, why, now);
        }
        result
    }

    /// [`Self::store`] once the step's lease `lease_id` is known to be valid and the sender's.
    fn store_in_lease(
        &mut self,
        plane: Plane,
        lease_id: u64,
        step: &StepView<'_>,
        now: u64,
    ) -> Result<bool, Refusal> {
        let lease = &self.leases[&lease_id];
        let range = lease.first_episode..lease.first_episode + u64::from(lease.episodes);
        if !range.contains(&step.episode_id) {
            return Err(Refusal::Episode(
                step.episode_id,
                format!("not an episode of lease {} (expected {range:?})", lease_id),
            ));
        }
        if step.policy_version > self.policy_version {
            return Err(Refusal::FutureVersion {
                got: step.policy_version,
                newest: self.policy_version,
            });
        }
        let rank = lease.rank;
        let track = self.episodes.entry(step.episode_id).or_default();
        if track.ended {
            return Err(Refusal::Episode(step.episode_id, "already ended".into()));
        }
        if step.step_index != track.next_index {
            return Err(Refusal::Episode(
                step.episode_id,
                format!(
                    "step {} out of order (expected {})",
                    step.step_index, track.next_index
                ),
            ));
        }
        let end = match (step.terminal, step.truncated) {
            (true, _) => StepEnd::Terminal,
            (false, true) => StepEnd::Truncated {
                final_obs: step.final_obs,
            },
            _ => StepEnd::Continue,
        };
        self.replay
            .push(
                step.episode_id,
                &Step {
                    obs: step.obs,
                    action: step.action,
                    reward: step.reward,
                    end,
                },
            )
            .map_err(|e| Refusal::Episode(step.episode_id, e.to_string()))?;
        let track = self.episodes.get_mut(&step.episode_id).expect("inserted above");
        track.next_index += 1;
        track.checksum = track.checksum.wrapping_add(step_checksum(step));
        let ended = step.terminal || step.truncated;
        track.ended = ended;
        self.rate.record_inserts(1);
        self.totals.steps_received += 1;
        *self.totals.rank_steps.entry(rank).or_default() += 1;
        let r = self.rank_entry(rank);
        match plane {
            Plane::Shm => r.steps_shm += 1,
            Plane::Grpc => r.steps_grpc += 1,
        }
        let lag = self.policy_version.saturating_sub(step.policy_version);
        self.lag.0 += lag;
        self.lag.1 += 1;
        if let Some(lease) = self.leases.get_mut(&lease_id) {
            lease.progress_ms = now;
            if let Some(kind) = self.totals.kinds.get_mut(lease.kind.as_str()) {
                kind.steps += 1;
            }
        }
        Ok(ended)
    }

    /// Marks the open lease of a refused step as broken (dropped by the next lease tick), if
    /// the step was sent by the lease's actor (with its credential) under a currently valid
    /// lease.
    fn break_lease(&mut self, header: &LeaseHeader, why: &Refusal, now: u64) {
        if self.check_secret(header.actor_id, &header.secret).is_err()
            || self
                .registry
                .check_lease(header.actor_id, header.lease_id, now)
                .is_err()
        {
            return;
        }
        if let Some(lease) = self.leases.get_mut(&header.lease_id) {
            if lease.actor == header.actor_id && lease.broken.is_none() {
                lease.broken = Some(why.to_string());
            }
        }
    }

    /// Refuses a request naming `actor` whose `secret` is not the credential of that
    /// registration (compared in constant time): [`Refusal::Unauthenticated`] for a wrong
    /// secret, [`Refusal::UnknownActor`] for an id without one (retired, forgotten or never
    /// registered here).
    pub fn check_secret(&self, actor: u64, secret: &[u8]) -> Result<(), Refusal> {
        match self.secrets.get(&actor) {
            Some(expected) if proto::auth::secret_matches(expected, secret) => Ok(()),
            Some(_) => Err(Refusal::Unauthenticated(format!(
                "the actor secret does not match actor {actor} (each registration gets its own; \
                 send RegisterReply.actor_secret)"
            ))),
            None if self.registry.rank_of(actor).is_some() => Err(Refusal::UnknownActor(
                actor,
                "retired (its rank registered again)".into(),
            )),
            None => Err(Refusal::UnknownActor(actor, "not registered".into())),
        }
    }

    /// Records a registration of `actor` of `rank` as `kind` with credential `secret`; the
    /// rank's previous registration (retired by the registry) loses its credential.
    pub fn registered(&mut self, actor: u64, rank: u32, kind: &str, secret: ActorSecret) {
        if let Some(previous) = self.ranks.get(&rank).and_then(|r| r.actor_ids.last()) {
            self.secrets.remove(previous);
            self.actor_kinds.remove(previous);
        }
        self.secrets.insert(actor, secret);
        self.actor_kinds.insert(actor, kind.to_owned());
        self.totals.kinds.entry(kind.to_owned()).or_default().registered += 1;
        let r = self.rank_entry(rank);
        r.registrations += 1;
        r.actor_ids.push(actor);
        if r.actor_ids.len() > RANK_IDS_REMEMBERED {
            r.actor_ids.remove(0);
        }
    }

    /// Forgets the records of `rank` (and of its last actor), which the registry forgot:
    /// its counters go into [`Totals::pruned_ranks`].
    fn forget_rank(&mut self, rank: u32, actor: Option<u64>) {
        let pruned = &mut self.totals.pruned_ranks;
        pruned.ranks += 1;
        pruned.steps += self.totals.rank_steps.remove(&rank).unwrap_or(0);
        if let Some(r) = self.ranks.remove(&rank) {
            pruned.registrations += r.registrations;
        }
        if let Some(id) = actor {
            self.secrets.remove(&id);
            self.actor_kinds.remove(&id);
        }
        tracing::debug!(rank, actor_id = actor, "forgot a dead rank");
    }

    fn rank_entry(&mut self, rank: u32) -> &mut RankStatus {
        self.ranks.entry(rank).or_insert_with(|| RankStatus {
            rank,
            ..RankStatus::default()
        })
    }

    /// The counters per rank of this learner process, by rank.
    pub fn ranks(&self) -> impl Iterator<Item = &RankStatus> {
        self.ranks.values()
    }

    /// The leases that expired in this learner process (the newest [`LEASES_REMEMBERED`]),
    /// oldest first.
    pub fn expired_recent(&self) -> impl Iterator<Item = &ExpiredLease> {
        self.expired_recent.iter()
    }

    /// The kind `actor` registered as (`unknown` if it is not known here).
    pub fn kind_of(&self, actor: u64) -> &str {
        self.actor_kinds.get(&actor).map_or("unknown", String::as_str)
    }

    /// Live actors per kind.
    pub fn active_by_kind(&self) -> BTreeMap<String, usize> {
        let mut active = BTreeMap::new();
        for a in self.registry.actors().iter().filter(|a| a.live) {
            *active.entry(self.kind_of(a.id).to_owned()).or_default() += 1;
        }
        active
    }

    fn remember_dropped(&mut self, lease: u64, why: String) {
        self.dropped.push_back((lease, why));
        if self.dropped.len() > DROPPED_REMEMBERED {
            self.dropped.pop_front();
        }
    }

    /// Why the learner dropped `lease` although its actor kept heartbeating, if it did
    /// (recently).
    pub fn dropped_reason(&self, lease: u64) -> Option<&str> {
        self.dropped
            .iter()
            .rev()
            .find(|(id, _)| *id == lease)
            .map(|(_, why)| why.as_str())
    }

    /// Compares a finished, reported episode's received steps with the actor's report.
    fn verify_episode(&mut self, episode: u64) {
        let Some(track) = self.episodes.get(&episode) else {
            return;
        };
        let Some((steps, checksum)) = track.reported else {
            return;
        };
        if !track.ended {
            return;
        }
        if steps == track.next_index && checksum == track.checksum {
            self.totals.episodes_verified += 1;
        } else {
            self.totals.episodes_mismatched += 1;
            tracing::error!(
                episode,
                received_steps = track.next_index,
                received_checksum = format_args!("{:#x}", track.checksum),
                reported_steps = steps,
                reported_checksum = format_args!("{checksum:#x}"),
                "episode mismatch: the received steps differ from the actor's report"
            );
        }
    }

    /// Finishes the lease once every episode is reported and complete.
    fn try_finish(&mut self, lease_id: u64, now_ms: u64) {
        let Some(lease) = self.leases.get(&lease_id) else {
            return;
        };
        let ids = lease.first_episode..lease.first_episode + u64::from(lease.episodes);
        let done = ids.clone().all(|e| {
            self.episodes
                .get(&e)
                .is_some_and(|t| t.ended && t.reported.is_some())
        });
        if !done {
            return;
        }
        let actor = lease.actor;
        if let Err(e) = self.registry.finish(actor, lease_id, now_ms) {
            tracing::warn!(lease = lease_id, actor_id = actor, "cannot finish the lease: {e}");
        }
        for e in ids {
            self.episodes.remove(&e);
        }
        self.leases.remove(&lease_id);
    }

    /// Forgets a lease that will not finish, abandoning its open episodes.
    fn drop_lease(&mut self, lease_id: u64) {
        let Some(lease) = self.leases.remove(&lease_id) else {
            return;
        };
        for e in lease.first_episode..lease.first_episode + u64::from(lease.episodes) {
            if let Some(track) = self.episodes.remove(&e) {
                if !track.ended && track.next_index > 0 {
                    self.replay.abandon(e);
                    self.totals.episodes_abandoned += 1;
                }
            }
        }
    }

    /// Drops every lease (the learner restarted or is stopping).
    pub fn drop_all_leases(&mut self) {
        let ids: Vec<u64> = self.leases.keys().copied().collect();
        for id in ids {
            self.drop_lease(id);
        }
    }

    /// Whether any episode of the lease has received steps or a report.
    pub fn lease_started(&self, lease_id: u64) -> bool {
        self.leases.get(&lease_id).is_some_and(|l| {
            (l.first_episode..l.first_episode + u64::from(l.episodes)).any(|e| self.episodes.contains_key(&e))
        })
    }

    /// Open leases being tracked.
    pub fn open_leases(&self) -> usize {
        self.leases.len()
    }
}

/// Whether `flag` is set (relaxed).
pub fn is_set(flag: &AtomicBool) -> bool {
    flag.load(Ordering::Acquire)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Td3Config;
    use proto::validate::{RefusalKind, Spaces};
    use scheduler::{Decision, RegistryConfig};

    const TTL: u64 = 1000;

    /// A learner core with one registered actor holding one lease of two episodes.
    struct Fixture {
        shared: Arc<Shared>,
        header: LeaseHeader,
        first: u64,
    }

    fn fixture(td3: Td3Config, progress_timeout_ms: u64) -> Fixture {
        let registry = Registry::new(
            RegistryConfig {
                lease_ttl_ms: TTL,
                episodes_per_assignment: 2,
                run_seed: 1,
            },
            vec![3, 5],
        )
        .unwrap();
        let core = Core::new(
            registry,
            ReplayBuffer::new(&td3),
            RateLimiter::new(&td3),
            Totals::default(),
            0,
        );
        let validator = Validator {
            run_id: "run".into(),
            incarnation: 9,
            spaces: Spaces {
                obs_dim: td3.obs_dim,
                act_dim: td3.act_dim,
                laser_dim: td3.laser_dim,
            },
        };
        let shared = Arc::new(Shared::new(
            validator,
            pb::RunSpec::default(),
            core,
            1_000_000,
            2,
            100,
            progress_timeout_ms,
        ));
        let now = shared.now_ms();
        let mut core = shared.lock();
        let actor = core.registry.register(0, "host".into(), 1, now);
        core.registered(actor, 0, "rust", SECRET);
        let Decision::Assign(a) = core.registry.next_assignment(actor, now, 0).unwrap() else {
            panic!("no assignment");
        };
        let first = Shared::open_lease(&mut core, a.lease_id, actor, a.episodes, now);
        drop(core);
        Fixture {
            shared,
            header: LeaseHeader {
                incarnation: 9,
                actor_id: actor,
                lease_id: a.lease_id,
                secret: SECRET,
            },
            first,
        }
    }

    fn td3_config() -> Td3Config {
        Td3Config {
            obs_dim: 3,
            act_dim: 1,
            laser_dim: 0,
            replay_capacity: 1024,
            warmup_steps: 1000,
            ..Td3Config::default()
        }
    }

    /// The fixture actor's credential.
    const SECRET: ActorSecret = [7; 16];

    const OBS: [f32; 3] = [0.1, 0.2, 0.3];
    const ACTION: [f32; 1] = [0.5];

    fn step(episode_id: u64, step_index: u32) -> StepView<'static> {
        StepView {
            episode_id,
            step_index,
            policy_version: 0,
            obs: &OBS,
            action: &ACTION,
            reward: -0.5,
            terminal: false,
            truncated: false,
            final_obs: &[],
        }
    }

    fn report(f: &Fixture, episode_return: f64) -> pb::EpisodeReport {
        pb::EpisodeReport {
            run: Some(pb::RunRef {
                run_id: "run".into(),
                incarnation: 9,
            }),
            actor_id: f.header.actor_id,
            lease_id: f.header.lease_id,
            actor_secret: proto::Bytes::copy_from_slice(&SECRET),
            episode_id: f.first,
            episode_return,
            score: 0.1,
            time_s: 10.0,
            ..Default::default()
        }
    }

    #[test]
    fn a_nan_report_is_refused_and_counters_always_reach_a_resume() {
        let f = fixture(td3_config(), 60_000);
        let e = f.shared.report(&report(&f, f64::NAN)).unwrap_err();
        assert_eq!(e.kind(), RefusalKind::NotFinite, "{e}");
        let core = f.shared.lock();
        assert_eq!(core.totals.episodes_reported, 0);
        assert!(core.totals.recent.is_empty());
        drop(core);
        let mut future = report(&f, -3.0);
        future.policy_version = 7;
        let e = f.shared.report(&future).unwrap_err();
        assert!(e.to_string().contains("policy_version"), "{e}");
        // Counters written by a learner that let a NaN through (serde_json wrote `null`) still
        // load.
        let mut totals = Totals::default();
        totals.recent.push_back(EpisodeStat {
            success: false,
            episode_return: f64::NAN,
            score: f64::INFINITY,
        });
        let json = serde_json::to_value(&totals).unwrap();
        assert!(json["recent"][0]["episode_return"].is_null(), "{json}");
        let back: Totals = serde_json::from_value(json).unwrap();
        assert_eq!(back.recent[0].episode_return, 0.0);
        assert_eq!(back.recent[0].score, 0.0);
    }

    #[test]
    fn a_refused_step_ends_its_lease_the_actor_is_told_and_the_cycle_advances() {
        let f = fixture(td3_config(), 60_000);
        f.shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 0))
            .unwrap();
        let mut bad = step(f.first, 1);
        bad.reward = f32::NAN;
        assert_eq!(
            f.shared.ingest(Plane::Grpc, &f.header, &bad).unwrap_err().kind(),
            RefusalKind::NotFinite
        );
        // Every later step of the episode would be refused: the lease must not stay open.
        let now = f.shared.now_ms();
        f.shared.expire_leases_at(now);
        let core = f.shared.lock();
        assert_eq!(core.open_leases(), 0);
        assert_eq!((core.totals.leases_dropped, core.totals.leases_expired), (1, 0));
        assert_eq!(core.totals.episodes_abandoned, 1);
        assert!(core
            .registry
            .check_lease(f.header.actor_id, f.header.lease_id, now)
            .is_err());
        assert!(
            core.dropped_reason(f.header.lease_id)
                .is_some_and(|why| why.contains("reward")),
            "{:?}",
            core.dropped_reason(f.header.lease_id)
        );
        assert_eq!(core.registry.cycle(), 1, "the only actor's turn is over");
        assert_eq!(
            core.registry
                .status()
                .worlds
                .iter()
                .map(|w| w.completed)
                .sum::<u64>(),
            0
        );
    }

    #[test]
    fn out_of_order_and_duplicate_steps_are_refused_and_end_the_lease() {
        for (index, what) in [(0, "duplicate"), (2, "gap")] {
            let f = fixture(td3_config(), 60_000);
            f.shared
                .ingest(Plane::Grpc, &f.header, &step(f.first, 0))
                .unwrap();
            let e = f
                .shared
                .ingest(Plane::Grpc, &f.header, &step(f.first, index))
                .unwrap_err();
            assert_eq!(e.kind(), RefusalKind::Episode, "{what}: {e}");
            assert!(e.to_string().contains("out of order"), "{what}: {e}");
            f.shared.expire_leases_at(f.shared.now_ms());
            assert_eq!(f.shared.lock().totals.leases_dropped, 1, "{what}");
        }
    }

    #[test]
    fn a_lease_without_progress_is_dropped_although_heartbeats_keep_it_alive() {
        let timeout = 5 * TTL;
        let f = fixture(td3_config(), timeout);
        f.shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 0))
            .unwrap();
        let progress = f.shared.now_ms();
        let heartbeat = |t: u64| {
            f.shared
                .lock()
                .registry
                .heartbeat(f.header.actor_id, Some(f.header.lease_id), t)
                .unwrap();
        };
        // A live heartbeat thread, a hung main loop: the TTL alone never ends the lease.
        for t in (0..10).map(|k| progress + k * TTL / 2) {
            heartbeat(t);
            f.shared.expire_leases_at(t);
            assert_eq!(f.shared.lock().open_leases(), 1, "at {t} ms");
        }
        let t = progress + timeout + 10;
        heartbeat(t - 20);
        f.shared.expire_leases_at(t);
        let core = f.shared.lock();
        assert_eq!(core.open_leases(), 0);
        assert_eq!((core.totals.leases_dropped, core.totals.leases_expired), (1, 0));
        assert!(core
            .dropped_reason(f.header.lease_id)
            .is_some_and(|why| why.contains("no progress")));
    }

    #[test]
    fn no_progress_clock_stands_still_while_the_learner_owes_the_policy() {
        let timeout = 2 * TTL;
        let f = fixture(td3_config(), timeout);
        // The cycle moved on but its policy is not published yet (e.g. a checkpoint is being
        // written): waiting actors are not at fault.
        f.shared.lock().registry.revoke(f.header.lease_id);
        let _ = f.shared.lock().registry.tick(0);
        f.shared.lock().drop_lease(f.header.lease_id);
        let f = {
            let mut core = f.shared.lock();
            assert_eq!(core.registry.cycle(), 1);
            let Decision::Assign(a) = core.registry.next_assignment(f.header.actor_id, 0, 0).unwrap() else {
                panic!("no assignment in cycle 1");
            };
            Shared::open_lease(&mut core, a.lease_id, f.header.actor_id, a.episodes, 0);
            drop(core);
            Fixture {
                header: LeaseHeader {
                    lease_id: a.lease_id,
                    ..f.header
                },
                first: 0,
                shared: f.shared.clone(),
            }
        };
        let t = 10 * timeout;
        for beat in (0..t).step_by((TTL / 2) as usize) {
            f.shared
                .lock()
                .registry
                .heartbeat(f.header.actor_id, Some(f.header.lease_id), beat)
                .unwrap();
            f.shared.expire_leases_at(beat);
        }
        f.shared.expire_leases_at(t);
        assert_eq!(f.shared.lock().open_leases(), 1);
        assert_eq!(f.shared.lock().totals.leases_dropped, 0);
    }

    #[test]
    fn inserts_never_wait_for_updates_that_cannot_run() {
        // No warm-up and room for one update: after one insert the limiter holds inserts back,
        // but with n-step 6 nothing is ready to sample, so no update can make room.
        let f = fixture(
            Td3Config {
                warmup_steps: 0,
                updates_per_insert: 1.0,
                rate_tolerance: 1.0,
                ..td3_config()
            },
            60_000,
        );
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        let (shared, header, first) = (f.shared.clone(), f.header, f.first);
        std::thread::spawn(move || {
            for i in 0..3 {
                shared.ingest(Plane::Grpc, &header, &step(first, i)).unwrap();
            }
            done_tx.send(()).unwrap();
        });
        // A watchdog against the deadlock, not a timing assertion.
        done_rx
            .recv_timeout(Duration::from_secs(120))
            .expect("watchdog: ingest blocked although no update could run");
        assert_eq!(f.shared.lock().rate.inserts(), 3);
    }

    #[test]
    fn expired_leases_refusals_under_them_and_planes_are_counted_by_number() {
        let f = fixture(td3_config(), 60_000);
        f.shared.ingest(Plane::Shm, &f.header, &step(f.first, 0)).unwrap();
        // No heartbeat within the TTL: the lease expires; a late step under it is refused.
        f.shared.expire_leases_at(f.shared.now_ms() + 2 * TTL);
        let e = f
            .shared
            .ingest(Plane::Grpc, &f.header, &step(f.first, 1))
            .unwrap_err();
        assert_eq!(e.kind(), RefusalKind::Lease, "{e}");
        let (lease, actor_id) = (f.header.lease_id, f.header.actor_id);
        assert_eq!(
            f.shared.refused_leases(),
            vec![RefusedLease { lease, records: 1 }]
        );
        let core = f.shared.lock();
        let expired: Vec<ExpiredLease> = core.expired_recent().copied().collect();
        assert_eq!(expired.len(), 1);
        assert_eq!(
            (expired[0].lease, expired[0].actor_id, expired[0].rank),
            (lease, actor_id, 0)
        );
        let ranks: Vec<RankStatus> = core.ranks().cloned().collect();
        assert_eq!(
            ranks,
            vec![RankStatus {
                rank: 0,
                registrations: 1,
                actor_ids: vec![actor_id],
                steps_shm: 1,
                steps_grpc: 0,
            }]
        );
    }

    #[test]
    fn steps_of_a_policy_version_not_yet_published_are_refused() {
        let f = fixture(td3_config(), 60_000);
        let mut s = step(f.first, 0);
        s.policy_version = 3;
        let e = f.shared.ingest(Plane::Grpc, &f.header, &s).unwrap_err();
        assert!(e.to_string().contains("newer than the newest published"), "{e}");
    }
}
