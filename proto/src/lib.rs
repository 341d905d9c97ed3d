#![warn(missing_docs)]
//! The wire contract between the ADP learner and its actors (`adp.v1`), and the two data planes
//! that carry it.
//!
//! - [`pb`]: the prost messages and tonic services generated at build time from
//!   `proto/adp/v1/adp.proto` (compiled with protox: no system `protoc`).
//! - [`floats`]: raw little-endian `f32` vectors inside `bytes` fields.
//! - [`validate`]: the one validation layer both data planes go through before anything
//!   reaches the replay buffer (shapes, finite values, ranges, known actor, valid lease, current
//!   run), with per-reason refusal counters.
//! - [`auth`]: the run's secret token (file with mode 0600) and the gRPC interceptors that send
//!   and check it; TLS settings.
//! - [`plane`]: the actor-side interface of a data plane ([`plane::StepSink`],
//!   [`plane::PolicySource`]) with its gRPC ([`grpc`]) and shared-memory ([`shm`])
//!   implementations.
//! - [`spec`]: the run's settings (planner, action space, environment: the `adp-settings`
//!   types) to and from their `RunSpec` messages.

pub mod auth;
pub mod checksum;
pub mod floats;
pub mod grpc;
pub mod plane;
pub mod shm;
pub mod spec;

pub mod validate;

/// Generated `adp.v1` messages and services.
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod pb {
    tonic::include_proto!("adp.v1");
}

pub use validate::{Refusal, RefusalCounts, Spaces, StepView};

/// The byte-buffer type of the generated messages' `bytes` fields.
pub use prost::bytes::Bytes;

/// This machine's host name (from `/proc/sys/kernel/hostname`; `localhost` if unreadable).
/// Actors and learner compare it to decide whether shared memory can carry the data plane.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_owned())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".into())
}
