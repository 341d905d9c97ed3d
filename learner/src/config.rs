//! The learner's hyper-parameters: one documented struct with the defaults of DESIGN §5.
//!
//! The defaults are the values the ADP authors trained with (`TD3_function_cluster.yaml`), with
//! two deliberate differences recorded on the fields: the n-step bootstrap uses `gamma^m` for the
//! `m` rewards actually summed, and Adam's epsilon is PyTorch's `1e-8` (burn's default is `1e-5`).

use std::path::Path;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Everything that defines one TD3 run of the learner.
///
/// Build it with [`Td3Config::default`] and override fields, or parse it from TOML with
/// [`Td3Config::from_toml_str`] / [`Td3Config::from_toml_file`] (unknown keys are refused and
/// missing keys take the defaults). Call [`Td3Config::validate`] before use; the constructors of
/// this crate that take a config do so themselves.
///
/// The struct is plain data (`Send + Sync`, cheap to clone).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Td3Config {
    /// Observation size: 730 for the 4-D decremental action space (720 laser values, the
    /// previous action, v, w and two (bearing, distance) goal pairs; N + 10 with the
    /// `sectors:N` laser layout). Comes from the planner's action space and the environment's
    /// laser layout; not a constant of this crate.
    pub obs_dim: usize,
    /// Action size: 4 for the decremental action space, 20 for the unconstrained one.
    pub act_dim: usize,
    /// How many leading observation values are laser ranges in [-1, 1] (720, or N with the
    /// `sectors:N` layout). The replay buffer stores them as 16-bit integers. Must be at most
    /// `obs_dim`; 0 stores everything as `f32`.
    pub laser_dim: usize,
    /// Hidden layer widths of the actor (ReLU between layers, tanh on the output).
    pub actor_hidden: Vec<usize>,
    /// Hidden layer widths of each of the twin critics (ReLU, scalar linear output).
    pub critic_hidden: Vec<usize>,
    /// Adam learning rate of the actor.
    pub actor_lr: f64,
    /// Adam learning rate of the twin critics.
    pub critic_lr: f64,
    /// Adam epsilon for every optimizer. PyTorch's default `1e-8`, which the reference code used;
    /// burn's own default is `1e-5`.
    pub adam_epsilon: f32,
    /// Discount factor per agent step.
    pub gamma: f64,
    /// Polyak coefficient of the target networks: `target <- (1 - tau) target + tau online`.
    pub tau: f64,
    /// Standard deviation of the target-policy smoothing noise (in normalized action units).
    pub target_noise: f64,
    /// The target-policy smoothing noise is clipped to `[-target_noise_clip, target_noise_clip]`.
    pub target_noise_clip: f64,
    /// The actor and all target networks are updated on every `policy_delay`-th critic update.
    pub policy_delay: u64,
    /// Transitions per gradient update.
    pub batch_size: usize,
    /// Longest n-step return; shorter at episode ends.
    pub n_step: usize,
    /// Replay capacity in agent steps (slots; a truncated episode uses one extra slot for its
    /// final observation).
    pub replay_capacity: usize,
    /// Inserted agent steps before the first gradient update.
    pub warmup_steps: u64,
    /// Exploration noise standard deviation at step 0 (normalized action units).
    pub exploration_start: f64,
    /// Exploration noise standard deviation at and after `exploration_steps`.
    pub exploration_end: f64,
    /// Agent steps over which exploration decays linearly from start to end; 0 (the default)
    /// means the run's own step budget, so a short run ends exploiting as a long one does (the
    /// reference code's fixed 1M `max_step` barely decays inside a 40K-step run).
    pub exploration_steps: u64,
    /// Critic-only warm-up: the actor (and the target actor) is not updated until this many
    /// critic updates are done, so the first actor steps follow a critic that has seen data
    /// rather than its random initialization. 0 updates the actor from the first
    /// `policy_delay`-th update, as plain TD3.
    pub actor_warmup_updates: u64,
    /// Gradient updates per inserted agent step once warm-up is over (Reverb's samples per
    /// insert, counted in updates).
    pub updates_per_insert: f64,
    /// How far, in updates, the learner may run ahead of or fall behind `updates_per_insert`
    /// before the rate limiter blocks updates or inserts.
    pub rate_tolerance: f64,
    /// Seed of every random stream of the learner (weights, noise, sampling).
    pub seed: u64,
}

