//! Initialization from DDP: fit the actor so that its deterministic action is a given constant
//! action (the DDP schedule in normalized units) for every observation, as the paper starts ADP.

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Tensor;
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use thiserror::Error;

use crate::nets::Actor;
use crate::td3::{seeded_rng, tensor2, Td3};

/// How the supervised fit runs.
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    /// Initial Adam learning rate of the fit (its own optimizer, discarded afterwards); it
    /// decays to zero over `max_steps` on a cosine, which removes Adam's noise floor.
    pub lr: f64,
    /// Before fitting, the output layer's weights are multiplied by this (the common
    /// small-output-layer initialization) and its bias is set to `atanh(target)`, so the fit
    /// only removes a small residual.
    pub output_scale: f64,
    /// Targets are clipped to ±this before `atanh` (tanh never reaches ±1). The clipping costs
    /// `1 - saturation` of action error on dimensions whose target is ±1, and sets how saturated
    /// they start: the actor's gradient there is scaled by `1 - saturation^2` (0.01 at 0.995).
    pub saturation: f32,
    /// Random observations per step, uniform in [-1, 1].
    pub batch_size: usize,
    /// Give up after this many steps.
    pub max_steps: usize,
    /// Stop once the largest absolute action error on a fresh check batch is below this.
    pub tolerance: f32,
    /// Check the error every this many steps, on `4 * batch_size` fresh observations.
    pub check_every: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            lr: 1e-4,
            output_scale: 0.01,
            saturation: 0.995,
            batch_size: 128,
            max_steps: 400,
            tolerance: 0.01,
            check_every: 25,
        }
    }
}

/// The outcome of a successful fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitReport {
    /// Gradient steps taken.
    pub steps: usize,
    /// Largest absolute action error on the last check batch.
    pub max_error: f32,
}

/// Why the fit failed.
#[derive(Debug, Error, PartialEq)]
pub enum FitError {
    /// The target action has the wrong size or a value outside [-1, 1].
    #[error("DDP init: target action {index} = {value} (of {len}, actor act_dim {act_dim}) must be finite, in [-1, 1]")]
    Target {
        /// Position of the offending value (or the length when the size is wrong).
        index: usize,
        /// The value (NaN when the size is wrong).
        value: f32,
        /// Length of the given target.
        len: usize,
        /// Action size of the actor.
        act_dim: usize,
    },
    /// The error did not fall below the tolerance within the step budget.
    #[error("DDP init: max action error {max_error} still above {tolerance} after {steps} steps")]
    NotConverged {
        /// Steps taken.
        steps: usize,
        /// Largest error on the last check.
        max_error: f32,
        /// The requested tolerance.
        tolerance: f32,
    },
}

/// Fit `actor` (on an autodiff device) by MSE on the pre-tanh output against `atanh(target)`
/// (a target of zeros is set exactly instead: zero output weights and bias),
/// so that `actor(obs) ≈ target` for observations uniform in [-1, 1], drawing observations from `rng`. Returns the fitted actor; the caller
/// installs it (e.g. with [`crate::td3::Td3::set_actor`], which also resets the targets).
/// Deterministic given the actor, the target and the RNG state.
pub fn fit_actor_to_action(
    mut actor: Actor,
    target: &[f32],
    options: &FitOptions,
    rng: &mut Pcg64Mcg,
) -> Result<(Actor, FitReport), FitError> {
    let (obs_dim, act_dim) = (actor.obs_dim(), actor.act_dim());
    let bad = |index: usize, value: f32| FitError::Target {
        index,
        value,
        len: target.len(),
        act_dim,
    };
    if target.len() != act_dim {
        return Err(bad(target.len(), f32::NAN));
    }
    if let Some(i) = target.iter().position(|v| !(v.is_finite() && v.abs() <= 1.0)) {
        return Err(bad(i, target[i]));
    }
    if target.iter().all(|&t| t == 0.0) {
        // The DDP-centred action map's DDP: zero output weights and bias give tanh(0) = 0 for
        // every observation, exactly, where the actor's gradient is unsaturated.
        let zeros = vec![0.0; act_dim];
        return Ok((
            actor.with_output(0.0, &zeros),
            FitReport {
                steps: 0,
                max_error: 0.0,
            },
        ));
    }
    let device = actor.device();
    // Start from an output layer that is nearly the answer, then fit the residual.
    let pre_goal: Vec<f32> = target
        .iter()
        .map(|t| t.clamp(-options.saturation, options.saturation).atanh())
        .collect();
    actor = actor.with_output(options.output_scale, &pre_goal);
    let mut optimizer = AdamConfig::new().init();
    let mut random_obs = |rows: usize| -> Tensor<2> {
        let values: Vec<f32> = (0..rows * obs_dim)
            .map(|_| rng.random_range(-1.0..=1.0))
            .collect();
        tensor2(&values, rows, obs_dim, &device)
    };
    // Regress the pre-tanh output onto atanh(target): a well-conditioned least-squares problem,
    // where an MSE on tanh outputs stalls in saturation for targets near ±1.
    let n = options.batch_size;
    let goal = tensor2(&pre_goal.repeat(n), n, act_dim, &device);
    let mut max_error = f32::INFINITY;
    for step in 1..=options.max_steps {
        let loss = (actor.pre_tanh(random_obs(n)) - goal.clone()).square().mean();
        let grads = GradientsParams::from_grads(loss.backward(), &actor);
        let progress = (step - 1) as f64 / options.max_steps as f64;
        let lr = options.lr * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        actor = optimizer.step(lr, actor, grads);
        if step % options.check_every == 0 || step == options.max_steps {
            let check = 4 * n;
            let check_goal = tensor2(&target.repeat(check), check, act_dim, &device).inner();
            let output = actor.valid().forward(random_obs(check).inner());
            max_error = (output - check_goal).abs().max().into_scalar::<f32>();
            if max_error < options.tolerance {
                return Ok((
                    actor,
                    FitReport {
                        steps: step,
                        max_error,
                    },
                ));
            }
        }
    }
    Err(FitError::NotConverged {
        steps: options.max_steps,
        max_error,
        tolerance: options.tolerance,
    })
}

