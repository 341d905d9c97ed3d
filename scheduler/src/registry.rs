//! The actor registry: registrations, leases and cycles. Pure logic; time is a monotonic
//! millisecond clock supplied by the caller (`now_ms`).
//!
//! # Cycles
//! The registry counts cycles from 0. In a cycle each actor gets at most one assignment; an
//! actor that finished (or lost) its assignment of the current cycle gets [`Decision::Idle`]
//! until the cycle advances. The cycle advances when at least one actor had an assignment in
//! it and none of those assignments is still open (each was finished or its lease expired): a
//! barrier over the actors that are working. An actor that registers mid-cycle gets an
//! assignment of the current cycle at once. Every `&mut` method first expires overdue leases
//! and then checks the barrier, so the cycle can advance inside any of them.
//!
//! # Deadlines
//! A cycle does not wait forever (see [`crate::deadline`] for the arithmetic): once a lease
//! finished in this registry, the cycle ends at the latest one *span* (`max(floor, k x median
//! episode time x episodes)`) after its first assignment. Leases of the cycle still open then
//! are ended ([`ExpiryCause::CycleDeadline`]) like expired ones: their worlds are dealt again
//! first, and the caller abandons their open episodes (what was stored of them stays stored
//! and counted once; later data under them is refused). Their ranks become *late*: a late
//! actor's next assignments are off the barrier (the cycle does not wait for them; the actor
//! gets its next one as soon as one ends) and each ends one span after it was assigned
//! ([`ExpiryCause::LeaseDeadline`]); a late actor that finishes an assignment is on time again
//! and idles until the next cycle like every other. So a straggler costs at most one span,
//! once, and the other actors then work at their own pace. [`Registry::stall`] (the caller's
//! no-progress bound, see [`Registry::stall_bound_ms`]) makes a rank late too.
//!
//! # Leases
//! An assignment opens a lease that is valid while `now_ms < deadline_ms`; the deadline starts
//! at `now_ms + lease_ttl_ms` and [`Registry::heartbeat`] with the lease id moves it to
//! `now_ms + lease_ttl_ms`. An overdue lease expires: its world goes back to the dealer (dealt
//! again first) and an [`Expired`] record is queued for the next [`Registry::tick`]. Data under
//! a lease is accepted ([`Registry::check_lease`]) only while the lease is open: after
//! [`Registry::finish`] or expiry it is refused, so an actor must send all of its data before
//! it calls `finish`. An actor not heard from (any call naming it) for `lease_ttl_ms` counts as
//! dead until it calls again.
//!
//! # Ranks
//! A rank may have several registrations at once. Registering a rank retires the rank's dead
//! registrations and the one the caller proves to be (`replaces`: the caller checked that
//! actor's credential); a live registration the caller cannot prove is kept, with its lease,
//! beside the new one, so no registration can end another's lease. A registration that goes
//! dead while a newer one of its rank exists is retired then. Every registration of a rank
//! draws from the rank's one episode counter, so seeds never repeat. Retired ids are queued
//! for [`Registry::drain_retired`].
//!
//! # Checkpoints
//! [`Registry::snapshot`] keeps what must survive a restart: the dealer counts, the cycle
//! counter, the id counters and the per-rank episode counters. Actors and leases do not
//! survive: [`Registry::restore`] starts without them (actors register again) and with every
//! in-flight assignment returned to the dealer, so those worlds are dealt first.

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};

use crate::assignment::{ActorId, Assignment, Decision, Expired, ExpiryCause};
use crate::deadline::{DeadlineRule, EpisodeTimes};
use crate::dealer::{Dealer, DealerError, WorldCount, WorldPool};
use crate::seed::episode_seed;

/// How many finished or expired leases are remembered to tell "expired" and "already
/// finished" apart from "unknown" in errors; older ones are reported as unknown.
const CLOSED_LEASES_REMEMBERED: usize = 4096;

/// How many retired actor records (ids replaced by a newer registration of their rank) are
/// kept to answer "retired" in errors; older ones are dropped and reported as unknown, so a
/// run whose actors restart for days holds a bounded registry.
const RETIRED_ACTORS_REMEMBERED: usize = 1024;

/// Registry settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegistryConfig {
    /// Lease (and liveness) time-to-live in milliseconds; positive.
    pub lease_ttl_ms: u64,
    /// Episodes per assignment; positive (default 2).
    pub episodes_per_assignment: u32,
    /// The run seed: episode seeds and the dealer's tie-break order derive from it.
    pub run_seed: u64,
    /// When a cycle and a late actor's lease end (see the module documentation).
    #[serde(default)]
    pub deadline: DeadlineRule,
}

impl Default for RegistryConfig {
    /// A 30 s lease, 2 episodes per assignment, run seed 0, the default deadlines.
    fn default() -> Self {
        Self {
            lease_ttl_ms: 30_000,
            episodes_per_assignment: 2,
            run_seed: 0,
            deadline: DeadlineRule::default(),
        }
    }
}

/// Why a registry operation was refused. Every variant names the actor and lease concerned.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RegistryError {
    /// The actor id was never registered, or it retired too long ago to be remembered.
    #[error("actor {actor} is not registered")]
    UnknownActor {
        /// The actor id given.
        actor: ActorId,
    },
    /// The actor id was retired: a registration of its rank proved to be it, or it stopped
    /// heartbeating while its rank had registered again.
    #[error("actor {actor} is retired: its rank registered again under a new id")]
    RetiredActor {
        /// The actor id given.
        actor: ActorId,
    },
    /// The lease id was never issued, or it closed too long ago to be remembered.
    #[error("actor {actor}: lease {lease} is unknown")]
    UnknownLease {
        /// The actor id given.
        actor: ActorId,
        /// The lease id given.
        lease: u64,
    },
    /// The lease expired (no heartbeat within the TTL, or its actor re-registered).
    #[error("actor {actor}: lease {lease} expired; its world was dealt again")]
    ExpiredLease {
        /// The actor id given.
        actor: ActorId,
        /// The lease id given.
        lease: u64,
    },
    /// The lease was issued to a different actor.
    #[error("actor {actor}: lease {lease} belongs to actor {owner}")]
    LeaseOfOtherActor {
        /// The actor id given.
        actor: ActorId,
        /// The lease id given.
        lease: u64,
        /// The actor the lease was issued to.
        owner: ActorId,
    },
    /// The lease was already finished: no more data or `finish` is accepted under it.
    #[error("actor {actor}: lease {lease} is already finished")]
    AlreadyFinished {
        /// The actor id given.
        actor: ActorId,
        /// The lease id given.
        lease: u64,
    },
    /// More episodes were reported under the lease than it assigned.
    #[error("actor {actor}: lease {lease} assigned {episodes} episodes, and all were already reported")]
    EpisodeOverflow {
        /// The actor id given.
        actor: ActorId,
        /// The lease id given.
        lease: u64,
        /// The episodes of the assignment.
        episodes: u32,
    },
    /// The configuration is unusable.
    #[error("invalid registry configuration: {0}")]
    InvalidConfig(String),
    /// The list of worlds is unusable.
    #[error("invalid world list: {0}")]
    Worlds(#[from] DealerError),
}

/// A registered actor, as listed by [`Registry::actors`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ActorInfo {
    /// The actor id.
    pub id: ActorId,
    /// The actor's rank.
    pub rank: u32,
    /// The host it registered from.
    pub host: String,
    /// Its process id on that host.
    pub pid: u32,
    /// Whether it was heard from within the TTL (as of the last `&mut` call).
    pub live: bool,
    /// Its open lease, if any.
    pub lease: Option<u64>,
    /// When it was last heard from.
    pub last_seen_ms: u64,
}

