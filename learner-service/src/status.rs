//! `status.json`: what the learner is doing, rewritten atomically every status period, for the
//! progress bar of `adp train`, for tests and for people watching a cluster job.
//!
//! Plain data: the learner's shared state fills a [`Status`] from a snapshot of its counters
//! (`Shared::status`).

use std::path::Path;

use scheduler::RankCounts;
use serde::{Deserialize, Serialize};

use crate::error::{FileError, StatusFileError};
use crate::totals::PrunedRanks;

/// Name of the status file in the run directory.
pub const STATUS_FILE: &str = "status.json";

/// The counters of one actor kind in `status.json`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct KindStatus {
    /// The kind (`rust`, `python`, `unknown`, ...).
    pub kind: String,
    /// Registrations over the run.
    pub registered: u64,
    /// Live actors of this kind now.
    pub active: usize,
    /// Episodes reported and accepted over the run.
    pub episodes: u64,
    /// Step records stored over the run.
    pub steps: u64,
}

/// Actor ids remembered per rank in [`RankStatus::actor_ids`].
pub const RANK_IDS_REMEMBERED: usize = 16;

/// Ranks listed one by one in [`Status::ranks`] and [`Status::rank_steps`] (the lowest rank
/// numbers); the rest are summed up in [`Status::ranks_omitted`] and
/// [`Status::rank_steps_omitted`], so `status.json` stays small however many ranks are live.
pub const RANKS_DETAILED: usize = 256;

/// Entries of [`Status::actor_kinds`] at most: when more kinds registered, the first
/// `KINDS_DETAILED - 1` (in name order) are listed and the others summed up as one entry named
/// [`OTHER_KINDS`].
pub const KINDS_DETAILED: usize = 32;

/// The kind under which the kinds beyond [`KINDS_DETAILED`] are summed up.
pub const OTHER_KINDS: &str = "(other kinds)";

/// Leases remembered in [`Status::leases_expired_recent`] and [`Status::refused_leases`]
/// (like the registry's retired actors, a bounded record: the oldest are forgotten).
pub const LEASES_REMEMBERED: usize = 1024;

/// The counters of one actor rank in `status.json`, over this learner process (they restart
/// with each incarnation, unlike [`Status::rank_steps`]).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RankStatus {
    /// The rank.
    pub rank: u32,
    /// Registrations of this rank (an actor that reconnects registers again).
    pub registrations: u64,
    /// The actor ids this rank registered as, oldest first (the newest
    /// [`RANK_IDS_REMEMBERED`]).
    pub actor_ids: Vec<u64>,
    /// Step records of this rank stored from the shared-memory data plane.
    pub steps_shm: u64,
    /// Step records of this rank stored from the gRPC data plane.
    pub steps_grpc: u64,
}

/// The ranks of this learner process left out of [`Status::ranks`], in aggregate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct OmittedRanks {
    /// Ranks left out.
    pub ranks: usize,
    /// Their registrations.
    pub registrations: u64,
    /// Their step records stored from the shared-memory data plane.
    pub steps_shm: u64,
    /// Their step records stored from the gRPC data plane.
    pub steps_grpc: u64,
}

/// The ranks of [`Status::rank_steps`] (over the whole run) left out, in aggregate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct OmittedRankSteps {
    /// Ranks left out.
    pub ranks: usize,
    /// Their step records stored.
    pub steps: u64,
}

/// The connections of one listener (TCP or the Unix socket) in `status.json`, over this learner
/// process.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ListenerStatus {
    /// Its cap: connections served at once (`[service] max_connections`, fitted to the
    /// open-file limit).
    pub cap: u64,
    /// Connections accepted.
    pub accepted: u64,
    /// Connections open now.
    pub open: u64,
    /// Times the cap was reached (later connections waited in the kernel's backlog).
    pub cap_reached: u64,
}

