//! How each stage is computed: a training through the caller's [`Trainer`], the constant
//! search, and the evaluations of DDP, vanilla, the best constant, the untrained, trained and
//! state-shuffled policies and the sweeps' points, each written atomically to its file in
//! the store.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use serde::Serialize;

use planner::{ActionSpace, Schedule};

use eval::policy::{EvalPolicy, LearnedPolicy};
use eval::EvalConfig;
use train_config::TrainConfig;

use super::config::{self, planner_name, space_label, Arm};
use super::controls::{
    best_constant, candidates, halving, keep_best, search_pairs, shuffle_pool, write_untrained_export,
    Candidate, SearchResult,
};
use super::plan::{write_atomic, Stage, SweepWho};
use super::record::EvalRecord;
use super::runner::{self, evaluate, observations, Controller, RunSpec};
use super::spent::{self, Spent};
use super::{cpu_seconds, Ctx};

/// The best constant action of arm `arm`, from its search's file.
fn best_action(ctx: &Ctx<'_>, arm: usize) -> anyhow::Result<Vec<f64>> {
    let search_file = ctx.layout.output(&Stage::Search { arm });
    let text = std::fs::read_to_string(&search_file)
        .with_context(|| format!("cannot read {}", search_file.display()))?;
    let search: SearchResult = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a search result", search_file.display()))?;
    Ok(search.candidates[search.best].action.clone())
}

/// Whether a run directory has a checkpoint to resume from.
fn has_checkpoint(run_dir: &Path) -> bool {
    std::fs::read_dir(run_dir.join("checkpoints")).is_ok_and(|entries| {
        entries
            .flatten()
            .any(|e| !e.file_name().to_string_lossy().contains("tmp"))
    })
}

/// The marker of a finished training run.
#[derive(Serialize)]
struct Trained {
    arm: String,
    seed_index: usize,
    td3_seed: u64,
    steps: u64,
    agent_steps: u64,
    updates: u64,
    export: PathBuf,
}

/// Trains one seed of one arm with `adp train` in its run directory (resuming a run that
/// stopped), then checks its export and writes the marker. Returns the time of every run
/// that worked on it ([`Spent`]) and, when some run's time is missing, the agent steps that
/// time covers ([`spent::timed_units`]). A run that stops before the end adds its time to the
/// run directory's account and fails, saying to resume.
pub(crate) fn train(ctx: &Ctx<'_>, arm: usize, seed: usize) -> anyhow::Result<(Spent, Option<f64>)> {
    let a = &ctx.ex.arms[arm];
    let cfg = run_train_config(ctx, arm, seed)?;
    let run_dir = ctx.layout.run_dir(arm, seed);
    let file = run_dir.join("experiment-train.toml");
    write_atomic(
        &file,
        toml::to_string_pretty(&cfg)
            .expect("configs serialize")
            .as_bytes(),
    )?;
    let resume = has_checkpoint(&run_dir);
    // The steps this run starts from; `None` when the checkpoint cannot be read here (the
    // trainer then says why, or this run's steps go untimed).
    let resumed_from = if resume {
        checkpoint_steps(&run_dir)
    } else {
        Some(0.0)
    };
    let before = Spent::load(&run_dir).unwrap_or_else(|e| {
        tracing::warn!("{e:#}; timing this training from this run on");
        Spent::default()
    });
    let (t0, cpu0) = (Instant::now(), cpu_seconds());
    ctx.trainer
        .train(&file, &run_dir, resume)
        .with_context(|| format!("training {} seed {seed} in {}", a.id(), run_dir.display()))?;
    let seconds = t0.elapsed().as_secs_f64();
    let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
    let export = run_dir.join("export");
    let policy = load_policy(&export, a.space)?;
    // The run's steps: its final checkpoint's (with `[greedy] select` the export may be an
    // earlier policy, whose card counts its own steps).
    let inserts = checkpoint_steps(&run_dir).map_or(policy.card.source.inserts, |s| s as u64);
    let this_run = resumed_from.map_or(0.0, |from| (inserts as f64 - from).max(0.0));
    let spent = before.plus(seconds, cpu, this_run);
    if inserts < cfg.run.steps {
        if let Err(e) = spent.save(&run_dir) {
            tracing::warn!("{e:#}: this run's time will be missing from the training's record");
        }
        bail!(
            "training {} seed {seed} stopped after {} of {} agent steps; run the experiment again \
             with --resume to continue it",
            a.id(),
            inserts,
            cfg.run.steps
        );
    }
    let timed = spent::timed_units(&before, resumed_from.unwrap_or(f64::INFINITY), this_run);
    write_trained(ctx, arm, seed, &cfg, &policy, export)?;
    Ok((spent, timed))
}

