//! What decides each stage's result, and the key that names it in the store.
//!
//! A stage's *recipe* is a JSON value holding everything that reaches its computation: the
//! resolved configuration (the evaluation configuration after the experiment's profile,
//! compute model and jitter are applied; the training configuration after the arm's planner,
//! space, speed, worlds and seed are set), the worlds, runs and seeds, and the recipes' keys of
//! the stages it reads (an evaluation of a trained policy names its training's key, the best
//! constant its search's). Its *key* is the SHA-256 of that value together with
//! [`RESULTS_VERSION`] and the stage kind, so two experiment files that contain the same
//! stage compute the same key, and a stage whose inputs differ in anything gets its own.
//!
//! Left out on purpose, because they do not change a result: names (the arm id, the run
//! name), where files go, the service's transport and timeouts, the sandbox and the SLURM
//! settings. Keys added after results were stored (`[greedy] select`, `[service]
//! init_action`, an arm's `start`) enter a recipe only when they are not the default, so the
//! stages stored before them keep their keys. `[run] actors = 0` (one per core) is resolved to the number of actors it starts
//! here, since the actor count changes the data a training collects.
//!
//! Pure: no files are read or written here.

use serde::Serialize;
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

use eval::EvalConfig;
use learner::LearnerDevice;
use train_config::TrainConfig;

use super::config::{planner_name, space_label, Arm, Experiment, Start};
use super::plan::{Stage, SweepWho};

/// The version of the code that changes results. Bump it in the commit that changes what any
/// stage computes (simulator, planners, worlds, learner, evaluation protocol): every key
/// changes with it, so the store computes every stage again instead of mixing results of two
/// versions. `tests::results_fingerprint` fails when DDP's episodes change and this number did
/// not.
pub const RESULTS_VERSION: u32 = 1;

/// Hexadecimal digits of a key (64 bits: collisions are out of reach for any store).
const KEY_HEX: usize = 16;

/// A stage's name in the store: hexadecimal, `KEY_HEX` digits.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct Key(pub String);

impl std::fmt::Display for Key {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// The kinds of stored results; each has a directory of its own in the store.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A training run (its directory: the export, the learning curves, the marker).
    Train,
    /// A constant search on the training worlds.
    Search,
    /// An untrained, DDP-initialized policy (an export directory).
    Policy,
    /// An evaluation on the test worlds (an [`super::record::EvalRecord`]).
    Eval,
}

impl Kind {
    /// The directory of this kind in the store.
    pub fn dir(self) -> &'static str {
        match self {
            Kind::Train => "train",
            Kind::Search => "search",
            Kind::Policy => "policy",
            Kind::Eval => "eval",
        }
    }
}

/// A stage's recipe and its key.
#[derive(Clone, Debug, Serialize)]
pub struct Recipe {
    /// The stage kind.
    pub kind: Kind,
    /// Everything that decides the result.
    pub inputs: Value,
    /// [`RESULTS_VERSION`] when the key was computed.
    pub version: u32,
    /// SHA-256 of the other three fields' JSON, truncated.
    pub key: Key,
}

impl Recipe {
    /// The recipe of `kind` with `inputs`, keyed.
    pub fn new(kind: Kind, inputs: Value) -> Self {
        let text = serde_json::to_string(&json!({
            "version": RESULTS_VERSION,
            "kind": kind,
            "inputs": inputs,
        }))
        .expect("JSON values serialize");
        let digest = Sha256::digest(text.as_bytes());
        let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
        Recipe {
            kind,
            inputs,
            version: RESULTS_VERSION,
            key: Key(hex[..KEY_HEX].to_string()),
        }
    }
}

/// The inputs that every recipe of one experiment draws on.
pub struct Inputs<'a> {
    /// The experiment.
    pub ex: &'a Experiment,
    /// Its resolved evaluation configuration.
    pub cfg: &'a EvalConfig,
    /// The actors a training with `[run] actors = 0` starts here.
    pub cores: u32,
}

