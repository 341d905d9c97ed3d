#![warn(missing_docs)]
//! The learning core of ADP: TD3 on burn with an n-step replay buffer, a samples-per-insert
//! rate limiter, the exploration schedule and the DDP initialization of the actor.
//!
//! The backend is chosen at runtime through the burn [`burn::tensor::Device`] handed to
//! [`Td3::new`] (`Device::flex()`, the pure-Rust CPU backend, by default);
//! [`device::LearnerDevice`] names the choices (`cpu`, `wgpu`) and opens them.
//!
//! Around the core: checkpoints ([`checkpoint`]), export of the policy as ONNX, safetensors and
//! a JSON card ([`export`]), and TensorBoard event files ([`tensorboard`]).

pub mod adam;
pub mod batch;
pub mod checkpoint;
pub mod config;
pub mod ddp_init;
pub mod device;
pub mod exploration;
pub mod export;
pub mod mem;
pub mod nets;
pub mod rate;
pub mod replay;
pub mod retention;
pub mod td3;
pub mod tensorboard;
#[cfg(test)]
mod test_util;

pub use batch::Batch;
/// The burn device type taken by [`Td3::new`] and [`checkpoint::load`] (`Device::flex()` is
/// the CPU backend).
pub use burn::tensor::Device;
pub use checkpoint::{CheckpointError, Manifest, RunState};
pub use config::{ConfigError, Td3Config};
pub use ddp_init::{fit_actor_to_action, FitError, FitOptions, FitReport};
pub use device::{DeviceError, LearnerDevice};
pub use exploration::ExplorationSchedule;
pub use export::{export_checkpoint, export_published, ExportError, ExportSummary, PolicyCard, Published};
pub use nets::{Actor, Critic, TwinCritic};
pub use rate::RateLimiter;
pub use replay::{EpisodeId, ReplayBuffer, ReplayError, Step, StepEnd};
pub use td3::{seeded_rng, Td3, Td3Error, UpdateStats};
pub use tensorboard::{EventWriter, TensorBoardError};