/// The training configuration of arm `arm`'s seed `seed` as it runs:
/// [`Experiment::train_config`], and for an arm that starts from its best constant
/// ([`config::Start::BestConstant`]) that action, read from its constant search's result, as
/// `[service] init_action`.
fn run_train_config(ctx: &Ctx<'_>, arm: usize, seed: usize) -> anyhow::Result<TrainConfig> {
    let a = &ctx.ex.arms[arm];
    let mut cfg = ctx.ex.train_config(a, seed);
    if a.start == config::Start::BestConstant {
        let action = best_action(ctx, arm).with_context(|| {
            format!(
                "{} starts from its best constant: its constant search must be in the store first",
                a.id()
            )
        })?;
        cfg.service.init_action = Some(action);
    }
    Ok(cfg)
}

/// The agent steps of the newest checkpoint of `run_dir` (where a resumed run starts).
fn checkpoint_steps(run_dir: &Path) -> Option<f64> {
    let dir = learner::retention::latest(&run_dir.join("checkpoints")).ok()??;
    Some(learner::checkpoint::read_manifest(&dir).ok()?.inserts as f64)
}

/// Writes the marker of arm `arm`'s finished training `seed` (configuration `cfg`, exported
/// `policy` in `export`): the stage's result.
pub(crate) fn write_trained(
    ctx: &Ctx<'_>,
    arm: usize,
    seed: usize,
    cfg: &TrainConfig,
    policy: &LearnedPolicy,
    export: PathBuf,
) -> anyhow::Result<()> {
    let src = &policy.card.source;
    let marker = Trained {
        arm: ctx.ex.arms[arm].id(),
        seed_index: seed,
        td3_seed: cfg.td3.seed,
        steps: cfg.run.steps,
        agent_steps: src.inserts,
        updates: src.updates,
        export,
    };
    write_atomic(
        &ctx.layout.output(&Stage::Train { arm, seed }),
        &serde_json::to_vec_pretty(&marker).expect("serializes"),
    )
}

/// The trained (or untrained) policy of an export directory, in `space`.
pub(crate) fn load_policy(dir: &Path, space: ActionSpace) -> anyhow::Result<LearnedPolicy> {
    match eval::policy::load(dir, Some(space))? {
        EvalPolicy::Learned(p) => Ok(*p),
        EvalPolicy::Constant { .. } => bail!("{}: not an export directory", dir.display()),
    }
}

/// The run settings of an arm on the test worlds.
fn test_spec<'a>(ctx: &'a Ctx<'_>, a: &Arm, trace: bool) -> RunSpec<'a> {
    RunSpec {
        cfg: &ctx.cfg,
        worlds: ctx.worlds,
        planner: a.planner,
        speed: a.speed,
        world_ids: &ctx.test_worlds,
        runs: ctx.ex.eval.runs,
        pairs: &[],
        seed: ctx.ex.eval.seed,
        trace,
        track: ctx.ex.train.env.observe_tracks > 0,
    }
}

/// A record of `ev` for arm `a`.
fn record(ctx: &Ctx<'_>, a: &Arm, controller: &str, ev: runner::Evaluation) -> EvalRecord {
    EvalRecord {
        controller: controller.into(),
        planner: planner_name(a.planner),
        space: (controller != "ddp").then(|| space_label(a.space)),
        speed: a.speed,
        seed_index: None,
        action: None,
        policy: None,
        runs: ctx.ex.eval.runs,
        trim: ctx.ex.eval.trim,
        seed: ctx.ex.eval.seed,
        per_world: ev.per_world,
        trace: ev.trace,
        compute: ev.compute,
        lidar: None,
    }
}