impl Inputs<'_> {
    /// The recipe of `stage`.
    pub fn recipe(&self, stage: &Stage) -> Recipe {
        let ex = self.ex;
        match *stage {
            Stage::Train { arm, seed } => self.train(&ex.arms[arm], seed),
            Stage::Search { arm } => self.search(&ex.arms[arm]),
            Stage::EvalDdp { planner, speed } => self.eval(
                json!({"controller": "ddp", "planner": planner_name(planner), "speed": speed}),
                self.cfg,
                (ex.eval.runs, ex.eval.trim),
            ),
            Stage::EvalVanilla { planner, speed } => self.eval(
                json!({"controller": "vanilla", "planner": planner_name(planner), "speed": speed}),
                self.cfg,
                (ex.eval.runs, ex.eval.trim),
            ),
            Stage::EvalConstant { arm } => self.eval(
                self.controller(arm, SweepWho::Constant),
                self.cfg,
                (ex.eval.runs, ex.eval.trim),
            ),
            Stage::EvalUntrained { arm } => {
                let a = &ex.arms[arm];
                self.eval(
                    json!({
                        "controller": "untrained",
                        "policy": self.untrained_policy(a).key,
                        "planner": planner_name(a.planner),
                        "speed": a.speed,
                    }),
                    self.cfg,
                    (ex.eval.runs, ex.eval.trim),
                )
            }
            Stage::EvalAdp { arm, seed } => self.eval(
                self.controller(arm, SweepWho::Adp { seed }),
                self.cfg,
                (ex.eval.runs, ex.eval.trim),
            ),
            Stage::EvalShuffled { arm, seed } => {
                let a = &ex.arms[arm];
                // Which arms get the control does not change what it computes.
                let mut shuffle = serde_json::to_value(&ex.shuffle).expect("sections serialize");
                if let Some(s) = shuffle.as_object_mut() {
                    s.remove("speeds");
                }
                self.eval(
                    json!({
                        "controller": "shuffled",
                        "train": self.train(a, seed).key,
                        "shuffle": shuffle,
                        "pool_worlds": ex.pool_worlds,
                    }),
                    self.cfg,
                    (ex.eval.runs, ex.eval.trim),
                )
            }
            Stage::Sweep { arm, point, who } => {
                let mut cfg = self.cfg.clone();
                cfg.compute = ex.sweep_points()[point];
                self.eval(self.controller(arm, who), &cfg, (ex.sweep.runs, ex.sweep.trim))
            }
            Stage::Sensing { arm, condition, who } => {
                let mut cfg = self.cfg.clone();
                // A condition the configuration refuses keys its own recipe; the stage
                // reports the error when it runs.
                if let Ok(lidar) = ex.sensing_conditions()[condition].apply(cfg.episode.lidar) {
                    cfg.episode.lidar = lidar;
                }
                let mut controller = self.controller(arm, who);
                controller["condition"] = json!(format!("{:?}", ex.sensing_conditions()[condition]));
                self.eval(controller, &cfg, (ex.sensing.runs, ex.sensing.trim))
            }
        }
    }

    /// The training recipe of `a`'s seed `seed`; an arm that starts from its best constant
    /// names its search's key under `start` (a DDP start, the default, adds nothing, so the
    /// recipes of such trainings are those they always had).
    pub fn train(&self, a: &Arm, seed: usize) -> Recipe {
        let cfg = self.ex.train_config(a, seed);
        let mut inputs = train_inputs(&cfg, self.cores);
        self.add_start(a, &mut inputs);
        Recipe::new(Kind::Train, inputs)
    }

    /// Adds `a`'s start to `inputs` when it is not the default: the best constant as the key
    /// of the search that finds it.
    fn add_start(&self, a: &Arm, inputs: &mut Value) {
        match a.start {
            Start::Ddp => {}
            Start::BestConstant => inputs["start"] = json!({ "best-constant": self.search(a).key }),
        }
    }

    /// The recipe of `a`'s constant search.
    pub fn search(&self, a: &Arm) -> Recipe {
        let ex = self.ex;
        Recipe::new(
            Kind::Search,
            json!({
                "planner": planner_name(a.planner),
                "space": space_label(a.space),
                "speed": a.speed,
                "env": ex.train.env,
                "config": format!("{:?}", self.cfg),
                "search": ex.search,
                "worlds": ex.search_worlds,
                "track": ex.train.env.observe_tracks > 0,
            }),
        )
    }

    /// The recipe of `a`'s untrained, DDP-initialized policy: the first seed's networks
    /// before any update (with `[train.service] init_action` and a best-constant start when
    /// given, which are left out otherwise).
    pub fn untrained_policy(&self, a: &Arm) -> Recipe {
        let cfg = self.ex.train_config(a, 0);
        let mut inputs = json!({
            "td3": cfg.td3,
            "env": cfg.env,
            "ddp_init": cfg.service.ddp_init,
            "space": space_label(a.space),
        });
        if let Some(action) = &cfg.service.init_action {
            inputs["init_action"] = json!(action);
        }
        self.add_start(a, &mut inputs);
        Recipe::new(Kind::Policy, inputs)
    }

    /// The controller `who` of arm `arm`, as it enters an evaluation's recipe.
    fn controller(&self, arm: usize, who: SweepWho) -> Value {
        let a = &self.ex.arms[arm];
        match who {
            SweepWho::Ddp => {
                json!({"controller": "ddp", "planner": planner_name(a.planner), "speed": a.speed})
            }
            SweepWho::Constant => json!({
                "controller": "constant",
                "search": self.search(a).key,
                "env": self.ex.train.env,
            }),
            SweepWho::Adp { seed } => json!({"controller": "adp", "train": self.train(a, seed).key}),
        }
    }

    /// An evaluation of `controller` on the test worlds under `cfg` with `(runs, trim)`.
    fn eval(&self, controller: Value, cfg: &EvalConfig, (runs, trim): (usize, usize)) -> Recipe {
        let ex = self.ex;
        Recipe::new(
            Kind::Eval,
            json!({
                "controller": controller,
                "config": format!("{cfg:?}"),
                "worlds": ex.test_worlds,
                "runs": runs,
                "trim": trim,
                "seed": ex.eval.seed,
                "track": ex.train.env.observe_tracks > 0,
            }),
        )
    }
}

