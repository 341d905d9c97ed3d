//! Drives one episode with a planner and a fixed schedule.

use sim::episode::{Episode, EpisodeConfig, EpisodeResult, Status};
use sim::World;

use crate::{PlanInput, Planner, Schedule};

/// Runs `planner` on `world` until the episode ends; returns the result and the number of
/// planning cycles. `on_cycle` sees the episode and the planner after every planning call,
/// before the command is applied (drawing, tracing; it may turn rollout recording on for the
/// next cycle); pass `|_, _| {}` when not needed.
pub fn run_episode(
    world: &World,
    cfg: EpisodeConfig,
    planner: &mut dyn Planner,
    schedule: &Schedule,
    max_speed: f64,
    seed: u64,
    mut on_cycle: impl FnMut(&Episode<'_>, &mut dyn Planner),
) -> (EpisodeResult, u64) {
    let mut ep = Episode::new(world, cfg, seed);
    let mut cycles = 0;
    while ep.status() == Status::Running {
        let cmd = planner.plan(&PlanInput {
            perception: ep.perception(),
            schedule,
            max_speed,
        });
        on_cycle(&ep, &mut *planner);
        ep.step(cmd);
        cycles += 1;
    }
    (ep.result(), cycles)
}
