//! Greedy evaluation while `adp train` runs: every `[greedy] every_steps` agent steps the
//! newest published policy drives the run's planner, without exploration noise, on held-out
//! worlds (the `val` split by default: training on `fit` never sees them), next to DDP on the
//! same worlds and seeds. Each evaluation also summarizes the schedules the policy chose:
//! per physical parameter its mean and spread, its mean in open and in cluttered scenes, and
//! its correlation with clutter (the share of lidar beams within [`actor::observation::CLUTTER_RADIUS_M`]).
//!
//! Results go to TensorBoard (a `greedy/` run next to the learner's: `greedy/success`,
//! `greedy/score`, the DDP reference lines `greedy/ddp_success` and `greedy/ddp_score`, and
//! `schedule/<param>_{mean,sd,open,cluttered,clutter_corr}`), and one JSON line per
//! evaluation to `greedy_eval.jsonl` in the run directory. Evaluations run on one background
//! thread, so the actors keep (almost) both cores; DDP is evaluated once.
//!
//! With `[greedy] select`, the monitor also evaluates the start policy (step 0) and keeps the
//! best candidate (see [`crate::selection`]); [`GreedyMonitor::chosen`] gives it at the end.

use planner::PlannerKind;
use std::borrow::Cow;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;

use serde::{Deserialize, Serialize};

use actor::closed_loop::{self, planner_seed, Chooser, Greedy};
use actor::{EnvConfig, MlpPolicy};
use learner::tensorboard::EventWriter;
use planner::{ActionSpace, Schedule};
use sim::{Status, World};

use crate::config::EvalConfig;
use crate::error::{Error, Result};
use crate::selection::{
    read_weights, write_atomic, write_weights, Candidate, Chosen, Selection, SelectionState, SELECTION_DIR,
    START_WEIGHTS, STATE_FILE,
};
use crate::GreedySection;
use crate::{eval_run, run_seed};

/// How one physical schedule parameter varied over an evaluation's agent steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParamStats {
    /// The parameter (`p`, `T`, `N`, `alpha`, `dt`, ...).
    pub name: String,
    /// Mean over all steps.
    pub mean: f64,
    /// Standard deviation over all steps.
    pub sd: f64,
    /// Mean over the steps at or below the median clutter.
    pub open: f64,
    /// Mean over the steps above the median clutter; `None` (JSON `null`) when no step is
    /// above it (every step as cluttered as the median, e.g. a policy that never moves).
    pub cluttered: Option<f64>,
    /// Pearson correlation with clutter (0 when either does not vary).
    pub clutter_corr: f64,
}

/// One greedy evaluation: a line of `greedy_eval.jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GreedyResult {
    /// Agent steps inserted when the policy was taken.
    pub agent_steps: u64,
    /// Its version.
    pub policy_version: u64,
    /// Success rate (%).
    pub success: f64,
    /// Mean BARN score.
    pub score: f64,
    /// DDP's success rate on the same worlds and seeds (%).
    pub ddp_success: f64,
    /// DDP's mean score.
    pub ddp_score: f64,
    /// Mean clutter of the steps (share of beams within [`actor::observation::CLUTTER_RADIUS_M`]; 0 in a record
    /// without it).
    #[serde(default)]
    pub clutter_mean: f64,
    /// The chosen schedules, per physical parameter (empty in a record without them).
    #[serde(default)]
    pub schedule: Vec<ParamStats>,
    /// The mean score per world, in the order of `[greedy] worlds` (empty in a record
    /// without them).
    #[serde(default)]
    pub world_scores: Vec<f64>,
}

/// One agent step of an evaluation: the scene's clutter and the chosen physical parameters.
pub type StepRecord = (f64, Vec<f64>);

