//! The store of results shared by every experiment, and where each stage of one experiment
//! finds its result in it.
//!
//! A stage's result lives under its recipe's key ([`super::recipe`]), not under the
//! experiment that computed it, so an experiment that contains a stage another one finished
//! reads that result instead of computing it again, and two experiment files that share an
//! arm print the same numbers for it. Layout of a store:
//!
//! | kind | result | marks it finished |
//! |---|---|---|
//! | training | `train/KEY/` (the `adp train` run directory; `export/` holds the policy) | `train/KEY/trained.json` |
//! | constant search | `search/KEY.json` | the file |
//! | untrained policy | `policy/KEY/` (an export directory) | `policy/KEY/policy.json` |
//! | evaluation | `eval/KEY.json` (an [`super::record::EvalRecord`]) | the file |
//!
//! Beside each result, `KEY.stage.json` (`train/KEY/stage.json` for a training) holds its
//! [`StageMeta`]: the recipe, what computed it and how long it took, from which `--plan`
//! estimates what is left. Every file is written through a temporary file and a rename, so
//! a result that exists is complete; results are never overwritten.
//!
//! Thread safety: a [`Store`] is a path; two processes may share a store as long as they do
//! not compute the same stage at once (an experiment's shards write distinct files).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use eval::EvalConfig;

use super::config::Experiment;
use super::plan::{write_atomic, Stage};
use super::recipe::{Inputs, Kind, Recipe};

/// A store of results: a directory.
#[derive(Clone, Debug)]
pub struct Store {
    /// Its root.
    pub dir: PathBuf,
}

/// What the store knows of how a result was made.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StageMeta {
    /// The stage in words, as the experiment that computed it described it.
    pub description: String,
    /// The experiment that computed it (`[experiment] name`).
    pub experiment: String,
    /// Its cost class ([`cost_class`], [`train_class`]): results of one class cost alike per
    /// unit.
    pub class: String,
    /// Work units: episodes for searches and evaluations, agent steps for trainings.
    pub units: f64,
    /// Wall-clock seconds it took (a training's: over every run that worked on it that
    /// left an account, [`super::spent`]).
    pub seconds: f64,
    /// Worker threads it ran on (the cores it had).
    pub threads: usize,
    /// CPU seconds it used (this process and the processes it waited for: a training's
    /// actors), when measured: the cost, whatever else shared the machine.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_s: Option<f64>,
    /// The units `seconds` and `cpu_s` cover, when fewer than `units`: a training resumed
    /// after a run whose time is not known (killed without writing its account, or from
    /// before trainings kept one). Estimates count only these.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timed_units: Option<f64>,
    /// When it finished (seconds since the Unix epoch).
    pub finished_unix_s: u64,
    /// The recipe whose key names it.
    pub recipe: serde_json::Value,
}

impl Store {
    /// Where `r`'s result lives: a file, or for trainings and policies a directory.
    pub fn path(&self, r: &Recipe) -> PathBuf {
        let dir = self.dir.join(r.kind.dir());
        match r.kind {
            Kind::Train | Kind::Policy => dir.join(&r.key.0),
            Kind::Search | Kind::Eval => dir.join(format!("{}.json", r.key)),
        }
    }

    /// The file whose existence says `r`'s result is finished.
    pub fn done_file(&self, r: &Recipe) -> PathBuf {
        match r.kind {
            Kind::Train => self.path(r).join("trained.json"),
            Kind::Policy => self.path(r).join(learner::export::JSON_FILE),
            Kind::Search | Kind::Eval => self.path(r),
        }
    }

    /// Where `r`'s [`StageMeta`] lives.
    pub fn meta_file(&self, r: &Recipe) -> PathBuf {
        match r.kind {
            Kind::Train | Kind::Policy => self.path(r).join("stage.json"),
            Kind::Search | Kind::Eval => self.dir.join(r.kind.dir()).join(format!("{}.stage.json", r.key)),
        }
    }

