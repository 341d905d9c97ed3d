//! Data and training of the residual corrector ([`crate::residual`]): samples logged from
//! episodes ([`record_samples`]) and minibatch Adam on their mean squared error ([`fit`]).
//!
//! A [`Sample`] is one confirmed moving track at one update where its history took a new
//! sample (so every 0.4 s per track) and is full, following a moving cylinder (the nearest,
//! within 1 m, as [`ForecastErrors`] matches them): its features, its curvature, and the
//! target, where the cylinder really is at each of the 7 steps minus the constant-velocity
//! forecast, in the track frame ([`crate::residual::TrackFrame`], m). An update whose 7
//! steps cross the end of the cylinder's loop (where it jumps back) gives no sample.
//!
//! [`fit`] splits the samples by world (a seeded draw of `val_fraction` of the worlds, at
//! least one each way), normalizes the features by the training samples' mean and standard
//! deviation and the targets by one scale (their root mean square), and trains the network
//! (seeded initialization, seeded shuffling) on every training sample, gated or not. The
//! corrector it returns carries the gain, threshold and clip it is given; [`StepRmse`]
//! measures it as it will be applied.
//!
//! [`ForecastErrors`]: crate::moving::ForecastErrors

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use sim::geometry::Vec2;
use sim::Episode;

use crate::moving::{crosses_loop_end, followed_cylinder, Tracking};
use crate::residual::{Corrector, CorrectorError, Layer, Mlp, TrainedWith, FEATURES, OUTPUTS, STEPS, STEP_S};

/// One logged sample (module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sample {
    /// World id.
    pub world: usize,
    /// Simulated time of the update (s).
    pub time: f64,
    /// The track's id.
    pub track: u64,
    /// Its curvature `chi` (rad).
    pub curvature: f64,
    /// Its features ([`crate::residual::Features`]).
    pub features: [f64; FEATURES],
    /// The truth minus the constant-velocity forecast at steps 1..=7, (along, across) per
    /// step in the track frame (m).
    pub target: [f64; OUTPUTS],
}

/// Appends to `out` the samples of `tracking`'s last update, made at `ep`'s current time.
pub fn record_samples(ep: &Episode<'_>, tracking: &Tracking, out: &mut Vec<Sample>) {
    if ep.world().moving.is_empty() {
        return;
    }
    let now = ep.scene().time();
    for (tr, o) in tracking.moving_tracks().zip(tracking.moving_in_map()) {
        if tr.history().last_time() != Some(tr.time) {
            continue;
        }
        let Some(f) = tr.residual_features() else {
            continue;
        };
        let Some((cylinder, turn, p, v)) = followed_cylinder(ep, o) else {
            continue;
        };
        if crosses_loop_end(cylinder, now, STEPS as f64 * STEP_S) {
            continue;
        }
        let mut target = [0.0; OUTPUTS];
        for k in 0..STEPS {
            let h = (k + 1) as f64 * STEP_S;
            let miss = cylinder.at(now + h).c - (p + v * h);
            let local = f.frame.to_track(miss.rotated(-turn));
            target[2 * k] = local.x;
            target[2 * k + 1] = local.y;
        }
        out.push(Sample {
            world: ep.world().id,
            time: now,
            track: tr.id,
            curvature: f.curvature,
            features: f.values,
            target,
        });
    }
}

/// How [`fit`] trains.
#[derive(Clone, Debug, PartialEq)]
pub struct FitSettings {
    /// Seed of the initialization, the split and the shuffling.
    pub seed: u64,
    /// Passes over the training samples.
    pub epochs: usize,
    /// Samples per Adam step.
    pub batch: usize,
    /// Adam's step size.
    pub learning_rate: f64,
    /// Share of the worlds held out for validation.
    pub val_fraction: f64,
    /// Hidden layer widths (the paper: 64, 64).
    pub hidden: Vec<usize>,
    /// The corrector's gain, threshold (rad) and clip (m).
    pub gain: f64,
    /// See `gain`.
    pub threshold_rad: f64,
    /// See `gain`.
    pub clip_m: f64,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            epochs: 30,
            batch: 64,
            learning_rate: 1e-3,
            val_fraction: 0.2,
            hidden: vec![64, 64],
            gain: crate::residual::PAPER_GAIN,
            threshold_rad: crate::residual::PAPER_THRESHOLD_RAD,
            clip_m: crate::residual::PAPER_CLIP_M,
        }
    }
}

