//! Drives episodes with a planner, one control period at a time, under a compute model.

use sim::episode::{Episode, EpisodeConfig, EpisodeResult, Status};
use sim::robot::Twist;
use sim::World;

use crate::compute::{periods, Budget, Compute, ComputeTally};
use crate::{PlanInput, Planner, Prediction, Schedule};

/// The planning loop of one episode: every control period either runs a planning cycle or,
/// while the previous cycle's modelled compute still runs, lets the robot keep its command.
///
/// Under a compute model a cycle's command takes effect after its modelled compute time (on
/// top of the profile's sensing and actuation latency, [`Episode::step_after`]); a cycle
/// that needs `k` > 1 control periods ([`periods`]) makes the next `k - 1` periods hold. The
/// free model (`None`) plans every period and applies the command after the profile's fixed
/// latency, exactly as before the model. Plain data; one per episode.
#[derive(Clone, Debug)]
pub struct CycleDriver {
    compute: Option<Compute>,
    control_dt: f64,
    /// Periods still to hold before the next cycle.
    holding: u32,
    tally: ComputeTally,
}

impl CycleDriver {
    /// A driver for periods of `control_dt` seconds under `compute` (`None`: free).
    pub fn new(compute: Option<Compute>, control_dt: f64) -> Self {
        Self {
            compute,
            control_dt,
            holding: 0,
            tally: ComputeTally::default(),
        }
    }

    /// What the cycles so far did and cost.
    pub fn tally(&self) -> &ComputeTally {
        &self.tally
    }

    /// Simulates one control period of `ep`: plans with `planner` on `schedule` unless the
    /// last cycle is still computing. `on_cycle` sees the episode, the planner and the command
    /// after each planning call, before the command is issued. Returns the episode's status.
    #[allow(clippy::too_many_arguments)]
    pub fn period(
        &mut self,
        ep: &mut Episode<'_>,
        planner: &mut dyn Planner,
        schedule: &Schedule,
        max_speed: f64,
        prediction: Prediction,
        on_cycle: &mut impl FnMut(&Episode<'_>, &mut dyn Planner, Twist),
    ) -> Status {
        if self.holding > 0 {
            self.holding -= 1;
            return ep.hold();
        }
        let cmd = planner.plan(&PlanInput {
            perception: ep.perception(),
            schedule,
            max_speed,
            prediction,
            budget: Budget::of(self.compute.as_ref()),
        });
        on_cycle(ep, &mut *planner, cmd);
        let cycle = planner.trace().cycle;
        match &self.compute {
            None => {
                self.tally.record(&cycle, 0.0, self.control_dt);
                ep.step(cmd)
            }
            Some(c) => {
                let compute_s = c.costs.cycle_ns(&cycle.work) * 1e-9;
                self.tally.record(&cycle, compute_s, self.control_dt);
                self.holding = periods(compute_s, self.control_dt) - 1;
                ep.step_after(cmd, compute_s)
            }
        }
    }
}

/// Runs `planner` on `world` until the episode ends, predicting with the model of the
/// episode's profile, under the compute model `compute` (`None`: free); returns the result
/// and what its planning cycles did and cost. `on_cycle` sees the episode, the planner and
/// its command after every planning call, before the command is applied (drawing, tracing;
/// it may turn rollout recording on for the next cycle); pass `|_, _, _| {}` when not needed.
#[allow(clippy::too_many_arguments)]
pub fn run_episode(
    world: &World,
    cfg: EpisodeConfig,
    planner: &mut dyn Planner,
    schedule: &Schedule,
    max_speed: f64,
    seed: u64,
    compute: Option<Compute>,
    mut on_cycle: impl FnMut(&Episode<'_>, &mut dyn Planner, Twist),
) -> (EpisodeResult, ComputeTally) {
    let mut ep = Episode::new(world, cfg, seed);
    let prediction = Prediction::for_profile(cfg.profile);
    let mut driver = CycleDriver::new(compute, cfg.control_dt);
    while ep.status() == Status::Running {
        driver.period(&mut ep, planner, schedule, max_speed, prediction, &mut on_cycle);
    }
    (ep.result(), *driver.tally())
}
