//! Export of a trained policy for use outside this project: the actor as an ONNX graph and as
//! safetensors, plus a JSON card with everything needed to feed it and to use its output.
//!
//! # Files written by [`export_checkpoint`]
//! - [`ONNX_FILE`]: the actor as an ONNX model (IR version [`IR_VERSION`], default-domain opset
//!   [`OPSET`]): `Gemm` (with `transB = 1`) and `Relu` for each hidden layer, `Gemm` and `Tanh`
//!   for the output. Input [`INPUT_NAME`] is `float32 [batch, obs_dim]` with a symbolic batch
//!   dimension, output [`OUTPUT_NAME`] is `float32 [batch, act_dim]` in [-1, 1]. The weights are
//!   initializers with the same names as in the safetensors file. Built from the official ONNX
//!   schema (`proto/onnx.proto`, compiled with prost at build time).
//! - [`SAFETENSORS_FILE`]: the actor weights, `layers.{i}.weight` (`[out, in]`, PyTorch's
//!   `nn.Linear` layout, so `y = x W^T + b`) and `layers.{i}.bias` (`[out]`), float32.
//! - [`JSON_FILE`]: a [`PolicyCard`]: the observation layout, the action space with its physical
//!   ranges and how an action becomes a rollout schedule, the software version and the checkpoint
//!   (run id, step counters) the weights come from.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor};
use planner::ActionSpace;
use prost::Message;
use safetensors::tensor::{Dtype, TensorView};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::checkpoint::{self, CheckpointError, Manifest};
use crate::nets::Actor;

/// The ONNX types generated from the official schema `proto/onnx.proto` (ONNX 1.17.0) by
/// `build.rs`. Generated code: this module uses only a few of its types, hence the allowances.
#[allow(dead_code, missing_docs, clippy::all, clippy::pedantic)]
pub(crate) mod onnx {
    include!(concat!(env!("OUT_DIR"), "/onnx.rs"));
}

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
/// ONNX IR version of the graph: 7, the IR version that goes with opset 13 (ONNX 1.8).
pub const IR_VERSION: i64 = 7;
/// Name of the ONNX graph's input.
pub const INPUT_NAME: &str = "obs";
/// Name of the ONNX graph's output.
pub const OUTPUT_NAME: &str = "action";
/// Name of the symbolic batch dimension of the ONNX input and output.
pub const BATCH_DIM: &str = "batch";
/// Laser beams at the start of every observation (DESIGN §5).
pub const LASER_BEAMS: usize = 720;
/// Laser ranges are clipped at this distance (m) before being mapped to [-1, 1], unless the run's
/// environment settings say otherwise (`laser_clip_m`).
pub const LASER_CLIP_M: f64 = 3.0;

/// Why an export failed. Every variant names the file involved.
#[derive(Debug, Error)]
pub enum ExportError {
    /// The checkpoint is missing, incomplete or damaged.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The checkpoint's networks do not fit the requested action space's observation layout.
    #[error("checkpoint {file}: {what}")]
    Mismatch {
        /// The checkpoint's manifest.
        file: PathBuf,
        /// What does not fit.
        what: String,
    },
    /// Writing an output file failed.
    #[error("export {op} {path}: {source}")]
    Io {
        /// What was attempted.
        op: &'static str,
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The safetensors encoder refused the weights.
    #[error("export {path}: cannot encode safetensors: {message}")]
    Safetensors {
        /// The file being written.
        path: PathBuf,
        /// The encoder's message.
        message: String,
    },
}

/// One dense layer of the actor in PyTorch's layout.
struct Dense {
    /// `[fan_out, fan_in]`, row-major.
    weight: Vec<f32>,
    /// `[fan_out]`.
    bias: Vec<f32>,
    fan_in: usize,
    fan_out: usize,
}

/// The actor's layers, input side first, with weights transposed from burn's `[in, out]`.
fn dense_layers(actor: &Actor) -> Vec<Dense> {
    actor
        .layers()
        .iter()
        .map(|layer| {
            let [fan_in, fan_out] = layer.weight.dims();
            let w = to_vec(layer.weight.val());
            let mut weight = vec![0.0; fan_in * fan_out];
            for i in 0..fan_in {
                for o in 0..fan_out {
                    weight[o * fan_in + i] = w[i * fan_out + o];
                }
            }
            let bias = layer
                .bias
                .as_ref()
                .map_or_else(|| vec![0.0; fan_out], |b| to_vec(b.val()));
            Dense {
                weight,
                bias,
                fan_in,
                fan_out,
            }
        })
        .collect()
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .try_to_vec::<f32>()
        .expect("actor parameters are f32")
}

fn le_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn weight_name(i: usize) -> String {
    format!("layers.{i}.weight")
}

fn bias_name(i: usize) -> String {
    format!("layers.{i}.bias")
}

/// `float32 [batch, width]` with the symbolic batch dimension.
fn batch_value_info(name: &str, width: usize) -> onnx::ValueInfoProto {
    use onnx::tensor_shape_proto::{dimension::Value, Dimension};
    let dim = |value| Dimension {
        value: Some(value),
        denotation: None,
    };
    onnx::ValueInfoProto {
        name: Some(name.into()),
        r#type: Some(onnx::TypeProto {
            value: Some(onnx::type_proto::Value::TensorType(onnx::type_proto::Tensor {
                elem_type: Some(onnx::tensor_proto::DataType::Float as i32),
                shape: Some(onnx::TensorShapeProto {
                    dim: vec![
                        dim(Value::DimParam(BATCH_DIM.into())),
                        dim(Value::DimValue(width as i64)),
                    ],
                }),
            })),
            denotation: None,
        }),
        ..Default::default()
    }
}

