//! The JSON card of an exported policy: what it holds, how it is made, and how it is read back.

use layout::{LaserLayout, DEFAULT_LASER_CLIP_M, MAX_OBSERVED_TRACKS, MAX_SECTORS};
use serde::{Deserialize, Serialize};
use settings::{ActionSpace, PlannerKind};
use thiserror::Error;

use crate::{CARD_FORMAT, CARD_FORMAT_VERSION, INPUT_NAME, ONNX_FILE, OPSET, OUTPUT_NAME, SAFETENSORS_FILE};

/// The JSON card of an exported policy ([`crate::JSON_FILE`]).
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
    /// config: `agent_period_cycles` planner cycles per action, `laser_clip_m`, the laser
    /// layout `observation`, rewards), so it
    /// can be run as it was trained; `null` when the checkpoint did not record them (the
    /// defaults applied).
    #[serde(default)]
    pub environment: serde_json::Value,
    /// The planner and speed cap the policy was trained with; absent from cards written
    /// before they were recorded (and from an `adp export` not told them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trained_for: Option<TrainedFor>,
}

/// What a policy was trained for besides its action space (`action.space`) and observation
/// (`observation`, `environment`): the planner whose schedule it chose and the runs' speed cap.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedFor {
    /// The planner (`dwa`, `mppi`, `log-mppi`, `system`).
    pub planner: PlannerKind,
    /// The speed cap of the training runs (m/s): the `[run] max_speed` of its configuration.
    pub max_speed: f64,
}

/// What a card records of the checkpoint its weights come from ([`PolicyCard::new`]): the
/// learner makes it from its checkpoint's manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    /// The run and its counters when the checkpoint was written.
    pub source: Source,
    /// The actor's input size.
    pub obs_dim: usize,
    /// How many of its inputs are the laser segment.
    pub laser_dim: usize,
    /// The actor's output size.
    pub act_dim: usize,
    /// The actor's hidden layer widths, input side first.
    pub actor_hidden: Vec<usize>,
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
    /// The action space (`decremental`, `incremental`, `unconstrained`, `fixed`,
    /// `weights:<planner>`, `decremental+weights:<planner>` or `velocity`).
    pub space: ActionSpace,
    /// Number of action values.
    pub dim: usize,
    /// Every value the network outputs lies in `[-1, 1]`.
    pub normalized_range: [f64; 2],
    /// Each value's physical meaning and range.
    pub dimensions: Vec<ActionDimension>,
    /// How a normalized value becomes a physical one.
    pub to_physical: String,
    /// How the physical values become the planner's rollout schedule (and gains, or the
    /// command of the velocity space).
    pub schedule: String,
    /// The normalized action that reproduces DDP with the hand-tuned gains (ADP's initial
    /// policy), as a worked example; the box centre for the velocity space, which has no DDP.
    pub ddp_action: Vec<f64>,
    /// Its physical values.
    pub ddp_physical: Vec<f64>,
}

/// One action value's meaning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionDimension {
    /// Parameter name (`p`, `T`, `N`, `alpha`, `dt`, `check_density`; a gain's name such as
    /// `w_obstacle`, whose value is a factor on the configured weight; `v_frac`, the share of
    /// the speed cap, and `w`, rad/s, in the velocity space).
    pub name: String,
    /// Physical value at normalized -1.
    pub low: f64,
    /// Physical value at normalized +1.
    pub high: f64,
    /// Rounded to the nearest integer after scaling.
    pub integer: bool,
}

/// The observation layout of DESIGN §5 for the laser layout `laser` and `space`: the laser
/// values (720 ranges, or one per sector; clipped at `laser_clip_m`), the previous action, v,
/// w, (bearing, distance) to the local and the global goal, and, when `tracks > 0`, the
/// nearest `tracks` moving tracks.
pub fn observation_layout(
    laser: LaserLayout,
    space: ActionSpace,
    laser_clip_m: f64,
    tracks: usize,
) -> ObservationLayout {
    let segments = layout::segments(laser, space.dim(), tracks)
        .iter()
        .map(|s| ObservationSegment {
            name: s.name.into(),
            offset: s.offset,
            size: s.size,
            encoding: s.encoding(laser, laser_clip_m),
        })
        .collect();
    ObservationLayout {
        dim: layout::obs_dim(laser, space.dim(), tracks),
        segments,
    }
}

