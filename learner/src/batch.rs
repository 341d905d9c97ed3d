//! A mini-batch of n-step transitions in host memory: what the replay buffer fills and a TD3
//! update consumes.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use crate::config::Td3Config;

/// `len` n-step transitions, row-major (`obs[i * obs_dim..(i + 1) * obs_dim]` is row `i`).
///
/// For row `i` with `m` rewards summed (`1 <= m <= n`):
/// - `reward[i] = sum_{k<m} gamma^k r_{t+k}` (the n-step return),
/// - `discount[i] = gamma^m`, the factor of the bootstrap value,
/// - `done[i]` is 1.0 when the window ended in a true terminal (no bootstrap) and 0.0
///   otherwise (a full window or a time-limit truncation: bootstrap from `next_obs`),
/// - `next_obs[i]` is the observation after the last summed step (for a terminal, it repeats the
///   last step's observation; it is multiplied by `1 - done = 0` anyway).
///
/// A `Batch` is reused across samples to avoid allocation; plain data, `Send + Sync`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Batch {
    /// Observation size of every row.
    pub obs_dim: usize,
    /// Action size of every row.
    pub act_dim: usize,
    /// Observations `s_t`, `len * obs_dim`.
    pub obs: Vec<f32>,
    /// Actions `a_t` in [-1, 1], `len * act_dim`.
    pub action: Vec<f32>,
    /// n-step returns, `len`.
    pub reward: Vec<f32>,
    /// Bootstrap discounts `gamma^m`, `len`.
    pub discount: Vec<f32>,
    /// 1.0 for a true terminal inside the window, else 0.0; `len`.
    pub done: Vec<f32>,
    /// Observations `s_{t+m}`, `len * obs_dim`.
    pub next_obs: Vec<f32>,
}

impl Batch {
    /// An empty batch for the given sizes.
    pub fn new(obs_dim: usize, act_dim: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            ..Self::default()
        }
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.reward.len()
    }

    /// Whether the batch has no rows.
    pub fn is_empty(&self) -> bool {
        self.reward.is_empty()
    }

    /// Resize every column to `len` rows (new values are zero).
    pub(crate) fn resize(&mut self, len: usize) {
        self.obs.resize(len * self.obs_dim, 0.0);
        self.next_obs.resize(len * self.obs_dim, 0.0);
        self.action.resize(len * self.act_dim, 0.0);
        self.reward.resize(len, 0.0);
        self.discount.resize(len, 0.0);
        self.done.resize(len, 0.0);
    }
}

/// A batch of uniform random values in [-1, 1] (every 5th row terminal, discount gamma^6):
/// the work of a real update without a replay buffer behind it (benchmarks and tests).
pub fn random_batch(config: &Td3Config, rows: usize, rng: &mut Pcg64Mcg) -> Batch {
    let mut b = Batch::new(config.obs_dim, config.act_dim);
    let mut uniform = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..=1.0)).collect() };
    b.obs = uniform(rows * config.obs_dim);
    b.next_obs = uniform(rows * config.obs_dim);
    b.action = uniform(rows * config.act_dim);
    b.reward = uniform(rows);
    b.discount = vec![config.gamma.powi(6) as f32; rows];
    b.done = (0..rows).map(|i| f32::from(u8::from(i % 5 == 0))).collect();
    b
}