/// Counters for a status display, from [`Registry::status`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegistryStatus {
    /// The current cycle; also the number of cycles completed, since cycles count from 0 and
    /// advance only by completing.
    pub cycle: u64,
    /// Actors heard from within the TTL.
    pub live_actors: usize,
    /// Live actors without an open lease.
    pub idle_actors: usize,
    /// Open leases.
    pub open_leases: usize,
    /// Leases that expired since the run started.
    pub expired_leases_total: u64,
    /// Assignments made since the run started.
    pub assignments_total: u64,
    /// Episodes reported through [`Registry::episode_done`] since the run started.
    pub episodes_reported_total: u64,
    /// Leases ended at a cycle's or their own deadline in this registry.
    pub leases_cut_total: u64,
    /// The median episode time of the newest finished leases (ms), if one finished here.
    pub median_episode_ms: Option<u64>,
    /// The span of an assignment now (ms): how long a cycle waits at most; `None` while
    /// nothing was measured (or deadlines are off).
    pub span_ms: Option<u64>,
    /// Ranks that are late (off the cycle barrier until they finish an assignment).
    pub late_ranks: usize,
    /// Per-world assignment counts from the dealer.
    pub worlds: Vec<WorldCount>,
}

/// How many ranks are in which state, from [`Registry::rank_counts`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RankCounts {
    /// Ranks with a live registration (heard from within the TTL).
    pub live: usize,
    /// Ranks without one, not forgotten yet (their actors stopped calling, or have not
    /// registered since a restore).
    pub dead: usize,
    /// Ranks whose registrations hold an open lease.
    pub leased: usize,
    /// Live registrations beyond one per rank (a rank registered again without proving to be
    /// its live registration: both work until one stops calling).
    pub extra_live: usize,
}

/// What of a registry survives a checkpoint; see the module documentation.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegistrySnapshot {
    dealer: Dealer,
    cycle: u64,
    next_actor_id: ActorId,
    next_lease_id: u64,
    rank_episodes: BTreeMap<u32, u64>,
    expired_leases_total: u64,
    assignments_total: u64,
    episodes_reported_total: u64,
    /// The most episodes issued to any forgotten rank: a rank registering later starts from
    /// here, so its seeds never repeat those of a forgotten rank of the same number.
    #[serde(default)]
    episode_floor: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Liveness {
    Live,
    Dead,
    Retired,
}

#[derive(Debug, Clone)]
struct ActorRecord {
    rank: u32,
    host: String,
    pid: u32,
    last_seen_ms: u64,
    liveness: Liveness,
    lease: Option<u64>,
}

/// The registrations of one rank.
#[derive(Debug, Clone, Default)]
struct RankSlot {
    /// Its registrations that are not retired, oldest first: the live ones and at most one dead
    /// one, the newest (older ones are retired when they die).
    actors: Vec<ActorId>,
    /// Episodes issued to the rank so far (its seeds' counter).
    issued: u64,
    /// Its last assignment ended at a deadline or stalled: its next ones are off the barrier.
    late: bool,
}

#[derive(Debug, Clone)]
struct OpenLease {
    assignment: Assignment,
    episodes_reported: u32,
    /// When it was assigned.
    assigned_ms: u64,
    /// A late actor's lease (off the barrier): its span (ms) and when that started counting
    /// (its assignment, or the last [`Registry::hold_deadlines`]).
    late: Option<(u64, u64)>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Closure {
    Finished,
    Expired,
}

/// An actor's part in the current cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Turn {
    Working,
    Done,
}

/// Actors, leases and cycles (see the module documentation).
///
/// Plain data: `Send` and `Sync`, mutated through `&mut self`; a server shares it behind a
/// mutex. Times are milliseconds of one monotonic clock chosen by the caller.
#[derive(Debug, Clone)]
pub struct Registry {
    config: RegistryConfig,
    dealer: Dealer,
    cycle: u64,
    next_actor_id: ActorId,
    next_lease_id: u64,
    actors: BTreeMap<ActorId, ActorRecord>,
    /// Retired actor ids still in `actors`, oldest first (at most
    /// [`RETIRED_ACTORS_REMEMBERED`]).
    retired: VecDeque<ActorId>,
    /// Actor ids retired since the last [`Registry::drain_retired`].
    newly_retired: Vec<ActorId>,
    /// Per rank: its registrations and the episodes issued to the rank so far.
    ranks: BTreeMap<u32, RankSlot>,
    open: BTreeMap<u64, OpenLease>,
    closed: BTreeMap<u64, (ActorId, Closure)>,
    turns: BTreeMap<ActorId, Turn>,
    expired_queue: Vec<Expired>,
    expired_leases_total: u64,
    assignments_total: u64,
    episodes_reported_total: u64,
    /// See [`RegistrySnapshot::episode_floor`].
    episode_floor: u64,
    /// Episode times of the newest finished leases.
    times: EpisodeTimes,
    /// When the current cycle's first on-time assignment was made, and when its deadline
    /// started counting (then, or the last [`Registry::hold_deadlines`]); `None` before it.
    cycle_opened: Option<(u64, u64)>,
    /// When a lease last finished (or the spans were last stretched).
    measured_ms: u64,
    /// Leases ended at a deadline.
    leases_cut_total: u64,
}

impl Registry {
    /// An empty registry at cycle 0 dealing from `worlds` (a list: non-empty, no duplicates).
    pub fn new(config: RegistryConfig, worlds: WorldPool) -> Result<Self, RegistryError> {
        let dealer = Dealer::of_pool(worlds, config.run_seed)?;
        Self::restore(
            config,
            RegistrySnapshot {
                dealer,
                cycle: 0,
                next_actor_id: 0,
                // Lease 0 means "no lease" on the wire (idle heartbeats).
                next_lease_id: 1,
                rank_episodes: BTreeMap::new(),
                expired_leases_total: 0,
                assignments_total: 0,
                episodes_reported_total: 0,
                episode_floor: 0,
            },
        )
    }

    /// A registry continuing from `snapshot` without actors or leases (see the module
    /// documentation); `config` may differ from the original run's (e.g. another TTL).
    pub fn restore(config: RegistryConfig, snapshot: RegistrySnapshot) -> Result<Self, RegistryError> {
        if config.lease_ttl_ms == 0 {
            return Err(RegistryError::InvalidConfig(
                "lease_ttl_ms must be positive".into(),
            ));
        }
        if config.episodes_per_assignment == 0 {
            return Err(RegistryError::InvalidConfig(
                "episodes_per_assignment must be positive".into(),
            ));
        }
        let mut dealer = snapshot.dealer;
        dealer.release_all_in_flight();
        Ok(Self {
            config,
            dealer,
            cycle: snapshot.cycle,
            next_actor_id: snapshot.next_actor_id,
            next_lease_id: snapshot.next_lease_id,
            actors: BTreeMap::new(),
            retired: VecDeque::new(),
            newly_retired: Vec::new(),
            ranks: snapshot
                .rank_episodes
                .into_iter()
                .map(|(rank, issued)| {
                    (
                        rank,
                        RankSlot {
                            actors: Vec::new(),
                            issued,
                            late: false,
                        },
                    )
                })
                .collect(),
            open: BTreeMap::new(),
            closed: BTreeMap::new(),
            turns: BTreeMap::new(),
            expired_queue: Vec::new(),
            expired_leases_total: snapshot.expired_leases_total,
            assignments_total: snapshot.assignments_total,
            episodes_reported_total: snapshot.episodes_reported_total,
            episode_floor: snapshot.episode_floor,
            times: EpisodeTimes::default(),
            cycle_opened: None,
            measured_ms: 0,
            leases_cut_total: 0,
        })
    }