/// The action space's name as in configuration files and the card (`decremental`,
/// `weights:dwa`, ...: [`ActionSpace::name`]).
pub fn space_name(space: ActionSpace) -> String {
    space.name()
}

/// How `space`'s physical values make a rollout schedule, set the planner's gains or drive
/// the robot (mirrors `planner::action`).
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
        ActionSpace::Weights(_) => {
            "the DDP schedule (p = 1.7, T = 2 s, N = 20, alpha = 0); each gain value is a factor on \
             the planner's configured objective weight of that name (1 = the hand-tuned weight, \
             0 = the term off, 2 = doubled), set before the agent step's first planning cycle"
        }
        ActionSpace::DecrementalWeights(_) => {
            "p, T, N, alpha make the decremental schedule (boundary times t_i = alpha (i/N) T + \
             (1 - alpha) (i/N)^p T, step i collision-checks round(n (1 - (i/N)^p)) of the \
             footprint's n boundary points); each following gain value is a factor on the \
             planner's configured objective weight of that name (1 = the hand-tuned weight)"
        }
        ActionSpace::Velocity => {
            "no planner and no schedule: the robot is commanded v = v_frac * max_speed (m/s, the \
             run's speed cap) and w (rad/s) every control period of the agent step"
        }
    }
}

/// Why a card was not read.
#[derive(Debug, Error)]
pub enum CardError {
    /// Not JSON, or not a card.
    #[error("{0}")]
    Parse(#[from] serde_json::Error),
    /// A card of another format or format version.
    #[error(
        "format {found:?} version {version}; this build reads {CARD_FORMAT:?} version {CARD_FORMAT_VERSION}"
    )]
    Format {
        /// Its `format`.
        found: String,
        /// Its `format_version`.
        version: u32,
    },
}

/// Why a checkpoint does not make a card for an action space ([`PolicyCard::new`]).
#[derive(Debug, Error)]
pub enum CardMismatch {
    /// The actor's output size is not the space's action size.
    #[error("act_dim = {act_dim} does not fit the {space} action space ({dim} values)")]
    ActDim {
        /// The checkpoint's `act_dim`.
        act_dim: usize,
        /// The action space.
        space: String,
        /// Its action size.
        dim: usize,
    },
    /// The actor's input does not match the space's observation layout.
    #[error(
        "obs_dim = {obs_dim} with laser_dim = {laser_dim} does not fit the observation layout of the \
         {space} action space with the {laser} laser layout ({dim} values, {laser_size} of them laser)"
    )]
    ObsDim {
        /// The checkpoint's `obs_dim`.
        obs_dim: usize,
        /// The checkpoint's `laser_dim`.
        laser_dim: usize,
        /// The action space.
        space: String,
        /// The recorded laser layout.
        laser: LaserLayout,
        /// Its observation size.
        dim: usize,
        /// Its laser values.
        laser_size: usize,
    },
    /// The recorded environment settings are not a table.
    #[error("the recorded environment settings are not a table: {0}")]
    Environment(serde_json::Value),
    /// The recorded laser clip is not a positive number.
    #[error("the recorded environment's laser_clip_m = {0} is not a positive number")]
    LaserClip(serde_json::Value),
    /// The recorded number of observed tracks is not an integer in range.
    #[error(
        "the recorded environment's observe_tracks = {0} is not an integer in 0..={max}",
        max = MAX_OBSERVED_TRACKS
    )]
    ObserveTracks(serde_json::Value),
    /// The recorded laser layout is not one.
    #[error(
        "the recorded environment's observation = {0} is not a laser layout (\"scan\" or \"sectors:N\" \
         with N in 1..={MAX_SECTORS})"
    )]
    Observation(serde_json::Value),
}

