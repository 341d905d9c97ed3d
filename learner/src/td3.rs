//! TD3 (Fujimoto et al. 2018) with n-step targets, readable top to bottom: the state, then one
//! update. The replay buffer supplies n-step returns and bootstrap discounts (see
//! [`crate::batch::Batch`]); everything else is here.

use burn::module::Module;
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_distr::Normal;
use rand_pcg::Pcg64Mcg;
use thiserror::Error;

use crate::adam::Adam;
use crate::batch::Batch;
use crate::config::{ConfigError, Td3Config};
use crate::nets::{Actor, Critic, TwinCritic};

/// Why an update or construction failed.
#[derive(Debug, Error)]
pub enum Td3Error {
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The batch does not fit the networks.
    #[error("td3 update: batch has {what} = {got}, networks expect {expected}")]
    BatchShape {
        /// `obs_dim`, `act_dim`, or a column length.
        what: &'static str,
        /// What the batch has.
        got: usize,
        /// What the networks expect.
        expected: usize,
    },
}

/// What one update measured (host scalars, read back after the step).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateStats {
    /// `MSE(Q1, y) + MSE(Q2, y)` before the critic step.
    pub critic_loss: f32,
    /// Mean of Q1 over the batch before the critic step.
    pub q1_mean: f32,
    /// Mean of the target `y` over the batch.
    pub target_mean: f32,
    /// `-mean Q1(s, pi(s))` before the actor step, on actor-update iterations only.
    pub actor_loss: Option<f32>,
    /// L2 norm of the gradient of both critics' losses (all their parameters together).
    pub critic_grad_norm: f32,
    /// L2 norm of the actor's gradient, on actor-update iterations only.
    pub actor_grad_norm: Option<f32>,
}

/// The learner's TD3 state: online actor and twin critics (on the autodiff device), their
/// target copies (on the plain device), Adam optimizers (actor, q1, q2), the target-noise RNG and the
/// update counter.
///
/// All randomness comes from `config.seed` through [`Pcg64Mcg`] streams owned here, never from
/// burn's global RNG, so two instances built from the same config on the same device compute
/// bit-identical parameters for the same batches (on the flex backend, whose parallel kernels
/// split work without changing the order of any reduction).
///
/// `Send` but not meant to be shared: one learner thread owns it and publishes actor snapshots
/// ([`Td3::policy`]) to others.
pub struct Td3 {
    pub(crate) config: Td3Config,
    /// Autodiff device of the online networks; `device.clone().inner()` holds the targets.
    pub(crate) device: Device,
    pub(crate) actor: Actor,
    pub(crate) critic: TwinCritic,
    pub(crate) actor_target: Actor,
    pub(crate) critic_target: TwinCritic,
    pub(crate) actor_opt: Adam,
    /// One Adam per critic (`[q1, q2]`).
    pub(crate) critic_opts: [Adam; 2],
    /// Target-policy smoothing noise.
    pub(crate) noise_rng: Pcg64Mcg,
    /// Completed updates; the actor steps when this reaches a multiple of `policy_delay`.
    pub(crate) updates: u64,
}

/// The seeded random stream `stream` of a run with seed `seed`. Streams: 0 weights, 1 target
/// noise, 2 replay sampling, 3 DDP fitting; callers may use others for their own purposes.
pub fn seeded_rng(seed: u64, stream: u64) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// A host slice as a `[rows, cols]` tensor on `device`.
pub(crate) fn tensor2(values: &[f32], rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(values.to_vec(), [rows, cols]), device)
}