fn initializer(name: String, dims: &[usize], values: &[f32]) -> onnx::TensorProto {
    onnx::TensorProto {
        name: Some(name),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: Some(onnx::tensor_proto::DataType::Float as i32),
        raw_data: Some(le_bytes(values)),
        ..Default::default()
    }
}

fn node(op_type: &str, name: String, input: Vec<String>, output: String) -> onnx::NodeProto {
    onnx::NodeProto {
        op_type: Some(op_type.into()),
        name: Some(name),
        input,
        output: vec![output],
        ..Default::default()
    }
}

/// The actor as a serialized ONNX `ModelProto` (see the module docs for the graph), with
/// `metadata` as the model's metadata properties.
pub fn actor_onnx(actor: &Actor, metadata: &[(&str, String)]) -> Vec<u8> {
    let layers = dense_layers(actor);
    let last = layers.len() - 1;
    let mut nodes = Vec::new();
    let mut initializers = Vec::new();
    let mut x = INPUT_NAME.to_string();
    for (i, layer) in layers.iter().enumerate() {
        initializers.push(initializer(
            weight_name(i),
            &[layer.fan_out, layer.fan_in],
            &layer.weight,
        ));
        initializers.push(initializer(bias_name(i), &[layer.fan_out], &layer.bias));
        let linear = format!("linear_{i}");
        let mut gemm = node(
            "Gemm",
            format!("gemm_{i}"),
            vec![x, weight_name(i), bias_name(i)],
            linear.clone(),
        );
        gemm.attribute.push(onnx::AttributeProto {
            name: Some("transB".into()),
            r#type: Some(onnx::attribute_proto::AttributeType::Int as i32),
            i: Some(1),
            ..Default::default()
        });
        nodes.push(gemm);
        let (op, out) = if i < last {
            ("Relu", format!("relu_{i}"))
        } else {
            ("Tanh", OUTPUT_NAME.to_string())
        };
        nodes.push(node(
            op,
            format!("{}_{i}", op.to_lowercase()),
            vec![linear],
            out.clone(),
        ));
        x = out;
    }
    let (obs_dim, act_dim) = (layers[0].fan_in, layers[last].fan_out);
    let model = onnx::ModelProto {
        ir_version: Some(IR_VERSION),
        opset_import: vec![onnx::OperatorSetIdProto {
            domain: Some(String::new()),
            version: Some(OPSET),
        }],
        producer_name: Some("adp".into()),
        producer_version: Some(env!("CARGO_PKG_VERSION").into()),
        doc_string: Some(
            "ADP TD3 actor: normalized observation -> action in [-1, 1]; see policy.json".into(),
        ),
        graph: Some(onnx::GraphProto {
            name: Some("adp_actor".into()),
            node: nodes,
            initializer: initializers,
            input: vec![batch_value_info(INPUT_NAME, obs_dim)],
            output: vec![batch_value_info(OUTPUT_NAME, act_dim)],
            ..Default::default()
        }),
        metadata_props: metadata
            .iter()
            .map(|(key, value)| onnx::StringStringEntryProto {
                key: Some((*key).into()),
                value: Some(value.clone()),
            })
            .collect(),
        ..Default::default()
    };
    model.encode_to_vec()
}

