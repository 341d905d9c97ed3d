//! Drives episodes with a planner, one control period at a time, under a compute model.

use sim::episode::{Episode, EpisodeConfig, EpisodeResult, Perception, Status};
use sim::robot::Twist;
use sim::World;

use crate::compute::{periods, Budget, Compute, ComputeTally, CycleWork};
use crate::moving::{ForecastErrors, Predicted, Tracking, TrackingConfig};
use crate::padp::{Padp, PadpConfig, PadpParts};
use crate::residual::Corrector;
use crate::residual_fit::{record_samples, Sample};
use crate::{PlanInput, Planner, Prediction, Schedule};
use std::sync::Arc;

/// The planning loop of one episode: every control period either runs a planning cycle or,
/// while the previous cycle's modelled compute still runs, lets the robot keep its command.
///
/// Under a compute model a cycle's command takes effect after its modelled compute time (on
/// top of the profile's sensing and actuation latency, [`Episode::step_after`]); a cycle
/// that needs `k` > 1 control periods ([`periods`]) makes the next `k - 1` periods hold. The
/// free model (`None`) plans every period and applies the command after the profile's fixed
/// latency, exactly as before the model.
///
/// With [`CycleDriver::with_tracking`], every planning cycle first runs the obstacle tracker
/// on the episode's scan and hands the planner the moving obstacles it predicts
/// ([`crate::moving`]); without it the planner is told of none. With
/// [`CycleDriver::with_padp`] PADP then runs on the tracks before the planner
/// ([`crate::padp`]). One per episode.
#[derive(Clone, Debug)]
pub struct CycleDriver {
    compute: Option<Compute>,
    control_dt: f64,
    /// Periods still to hold before the next cycle.
    holding: u32,
    tally: ComputeTally,
    tracking: Option<Tracking>,
    padp: Option<Padp>,
    /// The tracker's forecast against the truth, when measured.
    forecast_errors: Option<ForecastErrors>,
    /// The residual corrector's training samples, when logged.
    samples: Option<Vec<Sample>>,
}

impl CycleDriver {
    /// A driver for periods of `control_dt` seconds under `compute` (`None`: free).
    pub fn new(compute: Option<Compute>, control_dt: f64) -> Self {
        Self {
            compute,
            control_dt,
            holding: 0,
            tally: ComputeTally::default(),
            tracking: None,
            padp: None,
            forecast_errors: None,
            samples: None,
        }
    }

    /// The same driver, predicting moving obstacles with a tracker of `cfg`.
    pub fn with_tracking(mut self, cfg: TrackingConfig) -> Self {
        self.tracking = Some(Tracking::new(cfg));
        self
    }

    /// The same driver correcting the tracker's forecast with PADP's residual `corrector`
    /// ([`crate::residual`]). Panics without tracking ([`CycleDriver::with_tracking`] first).
    pub fn with_corrector(mut self, corrector: Arc<Corrector>) -> Self {
        let tracking = self
            .tracking
            .take()
            .expect("CycleDriver::with_corrector needs with_tracking first");
        self.tracking = Some(tracking.with_corrector(corrector));
        self
    }

    /// The same driver logging the residual corrector's training samples every cycle
    /// ([`record_samples`]; a harness tool: the planner sees none of it). It logs only with
    /// tracking.
    pub fn with_samples(mut self) -> Self {
        self.samples = Some(Vec::new());
        self
    }

