//! The TD3 networks: a tanh actor and twin ReLU critics (plain MLPs on the raw observation, as
//! in the reference), their seeded initialization and the Polyak update of target copies.

use burn::module::{Module, Param};
use burn::nn::Linear;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

/// A linear layer initialized like PyTorch's `nn.Linear` (weights and biases uniform in
/// `±1/sqrt(fan_in)`), drawn from `rng` so initialization is reproducible and independent of
/// burn's global RNG.
fn linear(fan_in: usize, fan_out: usize, device: &Device, rng: &mut Pcg64Mcg) -> Linear {
    let bound = 1.0 / (fan_in as f32).sqrt();
    let mut uniform = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-bound..bound)).collect() };
    // burn stores the weight as [d_input, d_output].
    let weight = uniform(fan_in * fan_out);
    let bias = uniform(fan_out);
    Linear {
        weight: Param::from_data(TensorData::new(weight, [fan_in, fan_out]), device),
        bias: Some(Param::from_data(TensorData::new(bias, [fan_out]), device)),
    }
}

/// Layers `sizes[0] -> sizes[1] -> ... -> sizes[last]`.
fn mlp(sizes: &[usize], device: &Device, rng: &mut Pcg64Mcg) -> Vec<Linear> {
    sizes
        .windows(2)
        .map(|w| linear(w[0], w[1], device, rng))
        .collect()
}

/// ReLU after every layer but the last.
fn forward_mlp(layers: &[Linear], mut x: Tensor<2>) -> Tensor<2> {
    let last = layers.len() - 1;
    for (i, layer) in layers.iter().enumerate() {
        x = layer.forward(x);
        if i < last {
            x = relu(x);
        }
    }
    x
}

/// `target <- (1 - tau) target + tau online`, layer by layer; `target` stays on its (plain)
/// device.
fn polyak_layers(target: Vec<Linear>, online: &[Linear], tau: f64) -> Vec<Linear> {
    fn mix<const D: usize>(t: Param<Tensor<D>>, o: &Param<Tensor<D>>, tau: f64) -> Param<Tensor<D>> {
        let o = o.val().inner();
        t.map(|t| t.mul_scalar(1.0 - tau) + o.mul_scalar(tau))
    }
    target
        .into_iter()
        .zip(online)
        .map(|(t, o)| Linear {
            weight: mix(t.weight, &o.weight, tau),
            bias: match (t.bias, &o.bias) {
                (Some(tb), Some(ob)) => Some(mix(tb, ob, tau)),
                (tb, _) => tb,
            },
        })
        .collect()
}

/// The deterministic policy `obs -> hidden (ReLU) ... -> act (tanh)`, actions in [-1, 1].
///
/// A burn module: cloning is cheap (tensors are reference counted) and a clone is an independent
/// value; `Send + Sync`. Use [`Module::valid`] for a copy without autodiff (what actors run).
#[derive(Module, Debug)]
pub struct Actor {
    layers: Vec<Linear>,
}

impl Actor {
    /// A freshly initialized actor `obs_dim -> hidden... -> act_dim` on `device`.
    pub fn new(
        obs_dim: usize,
        hidden: &[usize],
        act_dim: usize,
        device: &Device,
        rng: &mut Pcg64Mcg,
    ) -> Self {
        let sizes: Vec<usize> = [obs_dim]
            .iter()
            .chain(hidden)
            .chain(&[act_dim])
            .copied()
            .collect();
        Self {
            layers: mlp(&sizes, device, rng),
        }
    }

    /// Observation size.
    pub fn obs_dim(&self) -> usize {
        self.layers[0].weight.dims()[0]
    }

    /// Action size.
    pub fn act_dim(&self) -> usize {
        self.layers[self.layers.len() - 1].weight.dims()[1]
    }

    /// The linear layers, input side first (weights `[d_input, d_output]`, burn's layout).
    pub(crate) fn layers(&self) -> &[Linear] {
        &self.layers
    }