impl Default for Td3Config {
    fn default() -> Self {
        Self {
            obs_dim: 730,
            act_dim: 4,
            laser_dim: 720,
            actor_hidden: vec![512, 512],
            critic_hidden: vec![512, 256],
            actor_lr: 1e-5,
            critic_lr: 2e-5,
            adam_epsilon: 1e-8,
            gamma: 0.95,
            tau: 0.005,
            target_noise: 0.2,
            target_noise_clip: 0.5,
            policy_delay: 2,
            batch_size: 128,
            n_step: 6,
            replay_capacity: 200_000,
            warmup_steps: 1024,
            exploration_start: 0.2,
            exploration_end: 0.05,
            exploration_steps: 0,
            actor_warmup_updates: 2_000,
            updates_per_insert: 1.0,
            rate_tolerance: 1024.0,
            seed: 14,
        }
    }
}

/// Why a configuration was refused.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// A field holds a value outside its allowed range.
    #[error("config field `{field}` = {value}: {reason}")]
    Invalid {
        /// The offending field.
        field: &'static str,
        /// The value, formatted.
        value: String,
        /// What is allowed.
        reason: &'static str,
    },
    /// The TOML text did not parse or named an unknown key.
    #[error("config TOML{}: {source}", .path.as_ref().map(|p| format!(" in {p}")).unwrap_or_default())]
    Parse {
        /// The file, when read from one.
        path: Option<String>,
        /// The parser's message (it names the key and line).
        source: Box<toml::de::Error>,
    },
    /// The config file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
}

fn check(
    ok: bool,
    field: &'static str,
    value: impl ToString,
    reason: &'static str,
) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(ConfigError::Invalid {
            field,
            value: value.to_string(),
            reason,
        })
    }
}

fn finite_in(v: f64, lo: f64, hi: f64) -> bool {
    v.is_finite() && v >= lo && v <= hi
}

