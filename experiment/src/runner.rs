//! Runs one controller on a set of worlds with the papers' protocol, in parallel over
//! (world, run) with rayon like `adp eval`: run r of world w uses the seed
//! [`eval::run_seed`]`(seed, w, r)` whatever the controller, so the runs of two
//! controllers pair by seed (the same sensor noise, drift and start jitter).
//!
//! A controller is a schedule held for the whole run (DDP, a constant action: the plain
//! episode driver) or a network choosing the schedule every agent step through the RL
//! environment, either from the step's own observation ([`Controller::Policy`]) or from an
//! observation drawn from a pool of other steps' ([`Controller::Shuffled`]).

use anyhow::Context;
use planner::PlannerKind;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use actor::closed_loop::{self, Act, Chooser, Constant, Greedy};
use actor::{EnvConfig, MlpPolicy};
use planner::run::CycleDriver;
use planner::{ActionSpace, ComputeTally, Schedule, TrackingConfig};
use sim::{EpisodeResult, World};

use eval::EvalConfig;
use eval::{eval_run, run_seed, WorldRuns};

use super::stats::SplitMix64;

/// What chooses the schedule.
pub enum Controller<'a> {
    /// One schedule for the whole run.
    Schedule(Schedule),
    /// One action of a space that sets more than the schedule (objective gains, or the
    /// velocity space's command), applied at every agent step through the ADP environment
    /// with the affine map (so the action is the box action itself). Built by
    /// [`Controller::constant`].
    Constant {
        /// The box action.
        action: Vec<f32>,
        /// Its action space.
        space: ActionSpace,
        /// The environment settings the arm trains with.
        env: EnvConfig,
    },
    /// A network run greedily on each step's observation.
    Policy {
        /// The network.
        net: &'a MlpPolicy,
        /// The environment settings it was trained with.
        env: EnvConfig,
        /// Its action space.
        space: ActionSpace,
    },
    /// A network run greedily on observations drawn (seeded per run) from `pool` instead of
    /// the step's own.
    Shuffled {
        /// The network.
        net: &'a MlpPolicy,
        /// The environment settings it was trained with.
        env: EnvConfig,
        /// Its action space.
        space: ActionSpace,
        /// Observations of other steps.
        pool: &'a [Vec<f32>],
        /// Seed of the draws.
        seed: u64,
    },
}

impl<'a> Controller<'a> {
    /// The constant `action` of `space`: its schedule when the space only sets schedules
    /// (`points` boundary points, as every schedule of the experiment); otherwise the action
    /// itself, applied each agent step in an environment of `env` (gains and commands are
    /// set per agent step, which a schedule cannot carry).
    pub fn constant(
        space: ActionSpace,
        action: &[f64],
        points: usize,
        env: EnvConfig,
    ) -> anyhow::Result<Self> {
        if space.gains().is_none() && space != ActionSpace::Velocity {
            return Ok(Controller::Schedule(space.schedule_only(action, points)?));
        }
        // Refuses a wrong length or a non-finite value before any run starts.
        space.to_params(action)?;
        Ok(Controller::Constant {
            action: action.iter().map(|&x| x as f32).collect(),
            space,
            env: EnvConfig {
                action_map: planner::ActionMap::Affine,
                ..env
            },
        })
    }

    /// A trained (or untrained) policy run greedily on each step's own observation.
    pub fn of(p: &'a eval::policy::LearnedPolicy) -> Self {
        Controller::Policy {
            net: &p.net,
            env: p.env,
            space: p.space,
        }
    }
}

/// Where and how often to run.
pub struct RunSpec<'a> {
    /// Planner tunables and the episode protocol.
    pub cfg: &'a EvalConfig,
    /// Every world, indexed by id.
    pub worlds: &'a [World],
    /// The planner.
    pub planner: PlannerKind,
    /// Speed cap (m/s).
    pub speed: f64,
    /// World ids to run.
    pub world_ids: &'a [usize],
    /// Runs per world.
    pub runs: usize,
    /// When not empty: exactly these (world, run) pairs, instead of every run of
    /// `world_ids` (the constant search's rungs).
    pub pairs: &'a [(usize, usize)],
    /// Base seed.
    pub seed: u64,
    /// Record the chosen schedule and the clutter of every agent step of run 0 of every
    /// world (network controllers only).
    pub trace: bool,
    /// Run the moving-obstacle tracker in the schedule controllers' runs too, so that they
    /// plan with its forecast as the policies do whose environment observes tracks
    /// (`[train.env] observe_tracks > 0`).
    pub track: bool,
}