    /// Layer sizes, input first (`[obs_dim, hidden..., act_dim]`), and every parameter as one
    /// flat vector: per layer the weight `[in][out]` row-major (burn's layout, `y = x W + b`),
    /// then the bias. This is the layout actors load (`actor::policy::MlpPolicy::from_flat`)
    /// and that policy snapshots carry.
    pub fn flat_weights(&self) -> (Vec<usize>, Vec<f32>) {
        let mut dims = vec![self.obs_dim()];
        let mut flat = Vec::new();
        for layer in &self.layers {
            let [_, fan_out] = layer.weight.dims();
            dims.push(fan_out);
            flat.extend(tensor_values(layer.weight.val()));
            match &layer.bias {
                Some(b) => flat.extend(tensor_values(b.val())),
                None => flat.extend(std::iter::repeat_n(0.0, fan_out)),
            }
        }
        (dims, flat)
    }

    /// This actor's layers with the parameters of `flat` (the layout of
    /// [`Actor::flat_weights`], for the same layer sizes) on this actor's device: a policy
    /// that was published (and evaluated) as flat weights, as a network again. `None` when
    /// `flat` does not hold exactly this actor's number of parameters.
    pub fn with_flat_weights(&self, flat: &[f32]) -> Option<Self> {
        let device = self.device();
        let mut rest = flat;
        let mut layers = Vec::with_capacity(self.layers.len());
        for layer in &self.layers {
            let [fan_in, fan_out] = layer.weight.dims();
            if rest.len() < fan_in * fan_out + fan_out {
                return None;
            }
            let (weight, tail) = rest.split_at(fan_in * fan_out);
            let (bias, tail) = tail.split_at(fan_out);
            rest = tail;
            layers.push(Linear {
                weight: Param::from_data(TensorData::new(weight.to_vec(), [fan_in, fan_out]), &device),
                bias: Some(Param::from_data(
                    TensorData::new(bias.to_vec(), [fan_out]),
                    &device,
                )),
            });
        }
        rest.is_empty().then_some(Self { layers })
    }

    /// The device holding the weights (autodiff for a learner's online actor, plain for a
    /// snapshot).
    pub fn device(&self) -> Device {
        self.layers[0].weight.device()
    }

    /// Actions `[batch, act_dim]` for observations `[batch, obs_dim]`.
    pub fn forward(&self, obs: Tensor<2>) -> Tensor<2> {
        self.pre_tanh(obs).tanh()
    }

    /// The output layer before the final tanh, `[batch, act_dim]`.
    pub fn pre_tanh(&self, obs: Tensor<2>) -> Tensor<2> {
        forward_mlp(&self.layers, obs)
    }

    /// Actions for `obs.len() / obs_dim` row-major observations: the deterministic action plus
    /// N(0, `sigma`) noise from `rng`, clipped to [-1, 1] (the reference code did not clip).
    /// `sigma = 0` gives the greedy action. Runs on this actor's device.
    ///
    /// # Panics
    /// If `obs.len()` is not a multiple of [`Actor::obs_dim`].
    pub fn act<R: Rng + ?Sized>(&self, obs: &[f32], sigma: f64, rng: &mut R) -> Vec<f32> {
        let obs_dim = self.obs_dim();
        assert_eq!(
            obs.len() % obs_dim,
            0,
            "act: {} values is not a whole number of {obs_dim}-value observations",
            obs.len()
        );
        let device = self.device();
        let input = Tensor::<2>::from_data(
            TensorData::new(obs.to_vec(), [obs.len() / obs_dim, obs_dim]),
            &device,
        );
        let mut action: Vec<f32> = self
            .forward(input)
            .into_data()
            .try_into_vec()
            .expect("actor output is f32");
        if sigma > 0.0 {
            let normal = rand_distr::Normal::new(0.0, sigma).expect("sigma is finite and positive");
            for a in &mut action {
                *a = (f64::from(*a) + rng.sample(normal)).clamp(-1.0, 1.0) as f32;
            }
        }
        action
    }

    /// This actor with the output layer's weights multiplied by `factor` and its bias set to
    /// `bias` (`act_dim` values): with a small factor, the pre-tanh output is close to `bias` for
    /// every observation. The new values are fresh leaves with the old gradient settings.
    ///
    /// # Panics
    /// If `bias.len()` is not [`Actor::act_dim`].
    pub fn with_output(mut self, factor: f64, bias: &[f32]) -> Self {
        assert_eq!(bias.len(), self.act_dim(), "with_output: bias length");
        let Linear {
            weight,
            bias: old_bias,
        } = self.layers.pop().expect("an actor has layers");
        let leaf = |old: Tensor<1>, new: Tensor<1>| new.set_require_grad(old.is_require_grad());
        let weight = weight.map(|w| {
            let require_grad = w.is_require_grad();
            w.mul_scalar(factor).detach().set_require_grad(require_grad)
        });
        let bias = old_bias.map(|b| {
            b.map(|old| {
                let new = Tensor::from_data(TensorData::new(bias.to_vec(), [bias.len()]), &old.device());
                leaf(old, new)
            })
        });
        self.layers.push(Linear { weight, bias });
        self
    }

