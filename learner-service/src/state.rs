//! The learner's mutable state ([`Core`], behind [`crate::shared::Shared::core`]): registry,
//! replay buffer, rate limiter, counters, the open leases, and who registered (each
//! registration's credential and kind, the counters per rank).

use std::collections::{BTreeMap, HashMap};

use learner::rate::RateLimiter;
use learner::replay::ReplayBuffer;
use proto::plane::{ActorSecret, LeaseHeader};
use proto::validate::Refusal;
use scheduler::Registry;

use crate::leases::{first_episode_id, LeaseTrack, Leases};
use crate::status::{ExpiredLease, RankStatus, RANK_IDS_REMEMBERED};
use crate::totals::Totals;

/// Everything mutable, behind [`crate::shared::Shared::core`].
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
    /// The open leases and their episodes.
    pub(crate) leases: Leases,
    /// The kind of every actor registered with this learner process, by actor id.
    actor_kinds: HashMap<u64, String>,
    /// The credential of every current registration, by actor id (a retired or forgotten id
    /// has none: requests naming it are refused).
    secrets: HashMap<u64, ActorSecret>,
    /// Counters per rank over this learner process.
    ranks: BTreeMap<u32, RankStatus>,
    /// No more assignments: the budget is stored or a stop was requested.
    pub stopping: bool,
    /// Stop now (signal, shutdown call) rather than after the owed updates.
    pub abort: bool,
    /// The training thread is done and writes the final checkpoint: steps and reports are
    /// refused from now on (the actor is told), so none is acknowledged and then lost.
    pub closed: bool,
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
            leases: Leases::default(),
            actor_kinds: HashMap::new(),
            secrets: HashMap::new(),
            ranks: BTreeMap::new(),
            stopping: false,
            closed: false,
            abort: false,
        }
    }

    /// Records an assignment's lease so its steps can be admitted; returns its first episode
    /// id.
    pub fn open_lease(&mut self, lease_id: u64, actor: u64, episodes: u32, now_ms: u64) -> u64 {
        let first = first_episode_id(lease_id, episodes);
        let lease = LeaseTrack {
            actor,
            rank: self.registry.rank_of(actor).unwrap_or(u32::MAX),
            first_episode: first,
            episodes,
            progress_ms: now_ms,
            broken: None,
            kind: self.kind_of(actor).to_owned(),
        };
        self.leases.open(lease_id, lease);
        first
    }

    /// Marks the open lease of a refused step as broken (dropped by the next lease tick), if
    /// the step was sent by the lease's actor (with its credential) under a currently valid
    /// lease.
    pub(crate) fn break_lease(&mut self, header: &LeaseHeader, why: &Refusal, now: u64) {
        if self.check_secret(header.actor_id, &header.secret).is_err()
            || self
                .registry
                .check_lease(header.actor_id, header.lease_id, now)
                .is_err()
        {
            return;
        }
        self.leases
            .mark_broken(header.lease_id, header.actor_id, why.to_string());
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
    /// registrations the registry retired lose their credentials.
    pub fn registered(&mut self, actor: u64, rank: u32, kind: &str, secret: ActorSecret) {
        self.forget_retired();
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

    /// Drops the credentials and kinds of the registrations the registry retired since the last
    /// call (requests naming them are then refused as retired).
    pub(crate) fn forget_retired(&mut self) {
        for id in self.registry.drain_retired() {
            self.secrets.remove(&id);
            self.actor_kinds.remove(&id);
        }
    }

    /// Forgets the records of `rank` (and of its `actors`), which the registry forgot: its
    /// counters go into [`Totals::pruned_ranks`].
    pub(crate) fn forget_rank(&mut self, rank: u32, actors: &[u64]) {
        let pruned = &mut self.totals.pruned_ranks;
        pruned.ranks += 1;
        pruned.steps += self.totals.rank_steps.remove(&rank).unwrap_or(0);
        if let Some(r) = self.ranks.remove(&rank) {
            pruned.registrations += r.registrations;
        }
        for id in actors {
            self.secrets.remove(id);
            self.actor_kinds.remove(id);
        }
        tracing::debug!(rank, actor_ids = ?actors, "forgot a dead rank");
    }

    /// The counters of `rank`, started at zero.
    pub(crate) fn rank_entry(&mut self, rank: u32) -> &mut RankStatus {
        self.ranks.entry(rank).or_insert_with(|| RankStatus {
            rank,
            ..RankStatus::default()
        })
    }

    /// The counters per rank of this learner process, by rank.
    pub fn ranks(&self) -> impl Iterator<Item = &RankStatus> {
        self.ranks.values()
    }

    /// The leases that expired in this learner process (the newest
    /// [`crate::status::LEASES_REMEMBERED`]), oldest first.
    pub fn expired_recent(&self) -> impl Iterator<Item = &ExpiredLease> {
        self.leases.expired()
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

    /// Why the learner dropped `lease` although its actor kept heartbeating, if it did
    /// (recently).
    pub fn dropped_reason(&self, lease: u64) -> Option<&str> {
        self.leases.dropped_reason(lease)
    }

    /// Compares a finished, reported episode's received steps with the actor's report.
    pub(crate) fn verify_episode(&mut self, episode: u64) {
        let Some(track) = self.leases.episode(episode) else {
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
    pub(crate) fn try_finish(&mut self, lease_id: u64, now_ms: u64) {
        if !self.leases.complete(lease_id) {
            return;
        }
        let actor = self.leases.get(lease_id).map_or(0, |l| l.actor);
        if let Err(e) = self.registry.finish(actor, lease_id, now_ms) {
            tracing::warn!(lease = lease_id, actor_id = actor, "cannot finish the lease: {e}");
        }
        self.leases.close(lease_id);
    }

    /// Forgets a lease that will not finish, abandoning its open episodes.
    pub(crate) fn drop_lease(&mut self, lease_id: u64) {
        for e in self.leases.close(lease_id) {
            self.replay.abandon(e);
            self.totals.episodes_abandoned += 1;
        }
    }

    /// Drops every lease (the learner restarted or is stopping).
    pub fn drop_all_leases(&mut self) {
        for id in self.leases.ids() {
            self.drop_lease(id);
        }
    }

    /// Whether any episode of the lease has received steps or a report.
    pub fn lease_started(&self, lease_id: u64) -> bool {
        self.leases.started(lease_id)
    }

    /// Open leases being tracked.
    pub fn open_leases(&self) -> usize {
        self.leases.open_count()
    }
}