/// The actor's weights as a safetensors file (names and layout in the module docs), with
/// `metadata` in the header's `__metadata__`.
pub fn actor_safetensors(
    actor: &Actor,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, safetensors::SafeTensorError> {
    let layers = dense_layers(actor);
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (i, layer) in layers.iter().enumerate() {
        tensors.push((
            weight_name(i),
            vec![layer.fan_out, layer.fan_in],
            le_bytes(&layer.weight),
        ));
        tensors.push((bias_name(i), vec![layer.fan_out], le_bytes(&layer.bias)));
    }
    let views = tensors
        .iter()
        .map(|(name, shape, bytes)| Ok((name.as_str(), TensorView::new(Dtype::F32, shape.clone(), bytes)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
    safetensors::serialize(views, Some(metadata))
}

/// The JSON card of an exported policy ([`JSON_FILE`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyCard {
    /// Always [`CARD_FORMAT`].
    pub format: String,
    /// [`CARD_FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// The software that wrote the export.
    pub software: Software,
    /// The checkpoint the weights come from.
    pub source: Source,
    /// The network and its two serializations.
    pub network: NetworkCard,
    /// What the network reads.
    pub observation: ObservationLayout,
    /// What the network's output means.
    pub action: ActionCard,
    /// The environment settings the policy was trained with (the `[env]` table of the run
    /// config: `agent_period_cycles` planner cycles per action, `laser_clip_m`, rewards), so it
    /// can be run as it was trained; `null` when the checkpoint did not record them (the
    /// defaults applied).
    #[serde(default)]
    pub environment: serde_json::Value,
}

/// Name and version of the exporting software.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Software {
    /// `adp`.
    pub name: String,
    /// The crate version.
    pub version: String,
}

/// The checkpoint an export was made from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Source {
    /// The training run.
    pub run_id: String,
    /// Gradient updates done when the checkpoint was written.
    pub updates: u64,
    /// Agent steps inserted when the checkpoint was written.
    pub inserts: u64,
    /// Policy version at the checkpoint.
    pub policy_version: u64,
}

/// The actor network and where its serializations are.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkCard {
    /// Widths from the observation to the action, e.g. `[730, 512, 512, 4]`.
    pub layer_sizes: Vec<usize>,
    /// Activation after every hidden layer (`relu`).
    pub hidden_activation: String,
    /// Activation of the output layer (`tanh`).
    pub output_activation: String,
    /// The ONNX file.
    pub onnx_file: String,
    /// Its input name.
    pub onnx_input: String,
    /// Its output name.
    pub onnx_output: String,
    /// Its default-domain opset.
    pub onnx_opset: i64,
    /// The safetensors file.
    pub safetensors_file: String,
    /// The tensor names and layout of the safetensors file.
    pub safetensors_layout: String,
}

/// The observation vector, as consecutive segments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservationLayout {
    /// Total length.
    pub dim: usize,
    /// Segments in order; each starts where the previous one ends.
    pub segments: Vec<ObservationSegment>,
}

/// A run of observation values with one meaning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservationSegment {
    /// Short name, e.g. `laser`.
    pub name: String,
    /// Index of the first value.
    pub offset: usize,
    /// Number of values.
    pub size: usize,
    /// How the values are computed from the robot's state and sensors.
    pub encoding: String,
}

/// The action space of the policy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionCard {
    /// The action space (`decremental`, `incremental`, `unconstrained` or `fixed`).
    pub space: ActionSpace,
    /// Number of action values.
    pub dim: usize,
    /// Every value the network outputs lies in `[-1, 1]`.
    pub normalized_range: [f64; 2],
    /// Each value's physical meaning and range.
    pub dimensions: Vec<ActionDimension>,
    /// How a normalized value becomes a physical one.
    pub to_physical: String,
    /// How the physical values become the planner's rollout schedule.
    pub schedule: String,
    /// The normalized action that reproduces DDP (ADP's initial policy), as a worked example.
    pub ddp_action: Vec<f64>,
    /// Its physical values.
    pub ddp_physical: Vec<f64>,
}

/// One action value's meaning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionDimension {
    /// Parameter name (`p`, `T`, `N`, `alpha`, `dt`, `check_density`).
    pub name: String,
    /// Physical value at normalized -1.
    pub low: f64,
    /// Physical value at normalized +1.
    pub high: f64,
    /// Rounded to the nearest integer after scaling.
    pub integer: bool,
}

