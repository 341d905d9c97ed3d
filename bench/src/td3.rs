//! `adp bench learner`: the time of one TD3 update at the configured batch (and at any other
//! batches asked for) on the learner's device, its achieved GFLOP/s and, on the CPU, its
//! share of the machine's peak; the memory and sampling time of a full replay buffer (DESIGN
//! §8), measured through the learner's public API; with a Python that has torch, the same
//! update in PyTorch ([`crate::pytorch`]) and the ratio of the two.

use std::path::Path;
use std::time::Instant;

use learner::batch::random_batch;
use learner::{Batch, Device, LearnerDevice, ReplayBuffer, Step, StepEnd, Td3, Td3Config, Td3Error};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::pytorch::pytorch_update;
use crate::{figure, Figure};

/// The `learner` part's figures: [`td3_updates`] of `updates` on `device` at the embedded
/// training configuration's batch, then at each of `batches` (updates per second, achieved
/// GFLOP/s from [`update_macs`], and on the CPU the share of [`cpu_peak_gflops`]); with
/// `python` the same update in PyTorch and their ratio, and [`replay_full`].
pub fn run(
    updates: usize,
    python: Option<&Path>,
    device: LearnerDevice,
    batches: &[usize],
) -> anyhow::Result<Vec<Figure>> {
    // Timed at the steady state of training: the actor steps every `policy_delay` updates
    // (the critic-only warm-up of the first `actor_warmup_updates` is past).
    let cfg = Td3Config {
        actor_warmup_updates: 0,
        ..train_config::TrainConfig::load(None)?.td3
    };
    let opened = device.open()?;
    let peak = cpu_peak_gflops();
    if let (LearnerDevice::Cpu, Some(p)) = (device, &peak) {
        eprintln!("CPU peak: {:.1} GFLOP/s ({})", p.gflops, p.how);
    }
    let mut out = Vec::new();
    let mut configured = None;
    let mut sizes = vec![cfg.batch_size];
    sizes.extend(batches.iter().copied().filter(|&b| b != cfg.batch_size && b > 0));
    for batch_size in sizes {
        let c = Td3Config {
            batch_size,
            ..cfg.clone()
        };
        let t = td3_updates(&c, updates.max(2), &opened)?;
        let gflops = 2.0 * update_macs(&c) / (t.mean_ms * 1e-3) / 1e9;
        out.push(figure(
            format!(
                "TD3 update, batch {batch_size}, {device}, mean over {} updates",
                t.updates
            ),
            t.mean_ms,
            "ms",
        ));
        out.push(figure(
            format!("TD3 updates per second, batch {batch_size}, {device}"),
            1e3 / t.mean_ms,
            "1/s",
        ));
        out.push(figure(
            format!("TD3 update, batch {batch_size}, {device}, achieved"),
            gflops,
            "GFLOP/s",
        ));
        if let (LearnerDevice::Cpu, Some(p)) = (device, &peak) {
            out.push(figure(
                format!("TD3 update, batch {batch_size}, share of the CPU's peak"),
                100.0 * gflops / p.gflops,
                "%",
            ));
        }
        if batch_size == cfg.batch_size {
            out.push(figure(
                format!("TD3 update, batch {batch_size}, {device}, critic-only, median"),
                t.critic_only_median_ms,
                "ms",
            ));
            if let Some(ms) = t.with_actor_median_ms {
                out.push(figure(
                    format!("TD3 update, batch {batch_size}, {device}, critic + actor + targets, median"),
                    ms,
                    "ms",
                ));
            }
            configured = Some(t);
        }
    }
    let t = configured.expect("the configured batch is timed first");
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

/// Multiply-adds of one TD3 update of `config`'s networks at its batch size, averaged over
/// the policy delay. Per sample, with `A` and `C` the multiply-adds of one actor and one
/// critic forward pass (each dense layer `in x out`; a backward pass costs two forwards):
///
/// - every update: the target actor on the next observations (`A`), both target critics
///   (`2C`), both critics forward and backward (`3 x 2C`): `A + 8C`;
/// - every `policy_delay`-th update: the actor forward and backward (`3A`) and the first
///   critic forward and backward through its input (`2C`).
///
/// The default networks at batch 128: about 0.79 G multiply-adds.
pub fn update_macs(config: &Td3Config) -> f64 {
    let dense = |sizes: &[usize]| -> f64 { sizes.windows(2).map(|w| (w[0] * w[1]) as f64).sum() };
    let actor: Vec<usize> = std::iter::once(config.obs_dim)
        .chain(config.actor_hidden.iter().copied())
        .chain(std::iter::once(config.act_dim))
        .collect();
    let critic: Vec<usize> = std::iter::once(config.obs_dim + config.act_dim)
        .chain(config.critic_hidden.iter().copied())
        .chain(std::iter::once(1))
        .collect();
    let (a, c) = (dense(&actor), dense(&critic));
    let per_sample = a + 8.0 * c + (3.0 * a + 2.0 * c) / config.policy_delay.max(1) as f64;
    per_sample * config.batch_size as f64
}

/// The CPU's peak single-precision rate and how it was derived.
#[derive(Clone, Debug, PartialEq)]
pub struct Peak {
    /// GFLOP/s.
    pub gflops: f64,
    /// The derivation: cores x clock x vector lanes x 2 (fused multiply-add) x FMA units.
    pub how: String,
}

/// This machine's peak f32 rate: the cores this process may use x the clock `/proc/cpuinfo`
/// reports x the f32 lanes of its widest vector unit (16 with AVX-512, 8 with AVX2, 4
/// otherwise) x 2 (a fused multiply-add is two operations) x 2 FMA units per core (what
/// current x86 server cores have; a core with one halves the peak). `None` without a clock.
pub fn cpu_peak_gflops() -> Option<Peak> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let ghz = crate::cycle::clock_ghz()?;
    let flags = info.lines().find(|l| l.starts_with("flags"))?;
    let has = |f: &str| flags.split_whitespace().any(|x| x == f);
    let (lanes, unit) = if has("avx512f") {
        (16.0, "AVX-512")
    } else if has("avx2") && has("fma") {
        (8.0, "AVX2")
    } else {
        (4.0, "SSE")
    };
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
    Some(Peak {
        gflops: cores * ghz * lanes * 2.0 * 2.0,
        how: format!("{cores} cores x {ghz:.2} GHz x {lanes} f32 lanes ({unit}) x 2 (FMA) x 2 FMA units"),
    })
}

