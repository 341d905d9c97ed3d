#![warn(missing_docs)]
//! The files of an exported policy, as the learner writes them (`adp export`, the end of
//! `adp train`) and a runtime reads them:
//!
//! - [`JSON_FILE`]: the [`card::PolicyCard`]: the observation layout, the action space with its
//!   physical ranges and how an action becomes a rollout schedule, the environment and planner
//!   it was trained for, the software version and the checkpoint the weights come from.
//! - [`SAFETENSORS_FILE`]: the actor's weights, `layers.{i}.weight` (`[out, in]`, PyTorch's
//!   `nn.Linear` layout) and `layers.{i}.bias` (`[out]`), float32; [`weights`] reads them.
//! - [`ONNX_FILE`]: the same network as an ONNX graph, whose input and output names and opset
//!   the card records ([`INPUT_NAME`], [`OUTPUT_NAME`], [`OPSET`]).
//!
//! The writers (they read the learner's networks) stay in the learner; this crate holds what
//! both sides share and depends on neither: reading a policy links no learner.

pub mod card;
pub mod weights;

pub use card::{
    observation_layout, space_name, ActionCard, ActionDimension, CardError, CardMismatch, Checkpoint,
    NetworkCard, ObservationLayout, ObservationSegment, PolicyCard, Software, Source, TrainedFor,
};
pub use weights::{bias_name, read_actor_safetensors, weight_name, WeightsError};

/// Name of the ONNX file in an export directory.
pub const ONNX_FILE: &str = "policy.onnx";
/// Name of the safetensors file in an export directory.
pub const SAFETENSORS_FILE: &str = "policy.safetensors";
/// Name of the JSON card in an export directory.
pub const JSON_FILE: &str = "policy.json";
/// The `format` field of every [`PolicyCard`].
pub const CARD_FORMAT: &str = "adp-policy";
/// The card format version this build writes.
pub const CARD_FORMAT_VERSION: u32 = 1;

/// Default-domain operator set of the ONNX graph (Gemm, Relu and Tanh are unchanged since 13).
pub const OPSET: i64 = 13;
/// Name of the ONNX graph's input.
pub const INPUT_NAME: &str = "obs";
/// Name of the ONNX graph's output.
pub const OUTPUT_NAME: &str = "action";
