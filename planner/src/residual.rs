//! PADP's learned residual corrector of the Kalman forecast (KFRes, Eq. 3 of Wang and Yang's
//! PADP paper, `/work/shared/papers/padp-kalman-prediction-complexity-adaptive.md`): a small
//! MLP reads a track's filtered state, its covariance traces and its last five position
//! increments, and outputs a correction of the constant-velocity forecast at PADP's 7
//! prediction steps of [`STEP_S`] = 0.4 s; the corrected forecast is
//! `o(t + tau) = o(t) + v tau + alpha c r(tau)` with the curvature gate
//! `c = 1(chi >= chi_th)`.
//!
//! - **History** ([`History`]): per track, the last [`HISTORY_LEN`] = 6 estimated positions,
//!   sampled at scan times at least [`STEP_S`] apart (the first scan at or after 0.4 s since
//!   the last sample), so that its 5 increments span about 2 s, as the paper's 5 steps of
//!   0.4 s do. A fixed array: pushing never allocates.
//! - **Track frame** ([`TrackFrame`]): the believed frame rotated so that +x is the track's
//!   filtered velocity (the believed frame itself for a track at rest). The features and the
//!   residual are expressed in it: they depend on neither where the track is nor which way it
//!   goes, only on how its motion bends.
//! - **Features** ([`Features`]), fixed layout of [`FEATURES`] = 13 values:
//!   `[0]` speed `|v|` (m/s; the velocity in the track frame is `(|v|, 0)`), `[1]` trace of
//!   the position covariance (m^2), `[2]` trace of the velocity covariance ((m/s)^2),
//!   `[3 + 2 i]`, `[4 + 2 i]` for `i = 0..5` the increments between consecutive history
//!   samples, oldest first, in the track frame (along, across), each rescaled to one step of
//!   0.4 s (`(p_{i+1} - p_i) 0.4 / (t_{i+1} - t_i)`, m), so that scan timing does not matter.
//! - **Curvature** ([`History::curvature`]): `chi` = the absolute heading change (rad, in
//!   [0, pi]) between the first and the last increment of the history; 0 when the history is
//!   not full yet or either increment is shorter than [`MIN_INCREMENT_M`] (a track at rest
//!   has no heading: the gate stays closed).
//! - **Network** ([`Mlp`]): dense layers, ReLU on the hidden ones, linear output of
//!   [`OUTPUTS`] = 14 values: the residual at steps 1..=7 as (along, across) pairs in the
//!   track frame, in units of the file's `target_scale` (m); inputs are normalized by the
//!   file's feature mean and standard deviation.
//! - **Correction** ([`Corrector::correction`]): closed (`None`) when `chi < threshold_rad`;
//!   otherwise each step's residual times the gain, its length clipped to `clip_m`, turned
//!   back into the believed frame ([`Correction`]). Between the steps it is interpolated
//!   linearly in `tau`, from 0 at `tau = 0`; past the last step (2.8 s) the last step's
//!   correction is held.
//!
//! The paper's settings: gain 0.75, threshold 0.22 rad, and a clip of 2.4 grid cells per
//! step, which is [`PAPER_CLIP_M`] = 0.888 m here: its cells are converted to metres the way
//! the predictive cost field's scales are (`configs/eval.toml`, `[prediction.field]`), by the
//! ratio of the robot radii, the paper's 0.90 cells to the Jackal's 0.333 m (0.37 m per
//! cell). The corrector file ([`CorrectorFile`], JSON) carries its network, normalization,
//! these settings and how it was trained.
//!
//! With no corrector, or with the gate closed, nothing is added: the forecast is the
//! constant-velocity one, bit for bit.

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use sim::geometry::{wrap_angle, Vec2};

/// PADP's prediction steps `N_p`.
pub const STEPS: usize = 7;
/// Time between prediction steps (s).
pub const STEP_S: f64 = 0.4;
/// Positions a [`History`] keeps.
pub const HISTORY_LEN: usize = 6;
/// Increments of a full history.
pub const INCREMENTS: usize = HISTORY_LEN - 1;
/// Length of the feature vector ([`Features`]).
pub const FEATURES: usize = 3 + 2 * INCREMENTS;
/// Outputs of the network: (along, across) per step.
pub const OUTPUTS: usize = 2 * STEPS;
/// Shortest increment (m per step) that has a heading: 0.05 m/s.
pub const MIN_INCREMENT_M: f64 = 0.02;
/// The paper's residual gain `alpha`.
pub const PAPER_GAIN: f64 = 0.75;
/// The paper's curvature threshold `chi_th` (rad).
pub const PAPER_THRESHOLD_RAD: f64 = 0.22;
/// The paper's clip of 2.4 grid cells per step in metres: 2.4 x 0.333 m / 0.90 (see the
/// module documentation).
pub const PAPER_CLIP_M: f64 = 0.888;
/// The `format` of a corrector file.
pub const FORMAT: &str = "adp-kf-residual/1";