/// Times `updates` TD3 updates of networks built from `config` on `device`, after 20 warm-up
/// updates, cycling over 8 pre-drawn batches (the same protocol as `bench/td3_update.py`, so
/// the two figures compare).
pub fn td3_updates(config: &Td3Config, updates: usize, device: &Device) -> Result<UpdateTiming, Td3Error> {
    let mut td3 = Td3::new(config.clone(), device)?;
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
        let t = td3_updates(&config, 10, &Device::flex()).unwrap();
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
            &Device::flex(),
        )
        .unwrap();
        assert_eq!(none.with_actor_median_ms, None);
    }

    #[test]
    fn an_update_of_the_default_networks_is_0_79_g_multiply_adds() {
        let config = Td3Config {
            obs_dim: 730,
            act_dim: 4,
            actor_hidden: vec![512, 512],
            critic_hidden: vec![512, 256],
            batch_size: 128,
            policy_delay: 2,
            ..Td3Config::default()
        };
        // Actor 730-512-512-4: 637,952 per sample; critic 734-512-256-1: 507,136.
        // (A + 8C + (3A + 2C) / 2) x 128.
        assert_eq!(update_macs(&config), 788_365_312.0);
        let every = Td3Config {
            policy_delay: 1,
            ..config
        };
        assert!(
            update_macs(&every)
                > update_macs(&Td3Config {
                    policy_delay: 2,
                    ..every.clone()
                })
        );
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