    /// The state to checkpoint; in-flight assignments are recorded as released.
    pub fn snapshot(&self) -> RegistrySnapshot {
        let mut dealer = self.dealer.clone();
        dealer.release_all_in_flight();
        RegistrySnapshot {
            dealer,
            cycle: self.cycle,
            next_actor_id: self.next_actor_id,
            next_lease_id: self.next_lease_id,
            rank_episodes: self
                .ranks
                .iter()
                .map(|(&rank, slot)| (rank, slot.issued))
                .collect(),
            expired_leases_total: self.expired_leases_total,
            assignments_total: self.assignments_total,
            episodes_reported_total: self.episodes_reported_total,
            episode_floor: self.episode_floor,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &RegistryConfig {
        &self.config
    }

    /// The current cycle (0-based); equal to the number of cycles completed.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// Registers actor `rank` running as process `pid` on `host` and returns its new id.
    ///
    /// Retires the rank's dead registrations and `replaces` (an id the caller proved to be,
    /// ignored unless it is a current registration of `rank`): their open leases expire at
    /// once (reported by the next [`Registry::tick`]) and calls with their ids are refused. The
    /// rank's live registrations other than `replaces` are kept, leases and all, beside the new
    /// one (see the module documentation). The rank's episode counter continues, so its seeds
    /// never repeat.
    pub fn register(
        &mut self,
        rank: u32,
        host: String,
        pid: u32,
        now_ms: u64,
        replaces: Option<ActorId>,
    ) -> ActorId {
        self.settle(now_ms);
        let id = self.next_actor_id;
        self.next_actor_id += 1;
        let floor = self.episode_floor;
        let slot = self.ranks.entry(rank).or_insert_with(|| RankSlot {
            actors: Vec::new(),
            issued: floor,
            late: false,
        });
        let ending: Vec<ActorId> = slot
            .actors
            .iter()
            .copied()
            .filter(|&a| Some(a) == replaces || self.actors[&a].liveness == Liveness::Dead)
            .collect();
        for old in ending {
            self.retire(old);
        }
        self.ranks.get_mut(&rank).expect("inserted above").actors.push(id);
        self.actors.insert(
            id,
            ActorRecord {
                rank,
                host,
                pid,
                last_seen_ms: now_ms,
                liveness: Liveness::Live,
                lease: None,
            },
        );
        self.advance_if_done();
        id
    }

    /// The live registrations of `rank` (ids and when each was last heard from), oldest first.
    pub fn live_actors_of_rank(&self, rank: u32) -> Vec<(ActorId, u64)> {
        self.ranks.get(&rank).map_or_else(Vec::new, |slot| {
            slot.actors
                .iter()
                .map(|id| (*id, &self.actors[id]))
                .filter(|(_, record)| record.liveness == Liveness::Live)
                .map(|(id, record)| (id, record.last_seen_ms))
                .collect()
        })
    }

    /// Whether `actor` is a live registration (heartbeating within the TTL, not retired).
    pub fn is_live(&self, actor: ActorId) -> bool {
        self.actors
            .get(&actor)
            .is_some_and(|record| record.liveness == Liveness::Live)
    }

    /// The ids retired since the last call (their rank registered again, or they died beside a
    /// newer registration of their rank), for the caller to drop what it keeps per actor.
    pub fn drain_retired(&mut self) -> Vec<ActorId> {
        std::mem::take(&mut self.newly_retired)
    }

    /// The actor's next assignment: a new one (in the current cycle, at `policy_version`) if it
    /// has not had one this cycle, [`Decision::Idle`] if it finished or lost it; an actor
    /// that still holds an open lease gets that assignment again (e.g. the reply was lost). A
    /// late actor (see the module documentation) gets a new one whenever it holds none.
    pub fn next_assignment(
        &mut self,
        actor: ActorId,
        now_ms: u64,
        policy_version: u64,
    ) -> Result<Decision, RegistryError> {
        self.settle(now_ms);
        let (lease, rank) = self
            .touch(actor, now_ms)
            .map(|record| (record.lease, record.rank))?;
        if let Some(lease) = lease {
            return Ok(Decision::Assign(self.open[&lease].assignment.clone()));
        }
        if self.turns.contains_key(&actor) {
            return Ok(Decision::Idle);
        }
        let world = self.dealer.deal();
        let lease_id = self.next_lease_id;
        self.next_lease_id += 1;
        let episodes = self.config.episodes_per_assignment;
        let span = self.span_ms();
        let slot = self.ranks.get_mut(&rank).expect("a registered rank has a record");
        let late = span.filter(|_| slot.late).map(|span| (span, now_ms));
        let issued = &mut slot.issued;
        let seeds = (*issued..*issued + u64::from(episodes))
            .map(|counter| episode_seed(self.config.run_seed, rank, counter))
            .collect();
        *issued += u64::from(episodes);
        let assignment = Assignment {
            lease_id,
            actor,
            world,
            episodes,
            cycle: self.cycle,
            policy_version,
            seeds,
            deadline_ms: now_ms.saturating_add(self.config.lease_ttl_ms),
        };
        self.open.insert(
            lease_id,
            OpenLease {
                assignment: assignment.clone(),
                episodes_reported: 0,
                assigned_ms: now_ms,
                late,
            },
        );
        self.actors.get_mut(&actor).expect("touched above").lease = Some(lease_id);
        if late.is_none() {
            self.turns.insert(actor, Turn::Working);
            self.cycle_opened.get_or_insert((now_ms, now_ms));
        }
        self.assignments_total += 1;
        Ok(Decision::Assign(assignment))
    }

    /// Marks the actor alive and, with `Some(lease_id)`, extends that lease to
    /// `now_ms + lease_ttl_ms`. With `None` an open lease of the actor is not extended.
    pub fn heartbeat(
        &mut self,
        actor: ActorId,
        lease_id: Option<u64>,
        now_ms: u64,
    ) -> Result<(), RegistryError> {
        self.settle(now_ms);
        self.touch(actor, now_ms)?;
        if let Some(lease) = lease_id {
            self.open_lease(actor, lease)?;
            let deadline = now_ms.saturating_add(self.config.lease_ttl_ms);
            self.open
                .get_mut(&lease)
                .expect("checked open")
                .assignment
                .deadline_ms = deadline;
        }
        Ok(())
    }

    /// Counts one reported episode under the lease; refused unless the lease is open, and
    /// beyond the assignment's number of episodes.
    pub fn episode_done(&mut self, actor: ActorId, lease_id: u64, now_ms: u64) -> Result<(), RegistryError> {
        self.settle(now_ms);
        self.touch(actor, now_ms)?;
        self.open_lease(actor, lease_id)?;
        let open = self.open.get_mut(&lease_id).expect("checked open");
        if open.episodes_reported >= open.assignment.episodes {
            return Err(RegistryError::EpisodeOverflow {
                actor,
                lease: lease_id,
                episodes: open.assignment.episodes,
            });
        }
        open.episodes_reported += 1;
        self.episodes_reported_total += 1;
        Ok(())
    }

    /// Closes the lease as finished: its world counts as completed, its time is measured for
    /// the deadlines, the actor idles until the cycle advances (a late one is on time again),
    /// and no more data is accepted under the lease.
    pub fn finish(&mut self, actor: ActorId, lease_id: u64, now_ms: u64) -> Result<(), RegistryError> {
        self.settle(now_ms);
        self.touch(actor, now_ms)?;
        self.open_lease(actor, lease_id)?;
        let open = self.open.remove(&lease_id).expect("checked open");
        self.dealer
            .complete(open.assignment.world)
            .expect("an open lease holds an in-flight world");
        self.times
            .record(now_ms.saturating_sub(open.assigned_ms), open.assignment.episodes);
        self.measured_ms = now_ms;
        self.close(lease_id, actor, Closure::Finished);
        let record = self.actors.get_mut(&actor).expect("touched above");
        record.lease = None;
        let rank = record.rank;
        if let Some(slot) = self.ranks.get_mut(&rank) {
            slot.late = false;
        }
        self.turns.insert(actor, Turn::Done);
        self.advance_if_done();
        Ok(())
    }

    /// Whether data sent by `actor` under `lease_id` may be accepted at `now_ms`: the actor is
    /// current and the lease is its own, open, and not past its deadline (even if no `&mut`
    /// call has expired it yet). Data for finished leases is refused.
    pub fn check_lease(&self, actor: ActorId, lease_id: u64, now_ms: u64) -> Result<(), RegistryError> {
        self.record(actor)?;
        let open = self.open_lease(actor, lease_id)?;
        if now_ms >= open.assignment.deadline_ms {
            return Err(RegistryError::ExpiredLease {
                actor,
                lease: lease_id,
            });
        }
        Ok(())
    }

    /// Ends the open lease `lease_id` now as if it had expired (its world is dealt again, its
    /// actor idles until the next cycle, later data under it is refused, and the next
    /// [`Registry::tick`] reports it). For leases that cannot finish although their actor is
    /// alive. Returns whether the lease was open.
    pub fn revoke(&mut self, lease_id: u64) -> bool {
        self.end_now(lease_id, ExpiryCause::Revoked)
    }

    /// Ends the open lease `lease_id` as [`Registry::revoke`] does, for want of progress (the
    /// caller's bound, e.g. [`Registry::stall_bound_ms`]): its rank becomes late (see the
    /// module documentation). Returns whether the lease was open.
    pub fn stall(&mut self, lease_id: u64) -> bool {
        self.end_now(lease_id, ExpiryCause::Stalled)
    }

    fn end_now(&mut self, lease_id: u64, cause: ExpiryCause) -> bool {
        if !self.open.contains_key(&lease_id) {
            return false;
        }
        self.expire(lease_id, cause);
        self.advance_if_done();
        true
    }

    /// The caller holds the actors up at `now_ms` (it cannot take their data yet, or owes them
    /// the cycle's policy): the deadlines start counting again from `now_ms`, so no lease is
    /// ended for the caller's delay.
    pub fn hold_deadlines(&mut self, now_ms: u64) {
        if let Some((_, from)) = self.cycle_opened.as_mut() {
            *from = (*from).max(now_ms);
        }
        for open in self.open.values_mut() {
            if let Some((_, from)) = open.late.as_mut() {
                *from = (*from).max(now_ms);
            }
        }
    }

    /// The span of an assignment now (ms; see [`crate::deadline`]): a cycle ends at the latest
    /// this long after its first assignment. `None` before a lease finished here, or with
    /// deadlines off.
    pub fn span_ms(&self) -> Option<u64> {
        self.config
            .deadline
            .span_ms(self.times.median(), self.config.episodes_per_assignment)
    }

    /// How long a lease may go without progress before the caller should
    /// [`stall`](Registry::stall) it (`max(floor, k x median episode time)`); `None` before a
    /// lease finished here, or with deadlines off.
    pub fn stall_bound_ms(&self) -> Option<u64> {
        self.config.deadline.stall_ms(self.times.median())
    }

    /// Expires overdue leases, marks silent actors dead, advances the cycle if its barrier is
    /// met, and returns every lease expired since the previous `tick` (including those expired
    /// by other calls or by re-registration), oldest first.
    pub fn tick(&mut self, now_ms: u64) -> Vec<Expired> {
        self.settle(now_ms);
        std::mem::take(&mut self.expired_queue)
    }

    /// Forgets ranks whose registrations are all dead and hold no lease (and ranks without one
    /// since a restore, counted as last seen at time 0): those not seen for `after_ms` or more,
    /// and all but the `keep` most recently seen. Their actor records go too (calls naming
    /// those ids are then refused as unknown). Their episode counters fold into a floor that
    /// every rank registering later starts from, so seeds never repeat. Returns the forgotten
    /// ranks with their actor ids.
    pub fn forget_dead_ranks(&mut self, now_ms: u64, after_ms: u64, keep: usize) -> Vec<(u32, Vec<ActorId>)> {
        self.settle(now_ms);
        let mut dead: Vec<(u64, u32)> = self
            .ranks
            .iter()
            .filter(|(_, slot)| {
                slot.actors.iter().all(|id| {
                    let record = &self.actors[id];
                    record.liveness == Liveness::Dead && record.lease.is_none()
                })
            })
            .map(|(&rank, slot)| {
                let seen = slot
                    .actors
                    .iter()
                    .map(|id| self.actors[id].last_seen_ms)
                    .max()
                    .unwrap_or(0);
                (seen, rank)
            })
            .collect();
        if dead.len() <= keep && dead.iter().all(|d| now_ms.saturating_sub(d.0) < after_ms) {
            return Vec::new();
        }
        // Most recently seen first.
        dead.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut forgotten = Vec::new();
        for (i, (seen, rank)) in dead.into_iter().enumerate() {
            if i < keep && now_ms.saturating_sub(seen) < after_ms {
                continue;
            }
            let slot = self.ranks.remove(&rank).expect("listed above");
            self.episode_floor = self.episode_floor.max(slot.issued);
            for id in &slot.actors {
                self.actors.remove(id);
                self.turns.remove(id);
            }
            forgotten.push((rank, slot.actors));
        }
        self.advance_if_done();
        forgotten
    }

    /// The rank of actor `id` (also of a retired or dead one), if it ever registered here.
    pub fn rank_of(&self, id: ActorId) -> Option<u32> {
        self.actors.get(&id).map(|record| record.rank)
    }

    /// The registered, non-retired actors, by id.
    pub fn actors(&self) -> Vec<ActorInfo> {
        self.actors
            .iter()
            .filter(|(_, record)| record.liveness != Liveness::Retired)
            .map(|(&id, record)| ActorInfo {
                id,
                rank: record.rank,
                host: record.host.clone(),
                pid: record.pid,
                live: record.liveness == Liveness::Live,
                lease: record.lease,
                last_seen_ms: record.last_seen_ms,
            })
            .collect()
    }

    /// Counters as of the last `&mut` call.
    pub fn status(&self) -> RegistryStatus {
        let live = self
            .actors
            .values()
            .filter(|record| record.liveness == Liveness::Live);
        RegistryStatus {
            cycle: self.cycle,
            live_actors: live.clone().count(),
            idle_actors: live.filter(|record| record.lease.is_none()).count(),
            open_leases: self.open.len(),
            expired_leases_total: self.expired_leases_total,
            assignments_total: self.assignments_total,
            episodes_reported_total: self.episodes_reported_total,
            leases_cut_total: self.leases_cut_total,
            median_episode_ms: self.times.median(),
            span_ms: self.span_ms(),
            late_ranks: self.ranks.values().filter(|slot| slot.late).count(),
            worlds: self.dealer.counts(),
        }
    }

    /// How many ranks are live, dead and leased, as of the last `&mut` call.
    pub fn rank_counts(&self) -> RankCounts {
        let mut counts = RankCounts::default();
        for slot in self.ranks.values() {
            let records = slot.actors.iter().map(|id| &self.actors[id]);
            let live = records
                .clone()
                .filter(|record| record.liveness == Liveness::Live)
                .count();
            if live > 0 {
                counts.live += 1;
                counts.extra_live += live - 1;
            } else {
                counts.dead += 1;
            }
            if records.clone().any(|record| record.lease.is_some()) {
                counts.leased += 1;
            }
        }
        counts
    }

    /// Expires overdue leases, marks silent actors dead and advances the cycle if due.
    fn settle(&mut self, now_ms: u64) {
        let overdue: Vec<u64> = self
            .open
            .iter()
            .filter(|(_, open)| now_ms >= open.assignment.deadline_ms)
            .map(|(&lease, _)| lease)
            .collect();
        for lease in overdue {
            self.expire(lease, ExpiryCause::Silent);
        }
        self.apply_deadlines(now_ms);
        let ttl = self.config.lease_ttl_ms;
        let mut died = Vec::new();
        for (&id, record) in self.actors.iter_mut() {
            if record.liveness == Liveness::Live && now_ms >= record.last_seen_ms.saturating_add(ttl) {
                record.liveness = Liveness::Dead;
                died.push((id, record.rank));
            }
        }
        // A registration that died beside a newer one of its rank is retired: each rank keeps
        // at most one dead registration, its newest.
        for (id, rank) in died {
            if self.ranks[&rank].actors.last() != Some(&id) {
                self.retire(id);
            }
        }
        self.advance_if_done();
    }

    /// Retires the current registration `id`: its open lease expires, calls with it are
    /// refused, it leaves its rank's registrations, and it is queued for
    /// [`Registry::drain_retired`]; the oldest retired records beyond
    /// [`RETIRED_ACTORS_REMEMBERED`] are dropped.
    fn retire(&mut self, id: ActorId) {
        let record = self.actors.get_mut(&id).expect("retiring a registered actor");
        record.liveness = Liveness::Retired;
        let (lease, rank) = (record.lease, record.rank);
        if let Some(lease) = lease {
            self.expire(lease, ExpiryCause::Silent);
        }
        if let Some(slot) = self.ranks.get_mut(&rank) {
            slot.actors.retain(|&a| a != id);
        }
        self.newly_retired.push(id);
        self.retired.push_back(id);
        if self.retired.len() > RETIRED_ACTORS_REMEMBERED {
            let oldest = self.retired.pop_front().expect("over the bound");
            self.actors.remove(&oldest);
            self.turns.remove(&oldest);
        }
    }

    /// Ends the leases past a deadline at `now_ms` (see the module documentation): every
    /// on-time lease once the cycle's span has passed, and late leases past their own. When no
    /// lease finished during the cycle (or since the late lease was assigned), every actor may
    /// have slowed down: the spans are stretched.
    fn apply_deadlines(&mut self, now_ms: u64) {
        let Some(span_ms) = self.span_ms() else {
            return;
        };
        let cycle_over = self
            .cycle_opened
            .filter(|&(_, from)| now_ms >= from.saturating_add(span_ms))
            .map(|(first, _)| first);
        let mut starved = false;
        let due: Vec<(u64, ExpiryCause)> = self
            .open
            .iter()
            .filter_map(|(&id, open)| {
                let (cause, since) = match (open.late, cycle_over) {
                    (None, Some(first)) => (ExpiryCause::CycleDeadline { span_ms }, first),
                    (Some((span_ms, from)), _) if now_ms >= from.saturating_add(span_ms) => {
                        (ExpiryCause::LeaseDeadline { span_ms }, open.assigned_ms)
                    }
                    _ => return None,
                };
                starved |= self.measured_ms <= since;
                Some((id, cause))
            })
            .collect();
        if cycle_over.is_some() {
            // Every on-time lease ends now, so the barrier is met below (and the next cycle's
            // deadline counts from its own first assignment).
            self.cycle_opened = None;
        }
        for (lease, cause) in due {
            self.expire(lease, cause);
        }
        if starved {
            self.times
                .stretch(&self.config.deadline, self.config.episodes_per_assignment);
            self.measured_ms = now_ms;
        }
    }

    /// Ends the open lease `lease` for `cause`: its world goes back to the dealer, the actor's
    /// turn is over (a late actor's lease is no turn), and a deadline or stall makes its rank
    /// late.
    fn expire(&mut self, lease: u64, cause: ExpiryCause) {
        let open = self.open.remove(&lease).expect("expiring an open lease");
        let Assignment { actor, world, .. } = open.assignment;
        self.dealer
            .release(world)
            .expect("an open lease holds an in-flight world");
        self.close(lease, actor, Closure::Expired);
        let record = self
            .actors
            .get_mut(&actor)
            .expect("a lease's actor is registered");
        record.lease = None;
        let rank = record.rank;
        if open.late.is_none() {
            self.turns.insert(actor, Turn::Done);
        }
        if cause.is_deadline() || cause == ExpiryCause::Stalled {
            if let Some(slot) = self.ranks.get_mut(&rank) {
                slot.late = true;
            }
        }
        if cause.is_deadline() {
            self.leases_cut_total += 1;
        }
        self.expired_leases_total += 1;
        self.expired_queue.push(Expired {
            actor,
            lease_id: lease,
            world,
            cause,
        });
    }

    fn close(&mut self, lease: u64, actor: ActorId, closure: Closure) {
        self.closed.insert(lease, (actor, closure));
        if self.closed.len() > CLOSED_LEASES_REMEMBERED {
            self.closed.pop_first();
        }
    }

    /// Advances the cycle when someone worked in it and nobody is still working.
    fn advance_if_done(&mut self) {
        if !self.turns.is_empty() && self.turns.values().all(|&turn| turn == Turn::Done) {
            self.turns.clear();
            self.cycle += 1;
            self.cycle_opened = None;
        }
    }

    fn record(&self, actor: ActorId) -> Result<&ActorRecord, RegistryError> {
        match self.actors.get(&actor) {
            None => Err(RegistryError::UnknownActor { actor }),
            Some(record) if record.liveness == Liveness::Retired => {
                Err(RegistryError::RetiredActor { actor })
            }
            Some(record) => Ok(record),
        }
    }

    /// Checks that the actor is current and marks it alive at `now_ms`.
    fn touch(&mut self, actor: ActorId, now_ms: u64) -> Result<&ActorRecord, RegistryError> {
        self.record(actor)?;
        let record = self.actors.get_mut(&actor).expect("checked above");
        record.last_seen_ms = now_ms;
        record.liveness = Liveness::Live;
        Ok(record)
    }

    /// The open lease `lease` of `actor`, or why it is not one.
    fn open_lease(&self, actor: ActorId, lease: u64) -> Result<&OpenLease, RegistryError> {
        if let Some(open) = self.open.get(&lease) {
            let owner = open.assignment.actor;
            return if owner == actor {
                Ok(open)
            } else {
                Err(RegistryError::LeaseOfOtherActor { actor, lease, owner })
            };
        }
        match self.closed.get(&lease) {
            None => Err(RegistryError::UnknownLease { actor, lease }),
            Some(&(owner, _)) if owner != actor => {
                Err(RegistryError::LeaseOfOtherActor { actor, lease, owner })
            }
            Some((_, Closure::Finished)) => Err(RegistryError::AlreadyFinished { actor, lease }),
            Some((_, Closure::Expired)) => Err(RegistryError::ExpiredLease { actor, lease }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    const TTL: u64 = 1_000;

    fn registry(worlds: usize, run_seed: u64) -> Registry {
        let config = RegistryConfig {
            lease_ttl_ms: TTL,
            episodes_per_assignment: 2,
            run_seed,
            deadline: DeadlineRule::default(),
        };
        Registry::new(config, WorldPool::Listed((0..worlds).map(|w| w * 10).collect())).unwrap()
    }

    fn assign(registry: &mut Registry, actor: ActorId, now_ms: u64) -> Assignment {
        match registry.next_assignment(actor, now_ms, 0).unwrap() {
            Decision::Assign(assignment) => assignment,
            Decision::Idle => panic!("actor {actor} is idle at {now_ms} ms"),
        }
    }

    fn is_idle(registry: &mut Registry, actor: ActorId, now_ms: u64) -> bool {
        registry.next_assignment(actor, now_ms, 0).unwrap() == Decision::Idle
    }

    /// A registry of 6 worlds with deadlines k = 3, floor 100 ms, and a lease TTL so long that
    /// only deadlines end leases.
    fn with_deadlines() -> Registry {
        let config = RegistryConfig {
            lease_ttl_ms: 1_000_000,
            episodes_per_assignment: 2,
            run_seed: 4,
            deadline: DeadlineRule {
                multiple: 3,
                floor_ms: 100,
            },
        };
        Registry::new(config, WorldPool::Listed((0..6).collect())).unwrap()
    }

    #[test]
    fn a_straggler_costs_one_span_then_works_off_the_barrier() {
        let mut registry = with_deadlines();
        let honest = registry.register(0, "h".into(), 1, 0, None);
        let slow = registry.register(1, "h".into(), 2, 0, None);
        let first = assign(&mut registry, honest, 0);
        let held = assign(&mut registry, slow, 0);
        assert_eq!(registry.span_ms(), None, "nothing measured: the cycle waits");
        registry.finish(honest, first.lease_id, 100).unwrap();
        // 50 ms per episode: a span is 3 x 50 x 2 = 300 ms from the cycle's first assignment.
        assert_eq!(
            (registry.span_ms(), registry.stall_bound_ms()),
            (Some(300), Some(150))
        );
        assert!(registry.tick(299).is_empty());
        assert_eq!(registry.cycle(), 0);
        assert_eq!(
            registry.tick(300),
            vec![Expired {
                actor: slow,
                lease_id: held.lease_id,
                world: held.world,
                cause: ExpiryCause::CycleDeadline { span_ms: 300 },
            }]
        );
        assert_eq!(registry.cycle(), 1, "the deadline ended the cycle");
        assert_eq!(
            registry.check_lease(slow, held.lease_id, 300),
            Err(RegistryError::ExpiredLease {
                actor: slow,
                lease: held.lease_id
            }),
            "later data under it is refused"
        );
        // The straggler is late: its lease is off the barrier and ends one span after it was
        // assigned; the honest actor's cycles go at its own pace meanwhile.
        let next = assign(&mut registry, honest, 300);
        assert_eq!(
            next.world, held.world,
            "the cut lease's world is dealt again first"
        );
        let late = assign(&mut registry, slow, 300);
        assert_eq!(late.cycle, 1);
        registry.finish(honest, next.lease_id, 400).unwrap();
        assert_eq!(registry.cycle(), 2, "the late lease does not hold the cycle");
        let third = assign(&mut registry, honest, 400);
        registry.finish(honest, third.lease_id, 500).unwrap();
        assert_eq!(registry.cycle(), 3);
        assert!(registry.tick(599).is_empty());
        let cut = registry.tick(600);
        assert_eq!(
            cut.iter().map(|e| (e.lease_id, e.cause)).collect::<Vec<_>>(),
            [(late.lease_id, ExpiryCause::LeaseDeadline { span_ms: 300 })]
        );
        let status = registry.status();
        assert_eq!((status.leases_cut_total, status.late_ranks), (2, 1));
        // A late actor gets work whenever it holds none, and finishing it puts it back on
        // time: it idles until the next cycle like everyone else.
        let again = assign(&mut registry, slow, 600);
        registry.finish(slow, again.lease_id, 700).unwrap();
        assert_eq!(registry.status().late_ranks, 0);
        assert_eq!(registry.cycle(), 4, "its turn was the only one of cycle 3");
        let honest_lease = assign(&mut registry, honest, 701);
        let on_time = assign(&mut registry, slow, 702);
        assert_eq!((honest_lease.cycle, on_time.cycle), (4, 4));
        registry.finish(slow, on_time.lease_id, 720).unwrap();
        assert!(
            is_idle(&mut registry, slow, 721),
            "on time: it waits for the cycle"
        );
        registry.finish(honest, honest_lease.lease_id, 750).unwrap();
        assert_eq!(registry.cycle(), 5, "the barrier waited for both");
    }

    #[test]
    fn every_actor_slowing_down_together_stretches_the_spans() {
        let mut registry = with_deadlines();
        let a = registry.register(0, "h".into(), 1, 0, None);
        let first = assign(&mut registry, a, 0);
        registry.finish(a, first.lease_id, 100).unwrap();
        // Its episodes now take 1 s: spans of 300, then 900 (no lease finished within a
        // span), then 2,700 ms, which it meets.
        let mut now = 100;
        let mut spans = Vec::new();
        loop {
            let lease = assign(&mut registry, a, now);
            let done_at = now + 2_000;
            let mut cut = Vec::new();
            while cut.is_empty() && now < done_at {
                now += 50;
                cut = registry.tick(now);
            }
            if let [expired] = cut[..] {
                let (ExpiryCause::CycleDeadline { span_ms } | ExpiryCause::LeaseDeadline { span_ms }) =
                    expired.cause
                else {
                    panic!("{expired:?}");
                };
                spans.push(span_ms);
                assert!(spans.len() < 10, "the spans never grew: {spans:?}");
                continue;
            }
            registry.finish(a, lease.lease_id, now).unwrap();
            break;
        }
        assert_eq!(spans, [300, 900]);
        assert_eq!(registry.status().late_ranks, 0);
    }

    #[test]
    fn deadlines_wait_while_the_caller_holds_the_actors_up() {
        let mut registry = with_deadlines();
        let a = registry.register(0, "h".into(), 1, 0, None);
        let b = registry.register(1, "h".into(), 2, 0, None);
        let first = assign(&mut registry, a, 0);
        let held = assign(&mut registry, b, 0);
        registry.finish(a, first.lease_id, 100).unwrap();
        // The span is 300 ms from 0; the caller held everyone up until 250.
        registry.hold_deadlines(250);
        assert!(registry.tick(549).is_empty());
        let cut = registry.tick(550);
        assert_eq!(cut.len(), 1);
        assert_eq!(cut[0].lease_id, held.lease_id);
        // A late lease's span restarts the same way.
        let late = assign(&mut registry, b, 550);
        registry.hold_deadlines(800);
        assert!(registry.tick(1_099).is_empty());
        assert_eq!(
            registry
                .tick(1_100)
                .iter()
                .map(|e| e.lease_id)
                .collect::<Vec<_>>(),
            [late.lease_id]
        );
    }

    #[test]
    fn without_deadlines_the_cycle_waits_for_every_lease() {
        let config = RegistryConfig {
            deadline: DeadlineRule::OFF,
            lease_ttl_ms: 1_000_000,
            ..RegistryConfig::default()
        };
        let mut registry = Registry::new(config, WorldPool::Listed(vec![1, 2])).unwrap();
        let a = registry.register(0, "h".into(), 1, 0, None);
        let b = registry.register(1, "h".into(), 2, 0, None);
        let la = assign(&mut registry, a, 0);
        assign(&mut registry, b, 0);
        registry.finish(a, la.lease_id, 10).unwrap();
        assert!(registry.tick(999_999).is_empty());
        assert_eq!((registry.cycle(), registry.span_ms()), (0, None));
    }

    #[test]
    fn rejects_bad_configuration_and_worlds() {
        let zero_ttl = RegistryConfig {
            lease_ttl_ms: 0,
            ..RegistryConfig::default()
        };
        assert!(matches!(
            Registry::new(zero_ttl, WorldPool::Listed(vec![1])),
            Err(RegistryError::InvalidConfig(_))
        ));
        let zero_episodes = RegistryConfig {
            episodes_per_assignment: 0,
            ..RegistryConfig::default()
        };
        assert!(matches!(
            Registry::new(zero_episodes, WorldPool::Listed(vec![1])),
            Err(RegistryError::InvalidConfig(_))
        ));
        let error = Registry::new(RegistryConfig::default(), WorldPool::Listed(vec![])).unwrap_err();
        assert_eq!(error, RegistryError::Worlds(DealerError::NoWorlds));
    }

    #[test]
    fn worlds_stay_fair_over_many_cycles() {
        let mut registry = registry(7, 1);
        let actors: Vec<ActorId> = (0..3)
            .map(|rank| registry.register(rank, "h".into(), rank, 0, None))
            .collect();
        let mut now = 0;
        for cycle in 0..70 {
            let leases: Vec<Assignment> = actors.iter().map(|&a| assign(&mut registry, a, now)).collect();
            assert!(leases.iter().all(|lease| lease.cycle == cycle));
            for lease in leases {
                now += 5;
                registry.finish(lease.actor, lease.lease_id, now).unwrap();
            }
            let counts: Vec<u64> = registry.status().worlds.iter().map(|c| c.completed).collect();
            assert!(
                counts.iter().max().unwrap() - counts.iter().min().unwrap() <= 1,
                "{counts:?}"
            );
        }
        let status = registry.status();
        assert_eq!(status.cycle, 70);
        assert_eq!(status.assignments_total, 210);
        assert_eq!(status.worlds.iter().map(|c| c.completed).sum::<u64>(), 210);
        assert_eq!(
            (status.open_leases, status.idle_actors, status.live_actors),
            (0, 3, 3)
        );
    }

    #[test]
    fn finished_actor_idles_until_the_cycle_barrier_and_late_joiner_starts_at_once() {
        let mut registry = registry(5, 2);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let b = registry.register(1, "h".into(), 2, 0, None);
        let lease_a = assign(&mut registry, a, 0);
        let lease_b = assign(&mut registry, b, 0);
        registry.finish(a, lease_a.lease_id, 10).unwrap();
        assert!(is_idle(&mut registry, a, 20));
        assert_eq!(registry.cycle(), 0);
        let c = registry.register(2, "h".into(), 3, 30, None);
        let lease_c = assign(&mut registry, c, 30);
        assert_eq!(lease_c.cycle, 0);
        registry.finish(b, lease_b.lease_id, 40).unwrap();
        assert!(is_idle(&mut registry, a, 50), "c is still working in cycle 0");
        assert!(is_idle(&mut registry, b, 50));
        registry.finish(c, lease_c.lease_id, 60).unwrap();
        assert_eq!(registry.cycle(), 1);
        assert_eq!(assign(&mut registry, a, 70).cycle, 1);
    }

    #[test]
    fn expired_lease_returns_its_world_and_refuses_late_data() {
        let mut registry = registry(6, 3);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let b = registry.register(1, "h".into(), 2, 0, None);
        let lease = assign(&mut registry, a, 0);
        registry.heartbeat(b, None, 900).unwrap();
        assert!(registry.tick(TTL - 1).is_empty());
        registry.check_lease(a, lease.lease_id, TTL - 1).unwrap();
        let error = registry.check_lease(a, lease.lease_id, TTL).unwrap_err();
        assert!(error.to_string().contains("expired"), "{error}");
        let expired = registry.tick(TTL);
        assert_eq!(
            expired,
            vec![Expired {
                actor: a,
                lease_id: lease.lease_id,
                world: lease.world,
                cause: ExpiryCause::Silent,
            }]
        );
        let error = registry.check_lease(a, lease.lease_id, TTL + 1).unwrap_err();
        assert_eq!(
            error,
            RegistryError::ExpiredLease {
                actor: a,
                lease: lease.lease_id
            }
        );
        assert!(error.to_string().contains("expired"));
        let status = registry.status();
        assert_eq!(
            (status.expired_leases_total, status.live_actors),
            (1, 1),
            "a is dead, b alive"
        );
        assert_eq!(registry.finish(a, lease.lease_id, TTL + 1), Err(error));
        assert_eq!(
            assign(&mut registry, b, TTL + 2).world,
            lease.world,
            "released world is dealt first"
        );
    }

    #[test]
    fn lost_lease_counts_for_the_barrier() {
        let mut registry = registry(3, 4);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let lease = assign(&mut registry, a, 0);
        assert_eq!(registry.tick(TTL).len(), 1);
        assert_eq!(
            registry.cycle(),
            1,
            "the only worker lost its lease: the cycle is over"
        );
        let again = assign(&mut registry, a, TTL + 1);
        assert_eq!((again.world, again.cycle), (lease.world, 1));
    }

    #[test]
    fn heartbeats_extend_leases_and_check_ownership() {
        let mut registry = registry(4, 5);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let b = registry.register(1, "h".into(), 2, 0, None);
        let lease = assign(&mut registry, a, 0);
        registry.heartbeat(a, Some(lease.lease_id), 900).unwrap();
        registry.heartbeat(b, None, 900).unwrap();
        assert!(registry.tick(1_500).is_empty());
        registry.check_lease(a, lease.lease_id, 1_899).unwrap();
        assert_eq!(
            registry.heartbeat(b, Some(lease.lease_id), 1_000),
            Err(RegistryError::LeaseOfOtherActor {
                actor: b,
                lease: lease.lease_id,
                owner: a
            })
        );
        assert_eq!(
            registry.heartbeat(a, Some(99), 1_000),
            Err(RegistryError::UnknownLease { actor: a, lease: 99 })
        );
        assert_eq!(
            registry.heartbeat(77, None, 1_000),
            Err(RegistryError::UnknownActor { actor: 77 })
        );
        assert_eq!(registry.tick(1_900).len(), 1);
        assert_eq!(
            registry.heartbeat(a, Some(lease.lease_id), 1_901),
            Err(RegistryError::ExpiredLease {
                actor: a,
                lease: lease.lease_id
            })
        );
    }

    #[test]
    fn finished_lease_refuses_data_and_a_second_finish() {
        let mut registry = registry(4, 6);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let lease = assign(&mut registry, a, 0);
        registry.episode_done(a, lease.lease_id, 1).unwrap();
        registry.episode_done(a, lease.lease_id, 2).unwrap();
        assert_eq!(
            registry.episode_done(a, lease.lease_id, 3),
            Err(RegistryError::EpisodeOverflow {
                actor: a,
                lease: lease.lease_id,
                episodes: 2
            })
        );
        registry.finish(a, lease.lease_id, 4).unwrap();
        let finished = RegistryError::AlreadyFinished {
            actor: a,
            lease: lease.lease_id,
        };
        assert_eq!(registry.check_lease(a, lease.lease_id, 5), Err(finished.clone()));
        assert_eq!(registry.finish(a, lease.lease_id, 5), Err(finished));
        assert_eq!(registry.status().episodes_reported_total, 2);
    }

    #[test]
    fn asking_again_with_an_open_lease_returns_the_same_assignment() {
        let mut registry = registry(4, 7);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let first = assign(&mut registry, a, 0);
        registry.heartbeat(a, Some(first.lease_id), 500).unwrap();
        let again = assign(&mut registry, a, 600);
        assert_eq!(
            again,
            Assignment {
                deadline_ms: 1_500,
                ..first
            }
        );
        assert_eq!(registry.status().assignments_total, 1);
    }

    #[test]
    fn re_registration_retires_the_old_id_and_continues_seeds() {
        let mut registry = registry(5, 8);
        let old = registry.register(4, "h".into(), 100, 0, None);
        let other = registry.register(5, "h".into(), 101, 0, None);
        let lease_other = assign(&mut registry, other, 0);
        let lease = assign(&mut registry, old, 0);
        let new = registry.register(4, "h".into(), 200, 10, Some(old));
        assert_ne!(new, old);
        assert_eq!(registry.drain_retired(), [old]);
        assert_eq!(
            registry.tick(10),
            vec![Expired {
                actor: old,
                lease_id: lease.lease_id,
                world: lease.world,
                cause: ExpiryCause::Silent,
            }]
        );
        assert_eq!(
            registry.next_assignment(old, 11, 0),
            Err(RegistryError::RetiredActor { actor: old })
        );
        assert_eq!(
            registry.check_lease(old, lease.lease_id, 11),
            Err(RegistryError::RetiredActor { actor: old })
        );
        let fresh = assign(&mut registry, new, 11);
        assert_eq!(
            (fresh.cycle, fresh.world),
            (0, lease.world),
            "same cycle, released world first"
        );
        assert!(fresh.seeds.iter().all(|seed| !lease.seeds.contains(seed)));
        assert_eq!(fresh.seeds[0], episode_seed(8, 4, 2));
        registry.finish(other, lease_other.lease_id, 12).unwrap();
        assert_eq!(registry.cycle(), 0, "the new registration still works in cycle 0");
        assert_eq!(
            registry
                .actors()
                .iter()
                .map(|info| (info.id, info.pid))
                .collect::<Vec<_>>(),
            [(other, 101), (new, 200)]
        );
    }

    #[test]
    fn a_live_registration_is_kept_unless_the_caller_proves_to_be_it() {
        let mut registry = registry(5, 8);
        let holder = registry.register(3, "h".into(), 100, 0, None);
        let lease = assign(&mut registry, holder, 0);
        // Another registration of rank 3 without the holder's credential: the holder keeps
        // its lease and its heartbeats; the newcomer works beside it, on fresh seeds.
        let beside = registry.register(3, "h".into(), 200, 10, None);
        assert!(registry.drain_retired().is_empty());
        assert!(registry.tick(10).is_empty(), "no lease ended");
        registry.heartbeat(holder, Some(lease.lease_id), 20).unwrap();
        registry.check_lease(holder, lease.lease_id, 20).unwrap();
        let second = assign(&mut registry, beside, 20);
        assert!(second.seeds.iter().all(|s| !lease.seeds.contains(s)));
        assert_eq!(registry.live_actors_of_rank(3), [(holder, 20), (beside, 20)]);
        // The newcomer goes silent while the holder heartbeats: it is the rank's newest, so
        // it stays (dead) until the holder dies too; then the older one is retired.
        for t in (20..=2 * TTL + 20).step_by(TTL as usize / 2) {
            registry.heartbeat(holder, Some(lease.lease_id), t).unwrap();
        }
        assert_eq!(registry.live_actors_of_rank(3), [(holder, 2 * TTL + 20)]);
        assert!(registry.drain_retired().is_empty());
        registry.tick(4 * TTL);
        assert_eq!(registry.drain_retired(), [holder], "died beside a newer one");
        assert_eq!(
            registry.heartbeat(holder, None, 4 * TTL),
            Err(RegistryError::RetiredActor { actor: holder })
        );
        // A dead registration is retired by the next registration of its rank.
        let third = registry.register(3, "h".into(), 300, 4 * TTL, None);
        assert_eq!(registry.drain_retired(), [beside]);
        assert_eq!(registry.live_actors_of_rank(3), [(third, 4 * TTL)]);
        // `replaces` naming an actor of another rank retires nothing.
        let other = registry.register(4, "h".into(), 400, 4 * TTL, None);
        registry.register(3, "h".into(), 301, 4 * TTL, Some(other));
        assert!(registry.drain_retired().is_empty());
        assert_eq!(registry.live_actors_of_rank(4), [(other, 4 * TTL)]);
    }

    #[test]
    fn a_rank_with_a_live_registration_is_never_forgotten() {
        let mut registry = registry(3, 1);
        let holder = registry.register(7, "h".into(), 1, 0, None);
        let beside = registry.register(7, "h".into(), 2, 0, None);
        // The holder heartbeats; the newest registration is dead: the rank stays.
        for t in (0..=4 * TTL).step_by(TTL as usize / 2) {
            registry.heartbeat(holder, None, t).unwrap();
        }
        assert!(registry.forget_dead_ranks(4 * TTL, 0, 0).is_empty());
        assert!(registry.next_assignment(holder, 4 * TTL, 0).is_ok());
        assert!(registry
            .actors()
            .iter()
            .any(|info| info.id == beside && !info.live));
    }

    #[test]
    fn dead_ranks_are_forgotten_and_their_seeds_never_repeat() {
        let mut registry = registry(3, 1);
        let first = registry.register(7, "h".into(), 1, 0, None);
        let a = assign(&mut registry, first, 0);
        for _ in 0..a.episodes {
            registry.episode_done(first, a.lease_id, 1).unwrap();
        }
        registry.finish(first, a.lease_id, 1).unwrap();
        for rank in 100..110 {
            registry.register(rank, "h".into(), 1, 2, None);
        }
        // All silent, so dead after one TTL: keep the 4 most recently seen for now.
        let now = 2 + TTL + 1;
        let forgotten = registry.forget_dead_ranks(now, 10 * TTL, 4);
        assert_eq!(forgotten.len(), 7, "{forgotten:?}");
        assert!(
            forgotten.contains(&(7, vec![first])),
            "the least recently seen goes first"
        );
        assert_eq!(registry.snapshot().rank_episodes.len(), 4);
        assert_eq!(
            registry.next_assignment(first, now, 0),
            Err(RegistryError::UnknownActor { actor: first })
        );
        // Past the time bound every dead rank goes.
        assert_eq!(registry.forget_dead_ranks(now + 10 * TTL, 10 * TTL, 4).len(), 4);
        assert!(registry.snapshot().rank_episodes.is_empty());
        // Rank 7 again: its episode counter continues from the floor, so no seed repeats.
        let later = now + 10 * TTL;
        let again = registry.register(7, "h".into(), 1, later, None);
        let b = assign(&mut registry, again, later);
        assert!(
            b.seeds.iter().all(|s| !a.seeds.contains(s)),
            "{:?} {:?}",
            a.seeds,
            b.seeds
        );
    }

    #[test]
    fn retired_records_are_bounded_and_the_oldest_become_unknown() {
        let mut registry = registry(3, 1);
        let first = registry.register(0, "h".into(), 1, 0, None);
        let mut last_retired = first;
        let mut current = first;
        for pid in 0..RETIRED_ACTORS_REMEMBERED as u32 + 10 {
            last_retired = current;
            current = registry.register(0, "h".into(), pid + 2, 0, Some(current));
        }
        assert_eq!(registry.drain_retired().len(), RETIRED_ACTORS_REMEMBERED + 10);
        assert_eq!(registry.actors.len(), RETIRED_ACTORS_REMEMBERED + 1, "bounded");
        assert_eq!(
            registry.next_assignment(first, 1, 0),
            Err(RegistryError::UnknownActor { actor: first }),
            "dropped long ago"
        );
        assert_eq!(
            registry.next_assignment(last_retired, 1, 0),
            Err(RegistryError::RetiredActor { actor: last_retired }),
            "recently retired"
        );
        assert!(
            registry.next_assignment(current, 1, 0).is_ok(),
            "the current one works"
        );
        assert_eq!(
            registry.actors().iter().map(|info| info.id).collect::<Vec<_>>(),
            [current]
        );
    }

    #[test]
    fn seeds_are_reproducible_and_distinct() {
        let run = |run_seed| {
            let mut registry = registry(9, run_seed);
            let actors: Vec<ActorId> = (0..4)
                .map(|rank| registry.register(rank, "h".into(), rank, 0, None))
                .collect();
            let mut seeds = Vec::new();
            for step in 0..25 {
                for &actor in &actors {
                    let lease = assign(&mut registry, actor, step);
                    seeds.extend(lease.seeds.iter().copied());
                    registry.finish(actor, lease.lease_id, step).unwrap();
                }
            }
            seeds
        };
        let seeds = run(11);
        assert_eq!(seeds.len(), 200);
        assert_eq!(seeds.iter().collect::<HashSet<_>>().len(), 200);
        assert_eq!(seeds, run(11));
        assert_ne!(seeds, run(12));
    }

    #[test]
    fn silent_actor_is_dead_until_it_calls_again() {
        let mut registry = registry(2, 9);
        let a = registry.register(0, "h".into(), 1, 0, None);
        registry.tick(TTL);
        assert_eq!(registry.status().live_actors, 0);
        assert!(!registry.actors()[0].live);
        registry.heartbeat(a, None, TTL + 1).unwrap();
        assert_eq!(
            (registry.status().live_actors, registry.status().idle_actors),
            (1, 1)
        );
    }

    #[test]
    fn restore_drops_actors_and_leases_but_keeps_counts() {
        let mut registry = registry(4, 10);
        let a = registry.register(0, "h".into(), 1, 0, None);
        let done = assign(&mut registry, a, 0);
        registry.finish(a, done.lease_id, 1).unwrap();
        let open = assign(&mut registry, a, 2);
        let json = serde_json::to_string(&registry.snapshot()).unwrap();
        let snapshot: RegistrySnapshot = serde_json::from_str(&json).unwrap();
        let mut restored = Registry::restore(*registry.config(), snapshot).unwrap();
        assert_eq!(restored.cycle(), 1);
        assert!(restored.actors().is_empty());
        assert_eq!(
            restored.check_lease(a, open.lease_id, 3),
            Err(RegistryError::UnknownActor { actor: a })
        );
        let b = restored.register(0, "h".into(), 2, 3, None);
        assert!(b > a, "ids are not reused");
        let next = assign(&mut restored, b, 3);
        assert!(next.lease_id > open.lease_id, "lease ids are not reused");
        assert_eq!(next.world, open.world, "the in-flight world is dealt first");
        assert_eq!(
            next.seeds[0],
            episode_seed(10, 0, 4),
            "rank 0's episode counter continues"
        );
        let status = restored.status();
        assert_eq!(status.assignments_total, 3);
        assert_eq!(status.worlds.iter().map(|c| c.completed).sum::<u64>(), 1);
    }
}