    /// This actor moved `tau` of the way towards `online` (Polyak averaging).
    pub fn polyak(self, online: &Actor, tau: f64) -> Self {
        Self {
            layers: polyak_layers(self.layers, &online.layers, tau),
        }
    }

    /// Moves the layers out, leaving an actor without layers in their place (to be overwritten
    /// before any other use). Lets an update own the parameters without sharing their buffers.
    pub(crate) fn take(&mut self) -> Self {
        Self {
            layers: std::mem::take(&mut self.layers),
        }
    }
}

/// One Q-network `(obs, act) -> hidden (ReLU) ... -> 1`; the action is concatenated onto the
/// observation. A burn module (see [`Actor`] for cloning and thread safety).
#[derive(Module, Debug)]
pub struct Critic {
    layers: Vec<Linear>,
}

impl Critic {
    /// A freshly initialized critic `(obs_dim + act_dim) -> hidden... -> 1` on `device`.
    pub fn new(
        obs_dim: usize,
        act_dim: usize,
        hidden: &[usize],
        device: &Device,
        rng: &mut Pcg64Mcg,
    ) -> Self {
        let sizes: Vec<usize> = [obs_dim + act_dim]
            .iter()
            .chain(hidden)
            .chain(&[1])
            .copied()
            .collect();
        Self {
            layers: mlp(&sizes, device, rng),
        }
    }

    /// Q-values `[batch, 1]`.
    pub fn forward(&self, obs: Tensor<2>, action: Tensor<2>) -> Tensor<2> {
        forward_mlp(&self.layers, Tensor::cat(vec![obs, action], 1))
    }

    /// The same Q-values as [`Critic::forward`] (up to float rounding), with the first layer
    /// split by input rows: `relu(obs W_obs + action W_act + b) -> ...`. For a critic whose
    /// weights take no gradient (TD3's actor step): the observation product is then outside the
    /// autodiff graph, and the backward pass computes the gradient of the `act_dim` action
    /// inputs only instead of all `obs_dim + act_dim` of the concatenated input (on the paper's
    /// sizes, a 730 x 512 matrix product per step saved).
    pub fn forward_frozen(&self, obs: Tensor<2>, action: Tensor<2>) -> Tensor<2> {
        let first = &self.layers[0];
        let weight = first.weight.val();
        let [rows, cols] = weight.dims();
        let obs_dim = obs.dims()[1];
        let mut x = obs.matmul(weight.clone().slice([0..obs_dim, 0..cols]))
            + action.matmul(weight.slice([obs_dim..rows, 0..cols]));
        if let Some(bias) = &first.bias {
            x = x + bias.val().unsqueeze_dim(0);
        }
        let rest = &self.layers[1..];
        if rest.is_empty() {
            x
        } else {
            forward_mlp(rest, relu(x))
        }
    }

    fn polyak(self, online: &Critic, tau: f64) -> Self {
        Self {
            layers: polyak_layers(self.layers, &online.layers, tau),
        }
    }

    /// See [`Actor::take`].
    fn take(&mut self) -> Self {
        Self {
            layers: std::mem::take(&mut self.layers),
        }
    }
}

/// The twin critics of TD3, optimized together (one loss, one Adam).
#[derive(Module, Debug)]
pub struct TwinCritic {
    /// The critic whose value the actor maximizes.
    pub q1: Critic,
    /// The second critic (only used in the min of the target).
    pub q2: Critic,
}

impl TwinCritic {
    /// Two critics from `init`, called twice: `q1` first, then `q2` (with a shared seeded RNG,
    /// that order fixes which weights each gets).
    pub fn new(mut init: impl FnMut() -> Critic) -> Self {
        let q1 = init();
        let q2 = init();
        Self { q1, q2 }
    }

    /// `(Q1, Q2)`, each `[batch, 1]`.
    pub fn forward(&self, obs: Tensor<2>, action: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        (
            self.q1.forward(obs.clone(), action.clone()),
            self.q2.forward(obs, action),
        )
    }

