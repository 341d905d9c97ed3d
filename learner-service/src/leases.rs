//! The leases the learner tracks while their episodes arrive: which actor holds each one, its
//! episodes' progress (next step index, running checksum, end, the actor's report), when it
//! last made progress, whether a refused step broke it, and a bounded memory of the leases
//! dropped and expired.
//!
//! Plain bookkeeping: the registry (which deals and expires leases) and the replay buffer (which
//! abandons unfinished episodes) are the caller's ([`crate::core::Core`]).

use std::collections::{HashMap, VecDeque};
use std::ops::Range;

use crate::status::{ExpiredLease, LEASES_REMEMBERED};

/// Dropped leases remembered with the reason (told to their actors on their next heartbeat).
const DROPPED_REMEMBERED: usize = 4096;

/// Closed leases whose stored steps are remembered, to recognise a resent batch of them.
const CLOSED_REMEMBERED: usize = 4096;

/// First episode id of a lease: episode ids are `lease * episodes + i`, unique within a run
/// because lease ids are (they survive resumes in the registry snapshot).
pub fn first_episode_id(lease_id: u64, episodes: u32) -> u64 {
    lease_id * u64::from(episodes)
}

/// Per-episode bookkeeping while its steps arrive.
#[derive(Debug, Default)]
pub struct EpisodeTrack {
    /// The step index the next step must have.
    pub next_index: u32,
    /// Wrapping sum of the stored steps' checksums.
    pub checksum: u64,
    /// A terminal or truncated step was stored.
    pub ended: bool,
    /// What the actor reported: (steps, checksum).
    pub reported: Option<(u32, u64)>,
}

/// Per-lease bookkeeping.
#[derive(Debug)]
pub struct LeaseTrack {
    /// The actor holding it.
    pub actor: u64,
    /// That actor's rank (`u32::MAX` if unknown).
    pub rank: u32,
    /// Its first episode id ([`first_episode_id`]).
    pub first_episode: u64,
    /// Its number of episodes.
    pub episodes: u32,
    /// When the lease last made progress (opened, a step stored, a report accepted), in the
    /// registry's clock.
    pub progress_ms: u64,
    /// Why the lease can no longer finish (a step of one of its episodes was refused), if so.
    pub broken: Option<String>,
    /// The actor's kind (`rust`, `python`, ...).
    pub kind: String,
}

impl LeaseTrack {
    /// The ids of its episodes.
    pub fn episode_ids(&self) -> Range<u64> {
        self.first_episode..self.first_episode + u64::from(self.episodes)
    }
}

/// What a closed lease stored: enough to recognise its steps when they arrive again.
#[derive(Debug)]
struct ClosedLease {
    actor: u64,
    first_episode: u64,
    /// Steps stored per episode, in episode order.
    stored: Vec<u32>,
}

/// The open leases and their episodes, with the recently dropped, expired and closed ones.
#[derive(Debug, Default)]
pub struct Leases {
    leases: HashMap<u64, LeaseTrack>,
    episodes: HashMap<u64, EpisodeTrack>,
    /// Recently closed leases (bounded by [`CLOSED_REMEMBERED`]), with their order of closing.
    closed: HashMap<u64, ClosedLease>,
    closed_order: VecDeque<u64>,
    /// Recently dropped leases and why, oldest first (bounded by [`DROPPED_REMEMBERED`]).
    dropped: VecDeque<(u64, String)>,
    /// Leases that expired in this learner process, oldest first (bounded by
    /// [`LEASES_REMEMBERED`]).
    expired: VecDeque<ExpiredLease>,
}

impl Leases {
    /// Starts tracking lease `lease_id`.
    pub fn open(&mut self, lease_id: u64, lease: LeaseTrack) {
        self.leases.insert(lease_id, lease);
    }

    /// The open lease `lease_id`.
    pub fn get(&self, lease_id: u64) -> Option<&LeaseTrack> {
        self.leases.get(&lease_id)
    }

    /// The open lease `lease_id`, to update.
    pub fn get_mut(&mut self, lease_id: u64) -> Option<&mut LeaseTrack> {
        self.leases.get_mut(&lease_id)
    }

    /// Open leases.
    pub fn open_count(&self) -> usize {
        self.leases.len()
    }

    /// The ids of the open leases.
    pub fn ids(&self) -> Vec<u64> {
        self.leases.keys().copied().collect()
    }

    /// The track of `episode`, if a step or report of it arrived.
    pub fn episode(&self, episode: u64) -> Option<&EpisodeTrack> {
        self.episodes.get(&episode)
    }

    /// The track of `episode`, started empty if nothing of it arrived yet.
    pub fn episode_mut(&mut self, episode: u64) -> &mut EpisodeTrack {
        self.episodes.entry(episode).or_default()
    }