/// Every run of one world, in run order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldOutcome {
    /// World id.
    pub world: usize,
    /// Runs in run order.
    pub runs: Vec<EpisodeResult>,
}

impl WorldOutcome {
    /// As `adp eval`'s type, for [`eval::summarize`].
    pub fn to_world_runs(&self) -> WorldRuns {
        WorldRuns {
            world: self.world,
            runs: self.runs.clone(),
        }
    }
}

/// One agent step of a traced run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TracePoint {
    /// World id.
    pub world: usize,
    /// Local clutter of the step's observation ([`actor::observation::clutter`]).
    pub clutter: f64,
    /// The chosen schedule's physical parameters ([`ActionSpace::to_params`]).
    pub params: Vec<f64>,
}

/// Results of one controller.
pub struct Evaluation {
    /// Per world, every run.
    pub per_world: Vec<WorldOutcome>,
    /// The traced steps (empty unless asked for).
    pub trace: Vec<TracePoint>,
    /// Observations seen (when collecting; see [`observations`]).
    pub observations: Vec<Vec<f32>>,
    /// What every run's planning cycles did and cost, summed.
    pub compute: ComputeTally,
}

/// Runs `ctrl` on every world and run of `spec`.
pub fn evaluate(spec: &RunSpec<'_>, ctrl: &Controller<'_>) -> anyhow::Result<Evaluation> {
    run_all(spec, ctrl, false)
}

/// Runs `ctrl` (a network) on every world and run of `spec` and returns, besides the
/// results, every observation it saw, in (world, run, step) order.
pub fn observations(spec: &RunSpec<'_>, ctrl: &Controller<'_>) -> anyhow::Result<Evaluation> {
    run_all(spec, ctrl, true)
}

fn run_all(spec: &RunSpec<'_>, ctrl: &Controller<'_>, collect: bool) -> anyhow::Result<Evaluation> {
    let jobs: Vec<(usize, usize)> = if spec.pairs.is_empty() {
        spec.world_ids
            .iter()
            .flat_map(|&w| (0..spec.runs).map(move |r| (w, r)))
            .collect()
    } else {
        spec.pairs.to_vec()
    };
    for &(w, _) in &jobs {
        spec.worlds.get(w).with_context(|| {
            format!(
                "world {w} is not in the loaded data ({} worlds)",
                spec.worlds.len()
            )
        })?;
    }
    let results: Vec<RunOut> = jobs
        .par_iter()
        .map(|&(w, r)| run_one(spec, ctrl, w, r, collect).with_context(|| format!("world {w}, run {r}")))
        .collect::<anyhow::Result<_>>()?;
    let mut per_world: Vec<WorldOutcome> = Vec::new();
    let mut trace = Vec::new();
    let mut observations = Vec::new();
    let mut compute = ComputeTally::default();
    for (&(w, _), (res, tally, tr, obs)) in jobs.iter().zip(results) {
        compute += tally;
        match per_world.last_mut() {
            Some(last) if last.world == w => last.runs.push(res),
            _ => per_world.push(WorldOutcome {
                world: w,
                runs: vec![res],
            }),
        }
        trace.extend(tr);
        observations.extend(obs);
    }
    Ok(Evaluation {
        per_world,
        trace,
        observations,
        compute,
    })
}

/// What one run returns: its result, its planning cycles' compute, its trace and its
/// observations.
type RunOut = (EpisodeResult, ComputeTally, Vec<TracePoint>, Vec<Vec<f32>>);