    /// Moves both critics out, leaving critics without layers in their place (see
    /// [`Actor::take`]).
    pub(crate) fn take(&mut self) -> Self {
        Self {
            q1: self.q1.take(),
            q2: self.q2.take(),
        }
    }

    /// These critics moved `tau` of the way towards `online` (Polyak averaging).
    pub fn polyak(self, online: &TwinCritic, tau: f64) -> Self {
        Self {
            q1: self.q1.polyak(&online.q1, tau),
            q2: self.q2.polyak(&online.q2, tau),
        }
    }
}

#[cfg(test)]
impl Critic {
    /// A critic whose output is `value` for every input (zero weights, last bias `value`).
    pub(crate) fn constant(
        obs_dim: usize,
        act_dim: usize,
        hidden: &[usize],
        value: f32,
        device: &Device,
    ) -> Self {
        let mut critic = Self::new(obs_dim, act_dim, hidden, device, &mut Pcg64Mcg::new(0));
        let last = critic.layers.len() - 1;
        for (i, layer) in critic.layers.iter_mut().enumerate() {
            let fill = if i == last { value } else { 0.0 };
            layer.weight = Param::from_tensor(layer.weight.val().zeros_like());
            layer.bias = layer
                .bias
                .take()
                .map(|b| Param::from_tensor(b.val().zeros_like().add_scalar(fill)));
        }
        critic
    }
}

fn tensor_values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .try_to_vec::<f32>()
        .expect("network parameters are f32")
}

#[cfg(test)]
mod tests {
    use burn::module::Module;
    use burn::tensor::{Device, Tensor};
    use rand::Rng;
    use rand_pcg::Pcg64Mcg;

    use super::{Actor, Critic};
    use crate::td3::tensor2;

    /// Flat weights read back into an actor of the same sizes give the same network; a
    /// vector of another length is refused.
    #[test]
    fn flat_weights_round_trip() {
        let device = Device::flex();
        let a = Actor::new(7, &[5, 3], 2, &device, &mut Pcg64Mcg::new(1));
        let b = Actor::new(7, &[5, 3], 2, &device, &mut Pcg64Mcg::new(2));
        let (dims, flat) = a.flat_weights();
        let back = b.with_flat_weights(&flat).unwrap();
        assert_eq!(back.flat_weights(), (dims, flat.clone()));
        let obs: Vec<f32> = (0..14).map(|i| i as f32 / 7.0 - 1.0).collect();
        let mut rng = Pcg64Mcg::new(0);
        assert_eq!(back.act(&obs, 0.0, &mut rng), a.act(&obs, 0.0, &mut rng));
        assert!(b.with_flat_weights(&flat[1..]).is_none());
        assert!(b.with_flat_weights(&[flat.as_slice(), &[0.0]].concat()).is_none());
    }

    fn values(t: Tensor<2>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// The split first layer of the actor step computes the same Q-values, and the same
    /// gradient with respect to the action, as the concatenated one.
    #[test]
    fn frozen_forward_matches_forward_and_its_action_gradient() {
        let device = Device::flex().autodiff();
        let mut rng = Pcg64Mcg::new(11);
        let (obs_dim, act_dim, rows) = (37, 4, 9);
        let critic = Critic::new(obs_dim, act_dim, &[32, 16], &device, &mut rng).no_grad();
        let mut uniform = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
        let (obs, act) = (uniform(rows * obs_dim), uniform(rows * act_dim));
        let run = |frozen: bool| {
            let obs = tensor2(&obs, rows, obs_dim, &device);
            let action = tensor2(&act, rows, act_dim, &device).require_grad();
            let q = if frozen {
                critic.forward_frozen(obs, action.clone())
            } else {
                critic.forward(obs, action.clone())
            };
            let grads = q.clone().sum().backward();
            let grad = action.grad(&grads).expect("the action takes a gradient");
            (values(q.inner()), values(grad))
        };
        let ((q_split, g_split), (q_cat, g_cat)) = (run(true), run(false));
        assert_eq!(q_split.len(), rows);
        assert_eq!(g_split.len(), rows * act_dim);
        for (a, b) in q_split.iter().zip(&q_cat).chain(g_split.iter().zip(&g_cat)) {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
        }
        assert!(
            g_cat.iter().any(|g| g.abs() > 1e-4),
            "a zero gradient proves nothing"
        );
    }
}