    /// Records how `r`'s result was made (right after its result is written).
    pub fn write_meta(&self, r: &Recipe, meta: &StageMeta) -> anyhow::Result<()> {
        write_atomic(
            &self.meta_file(r),
            &serde_json::to_vec_pretty(meta).expect("records serialize"),
        )
    }

    /// How `r`'s result was made, when the store recorded it.
    pub fn meta(&self, r: &Recipe) -> Option<StageMeta> {
        let text = std::fs::read_to_string(self.meta_file(r)).ok()?;
        serde_json::from_str(&text).ok()
    }

    /// Every [`StageMeta`] in the store (unreadable records are skipped: they only feed
    /// estimates).
    pub fn all_meta(&self) -> Vec<StageMeta> {
        let mut files = Vec::new();
        for kind in [Kind::Train, Kind::Search, Kind::Policy, Kind::Eval] {
            let Ok(entries) = std::fs::read_dir(self.dir.join(kind.dir())) else {
                continue;
            };
            for e in entries.flatten() {
                let p = e.path();
                if p.is_dir() {
                    files.push(p.join("stage.json"));
                } else if p.to_string_lossy().ends_with(".stage.json") {
                    files.push(p);
                }
            }
        }
        files.sort();
        files
            .iter()
            .filter_map(|f| serde_json::from_str(&std::fs::read_to_string(f).ok()?).ok())
            .collect()
    }
}

/// Samples a training with the default learner replays per agent step: `[td3] batch_size`
/// (128) times `updates_per_insert` (1).
const DEFAULT_REPLAY: f64 = 128.0;

/// The cost class of a training that replays `replay` samples per agent step (`[td3]
/// batch_size` x `updates_per_insert`): the learner's work per agent step, which a training's
/// cost follows besides its planner's. The default replay keeps [`cost_class`]'s name
/// (`train:dwa:decremental`); another gets a class of its own (`train:dwa:decremental:replay32`),
/// so a cheap learner's trainings do not lower the estimate of the default's.
pub fn train_class(planner: &str, space: Option<&str>, replay: f64) -> String {
    let base = cost_class(Kind::Train, planner, space, true);
    if (replay - DEFAULT_REPLAY).abs() < 1e-9 {
        base
    } else {
        format!("{base}:replay{replay}")
    }
}

/// The cost class of a finished stage's record: a training's from the learner settings of its
/// recipe ([`train_class`]; records written before trainings were told apart by them name
/// only the planner and space), any other stage's as recorded.
pub fn class_of(meta: &StageMeta) -> String {
    let td3 = &meta.recipe["inputs"]["td3"];
    let mut parts = meta.class.split(':');
    match (
        parts.next(),
        parts.next(),
        parts.next(),
        td3["batch_size"].as_f64(),
        td3["updates_per_insert"].as_f64(),
    ) {
        (Some("train"), Some(planner), space, Some(batch), Some(rate)) => {
            train_class(planner, space, batch * rate)
        }
        _ => meta.class.clone(),
    }
}

/// The cost class of a stage: the kind, the planner and, for evaluations, whether a network
/// chooses (`policy`) or a fixed schedule does (`schedule`), and the action space (a policy
/// that drives the robot itself runs every episode to its time limit). A training's class
/// also depends on its learner: see [`train_class`].
pub fn cost_class(kind: Kind, planner: &str, space: Option<&str>, network: bool) -> String {
    match kind {
        Kind::Train => format!("train:{planner}:{}", space.unwrap_or("-")),
        Kind::Search | Kind::Policy => format!("search:{planner}:{}", space.unwrap_or("-")),
        Kind::Eval => format!(
            "eval:{planner}:{}:{}",
            if network { "policy" } else { "schedule" },
            space.unwrap_or("-")
        ),
    }
}