/// Summarizes per-step `(clutter, params)` records into one [`ParamStats`] per name (none
/// without records). Steps at or below the median clutter are "open", the others "cluttered".
/// A name that occurs more than once (the unconstrained space's `dt` of every step) is
/// numbered by its occurrence, `dt1`, `dt2`, ..., so that each statistic, TensorBoard tag
/// and report entry says which parameter it is. Pure.
pub fn schedule_stats(records: &[StepRecord], names: &[&str]) -> Vec<ParamStats> {
    let n = records.len();
    if n == 0 {
        return Vec::new();
    }
    let labels = distinct_names(names);
    // Over non-empty rows only (`all` and `open` always hold a step; `busy` may not).
    let mean = |f: &dyn Fn(&StepRecord) -> f64, rows: &[&StepRecord]| {
        rows.iter().map(|r| f(r)).sum::<f64>() / rows.len() as f64
    };
    let all: Vec<&StepRecord> = records.iter().collect();
    let mut clutter: Vec<f64> = records.iter().map(|r| r.0).collect();
    clutter.sort_by(f64::total_cmp);
    let median = if n % 2 == 1 {
        clutter[n / 2]
    } else {
        0.5 * (clutter[n / 2 - 1] + clutter[n / 2])
    };
    let open: Vec<&StepRecord> = records.iter().filter(|r| r.0 <= median).collect();
    let busy: Vec<&StepRecord> = records.iter().filter(|r| r.0 > median).collect();
    let c_mean = mean(&|r| r.0, &all);
    labels
        .into_iter()
        .enumerate()
        .map(|(k, name)| {
            let v = |r: &StepRecord| r.1[k];
            let m = mean(&v, &all);
            let var = mean(&|r| (v(r) - m).powi(2), &all);
            let c_var = mean(&|r| (r.0 - c_mean).powi(2), &all);
            let cov = mean(&|r| (v(r) - m) * (r.0 - c_mean), &all);
            let corr = if var > 1e-18 && c_var > 1e-18 {
                cov / (var * c_var).sqrt()
            } else {
                0.0
            };
            ParamStats {
                name,
                mean: m,
                sd: var.sqrt(),
                open: mean(&v, &open),
                cluttered: (!busy.is_empty()).then(|| mean(&v, &busy)),
                clutter_corr: corr,
            }
        })
        .collect()
}

/// `names`, each one that occurs more than once numbered by its occurrence from 1
/// (`["dt", "dt"]` gives `["dt1", "dt2"]`); the others unchanged. Pure.
fn distinct_names(names: &[&str]) -> Vec<String> {
    let mut seen: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    names
        .iter()
        .map(|&name| {
            if names.iter().filter(|&&m| m == name).count() == 1 {
                return name.to_string();
            }
            let k = seen.entry(name).or_default();
            *k += 1;
            format!("{name}{k}")
        })
        .collect()
}

/// Everything an evaluation needs besides the policy; shared with the background thread.
struct Setup {
    worlds: Vec<usize>,
    runs: usize,
    planner: PlannerKind,
    space: ActionSpace,
    max_speed: f64,
    env: EnvConfig,
    eval: EvalConfig,
    seed: u64,
}

/// Success %, mean score, the mean score per world (in the worlds' order), and the per-step
/// (clutter, params) records of the policy.
type Outcome = (f64, f64, Vec<f64>, Vec<StepRecord>);

impl Setup {
    /// World `w` for either side of the comparison. A world that cannot be loaded fails the
    /// evaluation with this one error on both sides, never skipped by one of them: the policy
    /// and DDP always cover the same worlds and seeds.
    fn world(w: usize) -> Result<Cow<'static, World>> {
        sim::catalog::load(w).map_err(|e| Error::World {
            world: w,
            message: e.to_string(),
        })
    }

    fn seeds(&self) -> impl Iterator<Item = (usize, u64)> + '_ {
        self.worlds
            .iter()
            .flat_map(move |&w| (0..self.runs).map(move |r| (w, run_seed(self.seed, w, r))))
    }

    /// The greedy policy closed-loop through the training environment (no step cap: the BARN
    /// clock of `[episode]` ends runs, as in `adp eval`; no domain randomization).
    fn policy(&self, net: &MlpPolicy) -> Result<Outcome> {
        let env = self.env.for_evaluation();
        let (mut wins, mut score, mut n) = (0usize, 0.0, 0usize);
        let mut records = Vec::new();
        let mut world_scores = vec![0.0; self.worlds.len()];
        for (i, (w, seed)) in self.seeds().enumerate() {
            let world = Self::world(w)?;
            let run = eval_run(&self.eval, &world, self.planner, self.max_speed, seed);
            let chooser = Chooser::Env {
                space: self.space,
                env: &env,
                act: &mut Greedy::new(net),
            };
            let r = closed_loop::run(run, chooser, |step| {
                let params = step
                    .env
                    .chosen_params()
                    .ok_or_else(|| Error::component("greedy evaluation", "a step without its schedule"))?;
                records.push((step.clutter, params));
                Ok::<(), Error>(())
            })?
            .episode;
            wins += usize::from(r.status == Status::Succeeded);
            score += r.score;
            world_scores[i / self.runs] += r.score / self.runs as f64;
            n += 1;
        }
        Ok((
            100.0 * wins as f64 / n.max(1) as f64,
            score / n.max(1) as f64,
            world_scores,
            records,
        ))
    }

    /// DDP through the plain episode driver on the same worlds and seeds.
    fn ddp(&self) -> Result<(f64, f64)> {
        let compute = self
            .env
            .compute
            .resolve(self.planner.name())
            .map_err(|e| Error::component(format!("the compute model of {}", self.planner.name()), e))?;
        let episode = self
            .eval
            .episode
            .with_profile(self.env.profile, self.env.dynamics);
        let schedule = Schedule::ddp_default();
        let (mut wins, mut score, mut n) = (0usize, 0.0, 0usize);
        for (w, seed) in self.seeds() {
            let world = Self::world(w)?;
            let mut planner = self.planner.build(&self.eval.planners(), planner_seed(seed));
            let (r, _) = planner::run::run_episode(
                &world,
                episode,
                planner.as_mut(),
                &schedule,
                self.max_speed,
                seed,
                compute,
                |_, _, _| {},
            );
            wins += usize::from(r.status == Status::Succeeded);
            score += r.score;
            n += 1;
        }
        Ok((100.0 * wins as f64 / n.max(1) as f64, score / n.max(1) as f64))
    }
}

