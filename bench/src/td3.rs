//! `adp bench learner`: the time of one TD3 update at the configured batch and the memory and
//! sampling time of a full replay buffer (DESIGN §8), measured through the learner's public
//! API; with a Python that has torch, the same update in PyTorch ([`crate::pytorch`]) and the
//! ratio of the two.

use std::path::Path;
use std::time::Instant;

use learner::batch::random_batch;
use learner::{Batch, Device, ReplayBuffer, Step, StepEnd, Td3, Td3Config, Td3Error};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::pytorch::pytorch_update;
use crate::{figure, Figure};

/// The `learner` part's figures: [`td3_updates`] of `updates` at the embedded training
/// configuration, with `python` the same in PyTorch and their ratio, and [`replay_full`].
pub fn run(updates: usize, python: Option<&Path>) -> anyhow::Result<Vec<Figure>> {
    let cfg = train_config::TrainConfig::load(None)?.td3;
    let t = td3_updates(&cfg, updates.max(2))?;
    let mut out = vec![
        figure(
            format!(
                "TD3 update, batch {}, mean over {} updates",
                cfg.batch_size, t.updates
            ),
            t.mean_ms,
            "ms",
        ),
        figure("TD3 update, critic-only, median", t.critic_only_median_ms, "ms"),
    ];
    if let Some(ms) = t.with_actor_median_ms {
        out.push(figure("TD3 update, critic + actor + targets, median", ms, "ms"));
    }
    if let Some(python) = python {
        let torch = pytorch_update(python, updates.max(2))?;
        out.push(figure(
            format!("PyTorch {} update, mean ({} threads)", torch.torch, torch.threads),
            torch.mean_ms,
            "ms",
        ));
        out.push(figure(
            "PyTorch update, critic-only, median",
            torch.critic_only_median_ms,
            "ms",
        ));
        out.push(figure(
            "PyTorch update, critic + actor + targets, median",
            torch.with_actor_median_ms,
            "ms",
        ));
        out.push(
            figure(
                "speed vs PyTorch (mean time ratio PyTorch / burn)",
                torch.mean_ms / t.mean_ms,
                "x",
            )
            .at_least(1.0),
        );
    }
    let r = replay_full(&cfg);
    out.push(figure(
        format!("replay {}K, slot arrays", r.capacity / 1000),
        r.storage_bytes as f64 / 1e6,
        "MB",
    ));
    if let Some(growth) = r.resident_growth_bytes {
        out.push(figure("replay, resident growth when full", growth as f64 / 1e6, "MB").at_most(800.0));
    }
    out.push(figure(
        format!("replay, sample a batch of {}, median", cfg.batch_size),
        r.sample_median_us,
        "us",
    ));
    out.push(figure(
        format!("replay snapshot ({:.0} MB) write", r.snapshot_bytes as f64 / 1e6),
        r.snapshot_write_s,
        "s",
    ));
    out.push(figure("replay snapshot read", r.snapshot_read_s, "s"));
    Ok(out)
}

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
    td3.init_actor_to_action(target, &learner::FitOptions::default())?;
    Ok(td3.policy().flat_weights())
}

/// Why [`fitted_policy_weights`] made no policy.
#[derive(Debug, thiserror::Error)]
pub enum FittedPolicyError {
    /// The networks could not be built.
    #[error(transparent)]
    Td3(#[from] learner::Td3Error),
    /// The actor could not be fitted to the target.
    #[error(transparent)]
    Fit(#[from] learner::FitError),
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
    let before = learner::mem::resident_set_bytes();
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
    let after = learner::mem::resident_set_bytes();
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

    /// Small networks on a 3-D observation and a 1-D action, fast enough for many updates.
    fn tiny_config() -> Td3Config {
        Td3Config {
            obs_dim: 3,
            act_dim: 1,
            laser_dim: 0,
            actor_hidden: vec![64, 64],
            critic_hidden: vec![64, 64],
            actor_lr: 1e-3,
            critic_lr: 1e-3,
            batch_size: 64,
            replay_capacity: 8192,
            actor_warmup_updates: 0,
            seed: 7,
            ..Td3Config::default()
        }
    }

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
