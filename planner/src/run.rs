//! Drives one episode with a planner and a fixed schedule.

use sim::episode::{Episode, EpisodeConfig, EpisodeResult, Status};
use sim::robot::Twist;
use sim::World;

use crate::{PlanInput, Planner, Prediction, Schedule};

/// Runs `planner` on `world` until the episode ends, predicting with the model of the
/// episode's profile; returns the result and the number of planning cycles. `on_cycle` sees
/// the episode, the planner and its command after every planning call, before the command
/// is applied (drawing, tracing; it may turn rollout recording on for the next cycle); pass
/// `|_, _, _| {}` when not needed.
pub fn run_episode(
    world: &World,
    cfg: EpisodeConfig,
    planner: &mut dyn Planner,
    schedule: &Schedule,
    max_speed: f64,
    seed: u64,
    mut on_cycle: impl FnMut(&Episode<'_>, &mut dyn Planner, Twist),
) -> (EpisodeResult, u64) {
    let mut ep = Episode::new(world, cfg, seed);
    let prediction = Prediction::for_profile(cfg.profile);
    let mut cycles = 0;
    while ep.status() == Status::Running {
        let cmd = planner.plan(&PlanInput {
            perception: ep.perception(),
            schedule,
            max_speed,
            prediction,
        });
        on_cycle(&ep, &mut *planner, cmd);
        ep.step(cmd);
        cycles += 1;
    }
    (ep.result(), cycles)
}