/// Why [`fit`] cannot train.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    /// A setting that cannot work.
    #[error("{0}")]
    Setting(String),
    /// Too few worlds or samples.
    #[error("{0}")]
    Data(String),
    /// The corrector it made does not check (a gain, threshold or clip out of range).
    #[error(transparent)]
    Corrector(#[from] CorrectorError),
}

/// Root mean square error per step (m) over a set of samples: of the constant-velocity
/// forecast, of the forecast corrected on every sample (ungated) and where the gate is open
/// (gated: the corrector as applied), with the share of the samples the gate opens on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StepRmse {
    /// Constant velocity.
    pub cv: [f64; STEPS],
    /// Corrected on every sample (gain and clip applied).
    pub ungated: [f64; STEPS],
    /// Corrected where the gate opens.
    pub gated: [f64; STEPS],
    /// Share of the samples where the gate opens.
    pub gated_share: f64,
    /// Samples.
    pub samples: usize,
}

impl StepRmse {
    /// Measures `corrector` on `samples`.
    pub fn of(corrector: &Corrector, samples: &[&Sample]) -> Self {
        let mut scratch = corrector.scratch();
        let (mut cv, mut ungated, mut gated) = ([0.0; STEPS], [0.0; STEPS], [0.0; STEPS]);
        let mut open = 0;
        for s in samples {
            let r = corrector.residual(&s.features, &mut scratch);
            let on = s.curvature >= corrector.threshold_rad;
            open += usize::from(on);
            for k in 0..STEPS {
                let t = Vec2::new(s.target[2 * k], s.target[2 * k + 1]);
                let fixed = t - corrector.applied(r[k]);
                cv[k] += t.dot(t);
                ungated[k] += fixed.dot(fixed);
                gated[k] += if on { fixed.dot(fixed) } else { t.dot(t) };
            }
        }
        let n = samples.len().max(1) as f64;
        let root = |a: [f64; STEPS]| a.map(|x| (x / n).sqrt());
        Self {
            cv: root(cv),
            ungated: root(ungated),
            gated: root(gated),
            gated_share: open as f64 / n,
            samples: samples.len(),
        }
    }
}

/// What [`fit`] made: the corrector, the loss per epoch and its validation errors.
#[derive(Clone, Debug)]
pub struct Fitted {
    /// The corrector.
    pub corrector: Corrector,
    /// Mean squared error (normalized targets) per epoch: (training, validation).
    pub losses: Vec<(f64, f64)>,
    /// Its errors on the validation samples.
    pub val: StepRmse,
}

/// The worlds of `samples`, split: (training, validation), each sorted; `val_fraction` of
/// them (rounded, at least one, at most all but one) drawn with `seed` for validation.
pub fn split_worlds(
    samples: &[Sample],
    val_fraction: f64,
    seed: u64,
) -> Result<(Vec<usize>, Vec<usize>), FitError> {
    let mut worlds: Vec<usize> = samples.iter().map(|s| s.world).collect();
    worlds.sort_unstable();
    worlds.dedup();
    if worlds.len() < 2 {
        return Err(FitError::Data(format!(
            "the samples come from {} world(s): a split by world needs at least 2",
            worlds.len()
        )));
    }
    let n_val = ((val_fraction * worlds.len() as f64).round() as usize).clamp(1, worlds.len() - 1);
    worlds.shuffle(&mut Pcg64Mcg::seed_from_u64(seed));
    let mut val = worlds.split_off(worlds.len() - n_val);
    worlds.sort_unstable();
    val.sort_unstable();
    Ok((worlds, val))
}

/// Gradients (or Adam moments) of every layer's weights and biases.
#[derive(Clone)]
struct Grads {
    w: Vec<Vec<f64>>,
    b: Vec<Vec<f64>>,
}

impl Grads {
    fn zeros(net: &Mlp) -> Self {
        Self {
            w: net.layers.iter().map(|l| vec![0.0; l.weights.len()]).collect(),
            b: net.layers.iter().map(|l| vec![0.0; l.biases.len()]).collect(),
        }
    }

    fn clear(&mut self) {
        self.w
            .iter_mut()
            .chain(self.b.iter_mut())
            .for_each(|v| v.fill(0.0));
    }
}

/// The activations of one forward pass and the backward pass's buffers.
struct Pass {
    acts: Vec<Vec<f64>>,
    delta: Vec<f64>,
    prev: Vec<f64>,
}

