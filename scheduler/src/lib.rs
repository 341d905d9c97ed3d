#![warn(missing_docs)]
//! Distribution for ADP (design §6): which actor runs which world when, and the local
//! processes that run them.
//!
//! - [`Dealer`] deals training worlds fairly: the world with the fewest assignments next,
//!   ties in a seeded order reshuffled every pass, expired assignments dealt again first; or,
//!   from a [`WorldPool::Fresh`] pool, a world never dealt before for every assignment.
//! - [`Registry`] tracks actors, leases and cycles: each actor gets one assignment of
//!   `episodes_per_assignment` episodes (with deterministic seeds, see [`seed`]) per cycle;
//!   the cycle advances when every actor working in it finished or lost its lease; leases
//!   expire without heartbeats and their data is refused afterwards; a cycle and a late
//!   actor's lease end at a [`deadline`] derived from measured episode times. It is pure logic driven
//!   by a caller-supplied millisecond clock and checkpoints through [`RegistrySnapshot`].
//! - [`Supervisor`] runs the actor processes of one node in a [`Sandbox`] (resource limits,
//!   no new privileges, death with the parent, own process group, optional bubblewrap),
//!   restarts crashed ones with exponential [`Backoff`] and shuts them down. Linux only.
//!
//! The dealer and registry are plain data (`Send + Sync`, mutated through `&mut self`); a
//! server shares them behind a mutex. The supervisor is `Send` and should be driven from one
//! long-lived thread (children die with the thread that spawned them).

pub mod assignment;
pub mod backoff;
pub mod deadline;
pub mod dealer;
pub mod registry;
pub mod sandbox;
pub mod seed;
pub mod supervisor;
#[cfg(test)]
mod test_util;

pub use assignment::{ActorId, Assignment, Decision, Expired, ExpiryCause};
pub use backoff::{Backoff, BackoffPolicy};
pub use deadline::{DeadlineRule, EpisodeTimes};
pub use dealer::{Dealer, DealerError, WorldCount, WorldPool};
pub use registry::{
    ActorInfo, RankCounts, Registry, RegistryConfig, RegistryError, RegistrySnapshot, RegistryStatus,
};
pub use sandbox::{BwrapMode, BwrapStatus, ProbeError, Sandbox, SandboxConfig, SandboxError};
pub use supervisor::{ExitKind, RankLaunch, Supervisor, SupervisorConfig, SupervisorError, SupervisorEvent};