/// A network fed, every agent step, an observation drawn from `pool` with its seeded stream
/// instead of the step's own (the state-shuffled control).
struct Drawn<'a> {
    greedy: Greedy<'a>,
    pool: &'a [Vec<f32>],
    rng: SplitMix64,
}

impl Act for Drawn<'_> {
    fn act(&mut self, obs: &[f32], action: &mut [f32]) {
        let input = if self.pool.is_empty() {
            obs
        } else {
            &self.pool[self.rng.below(self.pool.len())]
        };
        self.greedy.act(input, action);
    }
}

/// One run; returns its result, its planning cycles' compute, its trace (run 0 of a network
/// controller with `spec.trace`) and, with `collect`, its observations.
fn run_one(
    spec: &RunSpec<'_>,
    ctrl: &Controller<'_>,
    w: usize,
    r: usize,
    collect: bool,
) -> anyhow::Result<RunOut> {
    let seed = run_seed(spec.seed, w, r);
    let run = eval_run(spec.cfg, &spec.worlds[w], spec.planner, spec.speed, seed);
    let (mut constant, mut greedy, mut drawn);
    let (space, env, act, network): (_, _, &mut dyn Act, _) = match ctrl {
        Controller::Schedule(s) => {
            let mut driver = CycleDriver::new(
                spec.cfg.compute.resolve(spec.planner.name())?,
                spec.cfg.episode.control_dt,
            );
            if spec.track {
                driver = driver.with_tracking(TrackingConfig::default());
            }
            let chooser = Chooser::Fixed {
                schedule: s,
                driver: &mut driver,
            };
            let out = closed_loop::run(run, chooser, |_| anyhow::Ok(()))?;
            return Ok((out.episode, out.compute, Vec::new(), Vec::new()));
        }
        Controller::Constant { action, space, env } => {
            constant = Constant(action);
            (*space, *env, &mut constant, false)
        }
        Controller::Policy { net, env, space } => {
            greedy = Greedy::new(net);
            (*space, *env, &mut greedy, true)
        }
        Controller::Shuffled {
            net,
            env,
            space,
            pool,
            seed: s,
        } => {
            drawn = Drawn {
                greedy: Greedy::new(net),
                pool,
                rng: SplitMix64::new(*s ^ seed),
            };
            (*space, *env, &mut drawn, true)
        }
    };
    let chooser = Chooser::Env {
        space,
        env: &EnvConfig {
            compute: spec.cfg.compute,
            ..env.for_evaluation()
        },
        act,
    };
    let record = network && spec.trace && r == 0;
    let (mut trace, mut seen) = (Vec::new(), Vec::new());
    let out = closed_loop::run(run, chooser, |step| {
        if record {
            trace.push(TracePoint {
                world: w,
                clutter: step.clutter,
                params: step.env.chosen_params().context("a step without its schedule")?,
            });
        }
        if collect && network {
            seen.push(step.obs.to_vec());
        }
        anyhow::Ok(())
    })?;
    Ok((out.episode, out.compute, trace, seen))
}

