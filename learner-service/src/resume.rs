//! What training continues from: a checkpoint's full state, loaded and verified, falling back
//! from a damaged newest checkpoint to the previous one.

use std::path::{Path, PathBuf};

use learner::checkpoint;
use learner::rate::RateLimiter;
use learner::replay::ReplayBuffer;
use learner::td3::Td3;
use learner::Device;
use scheduler::{Registry, RegistryConfig, RegistrySnapshot};

use crate::error::ResumeError;
use crate::totals::Totals;

/// What training continues from: a checkpoint's state, or a fresh one.
pub(crate) struct TrainingState {
    /// The networks and optimizers.
    pub(crate) td3: Td3,
    /// The run id.
    pub(crate) run_id: String,
    /// Inserts vs updates.
    pub(crate) rate: RateLimiter,
    /// The replay sampler's random stream.
    pub(crate) sampler_rng: rand_pcg::Pcg64Mcg,
    /// The policy version published last.
    pub(crate) policy_version: u64,
    /// Actors, leases, cycles.
    pub(crate) registry: Registry,
    /// The counters.
    pub(crate) totals: Totals,
    /// The replay buffer.
    pub(crate) replay: ReplayBuffer,
}

/// Loads everything a resume needs from checkpoint `ckpt`, verifying every file. Counters that
/// do not parse are reset (with a warning) rather than failing: they are statistics, not
/// training state.
pub(crate) fn load_resume_state(
    ckpt: &Path,
    registry_cfg: &RegistryConfig,
    device: &Device,
) -> Result<TrainingState, ResumeError> {
    let (td3, state) = checkpoint::load(ckpt, device)?;
    let replay = checkpoint::load_replay(ckpt)?.unwrap_or_else(|| ReplayBuffer::new(td3.config()));
    let snapshot: RegistrySnapshot =
        serde_json::from_value(state.extra["registry"].clone()).map_err(|source| {
            ResumeError::RegistryState {
                checkpoint: ckpt.to_path_buf(),
                source,
            }
        })?;
    let totals: Totals = serde_json::from_value(state.extra["totals"].clone()).unwrap_or_else(|e| {
        tracing::warn!(
            checkpoint = %ckpt.display(),
            "the counters do not parse ({e}); they restart from zero"
        );
        Totals::default()
    });
    let registry = Registry::restore(*registry_cfg, snapshot).map_err(|source| ResumeError::Registry {
        checkpoint: ckpt.to_path_buf(),
        source,
    })?;
    Ok(TrainingState {
        td3,
        run_id: state.run_id,
        rate: state.rate,
        sampler_rng: state.sampler_rng,
        policy_version: state.policy_version,
        registry,
        totals,
        replay,
    })
}

/// Loads the newest of `candidates` (complete checkpoints, oldest first) that loads fully,
/// onto `device` (whichever device wrote it); each one skipped is logged as a warning and
/// returned with the reason.
pub(crate) fn newest_usable(
    dir: &Path,
    candidates: &[(u64, PathBuf)],
    registry_cfg: &RegistryConfig,
    device: &Device,
) -> Result<(PathBuf, TrainingState, Vec<String>), ResumeError> {
    let mut warnings = Vec::new();
    for (_, ckpt) in candidates.iter().rev() {
        match load_resume_state(ckpt, registry_cfg, device) {
            Ok(state) => return Ok((ckpt.clone(), state, warnings)),
            Err(e) => {
                let warning = format!(
                    "checkpoint {} is unusable ({e}); falling back to the previous one",
                    ckpt.display()
                );
                tracing::warn!("{warning}");
                warnings.push(warning);
            }
        }
    }
    Err(ResumeError::NoUsableCheckpoint {
        dir: dir.to_path_buf(),
        tried: candidates.len(),
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use learner::checkpoint;
    use learner::rate::RateLimiter;
    use learner::retention;
    use learner::td3::{seeded_rng, Td3};
    use learner::Device;
    use scheduler::{Registry, RegistryConfig};

    use super::*;
    use learner::batch::random_batch;
    use learner::Td3Config;
    use testkit::fresh_dir as temp_dir;

    #[test]
    fn a_corrupt_newest_checkpoint_falls_back_to_the_previous_one() {
        let config = Td3Config {
            obs_dim: 3,
            act_dim: 1,
            laser_dim: 0,
            actor_hidden: vec![16],
            critic_hidden: vec![16],
            batch_size: 4,
            replay_capacity: 64,
            ..Td3Config::default()
        };
        let registry_cfg = RegistryConfig {
            lease_ttl_ms: 1000,
            episodes_per_assignment: 2,
            run_seed: 1,
            deadline: scheduler::DeadlineRule::default(),
        };
        let registry = Registry::new(registry_cfg, scheduler::WorldPool::Listed(vec![1, 2])).unwrap();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let run = checkpoint::RunState {
            run_id: "r".into(),
            rate: RateLimiter::new(&config),
            sampler_rng: seeded_rng(0, 2),
            policy_version: 0,
            extra: serde_json::json!({ "registry": registry.snapshot(), "totals": Totals::default() }),
            environment: serde_json::Value::Null,
        };
        let root = temp_dir("resume-fallback");
        let mut rng = seeded_rng(0, 0);
        for name in ["ckpt-1", "ckpt-2"] {
            td3.update(&random_batch(&config, 4, &mut rng)).unwrap();
            checkpoint::save(&root.join(name), &td3, &run).unwrap();
        }
        // One flipped byte in a network file (the manifest still verifies).
        let flip = |file: &Path| {
            let mut bytes = std::fs::read(file).unwrap();
            let mid = bytes.len() / 2;
            bytes[mid] ^= 0xff;
            std::fs::write(file, bytes).unwrap();
        };
        flip(&root.join("ckpt-2").join("actor.bpk"));
        let candidates = retention::complete_checkpoints(&root).unwrap();
        assert_eq!(candidates.len(), 2, "the damage is only found by a full load");
        let (ckpt, state, warnings) =
            newest_usable(&root, &candidates, &registry_cfg, &Device::flex()).unwrap();
        assert_eq!(ckpt, root.join("ckpt-1"));
        assert_eq!(state.td3.updates(), 1);
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].contains("ckpt-2"), "{warnings:?}");
        // Nothing usable: the error names every checkpoint tried.
        flip(&root.join("ckpt-1").join("critic.bpk"));
        let e = newest_usable(
            &root,
            &retention::complete_checkpoints(&root).unwrap(),
            &registry_cfg,
            &Device::flex(),
        )
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("ckpt-1") && e.contains("ckpt-2"), "{e}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