/// What the learner's servers refused or closed before serving it, and what they repaired, in
/// `status.json`, over this learner process. Each refusal is also logged with the peer and the
/// cause (the first 20 of each cause, then every 1000th).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConnectionStatus {
    /// The TCP listener (`[service] listen`).
    pub tcp: ListenerStatus,
    /// The Unix socket `learner.sock`.
    pub unix: ListenerStatus,
    /// TCP connections closed at once because their source address already had `[service]
    /// max_connections_per_ip` open.
    pub refused_per_address: u64,
    /// Connections closed for sending no HTTP/2 preface (or TLS ClientHello) within `[service]
    /// handshake_timeout_ms`.
    pub closed_no_preface: u64,
    /// Connections closed for making no request with the run token within `[service]
    /// auth_deadline_ms`.
    pub closed_unauthenticated: u64,
    /// Requests refused for a message that does not decode (not protobuf, invalid UTF-8 in a
    /// string, a broken gRPC frame): INVALID_ARGUMENT.
    pub undecodable_requests: u64,
    /// Requests refused for a message over the size limit: RESOURCE_EXHAUSTED.
    pub oversized_requests: u64,
    /// Connections without a request carrying the run token closed to make room for a new
    /// one at `[service] max_connections_per_ip` or `max_connections` (the oldest first).
    #[serde(default)]
    pub closed_for_room: u64,
    /// `WatchPolicy` streams refused because `[service] max_policy_streams` were open.
    #[serde(default)]
    pub policy_streams_refused: u64,
    /// `WatchPolicy` streams refused because their TCP source address had `[service]
    /// policy_streams_per_ip` open.
    #[serde(default)]
    pub policy_streams_refused_per_address: u64,
    /// `WatchPolicy` streams ended because their registration opened one more than `[service]
    /// policy_streams_per_actor`.
    #[serde(default)]
    pub policy_streams_replaced: u64,
    /// `WatchPolicy` streams ended in the middle of a policy version that a newer one had
    /// superseded `[service] policy_send_grace_ms` before (a reader too slow to take it).
    #[serde(default)]
    pub policy_streams_unfinished: u64,
    /// `Register` calls refused because their TCP source address had `[service]
    /// registrations_per_ip` live registrations.
    #[serde(default)]
    pub registrations_refused_per_address: u64,
    /// Requests whose incomplete message was ended (RESOURCE_EXHAUSTED) to keep the bytes of
    /// incomplete messages under `[service] max_incomplete_bytes` or
    /// `max_incomplete_bytes_per_connection` (the oldest first).
    #[serde(default)]
    pub messages_ended_for_room: u64,
    /// Requests whose message was not complete within `[service] message_deadline_ms` of its
    /// first byte (DEADLINE_EXCEEDED).
    #[serde(default)]
    pub messages_past_deadline: u64,
    /// Requests on the Unix socket whose `:authority` was rewritten to one the server accepts
    /// (grpc-core clients send the socket's percent-encoded path).
    pub authorities_rewritten: u64,
}

/// A lease that expired (no heartbeat within its TTL), in `status.json`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExpiredLease {
    /// The lease id.
    pub lease: u64,
    /// The actor that held it.
    pub actor_id: u64,
    /// That actor's rank.
    pub rank: u32,
    /// The world it was dealt (dealt again).
    pub world: usize,
}

/// Records refused under one lease (refusals of kind `invalid_lease` name their lease), in
/// `status.json`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RefusedLease {
    /// The lease id the refused records were sent under.
    pub lease: u64,
    /// Records refused under it.
    pub records: u64,
}

/// The checkpoint a resumed learner continued from, in `status.json`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ResumeStatus {
    /// The checkpoint directory.
    pub checkpoint: String,
    /// Agent steps stored in it.
    pub inserts: u64,
    /// Gradient updates done in it.
    pub updates: u64,
}