/// Runs an evaluation or search stage and writes its result to `out`.
pub(crate) fn run_stage(ctx: &Ctx<'_>, stage: &Stage, out: &Path) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let points = planner::schedule::DEFAULT_BOUNDARY_POINTS;
    match *stage {
        Stage::Train { .. } => unreachable!("training runs outside the pool"),
        Stage::Search { arm } => search_stage(ctx, arm, out),
        Stage::EvalDdp { planner, speed } | Stage::EvalVanilla { planner, speed } => {
            let a = ex
                .arms
                .iter()
                .find(|a| a.planner == planner && a.speed == speed)
                .expect("a DDP or vanilla stage comes from an arm");
            let (name, schedule) = match stage {
                Stage::EvalDdp { .. } => ("ddp", Schedule::ddp_default()),
                _ => ("vanilla", Schedule::vanilla()),
            };
            let ev = evaluate(&test_spec(ctx, a, false), &Controller::Schedule(schedule))?;
            record(ctx, a, name, ev).save(out)
        }
        Stage::Sweep { arm, point, who } => sweep_stage(ctx, arm, point, who, out),
        Stage::Sensing { arm, condition, who } => sensing_stage(ctx, arm, condition, who, out),
        Stage::EvalConstant { arm } => {
            let a = &ex.arms[arm];
            let action = best_action(ctx, arm)?;
            let ev = evaluate(
                &test_spec(ctx, a, false),
                &Controller::constant(a.space, &action, points, ctx.ex.train.env)?,
            )?;
            let mut rec = record(ctx, a, "constant", ev);
            rec.action = Some(action);
            rec.save(out)
        }
        Stage::EvalUntrained { arm } => {
            let a = &ex.arms[arm];
            let dir = ctx.layout.untrained_export(arm);
            if !dir.join(learner::export::JSON_FILE).exists() {
                write_untrained_export(&run_train_config(ctx, arm, 0)?, a.space, &dir)?;
            }
            let p = load_policy(&dir, a.space)?;
            let ctrl = Controller::of(&p);
            let mut rec = record(ctx, a, "untrained", evaluate(&test_spec(ctx, a, false), &ctrl)?);
            rec.policy = Some(dir.display().to_string());
            rec.save(out)
        }
        Stage::EvalAdp { arm, seed } | Stage::EvalShuffled { arm, seed } => {
            let a = &ex.arms[arm];
            let dir = ctx.layout.run_dir(arm, seed).join("export");
            let p = load_policy(&dir, a.space)?;
            let policy = Controller::of(&p);
            let (name, ev) = if matches!(stage, Stage::EvalAdp { .. }) {
                ("adp", evaluate(&test_spec(ctx, a, true), &policy)?)
            } else {
                let pool = shuffle_observations(ctx, a, &p)?;
                let ctrl = Controller::Shuffled {
                    net: &p.net,
                    env: p.env,
                    space: p.space,
                    pool: &pool,
                    seed: ex.shuffle.seed,
                };
                ("shuffled", evaluate(&test_spec(ctx, a, false), &ctrl)?)
            };
            let mut rec = record(ctx, a, name, ev);
            rec.seed_index = Some(seed);
            rec.policy = Some(dir.display().to_string());
            rec.save(out)
        }
    }
}

