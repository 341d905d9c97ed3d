//! The learner's counters that survive a resume (checkpointed in the run state's `extra`):
//! steps, episodes, leases, recent episode statistics, and the counters per rank and per
//! actor kind.

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};

/// Recent episodes kept for the success rate and mean return shown in progress and TensorBoard.
const RECENT_EPISODES: usize = 100;

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
    /// Step records received again after they were stored (a batch resent over a broken
    /// connection): acknowledged to the actor as duplicates, not stored again.
    #[serde(default)]
    pub steps_duplicate: u64,
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
    /// Leases ended at a cycle's deadline, or a late actor's lease at its own (`[service]
    /// cycle_deadline_multiple`). Their worlds are dealt again.
    #[serde(default)]
    pub leases_cut: u64,
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

    /// Counts a reported episode and keeps it among the recent ones (the newest
    /// [`RECENT_EPISODES`]).
    pub fn record_episode(&mut self, episode: EpisodeStat) {
        self.episodes_reported += 1;
        self.successes += u64::from(episode.success);
        self.recent.push_back(episode);
        if self.recent.len() > RECENT_EPISODES {
            self.recent.pop_front();
        }
    }
}