/// A snapshot of the learner's counters.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// The run.
    pub run_id: String,
    /// This learner process.
    pub incarnation: u64,
    /// Agent steps stored.
    pub inserts: u64,
    /// The run's step budget.
    pub budget: u64,
    /// Gradient updates done.
    pub updates: u64,
    /// Newest published policy version.
    pub policy_version: u64,
    /// Scheduler cycle.
    pub cycle: u64,
    /// Occupied replay slots.
    pub replay_len: usize,
    /// Agent steps stored per second since the last status.
    pub inserts_per_s: f64,
    /// Updates per second since the last status.
    pub updates_per_s: f64,
    /// Mean policy-version lag of the steps stored since the last status.
    pub policy_lag: f64,
    /// Exploration sigma of the current inserts.
    pub exploration_sigma: f64,
    /// Live actors.
    pub live_actors: usize,
    /// Leases open.
    pub open_leases: usize,
    /// Step records stored in total.
    pub steps_received: u64,
    /// Step records received again after they were stored (resent batches), not stored twice.
    #[serde(default)]
    pub steps_duplicate: u64,
    /// Episodes reported.
    pub episodes: u64,
    /// Episodes whose received steps matched the actor's count and checksum.
    pub episodes_verified: u64,
    /// Episodes whose received steps did not match.
    pub episodes_mismatched: u64,
    /// Episodes abandoned by expired leases.
    pub episodes_abandoned: u64,
    /// Leases that expired (no heartbeat within their TTL).
    pub leases_expired: u64,
    /// Leases dropped although their actor heartbeated (a refused step, or no progress).
    pub leases_dropped: u64,
    /// Leases ended at a cycle's deadline (or a late actor's at its own).
    #[serde(default)]
    pub leases_cut: u64,
    /// The cycle deadline in force: how long a cycle waits at most after its first assignment
    /// (ms); `None` before a lease finished in this learner process, or with deadlines off.
    #[serde(default)]
    pub cycle_span_ms: Option<u64>,
    /// The median episode time of the newest finished leases (ms), the deadlines' measure.
    #[serde(default)]
    pub median_episode_ms: Option<u64>,
    /// Ranks off the cycle barrier (their last lease ended at a deadline or stalled) until
    /// they finish one.
    #[serde(default)]
    pub late_ranks: usize,
    /// Success rate of the recent episodes.
    pub success_rate: Option<f64>,
    /// Mean return of the recent episodes.
    pub mean_return: Option<f64>,
    /// Mean BARN score of the recent episodes.
    pub mean_score: Option<f64>,
    /// Refused records by reason.
    pub refused: Vec<(String, u64)>,
    /// Episodes completed per training world `(world, episodes)`.
    pub world_episodes: Vec<(usize, u64)>,
    /// Step records stored per actor rank `(rank, steps)`, over the whole run: the
    /// [`RANKS_DETAILED`] lowest ranks (the others in [`Status::rank_steps_omitted`]).
    pub rank_steps: Vec<(u32, u64)>,
    /// Counters per actor kind (`rust`, `python`, `unknown`, ...), a mixed fleet's view.
    pub actor_kinds: Vec<KindStatus>,
    /// Checkpoints the resume of this learner skipped as unusable, with the reason.
    pub resume_warnings: Vec<String>,
    /// Why the shared-memory data plane was offered but is not in use (actors use gRPC).
    pub shm_unavailable: Option<String>,
    /// The training thread has stopped (final checkpoint written).
    pub finished: bool,
    /// Counters per actor rank over this learner process (registrations, actor ids, steps per
    /// data plane), by rank: the [`RANKS_DETAILED`] lowest ranks (the others in
    /// [`Status::ranks_omitted`]).
    #[serde(default)]
    pub ranks: Vec<RankStatus>,
    /// The ranks left out of [`Status::ranks`], in aggregate.
    #[serde(default)]
    pub ranks_omitted: OmittedRanks,
    /// The ranks left out of [`Status::rank_steps`], in aggregate.
    #[serde(default)]
    pub rank_steps_omitted: OmittedRankSteps,
    /// How many ranks are live, dead and holding leases.
    #[serde(default)]
    pub rank_states: RankCounts,
    /// Registrations in this learner process that found their rank held by a live
    /// registration and did not carry its secret: the live one kept its lease, the new one
    /// works beside it (logged with the peer).
    #[serde(default)]
    pub registrations_beside_live: u64,
    /// Connections and requests refused, closed or repaired before they were served.
    #[serde(default)]
    pub connections: ConnectionStatus,
    /// Leases this learner process saw expire, oldest first (the newest
    /// [`LEASES_REMEMBERED`]; [`Status::leases_expired`] counts them all).
    #[serde(default)]
    pub leases_expired_recent: Vec<ExpiredLease>,
    /// Leases named by refused records (kind `invalid_lease`) in this learner process, in the
    /// order they were first refused (the newest [`LEASES_REMEMBERED`]).
    #[serde(default)]
    pub refused_leases: Vec<RefusedLease>,
    /// The checkpoint this learner resumed from (`None` for a fresh run).
    #[serde(default)]
    pub resumed_from: Option<ResumeStatus>,
    /// Ranks forgotten over the run (dead for `[service] rank_forget_ms`, or beyond
    /// `dead_ranks_kept`), in aggregate: they are no longer in [`Status::ranks`] or
    /// [`Status::rank_steps`].
    #[serde(default)]
    pub pruned_ranks: PrunedRanks,
}

impl Status {
    /// The TensorBoard scalars of this status (tag, value).
    pub fn scalars(&self) -> Vec<(&'static str, f64)> {
        let mut v = vec![
            ("service/updates_per_s", self.updates_per_s),
            ("service/inserts_per_s", self.inserts_per_s),
            ("service/replay_size", self.replay_len as f64),
            ("service/policy_version", self.policy_version as f64),
            ("service/policy_lag", self.policy_lag),
            ("service/live_actors", self.live_actors as f64),
            (
                "service/refused",
                self.refused.iter().map(|r| r.1).sum::<u64>() as f64,
            ),
            ("service/leases_expired", self.leases_expired as f64),
            ("service/leases_dropped", self.leases_dropped as f64),
            ("service/leases_cut", self.leases_cut as f64),
            ("train/exploration_sigma", self.exploration_sigma),
            ("train/updates", self.updates as f64),
        ];
        if let (Some(s), Some(r), Some(b)) = (self.success_rate, self.mean_return, self.mean_score) {
            v.extend([
                ("episode/success_rate", s),
                ("episode/return", r),
                ("episode/barn_score", b),
            ]);
        }
        v
    }
}

/// Writes `status` to `run_dir/status.json` atomically (temporary file + rename).
pub fn write_status(run_dir: &Path, status: &Status) -> Result<(), FileError> {
    let tmp = run_dir.join(format!(".{STATUS_FILE}.tmp"));
    let text = serde_json::to_string_pretty(status).expect("status serializes");
    std::fs::write(&tmp, text)
        .and_then(|_| std::fs::rename(&tmp, run_dir.join(STATUS_FILE)))
        .map_err(FileError::at(format!(
            "cannot write {}",
            run_dir.join(STATUS_FILE).display()
        )))
}

/// Reads `run_dir/status.json`.
pub fn read_status(run_dir: &Path) -> Result<Status, StatusFileError> {
    let p = run_dir.join(STATUS_FILE);
    let text = std::fs::read_to_string(&p).map_err(FileError::at(format!("cannot read {}", p.display())))?;
    serde_json::from_str(&text).map_err(|source| StatusFileError::Parse { path: p, source })
}
