//! Measurements behind `adp bench learner` (DESIGN §8): the time of one TD3 update and the
//! memory and sampling time of a full replay buffer. Pure functions over the learner's own
//! types; the command prints the figures and compares them with their targets.

use std::time::Instant;

use burn::tensor::Device;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::batch::Batch;
use crate::config::Td3Config;
use crate::replay::{ReplayBuffer, Step, StepEnd};
use crate::td3::{Td3, Td3Error};

/// Timing of TD3 updates at the configured batch size (wall clock, milliseconds).
#[derive(Clone, Debug, PartialEq)]
pub struct UpdateTiming {
    /// Timed updates (after the warm-up).
    pub updates: usize,
    /// Mean time of one update over all timed updates (critic-only and with actor).
    pub mean_ms: f64,
    /// Median of the updates that step only the critics.
    pub critic_only_median_ms: f64,
    /// Median of the updates that also step the actor and the target networks (every
    /// `policy_delay`-th), or `None` when none was timed.
    pub with_actor_median_ms: Option<f64>,
}

/// A batch of uniform random values in [-1, 1] (every 5th row terminal, discount gamma^6):
/// the work of a real update without a replay buffer behind it.
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

/// Times `updates` TD3 updates of networks built from `config` on the CPU device, after 20
/// warm-up updates, cycling over 8 pre-drawn batches (the same protocol as
/// `bench/td3_update.py`, so the two figures compare).
pub fn td3_updates(config: &Td3Config, updates: usize) -> Result<UpdateTiming, Td3Error> {
    let mut td3 = Td3::new(config.clone(), &Device::flex())?;
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    let batches: Vec<Batch> = (0..8)
        .map(|_| random_batch(config, config.batch_size, &mut rng))
        .collect();
    for b in batches.iter().cycle().take(20) {
        td3.update(b)?;
    }
    let (mut critic_only, mut with_actor) = (Vec::new(), Vec::new());
    let start = Instant::now();
    for b in batches.iter().cycle().take(updates) {
        let t = Instant::now();
        let stats = td3.update(b)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if stats.actor_loss.is_some() {
            with_actor.push(ms);
        } else {
            critic_only.push(ms);
        }
    }
    Ok(UpdateTiming {
        updates,
        mean_ms: start.elapsed().as_secs_f64() * 1e3 / updates.max(1) as f64,
        critic_only_median_ms: median(&mut critic_only).unwrap_or(f64::NAN),
        with_actor_median_ms: median(&mut with_actor),
    })
}

/// The flat weights (layer sizes and parameters, the layout actors run) of an actor built from
/// `config` and fitted to output `target` everywhere, as a run starts with `ddp_init`: the
/// policy the collection benchmark drives.
pub fn fitted_policy_weights(
    config: &Td3Config,
    target: &[f32],
) -> Result<(Vec<usize>, Vec<f32>), FittedPolicyError> {
    let mut td3 = Td3::new(config.clone(), &Device::flex())?;
    td3.init_actor_to_action(target, &crate::ddp_init::FitOptions::default())?;
    Ok(td3.policy().flat_weights())
}