/// The parts of a training configuration that decide what it learns: `[run]` without its
/// name (and with `actors = 0` resolved to `cores`), `[env]`, `[td3]`, `[greedy]` (the
/// learning curves kept with the run, and with `select` the policy exported), the `[service]`
/// keys that change the data (`ddp_init`, `episodes_per_assignment`, and `init_action` when
/// given) and, when it is not the CPU, `[learner] device`
/// (another backend sums in another order: the same run learns slightly different weights).
pub fn train_inputs(cfg: &TrainConfig, cores: u32) -> Value {
    let mut run = serde_json::to_value(&cfg.run).expect("configs serialize");
    run["name"] = Value::Null;
    if cfg.run.actors == 0 {
        run["actors"] = json!(cores);
    }
    let mut inputs = json!({
        "run": run,
        "env": cfg.env,
        "td3": cfg.td3,
        "greedy": cfg.greedy,
        "service": {
            "ddp_init": cfg.service.ddp_init,
            "episodes_per_assignment": cfg.service.episodes_per_assignment,
        },
    });
    if let Some(action) = &cfg.service.init_action {
        inputs["service"]["init_action"] = json!(action);
    }
    if cfg.learner.device != LearnerDevice::Cpu {
        inputs["learner"] = json!({ "device": cfg.learner.device });
    }
    inputs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Restrict;
    use crate::plan::{stages, Sweeps};

    const ONE: &str = "[experiment]\nname = \"one\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n";
    const TWO: &str = "[experiment]\nname = \"two\"\nplanners = [\"dwa\", \"mppi\"]\nspeeds = [1.0, 1.5]\n";

    fn keys(text: &str) -> Vec<(String, Key)> {
        let ex = Experiment::parse("t.toml", text, &Restrict::default()).unwrap();
        let cfg = EvalConfig::load(None).unwrap();
        let inputs = Inputs {
            ex: &ex,
            cfg: &cfg,
            cores: 2,
        };
        stages(&ex.arms, ex.seeds, &Sweeps::default())
            .iter()
            .map(|s| (format!("{s:?}"), inputs.recipe(s).key))
            .collect()
    }

    #[test]
    fn a_stage_shared_by_two_experiments_has_one_key() {
        let (one, two) = (keys(ONE), keys(TWO));
        // Every stage of the one-arm file is in the two-planner file, under the same key
        // although the arm indices differ (DWA at 1.5 m/s is the second arm there).
        for (stage, key) in &one {
            assert!(
                two.iter().any(|(_, k)| k == key),
                "{stage} ({key}) is not in the larger experiment"
            );
        }
        // And the larger file's keys are all different from each other.
        let mut seen: Vec<&Key> = two.iter().map(|(_, k)| k).collect();
        seen.sort();
        seen.dedup();
        assert_eq!(seen.len(), two.len());
    }

    #[test]
    fn anything_that_decides_a_result_changes_the_key() {
        let base = keys(ONE);
        for (what, text) in [
            ("runs per world", format!("{ONE}[eval]\nruns = 10\ntrim = 2\n")),
            ("training steps", format!("{ONE}[train.run]\nsteps = 1000\n")),
            (
                "the learning rate",
                format!("{ONE}[train.td3]\nactor_lr = 0.001\n"),
            ),
            ("the test worlds", format!("{ONE}test_worlds = \"hardest50\"\n")),
            (
                "the compute budget",
                format!("{ONE}[train.env.compute]\nbudget_scale = 2.0\n"),
            ),
        ] {
            let other = keys(&text);
            let changed = base.iter().zip(&other).filter(|(a, b)| a.1 != b.1).count();
            assert!(changed > 0, "{what}: no key changed");
        }
        // Only the training and what reads it change with the training steps: the DDP
        // evaluation and the constant search do not.
        let steps = keys(&format!("{ONE}[train.run]\nsteps = 1000\n"));
        for ((stage, a), (_, b)) in base.iter().zip(&steps) {
            let depends = stage.starts_with("Train")
                || stage.starts_with("EvalAdp")
                || stage.starts_with("EvalShuffled");
            assert_eq!(a != b, depends, "{stage}");
        }
    }

    /// The version of the code and the episodes it gives: DDP of every planner at 1.5 m/s on
    /// three test worlds, two runs each (statuses and times to the centisecond).
    const FINGERPRINT: (u32, &str) = (1, "5f055e75f0f75a4f");

    /// [`RESULTS_VERSION`] moves with what the code computes: when DDP's episodes change and
    /// the version did not, this fails and says what to write. (It watches the simulator, the
    /// planners, the worlds and the evaluation protocol; a change of the learner alone must be
    /// caught by its author.)
    #[test]
    fn results_fingerprint() {
        use crate::runner::{evaluate, Controller, RunSpec};
        use planner::{PlannerKind, Schedule};
        let ex = Experiment::parse("t.toml", ONE, &Restrict::default()).unwrap();
        let mut cfg = EvalConfig::load(None).unwrap();
        cfg.episode = cfg
            .episode
            .with_profile(ex.train.env.profile, ex.train.env.dynamics);
        cfg.compute = ex.train.env.compute;
        let mut text = String::new();
        for planner in [
            PlannerKind::Dwa,
            PlannerKind::Mppi,
            PlannerKind::LogMppi,
            PlannerKind::System,
        ] {
            let spec = RunSpec {
                cfg: &cfg,
                worlds: sim::catalog::worlds(),
                planner,
                speed: 1.5,
                world_ids: &[0, 120, 224],
                runs: 2,
                pairs: &[],
                seed: 0,
                trace: false,
                track: false,
            };
            let ev = evaluate(&spec, &Controller::Schedule(Schedule::ddp_default())).unwrap();
            for w in &ev.per_world {
                for r in &w.runs {
                    text += &format!("{planner:?} {} {:?} {:.0}\n", w.world, r.status, r.time_s * 100.0);
                }
            }
        }
        let digest = Sha256::digest(text.as_bytes());
        let hex: String = digest.iter().take(8).map(|b| format!("{b:02x}")).collect();
        assert_eq!(
            FINGERPRINT.0, RESULTS_VERSION,
            "RESULTS_VERSION is {RESULTS_VERSION}: set FINGERPRINT in experiment/src/recipe.rs to \
             ({RESULTS_VERSION}, {hex:?})"
        );
        assert_eq!(
            FINGERPRINT.1, hex,
            "DDP's episodes changed (now:\n{text}): a change of the code changes results, so bump \
             RESULTS_VERSION in experiment/src/recipe.rs and set FINGERPRINT to (the new version, \
             {hex:?})"
        );
    }

    /// The keys added after results were stored change no key at their defaults: a file
    /// that writes `start = "ddp"` and `[train.greedy] select = false` has the keys of one
    /// that leaves them out.
    #[test]
    fn default_start_and_selection_keep_the_stored_keys() {
        let base = keys(ONE);
        let explicit = keys(&format!(
            "{}start = \"ddp\"\n[train.greedy]\nselect = false\n",
            ONE
        ));
        assert_eq!(base, explicit);
        // Turned on, they key trainings of their own.
        let select = keys(&format!("{ONE}[train.greedy]\nselect = true\n"));
        let given = keys(&format!(
            "{ONE}[train.service]\ninit_action = [1.0, 0.0, 0.0, -1.0]\n"
        ));
        for other in [&select, &given] {
            for ((stage, a), (_, b)) in base.iter().zip(other.iter()) {
                if stage.starts_with("Train") {
                    assert_ne!(a, b, "{stage}");
                }
            }
        }
    }

    /// An arm that starts from its best constant has trainings, an untrained policy and
    /// evaluations of its own, and shares its constant search, DDP and best constant with
    /// the DDP-started arm.
    #[test]
    fn a_best_constant_start_keys_its_own_trainings() {
        let base = keys(ONE);
        let best = keys(&ONE.replace("[experiment]\n", "[experiment]\nstart = \"best-constant\"\n"));
        assert_eq!(base.len(), best.len());
        for (stage, key) in &best {
            let shared = stage.starts_with("Search")
                || stage.starts_with("EvalDdp")
                || stage.starts_with("EvalConstant");
            assert_eq!(base.iter().any(|(_, k)| k == key), shared, "{stage}");
        }
    }

    #[test]
    fn names_and_transport_do_not_change_a_key() {
        let base = keys(ONE);
        let renamed = keys(&ONE.replace("name = \"one\"", "name = \"renamed\""));
        assert_eq!(base, renamed);
        let transport = keys(&format!(
            "{ONE}[train.service]\nheartbeat_ms = 500\nlease_ttl_ms = 20000\n"
        ));
        assert_eq!(base, transport);
    }
}