impl PolicyCard {
    /// Reads a card ([`crate::JSON_FILE`]) written by [`PolicyCard::new`], refusing other
    /// formats and format versions.
    pub fn parse(text: &str) -> Result<Self, CardError> {
        let card: Self = serde_json::from_str(text)?;
        if card.format != CARD_FORMAT || card.format_version != CARD_FORMAT_VERSION {
            return Err(CardError::Format {
                found: card.format,
                version: card.format_version,
            });
        }
        Ok(card)
    }

    /// The card for an actor trained in `space` with the environment settings `environment`
    /// (the run's `[env]` table as recorded, `null` when not), from `checkpoint` (the learner's
    /// `&Manifest` converts). Fails when the checkpoint's observation or action size does not
    /// fit `space` and the recorded laser layout (`observation`, `scan` when absent), or the
    /// settings are not a table with a positive `laser_clip_m`.
    pub fn new(
        space: ActionSpace,
        checkpoint: impl Into<Checkpoint>,
        environment: &serde_json::Value,
    ) -> Result<Self, CardMismatch> {
        let config = checkpoint.into();
        let laser = laser_layout(environment)?;
        let layout = observation_layout(
            laser,
            space,
            laser_clip_m(environment)?,
            observe_tracks(environment)?,
        );
        if config.act_dim != space.dim() {
            return Err(CardMismatch::ActDim {
                act_dim: config.act_dim,
                space: space_name(space),
                dim: space.dim(),
            });
        }
        if config.obs_dim != layout.dim || config.laser_dim != laser.size() {
            return Err(CardMismatch::ObsDim {
                obs_dim: config.obs_dim,
                laser_dim: config.laser_dim,
                space: space_name(space),
                laser,
                dim: layout.dim,
                laser_size: laser.size(),
            });
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
            source: config.source,
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
            trained_for: None,
        })
    }
}

/// The laser clip of recorded environment settings: their `laser_clip_m`, or [`DEFAULT_LASER_CLIP_M`]
/// when they are `null` or do not set it.
fn laser_clip_m(environment: &serde_json::Value) -> Result<f64, CardMismatch> {
    let table = match environment {
        serde_json::Value::Null => return Ok(DEFAULT_LASER_CLIP_M),
        serde_json::Value::Object(table) => table,
        other => return Err(CardMismatch::Environment(other.clone())),
    };
    match table.get("laser_clip_m") {
        None => Ok(DEFAULT_LASER_CLIP_M),
        Some(v) => v
            .as_f64()
            .filter(|c| c.is_finite() && *c > 0.0)
            .ok_or_else(|| CardMismatch::LaserClip(v.clone())),
    }
}

/// The recorded environment's `observe_tracks` (0 when absent, as in settings recorded before
/// tracks could be observed). `environment` is a table or null ([`laser_clip_m`] checks it).
fn observe_tracks(environment: &serde_json::Value) -> Result<usize, CardMismatch> {
    match environment.get("observe_tracks") {
        None => Ok(0),
        Some(v) => v
            .as_u64()
            .map(|k| k as usize)
            .filter(|&k| k <= MAX_OBSERVED_TRACKS)
            .ok_or_else(|| CardMismatch::ObserveTracks(v.clone())),
    }
}

/// The recorded environment's laser layout `observation` (`scan` when absent, as in settings
/// recorded before layouts existed). `environment` is a table or null ([`laser_clip_m`]
/// checks it).
fn laser_layout(environment: &serde_json::Value) -> Result<LaserLayout, CardMismatch> {
    match environment.get("observation") {
        None => Ok(LaserLayout::Scan),
        Some(v) => v
            .as_str()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| CardMismatch::Observation(v.clone())),
    }
}
