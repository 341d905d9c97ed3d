//! The actor-side interface of a data plane: where step records go and where policies come
//! from. The actor loop is written against these two traits only, so the same code runs over
//! shared memory ([`crate::shm`]) on one node and over gRPC ([`crate::grpc`]) across nodes.

use thiserror::Error;

use crate::validate::StepView;

/// The credential of one registration (`RegisterReply.actor_secret`): 16 random bytes.
pub type ActorSecret = [u8; 16];

/// Who sends a step record: the lease it is delivered under. Plain data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeaseHeader {
    /// The learner incarnation the actor registered with.
    pub incarnation: u64,
    /// The actor.
    pub actor_id: u64,
    /// The lease of the assignment the step belongs to.
    pub lease_id: u64,
    /// The actor's credential from its registration; a record whose secret does not match
    /// `actor_id` is refused before it is used.
    pub secret: ActorSecret,
}

/// A policy version as an actor receives it.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyUpdate {
    /// The version.
    pub version: u64,
    /// Exploration noise sigma that goes with it.
    pub exploration_sigma: f64,
    /// Flat network weights (layout of `actor::policy::MlpPolicy::from_flat`).
    pub weights: Vec<f32>,
}

/// A data-plane failure on the actor side. The actor reconnects (with back-off) after any of
/// them.
#[derive(Debug, Error)]
pub enum PlaneError {
    /// The learner is gone or unreachable.
    #[error("learner unreachable over {plane}: {detail}")]
    Disconnected {
        /// `grpc` or `shm`.
        plane: &'static str,
        /// What failed.
        detail: String,
    },
    /// The learner refused records (counted there too).
    #[error("learner refused {refused} of {sent} step records: {reason}")]
    Refused {
        /// Records refused.
        refused: u64,
        /// Records sent.
        sent: u64,
        /// The learner's first reason.
        reason: String,
    },
    /// A record does not fit the plane (e.g. longer than a shared-memory slot).
    #[error("step record does not fit the {plane} plane: {detail}")]
    TooLarge {
        /// `grpc` or `shm`.
        plane: &'static str,
        /// Sizes.
        detail: String,
    },
    /// Setting the plane up failed.
    #[error("cannot open the {plane} data plane: {detail}")]
    Setup {
        /// `grpc` or `shm`.
        plane: &'static str,
        /// What failed.
        detail: String,
    },
}

/// What became of the step records a sink was given, as far as the learner said. Over a plane
/// with acknowledgements, `sent == accepted + duplicates + refused + unacknowledged` once the
/// sink is flushed; `accepted` is what the learner stored from this sink, each record once.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SinkTally {
    /// Records handed to the sink.
    pub sent: u64,
    /// Records the learner acknowledged as stored.
    pub accepted: u64,
    /// Records the learner acknowledged as stored before (they were resent after a broken
    /// connection): not stored twice.
    pub duplicates: u64,
    /// Records the learner refused, with the reason the sink returned.
    pub refused: u64,
    /// Records whose fate the learner never told: the sink gave up resending them.
    pub unacknowledged: u64,
    /// Times the sink opened a new stream to resend records after a broken one.
    pub resends: u64,
}

impl std::ops::AddAssign for SinkTally {
    fn add_assign(&mut self, o: Self) {
        self.sent += o.sent;
        self.accepted += o.accepted;
        self.duplicates += o.duplicates;
        self.refused += o.refused;
        self.unacknowledged += o.unacknowledged;
        self.resends += o.resends;
    }
}

/// Where an actor's step records go. Not shared between threads (`Send` only).
pub trait StepSink: Send {
    /// Sends one step under `header`. May block while the learner applies back-pressure (its
    /// rate limiter); never drops a record silently.
    fn send(&mut self, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), PlaneError>;

    /// Returns once every record sent so far has been handed to the learner (gRPC: the stream
    /// was closed and acknowledged; shared memory: delivered into the learner's queue). Call it
    /// at the end of an assignment, before the final episode report.
    fn flush(&mut self) -> Result<(), PlaneError>;

    /// What the learner said of the records sent so far; `None` on a plane without
    /// acknowledgements (shared memory delivers into the learner's queue and is told nothing).
    fn tally(&self) -> Option<SinkTally>;
}

/// Where an actor gets policy versions from. Not shared between threads (`Send` only).
pub trait PolicySource: Send {
    /// The newest policy version newer than `have` (`None` = any), if one is available now.
    /// Does not wait for a new version.
    fn poll(&mut self, have: Option<u64>) -> Result<Option<PolicyUpdate>, PlaneError>;
}