impl Pass {
    fn new(net: &Mlp) -> Self {
        let mut acts = vec![vec![0.0; net.layers[0].inputs]];
        acts.extend(net.layers.iter().map(|l| vec![0.0; l.outputs]));
        let width = acts.iter().map(Vec::len).max().unwrap_or(0);
        Self {
            acts,
            delta: vec![0.0; width],
            prev: vec![0.0; width],
        }
    }

    /// Forward pass of `x`; returns the output.
    fn forward(&mut self, net: &Mlp, x: &[f64]) -> &[f64] {
        self.acts[0].copy_from_slice(x);
        let last = net.layers.len() - 1;
        for (l, layer) in net.layers.iter().enumerate() {
            let (done, rest) = self.acts.split_at_mut(l + 1);
            layer.apply(&done[l], &mut rest[0], l < last);
        }
        &self.acts[last + 1]
    }

    /// Squared error of the last forward pass against `t`, and its gradient (scaled by
    /// `scale`) added to `g`.
    fn backward(&mut self, net: &Mlp, t: &[f64], scale: f64, g: &mut Grads) -> f64 {
        let n = net.layers.len();
        let mut loss = 0.0;
        for (o, (&y, &t)) in self.acts[n].iter().zip(t).enumerate() {
            loss += (y - t) * (y - t);
            self.delta[o] = 2.0 * (y - t) * scale;
        }
        for l in (0..n).rev() {
            let Layer {
                inputs,
                outputs,
                weights,
                ..
            } = &net.layers[l];
            let input = &self.acts[l];
            for o in 0..*outputs {
                let d = self.delta[o];
                g.b[l][o] += d;
                let row = &mut g.w[l][o * inputs..(o + 1) * inputs];
                for (gw, &a) in row.iter_mut().zip(input) {
                    *gw += d * a;
                }
            }
            if l == 0 {
                break;
            }
            for i in 0..*inputs {
                let back: f64 = (0..*outputs)
                    .map(|o| weights[o * inputs + i] * self.delta[o])
                    .sum();
                // ReLU: its input was positive exactly where its output is.
                self.prev[i] = if input[i] > 0.0 { back } else { 0.0 };
            }
            std::mem::swap(&mut self.delta, &mut self.prev);
        }
        loss
    }
}

/// Adam's moments and step count.
struct Adam {
    m: Grads,
    v: Grads,
    steps: i32,
}

impl Adam {
    const BETA1: f64 = 0.9;
    const BETA2: f64 = 0.999;
    const EPS: f64 = 1e-8;

    fn step(&mut self, net: &mut Mlp, g: &Grads, lr: f64) {
        self.steps += 1;
        let c1 = 1.0 - Self::BETA1.powi(self.steps);
        let c2 = 1.0 - Self::BETA2.powi(self.steps);
        for (l, layer) in net.layers.iter_mut().enumerate() {
            let params = [
                (&mut layer.weights, &g.w[l], &mut self.m.w[l], &mut self.v.w[l]),
                (&mut layer.biases, &g.b[l], &mut self.m.b[l], &mut self.v.b[l]),
            ];
            for (p, g, m, v) in params {
                for i in 0..p.len() {
                    m[i] = Self::BETA1 * m[i] + (1.0 - Self::BETA1) * g[i];
                    v[i] = Self::BETA2 * v[i] + (1.0 - Self::BETA2) * g[i] * g[i];
                    p[i] -= lr * (m[i] / c1) / ((v[i] / c2).sqrt() + Self::EPS);
                }
            }
        }
    }
}

