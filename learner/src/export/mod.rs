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
//!
//! Files: `onnx` (the ONNX graph), `weights` (the safetensors writer); the card, the
//! safetensors reader and the file names are the [`policy_file`] crate's (re-exported here),
//! which a runtime reads policies with without linking the learner; the observation layout
//! the card documents is the shared one of the [`layout`] crate.

mod onnx;
mod weights;

use std::path::{Path, PathBuf};

use burn::tensor::Device;
use settings::ActionSpace;
use thiserror::Error;

pub use onnx::{actor_onnx, BATCH_DIM, INPUT_NAME, IR_VERSION, OPSET, OUTPUT_NAME};
pub use policy_file::{
    observation_layout, read_actor_safetensors, space_name, ActionCard, ActionDimension, CardError,
    CardMismatch, NetworkCard, ObservationLayout, ObservationSegment, PolicyCard, Software, Source,
    TrainedFor, WeightsError, CARD_FORMAT, CARD_FORMAT_VERSION, JSON_FILE, ONNX_FILE, SAFETENSORS_FILE,
};
pub use weights::actor_safetensors;

use crate::checkpoint::{self, CheckpointError, Manifest};

/// A checkpoint's manifest is what a card records of the checkpoint ([`PolicyCard::new`]).
impl From<&Manifest> for policy_file::Checkpoint {
    fn from(manifest: &Manifest) -> Self {
        Self {
            source: Source {
                run_id: manifest.run_id.clone(),
                updates: manifest.updates,
                inserts: manifest.inserts,
                policy_version: manifest.policy_version,
            },
            obs_dim: manifest.config.obs_dim,
            laser_dim: manifest.config.laser_dim,
            act_dim: manifest.config.act_dim,
            actor_hidden: manifest.config.actor_hidden.clone(),
        }
    }
}

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
        #[source]
        what: CardMismatch,
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
    /// The weights of a published policy do not fit the checkpoint's actor.
    #[error("export: the policy's {got} weights do not fit the actor of checkpoint {} ({expected} parameters)", checkpoint.display())]
    Weights {
        /// The checkpoint whose actor sizes were expected.
        checkpoint: PathBuf,
        /// Its actor's number of parameters.
        expected: usize,
        /// The number given.
        got: usize,
    },
    /// The card of an export directory cannot be read back.
    #[error("export {}: {what}", path.display())]
    Card {
        /// The card.
        path: PathBuf,
        /// Why it was not read.
        #[source]
        what: CardError,
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
    export(checkpoint, out, space, None)
}

/// A policy a run published, as its flat weights (the layout of
/// [`crate::nets::Actor::flat_weights`]) with the counters of when it was taken: what
/// [`export_published`] writes in place of a checkpoint's actor.
#[derive(Debug, Clone, Copy)]
pub struct Published<'a> {
    /// The flat weights.
    pub weights: &'a [f32],
    /// Its policy version.
    pub policy_version: u64,
    /// Agent steps stored when it was taken.
    pub inserts: u64,
    /// Gradient updates done when it was taken.
    pub updates: u64,
}

/// Like [`export_checkpoint`], with the actor's weights replaced by `policy`'s and the card's
/// step counters by its: the export of a policy the run published earlier than its last
/// checkpoint (held-out selection). The checkpoint gives everything else (run id, network
/// sizes, environment); `policy` must have its actor's number of parameters.
pub fn export_published(
    checkpoint: &Path,
    out: &Path,
    space: ActionSpace,
    policy: &Published<'_>,
) -> Result<ExportSummary, ExportError> {
    export(checkpoint, out, space, Some(policy))
}

