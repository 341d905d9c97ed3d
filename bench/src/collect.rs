//! `adp bench collect`: agent steps per second of the actor's episode loop (simulator,
//! planner, policy inference, exploration; no learner), on one thread and on every core.

use std::time::Instant;

use actor::env::{AdpEnv, End};
use actor::exploration::Exploration;
use actor::policy::{MlpPolicy, Scratch};
use eval::EvalConfig;
use train_config::TrainConfig;

use crate::td3::fitted_policy_weights;
use crate::{figure, Figure};

/// The collection loop of one thread: episodes on the training worlds (round robin from
/// `thread`), the DDP-initialized policy with exploration noise 0.2, until `steps` agent steps.
fn collect_steps(
    net: &MlpPolicy,
    cfg: &TrainConfig,
    env: actor::EnvConfig,
    worlds: &[usize],
    thread: usize,
    steps: u64,
) -> anyhow::Result<u64> {
    let eval = EvalConfig::load(None)?;
    let space = cfg.run.action_space;
    let kind = cfg.run.planner;
    let n = actor::observation::obs_dim(env.observation, space, env.observe_tracks);
    let (mut obs, mut action) = (vec![0.0f32; n], vec![0.0f32; space.dim()]);
    let mut scratch = Scratch::default();
    let mut done = 0u64;
    let mut episode = 0usize;
    while done < steps {
        let seed = (thread as u64) << 32 | episode as u64;
        let world = sim::catalog::world(worlds[(thread + episode * 7) % worlds.len()])?;
        let mut env = AdpEnv::new(
            world,
            eval.episode,
            kind.build(&eval.planners(), seed),
            space,
            cfg.run.max_speed,
            env,
            seed,
        )?;
        let mut exploration = Exploration::new(0.2, seed);
        loop {
            env.observation(&mut obs);
            net.act(&obs, &mut action, &mut scratch);
            exploration.perturb(&mut action);
            let out = env.step(&action)?;
            done += 1;
            if out.end != End::Continue || done >= steps {
                break;
            }
        }
        episode += 1;
    }
    Ok(done)
}

/// The `collect` part's figures: `steps` agent steps on one core, with and without the compute
/// model, then on every core at once.
pub fn run(steps: u64) -> anyhow::Result<Vec<Figure>> {
    let cfg = TrainConfig::load(None)?;
    let space = cfg.run.action_space;
    let worlds = sim::splits::select(&cfg.run.worlds)?;
    let target: Vec<f32> = space.ddp_action().iter().map(|&a| a as f32).collect();
    let (dims, weights) = fitted_policy_weights(&cfg.td3, &target)?;
    let net = MlpPolicy::from_flat(&dims, weights)?;
    let steps = steps.max(10);
    let t = Instant::now();
    let one = collect_steps(&net, &cfg, cfg.env, &worlds, 0, steps)?;
    let single = one as f64 / t.elapsed().as_secs_f64();
    // The same steps without the compute model: what counting and budgeting cost.
    let free = actor::EnvConfig {
        compute: planner::ComputeConfig::FREE,
        ..cfg.env
    };
    let t = Instant::now();
    let one_free = collect_steps(&net, &cfg, free, &worlds, 0, steps)?;
    let single_free = one_free as f64 / t.elapsed().as_secs_f64();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let t = Instant::now();
    let total: u64 = std::thread::scope(|s| {
        let handles: Vec<_> = (0..cores)
            .map(|i| {
                let (net, cfg, worlds) = (&net, &cfg, &worlds);
                s.spawn(move || collect_steps(net, cfg, cfg.env, worlds, i + 1, steps))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a collecting thread panicked"))
            .sum::<anyhow::Result<u64>>()
    })?;
    let all = total as f64 / t.elapsed().as_secs_f64();
    Ok(vec![
        figure(
            format!(
                "collection, agent steps/s on one core ({} {})",
                cfg.run.planner.name(),
                learner::export::space_name(cfg.run.action_space)
            ),
            single,
            "1/s",
        )
        .at_least(1000.0),
        figure(
            "collection, agent steps/s on one core, compute model free",
            single_free,
            "1/s",
        ),
        figure(
            format!(
                "collection with the compute model ({}) / free (the episodes differ: latency)",
                eval::compute_label(&cfg.env.compute)
            ),
            single / single_free,
            "x",
        ),
        figure(
            format!("collection, agent steps/s on {cores} threads"),
            all,
            "1/s",
        ),
        figure(
            "collection scaling (all threads / (one core x threads))",
            all / (single * cores as f64),
            "x",
        ),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn collection_loop_counts_agent_steps_across_episode_ends() {
        let cfg = TrainConfig::load(None).unwrap();
        let space = cfg.run.action_space;
        let dims = [
            actor::observation::obs_dim(cfg.env.observation, space, cfg.env.observe_tracks),
            8,
            space.dim(),
        ];
        let net = MlpPolicy::from_flat(&dims, vec![0.0; actor::policy::param_count(&dims)]).unwrap();
        let worlds = sim::splits::select(&cfg.run.worlds).unwrap();
        // 250 steps cannot fit in one episode (capped at 200 agent steps).
        assert_eq!(collect_steps(&net, &cfg, cfg.env, &worlds, 0, 250).unwrap(), 250);
    }
}