/// The observation layout of DESIGN §5 for `space`: 720 laser values (ranges clipped at
/// `laser_clip_m`), the previous action, v, w, and (bearing, distance) to the local and the
/// global goal.
pub fn observation_layout(space: ActionSpace, laser_clip_m: f64) -> ObservationLayout {
    let parts: [(&str, usize, String); 6] = [
        (
            "laser",
            LASER_BEAMS,
            format!(
                "lidar ranges r (m) in beam order, beam k at -135 + k * 270/{} degrees from the \
                 heading (counter-clockwise positive); x = 2 * min(r, {laser_clip_m}) / \
                 {laser_clip_m} - 1, in [-1, 1]",
                LASER_BEAMS - 1
            ),
        ),
        (
            "previous_action",
            space.dim(),
            "the policy's previous action, normalized to [-1, 1] like its output".into(),
        ),
        ("v", 1, "measured linear velocity (m/s), not normalized".into()),
        (
            "w",
            1,
            "measured angular velocity (rad/s, counter-clockwise positive), not normalized".into(),
        ),
        (
            "local_goal",
            2,
            "bearing (rad, in [-pi, pi], relative to the heading) and distance (m) of the local \
             goal, not normalized"
                .into(),
        ),
        (
            "global_goal",
            2,
            "bearing (rad, in [-pi, pi], relative to the heading) and distance (m) of the global \
             goal, not normalized"
                .into(),
        ),
    ];
    let mut offset = 0;
    let segments = parts
        .into_iter()
        .map(|(name, size, encoding)| {
            let segment = ObservationSegment {
                name: name.into(),
                offset,
                size,
                encoding,
            };
            offset += size;
            segment
        })
        .collect();
    ObservationLayout {
        dim: offset,
        segments,
    }
}

/// The action space's name as in configuration files and the card (`decremental`, ...).
pub fn space_name(space: ActionSpace) -> String {
    match serde_json::to_value(space) {
        Ok(serde_json::Value::String(name)) => name,
        _ => unreachable!("ActionSpace serializes as a string"),
    }
}

/// How `space`'s physical values make a rollout schedule (mirrors `planner::action`).
fn schedule_text(space: ActionSpace) -> &'static str {
    match space {
        ActionSpace::Decremental => {
            "N steps with boundary times t_i = alpha (i/N) T + (1 - alpha) (i/N)^p T, i = 0..N; \
             step i (1-based) lasts t_i - t_(i-1) s and collision-checks round(n (1 - (i/N)^p)) \
             of the footprint's n boundary points"
        }
        ActionSpace::Incremental => {
            "the decremental schedule of the same (p, T, N, alpha) with its step lengths and \
             check counts in reverse order"
        }
        ActionSpace::Unconstrained => {
            "20 steps of dt_1..dt_20 s, all scaled by 2 / sum(dt) when the sum exceeds 2 s; with \
             t_i the end time of step i and H the horizon, step i collision-checks \
             round(n (1 - (t_i / H)^1.7)) of the footprint's n boundary points"
        }
        ActionSpace::Fixed => {
            "max(1, round(2 / dt)) steps of dt s, each collision-checking \
             round(check_density n) of the footprint's n boundary points"
        }
    }
}

