//! A trained policy read from an export directory (`adp export`, the end of `adp train`:
//! [`JSON_FILE`] and the weights it names), checked against this build's environment: the
//! card's action space, observation layout and layer sizes, the weights read by
//! [`read_actor_safetensors`] (PyTorch's `[out, in]` layout transposed into the flat `[in][out]`
//! layout of [`MlpPolicy`], every value finite).
//!
//! Every error is one line naming the file and the problem.

use std::path::{Path, PathBuf};

use policy_file::{read_actor_safetensors, space_name, PolicyCard, JSON_FILE};
use settings::{ActionSpace, EnvConfig};

use crate::mlp::MlpPolicy;
use crate::observation;

/// A trained policy read from an export directory.
#[derive(Debug)]
pub struct LearnedPolicy {
    /// The action space it was trained in (`action.space` of the card).
    pub space: ActionSpace,
    /// The actor network, ready for [`MlpPolicy::act`].
    pub net: MlpPolicy,
    /// The environment settings it was trained with (the card's `environment`; the defaults
    /// for a card that does not record them): its agent period and laser clip shape what it
    /// sees, so it is run with them.
    pub env: EnvConfig,
    /// The card as read (source run, step counters).
    pub card: PolicyCard,
    /// The card's path.
    pub card_path: PathBuf,
}

/// Why a policy was not loaded: the file at fault and what is wrong with it, in one line.
#[derive(Debug, thiserror::Error)]
#[error("policy {}: {message}", path.display())]
pub struct LoadError {
    /// The file at fault.
    pub path: PathBuf,
    /// What is wrong with it.
    pub message: String,
}

impl LoadError {
    fn new(path: &Path, message: impl Into<String>) -> Self {
        Self {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// The card of the export `path` names: its [`JSON_FILE`] when `path` is a directory, `path`
/// itself when it is a `.json` file; `None` for any other file (not an export: `adp eval`
/// reads it as a constant action). A `.onnx` or `.safetensors` file is refused: the card
/// describes the weights, so the directory (or the card) must be given.
pub fn card_path(path: &Path) -> Result<Option<PathBuf>, LoadError> {
    if path.is_dir() {
        return Ok(Some(path.join(JSON_FILE)));
    }
    match path.extension().and_then(|e| e.to_str()) {
        Some("json") => Ok(Some(path.to_path_buf())),
        Some("onnx" | "safetensors") => Err(LoadError::new(
            path,
            format!("give the export directory (or its {JSON_FILE}), which describes the weights"),
        )),
        _ => Ok(None),
    }
}

/// Reads and checks the card at `card_path` and the weights it names (see the module docs).
/// `requested` is the action space the caller runs (`adp eval --action`), when it names one:
/// the policy's must then be the same.
pub fn load(card_path: &Path, requested: Option<ActionSpace>) -> Result<LearnedPolicy, LoadError> {
    let dir = card_path.parent().unwrap_or(Path::new("."));
    let bad = |what: String| LoadError::new(card_path, what);
    let text = std::fs::read_to_string(card_path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => bad(format!(
            "not found (an export directory of `adp export` or `adp train` holds {JSON_FILE} \
             and the weights)"
        )),
        _ => bad(format!("cannot read: {e}")),
    })?;
    let card = PolicyCard::parse(&text).map_err(|e| bad(e.to_string()))?;
    let space = card.action.space;
    if let Some(r) = requested.filter(|&r| r != space) {
        return Err(bad(format!(
            "the policy was trained in the {} action space but --action is {} (leave --action \
             out to use the policy's)",
            space_name(space),
            space_name(r)
        )));
    }
    if card.action.dim != space.dim() {
        return Err(bad(format!(
            "action.dim = {} but the {} action space has {} values",
            card.action.dim,
            space_name(space),
            space.dim()
        )));
    }
    // Cards written before simulator profiles existed were trained on what is now `ideal`;
    // before the action map and reward scale existed, on the affine box and raw rewards.
    let mut recorded = match &card.environment {
        serde_json::Value::Null => serde_json::json!({}),
        other => other.clone(),
    };
    if let Some(map) = recorded.as_object_mut() {
        map.entry("profile").or_insert_with(|| "ideal".into());
        map.entry("action_map").or_insert_with(|| "affine".into());
        map.entry("reward_scale").or_insert_with(|| 1.0.into());
    }
    let env = serde_json::from_value::<EnvConfig>(recorded)
        .map_err(|e| e.to_string())
        .and_then(|env| env.validate().map(|()| env).map_err(|e| e.to_string()))
        .map_err(|e| bad(format!("environment: {e}")))?;
    let laser = env.observation;
    let want = observation::segments(laser, space, env.observe_tracks);
    let layout_fits = card.observation.dim == observation::obs_dim(laser, space, env.observe_tracks)
        && card.observation.segments.len() == want.len()
        && card
            .observation
            .segments
            .iter()
            .zip(&want)
            .all(|(got, w)| got.name == w.name && got.offset == w.offset && got.size == w.size);
    if !layout_fits {
        let sizes: Vec<String> = card
            .observation
            .segments
            .iter()
            .map(|s| format!("{} {}", s.name, s.size))
            .collect();
        return Err(bad(format!(
            "observation of {} values ({}) does not fit the {} action space's observation of {} \
             values ({} laser: environment observation = \"{laser}\"; {} previous action, v, w, \
             local goal, global goal, {} tracks: environment observe_tracks = {})",
            card.observation.dim,
            sizes.join(", "),
            space_name(space),
            observation::obs_dim(laser, space, env.observe_tracks),
            laser.size(),
            space.dim(),
            observation::TRACK_FLOATS * env.observe_tracks,
            env.observe_tracks
        )));
    }
    let dims = &card.network.layer_sizes;
    if dims.len() < 2
        || dims.contains(&0)
        || dims[0] != card.observation.dim
        || dims[dims.len() - 1] != card.action.dim
    {
        return Err(bad(format!(
            "network.layer_sizes {dims:?} must run from observation.dim = {} to action.dim = {}, \
             all sizes > 0",
            card.observation.dim, card.action.dim
        )));
    }
    let activations = (
        card.network.hidden_activation.as_str(),
        card.network.output_activation.as_str(),
    );
    if activations != ("relu", "tanh") {
        return Err(bad(format!(
            "activations {activations:?}: this build runs relu hidden layers and a tanh output"
        )));
    }
    let weights_path = dir.join(&card.network.safetensors_file);
    let flat = read_weights(&weights_path, dims)?;
    let net = MlpPolicy::from_flat(dims, flat).map_err(|e| LoadError::new(&weights_path, e.to_string()))?;
    Ok(LearnedPolicy {
        space,
        net,
        env,
        card,
        card_path: card_path.to_path_buf(),
    })
}

/// Reads the weights file `path` for the layer sizes `dims` in [`MlpPolicy`]'s flat layout
/// (see [`read_actor_safetensors`]).
fn read_weights(path: &Path, dims: &[usize]) -> Result<Vec<f32>, LoadError> {
    let bad = |what: String| LoadError::new(path, what);
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    read_actor_safetensors(&bytes, dims).map_err(|e| bad(e.to_string()))
}