/// Slack on the sampling interval of a [`History`] (s): scan times are sums of floats.
const SAMPLE_SLACK_S: f64 = 1e-6;

/// The last [`HISTORY_LEN`] positions of a track, at scan times at least [`STEP_S`] apart,
/// oldest first (believed frame). Plain data; pushing never allocates.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct History {
    times: [f64; HISTORY_LEN],
    points: [Vec2; HISTORY_LEN],
    len: usize,
}

impl History {
    /// Records the position `p` (m) estimated at time `t` (s, non-decreasing) unless the last
    /// sample is less than [`STEP_S`] older; the oldest sample leaves a full history.
    pub fn push(&mut self, t: f64, p: Vec2) {
        if self.len > 0 && t - self.times[self.len - 1] < STEP_S - SAMPLE_SLACK_S {
            return;
        }
        if self.len == HISTORY_LEN {
            self.times.copy_within(1.., 0);
            self.points.copy_within(1.., 0);
            self.len -= 1;
        }
        self.times[self.len] = t;
        self.points[self.len] = p;
        self.len += 1;
    }

    /// The samples so far, oldest first: (time (s), position (m)).
    pub fn samples(&self) -> impl Iterator<Item = (f64, Vec2)> + '_ {
        self.times[..self.len]
            .iter()
            .copied()
            .zip(self.points[..self.len].iter().copied())
    }

    /// Time of the newest sample (s), if any.
    pub fn last_time(&self) -> Option<f64> {
        self.len.checked_sub(1).map(|i| self.times[i])
    }

    /// Whether it holds [`HISTORY_LEN`] samples.
    pub fn is_full(&self) -> bool {
        self.len == HISTORY_LEN
    }

    /// The increments of a full history (believed frame, m), oldest first, each rescaled to
    /// one step of [`STEP_S`].
    pub fn increments(&self) -> Option<[Vec2; INCREMENTS]> {
        self.is_full().then(|| {
            std::array::from_fn(|i| {
                let dt = self.times[i + 1] - self.times[i];
                (self.points[i + 1] - self.points[i]) * (STEP_S / dt)
            })
        })
    }

    /// The recent motion curvature `chi` (rad, in [0, pi]): the absolute heading change from
    /// the first increment to the last; 0 when the history is not full or either of them is
    /// shorter than [`MIN_INCREMENT_M`].
    pub fn curvature(&self) -> f64 {
        let Some(inc) = self.increments() else {
            return 0.0;
        };
        let (a, b) = (inc[0], inc[INCREMENTS - 1]);
        if a.norm() < MIN_INCREMENT_M || b.norm() < MIN_INCREMENT_M {
            return 0.0;
        }
        wrap_angle(b.y.atan2(b.x) - a.y.atan2(a.x)).abs()
    }
}

/// The believed frame rotated so that +x is a track's velocity (the believed frame itself for
/// a velocity of zero).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackFrame {
    cos: f64,
    sin: f64,
}

impl TrackFrame {
    /// The frame of a track moving with `velocity` (believed frame).
    pub fn of(velocity: Vec2) -> Self {
        let speed = velocity.norm();
        if speed > 0.0 {
            Self {
                cos: velocity.x / speed,
                sin: velocity.y / speed,
            }
        } else {
            Self { cos: 1.0, sin: 0.0 }
        }
    }

    /// A believed-frame vector in this frame.
    pub fn to_track(&self, v: Vec2) -> Vec2 {
        Vec2::new(self.cos * v.x + self.sin * v.y, -self.sin * v.x + self.cos * v.y)
    }

    /// A vector of this frame in the believed frame.
    pub fn to_believed(&self, v: Vec2) -> Vec2 {
        Vec2::new(self.cos * v.x - self.sin * v.y, self.sin * v.x + self.cos * v.y)
    }
}