impl Td3 {
    /// Fresh networks (targets equal to the online networks) and optimizers for `config`, on
    /// `device` (a plain device such as `Device::flex()`; autodiff is added here).
    pub fn new(config: Td3Config, device: &Device) -> Result<Self, Td3Error> {
        config.validate()?;
        let device = device.clone().autodiff();
        let mut init = seeded_rng(config.seed, 0);
        let (obs, act) = (config.obs_dim, config.act_dim);
        let actor = Actor::new(obs, &config.actor_hidden, act, &device, &mut init);
        let critic = TwinCritic::new(|| Critic::new(obs, act, &config.critic_hidden, &device, &mut init));
        let adam = Adam::new(config.adam_epsilon);
        Ok(Self {
            actor_target: actor.valid(),
            critic_target: critic.valid(),
            actor,
            critic,
            critic_opts: [adam.clone(), adam.clone()],
            actor_opt: adam,
            noise_rng: seeded_rng(config.seed, 1),
            updates: 0,
            device,
            config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &Td3Config {
        &self.config
    }

    /// Updates done so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// A snapshot of the current actor without autodiff, for acting and publishing.
    pub fn policy(&self) -> Actor {
        self.actor.valid()
    }

    /// Replace the online and target actor (e.g. after the DDP initialization) with `actor`, a
    /// trainable actor on this learner's device or a snapshot from [`Td3::policy`]. The actor's
    /// optimizer state is reset, since it belonged to other weights.
    pub fn set_actor(&mut self, actor: Actor) {
        // A snapshot (plain device) becomes trainable again; a trainable actor is kept as is.
        let actor = if actor.device().is_autodiff() {
            actor
        } else {
            actor.to_device(&self.device).train()
        };
        self.actor_target = actor.valid();
        self.actor = actor;
        self.actor_opt = Adam::new(self.config.adam_epsilon);
    }

    /// The online actor (autodiff).
    pub fn actor(&self) -> &Actor {
        &self.actor
    }

    /// The online twin critics (autodiff).
    pub fn critic(&self) -> &TwinCritic {
        &self.critic
    }

    /// One TD3 update on `batch`:
    ///
    /// 1. target action `a' = clamp(pi'(s') + clip(N(0, target_noise), ±target_noise_clip), -1, 1)`;
    /// 2. target `y = R + discount * (1 - done) * min(Q1'(s', a'), Q2'(s', a'))`;
    /// 3. critic step on `MSE(Q1(s, a), y) + MSE(Q2(s, a), y)`;
    /// 4. every `policy_delay`-th update: actor step on `-mean Q1(s, pi(s))` (with the critic just
    ///    updated), then Polyak updates of the target actor and both target critics; during the
    ///    first `actor_warmup_updates` updates only the target critics move.
    ///
    /// The twin critics share no parameters, so their halves of steps 2 and 3 run in parallel
    /// (rayon); the sum of the two MSEs has the same gradients as two separate losses, and Adam is
    /// per-parameter, so one optimizer per critic is the same algorithm as one for both.
    pub fn update(&mut self, batch: &Batch) -> Result<UpdateStats, Td3Error> {
        self.check_batch(batch)?;
        // 1-2. The target, without autodiff.
        let y = self.target(batch);

        // 3. Critic step, one independent graph per critic.
        let c = &self.config;
        let (lr, device) = (c.critic_lr, &self.device);
        let [opt1, opt2] = &mut self.critic_opts;
        // Moved out (not cloned), so each parameter's buffer has one owner and Adam updates it
        // without a copy.
        let TwinCritic { q1, q2 } = self.critic.take();
        let ((q1, loss1, q1_mean), (q2, loss2, _)) = rayon::join(
            || critic_step(q1, opt1, lr, batch, y.clone(), device),
            || critic_step(q2, opt2, lr, batch, y.clone(), device),
        );
        self.critic = TwinCritic { q1, q2 };
        self.updates += 1;
        let critic_grad_norm = opt1.last_grad_norm().hypot(opt2.last_grad_norm());

        // 4. Delayed actor step and target updates. The critic's weights get no gradient here.
        // During the critic-only warm-up the critic targets still track the critics.
        let mut actor_loss = None;
        let mut actor_grad_norm = None;
        if self.updates.is_multiple_of(c.policy_delay) {
            let tau = c.tau;
            if self.updates > c.actor_warmup_updates {
                let obs = tensor2(&batch.obs, batch.len(), c.obs_dim, &self.device);
                let q1_frozen = self.critic.q1.clone().no_grad();
                let loss = q1_frozen
                    .forward_frozen(obs.clone(), self.actor.forward(obs))
                    .mean()
                    .neg();
                let grads = GradientsParams::from_grads(loss.backward(), &self.actor);
                self.actor = self.actor_opt.step(c.actor_lr, self.actor.take(), grads);
                actor_loss = Some(loss.into_scalar::<f32>());
                actor_grad_norm = Some(self.actor_opt.last_grad_norm());

                let (actor_target, critic_target) = (self.actor_target.take(), self.critic_target.take());
                let (actor, critic) = (&self.actor, &self.critic);
                (self.actor_target, self.critic_target) = rayon::join(
                    || actor_target.polyak(actor, tau),
                    || critic_target.polyak(critic, tau),
                );
            } else {
                self.critic_target = self.critic_target.take().polyak(&self.critic, tau);
            }
        }

        Ok(UpdateStats {
            critic_loss: loss1 + loss2,
            q1_mean,
            target_mean: y.mean().into_scalar::<f32>(),
            actor_loss,
            critic_grad_norm,
            actor_grad_norm,
        })
    }

    /// `y = R + discount * (1 - done) * min(Q1'(s', a'), Q2'(s', a'))` with the smoothed target
    /// action `a'`, as a `[batch, 1]` tensor on the plain device. Draws the target noise.
    pub(crate) fn target(&mut self, batch: &Batch) -> Tensor<2> {
        let c = &self.config;
        let (n, obs_dim, act_dim) = (batch.len(), c.obs_dim, c.act_dim);
        let plain = self.device.clone().inner();
        let next_obs = tensor2(&batch.next_obs, n, obs_dim, &plain);
        let noise = target_noise(
            &mut self.noise_rng,
            n * act_dim,
            c.target_noise,
            c.target_noise_clip,
        );
        let noise = tensor2(&noise, n, act_dim, &plain);
        let next_action = (self.actor_target.forward(next_obs.clone()) + noise).clamp(-1.0, 1.0);
        let TwinCritic { q1, q2 } = &self.critic_target;
        let (next_q1, next_q2) = rayon::join(
            || q1.forward(next_obs.clone(), next_action.clone()),
            || q2.forward(next_obs.clone(), next_action.clone()),
        );
        let bootstrap: Vec<f32> = batch
            .discount
            .iter()
            .zip(&batch.done)
            .map(|(g, d)| g * (1.0 - d))
            .collect();
        tensor2(&batch.reward, n, 1, &plain) + tensor2(&bootstrap, n, 1, &plain) * next_q1.min_pair(next_q2)
    }

    fn check_batch(&self, batch: &Batch) -> Result<(), Td3Error> {
        let n = batch.len();
        let checks = [
            ("obs_dim", batch.obs_dim, self.config.obs_dim),
            ("act_dim", batch.act_dim, self.config.act_dim),
            ("obs.len()", batch.obs.len(), n * self.config.obs_dim),
            ("next_obs.len()", batch.next_obs.len(), n * self.config.obs_dim),
            ("action.len()", batch.action.len(), n * self.config.act_dim),
            ("discount.len()", batch.discount.len(), n),
            ("done.len()", batch.done.len(), n),
        ];
        for (what, got, expected) in checks {
            if got != expected {
                return Err(Td3Error::BatchShape { what, got, expected });
            }
        }
        if n == 0 {
            return Err(Td3Error::BatchShape {
                what: "rows",
                got: 0,
                expected: self.config.batch_size,
            });
        }
        Ok(())
    }
}

/// One Adam step of one critic on `MSE(Q(s, a), y)`, in a graph of its own (fresh input
/// tensors), so the two critics can step on different threads. Returns the updated critic, the
/// loss and the mean Q before the step.
fn critic_step(
    critic: Critic,
    optimizer: &mut Adam,
    lr: f64,
    batch: &Batch,
    y: Tensor<2>,
    device: &Device,
) -> (Critic, f32, f32) {
    let n = batch.len();
    let obs = tensor2(&batch.obs, n, batch.obs_dim, device);
    let action = tensor2(&batch.action, n, batch.act_dim, device);
    let q = critic.forward(obs, action);
    let q_mean = q.clone().mean();
    let loss = (q - y.autodiff()).square().mean();
    let grads = GradientsParams::from_grads(loss.backward(), &critic);
    let critic = optimizer.step(lr, critic, grads);
    (critic, loss.into_scalar::<f32>(), q_mean.into_scalar::<f32>())
}

/// `len` draws of `clip(N(0, sigma), -clip, clip)` (the target-policy smoothing noise).
fn target_noise(rng: &mut Pcg64Mcg, len: usize, sigma: f64, clip: f64) -> Vec<f32> {
    if sigma == 0.0 {
        return vec![0.0; len];
    }
    let normal = Normal::new(0.0, sigma).expect("sigma is finite and positive");
    (0..len)
        .map(|_| rng.sample(normal).clamp(-clip, clip) as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::{ReplayBuffer, Step, StepEnd};
    use crate::test_util::{params, random_batch, tiny_config};

    /// The optimal action of the single-step task.
    fn f(obs: &[f32]) -> f32 {
        (0.7 * obs[0] - 0.4 * obs[1] * obs[2]).clamp(-0.9, 0.9)
    }

    #[test]
    fn target_on_hand_made_critics() {
        let config = Td3Config {
            target_noise: 0.3,
            ..tiny_config()
        };
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let plain = Device::flex();
        let mut batch = Batch::new(3, 1);
        batch.obs = vec![0.0; 9];
        batch.next_obs = vec![0.1, 0.2, 0.3, -0.5, 0.5, 0.0, 1.0, -1.0, 0.25];
        batch.action = vec![0.0; 3];
        batch.reward = vec![1.0, -2.0, 0.5];
        batch.discount = vec![0.95, 0.9025, 0.735_091_9];
        batch.done = vec![1.0, 0.0, 0.0];
        for ((c1, c2), min) in [((3.0, -2.0), -2.0f32), ((1.0, 5.0), 1.0)] {
            td3.critic_target = TwinCritic {
                q1: Critic::constant(3, 1, &[8], c1, &plain),
                q2: Critic::constant(3, 1, &[8], c2, &plain),
            };
            let y: Vec<f32> = td3.target(&batch).into_data().try_into_vec().unwrap();
            let expected = [1.0, -2.0 + 0.9025 * min, 0.5 + 0.735_091_9 * min];
            for (got, want) in y.iter().zip(expected) {
                assert!((got - want).abs() < 1e-6, "{y:?} vs {expected:?}");
            }
        }
    }

    #[test]
    fn target_noise_is_clipped_gaussian() {
        let mut rng = seeded_rng(1, 1);
        let clipped = target_noise(&mut rng, 20_000, 1.0, 0.5);
        assert!(clipped.iter().all(|x| x.abs() <= 0.5));
        let at_clip = clipped.iter().filter(|x| x.abs() == 0.5).count() as f64 / 20_000.0;
        assert!(
            (at_clip - 0.617).abs() < 0.02,
            "P(|N(0,1)| > 0.5) = 0.617, got {at_clip}"
        );
        let free = target_noise(&mut rng, 20_000, 0.2, 10.0);
        let var = free.iter().map(|x| f64::from(x * x)).sum::<f64>() / 20_000.0;
        assert!((var.sqrt() - 0.2).abs() < 0.005, "std {}", var.sqrt());
    }

    #[test]
    fn policy_delay_and_polyak_targets() {
        let config = Td3Config {
            tau: 0.25,
            ..tiny_config()
        };
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let mut rng = seeded_rng(3, 9);
        let (actor0, critic0, critic_t0) = (
            params(&td3.actor),
            params(&td3.critic),
            params(&td3.critic_target),
        );
        assert_eq!(critic0, critic_t0, "targets start equal to the online networks");
        let stats = td3.update(&random_batch(&config, 32, &mut rng)).unwrap();
        assert!(stats.actor_loss.is_none());
        assert_eq!(params(&td3.actor), actor0, "no actor step on update 1");
        assert_eq!(
            params(&td3.critic_target),
            critic_t0,
            "no target update on update 1"
        );
        assert_ne!(params(&td3.critic), critic0);
        let stats = td3.update(&random_batch(&config, 32, &mut rng)).unwrap();
        assert!(stats.actor_loss.is_some());
        assert_ne!(params(&td3.actor), actor0);
        // target = 0.75 target_old + 0.25 online_new, for the actor and both critics.
        for (target, old, online) in [
            (params(&td3.critic_target), critic_t0.clone(), params(&td3.critic)),
            (params(&td3.actor_target), actor0.clone(), params(&td3.actor)),
        ] {
            for ((t, o), n) in target.iter().zip(&old).zip(&online) {
                assert!((t - (0.75 * o + 0.25 * n)).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn critic_only_warm_up_holds_the_actor_but_moves_the_critic_targets() {
        let config = Td3Config {
            actor_warmup_updates: 4,
            ..tiny_config()
        };
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let mut rng = seeded_rng(3, 9);
        let (actor0, critic_t0) = (params(&td3.actor), params(&td3.critic_target));
        for k in 1..=4 {
            let stats = td3.update(&random_batch(&config, 32, &mut rng)).unwrap();
            assert!(stats.actor_loss.is_none(), "update {k} is critic-only");
        }
        assert_eq!(params(&td3.actor), actor0);
        assert_eq!(params(&td3.actor_target), actor0);
        assert_ne!(params(&td3.critic_target), critic_t0, "critic targets track");
        assert!(td3
            .update(&random_batch(&config, 32, &mut rng))
            .unwrap()
            .actor_loss
            .is_none());
        let stats = td3.update(&random_batch(&config, 32, &mut rng)).unwrap();
        assert!(stats.actor_loss.is_some(), "update 6: the first actor step");
        assert_ne!(params(&td3.actor), actor0);
    }

    #[test]
    fn same_seed_same_parameters_after_k_updates() {
        let config = tiny_config();
        let run = |seed: u64| {
            let mut td3 = Td3::new(
                Td3Config {
                    seed,
                    ..config.clone()
                },
                &Device::flex(),
            )
            .unwrap();
            let mut rng = seeded_rng(5, 2);
            for _ in 0..6 {
                td3.update(&random_batch(&config, 32, &mut rng)).unwrap();
            }
            [
                params(&td3.actor),
                params(&td3.critic),
                params(&td3.actor_target),
                params(&td3.critic_target),
            ]
        };
        let a = run(7);
        assert!(a == run(7), "same seed, same parameters bit for bit");
        assert!(a != run(8));
    }

    /// A single-step task: reward -(a - f(s))^2, episodes of one step (terminal). TD3 must learn
    /// the greedy action f(s) from uniformly random behaviour data through the replay buffer.
    #[test]
    fn learns_a_single_step_regression_task() {
        let config = tiny_config();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let mut data_rng = seeded_rng(config.seed, 10);
        let mut replay = ReplayBuffer::new(&config);
        for episode in 0..4096 {
            let obs: Vec<f32> = (0..3).map(|_| data_rng.random_range(-1.0..=1.0)).collect();
            let action = [data_rng.random_range(-1.0..=1.0f32)];
            let reward = -(action[0] - f(&obs)).powi(2);
            replay
                .push(
                    episode,
                    &Step {
                        obs: &obs,
                        action: &action,
                        reward,
                        end: StepEnd::Terminal,
                    },
                )
                .unwrap();
        }
        let test_obs: Vec<f32> = (0..3 * 512).map(|_| data_rng.random_range(-1.0..=1.0)).collect();
        let greedy_error = |td3: &Td3| -> f32 {
            let actions = td3.policy().act(&test_obs, 0.0, &mut Pcg64Mcg::new(0));
            actions
                .iter()
                .zip(test_obs.chunks(3))
                .map(|(a, o)| (a - f(o)).abs())
                .sum::<f32>()
                / 512.0
        };
        let initial = greedy_error(&td3);
        let mut sampler = seeded_rng(config.seed, 2);
        let mut batch = Batch::new(3, 1);
        for _ in 0..600 {
            replay
                .sample(config.batch_size, &mut sampler, &mut batch)
                .unwrap();
            td3.update(&batch).unwrap();
        }
        let last = greedy_error(&td3);
        println!("single-step task: mean |pi(s) - f(s)| {initial:.3} -> {last:.3}");
        assert!(last < 0.25 * initial && last < 0.08, "{initial} -> {last}");
    }

    #[test]
    fn bad_batches_are_refused() {
        let config = tiny_config();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let mut batch = random_batch(&config, 4, &mut seeded_rng(0, 0));
        batch.next_obs.pop();
        let err = td3.update(&batch).unwrap_err().to_string();
        assert!(err.contains("next_obs.len() = 11, networks expect 12"), "{err}");
        let err = Td3::new(Td3Config { gamma: 2.0, ..config }, &Device::flex())
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("`gamma`"), "{err}");
    }
}