/// [`export_checkpoint`], or [`export_published`] with `published`.
fn export(
    checkpoint: &Path,
    out: &Path,
    space: ActionSpace,
    published: Option<&Published<'_>>,
) -> Result<ExportSummary, ExportError> {
    let mut manifest = checkpoint::read_manifest(checkpoint)?;
    let (td3, run) = checkpoint::load(checkpoint, &Device::flex())?;
    let mut actor = td3.policy();
    if let Some(p) = published {
        let expected = actor.flat_weights().1.len();
        actor = actor
            .with_flat_weights(p.weights)
            .ok_or_else(|| ExportError::Weights {
                checkpoint: checkpoint.to_path_buf(),
                expected,
                got: p.weights.len(),
            })?;
        manifest.policy_version = p.policy_version;
        manifest.inserts = p.inserts;
        manifest.updates = p.updates;
    }
    let card = PolicyCard::new(space, &manifest, &run.environment).map_err(|what| ExportError::Mismatch {
        file: checkpoint.join(checkpoint::MANIFEST),
        what,
    })?;

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

/// Records in the card of the export directory `dir` what the policy was trained for (the
/// trainer's export knows only the checkpoint, so `adp train` and `adp export` add the run's
/// planner and speed cap after it): rewrites [`JSON_FILE`] with `trained_for` set, leaving
/// the weights alone. Returns the card written.
pub fn record_trained_for(dir: &Path, trained_for: TrainedFor) -> Result<PolicyCard, ExportError> {
    let path = dir.join(JSON_FILE);
    let text = std::fs::read_to_string(&path).map_err(|source| ExportError::Io {
        op: "read",
        path: path.clone(),
        source,
    })?;
    let mut card = PolicyCard::parse(&text).map_err(|what| ExportError::Card {
        path: path.clone(),
        what,
    })?;
    card.trained_for = Some(trained_for);
    let mut json = serde_json::to_vec_pretty(&card).expect("the card serializes");
    json.push(b'\n');
    write_file(&path, &json)?;
    Ok(card)
}

#[cfg(test)]
mod tests {
    use std::collections::{BTreeMap, HashMap};

    use prost::Message;
    use rand::Rng;
    use safetensors::tensor::Dtype;
    use tract_onnx::prelude::*;

    use super::onnx::proto as onnx;
    use super::*;
    use crate::checkpoint::Manifest;
    use crate::config::Td3Config;
    use crate::nets::Actor;
    use crate::td3::seeded_rng;

    /// The learner's observation layout (network input size, card) is the shared layout's
    /// (which the actor builds), value for value, in every action space.
    #[test]
    fn the_learners_observation_layout_is_the_actors() {
        let c = Td3Config::default();
        assert_eq!(
            (c.obs_dim, c.laser_dim, c.act_dim),
            (
                layout::obs_dim(layout::LaserLayout::Scan, ActionSpace::Decremental.dim(), 0),
                layout::LASER_BEAMS,
                ActionSpace::Decremental.dim()
            )
        );
        for space in [
            ActionSpace::Decremental,
            ActionSpace::Incremental,
            ActionSpace::Unconstrained,
            ActionSpace::Fixed,
            ActionSpace::Weights(settings::Gains::System),
            ActionSpace::DecrementalWeights(settings::Gains::Dwa),
            ActionSpace::Velocity,
        ] {
            for (tracks, laser) in [
                (0, layout::LaserLayout::Scan),
                (4, layout::LaserLayout::Scan),
                (4, layout::LaserLayout::Sectors(15)),
            ] {
                let card = observation_layout(laser, space, layout::DEFAULT_LASER_CLIP_M, tracks);
                let card_segments: Vec<(&str, usize, usize)> = card
                    .segments
                    .iter()
                    .map(|s| (s.name.as_str(), s.offset, s.size))
                    .collect();
                let layout_segments: Vec<(&str, usize, usize)> = layout::segments(laser, space.dim(), tracks)
                    .iter()
                    .map(|s| (s.name, s.offset, s.size))
                    .collect();
                assert_eq!(card_segments, layout_segments, "{space:?}");
                assert_eq!(card.dim, layout::obs_dim(laser, space.dim(), tracks), "{space:?}");
            }
        }
    }

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

    /// A published policy's weights replace the checkpoint's actor in the export, with its
    /// counters in the card; weights of another size are refused by name.
    #[test]
    fn export_published_writes_the_given_weights_and_counters() {
        let dir = std::env::temp_dir().join(format!("adp-export-published-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let config = Td3Config {
            actor_hidden: vec![8],
            critic_hidden: vec![8],
            ..Td3Config::default()
        };
        let td3 = crate::td3::Td3::new(config.clone(), &Device::flex()).unwrap();
        let run = checkpoint::RunState {
            run_id: "run-p".into(),
            rate: crate::rate::RateLimiter::new(&config),
            sampler_rng: seeded_rng(1, 2),
            policy_version: 9,
            extra: serde_json::Value::Null,
            environment: serde_json::Value::Null,
        };
        let ckpt = dir.join("ckpt");
        std::fs::create_dir_all(&dir).unwrap();
        checkpoint::save(&ckpt, &td3, &run).unwrap();
        let other = Actor::new(730, &[8], 4, &Device::flex(), &mut seeded_rng(77, 0));
        let (_, weights) = other.flat_weights();
        let published = Published {
            weights: &weights,
            policy_version: 2,
            inserts: 500,
            updates: 40,
        };
        let out = dir.join("export");
        let summary = export_published(&ckpt, &out, ActionSpace::Decremental, &published).unwrap();
        let s = &summary.card.source;
        assert_eq!(
            (s.run_id.as_str(), s.policy_version, s.inserts, s.updates),
            ("run-p", 2, 500, 40)
        );
        let bytes = std::fs::read(out.join(SAFETENSORS_FILE)).unwrap();
        let back = read_actor_safetensors(&bytes, &[730, 8, 4]).unwrap();
        assert_eq!(back, weights);
        let short = Published {
            weights: &weights[1..],
            ..published
        };
        let e = export_published(&ckpt, &out, ActionSpace::Decremental, &short)
            .unwrap_err()
            .to_string();
        assert!(e.contains("weights do not fit") && e.contains("ckpt"), "{e}");
        // The card says nothing of the planner until told; once told, it reads back, the
        // weights untouched.
        assert_eq!(summary.card.trained_for, None);
        let trained_for = TrainedFor {
            planner: settings::PlannerKind::Mppi,
            max_speed: 1.5,
        };
        let card = record_trained_for(&out, trained_for).unwrap();
        let text = std::fs::read_to_string(out.join(JSON_FILE)).unwrap();
        assert!(
            text.contains("\"trained_for\"") && text.contains("\"mppi\""),
            "{text}"
        );
        assert_eq!(PolicyCard::parse(&text).unwrap(), card);
        assert_eq!(card.trained_for, Some(trained_for));
        assert_eq!(std::fs::read(out.join(SAFETENSORS_FILE)).unwrap(), bytes);
        let e = record_trained_for(&dir, trained_for).unwrap_err().to_string();
        assert!(e.contains("read") && e.contains(JSON_FILE), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
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

    /// A run that observed 4 tracks records it in its environment settings; its card's
    /// layout ends with the 16-float tracks segment, and a bad count is refused by name.
    #[test]
    fn card_records_the_observed_tracks() {
        let with_tracks = Td3Config {
            obs_dim: 746,
            ..Td3Config::default()
        };
        let env = serde_json::json!({ "observe_tracks": 4 });
        let card = PolicyCard::new(ActionSpace::Decremental, &manifest(with_tracks.clone()), &env).unwrap();
        assert_eq!(card.observation.dim, 746);
        let last = card.observation.segments.last().unwrap();
        assert_eq!((last.name.as_str(), last.offset, last.size), ("tracks", 730, 16));
        assert!(last.encoding.contains("4 nearest"), "{}", last.encoding);
        // The same checkpoint without the setting does not fit the layout.
        let err = PolicyCard::new(
            ActionSpace::Decremental,
            &manifest(with_tracks.clone()),
            &serde_json::Value::Null,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("obs_dim = 746") && err.contains("730 values"),
            "{err}"
        );
        let bad = serde_json::json!({ "observe_tracks": -1 });
        let err = PolicyCard::new(ActionSpace::Decremental, &manifest(with_tracks), &bad)
            .unwrap_err()
            .to_string();
        assert!(err.contains("observe_tracks = -1"), "{err}");
    }

    /// A run with the `sectors:25` laser layout records it; its card's laser segment has 25
    /// values documented as sector minima, and a checkpoint sized for another layout, or a
    /// layout that is none, is refused by name.
    #[test]
    fn card_records_the_laser_layout() {
        let sectors = Td3Config {
            obs_dim: 35,
            laser_dim: 25,
            ..Td3Config::default()
        };
        let env = serde_json::json!({ "observation": "sectors:25" });
        let card = PolicyCard::new(ActionSpace::Decremental, &manifest(sectors.clone()), &env).unwrap();
        assert_eq!(card.observation.dim, 35);
        let laser = &card.observation.segments[0];
        assert_eq!((laser.name.as_str(), laser.size), ("laser", 25));
        assert!(laser.encoding.contains("25 equal sectors"), "{}", laser.encoding);
        assert_eq!(card.observation.segments[1].offset, 25);
        assert_eq!(card.environment, env);
        // The 730-input checkpoint does not fit it, nor the 35-input one the default layout.
        let err = PolicyCard::new(ActionSpace::Decremental, &manifest(Td3Config::default()), &env)
            .unwrap_err()
            .to_string();
        assert_eq!(
            err,
            "obs_dim = 730 with laser_dim = 720 does not fit the observation layout of the decremental \
             action space with the sectors:25 laser layout (35 values, 25 of them laser)"
        );
        let err = PolicyCard::new(
            ActionSpace::Decremental,
            &manifest(sectors.clone()),
            &serde_json::Value::Null,
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("with the scan laser layout (730 values"), "{err}");
        let bad = serde_json::json!({ "observation": "sectors:0" });
        let err = PolicyCard::new(ActionSpace::Decremental, &manifest(sectors), &bad)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("observation = \"sectors:0\" is not a laser layout"),
            "{err}"
        );
    }

    #[test]
    fn card_refuses_sizes_that_do_not_fit_the_space() {
        let err = PolicyCard::new(
            ActionSpace::Unconstrained,
            &manifest(Td3Config::default()),
            &serde_json::Value::Null,
        )
        .unwrap_err()
        .to_string();
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
        .unwrap_err()
        .to_string();
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
            let err = PolicyCard::new(ActionSpace::Decremental, &manifest(Td3Config::default()), &bad)
                .unwrap_err()
                .to_string();
            assert!(err.contains("environment"), "{err}");
        }
    }

    /// The objective-weight and velocity spaces name every output and its range in the card,
    /// and the card reads back with the same space.
    #[test]
    fn card_names_gains_and_the_velocity_command() {
        let card_of = |space: ActionSpace| {
            let config = Td3Config {
                obs_dim: layout::obs_dim(layout::LaserLayout::Scan, space.dim(), 0),
                act_dim: space.dim(),
                ..Td3Config::default()
            };
            PolicyCard::new(space, &manifest(config), &serde_json::Value::Null).unwrap()
        };
        let space = ActionSpace::DecrementalWeights(settings::Gains::Mppi);
        let card = card_of(space);
        let dims: Vec<(&str, f64, f64)> = card
            .action
            .dimensions
            .iter()
            .map(|d| (d.name.as_str(), d.low, d.high))
            .collect();
        assert_eq!(
            dims[4..],
            [
                ("w_goal", 0.0, 2.0),
                ("w_path", 0.0, 2.0),
                ("w_obstacle", 0.0, 2.0),
                ("w_heading", 0.0, 2.0),
                ("w_smooth", 0.0, 2.0)
            ]
        );
        assert_eq!(card.action.dim, 9);
        assert_eq!(card.observation.dim, 735);
        assert_eq!(card.action.ddp_physical[4..], [1.0; 5]);
        assert!(
            card.action.schedule.contains("factor on the"),
            "{}",
            card.action.schedule
        );
        let json = serde_json::to_value(&card).unwrap();
        assert_eq!(json["action"]["space"], "decremental+weights:mppi");
        assert_eq!(serde_json::from_value::<PolicyCard>(json).unwrap(), card);

        let card = card_of(ActionSpace::Velocity);
        let dims: Vec<(&str, f64, f64)> = card
            .action
            .dimensions
            .iter()
            .map(|d| (d.name.as_str(), d.low, d.high))
            .collect();
        assert_eq!(dims, [("v_frac", 0.0, 1.0), ("w", -2.0, 2.0)]);
        assert_eq!(card.network.layer_sizes, [728, 512, 512, 2]);
        assert!(card.action.schedule.contains("v = v_frac * max_speed"));
    }
}
