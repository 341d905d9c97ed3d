//! What the [`Registry`](crate::Registry) hands out and reports: assignments and expiries.

use serde::{Deserialize, Serialize};

/// Identifies one registration of an actor. Ids are never reused within a run (also not
/// across a checkpoint restore).
pub type ActorId = u64;

/// One unit of work: run `episodes` episodes in `world` with the given seeds.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Assignment {
    /// The lease under which the actor's data is accepted; never reused within a run.
    pub lease_id: u64,
    /// The actor the assignment is for.
    pub actor: ActorId,
    /// The training world to run.
    pub world: usize,
    /// How many episodes to run (`RegistryConfig::episodes_per_assignment`).
    pub episodes: u32,
    /// The cycle the assignment belongs to.
    pub cycle: u64,
    /// The policy version the learner reported when the assignment was made.
    pub policy_version: u64,
    /// One seed per episode, see [`episode_seed`](crate::seed::episode_seed).
    pub seeds: Vec<u64>,
    /// The lease is valid while `now_ms < deadline_ms`; heartbeats move the deadline.
    pub deadline_ms: u64,
}

/// The answer to [`Registry::next_assignment`](crate::Registry::next_assignment).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Decision {
    /// Work to do now.
    Assign(Assignment),
    /// The actor already had its assignment in the current cycle: ask again later.
    Idle,
}

/// Why a lease ended without finishing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ExpiryCause {
    /// No heartbeat within the TTL, or its actor was retired (its rank registered again).
    #[default]
    Silent,
    /// The caller ended it ([`Registry::revoke`](crate::Registry::revoke)).
    Revoked,
    /// The caller ended it for want of progress ([`Registry::stall`](crate::Registry::stall)).
    Stalled,
    /// The cycle's deadline passed while it was open (one span after the cycle's first
    /// assignment, see [`deadline`](crate::deadline)).
    CycleDeadline {
        /// The span in force (ms).
        span_ms: u64,
    },
    /// A late actor's lease ran its span without finishing.
    LeaseDeadline {
        /// The span it was given (ms).
        span_ms: u64,
    },
}

impl ExpiryCause {
    /// Whether a deadline ended it (its rank is then late, see
    /// [`Registry`](crate::Registry)'s documentation).
    pub fn is_deadline(self) -> bool {
        matches!(self, Self::CycleDeadline { .. } | Self::LeaseDeadline { .. })
    }
}

/// A lease that ended without finishing (no heartbeat within the TTL, its actor re-registered,
/// a deadline, or the caller ended it): its world was returned to the dealer and the caller
/// should abandon the actor's open episodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Expired {
    /// The actor that held the lease.
    pub actor: ActorId,
    /// The expired lease.
    pub lease_id: u64,
    /// The world of the lease, now dealt again first.
    pub world: usize,
    /// Why it ended.
    pub cause: ExpiryCause,
}