/// What a background evaluation returns: the result, and DDP's numbers when it computed them.
type Job = JoinHandle<Result<(GreedyResult, (f64, f64))>>;

/// A policy taken for evaluation, as held-out selection keeps it until its score is known.
struct Taken {
    /// Gradient updates done when it was taken.
    updates: u64,
    /// Its flat weights.
    weights: Vec<f32>,
    /// Whether it is the run's start policy.
    start: bool,
}

/// Held-out selection within a monitor: the candidates, persisted in the run directory.
struct Selector {
    /// `<run dir>/selection`.
    dir: PathBuf,
    /// `[greedy] worlds` as written (for the report).
    worlds: String,
    state: SelectionState,
    /// The best candidate's weights.
    best: Option<Vec<f32>>,
    /// The start policy's weights, while it waits for its evaluation.
    start: Option<Vec<f32>>,
}

/// The number of parameters of an MLP of layer sizes `dims` (weights and biases).
fn param_count(dims: &[usize]) -> usize {
    dims.windows(2).map(|w| w[0] * w[1] + w[1]).sum()
}

impl Selector {
    /// The selection of a run in `run_dir` evaluated on `worlds` x `runs`: a fresh one, or
    /// the one a resumed run persisted (refused when it was made on other worlds or runs,
    /// whose scores do not compare).
    fn open(run_dir: &Path, section: &GreedySection, worlds: &[usize]) -> Result<Self> {
        let dir = run_dir.join(SELECTION_DIR);
        let path = dir.join(STATE_FILE);
        let fresh = SelectionState {
            worlds: worlds.to_vec(),
            runs: section.runs,
            dims: Vec::new(),
            selection: Selection::gated(section.select_confidence),
            best_weights: None,
        };
        let mut me = Self {
            dir,
            worlds: section.worlds.clone(),
            state: fresh,
            best: None,
            start: None,
        };
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(me),
            Err(e) => return Err(Error::io("read", &path, e)),
        };
        let state: SelectionState = serde_json::from_str(&text)
            .map_err(|e| Error::Refused(format!("{}: not a selection state: {e}", path.display())))?;
        if state.worlds != worlds || state.runs != section.runs {
            return Err(Error::Refused(format!(
                "{}: the run's selection compared policies on other worlds or runs ({} worlds x {} \
                 runs) than [greedy] worlds = {:?}, runs = {} ({} worlds): their scores do not \
                 compare; resume with the run's own [greedy] settings",
                path.display(),
                state.worlds.len(),
                state.runs,
                section.worlds,
                section.runs,
                worlds.len()
            )));
        }
        let count = param_count(&state.dims);
        if let Some(name) = &state.best_weights {
            me.best = Some(read_weights(&me.dir.join(name), count)?);
        }
        let start = me.dir.join(START_WEIGHTS);
        if state.selection.start().is_none() && start.exists() {
            me.start = Some(read_weights(&start, count)?);
        }
        me.state = state;
        // The gate is the configuration's, also for a run resumed with another one.
        me.state.selection.confidence = section.select_confidence;
        Ok(me)
    }

    /// Writes the state file.
    fn save(&self) -> Result<()> {
        std::fs::create_dir_all(&self.dir).map_err(|e| Error::io("create", &self.dir, e))?;
        let json = serde_json::to_vec_pretty(&self.state).expect("a selection state serializes");
        write_atomic(&self.dir.join(STATE_FILE), &json)
    }

    /// Refuses policies of other layer sizes than the selection's (recording the first).
    fn check_dims(&mut self, dims: &[usize]) -> Result<()> {
        if self.state.dims.is_empty() {
            self.state.dims = dims.to_vec();
        } else if self.state.dims != dims {
            return Err(Error::Refused(format!(
                "held-out selection: a policy of layer sizes {dims:?}, but the run's candidates \
                 have {:?}",
                self.state.dims
            )));
        }
        Ok(())
    }

    /// Keeps the start policy of a fresh run (persisted, so a run stopped before its
    /// evaluation still evaluates it when resumed) for evaluation, forgetting any candidate
    /// an earlier run in the same directory left.
    fn keep_start(&mut self, dims: &[usize], weights: Vec<f32>) -> Result<()> {
        if let Some(old) = self.state.best_weights.take() {
            let _ = std::fs::remove_file(self.dir.join(old));
        }
        self.state.selection = Selection::default();
        self.state.dims = Vec::new();
        self.best = None;
        self.check_dims(dims)?;
        std::fs::create_dir_all(&self.dir).map_err(|e| Error::io("create", &self.dir, e))?;
        write_weights(&self.dir.join(START_WEIGHTS), &weights)?;
        self.save()?;
        self.start = Some(weights);
        Ok(())
    }

    /// Offers the evaluated policy `taken` with result `r`; persists the new best's weights
    /// (under a name of its own, so the state never names weights that are not its best's),
    /// then the state.
    fn offer(&mut self, r: &GreedyResult, taken: Taken) -> Result<()> {
        let c = Candidate {
            agent_steps: r.agent_steps,
            policy_version: r.policy_version,
            updates: taken.updates,
            score: r.score,
            success: r.success,
            world_scores: r.world_scores.clone(),
        };
        let old = self.state.best_weights.clone();
        // Taken over only once its weights are on disk.
        let mut next = self.state.selection.clone();
        if next.offer(c) {
            let name = format!("best-{}-v{}.f32", r.agent_steps, r.policy_version);
            std::fs::create_dir_all(&self.dir).map_err(|e| Error::io("create", &self.dir, e))?;
            write_weights(&self.dir.join(&name), &taken.weights)?;
            self.state.best_weights = Some(name);
            self.best = Some(taken.weights);
        }
        self.state.selection = next;
        self.save()?;
        if let Some(old) = old.filter(|o| Some(o) != self.state.best_weights.as_ref()) {
            let _ = std::fs::remove_file(self.dir.join(old));
        }
        if taken.start {
            let _ = std::fs::remove_file(self.dir.join(START_WEIGHTS));
        }
        Ok(())
    }
}