    /// Whether any episode of the lease has received steps or a report.
    pub fn started(&self, lease_id: u64) -> bool {
        self.leases
            .get(&lease_id)
            .is_some_and(|l| l.episode_ids().any(|e| self.episodes.contains_key(&e)))
    }

    /// Whether every episode of the lease has ended and been reported.
    pub fn complete(&self, lease_id: u64) -> bool {
        self.leases.get(&lease_id).is_some_and(|l| {
            l.episode_ids().all(|e| {
                self.episodes
                    .get(&e)
                    .is_some_and(|t| t.ended && t.reported.is_some())
            })
        })
    }

    /// Stops tracking the lease and its episodes; returns the ids of its episodes that had
    /// steps but did not end (the caller abandons them in the replay buffer).
    pub fn close(&mut self, lease_id: u64) -> Vec<u64> {
        let Some(lease) = self.leases.remove(&lease_id) else {
            return Vec::new();
        };
        let mut stored = Vec::with_capacity(lease.episodes as usize);
        let abandoned = lease
            .episode_ids()
            .filter(|e| {
                let track = self.episodes.remove(e);
                stored.push(track.as_ref().map_or(0, |t| t.next_index));
                track.is_some_and(|t| !t.ended && t.next_index > 0)
            })
            .collect();
        let closed = ClosedLease {
            actor: lease.actor,
            first_episode: lease.first_episode,
            stored,
        };
        if self.closed.insert(lease_id, closed).is_none() {
            self.closed_order.push_back(lease_id);
        }
        if self.closed_order.len() > CLOSED_REMEMBERED {
            if let Some(old) = self.closed_order.pop_front() {
                self.closed.remove(&old);
            }
        }
        abandoned
    }

    /// How many steps of `episode` the learner stored under lease `lease_id` of `actor`, while
    /// the lease is open or one of the recently closed: a step of it with a smaller index was
    /// stored already. `None` when the lease is not `actor`'s, the episode not one of it, or
    /// the lease unknown.
    pub fn stored_steps(&self, lease_id: u64, actor: u64, episode: u64) -> Option<u32> {
        if let Some(lease) = self.leases.get(&lease_id) {
            return (lease.actor == actor && lease.episode_ids().contains(&episode))
                .then(|| self.episodes.get(&episode).map_or(0, |t| t.next_index));
        }
        let closed = self.closed.get(&lease_id).filter(|c| c.actor == actor)?;
        let i = episode.checked_sub(closed.first_episode)?;
        closed.stored.get(usize::try_from(i).ok()?).copied()
    }

    /// Marks the lease broken with `why` if `actor` holds it (the first reason is kept).
    pub fn mark_broken(&mut self, lease_id: u64, actor: u64, why: String) {
        if let Some(lease) = self.leases.get_mut(&lease_id) {
            if lease.actor == actor && lease.broken.is_none() {
                lease.broken = Some(why);
            }
        }
    }

    /// The leases to drop at `now` although their actors heartbeat, with the reason and whether
    /// it is a stall: the broken ones, and those without progress for `timeout_ms` (stalled).
    /// While `learner_holds` (the learner itself keeps actors waiting) every lease counts as
    /// making progress.
    pub fn overdue(&mut self, now: u64, timeout_ms: u64, learner_holds: bool) -> Vec<(u64, String, bool)> {
        let mut due = Vec::new();
        for (&id, lease) in self.leases.iter_mut() {
            if learner_holds {
                lease.progress_ms = now;
            }
            if let Some(why) = &lease.broken {
                due.push((id, format!("a step was refused ({why})"), false));
            } else if now.saturating_sub(lease.progress_ms) >= timeout_ms {
                due.push((
                    id,
                    format!(
                        "no progress for {} ms (bound {timeout_ms} ms: progress_timeout_ms, or \
                         cycle_deadline_multiple x the median episode time if shorter)",
                        now - lease.progress_ms
                    ),
                    true,
                ));
            }
        }
        due
    }

    /// Remembers that `lease` was dropped and why.
    pub fn remember_dropped(&mut self, lease: u64, why: String) {
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

    /// Remembers an expired lease.
    pub fn remember_expired(&mut self, expired: ExpiredLease) {
        self.expired.push_back(expired);
        if self.expired.len() > LEASES_REMEMBERED {
            self.expired.pop_front();
        }
    }

    /// The leases that expired in this learner process (the newest [`LEASES_REMEMBERED`]),
    /// oldest first.
    pub fn expired(&self) -> impl Iterator<Item = &ExpiredLease> {
        self.expired.iter()
    }
}