/// A track's input to the corrector (layout in the module documentation), its frame and its
/// curvature.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Features {
    /// The feature vector.
    pub values: [f64; FEATURES],
    /// The track frame the values (and the residual) are expressed in.
    pub frame: TrackFrame,
    /// `chi` ([`History::curvature`], rad).
    pub curvature: f64,
}

impl Features {
    /// The features of a track with filtered `velocity` (m/s, believed frame), position and
    /// velocity covariance traces (m^2, (m/s)^2) and `history`; `None` until the history is
    /// full.
    pub fn of(
        velocity: Vec2,
        position_variance: f64,
        velocity_variance: f64,
        history: &History,
    ) -> Option<Self> {
        let inc = history.increments()?;
        let frame = TrackFrame::of(velocity);
        let mut values = [0.0; FEATURES];
        values[0] = velocity.norm();
        values[1] = position_variance;
        values[2] = velocity_variance;
        for (i, d) in inc.iter().enumerate() {
            let local = frame.to_track(*d);
            values[3 + 2 * i] = local.x;
            values[4 + 2 * i] = local.y;
        }
        Some(Self {
            values,
            frame,
            curvature: history.curvature(),
        })
    }
}

/// The correction added to the constant-velocity forecast at the prediction steps
/// (`steps[k]` at `tau = (k + 1) STEP_S`; m, in the frame of its forecast).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Correction {
    /// The correction at steps 1..=7.
    pub steps: [Vec2; STEPS],
}

impl Correction {
    /// The correction `tau` seconds after the estimate: 0 for `tau <= 0`, linear between 0 at
    /// `tau = 0` and the steps, the last step's from [`STEPS`] x [`STEP_S`] = 2.8 s on.
    #[inline]
    pub fn at(&self, tau: f64) -> Vec2 {
        if tau.is_nan() || tau <= 0.0 {
            return Vec2::default();
        }
        let x = tau / STEP_S;
        if x >= STEPS as f64 {
            return self.steps[STEPS - 1];
        }
        let k = x as usize;
        let f = x - k as f64;
        let a = if k == 0 {
            Vec2::default()
        } else {
            self.steps[k - 1]
        };
        a + (self.steps[k] - a) * f
    }

    /// The same correction rotated by `angle` (rad), for a forecast seen in a rotated frame.
    pub fn rotated(&self, angle: f64) -> Self {
        Self {
            steps: self.steps.map(|v| v.rotated(angle)),
        }
    }
}

/// One dense layer: `y = W x + b`, `W` row-major (`outputs` rows of `inputs`).
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// Input width.
    pub inputs: usize,
    /// Output width.
    pub outputs: usize,
    /// `outputs x inputs` weights, row-major.
    pub weights: Vec<f64>,
    /// `outputs` biases.
    pub biases: Vec<f64>,
}

impl Layer {
    /// `y = W x + b`, then ReLU when `relu`; `x` has `inputs` values, `y` `outputs`.
    #[inline]
    pub fn apply(&self, x: &[f64], y: &mut [f64], relu: bool) {
        for (o, out) in y.iter_mut().enumerate() {
            let row = &self.weights[o * self.inputs..(o + 1) * self.inputs];
            let s = row.iter().zip(x).fold(self.biases[o], |s, (w, v)| s + w * v);
            *out = if relu { s.max(0.0) } else { s };
        }
    }
}

/// A multilayer perceptron: ReLU after every layer but the last.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    /// The layers, input first.
    pub layers: Vec<Layer>,
}

/// The buffers of [`Mlp::forward`]: two of the widest layer's width.
#[derive(Clone, Debug, Default)]
pub struct MlpScratch {
    a: Vec<f64>,
    b: Vec<f64>,
}

impl Mlp {
    /// A network of layer widths `sizes` (input first, at least two), seeded: weights
    /// uniform in `+-sqrt(6 / inputs)` (He, for ReLU), the last layer's scaled by 0.1 so the
    /// initial output is near 0; biases 0.
    pub fn seeded(sizes: &[usize], seed: u64) -> Self {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let n = sizes.len() - 1;
        let layers = (0..n)
            .map(|l| {
                let (inputs, outputs) = (sizes[l], sizes[l + 1]);
                let bound = (6.0 / inputs as f64).sqrt() * if l + 1 == n { 0.1 } else { 1.0 };
                Layer {
                    inputs,
                    outputs,
                    weights: (0..inputs * outputs)
                        .map(|_| rng.random_range(-bound..bound))
                        .collect(),
                    biases: vec![0.0; outputs],
                }
            })
            .collect();
        Self { layers }
    }