/// Drives the greedy evaluations of one training run (owned by the `adp train` loop; not
/// shared between threads).
pub struct GreedyMonitor {
    setup: Arc<Setup>,
    every: u64,
    next_at: u64,
    ddp: Option<(f64, f64)>,
    job: Option<Job>,
    run_dir: PathBuf,
    writer: Option<EventWriter>,
    /// Held-out selection, with `[greedy] select`.
    selector: Option<Selector>,
    /// The policy of the running job, while selection waits for its score.
    taken: Option<Taken>,
}

impl GreedyMonitor {
    /// A monitor for a run in `run_dir`, or `None` when `section.every_steps` is 0. Refuses
    /// unknown worlds and zero runs, and a selection that [`GreedySection::check_selection`]
    /// refuses or that a resumed run made on other worlds. `resumed_at` is the run's agent
    /// steps so far; with `select`, a resumed run continues the selection it persisted.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        section: &GreedySection,
        run_dir: &Path,
        planner: PlannerKind,
        space: ActionSpace,
        max_speed: f64,
        env: EnvConfig,
        seed: u64,
        resumed_at: u64,
    ) -> Result<Option<Self>> {
        section.check_selection()?;
        if section.every_steps == 0 {
            return Ok(None);
        }
        if section.runs == 0 {
            return Err(Error::Refused("[greedy] runs must be at least 1".into()));
        }
        let worlds = sim::splits::select(&section.worlds)
            .map_err(|e| Error::Refused(format!("[greedy] worlds = {:?}: {e}", section.worlds)))?;
        let selector = if section.select {
            Some(Selector::open(run_dir, section, &worlds)?)
        } else {
            None
        };
        let setup = Setup {
            worlds,
            runs: section.runs,
            planner,
            space,
            max_speed,
            env,
            eval: EvalConfig::load(None)?,
            // Its own stream: not the seeds of training episodes.
            seed: seed ^ 0x6772_6565_6479,
        };
        Ok(Some(Self {
            setup: Arc::new(setup),
            every: section.every_steps,
            next_at: (resumed_at / section.every_steps + 1) * section.every_steps,
            ddp: None,
            job: None,
            run_dir: run_dir.to_owned(),
            writer: None,
            selector,
            taken: None,
        }))
    }

    /// With `[greedy] select`, makes the run's start policy (layer sizes and flat weights, as
    /// `Learner::start_policy` gives them) the first candidate: persisted in the run
    /// directory and evaluated before the next policy, as agent step 0. Without selection,
    /// nothing.
    pub fn select_start(&mut self, dims: &[usize], weights: Vec<f32>) -> Result<()> {
        match self.selector.as_mut() {
            Some(s) => s.keep_start(dims, weights),
            None => Ok(()),
        }
    }

    /// With `[greedy] select`, the best candidate so far (the earliest on ties) with the
    /// report of the selection; `None` without selection or before any candidate.
    pub fn chosen(&self) -> Option<Chosen> {
        let s = self.selector.as_ref()?;
        let report = s.state.selection.report(&s.worlds, s.state.runs)?;
        Some(Chosen {
            report,
            candidate: s.state.selection.best()?.clone(),
            weights: s.best.clone()?,
        })
    }

    /// Call often from the training loop with the run's agent steps and updates and a way
    /// to take the newest policy `(version, layer sizes, flat weights)`: collects a finished
    /// evaluation (returning it for display) and starts the next one when due (with
    /// selection, the start policy's first). A failed evaluation is reported and skipped;
    /// training goes on.
    pub fn poll<E: std::error::Error + Send + Sync + 'static>(
        &mut self,
        inserts: u64,
        updates: u64,
        latest: impl FnOnce() -> Result<(u64, Vec<usize>, Vec<f32>), E>,
    ) -> Option<Result<GreedyResult>> {
        let done = self.collect(false);
        if self.job.is_none() && self.start_pending() {
            if let Err(e) = self.launch_start() {
                return Some(Err(e));
            }
        } else if self.job.is_none() && inserts >= self.next_at {
            self.next_at = (inserts / self.every + 1) * self.every;
            if let Err(e) = self.start(inserts, updates, latest) {
                return Some(Err(e));
            }
        }
        done
    }

    /// Evaluates the newest policy now and waits for it (and for one still running, and with
    /// selection for the start policy when it is still waiting): the final point of the
    /// curve. [`GreedyMonitor::chosen`] then gives the selection's result.
    pub fn finish<E: std::error::Error + Send + Sync + 'static>(
        &mut self,
        inserts: u64,
        updates: u64,
        latest: impl FnOnce() -> Result<(u64, Vec<usize>, Vec<f32>), E>,
    ) -> Vec<Result<GreedyResult>> {
        let mut out: Vec<_> = self.collect(true).into_iter().collect();
        if self.start_pending() {
            match self.launch_start() {
                Ok(()) => out.extend(self.collect(true)),
                Err(e) => out.push(Err(e)),
            }
        }
        match self.start(inserts, updates, latest) {
            Ok(()) => out.extend(self.collect(true)),
            Err(e) => out.push(Err(e)),
        }
        out
    }

    /// Whether selection's start policy waits for its evaluation.
    fn start_pending(&self) -> bool {
        self.selector.as_ref().is_some_and(|s| s.start.is_some())
    }

    /// Starts the evaluation of selection's start policy (agent step 0, version 0).
    fn launch_start(&mut self) -> Result<()> {
        let s = self.selector.as_mut().expect("a start waits only with selection");
        let weights = s.start.take().expect("a start waits");
        let dims = s.state.dims.clone();
        self.launch(0, 0, 0, &dims, weights, true)
    }

    fn start<E: std::error::Error + Send + Sync + 'static>(
        &mut self,
        inserts: u64,
        updates: u64,
        latest: impl FnOnce() -> Result<(u64, Vec<usize>, Vec<f32>), E>,
    ) -> Result<()> {
        let (version, dims, weights) = latest().map_err(|e| Error::component("the newest policy", e))?;
        if version == 0 {
            return Ok(()); // nothing published yet
        }
        self.launch(inserts, updates, version, &dims, weights, false)
    }

    /// Starts the evaluation of policy `version` taken at `inserts` agent steps and `updates`
    /// updates (with selection, keeping its weights for the selection).
    fn launch(
        &mut self,
        inserts: u64,
        updates: u64,
        version: u64,
        dims: &[usize],
        weights: Vec<f32>,
        start: bool,
    ) -> Result<()> {
        if let Some(s) = self.selector.as_mut() {
            s.check_dims(dims)?;
            self.taken = Some(Taken {
                updates,
                weights: weights.clone(),
                start,
            });
        }
        let net = MlpPolicy::from_flat(dims, weights)
            .map_err(|e| Error::component(format!("greedy evaluation: policy {version}"), e))?;
        let setup = self.setup.clone();
        let ddp = self.ddp;
        self.job = Some(std::thread::spawn(move || {
            let ddp = match ddp {
                Some(d) => d,
                None => setup.ddp()?,
            };
            let (success, score, world_scores, records) = setup.policy(&net)?;
            let names: Vec<&str> = setup.space.ranges().iter().map(|r| r.0).collect();
            let clutter_mean = records.iter().map(|r| r.0).sum::<f64>() / records.len().max(1) as f64;
            Ok((
                GreedyResult {
                    agent_steps: inserts,
                    policy_version: version,
                    success,
                    score,
                    ddp_success: ddp.0,
                    ddp_score: ddp.1,
                    clutter_mean,
                    schedule: schedule_stats(&records, &names),
                    world_scores,
                },
                ddp,
            ))
        }));
        Ok(())
    }

    /// Takes a finished job's result (waiting for it when `wait`), and records it.
    fn collect(&mut self, wait: bool) -> Option<Result<GreedyResult>> {
        if !wait && !self.job.as_ref().is_some_and(JoinHandle::is_finished) {
            return None;
        }
        let job = self.job.take()?;
        let taken = self.taken.take();
        let result = match job.join() {
            Ok(Ok((r, ddp))) => {
                self.ddp = Some(ddp);
                self.record(&r).and_then(|()| self.select(&r, taken)).map(|()| r)
            }
            Ok(Err(e)) => Err(Error::Greedy(Box::new(e))),
            Err(_) => Err(Error::Panicked),
        };
        Some(result)
    }

    /// Offers the evaluated policy to the selection, if any.
    fn select(&mut self, r: &GreedyResult, taken: Option<Taken>) -> Result<()> {
        match (self.selector.as_mut(), taken) {
            (Some(s), Some(t)) => s.offer(r, t),
            _ => Ok(()),
        }
    }

    /// Appends `r` to `greedy_eval.jsonl` and to the `greedy/` TensorBoard run.
    fn record(&mut self, r: &GreedyResult) -> Result<()> {
        let path = self.run_dir.join("greedy_eval.jsonl");
        std::fs::create_dir_all(&self.run_dir).map_err(|e| Error::io("create", &self.run_dir, e))?;
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| Error::io("open", &path, e))?;
        let line = serde_json::to_string(r).expect("a greedy result serializes");
        writeln!(file, "{line}").map_err(|e| Error::io("write", &path, e))?;
        if self.writer.is_none() {
            let board = EventWriter::create(&self.run_dir.join("greedy"))
                .map_err(|e| Error::component("greedy evaluation", e))?;
            self.writer = Some(board);
        }
        let w = self.writer.as_mut().expect("just created");
        let mut values: Vec<(String, f64)> = vec![
            ("greedy/success".into(), r.success),
            ("greedy/score".into(), r.score),
            ("greedy/ddp_success".into(), r.ddp_success),
            ("greedy/ddp_score".into(), r.ddp_score),
            ("schedule/clutter_mean".into(), r.clutter_mean),
        ];
        for p in &r.schedule {
            for (what, v) in [
                ("mean", Some(p.mean)),
                ("sd", Some(p.sd)),
                ("open", Some(p.open)),
                ("cluttered", p.cluttered),
                ("clutter_corr", Some(p.clutter_corr)),
            ] {
                if let Some(v) = v {
                    values.push((format!("schedule/{}_{what}", p.name), v));
                }
            }
        }
        let refs: Vec<(&str, f64)> = values.iter().map(|(t, v)| (t.as_str(), *v)).collect();
        w.scalars(r.agent_steps, &refs)
            .and_then(|()| w.flush())
            .map_err(|e| Error::component("greedy evaluation", e))?;
        Ok(())
    }
}