/// Where the stages of one experiment find their results: the experiment directory (its
/// `experiment.toml`, report, results and figures) and every stage's result in the store,
/// under its recipe's key.
#[derive(Clone, Debug)]
pub struct Layout {
    /// The experiment directory.
    pub dir: PathBuf,
    /// The store its results live in.
    pub store: Store,
    /// The experiment.
    ex: Experiment,
    /// Its resolved evaluation configuration.
    cfg: EvalConfig,
    /// The actors a training with `[run] actors = 0` starts here.
    cores: u32,
}

impl Layout {
    /// The layout of experiment `ex` evaluated under `cfg`, in `dir`, with its results in
    /// `store`; `cores` is what `[run] actors = 0` resolves to.
    pub fn new(dir: PathBuf, store: Store, ex: &Experiment, cfg: &EvalConfig, cores: u32) -> Self {
        Layout {
            dir,
            store,
            ex: ex.clone(),
            cfg: cfg.clone(),
            cores,
        }
    }

    fn inputs(&self) -> Inputs<'_> {
        Inputs {
            ex: &self.ex,
            cfg: &self.cfg,
            cores: self.cores,
        }
    }

    /// The recipe of `stage`.
    pub fn recipe(&self, stage: &Stage) -> Recipe {
        self.inputs().recipe(stage)
    }

    /// The file `stage` writes, and whose existence says it is finished.
    pub fn output(&self, stage: &Stage) -> PathBuf {
        self.store.done_file(&self.recipe(stage))
    }

    /// The training run directory of arm `arm`'s seed `seed`.
    pub fn run_dir(&self, arm: usize, seed: usize) -> PathBuf {
        self.store.path(&self.recipe(&Stage::Train { arm, seed }))
    }

    /// The export directory of arm `arm`'s untrained policy.
    pub fn untrained_export(&self, arm: usize) -> PathBuf {
        self.store
            .path(&self.inputs().untrained_policy(&self.ex.arms[arm]))
    }

    /// Whether `stage` is finished.
    pub fn done(&self, stage: &Stage) -> bool {
        self.output(stage).exists()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recipe::Key;

    fn recipe(kind: Kind) -> Recipe {
        let mut r = Recipe::new(kind, serde_json::json!({"x": 1}));
        r.key = Key("00112233aabbccdd".into());
        r
    }

    #[test]
    fn results_live_under_their_kind_and_key() {
        let store = Store { dir: "/s".into() };
        assert_eq!(
            store.done_file(&recipe(Kind::Train)),
            PathBuf::from("/s/train/00112233aabbccdd/trained.json")
        );
        assert_eq!(
            store.done_file(&recipe(Kind::Eval)),
            PathBuf::from("/s/eval/00112233aabbccdd.json")
        );
        assert_eq!(
            store.meta_file(&recipe(Kind::Search)),
            PathBuf::from("/s/search/00112233aabbccdd.stage.json")
        );
        assert_eq!(
            store.done_file(&recipe(Kind::Policy)),
            PathBuf::from("/s/policy/00112233aabbccdd/policy.json")
        );
    }

    #[test]
    fn meta_round_trips_and_gives_a_rate() {
        let dir = std::env::temp_dir().join(format!("adp-store-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let store = Store { dir: dir.clone() };
        let r = recipe(Kind::Eval);
        let meta = StageMeta {
            description: "evaluate DDP".into(),
            experiment: "t".into(),
            class: cost_class(Kind::Eval, "dwa", None, false),
            units: 4500.0,
            seconds: 180.0,
            threads: 2,
            cpu_s: None,
            timed_units: None,
            finished_unix_s: 1,
            recipe: serde_json::to_value(&r).unwrap(),
        };
        store.write_meta(&r, &meta).unwrap();
        let back = store.meta(&r).unwrap();
        assert_eq!(back.class, "eval:dwa:schedule:-");
        assert_eq!((back.units, back.seconds, back.threads), (4500.0, 180.0, 2));
        assert_eq!(store.all_meta().len(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