/// A seeded reservoir sample (algorithm R) of at most `k` of `items`, in draw order.
pub fn reservoir<T: Clone>(items: &[T], k: usize, seed: u64) -> Vec<T> {
    let mut rng = SplitMix64::new(seed);
    let mut out: Vec<T> = Vec::with_capacity(k.min(items.len()));
    for (i, item) in items.iter().enumerate() {
        if out.len() < k {
            out.push(item.clone());
        } else {
            let j = rng.below(i + 1);
            if j < k {
                out[j] = item.clone();
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use actor::LASER_BEAMS;

    use super::*;

    #[test]
    fn reservoir_keeps_k_distinct_items_reproducibly() {
        let items: Vec<usize> = (0..1000).collect();
        let a = reservoir(&items, 10, 5);
        assert_eq!(a.len(), 10);
        assert_eq!(a, reservoir(&items, 10, 5));
        assert_ne!(a, reservoir(&items, 10, 6));
        assert!(a.iter().any(|&x| x >= 10), "later items get in");
        assert_eq!(reservoir(&items[..3], 10, 5), vec![0, 1, 2]);
    }

    /// The state-shuffled policy acts on pool observations, not on its own: a network whose
    /// output follows the laser chooses other schedules when fed a pool of one
    /// all-obstacles-close observation.
    #[test]
    fn shuffled_policy_differs_from_the_real_one() {
        let cfg = EvalConfig::load(None).unwrap();
        let space = ActionSpace::Decremental;
        // Layer 730 -> 4: output 1 (T) = tanh(0.002 x sum of the laser encodings).
        let mut flat = vec![0.0f32; 730 * 4];
        for i in 0..LASER_BEAMS {
            flat[i * 4 + 1] = 0.002;
        }
        flat.extend([0.0f32; 4]);
        let net = MlpPolicy::from_flat(&[730, 4], flat).unwrap();
        let spec = RunSpec {
            cfg: &cfg,
            worlds: sim::catalog::worlds(),
            planner: PlannerKind::Dwa,
            speed: 1.5,
            world_ids: &[3],
            runs: 1,
            pairs: &[],
            seed: 9,
            trace: true,
            track: false,
        };
        let env = EnvConfig::default();
        let real = evaluate(
            &spec,
            &Controller::Policy {
                net: &net,
                env,
                space,
            },
        )
        .unwrap();
        let pool = vec![vec![-1.0f32; 730]];
        let shuffled = evaluate(
            &spec,
            &Controller::Shuffled {
                net: &net,
                env,
                space,
                pool: &pool,
                seed: 1,
            },
        )
        .unwrap();
        let t = |e: &Evaluation| e.trace.iter().map(|p| p.params[1]).collect::<Vec<_>>();
        let (a, b) = (t(&real), t(&shuffled));
        assert!(!a.is_empty() && !b.is_empty());
        // Fed only the pool's observation, every step's output is tanh(-1.44) on T.
        let want = env
            .action_map
            .params(space, &[0.0, (-1.44f32).tanh(), 0.0, 0.0])
            .unwrap()[1];
        assert!(b.iter().all(|&x| (x - want).abs() < 1e-4), "{b:?}");
        assert!(a.iter().all(|&x| (x - want).abs() > 0.05), "{a:?}");
        assert_eq!(real.per_world[0].runs.len(), 1);
    }

    /// A constant action of an objective-weight space runs through the environment: at the
    /// gains' centre it is DDP's run exactly; a heavier obstacle gain drives another run.
    #[test]
    fn constant_weight_actions_run_and_the_centre_is_ddp() {
        let cfg = EvalConfig::load(None).unwrap();
        let spec = RunSpec {
            cfg: &cfg,
            worlds: sim::catalog::worlds(),
            planner: PlannerKind::Dwa,
            speed: 1.5,
            world_ids: &[3, 120],
            runs: 1,
            pairs: &[],
            seed: 9,
            trace: false,
            track: false,
        };
        let space = ActionSpace::Weights(planner::Gains::Dwa);
        let env = EnvConfig::default();
        let ddp = evaluate(&spec, &Controller::Schedule(Schedule::ddp_default())).unwrap();
        let centre = Controller::constant(space, &space.ddp_action(), 20, env).unwrap();
        assert!(matches!(centre, Controller::Constant { .. }));
        let same = evaluate(&spec, &centre).unwrap();
        assert_eq!(same.per_world, ddp.per_world);
        // The obstacle gain (the third of DWA's goal, path, obstacle, speed) at its top, 2.
        let mut heavy = space.ddp_action();
        heavy[2] = 1.0;
        let other = evaluate(&spec, &Controller::constant(space, &heavy, 20, env).unwrap()).unwrap();
        assert_ne!(other.per_world, ddp.per_world);
        // A schedule-only space still evaluates its schedule directly; a bad action is refused.
        let d = ActionSpace::Decremental;
        assert!(matches!(
            Controller::constant(d, &d.ddp_action(), 20, env).unwrap(),
            Controller::Schedule(_)
        ));
        assert!(Controller::constant(space, &[0.0; 3], 20, env).is_err());
    }
}