impl Td3 {
    /// Fit the online actor to the constant action `target` ([`fit_actor_to_action`], with the
    /// run's seeded stream 3) and install it: the target actor becomes a copy and the actor's
    /// Adam state starts fresh. The critics are untouched.
    pub fn init_actor_to_action(
        &mut self,
        target: &[f32],
        options: &FitOptions,
    ) -> Result<FitReport, FitError> {
        let mut rng = seeded_rng(self.config().seed, 3);
        let (actor, report) = fit_actor_to_action(self.actor().clone(), target, options, &mut rng)?;
        self.set_actor(actor);
        Ok(report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Td3Config;
    use crate::test_util::params;
    use burn::tensor::Device;

    fn max_error_on_random_obs(actor: &Actor, target: &[f32], rows: usize, seed: u64) -> f32 {
        let mut rng = seeded_rng(seed, 99);
        let obs: Vec<f32> = (0..rows * actor.obs_dim())
            .map(|_| rng.random_range(-1.0..=1.0))
            .collect();
        let actions = actor.valid().act(&obs, 0.0, &mut rng);
        actions
            .chunks(target.len())
            .flat_map(|a| a.iter().zip(target).map(|(x, t)| (x - t).abs()))
            .fold(0.0, f32::max)
    }

    #[test]
    fn fitted_full_size_actor_outputs_the_target_for_any_observation() {
        let mut td3 = Td3::new(Td3Config::default(), &Device::flex()).unwrap();
        let target = [1.0, -0.333, 0.4286, -1.0];
        let before = max_error_on_random_obs(&td3.policy(), &target, 256, 1);
        let report = td3.init_actor_to_action(&target, &FitOptions::default()).unwrap();
        let after = max_error_on_random_obs(&td3.policy(), &target, 2048, 2);
        println!(
            "DDP init: {} steps, max error {before} -> {after} (check batch {})",
            report.steps, report.max_error
        );
        assert!(after < 0.02, "max error {after}");
        assert!(before > 0.5);
        assert_eq!(
            params(&td3.actor_target),
            params(td3.actor()),
            "the target actor is reset to the fit"
        );
    }

    #[test]
    fn a_zero_target_is_exact_and_unsaturated_and_trains() {
        // The DDP-centred map puts DDP at 0: the initial actor outputs exactly 0 on any
        // observation, where tanh' = 1, so every action dimension gets the critic's full
        // gradient, and the first actor step moves every dimension.
        let config = crate::test_util::tiny_config();
        let config = Td3Config { act_dim: 4, ..config };
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let report = td3
            .init_actor_to_action(&[0.0; 4], &FitOptions::default())
            .unwrap();
        assert_eq!(report.steps, 0);
        assert_eq!(max_error_on_random_obs(&td3.policy(), &[0.0; 4], 512, 5), 0.0);
        let mut rng = seeded_rng(0, 0);
        let obs: Vec<f32> = (0..64 * config.obs_dim)
            .map(|_| rng.random_range(-1.0..=1.0))
            .collect();
        let pre = td3
            .policy()
            .pre_tanh(tensor2(&obs, 64, config.obs_dim, &td3.policy().device()));
        assert_eq!(
            pre.abs().max().into_scalar::<f32>(),
            0.0,
            "tanh'(0) = 1: unsaturated"
        );
        for _ in 0..2 {
            td3.update(&crate::test_util::random_batch(&config, 32, &mut rng))
                .unwrap();
        }
        let moved = td3.policy().valid().act(&obs, 0.0, &mut rng);
        for d in 0..4 {
            assert!(
                moved.iter().skip(d).step_by(4).any(|&a| a != 0.0),
                "dimension {d} moved after one actor step"
            );
        }
    }

    #[test]
    fn a_snapshot_can_be_installed_and_trained() {
        let config = crate::test_util::tiny_config();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let snapshot = Td3::new(
            Td3Config {
                seed: 99,
                ..config.clone()
            },
            &Device::flex(),
        )
        .unwrap()
        .policy();
        td3.set_actor(snapshot.clone());
        assert_eq!(params(td3.actor()), params(&snapshot));
        let mut rng = seeded_rng(0, 0);
        for _ in 0..2 {
            td3.update(&crate::test_util::random_batch(&config, 8, &mut rng))
                .unwrap();
        }
        assert_ne!(
            params(td3.actor()),
            params(&snapshot),
            "the installed actor trains"
        );
    }

    #[test]
    fn bad_targets_are_refused() {
        let device = Device::flex().autodiff();
        let actor = Actor::new(3, &[4], 2, &device, &mut seeded_rng(0, 0));
        let opts = FitOptions::default();
        let err = fit_actor_to_action(actor.clone(), &[0.0], &opts, &mut seeded_rng(0, 3)).unwrap_err();
        assert!(err.to_string().contains("act_dim 2"), "{err}");
        let err = fit_actor_to_action(actor, &[0.0, 1.5], &opts, &mut seeded_rng(0, 3)).unwrap_err();
        assert!(err.to_string().contains("target action 1 = 1.5"), "{err}");
    }
}
