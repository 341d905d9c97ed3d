//! The unit tests' learner: shared state with one registered actor holding one lease of two
//! episodes, and the steps and reports it sends.

use std::sync::Arc;

use learner::config::Td3Config;
use learner::rate::RateLimiter;
use learner::replay::ReplayBuffer;
use proto::plane::{ActorSecret, LeaseHeader};
use proto::validate::{Spaces, Validator};
use proto::{pb, StepView};
use scheduler::{Decision, Registry, RegistryConfig};

use crate::shared::Shared;
use crate::state::Core;
use crate::totals::Totals;

/// The fixture's lease TTL (ms).
pub const TTL: u64 = 1000;

/// A learner core with one registered actor holding one lease of two episodes.
pub struct Fixture {
    /// The shared state.
    pub shared: Arc<Shared>,
    /// The lease's header as its actor sends it.
    pub header: LeaseHeader,
    /// The lease's first episode id.
    pub first: u64,
}

/// A fixture over networks of `td3`'s sizes, dropping leases without progress after
/// `progress_timeout_ms`.
pub fn fixture(td3: Td3Config, progress_timeout_ms: u64) -> Fixture {
    let registry = Registry::new(
        RegistryConfig {
            lease_ttl_ms: TTL,
            episodes_per_assignment: 2,
            run_seed: 1,
            deadline: scheduler::DeadlineRule::default(),
        },
        scheduler::WorldPool::Listed(vec![3, 5]),
    )
    .unwrap();
    let core = Core::new(
        registry,
        ReplayBuffer::new(&td3),
        RateLimiter::new(&td3),
        Totals::default(),
        0,
    );
    let validator = Validator {
        run_id: "run".into(),
        incarnation: 9,
        spaces: Spaces {
            obs_dim: td3.obs_dim,
            act_dim: td3.act_dim,
            laser_dim: td3.laser_dim,
        },
    };
    let shared = Arc::new(Shared::new(
        validator,
        pb::RunSpec::default(),
        core,
        1_000_000,
        100,
        progress_timeout_ms,
    ));
    let now = shared.now_ms();
    let mut core = shared.lock();
    let actor = core.registry.register(0, "host".into(), 1, now, None);
    core.registered(actor, 0, "rust", SECRET);
    let Decision::Assign(a) = core.registry.next_assignment(actor, now, 0).unwrap() else {
        panic!("no assignment");
    };
    let first = core.open_lease(a.lease_id, actor, a.episodes, now);
    drop(core);
    Fixture {
        shared,
        header: LeaseHeader {
            incarnation: 9,
            actor_id: actor,
            lease_id: a.lease_id,
            secret: SECRET,
        },
        first,
    }
}

/// Tiny sizes: a 3-float observation, a 1-float action.
pub fn td3_config() -> Td3Config {
    Td3Config {
        obs_dim: 3,
        act_dim: 1,
        laser_dim: 0,
        replay_capacity: 1024,
        warmup_steps: 1000,
        ..Td3Config::default()
    }
}

/// The fixture actor's credential.
pub const SECRET: ActorSecret = [7; 16];

/// The observation of every fixture step.
const OBS: [f32; 3] = [0.1, 0.2, 0.3];
/// The action of every fixture step.
const ACTION: [f32; 1] = [0.5];

/// Step `step_index` of `episode_id`, made with policy version 0.
pub fn step(episode_id: u64, step_index: u32) -> StepView<'static> {
    StepView {
        episode_id,
        step_index,
        policy_version: 0,
        obs: &OBS,
        action: &ACTION,
        reward: -0.5,
        terminal: false,
        truncated: false,
        final_obs: &[],
    }
}

/// The report of the fixture lease's first episode with `episode_return`.
pub fn report(f: &Fixture, episode_return: f64) -> pb::EpisodeReport {
    pb::EpisodeReport {
        run: Some(pb::RunRef {
            run_id: "run".into(),
            incarnation: 9,
        }),
        actor_id: f.header.actor_id,
        lease_id: f.header.lease_id,
        actor_secret: proto::Bytes::copy_from_slice(&SECRET),
        episode_id: f.first,
        episode_return,
        score: 0.1,
        time_s: 10.0,
        ..Default::default()
    }
}