/// Trains a corrector on `samples` (module documentation; `data` names them in the record),
/// calling `on_epoch(epoch, train_loss, val_loss)` after each epoch.
pub fn fit(
    samples: &[Sample],
    s: &FitSettings,
    data: &str,
    mut on_epoch: impl FnMut(usize, f64, f64),
) -> Result<Fitted, FitError> {
    if s.epochs == 0 || s.batch == 0 {
        return Err(FitError::Setting(format!(
            "epochs {} and batch {} must be at least 1",
            s.epochs, s.batch
        )));
    }
    if !(s.learning_rate.is_finite() && s.learning_rate > 0.0) {
        return Err(FitError::Setting(format!(
            "learning rate {} must be finite and > 0",
            s.learning_rate
        )));
    }
    if !(s.val_fraction > 0.0 && s.val_fraction < 1.0) {
        return Err(FitError::Setting(format!(
            "validation fraction {} must be in (0, 1)",
            s.val_fraction
        )));
    }
    if s.hidden.contains(&0) {
        return Err(FitError::Setting(format!(
            "hidden widths {:?} must be at least 1",
            s.hidden
        )));
    }
    let (train_worlds, val_worlds) = split_worlds(samples, s.val_fraction, s.seed)?;
    let (train, val): (Vec<&Sample>, Vec<&Sample>) = samples
        .iter()
        .partition(|x| train_worlds.binary_search(&x.world).is_ok());
    // Normalization from the training samples.
    let n = train.len() as f64;
    let mut mean = [0.0; FEATURES];
    let mut std = [0.0; FEATURES];
    for x in &train {
        for (m, f) in mean.iter_mut().zip(&x.features) {
            *m += f / n;
        }
    }
    for x in &train {
        for ((v, f), m) in std.iter_mut().zip(&x.features).zip(&mean) {
            *v += (f - m).powi(2) / n;
        }
    }
    let std = std.map(|v| v.sqrt().max(1e-6));
    let sq: f64 = train.iter().flat_map(|x| x.target.iter()).map(|t| t * t).sum();
    let scale = (sq / (n * OUTPUTS as f64)).sqrt().max(1e-6);
    let normalized = |x: &Sample| {
        let f: [f64; FEATURES] = std::array::from_fn(|i| (x.features[i] - mean[i]) / std[i]);
        let t: [f64; OUTPUTS] = x.target.map(|t| t / scale);
        (f, t)
    };
    let train_n: Vec<_> = train.iter().map(|x| normalized(x)).collect();
    let val_n: Vec<_> = val.iter().map(|x| normalized(x)).collect();

    let mut sizes = vec![FEATURES];
    sizes.extend(&s.hidden);
    sizes.push(OUTPUTS);
    let mut rng = Pcg64Mcg::seed_from_u64(s.seed);
    let mut net = Mlp::seeded(&sizes, rand::Rng::random(&mut rng));
    let mut pass = Pass::new(&net);
    let mut grads = Grads::zeros(&net);
    let mut adam = Adam {
        m: Grads::zeros(&net),
        v: Grads::zeros(&net),
        steps: 0,
    };
    let mean_loss = |net: &Mlp, pass: &mut Pass, set: &[([f64; FEATURES], [f64; OUTPUTS])]| {
        let mut sink = Grads::zeros(net);
        let total: f64 = set
            .iter()
            .map(|(f, t)| {
                pass.forward(net, f);
                pass.backward(net, t, 0.0, &mut sink)
            })
            .sum();
        total / (set.len().max(1) * OUTPUTS) as f64
    };
    let mut order: Vec<usize> = (0..train_n.len()).collect();
    let mut losses = Vec::with_capacity(s.epochs);
    for epoch in 0..s.epochs {
        order.shuffle(&mut rng);
        let mut total = 0.0;
        for chunk in order.chunks(s.batch) {
            grads.clear();
            let scale = 1.0 / (chunk.len() * OUTPUTS) as f64;
            for &i in chunk {
                let (f, t) = &train_n[i];
                pass.forward(&net, f);
                total += pass.backward(&net, t, scale, &mut grads);
            }
            adam.step(&mut net, &grads, s.learning_rate);
        }
        let train_loss = total / (train_n.len().max(1) * OUTPUTS) as f64;
        let val_loss = mean_loss(&net, &mut pass, &val_n);
        losses.push((train_loss, val_loss));
        on_epoch(epoch + 1, train_loss, val_loss);
    }
    let mut corrector = Corrector::new(
        net,
        mean,
        std,
        scale,
        s.gain,
        s.threshold_rad,
        s.clip_m,
        TrainedWith::default(),
    )?;
    // Measured as it will be loaded: with the file's f32 weights.
    corrector = Corrector::from_file(corrector.to_file(), "(fitted)")?;
    let val_rmse = StepRmse::of(&corrector, &val);
    corrector.trained = TrainedWith {
        data: data.to_string(),
        train_worlds,
        val_worlds,
        samples: [train.len(), val.len()],
        seed: s.seed,
        epochs: s.epochs,
        batch: s.batch,
        learning_rate: s.learning_rate,
        val_rmse_m: [val_rmse.cv, val_rmse.gated],
    };
    Ok(Fitted {
        corrector,
        losses,
        val: val_rmse,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::residual::{Features, History, HISTORY_LEN};
    use rand::Rng;

    /// Samples of obstacles on circles (radius 1.5 to 4 m, 0.5 to 1.5 m/s, either way) and,
    /// one in four, on straight lines, 10 worlds of 12 obstacles, observed every 0.4 s with
    /// 1 cm of position noise and the true velocity.
    fn circles(seed: u64) -> Vec<Sample> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut out = Vec::new();
        for obstacle in 0..120 {
            let world = obstacle % 10;
            let straight = obstacle % 4 == 0;
            let speed = rng.random_range(0.5..1.5);
            let radius: f64 = rng.random_range(1.5..4.0);
            let turn = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let omega = turn * speed / radius;
            let phase: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let at = |t: f64| {
                if straight {
                    Vec2::new(phase.cos(), phase.sin()) * (speed * t)
                } else {
                    let a = phase + omega * t;
                    Vec2::new(a.cos(), a.sin()) * radius
                }
            };
            let velocity = |t: f64| {
                if straight {
                    Vec2::new(phase.cos(), phase.sin()) * speed
                } else {
                    let a = phase + omega * t;
                    Vec2::new(-a.sin(), a.cos()) * (radius * omega)
                }
            };
            let mut h = History::default();
            for k in 0..30 {
                let t = k as f64 * STEP_S;
                let noise = Vec2::new(rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01));
                h.push(t, at(t) + noise);
                if k + 1 < HISTORY_LEN {
                    continue;
                }
                let v = velocity(t);
                let f = Features::of(v, 0.002, 0.05, &h).unwrap();
                let p = h.samples().last().unwrap().1;
                let mut target = [0.0; OUTPUTS];
                for s in 0..STEPS {
                    let tau = (s + 1) as f64 * STEP_S;
                    let miss = f.frame.to_track(at(t + tau) - (p + v * tau));
                    target[2 * s] = miss.x;
                    target[2 * s + 1] = miss.y;
                }
                out.push(Sample {
                    world,
                    time: t,
                    track: obstacle as u64,
                    curvature: f.curvature,
                    features: f.values,
                    target,
                });
            }
        }
        out
    }

    #[test]
    fn a_fit_on_circles_beats_constant_velocity_and_repeats_with_its_seed() {
        let samples = circles(7);
        let settings = FitSettings {
            seed: 3,
            epochs: 30,
            ..FitSettings::default()
        };
        let mut epochs = 0;
        let fitted = fit(&samples, &settings, "circles", |_, _, _| epochs += 1).unwrap();
        assert_eq!(epochs, 30);
        let (first, last) = (fitted.losses[0], *fitted.losses.last().unwrap());
        assert!(
            last.0 < 0.5 * first.0 && last.1 < 0.5 * first.1,
            "{:?}",
            fitted.losses
        );
        let v = fitted.val;
        // Two of the ten worlds validate; most samples turn past the threshold.
        assert_eq!(fitted.corrector.trained.val_worlds.len(), 2);
        assert!(v.gated_share > 0.5, "{v:?}");
        // 2.8 s ahead, the corrected forecast is well below constant velocity's.
        assert!(v.gated[6] < 0.6 * v.cv[6], "{v:?}");
        assert!(v.ungated[6] < 0.6 * v.cv[6], "{v:?}");
        // The same seed, the same corrector.
        let again = fit(&samples, &settings, "circles", |_, _, _| {}).unwrap();
        assert_eq!(again.corrector, fitted.corrector);
        assert_eq!(again.losses, fitted.losses);
    }

    #[test]
    fn worlds_are_split_not_samples() {
        let samples = circles(1);
        let (train, val) = split_worlds(&samples, 0.2, 4).unwrap();
        assert_eq!((train.len(), val.len()), (8, 2));
        assert!(train.iter().all(|w| !val.contains(w)));
        assert_eq!(split_worlds(&samples, 0.2, 4).unwrap(), (train, val));
        let one: Vec<Sample> = samples.iter().filter(|s| s.world == 3).copied().collect();
        let e = split_worlds(&one, 0.2, 4).unwrap_err().to_string();
        assert!(e.contains("1 world(s)"), "{e}");
        let bad = FitSettings {
            val_fraction: 1.0,
            ..FitSettings::default()
        };
        let e = fit(&samples, &bad, "x", |_, _, _| {}).unwrap_err().to_string();
        assert!(e.contains("validation fraction 1"), "{e}");
    }
}
