//! The learner's shared state ([`Shared`]): run identity and spec, refusal counters, and the
//! mutable [`Core`] behind one mutex. Both data planes ([`crate::ingest`]), the control plane,
//! lease expiry ([`crate::expiry`]) and the training thread go through it.
//!
//! Locking: one mutex ([`Shared::core`]) guards everything mutable; it is held for
//! bookkeeping and buffer copies only, never across a gradient update or network I/O. The
//! condition variable [`Shared::wake`] is notified after every insert, update, cycle change and
//! stop request.

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;

use proto::pb;
use proto::plane::LeaseHeader;
use proto::validate::{Refusal, RefusalCounts, Validator};

use crate::listen::ConnectionStats;
use crate::state::Core;
use crate::status::{
    KindStatus, OmittedRankSteps, OmittedRanks, RefusedLease, ResumeStatus, Status, KINDS_DETAILED,
    LEASES_REMEMBERED, OTHER_KINDS, RANKS_DETAILED,
};

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
    /// Connections and requests the servers refused, closed or repaired (shown in
    /// `status.json`).
    pub connections: Arc<ConnectionStats>,
    /// Registrations that found their rank held by a live registration whose secret they did
    /// not carry (shown in `status.json`).
    pub registrations_beside_live: AtomicU64,
    /// `[service] registrations_per_ip`.
    pub registrations_per_address: usize,
    /// The registrations made from each TCP source address (pruned to the live ones when the
    /// address registers again).
    pub registrations_by_address: Mutex<HashMap<IpAddr, Vec<u64>>>,
}

/// What the training thread measured since its last status (see [`Shared::status`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Rates {
    /// Agent steps stored per second.
    pub inserts_per_s: f64,
    /// Gradient updates per second.
    pub updates_per_s: f64,
    /// Mean policy-version lag of the steps stored.
    pub policy_lag: f64,
    /// Exploration sigma of the current inserts.
    pub exploration_sigma: f64,
}

impl Shared {
    /// Shared state over a fresh or restored core.
    pub fn new(
        validator: Validator,
        spec: pb::RunSpec,
        core: Core,
        budget: u64,
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
            connections: Arc::new(ConnectionStats::default()),
            registrations_beside_live: AtomicU64::new(0),
            registrations_per_address: usize::MAX,
            registrations_by_address: Mutex::new(HashMap::new()),
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

    /// A snapshot of the counters for `status.json` (call with `core`, this state's core,
    /// locked), with the training thread's rates since its last status.
    pub fn status(&self, core: &Core, rates: Rates) -> Status {
        let reg = core.registry.status();
        let t = &core.totals;
        let means = t.recent_means();
        Status {
            run_id: self.validator.run_id.clone(),
            incarnation: self.validator.incarnation,
            inserts: core.rate.inserts(),
            budget: self.budget,
            updates: core.rate.updates(),
            policy_version: core.policy_version,
            cycle: reg.cycle,
            replay_len: core.replay.len(),
            inserts_per_s: rates.inserts_per_s,
            updates_per_s: rates.updates_per_s,
            policy_lag: rates.policy_lag,
            exploration_sigma: rates.exploration_sigma,
            live_actors: reg.live_actors,
            open_leases: core.open_leases(),
            steps_received: t.steps_received,
            steps_duplicate: t.steps_duplicate,
            episodes: t.episodes_reported,
            episodes_verified: t.episodes_verified,
            episodes_mismatched: t.episodes_mismatched,
            episodes_abandoned: t.episodes_abandoned,
            leases_expired: t.leases_expired,
            leases_dropped: t.leases_dropped,
            leases_cut: t.leases_cut,
            cycle_span_ms: reg.span_ms,
            median_episode_ms: reg.median_episode_ms,
            late_ranks: reg.late_ranks,
            success_rate: means.map(|m| m.0),
            mean_return: means.map(|m| m.1),
            mean_score: means.map(|m| m.2),
            refused: self
                .refusals
                .snapshot()
                .into_iter()
                .map(|(k, v)| (k.to_owned(), v))
                .collect(),
            world_episodes: reg.worlds.iter().map(|w| (w.world, w.completed)).collect(),
            rank_steps: t
                .rank_steps
                .iter()
                .take(RANKS_DETAILED)
                .map(|(&r, &n)| (r, n))
                .collect(),
            rank_steps_omitted: OmittedRankSteps {
                ranks: t.rank_steps.len().saturating_sub(RANKS_DETAILED),
                steps: t.rank_steps.values().skip(RANKS_DETAILED).sum(),
            },
            actor_kinds: {
                let active = core.active_by_kind();
                let mut kinds: Vec<KindStatus> = t
                    .kinds
                    .iter()
                    .map(|(kind, k)| KindStatus {
                        kind: kind.clone(),
                        registered: k.registered,
                        active: active.get(kind).copied().unwrap_or(0),
                        episodes: k.episodes,
                        steps: k.steps,
                    })
                    .collect();
                if kinds.len() > KINDS_DETAILED {
                    let rest = kinds.split_off(KINDS_DETAILED - 1);
                    kinds.push(rest.into_iter().fold(
                        KindStatus {
                            kind: OTHER_KINDS.to_owned(),
                            ..KindStatus::default()
                        },
                        |mut sum, k| {
                            sum.registered += k.registered;
                            sum.active += k.active;
                            sum.episodes += k.episodes;
                            sum.steps += k.steps;
                            sum
                        },
                    ));
                }
                kinds
            },
            resume_warnings: self.resume_warnings.clone(),
            shm_unavailable: self.shm_unavailable.lock().expect("shm note lock").clone(),
            finished: is_set(&self.finished),
            ranks: core.ranks().take(RANKS_DETAILED).cloned().collect(),
            ranks_omitted: core
                .ranks()
                .skip(RANKS_DETAILED)
                .fold(OmittedRanks::default(), |mut sum, r| {
                    sum.ranks += 1;
                    sum.registrations += r.registrations;
                    sum.steps_shm += r.steps_shm;
                    sum.steps_grpc += r.steps_grpc;
                    sum
                }),
            rank_states: core.registry.rank_counts(),
            registrations_beside_live: self.registrations_beside_live.load(Ordering::Relaxed),
            connections: self.connections.snapshot(),
            leases_expired_recent: core.expired_recent().copied().collect(),
            refused_leases: self.refused_leases(),
            resumed_from: self.resumed_from.clone(),
            pruned_ranks: t.pruned_ranks,
        }
    }
}

/// Whether `flag` is set (acquire).
pub fn is_set(flag: &AtomicBool) -> bool {
    flag.load(Ordering::Acquire)
}