    /// The layer widths, input first.
    pub fn sizes(&self) -> Vec<usize> {
        let mut s = vec![self.layers[0].inputs];
        s.extend(self.layers.iter().map(|l| l.outputs));
        s
    }

    /// Buffers for [`Mlp::forward`] (the only allocation of inference).
    pub fn scratch(&self) -> MlpScratch {
        let width = self
            .layers
            .iter()
            .map(|l| l.inputs.max(l.outputs))
            .max()
            .unwrap_or(0);
        MlpScratch {
            a: vec![0.0; width],
            b: vec![0.0; width],
        }
    }

    /// The output for input `x` (as many values as the first layer's inputs), computed in
    /// `scratch` (from [`Mlp::scratch`] of this network). Does not allocate.
    pub fn forward<'s>(&self, x: &[f64], scratch: &'s mut MlpScratch) -> &'s [f64] {
        let (mut a, mut b) = (&mut scratch.a, &mut scratch.b);
        a[..x.len()].copy_from_slice(x);
        let last = self.layers.len() - 1;
        for (l, layer) in self.layers.iter().enumerate() {
            layer.apply(&a[..layer.inputs], &mut b[..layer.outputs], l < last);
            std::mem::swap(&mut a, &mut b);
        }
        &a[..self.layers[last].outputs]
    }
}

/// How a corrector was trained, for the record (the corrector does not use it).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedWith {
    /// The samples file.
    pub data: String,
    /// Worlds of the training samples.
    pub train_worlds: Vec<usize>,
    /// Worlds of the validation samples.
    pub val_worlds: Vec<usize>,
    /// Training and validation samples.
    pub samples: [usize; 2],
    /// Seed of the initialization, the split and the shuffling.
    pub seed: u64,
    /// Passes over the training samples.
    pub epochs: usize,
    /// Samples per Adam step.
    pub batch: usize,
    /// Adam's step size.
    pub learning_rate: f64,
    /// Validation RMSE per step of the constant-velocity forecast and of the gated corrected
    /// one (m).
    pub val_rmse_m: [[f64; STEPS]; 2],
}

/// A corrector file (JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorrectorFile {
    /// Must be [`FORMAT`].
    pub format: String,
    /// Layer widths, input first: [`FEATURES`], the hidden widths, [`OUTPUTS`].
    pub layers: Vec<usize>,
    /// Each layer's weights, row-major (outputs x inputs).
    pub weights: Vec<Vec<f32>>,
    /// Each layer's biases.
    pub biases: Vec<Vec<f32>>,
    /// Mean of each feature over the training samples.
    pub feature_mean: Vec<f64>,
    /// Standard deviation of each feature (> 0).
    pub feature_std: Vec<f64>,
    /// Metres per unit of the network's outputs (> 0).
    pub target_scale: f64,
    /// Residual gain `alpha` (>= 0).
    pub gain: f64,
    /// Curvature threshold `chi_th` (rad, >= 0).
    pub threshold_rad: f64,
    /// Longest correction per step (m, > 0).
    pub clip_m: f64,
    /// How it was trained.
    pub trained: TrainedWith,
}

/// Why a corrector file cannot be used; the message names the file and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("corrector {file}: {why}")]
pub struct CorrectorError {
    /// The file (or the name of an embedded one).
    pub file: String,
    /// What is wrong.
    pub why: String,
}

/// The residual corrector: its network, normalization and settings (module documentation).
/// Shared read-only by every episode; each keeps its own [`CorrectorScratch`].
#[derive(Clone, Debug, PartialEq)]
pub struct Corrector {
    net: Mlp,
    feature_mean: [f64; FEATURES],
    feature_std: [f64; FEATURES],
    target_scale: f64,
    /// Residual gain `alpha`.
    pub gain: f64,
    /// Curvature threshold `chi_th` (rad).
    pub threshold_rad: f64,
    /// Longest correction per step (m).
    pub clip_m: f64,
    /// How it was trained.
    pub trained: TrainedWith,
}

/// The buffers of one episode's corrections.
#[derive(Clone, Debug)]
pub struct CorrectorScratch {
    input: [f64; FEATURES],
    net: MlpScratch,
}