/// The constant search of arm `arm`: successive halving of the candidate constant actions
/// over (world, run) pairs of the constant-search worlds; writes the [`SearchResult`] to
/// `out`.
fn search_stage(ctx: &Ctx<'_>, arm: usize, out: &Path) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let points = planner::schedule::DEFAULT_BOUNDARY_POINTS;
    let a = &ex.arms[arm];
    let s = &ex.search;
    let mut found = candidates(a.space, s.candidates, s.seed)
        .into_iter()
        .map(|action| {
            Ok(Candidate {
                params: a.space.to_params(&action)?,
                action,
                score: 0.0,
                success_pct: 0.0,
                pairs: 0,
                compute_ms_per_cycle: 0.0,
                compute: Default::default(),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    // Successive halving over (world, run) pairs shared by every candidate, so the
    // candidates pair by seed at every rung.
    let pairs = search_pairs(&ex.search_worlds, s.runs, s.seed);
    let rungs = halving(found.len(), s.eta, s.first_pairs, pairs.len());
    let mut sums = vec![(0.0, 0usize); found.len()];
    let mut alive: Vec<usize> = (0..found.len()).collect();
    let mut done = 0;
    for (k, &(keep, upto)) in rungs.iter().enumerate() {
        alive = keep_best(&found, &alive, keep);
        for &i in &alive {
            let spec = RunSpec {
                cfg: &ctx.cfg,
                worlds: ctx.worlds,
                planner: a.planner,
                speed: a.speed,
                world_ids: &[],
                runs: 0,
                pairs: &pairs[done..upto],
                seed: s.seed,
                trace: false,
                track: ctx.ex.train.env.observe_tracks > 0,
            };
            let ctrl = Controller::constant(a.space, &found[i].action, points, ctx.ex.train.env)?;
            let ev = evaluate(&spec, &ctrl)?;
            let c = &mut found[i];
            for r in ev.per_world.iter().flat_map(|w| w.runs.iter()) {
                sums[i].0 += r.score;
                sums[i].1 += usize::from(r.status == sim::Status::Succeeded);
            }
            c.pairs = upto;
            c.score = sums[i].0 / upto as f64;
            c.success_pct = 100.0 * sums[i].1 as f64 / upto as f64;
            c.compute += ev.compute;
            c.compute_ms_per_cycle = c.compute.ms_per_cycle();
        }
        let top = &found[keep_best(&found, &alive, 1)[0]];
        tracing::info!(
            "  rung {k}: {} candidates x {upto} (world, run) pairs; best score {:.4}, success \
             {:.1} %, {:.1} ms per cycle",
            alive.len(),
            top.score,
            top.success_pct,
            top.compute_ms_per_cycle
        );
        done = upto;
    }
    let result = SearchResult {
        space: a.space,
        worlds: ex.search_worlds.clone(),
        runs: s.runs,
        rungs,
        best: best_constant(&found),
        candidates: found,
    };
    write_atomic(out, &serde_json::to_vec_pretty(&result).expect("serializes"))
}

/// One controller (`who`) of arm `arm` at budget-sweep point `point` on the test worlds;
/// writes its record to `out`.
fn sweep_stage(ctx: &Ctx<'_>, arm: usize, point: usize, who: SweepWho, out: &Path) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let mut cfg = ctx.cfg.clone();
    cfg.compute = ex.sweep_points()[point];
    sweep_record(ctx, arm, who, &cfg, (ex.sweep.runs, ex.sweep.trim))?.save(out)
}

/// One controller (`who`) of arm `arm` under sensing condition `condition` on the test
/// worlds (the condition replaces the evaluation's lidar, so the planner's costmap and the
/// policy's observation both see its scans); writes its record, with the lidar, to `out`.
fn sensing_stage(
    ctx: &Ctx<'_>,
    arm: usize,
    condition: usize,
    who: SweepWho,
    out: &Path,
) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let mut cfg = ctx.cfg.clone();
    cfg.episode.lidar = sensing_lidar(ctx, condition)?;
    let mut rec = sweep_record(ctx, arm, who, &cfg, (ex.sensing.runs, ex.sensing.trim))?;
    rec.lidar = Some(cfg.episode.lidar);
    rec.save(out)
}

/// The lidar of sensing condition `condition`: the evaluation configuration's with the
/// condition's values.
pub(crate) fn sensing_lidar(ctx: &Ctx<'_>, condition: usize) -> anyhow::Result<sim::lidar::LidarConfig> {
    ctx.ex.sensing_conditions()[condition]
        .apply(ctx.cfg.episode.lidar)
        .with_context(|| format!("[sensing_sweep] condition {condition}"))
}

/// The record of one controller (`who`) of arm `arm` of a sweep on the test worlds, run
/// with `cfg` and `(runs, trim)`; every controller's run r of world w has the same seed.
fn sweep_record(
    ctx: &Ctx<'_>,
    arm: usize,
    who: SweepWho,
    cfg: &EvalConfig,
    (runs, trim): (usize, usize),
) -> anyhow::Result<EvalRecord> {
    let points = planner::schedule::DEFAULT_BOUNDARY_POINTS;
    let a = &ctx.ex.arms[arm];
    let spec = RunSpec {
        cfg,
        runs,
        ..test_spec(ctx, a, false)
    };
    let (name, ev, action, policy) = match who {
        SweepWho::Ddp => (
            "ddp",
            evaluate(&spec, &Controller::Schedule(Schedule::ddp_default()))?,
            None,
            None,
        ),
        SweepWho::Constant => {
            let action = best_action(ctx, arm)?;
            let ctrl = Controller::constant(a.space, &action, points, ctx.ex.train.env)?;
            ("constant", evaluate(&spec, &ctrl)?, Some(action), None)
        }
        SweepWho::Adp { seed } => {
            let dir = ctx.layout.run_dir(arm, seed).join("export");
            let p = load_policy(&dir, a.space)?;
            let ctrl = Controller::of(&p);
            (
                "adp",
                evaluate(&spec, &ctrl)?,
                None,
                Some(dir.display().to_string()),
            )
        }
    };
    let mut rec = record(ctx, a, name, ev);
    rec.runs = runs;
    rec.trim = trim;
    rec.action = action;
    rec.policy = policy;
    if let SweepWho::Adp { seed } = who {
        rec.seed_index = Some(seed);
    }
    Ok(rec)
}

/// The observation pool of the state-shuffled control: the policy's own observations on the
/// pool worlds (training worlds, one run each), reservoir-sampled.
fn shuffle_observations(ctx: &Ctx<'_>, a: &Arm, p: &LearnedPolicy) -> anyhow::Result<Vec<Vec<f32>>> {
    let spec = RunSpec {
        cfg: &ctx.cfg,
        worlds: ctx.worlds,
        planner: a.planner,
        speed: a.speed,
        world_ids: &ctx.ex.pool_worlds,
        runs: 1,
        pairs: &[],
        seed: ctx.ex.shuffle.seed,
        trace: false,
        track: ctx.ex.train.env.observe_tracks > 0,
    };
    let ctrl = Controller::of(p);
    let seen = observations(&spec, &ctrl)?.observations;
    Ok(shuffle_pool(&seen, ctx.ex.shuffle.pool, ctx.ex.shuffle.seed))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Experiment, Restrict};
    use crate::eval_config;
    use crate::store::{Layout, Store};
    use crate::Trainer;
    use planner::PlannerKind;

    /// A trainer for tests that train nothing.
    struct NoTraining;

    impl Trainer for NoTraining {
        fn train(&self, _: &Path, _: &Path, _: bool) -> anyhow::Result<()> {
            anyhow::bail!("this test trains nothing")
        }

        fn actors(&self) -> u32 {
            2
        }
    }

    /// A sensing-sweep evaluation runs under its condition's lidar: on two worlds, a
    /// noiseless condition over a noiseless configuration reproduces the main DDP evaluation
    /// bit for bit, run by run; heavy noise drives other episodes. Both record their lidar.
    #[test]
    fn a_sensing_evaluation_applies_its_lidar_condition() {
        let dir = std::env::temp_dir().join(format!("adp-sensing-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let eval_toml = dir.join("eval.toml");
        let base = include_str!("../../configs/eval.toml");
        assert!(base.contains("noise_sigma = 0.001 "));
        std::fs::write(
            &eval_toml,
            base.replace("noise_sigma = 0.001 ", "noise_sigma = 0.0 "),
        )
        .unwrap();
        let text = format!(
            "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\ntest_worlds = \
             \"0,1\"\n[eval]\nruns = 2\ntrim = 0\nconfig = {:?}\n[sensing_sweep]\n\
             noise_fractions = [0.0, 0.5]\nruns = 2\ntrim = 0\n",
            eval_toml.display().to_string()
        );
        let ex = Experiment::parse("t.toml", &text, &Restrict::default()).unwrap();
        let cfg = eval_config(&ex).unwrap();
        let ctx = Ctx {
            ex: &ex,
            trainer: &NoTraining,
            layout: Layout::new(
                dir.clone(),
                Store {
                    dir: dir.join("store"),
                },
                &ex,
                &cfg,
                2,
            ),
            cfg,
            worlds: sim::catalog::worlds(),
            test_worlds: ex.test_worlds.clone(),
        };
        let run = |stage: Stage| {
            let out = ctx.layout.output(&stage);
            run_stage(&ctx, &stage, &out).unwrap();
            EvalRecord::load(&out).unwrap()
        };
        let main = run(Stage::EvalDdp {
            planner: PlannerKind::Dwa,
            speed: 1.5,
        });
        let sensing = |condition| {
            run(Stage::Sensing {
                arm: 0,
                condition,
                who: SweepWho::Ddp,
            })
        };
        let (clean, noisy) = (sensing(0), sensing(1));
        assert_eq!(main.lidar, None);
        assert_eq!(clean.per_world, main.per_world);
        assert_eq!(clean.lidar, Some(ctx.cfg.episode.lidar));
        assert_eq!(noisy.lidar.unwrap().noise_fraction, 0.5);
        assert_eq!(noisy.per_world.len(), 2);
        assert!(noisy.per_world.iter().all(|w| w.runs.len() == 2));
        assert_ne!(noisy.per_world, main.per_world);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
