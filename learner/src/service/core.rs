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
use proto::plane::LeaseHeader;
use proto::validate::{Refusal, RefusalCounts, Validator};
use proto::{pb, StepView};
use scheduler::{Registry, RegistryError};
use serde::{Deserialize, Serialize};

use crate::rate::RateLimiter;
use crate::replay::{ReplayBuffer, Step, StepEnd};

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
}

/// One reported episode, for the recent-episode statistics.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct EpisodeStat {
    /// Reached the goal.
    pub success: bool,
    /// Undiscounted return.
    pub episode_return: f64,
    /// BARN score.
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
    /// Leases that expired.
    pub leases_expired: u64,
    /// Recent episodes, oldest first.
    pub recent: VecDeque<EpisodeStat>,
    /// Successes among all reported episodes.
    pub successes: u64,
    /// Step records stored per actor rank (every task of a cluster job shows up here).
    #[serde(default)]
    pub rank_steps: BTreeMap<u32, u64>,
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
    started: Instant,
    /// Set once the training thread has finished (final checkpoint written).
    pub finished: AtomicBool,
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
            started: Instant::now(),
            finished: AtomicBool::new(false),
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

    /// Counts and logs a refusal (the first 50 in full, then every 1000th).
    pub fn refuse(&self, why: &Refusal, n: u64) {
        self.refusals.record(why, n);
        let mut left = self.log_budget.lock().expect("log budget");
        let total = self.refusals.total();
        if *left > 0 || total.is_multiple_of(1000) {
            *left = left.saturating_sub(1);
            eprintln!("learner: refused {n} record(s): {why} ({total} refused so far)");
        }
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

    /// Validates one step and stores it, blocking while the rate limiter holds inserts back.
    /// Returns the refusal when the step was refused (counted and logged).
    pub fn ingest(&self, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), Refusal> {
        let result = self.ingest_inner(header, step);
        if let Err(why) = &result {
            self.refuse(why, 1);
        }
        result
    }

    fn ingest_inner(&self, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), Refusal> {
        if header.incarnation != self.validator.incarnation {
            return Err(Refusal::StaleIncarnation {
                current: self.validator.incarnation,
                got: header.incarnation,
            });
        }
        self.validator.check_step(step)?;
        let mut core = self.lock();
        while core.rate.inserts_allowed() == 0 && !core.abort {
            core = self
                .wake
                .wait_timeout(core, Duration::from_millis(50))
                .expect("learner state lock poisoned")
                .0;
        }
        let now = self.now_ms();
        core.registry
            .check_lease(header.actor_id, header.lease_id, now)
            .map_err(lease_refusal)?;
        let lease = core.leases.get(&header.lease_id).ok_or_else(|| {
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
        let range = lease.first_episode..lease.first_episode + u64::from(lease.episodes);
        if !range.contains(&step.episode_id) {
            return Err(Refusal::Episode(
                step.episode_id,
                format!("not an episode of lease {} (expected {range:?})", header.lease_id),
            ));
        }
        let rank = lease.rank;
        let track = core.episodes.entry(step.episode_id).or_default();
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
        let pushed = core.replay.push(
            step.episode_id,
            &Step {
                obs: step.obs,
                action: step.action,
                reward: step.reward,
                end,
            },
        );
        if let Err(e) = pushed {
            return Err(Refusal::Episode(step.episode_id, e.to_string()));
        }
        let track = core.episodes.get_mut(&step.episode_id).expect("inserted above");
        track.next_index += 1;
        track.checksum = track.checksum.wrapping_add(step_checksum(step));
        let ended = step.terminal || step.truncated;
        track.ended = ended;
        core.rate.record_inserts(1);
        core.totals.steps_received += 1;
        *core.totals.rank_steps.entry(rank).or_default() += 1;
        let lag = core.policy_version.saturating_sub(step.policy_version);
        core.lag.0 += lag;
        core.lag.1 += 1;
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
    pub fn open_lease(core: &mut Core, lease_id: u64, actor: u64, episodes: u32) -> u64 {
        let first = first_episode_id(lease_id, episodes);
        let rank = core.registry.rank_of(actor).unwrap_or(u32::MAX);
        core.leases.insert(
            lease_id,
            LeaseTrack {
                actor,
                rank,
                first_episode: first,
                episodes,
            },
        );
        first
    }

    /// Handles an episode report: statistics, verification against the received steps, and the
    /// end of the lease once all its episodes are reported and complete.
    pub fn report(&self, r: &pb::EpisodeReport) -> Result<(), Refusal> {
        let run = r.run.clone().unwrap_or_default();
        self.validator.check_run(&run.run_id, run.incarnation)?;
        let now = self.now_ms();
        let mut core = self.lock();
        core.registry
            .check_lease(r.actor_id, r.lease_id, now)
            .map_err(lease_refusal)?;
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
        core.verify_episode(r.episode_id);
        core.try_finish(r.lease_id, now);
        Ok(())
    }

    /// Expires overdue leases: their worlds go back to the pool and their unfinished episodes
    /// are abandoned in the replay buffer (never marked terminal).
    pub fn expire_leases(&self) {
        let now = self.now_ms();
        let mut core = self.lock();
        for expired in core.registry.tick(now) {
            eprintln!(
                "learner: lease {} of actor {} (world {}) expired; the world is dealt again",
                expired.lease_id, expired.actor, expired.world
            );
            core.totals.leases_expired += 1;
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
            stopping: false,
            abort: false,
        }
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
            eprintln!(
                "learner: episode {episode}: received {} steps (checksum {:#x}), the actor reported {steps} \
                 ({checksum:#x})",
                track.next_index, track.checksum
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
            eprintln!("learner: finishing lease {lease_id}: {e}");
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