impl Corrector {
    /// Reads and checks the corrector file at `path`.
    pub fn load(path: &Path) -> Result<Self, CorrectorError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| CorrectorError {
            file: name.clone(),
            why: format!("cannot read: {e}"),
        })?;
        Self::from_json(&text, &name)
    }

    /// Parses and checks a corrector file's text; `name` names it in errors.
    pub fn from_json(text: &str, name: &str) -> Result<Self, CorrectorError> {
        let file: CorrectorFile = serde_json::from_str(text).map_err(|e| CorrectorError {
            file: name.to_string(),
            why: format!("not a corrector file: {e}"),
        })?;
        Self::from_file(file, name)
    }

    /// Checks a parsed corrector file; `name` names it in errors.
    pub fn from_file(f: CorrectorFile, name: &str) -> Result<Self, CorrectorError> {
        let err = |why: String| CorrectorError {
            file: name.to_string(),
            why,
        };
        if f.format != FORMAT {
            return Err(err(format!("format {:?}, expected {FORMAT:?}", f.format)));
        }
        let n = f.layers.len();
        if n < 2 || f.layers[0] != FEATURES || f.layers[n - 1] != OUTPUTS {
            return Err(err(format!(
                "layers {:?}: must start with {FEATURES} inputs and end with {OUTPUTS} outputs",
                f.layers
            )));
        }
        if f.layers.contains(&0) {
            return Err(err(format!("layers {:?}: a layer of width 0", f.layers)));
        }
        if f.weights.len() != n - 1 || f.biases.len() != n - 1 {
            return Err(err(format!(
                "{} weight and {} bias arrays for {} layers",
                f.weights.len(),
                f.biases.len(),
                n - 1
            )));
        }
        let mut layers = Vec::with_capacity(n - 1);
        for l in 0..n - 1 {
            let (inputs, outputs) = (f.layers[l], f.layers[l + 1]);
            if f.weights[l].len() != inputs * outputs || f.biases[l].len() != outputs {
                return Err(err(format!(
                    "layer {l} ({inputs} -> {outputs}) has {} weights and {} biases, expected {} and {outputs}",
                    f.weights[l].len(),
                    f.biases[l].len(),
                    inputs * outputs
                )));
            }
            if !f.weights[l].iter().chain(&f.biases[l]).all(|v| v.is_finite()) {
                return Err(err(format!("layer {l} has a value that is not finite")));
            }
            layers.push(Layer {
                inputs,
                outputs,
                weights: f.weights[l].iter().map(|&w| f64::from(w)).collect(),
                biases: f.biases[l].iter().map(|&b| f64::from(b)).collect(),
            });
        }
        let stats = |key: &str, v: &[f64], positive: bool| -> Result<[f64; FEATURES], CorrectorError> {
            let a: [f64; FEATURES] = v
                .try_into()
                .map_err(|_| err(format!("{key} has {} values, expected {FEATURES}", v.len())))?;
            if let Some(i) = a.iter().position(|x| !x.is_finite() || (positive && *x <= 0.0)) {
                let need = if positive { "finite and > 0" } else { "finite" };
                return Err(err(format!("{key}[{i}] = {}: must be {need}", a[i])));
            }
            Ok(a)
        };
        let feature_mean = stats("feature_mean", &f.feature_mean, false)?;
        let feature_std = stats("feature_std", &f.feature_std, true)?;
        for (key, value, positive) in [
            ("target_scale", f.target_scale, true),
            ("gain", f.gain, false),
            ("threshold_rad", f.threshold_rad, false),
            ("clip_m", f.clip_m, true),
        ] {
            if !(value.is_finite() && (value > 0.0 || (!positive && value == 0.0))) {
                let need = if positive { "> 0" } else { ">= 0" };
                return Err(err(format!("{key} = {value}: must be finite and {need}")));
            }
        }
        Ok(Self {
            net: Mlp { layers },
            feature_mean,
            feature_std,
            target_scale: f.target_scale,
            gain: f.gain,
            threshold_rad: f.threshold_rad,
            clip_m: f.clip_m,
            trained: f.trained,
        })
    }

    /// A corrector of `net` (whose outputs are in units of `target_scale` m) with the
    /// feature normalization and settings given (checked as a file's are).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        net: Mlp,
        feature_mean: [f64; FEATURES],
        feature_std: [f64; FEATURES],
        target_scale: f64,
        gain: f64,
        threshold_rad: f64,
        clip_m: f64,
        trained: TrainedWith,
    ) -> Result<Self, CorrectorError> {
        let c = Self {
            net,
            feature_mean,
            feature_std,
            target_scale,
            gain,
            threshold_rad,
            clip_m,
            trained,
        };
        Self::from_file(c.to_file(), "(in memory)").map(|_| c)
    }

    /// The file of this corrector (weights rounded to `f32`).
    pub fn to_file(&self) -> CorrectorFile {
        CorrectorFile {
            format: FORMAT.to_string(),
            layers: self.net.sizes(),
            weights: self
                .net
                .layers
                .iter()
                .map(|l| l.weights.iter().map(|&w| w as f32).collect())
                .collect(),
            biases: self
                .net
                .layers
                .iter()
                .map(|l| l.biases.iter().map(|&b| b as f32).collect())
                .collect(),
            feature_mean: self.feature_mean.to_vec(),
            feature_std: self.feature_std.to_vec(),
            target_scale: self.target_scale,
            gain: self.gain,
            threshold_rad: self.threshold_rad,
            clip_m: self.clip_m,
            trained: self.trained.clone(),
        }
    }

    /// The network.
    pub fn net(&self) -> &Mlp {
        &self.net
    }

    /// Buffers for one episode's corrections.
    pub fn scratch(&self) -> CorrectorScratch {
        CorrectorScratch {
            input: [0.0; FEATURES],
            net: self.net.scratch(),
        }
    }

    /// The network's residual for `values` (features), ungated and unscaled by the gain: per
    /// step (along, across) in the track frame (m). Does not allocate.
    pub fn residual(&self, values: &[f64; FEATURES], scratch: &mut CorrectorScratch) -> [Vec2; STEPS] {
        for (i, x) in scratch.input.iter_mut().enumerate() {
            *x = (values[i] - self.feature_mean[i]) / self.feature_std[i];
        }
        let out = self.net.forward(&scratch.input, &mut scratch.net);
        std::array::from_fn(|k| Vec2::new(out[2 * k], out[2 * k + 1]) * self.target_scale)
    }

    /// The step correction applied for a residual `r` (m): `gain x r`, its length clipped to
    /// `clip_m`.
    pub fn applied(&self, r: Vec2) -> Vec2 {
        let c = r * self.gain;
        let n = c.norm();
        if n > self.clip_m {
            c * (self.clip_m / n)
        } else {
            c
        }
    }

    /// The correction of a track with `features` (believed frame): `None` when the gate is
    /// closed (`chi < threshold_rad`). Does not allocate.
    pub fn correction(&self, features: &Features, scratch: &mut CorrectorScratch) -> Option<Correction> {
        if features.curvature < self.threshold_rad {
            return None;
        }
        let r = self.residual(&features.values, scratch);
        Some(Correction {
            steps: r.map(|v| features.frame.to_believed(self.applied(v))),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A full history of positions `p(t)` at t = 0, 0.4, ..., 2.0 s.
    fn history(p: impl Fn(f64) -> Vec2) -> History {
        let mut h = History::default();
        for k in 0..HISTORY_LEN {
            let t = k as f64 * STEP_S;
            h.push(t, p(t));
        }
        h
    }

    /// A 13-64-64-14 corrector of `seed` with identity normalization and the paper's settings.
    fn corrector(seed: u64) -> Corrector {
        Corrector::new(
            Mlp::seeded(&[FEATURES, 64, 64, OUTPUTS], seed),
            [0.0; FEATURES],
            [1.0; FEATURES],
            1.0,
            PAPER_GAIN,
            PAPER_THRESHOLD_RAD,
            PAPER_CLIP_M,
            TrainedWith::default(),
        )
        .unwrap()
    }

    #[test]
    fn a_two_two_one_network_by_hand() {
        // Hidden: relu(1 x0 - 2 x1 + 0.5), relu(-1 x0 + 1 x1 + 0); output: 2 h0 - 3 h1 + 1.
        let net = Mlp {
            layers: vec![
                Layer {
                    inputs: 2,
                    outputs: 2,
                    weights: vec![1.0, -2.0, -1.0, 1.0],
                    biases: vec![0.5, 0.0],
                },
                Layer {
                    inputs: 2,
                    outputs: 1,
                    weights: vec![2.0, -3.0],
                    biases: vec![1.0],
                },
            ],
        };
        let mut s = net.scratch();
        // x = (3, 1): h = (relu(1.5), relu(-2)) = (1.5, 0); y = 3 + 1 = 4.
        assert_eq!(net.forward(&[3.0, 1.0], &mut s), &[4.0]);
        // x = (0, 2): h = (relu(-3.5), relu(2)) = (0, 2); y = -6 + 1 = -5.
        assert_eq!(net.forward(&[0.0, 2.0], &mut s), &[-5.0]);
        assert_eq!(net.sizes(), vec![2, 2, 1]);
    }

    #[test]
    fn the_curvature_of_straight_turning_and_standing_tracks() {
        let straight = history(|t| Vec2::new(1.0 + 0.8 * t, -2.0 + 0.6 * t));
        assert!(straight.curvature() < 1e-12, "{}", straight.curvature());
        // On a circle of radius 2 m at 1 m/s: the chord directions of the first and the last
        // 0.4 s turn by the angle travelled between their midpoints, 4 x 0.4 s x 0.5 rad/s.
        let turning = history(|t| Vec2::new(2.0 * (0.5 * t).cos(), 2.0 * (0.5 * t).sin()));
        assert!(
            (turning.curvature() - 0.8).abs() < 1e-12,
            "{}",
            turning.curvature()
        );
        // Turning the other way gives the same (absolute) curvature.
        let mirrored = history(|t| Vec2::new(2.0 * (0.5 * t).cos(), -2.0 * (0.5 * t).sin()));
        assert!((mirrored.curvature() - 0.8).abs() < 1e-12);
        // A track at rest, jittering by millimetres, has no heading.
        let standing = history(|t| Vec2::new(3.0 + 0.003 * (7.0 * t).sin(), 0.002 * t));
        assert_eq!(standing.curvature(), 0.0);
        // Not full yet: no increments, no curvature.
        let mut young = History::default();
        young.push(0.0, Vec2::default());
        young.push(0.4, Vec2::new(1.0, 0.0));
        assert_eq!(young.increments(), None);
        assert_eq!(young.curvature(), 0.0);
    }

    #[test]
    fn the_history_samples_every_step_and_keeps_the_last_six() {
        let mut h = History::default();
        // Scans every 0.05 s for 3 s: samples at 0, 0.4, ..., 2.8 s; the last six kept.
        for k in 0..=60 {
            let t = k as f64 * 0.05;
            h.push(t, Vec2::new(t, 0.0));
        }
        let times: Vec<f64> = h.samples().map(|s| s.0).collect();
        let expected = [1.2, 1.6, 2.0, 2.4, 2.8];
        assert_eq!(times.len(), HISTORY_LEN);
        for (t, e) in times[1..].iter().zip(expected) {
            assert!((t - e).abs() < 1e-9, "{times:?}");
        }
        // Increments are rescaled to 0.4 s: 0.4 m each at 1 m/s whatever the sampling.
        let mut uneven = History::default();
        for (k, t) in [0.0, 0.45, 0.85, 1.3, 1.7, 2.25].iter().enumerate() {
            uneven.push(*t, Vec2::new(*t, k as f64 * 0.0));
        }
        for d in uneven.increments().unwrap() {
            assert!((d.x - 0.4).abs() < 1e-12 && d.y == 0.0, "{d:?}");
        }
    }

    #[test]
    fn features_are_in_the_track_frame() {
        // Moving +y at 1 m/s: the increments are (0.4, 0) along the motion.
        let h = history(|t| Vec2::new(5.0, t));
        let f = Features::of(Vec2::new(0.0, 1.0), 0.01, 0.2, &h).unwrap();
        assert_eq!(&f.values[..3], &[1.0, 0.01, 0.2]);
        for i in 0..INCREMENTS {
            assert!((f.values[3 + 2 * i] - 0.4).abs() < 1e-12);
            assert!(f.values[4 + 2 * i].abs() < 1e-12);
        }
        // The frame turns track-frame vectors back: +x (along) is +y believed.
        let v = f.frame.to_believed(Vec2::new(1.0, 0.0));
        assert!((v - Vec2::new(0.0, 1.0)).norm() < 1e-12);
        assert_eq!(f.frame.to_track(v), Vec2::new(1.0, 0.0));
        assert!(Features::of(Vec2::default(), 0.0, 0.0, &History::default()).is_none());
    }

    #[test]
    fn a_straight_track_gets_exactly_the_kalman_forecast() {
        let c = corrector(3);
        let mut s = c.scratch();
        let straight = history(|t| Vec2::new(t, 0.5 * t));
        let f = Features::of(Vec2::new(1.0, 0.5), 0.01, 0.1, &straight).unwrap();
        assert_eq!(c.correction(&f, &mut s), None, "the gate is closed");
        // A turning one passes the gate: a correction, none of its steps longer than the clip.
        let turning = history(|t| Vec2::new(2.0 * (0.5 * t).cos(), 2.0 * (0.5 * t).sin()));
        let f = Features::of(Vec2::new(0.0, 1.0), 0.01, 0.1, &turning).unwrap();
        let corr = c.correction(&f, &mut s).expect("the gate is open");
        assert!(corr.steps.iter().all(|v| v.norm() <= PAPER_CLIP_M + 1e-12));
        assert!(corr.steps.iter().any(|v| v.norm() > 0.0));
        // It is the network's residual x gain, turned from the track frame (+x = +y).
        let r = c.residual(&f.values, &mut s);
        let want = f.frame.to_believed(c.applied(r[3]));
        assert_eq!(corr.steps[3], want);
    }

    #[test]
    fn the_gain_and_the_clip() {
        let c = corrector(1);
        // 0.75 x (0.4, 0.3) = (0.3, 0.225): under the clip, kept.
        let a = c.applied(Vec2::new(0.4, 0.3));
        assert!((a - Vec2::new(0.3, 0.225)).norm() < 1e-15);
        // 0.75 x (3, 4) is 3.75 m long: cut to 0.888 m in the same direction.
        let a = c.applied(Vec2::new(3.0, 4.0));
        assert!((a.norm() - PAPER_CLIP_M).abs() < 1e-12);
        assert!((a - Vec2::new(0.6, 0.8) * PAPER_CLIP_M).norm() < 1e-12);
    }

    #[test]
    fn the_correction_is_interpolated_in_tau() {
        let steps = std::array::from_fn(|k| Vec2::new(k as f64 + 1.0, -2.0 * (k as f64 + 1.0)));
        let c = Correction { steps };
        assert_eq!(c.at(0.0), Vec2::default());
        assert_eq!(c.at(-1.0), Vec2::default());
        // Halfway to step 1: half of it.
        assert!((c.at(0.2) - Vec2::new(0.5, -1.0)).norm() < 1e-12);
        // At the steps, the steps; between 2 and 3 a quarter of the way.
        assert!((c.at(0.8) - steps[1]).norm() < 1e-12);
        assert!((c.at(0.9) - Vec2::new(2.25, -4.5)).norm() < 1e-12);
        // From 2.8 s on the last is held.
        assert!((c.at(2.8) - steps[6]).norm() < 1e-12);
        assert_eq!(c.at(2.81), steps[6]);
        assert_eq!(c.at(10.0), steps[6]);
        // Rotated by 90 degrees: (x, y) -> (-y, x).
        let r = c.rotated(std::f64::consts::FRAC_PI_2);
        assert!((r.at(0.4) - Vec2::new(2.0, 1.0)).norm() < 1e-12);
    }

    #[test]
    fn a_malformed_file_is_named_with_its_fault() {
        let good = corrector(5).to_file();
        let text = serde_json::to_string(&good).unwrap();
        let back = Corrector::from_json(&text, "c.json").unwrap();
        assert_eq!(back.to_file(), good, "round trip");
        let fault = |edit: &dyn Fn(&mut CorrectorFile)| {
            let mut f = good.clone();
            edit(&mut f);
            Corrector::from_file(f, "c.json").unwrap_err().to_string()
        };
        let e = fault(&|f| f.layers[0] = 12);
        assert!(e.starts_with("corrector c.json: layers [12, 64, 64, 14]"), "{e}");
        let e = fault(&|f| {
            f.weights[1].pop();
        });
        assert!(e.contains("layer 1 (64 -> 64) has 4095 weights"), "{e}");
        let e = fault(&|f| f.feature_std[4] = 0.0);
        assert!(e.contains("feature_std[4] = 0: must be finite and > 0"), "{e}");
        let e = fault(&|f| f.clip_m = -1.0);
        assert!(e.contains("clip_m = -1"), "{e}");
        let e = fault(&|f| f.format = "v0".into());
        assert!(e.contains("format \"v0\""), "{e}");
        let e = Corrector::from_json("{\"format\": 1}", "bad.json")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("corrector bad.json: not a corrector file"), "{e}");
        let e = Corrector::load(Path::new("/nonexistent/c.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/c.json: cannot read"), "{e}");
    }
}