/// Why [`fitted_policy_weights`] made no policy.
#[derive(Debug, thiserror::Error)]
pub enum FittedPolicyError {
    /// The networks could not be built.
    #[error(transparent)]
    Td3(#[from] crate::td3::Td3Error),
    /// The actor could not be fitted to the target.
    #[error(transparent)]
    Fit(#[from] crate::ddp_init::FitError),
}

/// Memory and speed of a full replay buffer.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayFigures {
    /// Capacity (agent steps) of the filled buffer.
    pub capacity: usize,
    /// Bytes of the slot arrays.
    pub storage_bytes: usize,
    /// Growth of the process's resident set while the buffer was built and filled twice over
    /// (`None` where `/proc/self/statm` is unreadable).
    pub resident_growth_bytes: Option<u64>,
    /// Median time to sample one batch (microseconds) over 1000 batches.
    pub sample_median_us: f64,
    /// Time to write the buffer's checkpoint snapshot to memory (seconds).
    pub snapshot_write_s: f64,
    /// Time to read that snapshot back (seconds).
    pub snapshot_read_s: f64,
    /// Size of the snapshot (bytes).
    pub snapshot_bytes: usize,
}

/// Fills a buffer of `config.replay_capacity` twice over with random observations in episodes
/// of 200 steps (so the ring wraps), then times sampling `config.batch_size` rows and the
/// checkpoint snapshot round trip.
pub fn replay_full(config: &Td3Config) -> ReplayFigures {
    let before = crate::mem::resident_set_bytes();
    let mut buf = ReplayBuffer::new(config);
    let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
    let mut obs = vec![0.0f32; config.obs_dim];
    let action = vec![0.1f32; config.act_dim];
    for i in 0..config.replay_capacity * 2 {
        obs.iter_mut().for_each(|x| *x = rng.random_range(-1.0..=1.0));
        let end = if i % 200 == 199 {
            StepEnd::Terminal
        } else {
            StepEnd::Continue
        };
        let step = Step {
            obs: &obs,
            action: &action,
            reward: -0.5,
            end,
        };
        buf.push((i / 200) as u64, &step)
            .expect("steps built from the config fit the buffer");
    }
    let after = crate::mem::resident_set_bytes();
    let mut batch = Batch::new(config.obs_dim, config.act_dim);
    let mut times: Vec<f64> = (0..1000)
        .map(|_| {
            let t = Instant::now();
            buf.sample(config.batch_size, &mut rng, &mut batch)
                .expect("a filled buffer has ready steps");
            t.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    let t = Instant::now();
    let mut snapshot = Vec::with_capacity(buf.storage_bytes() + 4096);
    buf.write_snapshot(&mut snapshot)
        .expect("writing to memory cannot fail");
    let snapshot_write_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let back = ReplayBuffer::read_snapshot(&snapshot, config).expect("a snapshot just written reads back");
    let snapshot_read_s = t.elapsed().as_secs_f64();
    assert_eq!(back.len(), buf.len(), "the snapshot round trip lost steps");
    ReplayFigures {
        capacity: config.replay_capacity,
        storage_bytes: buf.storage_bytes(),
        resident_growth_bytes: before.zip(after).map(|(b, a)| a.saturating_sub(b)),
        sample_median_us: median(&mut times).unwrap_or(f64::NAN),
        snapshot_write_s,
        snapshot_read_s,
        snapshot_bytes: snapshot.len(),
    }
}

/// The median of `v` (sorted in place), `None` when empty.
pub fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::tiny_config;

    #[test]
    fn update_timing_separates_critic_and_actor_updates() {
        let config = tiny_config();
        let t = td3_updates(&config, 10).unwrap();
        assert_eq!(t.updates, 10);
        assert!(t.mean_ms > 0.0 && t.critic_only_median_ms > 0.0, "{t:?}");
        assert!(
            t.with_actor_median_ms.is_some(),
            "policy delay 2 steps the actor in 10 updates"
        );
        let none = td3_updates(
            &Td3Config {
                policy_delay: 100,
                ..config
            },
            3,
        )
        .unwrap();
        assert_eq!(none.with_actor_median_ms, None);
    }

    #[test]
    fn full_replay_figures_describe_a_wrapped_buffer() {
        let config = Td3Config {
            replay_capacity: 1000,
            ..tiny_config()
        };
        let f = replay_full(&config);
        assert_eq!(f.capacity, 1000);
        assert!(f.storage_bytes >= 1000 * 3 * 4, "{f:?}");
        assert!(f.snapshot_bytes >= f.storage_bytes, "{f:?}");
        assert!(f.sample_median_us > 0.0, "{f:?}");
    }

    #[test]
    fn median_of_odd_and_even_lengths() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
    }
}