    /// The samples logged so far (empty when not logging).
    pub fn take_samples(&mut self) -> Vec<Sample> {
        self.samples.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// The same driver running the `parts` of PADP with `cfg` (validated by the caller:
    /// [`PadpConfig::validate`]) on the tracker's forecast: it runs only with tracking
    /// ([`CycleDriver::with_tracking`]).
    pub fn with_padp(mut self, cfg: PadpConfig, parts: PadpParts) -> Self {
        self.padp = Some(Padp::new(cfg, parts));
        self
    }

    /// The same driver measuring the tracker's forecast against the episode's ground truth
    /// every cycle ([`ForecastErrors`]; a harness metric: the planner sees none of it). It
    /// measures only with tracking.
    pub fn with_forecast_errors(mut self) -> Self {
        self.forecast_errors = Some(ForecastErrors::default());
        self
    }

    /// The forecast errors so far, when measured.
    pub fn forecast_errors(&self) -> Option<&ForecastErrors> {
        self.forecast_errors.as_ref()
    }

    /// PADP, when on.
    pub fn padp(&self) -> Option<&Padp> {
        self.padp.as_ref()
    }

    /// The obstacle tracking, when on.
    pub fn tracking(&self) -> Option<&Tracking> {
        self.tracking.as_ref()
    }

    /// The compute model (`None`: free).
    pub fn compute(&self) -> Option<&Compute> {
        self.compute.as_ref()
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
        if self.holds() {
            return ep.hold();
        }
        if let Some(t) = &mut self.tracking {
            t.update(ep);
            if let Some(e) = &mut self.forecast_errors {
                e.record(ep, t);
            }
            if let Some(s) = &mut self.samples {
                record_samples(ep, t, s);
            }
        }
        if let (Some(p), Some(t)) = (&mut self.padp, &self.tracking) {
            p.cycle(ep, t, planner);
            if p.parts().adapt {
                self.tally.pressure_cycles[p.mode().index()] += 1;
            }
        }
        let moving = match &self.tracking {
            Some(t) => t.moving(),
            None => &[],
        };
        let cmd = Self::plan(
            self.compute.as_ref(),
            planner,
            ep.perception(),
            schedule,
            max_speed,
            prediction,
            moving,
        );
        on_cycle(ep, &mut *planner, cmd);
        match self.charge(planner) {
            None => ep.step(cmd),
            Some(compute_s) => ep.step_after(cmd, compute_s),
        }
    }

    /// Whether this control period holds the last command because the last cycle's modelled
    /// compute still runs; counts the hold down. The first half of [`CycleDriver::period`]
    /// for a caller that owns the perception (a robot's runtime): when it is `false`, plan
    /// with [`CycleDriver::plan_cycle`].
    pub fn holds(&mut self) -> bool {
        if self.holding > 0 {
            self.holding -= 1;
            return true;
        }
        false
    }

    /// Plans one cycle on `perception` with `planner` (no moving obstacles: a caller without
    /// tracking) and charges it (records its work in the tally): returns the command and its
    /// modelled compute time (`None` under the free model, where it acts after the fixed
    /// latency). Call it only when [`CycleDriver::holds`] said `false`.
    pub fn plan_cycle(
        &mut self,
        planner: &mut dyn Planner,
        perception: Perception<'_>,
        schedule: &Schedule,
        max_speed: f64,
        prediction: Prediction,
    ) -> (Twist, Option<f64>) {
        let cmd = Self::plan(
            self.compute.as_ref(),
            planner,
            perception,
            schedule,
            max_speed,
            prediction,
            &[],
        );
        (cmd, self.charge(planner))
    }

    /// One planning call under the budget of `compute`.
    fn plan(
        compute: Option<&Compute>,
        planner: &mut dyn Planner,
        perception: Perception<'_>,
        schedule: &Schedule,
        max_speed: f64,
        prediction: Prediction,
        moving: &[Predicted],
    ) -> Twist {
        planner.plan(&PlanInput {
            perception,
            schedule,
            max_speed,
            prediction,
            budget: Budget::of(compute),
            moving,
        })
    }

    /// Records the work of `planner`'s last cycle in the tally and, under a compute model,
    /// how many periods the next cycles hold for it; returns its modelled compute time
    /// (`None` under the free model).
    fn charge(&mut self, planner: &dyn Planner) -> Option<f64> {
        let cycle = planner.trace().cycle;
        match &self.compute {
            None => {
                self.tally.record(&cycle, 0.0, self.control_dt);
                None
            }
            Some(c) => {
                let compute_s = c.costs.cycle_ns(&cycle.work) * 1e-9;
                self.tally.record(&cycle, compute_s, self.control_dt);
                self.holding = periods(compute_s, self.control_dt) - 1;
                Some(compute_s)
            }
        }
    }

    /// Charges a cycle that issued a command without planning (the velocity action space):
    /// no work and no modelled compute. Returns `Some(0.0)` under a compute model (the
    /// command acts after the profile's latency less its planning share), `None` under the
    /// free model.
    pub fn charge_command(&mut self) -> Option<f64> {
        self.tally.record(&CycleWork::default(), 0.0, self.control_dt);
        self.compute.as_ref().map(|_| 0.0)
    }

    /// Simulates one control period of `ep` issuing `cmd` without planning (the velocity
    /// action space's pure-RL policy): a cycle of no work and no modelled compute, so under a
    /// compute model the command acts after the profile's latency less its planning share.
    /// Returns the episode's status.
    pub fn command(&mut self, ep: &mut Episode<'_>, cmd: Twist) -> Status {
        match self.charge_command() {
            None => ep.step(cmd),
            Some(compute_s) => ep.step_after(cmd, compute_s),
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
    on_cycle: impl FnMut(&Episode<'_>, &mut dyn Planner, Twist),
) -> (EpisodeResult, ComputeTally) {
    let mut driver = CycleDriver::new(compute, cfg.control_dt);
    let result = drive_episode(
        world,
        cfg,
        planner,
        schedule,
        max_speed,
        seed,
        &mut driver,
        on_cycle,
    );
    (result, *driver.tally())
}

/// [`run_episode`] with a driver of the caller's (for example one that tracks moving
/// obstacles: [`CycleDriver::with_tracking`]), kept by the caller to read what it measured
/// afterwards (its tally, its forecast errors); returns the result.
#[allow(clippy::too_many_arguments)]
pub fn drive_episode(
    world: &World,
    cfg: EpisodeConfig,
    planner: &mut dyn Planner,
    schedule: &Schedule,
    max_speed: f64,
    seed: u64,
    driver: &mut CycleDriver,
    mut on_cycle: impl FnMut(&Episode<'_>, &mut dyn Planner, Twist),
) -> EpisodeResult {
    let mut ep = Episode::new(world, cfg, seed);
    let prediction = Prediction::for_profile(cfg.profile);
    while ep.status() == Status::Running {
        driver.period(&mut ep, planner, schedule, max_speed, prediction, &mut on_cycle);
    }
    ep.result()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compute::{UnitCosts, Work};
    use crate::Trace;
    use sim::EpisodeConfig;

    /// Drives straight at 1 m/s and reports 1,000 check points of work every cycle.
    struct Straight {
        trace: Trace,
        calls: u32,
    }

    impl Planner for Straight {
        fn name(&self) -> &'static str {
            "dwa"
        }

        fn plan(&mut self, _: &PlanInput<'_>) -> Twist {
            self.calls += 1;
            self.trace.cycle = CycleWork {
                work: Work {
                    points: 1000,
                    ..Work::default()
                },
                samples: 1,
                evaluated: 1,
            };
            Twist::new(1.0, 0.0)
        }

        fn trace(&self) -> &Trace {
            &self.trace
        }

        fn trace_mut(&mut self) -> &mut Trace {
            &mut self.trace
        }
    }

    fn compute(point_ns: f64) -> Compute {
        Compute {
            costs: UnitCosts {
                point_ns,
                ..UnitCosts::ZERO
            },
            budget_ns: f64::INFINITY,
        }
    }

    /// Runs 6 control periods; returns the planning calls, the tally and the speed after each
    /// period.
    fn drive(compute: Option<Compute>) -> (u32, ComputeTally, Vec<f64>) {
        let world = World::corridor(1.5, &[]);
        let cfg = EpisodeConfig::default().with_profile(sim::Profile::Ideal, None);
        let mut ep = Episode::new(&world, cfg, 1);
        let mut p = Straight {
            trace: Trace::default(),
            calls: 0,
        };
        let mut d = CycleDriver::new(compute, cfg.control_dt);
        let mut speeds = Vec::new();
        for _ in 0..6 {
            d.period(
                &mut ep,
                &mut p,
                &Schedule::vanilla(),
                1.0,
                Prediction::IDEAL,
                &mut |_, _, _| {},
            );
            speeds.push(ep.state().vel.v);
        }
        (p.calls, *d.tally(), speeds)
    }

    #[test]
    fn the_command_waits_for_the_modelled_compute_and_a_late_cycle_holds_the_next() {
        // Free: every period plans; the ideal robot (no latency) moves in the first period.
        let (calls, tally, speeds) = drive(None);
        assert_eq!((calls, tally.cycles, tally.late_cycles), (6, 6, 0));
        assert!(speeds[0] > 0.0);
        // 30 ms of compute (1,000 points x 30 us): the command acts 0.03 s into the first
        // period (the ideal profile has no latency to replace), still every period plans.
        let (calls, tally, speeds) = drive(Some(compute(30_000.0)));
        assert_eq!((calls, tally.late_cycles), (6, 0));
        assert!((tally.modelled_ms - 180.0).abs() < 1e-9);
        let (_, _, free) = drive(None);
        assert!(speeds[0] > 0.0 && speeds[0] < free[0], "{speeds:?} vs {free:?}");
        // 70 ms: each cycle takes two periods, so every other period holds the command.
        let (calls, tally, _) = drive(Some(compute(70_000.0)));
        assert_eq!((calls, tally.cycles, tally.late_cycles), (3, 3, 3));
    }

    #[test]
    fn same_seed_same_trajectory_under_a_budget() {
        let world = sim::catalog::world(120).unwrap();
        let run = || {
            let mut dwa = crate::Dwa::new(crate::DwaConfig::default());
            let compute = crate::ComputeConfig::default().resolve("dwa").unwrap();
            run_episode(
                world,
                EpisodeConfig::default(),
                &mut dwa,
                &Schedule::ddp_default(),
                1.5,
                7,
                compute,
                |_, _, _| {},
            )
        };
        let (a, ta) = run();
        let (b, tb) = run();
        assert_eq!((a, ta), (b, tb));
        assert!(ta.modelled_ms > 0.0 && ta.samples > 0);
    }
}