impl PolicyCard {
    /// The card for an actor trained in `space` with the environment settings `environment`
    /// (see [`checkpoint::RunState::environment`]), from the checkpoint whose manifest is `manifest`. Fails
    /// when the checkpoint's observation or action size does not fit `space`, or the settings
    /// are not a table with a positive `laser_clip_m`.
    pub fn new(
        space: ActionSpace,
        manifest: &Manifest,
        environment: &serde_json::Value,
    ) -> Result<Self, String> {
        let config = &manifest.config;
        let layout = observation_layout(space, laser_clip_m(environment)?);
        if config.act_dim != space.dim() {
            return Err(format!(
                "act_dim = {} does not fit the {} action space ({} values)",
                config.act_dim,
                space_name(space),
                space.dim()
            ));
        }
        if config.obs_dim != layout.dim || config.laser_dim != LASER_BEAMS {
            return Err(format!(
                "obs_dim = {} with laser_dim = {} does not fit the observation layout of the \
                 {} action space ({} values, {LASER_BEAMS} of them laser)",
                config.obs_dim,
                config.laser_dim,
                space_name(space),
                layout.dim
            ));
        }
        let layer_sizes = std::iter::once(config.obs_dim)
            .chain(config.actor_hidden.iter().copied())
            .chain(std::iter::once(config.act_dim))
            .collect();
        let ddp_action = space.ddp_action();
        let ddp_physical = space
            .to_params(&ddp_action)
            .expect("the DDP action is a valid action of its space");
        Ok(Self {
            format: CARD_FORMAT.into(),
            format_version: CARD_FORMAT_VERSION,
            software: Software {
                name: "adp".into(),
                version: env!("CARGO_PKG_VERSION").into(),
            },
            source: Source {
                run_id: manifest.run_id.clone(),
                updates: manifest.updates,
                inserts: manifest.inserts,
                policy_version: manifest.policy_version,
            },
            network: NetworkCard {
                layer_sizes,
                hidden_activation: "relu".into(),
                output_activation: "tanh".into(),
                onnx_file: ONNX_FILE.into(),
                onnx_input: INPUT_NAME.into(),
                onnx_output: OUTPUT_NAME.into(),
                onnx_opset: OPSET,
                safetensors_file: SAFETENSORS_FILE.into(),
                safetensors_layout: "float32 layers.{i}.weight [out, in] and layers.{i}.bias [out] \
                                     for i = 0, 1, ...; layer i computes x W^T + b, followed by \
                                     relu (hidden layers) or tanh (last layer)"
                    .into(),
            },
            observation: layout,
            action: ActionCard {
                space,
                dim: space.dim(),
                normalized_range: [-1.0, 1.0],
                dimensions: space
                    .ranges()
                    .into_iter()
                    .map(|(name, low, high)| ActionDimension {
                        name: name.into(),
                        low,
                        high,
                        integer: name == "N",
                    })
                    .collect(),
                to_physical: "x = low + (clamp(a, -1, 1) + 1) / 2 * (high - low); integer \
                              dimensions are then rounded to the nearest integer"
                    .into(),
                schedule: schedule_text(space).into(),
                ddp_action,
                ddp_physical,
            },
            environment: environment.clone(),
        })
    }
}

/// The laser clip of recorded environment settings: their `laser_clip_m`, or [`LASER_CLIP_M`]
/// when they are `null` or do not set it.
fn laser_clip_m(environment: &serde_json::Value) -> Result<f64, String> {
    let table = match environment {
        serde_json::Value::Null => return Ok(LASER_CLIP_M),
        serde_json::Value::Object(table) => table,
        other => {
            return Err(format!(
                "the recorded environment settings are not a table: {other}"
            ))
        }
    };
    match table.get("laser_clip_m") {
        None => Ok(LASER_CLIP_M),
        Some(v) => v
            .as_f64()
            .filter(|c| c.is_finite() && *c > 0.0)
            .ok_or_else(|| format!("the recorded environment's laser_clip_m = {v} is not a positive number")),
    }
}

/// What [`export_checkpoint`] wrote.
#[derive(Debug, Clone)]
pub struct ExportSummary {
    /// The files written, with their sizes in bytes.
    pub files: Vec<(PathBuf, u64)>,
    /// The card written to [`JSON_FILE`].
    pub card: PolicyCard,
}

/// Write `data` to `path` through a temporary file and a rename, so a failed export never
/// leaves a partial file under the final name.
fn write_file(path: &Path, data: &[u8]) -> Result<(), ExportError> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    let io = |op, path: &Path| {
        let path = path.to_path_buf();
        move |source| ExportError::Io { op, path, source }
    };
    std::fs::write(&tmp, data).map_err(io("write", &tmp))?;
    std::fs::rename(&tmp, path).map_err(io("rename into place", path))
}