/// One line for the progress display.
pub fn describe(r: &GreedyResult) -> String {
    let params: Vec<String> = r
        .schedule
        .iter()
        .map(|p| {
            let cluttered = match p.cluttered {
                Some(c) => format!("{c:.2}"),
                None => "none".into(),
            };
            format!(
                "{} {:.2}±{:.2} (open {:.2}, cluttered {cluttered})",
                p.name, p.mean, p.sd, p.open
            )
        })
        .collect();
    format!(
        "greedy v{} at {} steps: success {:.1}% score {:.3} (DDP {:.1}% {:.3}); {}",
        r.policy_version,
        r.agent_steps,
        r.success,
        r.score,
        r.ddp_success,
        r.ddp_score,
        params.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_statistics_by_hand() {
        // Four steps: clutter 0.1, 0.2, 0.3, 0.4 (median 0.25); T = 2.2, 2.0, 1.8, 1.6 falls
        // with clutter (correlation -1); p constant (sd 0, correlation 0).
        let records: Vec<(f64, Vec<f64>)> = [(0.1, 2.2), (0.2, 2.0), (0.3, 1.8), (0.4, 1.6)]
            .iter()
            .map(|&(c, t)| (c, vec![1.7, t]))
            .collect();
        let s = schedule_stats(&records, &["p", "T"]);
        let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        close(s[0].mean, 1.7);
        close(s[0].sd, 0.0);
        assert_eq!(s[0].clutter_corr, 0.0);
        close(s[1].mean, 1.9);
        close(s[1].sd, 0.05f64.sqrt()); // deviations ±0.3, ±0.1: (0.09 + 0.01) * 2 / 4
        close(s[1].open, 2.1);
        close(s[1].cluttered.unwrap(), 1.7);
        close(s[1].clutter_corr, -1.0);
        assert!(schedule_stats(&[], &["p"]).is_empty());
        // Repeated names (the unconstrained space's dt per step) are numbered; unique ones
        // keep their name.
        let dts: Vec<StepRecord> = (0..3).map(|i| (i as f64, vec![0.1, 0.05, 1.0])).collect();
        let names: Vec<String> = schedule_stats(&dts, &["dt", "dt", "N"])
            .into_iter()
            .map(|p| p.name)
            .collect();
        assert_eq!(names, ["dt1", "dt2", "N"]);
        // A policy that never moves: every step as cluttered as the median. The record still
        // reads back (a NaN would be written as `null` and refused by the reader).
        let still: Vec<StepRecord> = (0..3).map(|_| (0.0, vec![0.5])).collect();
        let s = schedule_stats(&still, &["v_frac"]);
        assert_eq!((s[0].open, s[0].cluttered, s[0].sd), (0.5, None, 0.0));
        let r = GreedyResult {
            agent_steps: 1,
            policy_version: 1,
            success: 0.0,
            score: 0.0,
            ddp_success: 100.0,
            ddp_score: 0.5,
            clutter_mean: 0.0,
            schedule: s,
            world_scores: vec![0.25, 0.5],
        };
        let line = serde_json::to_string(&r).unwrap();
        assert!(line.contains("\"cluttered\":null"), "{line}");
        assert_eq!(serde_json::from_str::<GreedyResult>(&line).unwrap(), r);
        assert!(
            describe(&r).contains("(open 0.50, cluttered none)"),
            "{}",
            describe(&r)
        );
    }

    /// A world that cannot be loaded (360: no world has that id) fails both sides of the
    /// comparison with the same error naming it; neither side skips it and reports numbers
    /// over fewer worlds than the other.
    #[test]
    fn a_world_that_cannot_be_loaded_fails_both_sides_alike() {
        let setup = Setup {
            worlds: vec![1, 360],
            runs: 1,
            planner: PlannerKind::Dwa,
            space: ActionSpace::Decremental,
            max_speed: 1.5,
            env: EnvConfig::default(),
            eval: EvalConfig::load(None).unwrap(),
            seed: 3,
        };
        let ddp = format!("{:#}", setup.ddp().unwrap_err());
        // The DDP-initialized policy (zero output layer).
        let mut flat = vec![0.0f32; 730 * 4];
        flat.extend([0.0f32; 4]);
        let net = MlpPolicy::from_flat(&[730, 4], flat).unwrap();
        let policy = format!("{:#}", setup.policy(&net).unwrap_err());
        assert_eq!(ddp, policy);
        assert!(
            ddp.starts_with("world 360 cannot be loaded: world 360 does not exist"),
            "{ddp}"
        );
    }

    #[test]
    fn evaluations_are_due_every_k_steps_and_record_a_json_line() {
        let dir = std::env::temp_dir().join(format!("adp-greedy-monitor-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let section = GreedySection {
            every_steps: 100,
            worlds: "1".into(),
            runs: 1,
            select: false,
            select_confidence: 0.0,
        };
        let env = EnvConfig::default();
        let mut m = GreedyMonitor::new(
            &section,
            &dir,
            PlannerKind::Dwa,
            ActionSpace::Decremental,
            1.5,
            env,
            3,
            250,
        )
        .unwrap()
        .unwrap();
        assert_eq!(m.next_at, 300, "a resumed run continues the grid");
        // The DDP-initialized output (zeros) is DDP: same success and score as DDP's row.
        let mut flat = vec![0.0f32; 730 * 4];
        flat.extend([0.0f32; 4]);
        let latest = || Ok::<_, std::io::Error>((7, vec![730, 4], flat.clone()));
        assert!(m.poll(299, 9, latest).is_none() && m.job.is_none(), "not due yet");
        assert!(m.poll(300, 9, latest).is_none() && m.job.is_some(), "started");
        let results = m.finish(300, 9, latest);
        assert!(m.chosen().is_none(), "no selection without select");
        assert_eq!(results.len(), 2);
        let r = results[0].as_ref().unwrap();
        assert_eq!((r.agent_steps, r.policy_version), (300, 7));
        assert_eq!((r.success, r.score), (r.ddp_success, r.ddp_score));
        assert_eq!(r.success, 100.0, "DWA-DDP solves world 1");
        let t = r.schedule.iter().find(|p| p.name == "T").unwrap();
        assert!(
            (t.mean - 2.0).abs() < 1e-12 && t.sd < 1e-12,
            "DDP's T = 2 s: {t:?}"
        );
        let lines = std::fs::read_to_string(dir.join("greedy_eval.jsonl")).unwrap();
        assert_eq!(lines.lines().count(), 2);
        let back: GreedyResult = serde_json::from_str(lines.lines().next().unwrap()).unwrap();
        assert_eq!(&back, r);
        assert!(
            std::fs::read_dir(dir.join("greedy")).unwrap().count() == 1,
            "one event file"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// With selection, the start policy is evaluated first (as step 0), the best candidate is
    /// persisted, a tie keeps the start, and a resumed monitor knows the best; a resumed run
    /// whose [greedy] worlds changed is refused.
    #[test]
    fn selection_evaluates_the_start_persists_the_best_and_survives_a_resume() {
        let dir = std::env::temp_dir().join(format!("adp-greedy-select-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let section = GreedySection {
            every_steps: 100,
            worlds: "156".into(),
            runs: 1,
            select: true,
            select_confidence: 0.0,
        };
        let monitor = |section: &GreedySection, at: u64| {
            GreedyMonitor::new(
                section,
                &dir,
                PlannerKind::Dwa,
                ActionSpace::Decremental,
                1.5,
                EnvConfig::default(),
                3,
                at,
            )
        };
        let mut m = monitor(&section, 0).unwrap().unwrap();
        // Start and later policy alike (zero outputs): the later one ties, the start wins.
        let mut flat = vec![0.0f32; 730 * 4];
        flat.extend([0.0f32; 4]);
        m.select_start(&[730, 4], flat.clone()).unwrap();
        assert!(dir.join(SELECTION_DIR).join(START_WEIGHTS).exists());
        let latest = || Ok::<_, std::io::Error>((3, vec![730, 4], flat.clone()));
        assert!(
            m.poll(10, 1, latest).is_none() && m.job.is_some(),
            "the start first"
        );
        let results = m.finish(120, 40, latest);
        let steps: Vec<u64> = results.iter().map(|r| r.as_ref().unwrap().agent_steps).collect();
        assert_eq!(steps, [0, 120]);
        let chosen = m.chosen().unwrap();
        assert_eq!(
            (chosen.candidate.agent_steps, chosen.candidate.policy_version),
            (0, 0)
        );
        assert_eq!(chosen.weights, flat);
        assert_eq!(chosen.report.start_score, Some(chosen.report.exported_score));
        assert_eq!(
            (chosen.report.last_step, chosen.report.candidates.len()),
            (120, 2)
        );
        assert!(
            !dir.join(SELECTION_DIR).join(START_WEIGHTS).exists(),
            "the start was evaluated"
        );
        // A resumed run continues the selection.
        let resumed = monitor(&section, 120).unwrap().unwrap();
        let again = resumed.chosen().unwrap();
        assert_eq!(again.report, chosen.report);
        assert_eq!(again.weights, flat);
        // ... but not on other worlds.
        let other = GreedySection {
            worlds: "166".into(),
            ..section.clone()
        };
        let e = monitor(&other, 120).err().unwrap().to_string();
        assert!(e.contains("other worlds or runs"), "{e}");
        // Selection on the test worlds is refused here too.
        let test = GreedySection {
            worlds: "hardest50".into(),
            ..section
        };
        let e = monitor(&test, 0).err().unwrap().to_string();
        assert!(e.contains("includes test world"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