impl Td3Config {
    /// Parse a config from TOML text; missing keys take the defaults, unknown keys are errors.
    /// The result is validated.
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let config: Self = toml::from_str(text).map_err(|source| ConfigError::Parse {
            path: None,
            source: Box::new(source),
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Read and parse a TOML config file (see [`Td3Config::from_toml_str`]).
    pub fn from_toml_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let config: Self = toml::from_str(&text).map_err(|source| ConfigError::Parse {
            path: Some(path.display().to_string()),
            source: Box::new(source),
        })?;
        config.validate()?;
        Ok(config)
    }

    /// The config as TOML text (round-trips through [`Td3Config::from_toml_str`]).
    pub fn to_toml_string(&self) -> String {
        toml::to_string(self).expect("a Td3Config always serializes to TOML")
    }

    /// Check every field; the error names the first offending field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(self.obs_dim > 0, "obs_dim", self.obs_dim, "must be > 0")?;
        check(self.act_dim > 0, "act_dim", self.act_dim, "must be > 0")?;
        check(
            self.laser_dim <= self.obs_dim,
            "laser_dim",
            self.laser_dim,
            "must be <= obs_dim",
        )?;
        for (field, hidden) in [
            ("actor_hidden", &self.actor_hidden),
            ("critic_hidden", &self.critic_hidden),
        ] {
            check(
                !hidden.is_empty() && hidden.iter().all(|&w| w > 0),
                field,
                format!("{hidden:?}"),
                "needs at least one layer, every width > 0",
            )?;
        }
        for (field, lr) in [("actor_lr", self.actor_lr), ("critic_lr", self.critic_lr)] {
            check(lr.is_finite() && lr > 0.0, field, lr, "must be finite and > 0")?;
        }
        check(
            self.adam_epsilon.is_finite() && self.adam_epsilon > 0.0,
            "adam_epsilon",
            self.adam_epsilon,
            "must be finite and > 0",
        )?;
        check(
            finite_in(self.gamma, 0.0, 1.0),
            "gamma",
            self.gamma,
            "must be in [0, 1]",
        )?;
        check(
            finite_in(self.tau, 0.0, 1.0) && self.tau > 0.0,
            "tau",
            self.tau,
            "must be in (0, 1]",
        )?;
        check(
            finite_in(self.target_noise, 0.0, f64::MAX),
            "target_noise",
            self.target_noise,
            "must be finite and >= 0",
        )?;
        check(
            finite_in(self.target_noise_clip, 0.0, f64::MAX),
            "target_noise_clip",
            self.target_noise_clip,
            "must be finite and >= 0",
        )?;
        check(
            self.policy_delay > 0,
            "policy_delay",
            self.policy_delay,
            "must be > 0",
        )?;
        check(self.batch_size > 0, "batch_size", self.batch_size, "must be > 0")?;
        check(self.n_step > 0, "n_step", self.n_step, "must be > 0")?;
        check(
            self.replay_capacity > self.n_step && self.replay_capacity < u32::MAX as usize,
            "replay_capacity",
            self.replay_capacity,
            "must be > n_step and < 2^32 - 1",
        )?;
        for (field, sigma) in [
            ("exploration_start", self.exploration_start),
            ("exploration_end", self.exploration_end),
        ] {
            check(
                finite_in(sigma, 0.0, f64::MAX),
                field,
                sigma,
                "must be finite and >= 0",
            )?;
        }
        check(
            self.updates_per_insert.is_finite() && self.updates_per_insert > 0.0,
            "updates_per_insert",
            self.updates_per_insert,
            "must be finite and > 0",
        )?;
        check(
            finite_in(self.rate_tolerance, 1.0, f64::MAX),
            "rate_tolerance",
            self.rate_tolerance,
            "must be finite and >= 1 (one update)",
        )?;
        // Inserts stop when the learner lags by more than `rate_tolerance` updates; if that is
        // less than one insert's worth of updates, the limiter can hold inserts back while
        // allowing no update either, and the run deadlocks.
        check(
            self.rate_tolerance >= self.updates_per_insert,
            "rate_tolerance",
            self.rate_tolerance,
            "must be >= updates_per_insert (otherwise the rate limiter can block inserts while allowing no update: a deadlock)",
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_match_design_section_5_and_validate() {
        let c = Td3Config::default();
        c.validate().unwrap();
        assert_eq!((c.obs_dim, c.act_dim, c.laser_dim), (730, 4, 720));
        assert_eq!(c.actor_hidden, [512, 512]);
        assert_eq!(c.critic_hidden, [512, 256]);
        assert_eq!((c.actor_lr, c.critic_lr), (1e-5, 2e-5));
        assert_eq!((c.gamma, c.tau), (0.95, 0.005));
        assert_eq!((c.target_noise, c.target_noise_clip), (0.2, 0.5));
        assert_eq!((c.policy_delay, c.batch_size, c.n_step), (2, 128, 6));
        assert_eq!((c.replay_capacity, c.warmup_steps), (200_000, 1024));
        assert_eq!((c.exploration_start, c.exploration_end), (0.2, 0.05));
        assert_eq!(c.updates_per_insert, 1.0);
    }

    #[test]
    fn toml_round_trip_and_partial_files() {
        let c = Td3Config {
            act_dim: 20,
            obs_dim: 746,
            ..Td3Config::default()
        };
        assert_eq!(Td3Config::from_toml_str(&c.to_toml_string()).unwrap(), c);
        let partial = Td3Config::from_toml_str("act_dim = 20\nobs_dim = 746\n").unwrap();
        assert_eq!(partial, c);
    }

    #[test]
    fn unknown_keys_are_refused_with_their_name() {
        let err = Td3Config::from_toml_str("gama = 0.9\n").unwrap_err();
        assert!(err.to_string().contains("gama"), "{err}");
    }

    #[test]
    fn invalid_values_name_the_field() {
        let cases: Vec<(&str, Td3Config)> = vec![
            (
                "gamma",
                Td3Config {
                    gamma: 1.5,
                    ..Default::default()
                },
            ),
            (
                "tau",
                Td3Config {
                    tau: 0.0,
                    ..Default::default()
                },
            ),
            (
                "laser_dim",
                Td3Config {
                    laser_dim: 731,
                    ..Default::default()
                },
            ),
            (
                "actor_hidden",
                Td3Config {
                    actor_hidden: vec![],
                    ..Default::default()
                },
            ),
            (
                "critic_hidden",
                Td3Config {
                    critic_hidden: vec![8, 0],
                    ..Default::default()
                },
            ),
            (
                "critic_lr",
                Td3Config {
                    critic_lr: f64::NAN,
                    ..Default::default()
                },
            ),
            (
                "replay_capacity",
                Td3Config {
                    replay_capacity: 6,
                    ..Default::default()
                },
            ),
            (
                "policy_delay",
                Td3Config {
                    policy_delay: 0,
                    ..Default::default()
                },
            ),
            (
                "rate_tolerance",
                Td3Config {
                    rate_tolerance: 0.5,
                    ..Default::default()
                },
            ),
            (
                "rate_tolerance",
                Td3Config {
                    updates_per_insert: 4.0,
                    rate_tolerance: 1.0,
                    ..Default::default()
                },
            ),
        ];
        for (field, c) in cases {
            let err = c.validate().unwrap_err();
            assert!(err.to_string().contains(&format!("`{field}`")), "{field}: {err}");
        }
    }
}