/// Load the verified checkpoint `checkpoint` (see [`checkpoint::load`]) and write
/// [`ONNX_FILE`], [`SAFETENSORS_FILE`] and [`JSON_FILE`] into `out` (created if needed; existing
/// files of these names are replaced). `space` is the action space the run trained in; the
/// checkpoint's sizes must fit it.
pub fn export_checkpoint(
    checkpoint: &Path,
    out: &Path,
    space: ActionSpace,
) -> Result<ExportSummary, ExportError> {
    let manifest = checkpoint::read_manifest(checkpoint)?;
    let (td3, run) = checkpoint::load(checkpoint, &Device::flex())?;
    let card = PolicyCard::new(space, &manifest, &run.environment).map_err(|what| ExportError::Mismatch {
        file: checkpoint.join(checkpoint::MANIFEST),
        what,
    })?;
    let actor = td3.policy();

    std::fs::create_dir_all(out).map_err(|source| ExportError::Io {
        op: "create directory",
        path: out.to_path_buf(),
        source,
    })?;
    let source = &card.source;
    let metadata = [
        ("adp.action_space", space_name(space)),
        ("adp.run_id", source.run_id.clone()),
        ("adp.updates", source.updates.to_string()),
        ("adp.policy_version", source.policy_version.to_string()),
        ("adp.version", card.software.version.clone()),
    ];
    let onnx_path = out.join(ONNX_FILE);
    let st_path = out.join(SAFETENSORS_FILE);
    let json_path = out.join(JSON_FILE);
    let onnx = actor_onnx(&actor, &metadata);
    let st_metadata = metadata.iter().map(|(k, v)| (k.to_string(), v.clone())).collect();
    let safetensors = actor_safetensors(&actor, st_metadata).map_err(|e| ExportError::Safetensors {
        path: st_path.clone(),
        message: e.to_string(),
    })?;
    let mut json = serde_json::to_vec_pretty(&card).expect("the card serializes");
    json.push(b'\n');
    let mut files = Vec::new();
    for (path, data) in [(onnx_path, onnx), (st_path, safetensors), (json_path, json)] {
        write_file(&path, &data)?;
        files.push((path, data.len() as u64));
    }
    Ok(ExportSummary { files, card })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use rand::Rng;
    use tract_onnx::prelude::*;

    use super::*;
    use crate::config::Td3Config;
    use crate::td3::seeded_rng;

    /// The full-size decremental actor, 730-512-512-4, with seeded weights.
    fn full_actor() -> Actor {
        let c = Td3Config::default();
        Actor::new(
            c.obs_dim,
            &c.actor_hidden,
            c.act_dim,
            &Device::flex(),
            &mut seeded_rng(21, 0),
        )
    }

    /// `rows` observations with the value ranges of DESIGN §5 (laser and previous action in
    /// [-1, 1], the rest in a few physical units).
    fn random_obs(rows: usize, dim: usize, seed: u64) -> Vec<f32> {
        let mut rng = seeded_rng(seed, 40);
        (0..rows * dim)
            .map(|i| {
                let bound = if i % dim < dim - 6 { 1.0 } else { 4.0 };
                rng.random_range(-bound..=bound)
            })
            .collect()
    }

    fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
    }

    fn burn_actions(actor: &Actor, obs: &[f32]) -> Vec<f32> {
        actor.act(obs, 0.0, &mut seeded_rng(0, 0))
    }

    /// The ONNX graph run by tract (a real ONNX runtime) matches burn within 1e-5 on 100 random
    /// observations, and on a batch of one through the same symbolic batch dimension.
    #[test]
    fn onnx_matches_burn_in_tract() {
        let actor = full_actor();
        let bytes = actor_onnx(&actor, &[]);
        let model = tract_onnx::onnx()
            .model_for_read(&mut bytes.as_slice())
            .unwrap()
            .into_optimized()
            .unwrap()
            .into_runnable()
            .unwrap();
        for rows in [100, 1] {
            let obs = random_obs(rows, 730, rows as u64);
            let input = tract_ndarray::Array2::from_shape_vec((rows, 730), obs.clone())
                .unwrap()
                .into_tensor();
            let outputs = model.run(tvec!(input.into())).unwrap();
            let got = outputs[0].to_plain_array_view::<f32>().unwrap();
            assert_eq!(got.shape(), &[rows, 4]);
            let got: Vec<f32> = got.iter().copied().collect();
            let want = burn_actions(&actor, &obs);
            let diff = max_abs_diff(&got, &want);
            assert!(diff <= 1e-5, "tract vs burn, batch {rows}: max |diff| {diff}");
            assert!(want.iter().any(|a| a.abs() > 0.05), "a degenerate test: {want:?}");
        }
    }

    #[test]
    fn onnx_graph_follows_the_documented_interface() {
        let actor = full_actor();
        let bytes = actor_onnx(&actor, &[("adp.run_id", "r1".into())]);
        let model = onnx::ModelProto::decode(bytes.as_slice()).unwrap();
        assert_eq!(model.ir_version, Some(IR_VERSION));
        assert_eq!(model.opset_import.len(), 1);
        assert_eq!(model.opset_import[0].domain.as_deref(), Some(""));
        assert_eq!(model.opset_import[0].version, Some(13));
        assert_eq!(model.metadata_props[0].value.as_deref(), Some("r1"));
        let graph = model.graph.unwrap();
        let ops: Vec<&str> = graph.node.iter().map(|n| n.op_type()).collect();
        assert_eq!(ops, ["Gemm", "Relu", "Gemm", "Relu", "Gemm", "Tanh"]);
        let dims = |v: &onnx::ValueInfoProto| -> Vec<String> {
            let Some(onnx::type_proto::Value::TensorType(t)) = &v.r#type.as_ref().unwrap().value else {
                panic!("not a tensor type");
            };
            assert_eq!(t.elem_type, Some(onnx::tensor_proto::DataType::Float as i32));
            t.shape
                .as_ref()
                .unwrap()
                .dim
                .iter()
                .map(|d| match d.value.as_ref().unwrap() {
                    onnx::tensor_shape_proto::dimension::Value::DimValue(v) => v.to_string(),
                    onnx::tensor_shape_proto::dimension::Value::DimParam(p) => p.clone(),
                })
                .collect()
        };
        assert_eq!(
            (graph.input[0].name(), dims(&graph.input[0])),
            ("obs", vec!["batch".into(), "730".into()])
        );
        assert_eq!(
            (graph.output[0].name(), dims(&graph.output[0])),
            ("action", vec!["batch".into(), "4".into()])
        );
        let shapes: Vec<(String, Vec<i64>)> = graph
            .initializer
            .iter()
            .map(|t| (t.name().to_string(), t.dims.clone()))
            .collect();
        assert_eq!(shapes[0], ("layers.0.weight".into(), vec![512, 730]));
        assert_eq!(shapes[5], ("layers.2.bias".into(), vec![4]));
    }

    /// The safetensors file holds the documented layout: a plain-Rust forward pass through its
    /// tensors (`tanh(relu(relu(x W0^T + b0) W1^T + b1) W2^T + b2)`) matches burn.
    #[test]
    fn safetensors_layout_reproduces_the_actor() {
        let actor = Actor::new(730, &[32, 16], 4, &Device::flex(), &mut seeded_rng(5, 0));
        let metadata = HashMap::from([("adp.run_id".to_string(), "r2".to_string())]);
        let bytes = actor_safetensors(&actor, metadata).unwrap();
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        assert_eq!(header.metadata().as_ref().unwrap()["adp.run_id"], "r2");
        let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let mut names = file.names();
        names.sort();
        assert_eq!(
            names,
            [
                "layers.0.bias",
                "layers.0.weight",
                "layers.1.bias",
                "layers.1.weight",
                "layers.2.bias",
                "layers.2.weight"
            ]
        );
        let floats = |name: &str| -> (Vec<usize>, Vec<f32>) {
            let t = file.tensor(name).unwrap();
            assert_eq!(t.dtype(), Dtype::F32);
            let values = t
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect();
            (t.shape().to_vec(), values)
        };
        let obs = random_obs(3, 730, 9);
        let mut x: Vec<Vec<f32>> = obs.chunks(730).map(<[f32]>::to_vec).collect();
        for i in 0..3 {
            let (shape, w) = floats(&format!("layers.{i}.weight"));
            let (bias_shape, b) = floats(&format!("layers.{i}.bias"));
            let (out, inp) = (shape[0], shape[1]);
            assert_eq!(bias_shape, [out]);
            x = x
                .iter()
                .map(|row| {
                    (0..out)
                        .map(|o| {
                            let y = b[o] + (0..inp).map(|k| row[k] * w[o * inp + k]).sum::<f32>();
                            if i < 2 {
                                y.max(0.0)
                            } else {
                                y.tanh()
                            }
                        })
                        .collect()
                })
                .collect();
        }
        let got: Vec<f32> = x.concat();
        let diff = max_abs_diff(&got, &burn_actions(&actor, &obs));
        assert!(diff <= 1e-5, "safetensors forward vs burn: {diff}");
    }

    fn manifest(config: Td3Config) -> Manifest {
        Manifest {
            format: checkpoint::FORMAT.into(),
            format_version: checkpoint::FORMAT_VERSION,
            run_id: "run-7".into(),
            updates: 1200,
            inserts: 2300,
            policy_version: 12,
            config,
            files: BTreeMap::new(),
        }
    }

    #[test]
    fn card_describes_layout_ranges_and_source() {
        let card = PolicyCard::new(
            ActionSpace::Decremental,
            &manifest(Td3Config::default()),
            &serde_json::Value::Null,
        )
        .unwrap();
        assert_eq!(card.network.layer_sizes, [730, 512, 512, 4]);
        assert_eq!(
            (
                card.source.run_id.as_str(),
                card.source.updates,
                card.source.inserts
            ),
            ("run-7", 1200, 2300)
        );
        let layout: Vec<(&str, usize, usize)> = card
            .observation
            .segments
            .iter()
            .map(|s| (s.name.as_str(), s.offset, s.size))
            .collect();
        assert_eq!(
            layout,
            [
                ("laser", 0, 720),
                ("previous_action", 720, 4),
                ("v", 724, 1),
                ("w", 725, 1),
                ("local_goal", 726, 2),
                ("global_goal", 728, 2)
            ]
        );
        let dims: Vec<(&str, f64, f64, bool)> = card
            .action
            .dimensions
            .iter()
            .map(|d| (d.name.as_str(), d.low, d.high, d.integer))
            .collect();
        assert_eq!(
            dims,
            [
                ("p", 1.0, 1.7, false),
                ("T", 1.6, 2.2, false),
                ("N", 15.0, 22.0, true),
                ("alpha", 0.0, 0.6, false)
            ]
        );
        // The worked example follows the documented affine map.
        for ((a, x), d) in card
            .action
            .ddp_action
            .iter()
            .zip(&card.action.ddp_physical)
            .zip(&card.action.dimensions)
        {
            let mapped = d.low + (a + 1.0) / 2.0 * (d.high - d.low);
            assert!((mapped - x).abs() < 1e-9, "{d:?}: {a} -> {x}");
        }
        assert_eq!(card.action.ddp_physical, [1.7, 2.0, 20.0, 0.0]);
        // The JSON round-trips and names the space as configuration files do.
        let json = serde_json::to_string(&card).unwrap();
        assert!(json.contains("\"space\":\"decremental\""), "{json}");
        assert_eq!(serde_json::from_str::<PolicyCard>(&json).unwrap(), card);

        let unconstrained = Td3Config {
            obs_dim: 746,
            act_dim: 20,
            ..Td3Config::default()
        };
        let card = PolicyCard::new(
            ActionSpace::Unconstrained,
            &manifest(unconstrained),
            &serde_json::Value::Null,
        )
        .unwrap();
        assert_eq!(card.observation.dim, 746);
        assert_eq!(card.action.dimensions.len(), 20);
    }

    #[test]
    fn card_refuses_sizes_that_do_not_fit_the_space() {
        let err = PolicyCard::new(
            ActionSpace::Unconstrained,
            &manifest(Td3Config::default()),
            &serde_json::Value::Null,
        )
        .unwrap_err();
        assert!(
            err.contains("act_dim = 4") && err.contains("unconstrained"),
            "{err}"
        );
        let small = Td3Config {
            obs_dim: 3,
            laser_dim: 0,
            ..Td3Config::default()
        };
        let err = PolicyCard::new(
            ActionSpace::Decremental,
            &manifest(small),
            &serde_json::Value::Null,
        )
        .unwrap_err();
        assert!(err.contains("obs_dim = 3") && err.contains("730 values"), "{err}");
    }

    /// The card carries the run's environment settings and documents the laser encoding with
    /// the run's clip, not the default one; settings that cannot be right are refused.
    #[test]
    fn card_documents_the_recorded_environment() {
        let laser = |card: &PolicyCard| card.observation.segments[0].encoding.clone();
        let env = serde_json::json!({ "agent_period_cycles": 4, "laser_clip_m": 4.5 });
        let card = PolicyCard::new(ActionSpace::Decremental, &manifest(Td3Config::default()), &env).unwrap();
        assert!(laser(&card).contains("min(r, 4.5) / 4.5"), "{}", laser(&card));
        assert_eq!(card.environment, env);
        let json = serde_json::to_string(&card).unwrap();
        assert_eq!(serde_json::from_str::<PolicyCard>(&json).unwrap(), card);

        // Not recorded (an older checkpoint): the default clip, and the card says `null`.
        let card = PolicyCard::new(
            ActionSpace::Decremental,
            &manifest(Td3Config::default()),
            &serde_json::Value::Null,
        )
        .unwrap();
        assert!(laser(&card).contains("min(r, 3) / 3"), "{}", laser(&card));
        assert!(card.environment.is_null());

        for bad in [
            serde_json::json!({ "laser_clip_m": -1.0 }),
            serde_json::json!({ "laser_clip_m": "far" }),
            serde_json::json!([1, 2]),
        ] {
            let err =
                PolicyCard::new(ActionSpace::Decremental, &manifest(Td3Config::default()), &bad).unwrap_err();
            assert!(err.contains("environment"), "{err}");
        }
    }
}
