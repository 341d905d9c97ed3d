//! "It learns": a 2-D point mass with inertia must reach a goal. TD3 with n-step replay, the
//! rate limiter and the exploration schedule, through the public API only, from a fixed seed
//! and within a fixed budget of agent steps and updates.

use burn::tensor::Device;
use learner::{
    seeded_rng, Batch, ExplorationSchedule, RateLimiter, ReplayBuffer, Step, StepEnd, Td3, Td3Config,
};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

/// Steps before a time-limit truncation.
const CAP: usize = 40;
/// Distance at which the goal (the origin) counts as reached.
const GOAL: f32 = 0.1;

/// Position and velocity; the observation is `[x, y, vx, vy]`.
#[derive(Clone, Copy)]
struct PointMass {
    p: [f32; 2],
    v: [f32; 2],
}

impl PointMass {
    /// At distance 0.8 from the goal in direction `angle`, at rest.
    fn new(angle: f32) -> Self {
        Self {
            p: [0.8 * angle.cos(), 0.8 * angle.sin()],
            v: [0.0; 2],
        }
    }

    fn obs(&self) -> [f32; 4] {
        [self.p[0], self.p[1], self.v[0], self.v[1]]
    }

    fn dist(&self) -> f32 {
        self.p[0].hypot(self.p[1])
    }

    /// Accelerate by `a` in [-1, 1]^2; reward `10 * progress - 0.1`, `+5` on reaching the goal.
    fn step(&mut self, a: &[f32]) -> (f32, bool) {
        let before = self.dist();
        for ((p, v), a) in self.p.iter_mut().zip(&mut self.v).zip(a) {
            *v = 0.8 * *v + 0.2 * a;
            *p = (*p + 0.1 * *v).clamp(-1.5, 1.5);
        }
        let reached = self.dist() < GOAL;
        let reward = 10.0 * (before - self.dist()) - 0.1 + if reached { 5.0 } else { 0.0 };
        (reward, reached)
    }
}

/// Greedy return and success over 16 evenly spread starts.
fn evaluate(td3: &Td3) -> (f32, f32) {
    let policy = td3.policy();
    let mut no_noise = Pcg64Mcg::new(0);
    let (mut total, mut successes) = (0.0, 0);
    for k in 0..16 {
        let mut env = PointMass::new(k as f32 * std::f32::consts::TAU / 16.0 + 0.1);
        for _ in 0..CAP {
            let action = policy.act(&env.obs(), 0.0, &mut no_noise);
            let (reward, reached) = env.step(&action);
            total += reward;
            if reached {
                successes += 1;
                break;
            }
        }
    }
    (total / 16.0, successes as f32 / 16.0)
}

#[test]
fn td3_learns_to_reach_the_goal_with_a_point_mass() {
    let config = Td3Config {
        obs_dim: 4,
        act_dim: 2,
        laser_dim: 0,
        actor_hidden: vec![64, 64],
        critic_hidden: vec![64, 64],
        actor_lr: 1e-3,
        critic_lr: 1e-3,
        batch_size: 64,
        n_step: 3,
        replay_capacity: 20_000,
        warmup_steps: 500,
        exploration_start: 0.5,
        exploration_end: 0.1,
        exploration_steps: 4_000,
        actor_warmup_updates: 0,
        rate_tolerance: 8.0,
        seed: 3,
        ..Td3Config::default()
    };
    let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
    let mut replay = ReplayBuffer::new(&config);
    let mut rate = RateLimiter::new(&config);
    let schedule = ExplorationSchedule::new(&config, 5_000);
    let mut env_rng = seeded_rng(config.seed, 20);
    let mut act_rng = seeded_rng(config.seed, 21);
    let mut sampler = seeded_rng(config.seed, 2);
    let mut batch = Batch::new(config.obs_dim, config.act_dim);
    let (initial_return, initial_success) = evaluate(&td3);

    let mut episode = 0u64;
    let mut env = PointMass::new(env_rng.random_range(0.0..std::f32::consts::TAU));
    let mut t = 0;
    let mut policy = td3.policy();
    while rate.inserts() < 5_000 {
        let obs = env.obs();
        let sigma = schedule.sigma(rate.inserts());
        let action = policy.act(&obs, sigma, &mut act_rng);
        let (reward, reached) = env.step(&action);
        t += 1;
        let next = env.obs();
        let end = if reached {
            StepEnd::Terminal
        } else if t == CAP {
            StepEnd::Truncated { final_obs: &next }
        } else {
            StepEnd::Continue
        };
        replay
            .push(
                episode,
                &Step {
                    obs: &obs,
                    action: &action,
                    reward,
                    end,
                },
            )
            .unwrap();
        rate.record_inserts(1);
        if end != StepEnd::Continue {
            episode += 1;
            t = 0;
            env = PointMass::new(env_rng.random_range(0.0..std::f32::consts::TAU));
        }
        let updates = rate.updates_allowed();
        for _ in 0..updates {
            replay
                .sample(config.batch_size, &mut sampler, &mut batch)
                .unwrap();
            td3.update(&batch).unwrap();
        }
        rate.record_updates(updates);
        if updates > 0 {
            policy = td3.policy();
        }
    }
    let (final_return, final_success) = evaluate(&td3);
    println!(
        "point mass: greedy return {initial_return:.2} -> {final_return:.2}, success \
         {initial_success:.2} -> {final_success:.2}, {} updates, {episode} episodes",
        td3.updates()
    );
    assert!(
        final_success >= 0.9 && final_return > 8.0,
        "return {final_return}, success {final_success}"
    );
}
