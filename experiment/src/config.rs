//! The experiment file (`configs/experiments/NAME.toml`): arms, seeds, world splits, the
//! evaluation protocol, the controls, the statistics and the training configuration.
//!
//! Every table refuses keys it does not know, naming the key and the file. `[train]` is a
//! training configuration in the format of `configs/local.toml` (`[train.run]`,
//! `[train.env]`, `[train.td3]`, `[train.service]`, `[train.sandbox]`), laid over the embedded
//! `configs/local.toml` less the main job's recipe ([`MAIN_JOB_KEYS`]) and checked by
//! [`TrainConfig::parse`], so every key `adp train` knows is available here and the main
//! job's recipe can change without changing any experiment. Per arm and seed the experiment sets `[run] planner`,
//! `action_space`, `max_speed`, `worlds` and `name`, `[env] observation` (an arm of
//! `[experiment] observations`), `[td3] seed`, `obs_dim` and `act_dim` (see
//! [`Experiment::train_config`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use actor::LaserLayout;
use planner::ActionSpace;
use sim::lidar::LidarConfig;

use eval::config::one_line;
use eval::LidarOverride;
use planner::PlannerKind;
use train_config::TrainConfig;

/// Why an experiment file cannot be used. The message is one line naming the file and the key,
/// or the command-line restriction.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file cannot be read.
    #[error("cannot read experiment config {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A key of the file holds a value the experiment cannot use (or is unknown).
    #[error("{file}: {message}")]
    Invalid {
        /// The file's name as given.
        file: String,
        /// The table, the key and what is wrong, e.g. `[eval] runs = 0 ...`.
        message: String,
    },
    /// `[train]` is not a valid training configuration; the message names the file.
    #[error("{0}")]
    Train(String),
    /// A command-line restriction (`--planners`, `--spaces`, `--speeds`, `--seeds`) is not a
    /// subset of what the file declares.
    #[error("{0}")]
    Restriction(String),
}

impl ConfigError {
    /// An [`ConfigError::Invalid`] of the file `file`.
    fn invalid(file: &str, message: impl Into<String>) -> Self {
        Self::Invalid {
            file: file.to_owned(),
            message: message.into(),
        }
    }
}

/// A result of reading an experiment file.
pub type Result<T, E = ConfigError> = std::result::Result<T, E>;

/// The embedded training defaults that `[train]` is laid over ([`train_base`]).
const LOCAL_TOML: &str = include_str!("../../configs/local.toml");

/// The keys of `configs/local.toml` that make the main job's recipe (`adp train` with no
/// `--config`), as `(table, key)`. They do not reach experiments: an experiment takes the
/// code's default of each unless its `[train]` sets it, so changing the main job changes no
/// stored stage.
pub const MAIN_JOB_KEYS: [(&str, &str); 7] = [
    ("run", "steps"),
    ("run", "planner"),
    ("td3", "updates_per_insert"),
    ("service", "init_action"),
    ("greedy", "every_steps"),
    ("greedy", "runs"),
    ("greedy", "select"),
];

/// The table `[train]` is laid over: the embedded `configs/local.toml` less
/// [`MAIN_JOB_KEYS`].
pub fn train_base() -> toml::Table {
    let mut base: toml::Table = toml::from_str(LOCAL_TOML).expect("the embedded local.toml parses");
    for (table, key) in MAIN_JOB_KEYS {
        if let Some(toml::Value::Table(t)) = base.get_mut(table) {
            t.remove(key);
        }
    }
    base
}

/// `[experiment]`: what is compared.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentSection {
    /// Name (default output directory `runs/experiments/<name>`).
    pub name: String,
    /// Planners (dwa, mppi, log-mppi, system).
    pub planners: Vec<String>,
    /// ADP action spaces (decremental, incremental, unconstrained, fixed).
    #[serde(default = "default_spaces")]
    pub action_spaces: Vec<String>,
    /// Speed caps (m/s).
    pub speeds: Vec<f64>,
    /// Training-world selections, one arm per entry (split names, ranges or lists,
    /// `generated:N`, or `generated` for a new generated world every assignment; default
    /// `fit`, which leaves `val` to the greedy evaluation of `[train.greedy]`).
    #[serde(default = "default_train_worlds")]
    pub train_worlds: Vec<String>,
    /// The held-out worlds every policy and control is evaluated on.
    #[serde(default = "default_test_worlds")]
    pub test_worlds: String,
    /// Training seeds per arm.
    #[serde(default = "default_seeds")]
    pub seeds: usize,
    /// `[td3] seed` of the first training seed; seed k trains with `first_seed + k`.
    #[serde(default = "default_first_seed")]
    pub first_seed: u64,
    /// Observation layouts (`"scan"`, `"sectors:N"`), one arm per entry (absent: the one
    /// layout of `[train.env] observation`). An arm whose layout is `[train.env]`'s keeps the
    /// id it has without this key; the others' ids end in the layout (`-sectors15`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observations: Option<Vec<String>>,
    /// The store of results (default `runs/store`; `--store` overrides): every stage's
    /// result lives there under the key of what decides it, so experiments that share a
    /// stage compute it once. Relative to the directory `adp experiment` runs in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub store: Option<std::path::PathBuf>,
    /// More arms: each group's cross product of planners, action spaces, speeds and training
    /// worlds (a key it leaves out is this section's) joins the arms, after the section's own
    /// and without repeating an arm. One file can so hold tables whose arms are not one cross
    /// product (a planner x speed grid, and action spaces on one planner).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub groups: Vec<ArmGroup>,
    /// What every arm's training starts from (default `ddp`; a group may set its own). With
    /// `best-constant` the arm's constant search runs before its training (see [`Start`]).
    #[serde(default, skip_serializing_if = "Start::is_ddp")]
    pub start: Start,
}

/// What an arm's training starts from (`start` of `[experiment]` or of a group).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Start {
    /// The training configuration's own start: the actor fitted to DDP (`[train.service]
    /// ddp_init`), or to `[train.service] init_action` when given. The paper's start, and
    /// the one every stage stored before this key existed was trained from.
    #[default]
    Ddp,
    /// The actor fitted to the arm's best constant action from its constant search (on
    /// `[constant_search] worlds`, never a test world), as `[service] init_action` (in place
    /// of any `[train.service] init_action`). The arm's id ends in `-bestconst`, its untrained
    /// control is that fitted actor, and its trainings' recipes name the search's key.
    BestConstant,
}

impl Start {
    /// Whether this is the default start ([`Start::Ddp`]), which recipes and ids leave out.
    pub fn is_ddp(&self) -> bool {
        *self == Start::Ddp
    }
}

/// `[[experiment.groups]]`: one more cross product of arms.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmGroup {
    /// What the group is for (a table's name, for the reader).
    #[serde(default)]
    pub name: String,
    /// Planners (default: `[experiment] planners`).
    pub planners: Option<Vec<String>>,
    /// Action spaces (default: `[experiment] action_spaces`).
    pub action_spaces: Option<Vec<String>>,
    /// Speed caps (default: `[experiment] speeds`).
    pub speeds: Option<Vec<f64>>,
    /// Training-world selections (default: `[experiment] train_worlds`).
    pub train_worlds: Option<Vec<String>>,
    /// What the group's arms start from (default: `[experiment] start`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<Start>,
    /// The name of the group's training recipe (lower-case letters, digits and `-`): its
    /// arms' ids end in `-<recipe>`, and the paper's tables show them as rows of their own
    /// beside the experiment's recipe. Required with `train`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recipe: Option<String>,
    /// The recipe's training settings, in the format of `[train]`, laid over the experiment's
    /// `[train]` for this group's trainings only. DDP, vanilla, the constant search and the
    /// best constant are the experiment's (they read `[train.env]` of the experiment, not
    /// this table), so every recipe of a cell is compared with the same controls.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train: Option<toml::Table>,
}

impl ArmGroup {
    /// The section with this group's keys in place of its own, and no groups.
    fn over(&self, ex: &ExperimentSection) -> ExperimentSection {
        ExperimentSection {
            planners: self.planners.clone().unwrap_or_else(|| ex.planners.clone()),
            action_spaces: self
                .action_spaces
                .clone()
                .unwrap_or_else(|| ex.action_spaces.clone()),
            speeds: self.speeds.clone().unwrap_or_else(|| ex.speeds.clone()),
            train_worlds: self
                .train_worlds
                .clone()
                .unwrap_or_else(|| ex.train_worlds.clone()),
            groups: Vec::new(),
            start: self.start.unwrap_or(ex.start),
            ..ex.clone()
        }
    }
}

fn default_spaces() -> Vec<String> {
    vec!["decremental".into()]
}
fn default_train_worlds() -> Vec<String> {
    vec!["fit".into()]
}
fn default_test_worlds() -> String {
    "test".into()
}
fn default_seeds() -> usize {
    3
}
fn default_first_seed() -> u64 {
    1
}

/// `[eval]`: the papers' protocol on the test worlds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalSection {
    /// Runs per world.
    pub runs: usize,
    /// Fastest and slowest runs dropped per world.
    pub trim: usize,
    /// Base seed of every run (shared by all controllers, so runs pair by seed).
    pub seed: u64,
    /// Start-position jitter (m), see `[episode] start_jitter_m` of `configs/eval.toml`.
    pub start_jitter_m: f64,
    /// Start-heading jitter (rad).
    pub start_jitter_yaw_rad: f64,
    /// An evaluation configuration (planner tunables; default: the embedded
    /// `configs/eval.toml`). Its `[episode] profile` is replaced by `[train.env] profile`.
    pub config: Option<String>,
    /// Also evaluate the vanilla schedule (the planner's uniform fine grid) per planner and
    /// speed: the DDP paper's calibration row.
    pub vanilla: bool,
}

impl Default for EvalSection {
    fn default() -> Self {
        Self {
            runs: 20,
            trim: 5,
            seed: 0,
            start_jitter_m: 0.1,
            start_jitter_yaw_rad: 0.1,
            config: None,
            vanilla: false,
        }
    }
}

/// `[constant_search]`: the best constant schedule, searched on training worlds only.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SearchSection {
    /// Worlds searched on (must not meet the test worlds).
    pub worlds: String,
    /// Candidate actions: DDP's, then DDP with one dimension at either end (for spaces of at
    /// most 8 dimensions), then seeded uniform draws, up to this many.
    pub candidates: usize,
    /// Runs per world that the finalists get (the resource ceiling of the halving).
    pub runs: usize,
    /// Successive halving: every candidate first runs `first_pairs` (world, run) pairs; each
    /// rung keeps the best `1 / eta` by mean score and gives the survivors `eta` times the
    /// pairs, until `runs` runs of every world are reached ([`super::controls::halving`]).
    pub eta: usize,
    /// (World, run) pairs of the first rung.
    pub first_pairs: usize,
    /// Seed of the draws, of the pair order and of the runs.
    pub seed: u64,
}

impl Default for SearchSection {
    fn default() -> Self {
        Self {
            worlds: "train".into(),
            candidates: 243,
            runs: 9,
            eta: 3,
            first_pairs: 25,
            seed: 1,
        }
    }
}

/// `[compute_sweep]`: DDP, the best constant and every ADP seed of one arm evaluated under
/// other cycle budgets of the training compute model, and without a compute model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SweepSection {
    /// Budget multipliers of `[train.env.compute]` (empty: no sweep).
    pub budget_scales: Vec<f64>,
    /// Also evaluate under `model = "free"` (no budget, no modelled latency).
    pub free: bool,
    /// Runs per test world of each sweep evaluation.
    pub runs: usize,
    /// Fastest and slowest runs dropped per world before averaging (as `[eval] trim`, for
    /// this section's own run count: `2 * trim < runs`).
    pub trim: usize,
    /// The arm swept (index into the arms in file order: planners x spaces x speeds x
    /// training worlds x observations).
    pub arm: usize,
}

impl Default for SweepSection {
    fn default() -> Self {
        Self {
            budget_scales: Vec::new(),
            free: false,
            runs: 5,
            trim: 1,
            arm: 0,
        }
    }
}

/// `[sensing_sweep]`: DDP, the best constant and every ADP seed of the covered arms evaluated
/// on the test worlds under other lidar conditions (the evaluation's lidar only: the
/// planner's costmap and the policy's observation both see the degraded scan). The
/// conditions are the cross product beams x noise fractions x dropouts, in that order (an
/// empty list keeps the `[eval] config`'s value); all three empty: no sweep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensingSection {
    /// Lidar beam counts over the 270-degree field.
    pub beams: Vec<usize>,
    /// Range noise sigmas as fractions of each scan's mean range (each replaces the absolute
    /// `noise_sigma`, which becomes 0: a fraction of 0 is a noiseless lidar).
    pub noise_fractions: Vec<f64>,
    /// Probabilities that a beam returns nothing.
    pub dropouts: Vec<f64>,
    /// Runs per test world of each sweep evaluation.
    pub runs: usize,
    /// Fastest and slowest runs dropped per world before averaging (`2 * trim < runs`).
    pub trim: usize,
    /// The arms covered (indices into the arms in file order, as `[compute_sweep] arm`);
    /// empty: every arm.
    pub arms: Vec<usize>,
}

impl Default for SensingSection {
    fn default() -> Self {
        Self {
            beams: Vec::new(),
            noise_fractions: Vec::new(),
            dropouts: Vec::new(),
            runs: 5,
            trim: 1,
            arms: Vec::new(),
        }
    }
}

/// `[shuffle]`: the state-shuffled control.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShuffleSection {
    /// Worlds whose observations fill the pool (must not meet the test worlds).
    pub worlds: String,
    /// At most this many of them are driven (the first ones of the selection).
    pub max_worlds: usize,
    /// Observations kept (seeded reservoir sample over every agent step driven).
    pub pool: usize,
    /// Seed of the reservoir and of the per-step draws.
    pub seed: u64,
    /// The speed caps whose arms get the control (empty: every arm). It asks whether the
    /// policy uses what it sees, which one speed answers; the others save its evaluations.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub speeds: Vec<f64>,
}

impl Default for ShuffleSection {
    fn default() -> Self {
        Self {
            worlds: "train".into(),
            max_worlds: 10,
            pool: 4096,
            seed: 2,
            speeds: Vec::new(),
        }
    }
}

/// `[stats]`: the paired statistics.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StatsSection {
    /// Bootstrap resamples.
    pub resamples: usize,
    /// Confidence of the intervals.
    pub confidence: f64,
    /// Seed of the resampling.
    pub seed: u64,
}

impl Default for StatsSection {
    fn default() -> Self {
        Self {
            resamples: 10_000,
            confidence: 0.95,
            seed: 3,
        }
    }
}

/// `[figures]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FiguresSection {
    /// Test world of the rendered ADP episode (default: the last test world, the hardest).
    pub render_world: Option<usize>,
}

/// `[report]`: what the report shows besides the per-arm tables.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReportSection {
    /// Lead with the ADP paper's Tables I-III, beside the papers' numbers, and write them
    /// to `results.json` (`{"paper": ..., "arms": ...}`) and the compact Table I to
    /// `table1.md`.
    pub paper_tables: bool,
    /// The hardest test worlds of Table III (a subset of the test worlds).
    pub hardest: String,
    /// What the reader must know that the protocol does not show, one sentence each (e.g. a
    /// setting that was chosen on test worlds before this file existed): printed under the
    /// protocol and above the tables, and the protocol's "the test worlds are used for
    /// nothing but these numbers" points to them.
    pub limitations: Vec<String>,
}

impl Default for ReportSection {
    fn default() -> Self {
        Self {
            paper_tables: false,
            hardest: "hardest50".into(),
            limitations: Vec::new(),
        }
    }
}

/// `[slurm]`: the job `adp experiment --emit-slurm` writes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlurmJob {
    /// Nodes of the allocation.
    pub nodes: u32,
    /// Tasks: the evaluation shards (one per task).
    pub tasks: u32,
    /// CPUs per task.
    pub cpus_per_task: u32,
    /// Time limit `[D-]HH:MM:SS`.
    pub time: String,
    /// Partition; empty = the cluster's default.
    pub partition: String,
    /// Account; empty = the user's default.
    pub account: String,
    /// Shell lines run first (e.g. `module load ...`).
    pub setup: Vec<String>,
    /// The `adp` executable on the compute nodes; empty = the one that wrote the script.
    pub adp: String,
}

impl Default for SlurmJob {
    fn default() -> Self {
        Self {
            nodes: 1,
            tasks: 8,
            cpus_per_task: 1,
            time: "24:00:00".into(),
            partition: String::new(),
            account: String::new(),
            setup: Vec::new(),
            adp: String::new(),
        }
    }
}

/// The file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    experiment: ExperimentSection,
    #[serde(default)]
    eval: EvalSection,
    #[serde(default)]
    constant_search: SearchSection,
    #[serde(default)]
    shuffle: ShuffleSection,
    #[serde(default)]
    compute_sweep: SweepSection,
    #[serde(default)]
    sensing_sweep: SensingSection,
    #[serde(default)]
    stats: StatsSection,
    #[serde(default)]
    figures: FiguresSection,
    #[serde(default)]
    report: ReportSection,
    #[serde(default)]
    slurm: SlurmJob,
    #[serde(default)]
    train: toml::Table,
}

/// One arm: a planner, an action space, a speed cap, a set of training worlds and an
/// observation layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Arm {
    /// The planner.
    pub planner: PlannerKind,
    /// The ADP action space.
    pub space: ActionSpace,
    /// Speed cap (m/s).
    pub speed: f64,
    /// Training-world selection as written.
    pub train_worlds: String,
    /// The observation layout when it is not `[train.env] observation` (`None`: that one).
    pub observation: Option<LaserLayout>,
    /// What its training starts from.
    pub start: Start,
    /// The training recipe of its group (`None`: the experiment's `[train]`).
    pub recipe: Option<String>,
}

impl Arm {
    /// A file-name-safe id, e.g. `dwa-decremental-1.5-train`, with an observation layout
    /// of its own `dwa-decremental-1.5-train-sectors15`, and starting from the best constant
    /// `dwa-decremental-1.5-train-bestconst`, and of a group's recipe `project` in
    /// `dwa-decremental-1.5-train-bestconst-project`. Only letters, digits and `-+._`: a
    /// space's `:` becomes `_` (`dwa-weights_dwa-1.5-fit`), since the ids name directories of
    /// experiments kept in the repository, and Windows checkouts refuse `:` in a path.
    pub fn id(&self) -> String {
        let worlds: String = self
            .train_worlds
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let layout: String = self.observation.map_or_else(String::new, |l| {
            let name: String = l
                .to_string()
                .chars()
                .filter(char::is_ascii_alphanumeric)
                .collect();
            format!("-{name}")
        });
        let start = match self.start {
            Start::Ddp => "",
            Start::BestConstant => "-bestconst",
        };
        let recipe = self.recipe.as_ref().map_or_else(String::new, |r| format!("-{r}"));
        format!(
            "{}-{}-{}-{worlds}{layout}{start}{recipe}",
            planner_name(self.planner),
            space_label(self.space).replace(':', "_"),
            speed_label(self.speed)
        )
    }

    /// Whether `other` differs from this arm at most in its observation layout and training
    /// worlds, so that its DDP, constant search and best constant are this arm's: they observe
    /// nothing and are searched on `[constant_search] worlds`, one selection for every arm.
    pub fn same_controls(&self, other: &Arm) -> bool {
        (self.planner, self.space) == (other.planner, other.space) && self.speed == other.speed
    }

    /// Whether `other` differs from this arm at most in its training worlds, so that its
    /// untrained policy (the initialized actor of the first seed, which has seen no world) is
    /// this arm's.
    pub fn same_untrained(&self, other: &Arm) -> bool {
        self.same_controls(other)
            && self.observation == other.observation
            && self.start == other.start
            && self.recipe == other.recipe
    }
}

/// The planner's name as on the command line (`log-mppi`).
pub fn planner_name(p: PlannerKind) -> String {
    p.name().to_string()
}

/// The action space's name (`decremental`).
pub fn space_label(s: ActionSpace) -> String {
    learner::export::space_name(s)
}

/// A speed as in file names and tables (`1.5`, `2.0`).
pub fn speed_label(v: f64) -> String {
    format!("{v:.1}")
}

/// Restrictions of an experiment, e.g. from the command line (each must be a subset of the file's).
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Restrict {
    /// Only these planners (comma-separated; a subset of the file's).
    #[cfg_attr(feature = "clap", arg(long, value_enum, value_delimiter = ','))]
    pub planners: Vec<PlannerKind>,
    /// Only these action spaces (comma-separated; a subset of the file's).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub spaces: Vec<ActionSpace>,
    /// Only these speed caps (comma-separated; a subset of the file's).
    #[cfg_attr(feature = "clap", arg(long, value_delimiter = ','))]
    pub speeds: Vec<f64>,
    /// Only the first this many training seeds of each arm.
    #[cfg_attr(feature = "clap", arg(long))]
    pub seeds: Option<usize>,
    /// Agent steps per training run (overrides `[train.run]` steps).
    #[cfg_attr(feature = "clap", arg(long))]
    pub steps: Option<u64>,
}

/// A checked experiment.
#[derive(Clone, Debug)]
pub struct Experiment {
    /// `[experiment]`.
    pub section: ExperimentSection,
    /// `[eval]`.
    pub eval: EvalSection,
    /// `[constant_search]`.
    pub search: SearchSection,
    /// `[shuffle]`.
    pub shuffle: ShuffleSection,
    /// `[compute_sweep]`.
    pub sweep: SweepSection,
    /// `[sensing_sweep]`.
    pub sensing: SensingSection,
    /// `[stats]`.
    pub stats: StatsSection,
    /// `[slurm]`.
    pub slurm: SlurmJob,
    /// `[train]` over [`train_base`].
    pub train: TrainConfig,
    /// The groups' training recipes by name: a group's `train` over the experiment's
    /// `[train]`.
    pub recipes: Vec<(String, TrainConfig)>,
    /// The arms (after restrictions), planner-major.
    pub arms: Vec<Arm>,
    /// Seeds per arm (after restrictions).
    pub seeds: usize,
    /// Test world ids.
    pub test_worlds: Vec<usize>,
    /// Constant-search world ids.
    pub search_worlds: Vec<usize>,
    /// Shuffle-pool world ids (at most `max_worlds`).
    pub pool_worlds: Vec<usize>,
    /// The world of the rendered episode.
    pub render_world: usize,
    /// `[report]`.
    pub report: ReportSection,
    /// The hardest test worlds of `[report] hardest` (with `paper_tables`; else empty).
    pub hardest_worlds: Vec<usize>,
}

/// Deep merge: `over`'s values replace `base`'s, tables merge key by key.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// `[train]` laid over [`train_base`] and checked, with `--steps` applied; unknown keys of
/// `[train]` are named as written.
fn parse_train(name: &str, table: toml::Table, restrict: &Restrict) -> Result<TrainConfig> {
    parse_recipe(name, "[train]", &[table], restrict)
}

/// `layers` laid in order over [`train_base`] and checked, with `--steps` applied; `what`
/// names the last layer in errors (`[train]`, or a group's `train`).
fn parse_recipe(name: &str, what: &str, layers: &[toml::Table], restrict: &Restrict) -> Result<TrainConfig> {
    let mut base = train_base();
    for table in layers {
        // Unknown keys are named before the merge (whose text has other lines).
        TrainConfig::deserialize(table.clone())
            .map_err(|e| ConfigError::invalid(name, format!("{what}: {}", one_line(&e.to_string()))))?;
        merge(&mut base, table.clone());
    }
    let mut train = TrainConfig::parse(
        &format!("{name}: {what}"),
        &toml::to_string(&base).expect("a TOML table serializes"),
    )
    .map_err(|e| ConfigError::Train(one_line(&e.to_string())))?;
    if let Some(steps) = restrict.steps {
        train.run.steps = steps;
    }
    Ok(train)
}

/// The groups' recipes (a group's `train` over `[train]`), by name: a name is lower-case
/// letters, digits and `-`, a `train` table needs one, and groups that share a name share
/// their table.
fn group_recipes(
    name: &str,
    ex: &ExperimentSection,
    train: &toml::Table,
    restrict: &Restrict,
) -> Result<Vec<(String, TrainConfig)>> {
    let mut recipes: Vec<(String, &toml::Table, TrainConfig)> = Vec::new();
    for (i, g) in ex.groups.iter().enumerate() {
        let label = format!("[[experiment.groups]] {} ({:?})", i + 1, g.name);
        let err = |what: String| ConfigError::invalid(name, format!("{label}: {what}"));
        let (recipe, table) = match (&g.recipe, &g.train) {
            (None, None) => continue,
            (None, Some(_)) => return Err(err("`train` needs a `recipe` name for its arms".into())),
            (Some(r), None) => {
                return Err(err(format!(
                    "recipe {r:?} has no `train` table (the experiment's own recipe has no name)"
                )))
            }
            (Some(r), Some(t)) => (r, t),
        };
        if recipe.is_empty()
            || !recipe
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-')
        {
            return Err(err(format!(
                "recipe {recipe:?}: a name is lower-case letters, digits and `-`"
            )));
        }
        match recipes.iter().find(|(r, _, _)| r == recipe) {
            Some((_, t, _)) if *t != table => {
                return Err(err(format!(
                    "recipe {recipe:?} is declared twice with different `train` tables"
                )))
            }
            Some(_) => {}
            None => {
                let cfg = parse_recipe(
                    name,
                    &format!("{label} train"),
                    &[train.clone(), table.clone()],
                    restrict,
                )?;
                recipes.push((recipe.clone(), table, cfg));
            }
        }
    }
    Ok(recipes.into_iter().map(|(r, _, c)| (r, c)).collect())
}

/// The planners and action spaces of `[experiment]`, checked with its speeds and seeds.
fn planners_and_spaces(name: &str, ex: &ExperimentSection) -> Result<(Vec<PlannerKind>, Vec<ActionSpace>)> {
    let err = |key: &str, what: String| ConfigError::invalid(name, format!("[experiment] {key}: {what}"));
    let planners: Vec<PlannerKind> = ex
        .planners
        .iter()
        .map(|p| {
            p.parse::<PlannerKind>().map_err(|_| {
                err(
                    "planners",
                    format!("unknown planner `{p}` (dwa, mppi, log-mppi, system)"),
                )
            })
        })
        .collect::<Result<_>>()?;
    let spaces: Vec<ActionSpace> = ex
        .action_spaces
        .iter()
        .map(|s| {
            s.parse()
                .map_err(|e: planner::NameError| err("action_spaces", e.to_string()))
        })
        .collect::<Result<_>>()?;
    if planners.is_empty() || spaces.is_empty() || ex.speeds.is_empty() || ex.train_worlds.is_empty() {
        return Err(ConfigError::invalid(
            name,
            "[experiment] planners, action_spaces, speeds and train_worlds must not be empty",
        ));
    }
    // A space that sets a planner's objective gains pairs only with that planner.
    for s in &spaces {
        if let Some(g) = s.gains() {
            if !planners.iter().any(|p| p.name() == g.planner()) {
                return Err(err(
                    "action_spaces",
                    format!(
                        "`{s}` sets the gains of {}, which is not in planners",
                        g.planner()
                    ),
                ));
            }
        }
    }
    for &v in &ex.speeds {
        if !(v.is_finite() && v > 0.0 && v <= 2.0) {
            return Err(err("speeds", format!("{v} must be in (0, 2] m/s")));
        }
    }
    if ex.seeds == 0 {
        return Err(err("seeds", "must be at least 1".into()));
    }
    Ok((planners, spaces))
}

/// The test, constant-search and shuffle-pool world ids, in that order; every selection
/// other than the test worlds (also the training and greedy-evaluation worlds) must select
/// at least one world and no test world.
fn world_splits(
    name: &str,
    ex: &ExperimentSection,
    train: &TrainConfig,
    search: &SearchSection,
    shuffle: &ShuffleSection,
) -> Result<(Vec<usize>, Vec<usize>, Vec<usize>)> {
    let select = |section: &str, key: &str, sel: &str| {
        sim::splits::select(sel)
            .map_err(|e| ConfigError::invalid(name, format!("[{section}] {key} = {sel:?}: {e}")))
    };
    let test_worlds = select("experiment", "test_worlds", &ex.test_worlds)?;
    let disjoint = |section: &str, key: &str, sel: &str| -> Result<Vec<usize>> {
        let ids = select(section, key, sel)?;
        if let Some(w) = ids.iter().find(|w| test_worlds.contains(w)) {
            return Err(ConfigError::invalid(
                name,
                format!(
                    "[{section}] {key} = {sel:?} includes test world {w}: the test worlds \
                 ({}) are never used for training or selection",
                    ex.test_worlds
                ),
            ));
        }
        if ids.is_empty() {
            return Err(ConfigError::invalid(
                name,
                format!("[{section}] {key} = {sel:?} selects no world"),
            ));
        }
        Ok(ids)
    };
    for tw in &ex.train_worlds {
        if tw.trim() == sim::splits::FRESH_GENERATED {
            // A new generated world for every assignment: none may be a test world.
            if let Some(w) = test_worlds.iter().find(|&&w| sim::catalog::is_generated(w)) {
                return Err(ConfigError::invalid(
                    name,
                    format!(
                        "[experiment] train_worlds = \"generated\" may deal test world {w} \
                     (the test worlds include generated ones)"
                    ),
                ));
            }
            continue;
        }
        disjoint("experiment", "train_worlds", tw)?;
    }
    if train.greedy.every_steps > 0 {
        disjoint("train.greedy", "worlds", &train.greedy.worlds)?;
    }
    let search_worlds = disjoint("constant_search", "worlds", &search.worlds)?;
    let mut pool_worlds = disjoint("shuffle", "worlds", &shuffle.worlds)?;
    pool_worlds.truncate(shuffle.max_worlds.max(1));
    Ok((test_worlds, search_worlds, pool_worlds))
}

/// Checks `[eval]`, `[constant_search]`, `[slurm]`, `[shuffle]` and `[stats]`, in that order.
fn check_tables(
    name: &str,
    ev: &EvalSection,
    cs: &SearchSection,
    sl: &SlurmJob,
    shuffle: &ShuffleSection,
    st: &StatsSection,
) -> Result<()> {
    if ev.runs == 0 || 2 * ev.trim >= ev.runs {
        return Err(ConfigError::invalid(
            name,
            format!(
                "[eval] runs = {} and trim = {}: runs must be at least 1 and trim less than \
             half of runs",
                ev.runs, ev.trim
            ),
        ));
    }
    let jitter = sim::EpisodeConfig {
        start_jitter_m: ev.start_jitter_m,
        start_jitter_yaw_rad: ev.start_jitter_yaw_rad,
        ..sim::EpisodeConfig::default()
    };
    jitter
        .validate()
        .map_err(|e| ConfigError::invalid(name, format!("[eval] {e}")))?;
    if cs.candidates == 0 || cs.runs == 0 || cs.first_pairs == 0 || cs.eta < 2 {
        return Err(ConfigError::invalid(
            name,
            "[constant_search] candidates, runs and first_pairs must be at least 1 and \
             eta at least 2",
        ));
    }
    if sl.nodes == 0 || sl.tasks == 0 || sl.cpus_per_task == 0 || sl.time.is_empty() {
        return Err(ConfigError::invalid(
            name,
            "[slurm] nodes, tasks and cpus_per_task must be at least 1 and time set",
        ));
    }
    if shuffle.pool == 0 {
        return Err(ConfigError::invalid(name, "[shuffle] pool must be at least 1"));
    }
    if !(st.confidence > 0.0 && st.confidence < 1.0) || st.resamples == 0 {
        return Err(ConfigError::invalid(
            name,
            format!(
                "[stats] confidence = {} must be in (0, 1) and resamples = {} at least 1",
                st.confidence, st.resamples
            ),
        ));
    }
    Ok(())
}

/// The seeds per arm after `--seeds`, once every restriction is checked to be a subset of
/// what the file declares.
fn restricted_seeds(
    name: &str,
    restrict: &Restrict,
    planners: &[PlannerKind],
    spaces: &[ActionSpace],
    ex: &ExperimentSection,
) -> Result<usize> {
    // Restrictions: each a subset of what the file declares.
    let keep = |flag: &str, listed: bool, value: String| -> Result<()> {
        if listed {
            Ok(())
        } else {
            Err(ConfigError::Restriction(format!(
                "{flag} {value}: not in the experiment's {name}"
            )))
        }
    };
    for p in &restrict.planners {
        keep("--planners", planners.contains(p), planner_name(*p))?;
    }
    for s in &restrict.spaces {
        keep("--spaces", spaces.contains(s), space_label(*s))?;
    }
    for v in &restrict.speeds {
        keep(
            "--speeds",
            ex.speeds.iter().any(|x| (x - v).abs() < 1e-9),
            speed_label(*v),
        )?;
    }
    let seeds = match restrict.seeds {
        Some(0) => return Err(ConfigError::Restriction("--seeds must be at least 1".into())),
        Some(s) if s > ex.seeds => {
            return Err(ConfigError::Restriction(format!(
                "--seeds {s}: the experiment declares {} seeds",
                ex.seeds
            )))
        }
        Some(s) => s,
        None => ex.seeds,
    };
    Ok(seeds)
}

/// The arms, planner-major: every kept planner, action space (a gains space only with its
/// planner), speed, training-world selection and observation layout (`observations`, as
/// [`observation_layouts`] gives them).
fn restricted_arms(
    restrict: &Restrict,
    planners: &[PlannerKind],
    spaces: &[ActionSpace],
    ex: &ExperimentSection,
    observations: &[Option<LaserLayout>],
    recipe: Option<&str>,
) -> Vec<Arm> {
    let mut arms = Vec::new();
    for &planner in planners
        .iter()
        .filter(|p| restrict.planners.is_empty() || restrict.planners.contains(p))
    {
        for &space in spaces.iter().filter(|s| {
            (restrict.spaces.is_empty() || restrict.spaces.contains(s))
                && s.gains().is_none_or(|g| g.planner() == planner.name())
        }) {
            for &speed in ex.speeds.iter().filter(|v| {
                restrict.speeds.is_empty() || restrict.speeds.iter().any(|x| (x - *v).abs() < 1e-9)
            }) {
                for tw in &ex.train_worlds {
                    for &observation in observations {
                        arms.push(Arm {
                            planner,
                            space,
                            speed,
                            train_worlds: tw.clone(),
                            observation,
                            start: ex.start,
                            recipe: recipe.map(str::to_string),
                        });
                    }
                }
            }
        }
    }
    arms
}

/// The observation layouts of `[experiment] observations` in file order, `None` for the one
/// of `[train.env] observation` (`base`); absent: that one alone.
fn observation_layouts(
    name: &str,
    ex: &ExperimentSection,
    base: LaserLayout,
) -> Result<Vec<Option<LaserLayout>>> {
    let Some(listed) = &ex.observations else {
        return Ok(vec![None]);
    };
    if listed.is_empty() {
        return Err(ConfigError::invalid(
            name,
            "[experiment] observations must not be empty (leave it out for [train.env] observation)",
        ));
    }
    let mut layouts: Vec<LaserLayout> = Vec::new();
    for text in listed {
        let layout: LaserLayout = text
            .parse()
            .map_err(|e| ConfigError::invalid(name, format!("[experiment] observations: {e}")))?;
        if layouts.contains(&layout) {
            return Err(ConfigError::invalid(
                name,
                format!("[experiment] observations: `{text}` is listed twice"),
            ));
        }
        layouts.push(layout);
    }
    Ok(layouts.into_iter().map(|l| (l != base).then_some(l)).collect())
}

/// Checks `[sensing_sweep]` against the experiment's `arm_count` arms: every value a lidar
/// can take, no value twice, its runs and trim, and its arms.
fn check_sensing(name: &str, s: &SensingSection, arm_count: usize) -> Result<()> {
    let err = |key: &str, what: String| ConfigError::invalid(name, format!("[sensing_sweep] {key}{what}"));
    let check = |key: &str, value: String, lidar: LidarConfig| {
        lidar.validate().map_err(|e| err(key, format!(" = {value}: {e}")))
    };
    for &beams in &s.beams {
        check(
            "beams",
            beams.to_string(),
            LidarConfig {
                beams,
                ..LidarConfig::default()
            },
        )?;
    }
    for &noise_fraction in &s.noise_fractions {
        let lidar = LidarConfig {
            noise_fraction,
            noise_sigma: 0.0,
            ..LidarConfig::default()
        };
        check("noise_fractions", noise_fraction.to_string(), lidar)?;
    }
    for &dropout in &s.dropouts {
        check(
            "dropouts",
            dropout.to_string(),
            LidarConfig {
                dropout,
                ..LidarConfig::default()
            },
        )?;
    }
    let twice = |values: Vec<String>| {
        let first = values.iter().enumerate().find(|(i, v)| values[..*i].contains(v));
        first.map(|(_, v)| v.clone())
    };
    for (key, values) in [
        ("beams", s.beams.iter().map(ToString::to_string).collect()),
        (
            "noise_fractions",
            s.noise_fractions.iter().map(ToString::to_string).collect(),
        ),
        ("dropouts", s.dropouts.iter().map(ToString::to_string).collect()),
        ("arms", s.arms.iter().map(ToString::to_string).collect()),
    ] {
        if let Some(v) = twice(values) {
            return Err(err(key, format!(": {v} is listed twice")));
        }
    }
    if s.runs == 0 || 2 * s.trim >= s.runs {
        return Err(err(
            "runs",
            format!(
                " = {} and trim = {}: runs must be at least 1 and trim less than half of runs",
                s.runs, s.trim
            ),
        ));
    }
    if let Some(a) = s.arms.iter().find(|&&a| a >= arm_count) {
        return Err(err(
            "arms",
            format!(": arm {a}, but the experiment has {arm_count} arm(s) (indices from 0)"),
        ));
    }
    Ok(())
}

/// Checks `[compute_sweep]` against the experiment's `arm_count` arms.
fn check_sweep(name: &str, sweep: &SweepSection, arm_count: usize) -> Result<()> {
    if !sweep.budget_scales.is_empty() || sweep.free {
        if sweep.arm >= arm_count {
            return Err(ConfigError::invalid(
                name,
                format!(
                    "[compute_sweep] arm = {} but the experiment has {} arm(s)",
                    sweep.arm, arm_count
                ),
            ));
        }
        if sweep.runs == 0
            || 2 * sweep.trim >= sweep.runs
            || sweep.budget_scales.iter().any(|k| !(k.is_finite() && *k > 0.0))
        {
            return Err(ConfigError::invalid(
                name,
                format!(
                    "[compute_sweep] runs = {} and trim = {}: runs must be at least 1, trim \
                 less than half of runs, and every budget scale finite and > 0",
                    sweep.runs, sweep.trim
                ),
            ));
        }
    }
    Ok(())
}

impl Experiment {
    /// Reads and checks the experiment file `path`.
    pub fn load(path: &Path, restrict: &Restrict) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&path.display().to_string(), &text, restrict)
    }

    /// Parses and checks the experiment file `text`; every error is one line starting with
    /// `name`.
    pub fn parse(name: &str, text: &str, restrict: &Restrict) -> Result<Self> {
        let raw: RawFile =
            toml::from_str(text).map_err(|e| ConfigError::invalid(name, one_line(&e.to_string())))?;
        let train = parse_train(name, raw.train.clone(), restrict)?;
        let ex = &raw.experiment;
        let recipes = group_recipes(name, ex, &raw.train, restrict)?;
        let (mut planners, mut spaces) = planners_and_spaces(name, ex)?;
        let (test_worlds, search_worlds, pool_worlds) =
            world_splits(name, ex, &train, &raw.constant_search, &raw.shuffle)?;
        // Every group is checked as a section of its own; restrictions may name what any
        // group declares.
        let mut declared = ex.clone();
        let mut groups = Vec::new();
        for (i, g) in ex.groups.iter().enumerate() {
            let gx = g.over(ex);
            let label = format!("{name}: [[experiment.groups]] {} ({:?})", i + 1, g.name);
            let (gp, gs) = planners_and_spaces(&label, &gx)?;
            world_splits(&label, &gx, &train, &raw.constant_search, &raw.shuffle)?;
            for p in &gp {
                if !planners.contains(p) {
                    planners.push(*p);
                }
            }
            for sp in &gs {
                if !spaces.contains(sp) {
                    spaces.push(*sp);
                }
            }
            for v in &gx.speeds {
                if !declared.speeds.contains(v) {
                    declared.speeds.push(*v);
                }
            }
            groups.push((gp, gs, gx));
        }
        check_tables(
            name,
            &raw.eval,
            &raw.constant_search,
            &raw.slurm,
            &raw.shuffle,
            &raw.stats,
        )?;
        let render_world = match raw.figures.render_world {
            Some(w) if !test_worlds.contains(&w) => {
                return Err(ConfigError::invalid(
                    name,
                    format!("[figures] render_world = {w} is not one of the test worlds"),
                ))
            }
            Some(w) => w,
            None => *test_worlds
                .last()
                .ok_or_else(|| ConfigError::invalid(name, "[experiment] test_worlds selects no world"))?,
        };
        let seeds = restricted_seeds(name, restrict, &planners, &spaces, &declared)?;
        let observations = observation_layouts(name, ex, train.env.observation)?;
        let (own_planners, own_spaces) = planners_and_spaces(name, ex)?;
        let mut arms = restricted_arms(restrict, &own_planners, &own_spaces, ex, &observations, None);
        for ((gp, gs, gx), g) in groups.iter().zip(&ex.groups) {
            for a in restricted_arms(restrict, gp, gs, gx, &observations, g.recipe.as_deref()) {
                if !arms.contains(&a) {
                    arms.push(a);
                }
            }
        }
        if arms.is_empty() {
            return Err(ConfigError::invalid(name, "the restrictions leave no arm"));
        }
        let hardest_worlds = if raw.report.paper_tables {
            let ids = sim::splits::select(&raw.report.hardest).map_err(|e| {
                ConfigError::invalid(name, format!("[report] hardest = {:?}: {e}", raw.report.hardest))
            })?;
            if let Some(w) = ids.iter().find(|w| !test_worlds.contains(w)) {
                return Err(ConfigError::invalid(
                    name,
                    format!(
                        "[report] hardest = {:?} includes world {w}, which is not a test world",
                        raw.report.hardest
                    ),
                ));
            }
            ids
        } else {
            Vec::new()
        };
        let sweep = raw.compute_sweep;
        check_sweep(name, &sweep, arms.len())?;
        let sensing = raw.sensing_sweep;
        check_sensing(name, &sensing, arms.len())?;
        Ok(Self {
            section: raw.experiment,
            eval: raw.eval,
            search: raw.constant_search,
            shuffle: raw.shuffle,
            sweep,
            sensing,
            stats: raw.stats,
            slurm: raw.slurm,
            train,
            recipes,
            arms,
            seeds,
            test_worlds,
            search_worlds,
            pool_worlds,
            render_world,
            report: raw.report,
            hardest_worlds,
        })
    }

    /// The compute models of the budget sweep, in order (empty without a sweep).
    pub fn sweep_points(&self) -> Vec<planner::ComputeConfig> {
        let base = self.train.env.compute;
        let mut out: Vec<planner::ComputeConfig> = (self.sweep.budget_scales.iter())
            .map(|&k| planner::ComputeConfig {
                budget_scale: base.budget_scale * k,
                ..base
            })
            .collect();
        if self.sweep.free {
            out.push(planner::ComputeConfig::FREE);
        }
        out
    }

    /// The sensing conditions of `[sensing_sweep]`, in order (empty without a sweep).
    pub fn sensing_conditions(&self) -> Vec<LidarOverride> {
        let s = &self.sensing;
        if s.beams.is_empty() && s.noise_fractions.is_empty() && s.dropouts.is_empty() {
            return Vec::new();
        }
        LidarOverride::combinations(&s.beams, &s.noise_fractions, &s.dropouts)
    }

    /// The arms the sensing sweep covers, in order (every arm when `[sensing_sweep] arms` is
    /// empty; none without conditions).
    pub fn sensing_arms(&self) -> Vec<usize> {
        match (self.sensing_conditions().is_empty(), self.sensing.arms.is_empty()) {
            (true, _) => Vec::new(),
            (false, true) => (0..self.arms.len()).collect(),
            (false, false) => self.sensing.arms.clone(),
        }
    }

    /// The observation layout `arm` trains with.
    pub fn observation(&self, arm: &Arm) -> LaserLayout {
        arm.observation.unwrap_or(self.train.env.observation)
    }

    /// The training configuration of `arm`'s seed `seed` (0-based): `[train]` (with the arm's
    /// group's recipe laid over it, if it has one) with the arm's
    /// planner, action space and observation layout (and the observation, laser and action
    /// sizes they need), speed cap and training worlds, and `[td3] seed = first_seed + seed`.
    pub fn train_config(&self, arm: &Arm, seed: usize) -> TrainConfig {
        let mut cfg = match &arm.recipe {
            None => self.train.clone(),
            Some(r) => self
                .recipes
                .iter()
                .find(|(name, _)| name == r)
                .map(|(_, c)| c.clone())
                .expect("an arm's recipe is one of the experiment's"),
        };
        cfg.run.name = format!("{}-seed{seed}", arm.id());
        cfg.run.planner = arm.planner;
        cfg.run.action_space = arm.space;
        cfg.run.max_speed = arm.speed;
        cfg.run.worlds = arm.train_worlds.clone();
        cfg.env.observation = self.observation(arm);
        (cfg.td3.obs_dim, cfg.td3.act_dim, cfg.td3.laser_dim) = cfg.td3_sizes();
        cfg.td3.seed = self.section.first_seed + seed as u64;
        cfg
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n";

    fn parse(text: &str) -> Result<Experiment> {
        Experiment::parse("x.toml", text, &Restrict::default())
    }

    /// Every shipped experiment keeps the test worlds for the reported numbers only: the
    /// worlds its trainings deal, its greedy evaluations (and held-out selection) run on, its
    /// constant searches and its state-shuffled pools read meet neither a test split of the
    /// split files (`test`, `hardest50`, any `*-test`) nor its own test worlds.
    #[test]
    fn no_training_selection_search_or_pool_world_may_be_a_test_world() {
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/experiments"));
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        files.sort();
        assert!(files.len() >= 10, "{files:?}");
        let held_out = sim::splits::held_out_worlds();
        for file in &files {
            let ex = Experiment::load(file, &Restrict::default()).unwrap();
            let name = file.file_name().unwrap().to_string_lossy();
            let is_test = |w: &usize| held_out.contains(w) || ex.test_worlds.contains(w);
            let check = |what: &str, ids: &[usize]| {
                assert!(!ids.is_empty(), "{name}: {what} selects no world");
                if let Some(w) = ids.iter().find(|w| is_test(w)) {
                    panic!("{name}: {what} reads test world {w}");
                }
            };
            for arm in &ex.arms {
                for seed in 0..ex.seeds {
                    let cfg = ex.train_config(arm, seed);
                    match cfg.worlds().unwrap() {
                        scheduler::WorldPool::Listed(ids) => {
                            check(&format!("the training of {} seed {seed}", arm.id()), &ids)
                        }
                        // Fresh generated worlds from `first` on: no test world may be one.
                        scheduler::WorldPool::Fresh { first } => {
                            if let Some(w) = ex.test_worlds.iter().find(|&&w| w >= first) {
                                panic!("{name}: {} may deal test world {w}", arm.id());
                            }
                        }
                    }
                    if cfg.greedy.every_steps > 0 || cfg.greedy.select {
                        let ids = sim::splits::select(&cfg.greedy.worlds).unwrap();
                        check("[train.greedy] worlds (its curves and any selection)", &ids);
                    }
                }
            }
            check("[constant_search] worlds", &ex.search_worlds);
            check(
                "[shuffle] worlds",
                &sim::splits::select(&ex.shuffle.worlds).unwrap(),
            );
            check("the shuffle pool", &ex.pool_worlds);
        }
    }

    /// `start` of `[experiment]` and of a group: the default (`ddp`) changes no arm;
    /// `best-constant` makes arms of their own, with ids that say so.
    #[test]
    fn the_start_of_arms_is_ddp_unless_given() {
        let ex = parse(MINIMAL).unwrap();
        assert_eq!(ex.arms[0].start, Start::Ddp);
        assert_eq!(ex.arms[0].id(), "dwa-decremental-1.5-fit");
        let best = parse(&MINIMAL.replace("speeds", "start = \"best-constant\"\nspeeds")).unwrap();
        assert_eq!(best.arms[0].start, Start::BestConstant);
        assert_eq!(best.arms[0].id(), "dwa-decremental-1.5-fit-bestconst");
        let text = format!(
            "{MINIMAL}[[experiment.groups]]\nname = \"from the best constant\"\nstart = \"best-constant\"\n"
        );
        let both = parse(&text).unwrap();
        let ids: Vec<String> = both.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            ["dwa-decremental-1.5-fit", "dwa-decremental-1.5-fit-bestconst"]
        );
        assert!(both.arms[1].same_controls(&both.arms[0]) && !both.arms[1].same_untrained(&both.arms[0]));
        let e = parse(&MINIMAL.replace("speeds", "start = \"constant\"\nspeeds"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("constant") && e.contains("ddp"), "{e}");
    }

    /// A group's recipe lays its `train` over `[train]` for its own arms only: their ids say
    /// which recipe, they share the experiment's controls but not its untrained policy, and
    /// a recipe without a name, a name without a table, a bad name or one name with two
    /// tables is refused, naming the group.
    #[test]
    fn a_group_recipe_trains_its_own_arms_only() {
        let group =
            "[[experiment.groups]]\nname = \"ours\"\nstart = \"best-constant\"\nrecipe = \"project\"\n\
                     [experiment.groups.train.td3]\nupdates_per_insert = 0.25\n\
                     [experiment.groups.train.greedy]\nselect = true\n";
        let text = format!("{MINIMAL}{group}[train.run]\nsteps = 1000\n");
        let ex = parse(&text).unwrap();
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.5-fit",
                "dwa-decremental-1.5-fit-bestconst-project"
            ]
        );
        let (paper, ours) = (ex.train_config(&ex.arms[0], 0), ex.train_config(&ex.arms[1], 0));
        assert_eq!(
            (paper.run.steps, ours.run.steps),
            (1000, 1000),
            "[train] reaches both"
        );
        assert_eq!(ours.td3.updates_per_insert, 0.25);
        assert!(ours.greedy.select && !paper.greedy.select);
        assert_ne!(paper.td3.updates_per_insert, 0.25);
        assert!(ex.arms[1].same_controls(&ex.arms[0]) && !ex.arms[1].same_untrained(&ex.arms[0]));
        for (bad, says) in [
            (
                group.replace("recipe = \"project\"\n", ""),
                "needs a `recipe` name",
            ),
            (
                "[[experiment.groups]]\nrecipe = \"project\"\n".to_string(),
                "has no `train` table",
            ),
            (
                group.replace("\"project\"", "\"Project 2\""),
                "lower-case letters",
            ),
            (
                format!("{group}{}", group.replace("0.25", "0.5")),
                "declared twice with different `train` tables",
            ),
            (group.replace("select = true", "selekt = true"), "selekt"),
        ] {
            let e = parse(&format!("{MINIMAL}{bad}")).unwrap_err().to_string();
            assert!(e.contains("[[experiment.groups]] ") && e.contains(says), "{e}");
        }
    }

    #[test]
    fn shipped_experiments_parse() {
        for (file, arms) in [("table1.toml", 9), ("table2.toml", 3)] {
            let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
                .join("configs/experiments")
                .join(file);
            let ex = Experiment::load(&path, &Restrict::default()).unwrap();
            assert_eq!(ex.arms.len(), arms, "{file}");
            assert_eq!(ex.test_worlds.len(), 225);
            assert_eq!((ex.eval.runs, ex.eval.trim), (20, 5));
        }
    }

    /// The dynamic experiment trains on DynaBARN's training worlds, evaluates on its 30 test
    /// worlds, and observes 4 tracks (so its networks take 746 inputs).
    #[test]
    fn the_dynamic_experiment_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/dynamic.toml");
        let ex = Experiment::load(&path, &Restrict::default()).unwrap();
        assert_eq!(ex.arms.len(), 1);
        assert_eq!(ex.test_worlds.len(), 30);
        assert!(ex.test_worlds.iter().all(|w| (300..360).contains(w)));
        assert_eq!(ex.arms[0].train_worlds, "dynabarn-fit");
        assert_eq!(ex.train.env.observe_tracks, 4);
        assert_eq!(ex.train_config(&ex.arms[0], 0).td3.obs_dim, 746);
    }

    /// The RL-DWA experiment has one DWA arm per action space, and sizes each arm's networks
    /// from its space.
    #[test]
    fn the_rl_dwa_experiment_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/rl-dwa.toml");
        let ex = Experiment::load(&path, &Restrict::default()).unwrap();
        let ids: Vec<String> = ex.arms.iter().map(|a| a.id()).collect();
        assert!(ids.iter().all(|id| id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-+._".contains(c))));
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.5-fit",
                "dwa-weights_dwa-1.5-fit",
                "dwa-decremental+weights_dwa-1.5-fit",
                "dwa-velocity-1.5-fit"
            ]
        );
        let dims: Vec<(usize, usize)> = (0..4)
            .map(|k| {
                let c = ex.train_config(&ex.arms[k], 0);
                (c.td3.obs_dim, c.td3.act_dim)
            })
            .collect();
        assert_eq!(dims, [(730, 4), (730, 4), (734, 8), (728, 2)]);
        assert_eq!(ex.test_worlds.len(), 225);
    }

    /// The stuck ablation's velocity arm trains exactly as rl-dwa.toml's (the same seeds,
    /// worlds, networks and TD3 settings) except for the reward's stuck term.
    #[test]
    fn the_stuck_ablation_differs_from_rl_dwa_only_in_the_stuck_term() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments");
        let base = Experiment::load(&dir.join("rl-dwa.toml"), &Restrict::default()).unwrap();
        let stuck = Experiment::load(&dir.join("rl-dwa-stuck.toml"), &Restrict::default()).unwrap();
        assert_eq!(stuck.arms.len(), 1);
        let velocity = base.arms.iter().find(|a| a.id() == stuck.arms[0].id()).unwrap();
        for seed in 0..3 {
            let mut ablation = stuck.train_config(&stuck.arms[0], seed);
            let original = base.train_config(velocity, seed);
            let env = ablation.env;
            assert_eq!(
                (env.stuck_window, env.stuck_progress_m, env.stuck_reward),
                (20, 0.5, -5.0)
            );
            assert_eq!(original.env.stuck_window, 0);
            ablation.env.stuck_window = 0;
            ablation.env.stuck_progress_m = original.env.stuck_progress_m;
            ablation.env.stuck_reward = original.env.stuck_reward;
            assert_eq!(ablation, original, "seed {seed}");
        }
        assert_eq!(
            (stuck.eval.runs, stuck.eval.trim),
            (base.eval.runs, base.eval.trim)
        );
        assert_eq!(stuck.test_worlds, base.test_worlds);
    }

    /// The learner-setting experiments train the paper's DWA 1.5 m/s arm exactly as the paper
    /// does (the same seeds, worlds, networks, steps and TD3 settings) except for `[td3]
    /// batch_size` and `updates_per_insert`, and evaluate and search as it does, in its store:
    /// so their ADP rows differ from the paper's by the learner setting alone.
    #[test]
    fn the_learner_settings_differ_from_the_paper_only_in_batch_and_update_rate() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments");
        let paper = Experiment::load(&dir.join("paper.toml"), &Restrict::default()).unwrap();
        let arm = paper
            .arms
            .iter()
            .find(|a| a.id() == "dwa-decremental-1.5-fit")
            .unwrap();
        for (file, batch) in [("learner-batch512.toml", 512), ("learner-upi025.toml", 128)] {
            let ex = Experiment::load(&dir.join(file), &Restrict::default()).unwrap();
            assert_eq!(ex.arms, std::slice::from_ref(arm), "{file}");
            assert_eq!(ex.seeds, paper.seeds, "{file}");
            assert_eq!(ex.section.first_seed, paper.section.first_seed, "{file}");
            assert_eq!(ex.section.store, paper.section.store, "{file}");
            for seed in 0..ex.seeds {
                let mut setting = ex.train_config(&ex.arms[0], seed);
                assert_eq!(
                    (setting.td3.batch_size, setting.td3.updates_per_insert),
                    (batch, 0.25),
                    "{file}"
                );
                let original = paper.train_config(arm, seed);
                setting.td3.batch_size = original.td3.batch_size;
                setting.td3.updates_per_insert = original.td3.updates_per_insert;
                assert_eq!(setting, original, "{file} seed {seed}");
            }
            let eval = EvalSection {
                vanilla: paper.eval.vanilla,
                ..ex.eval.clone()
            };
            assert_eq!(eval, paper.eval, "{file}");
            assert_eq!(ex.search, paper.search, "{file}");
            assert_eq!(ex.stats, paper.stats, "{file}");
            // The speeds with the control are the paper's arms' business; at 1.5 m/s both
            // evaluate it.
            assert!(ex.shuffle.speeds.contains(&1.5), "{file}");
            let shuffle = ShuffleSection {
                speeds: paper.shuffle.speeds.clone(),
                ..ex.shuffle.clone()
            };
            assert_eq!(shuffle, paper.shuffle, "{file}");
            assert_eq!(ex.test_worlds, paper.test_worlds, "{file}");
        }
    }

    /// Groups add their own cross products after the section's arms, without repeating an
    /// arm; their world selections are checked like the section's, and a restriction may
    /// name what only a group declares.
    #[test]
    fn groups_add_arms_of_their_own() {
        let text = format!(
            "{MINIMAL}[[experiment.groups]]\nname = \"spaces\"\naction_spaces = [\"decremental\", \
             \"incremental\"]\n[[experiment.groups]]\nplanners = [\"system\"]\nspeeds = [1.0]\n"
        );
        let ex = parse(&text).unwrap();
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.5-fit",
                "dwa-incremental-1.5-fit",
                "system-decremental-1.0-fit"
            ]
        );
        let only = Restrict {
            planners: vec![PlannerKind::System],
            ..Restrict::default()
        };
        let ex = Experiment::parse("t.toml", &text, &only).unwrap();
        assert_eq!(ex.arms.len(), 1);
        let err = parse(&format!(
            "{MINIMAL}[[experiment.groups]]\ntrain_worlds = [\"test\"]\n"
        ))
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("[[experiment.groups]] 1") && err.contains("test world"),
            "{err}"
        );
        let err = parse(&format!("{MINIMAL}[[experiment.groups]]\nplanner = [\"dwa\"]\n"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("planner"), "{err}");
    }

    #[test]
    fn minimal_file_takes_the_defaults() {
        let ex = parse(MINIMAL).unwrap();
        assert_eq!(ex.arms.len(), 1);
        assert_eq!(ex.arms[0].id(), "dwa-decremental-1.5-fit");
        assert_eq!(ex.seeds, 3);
        let base = toml::to_string(&train_base()).unwrap();
        assert_eq!(ex.train, TrainConfig::parse("base", &base).unwrap());
        // The main job's recipe does not reach experiments; the rest of local.toml does.
        let (code, local) = (
            TrainConfig::parse("none", "").unwrap(),
            TrainConfig::load(None).unwrap(),
        );
        assert_eq!(
            (ex.train.run.steps, ex.train.run.planner),
            (code.run.steps, code.run.planner)
        );
        assert_eq!(ex.train.td3.updates_per_insert, code.td3.updates_per_insert);
        assert_eq!(
            (&ex.train.service.init_action, &ex.train.greedy),
            (&None, &code.greedy)
        );
        assert_eq!(ex.train.env.action_map, local.env.action_map);
        let c = ex.train_config(&ex.arms[0], 2);
        assert_eq!((c.td3.seed, c.run.max_speed, c.td3.act_dim), (3, 1.5, 4));
    }

    #[test]
    fn unknown_keys_are_named_with_the_file() {
        for (extra, key) in [
            ("[experiment2]\n", "experiment2"),
            ("[eval]\nrunz = 3\n", "runz"),
            ("[train.td3]\nactor_lrr = 1e-4\n", "actor_lrr"),
            ("[train.run]\nstepz = 3\n", "stepz"),
            ("[shuffle]\npoool = 3\n", "poool"),
            ("[slurm]\ntaskz = 3\n", "taskz"),
            ("[figures]\nrender = 3\n", "render"),
        ] {
            let e = parse(&format!("{MINIMAL}{extra}")).unwrap_err().to_string();
            assert!(
                e.starts_with("x.toml") && e.contains(key) && !e.contains('\n'),
                "{e}"
            );
        }
        let e = parse("[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\nfoo = 1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("foo"), "{e}");
    }

    #[test]
    fn train_keys_flow_into_the_training_config() {
        let ex = parse(&format!(
            "{MINIMAL}[train.td3]\nactor_lr = 0.001\n[train.run]\nsteps = 200\n"
        ))
        .unwrap();
        assert_eq!(ex.train.td3.actor_lr, 0.001);
        assert_eq!(ex.train.run.steps, 200);
        assert_eq!(
            ex.train.td3.batch_size,
            TrainConfig::load(None).unwrap().td3.batch_size
        );
    }

    #[test]
    fn test_worlds_are_never_used_for_selection() {
        let e = parse(&format!("{MINIMAL}[constant_search]\nworlds = \"0..10\"\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[constant_search] worlds") && e.contains("test world"),
            "{e}"
        );
        let e = parse(&MINIMAL.replace("speeds", "train_worlds = [\"test\"]\nspeeds"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("train_worlds"), "{e}");
        let e = parse(&format!("{MINIMAL}[train.greedy]\nworlds = \"hardest50\"\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("[train.greedy] worlds"), "{e}");
    }

    #[test]
    fn generated_training_worlds_make_arms_of_their_own() {
        let ex = parse(&MINIMAL.replace(
            "speeds",
            "train_worlds = [\"generated:75\", \"generated\"]\nspeeds",
        ))
        .unwrap();
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.5-generated_75",
                "dwa-decremental-1.5-generated"
            ]
        );
        assert_eq!(
            ex.train_config(&ex.arms[0], 0).worlds().unwrap(),
            scheduler::WorldPool::Listed((1_000_000..1_000_075).collect())
        );
        assert_eq!(
            ex.train_config(&ex.arms[1], 0).worlds().unwrap(),
            scheduler::WorldPool::Fresh { first: 1_000_000 }
        );
        // A fresh pool could deal a generated test world.
        let e = parse(&MINIMAL.replace(
            "speeds",
            "train_worlds = [\"generated\"]\ntest_worlds = \"generated:5\"\nspeeds",
        ))
        .unwrap_err()
        .to_string();
        assert!(e.contains("may deal test world 1000000"), "{e}");
        // The shipped training-world table: five arms, the last one fresh.
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/worlds.toml");
        let ex = Experiment::load(&path, &Restrict::default()).unwrap();
        let pools: Vec<scheduler::WorldPool> = (ex.arms.iter())
            .map(|a| ex.train_config(a, 0).worlds().unwrap())
            .collect();
        let sizes: Vec<Option<usize>> = (pools.iter())
            .map(|p| match p {
                scheduler::WorldPool::Listed(w) => Some(w.len()),
                scheduler::WorldPool::Fresh { .. } => None,
            })
            .collect();
        assert_eq!(sizes, [Some(25), Some(75), Some(75), Some(1000), None]);
        assert_eq!(ex.test_worlds.len(), 225);
    }

    #[test]
    fn bad_values_and_restrictions_are_refused() {
        let e = parse(&format!("{MINIMAL}[eval]\nruns = 4\ntrim = 2\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("[eval]") && e.contains("trim"), "{e}");
        // The sweep's runs are its own: its trim is checked against them (5 runs, trim 5
        // would leave nothing of a world to average).
        let sweep = |trim: usize| {
            parse(&format!(
                "{MINIMAL}[compute_sweep]\nbudget_scales = [1.0]\nruns = 5\ntrim = {trim}\n"
            ))
        };
        let e = sweep(3).unwrap_err().to_string();
        assert!(e.contains("[compute_sweep]") && e.contains("trim = 3"), "{e}");
        assert_eq!(sweep(2).unwrap().sweep.trim, 2);
        let e = parse(&MINIMAL.replace("dwa", "dwaa")).unwrap_err().to_string();
        assert!(e.contains("dwaa"), "{e}");
        let e = parse(&format!("{MINIMAL}[eval]\nstart_jitter_m = 3.0\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("start_jitter_m"), "{e}");
        let r = Restrict {
            planners: vec![PlannerKind::Mppi],
            ..Restrict::default()
        };
        let e = Experiment::parse("x.toml", MINIMAL, &r).unwrap_err().to_string();
        assert!(e.contains("--planners mppi"), "{e}");
        let r = Restrict {
            seeds: Some(1),
            steps: Some(50),
            ..Restrict::default()
        };
        let ex = Experiment::parse("x.toml", MINIMAL, &r).unwrap();
        assert_eq!((ex.seeds, ex.train.run.steps), (1, 50));
    }

    /// Observation layouts are the innermost arm axis: the layout of `[train.env]
    /// observation` keeps today's id, the others end in theirs, and each arm's networks take
    /// its layout's inputs.
    #[test]
    fn observation_layouts_make_arms() {
        let ex = parse(&MINIMAL.replace(
            "speeds = [1.5]",
            "speeds = [1.5, 2.0]\nobservations = [\"scan\", \"sectors:15\"]",
        ))
        .unwrap();
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.5-fit",
                "dwa-decremental-1.5-fit-sectors15",
                "dwa-decremental-2.0-fit",
                "dwa-decremental-2.0-fit-sectors15"
            ]
        );
        let sizes = |ex: &Experiment| -> Vec<(usize, usize, String)> {
            (ex.arms.iter())
                .map(|a| {
                    let c = ex.train_config(a, 0);
                    (c.td3.obs_dim, c.td3.laser_dim, c.env.observation.to_string())
                })
                .collect()
        };
        assert_eq!(
            sizes(&ex)[..2],
            [(730, 720, "scan".into()), (25, 15, "sectors:15".into())]
        );
        assert_eq!(
            ex.train_config(&ex.arms[1], 0).run.name,
            "dwa-decremental-1.5-fit-sectors15-seed0"
        );
        assert!(ex.arms[1].same_controls(&ex.arms[0]) && !ex.arms[2].same_controls(&ex.arms[0]));
        // Without the key: one arm of [train.env] observation, its id as before.
        let env = format!("{MINIMAL}[train.env]\nobservation = \"sectors:25\"\n");
        let ex = parse(&env).unwrap();
        assert_eq!(ex.arms[0].id(), "dwa-decremental-1.5-fit");
        assert_eq!(sizes(&ex), [(35, 25, "sectors:25".into())]);
        // With it, [train.env]'s layout is the one without a suffix.
        let ex = parse(&env.replace("speeds", "observations = [\"scan\", \"sectors:25\"]\nspeeds")).unwrap();
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(ids, ["dwa-decremental-1.5-fit-scan", "dwa-decremental-1.5-fit"]);
        assert_eq!(
            sizes(&ex),
            [(730, 720, "scan".into()), (35, 25, "sectors:25".into())]
        );
    }

    #[test]
    fn bad_observations_and_sensing_values_are_named() {
        let obs = |list: &str| {
            parse(&MINIMAL.replace("speeds", &format!("observations = {list}\nspeeds")))
                .unwrap_err()
                .to_string()
        };
        for (list, needle) in [
            ("[]", "must not be empty"),
            ("[\"sectors:0\"]", "\"sectors:0\" is not a laser layout"),
            (
                "[\"scan\", \"sectors:15\", \"sectors:15\"]",
                "`sectors:15` is listed twice",
            ),
        ] {
            let e = obs(list);
            assert!(
                e.starts_with("x.toml: [experiment] observations") && e.contains(needle) && !e.contains('\n'),
                "{e}"
            );
        }
        let sensing = |body: &str| {
            parse(&format!("{MINIMAL}[sensing_sweep]\n{body}\n"))
                .unwrap_err()
                .to_string()
        };
        for (body, needle) in [
            (
                "noise_fractions = [0.1, 1.5]",
                "[sensing_sweep] noise_fractions = 1.5: ",
            ),
            ("beams = [1]", "[sensing_sweep] beams = 1: "),
            ("dropouts = [1.0]", "[sensing_sweep] dropouts = 1: "),
            (
                "noise_fractions = [0.1, 0.1]",
                "[sensing_sweep] noise_fractions: 0.1 is listed twice",
            ),
            (
                "dropouts = [0.1]\nruns = 4\ntrim = 2",
                "[sensing_sweep] runs = 4 and trim = 2",
            ),
            ("dropouts = [0.1]\nruns = 0", "[sensing_sweep] runs = 0"),
            (
                "dropouts = [0.1]\narms = [0, 1]",
                "[sensing_sweep] arms: arm 1, but the experiment has 1 arm(s)",
            ),
            ("noise = [0.1]", "noise"),
        ] {
            let e = sensing(body);
            assert!(
                e.starts_with("x.toml: ") && e.contains(needle) && !e.contains('\n'),
                "{e}"
            );
        }
    }

    /// The conditions are the cross product beams x noise fractions x dropouts, and the sweep
    /// covers every arm unless it lists some; without values there is none.
    #[test]
    fn sensing_conditions_are_the_cross_product() {
        let ex = parse(MINIMAL).unwrap();
        assert!(ex.sensing_conditions().is_empty() && ex.sensing_arms().is_empty());
        let ex = parse(&format!(
            "{}[sensing_sweep]\nbeams = [720, 90]\nnoise_fractions = [0.0, 0.1, 0.2]\n",
            MINIMAL.replace("speeds = [1.5]", "speeds = [1.5, 2.0]")
        ))
        .unwrap();
        let c = ex.sensing_conditions();
        assert_eq!(c.len(), 6);
        assert_eq!(
            (c[0].beams, c[0].noise_fraction, c[0].dropout),
            (Some(720), Some(0.0), None)
        );
        assert_eq!((c[5].beams, c[5].noise_fraction), (Some(90), Some(0.2)));
        assert_eq!(ex.sensing_arms(), [0, 1]);
        let ex = parse(&format!(
            "{MINIMAL}[sensing_sweep]\ndropouts = [0.1]\narms = [0]\n"
        ))
        .unwrap();
        assert_eq!((ex.sensing_conditions().len(), ex.sensing_arms()), (1, vec![0]));
    }

    /// The sensing experiment: DWA at 1.5 m/s in four observation layouts on the 225 test
    /// worlds, swept over four noise levels of a 720-beam lidar.
    #[test]
    fn the_sensing_experiment_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/sensing.toml");
        let ex = Experiment::load(&path, &Restrict::default()).unwrap();
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.5-fit",
                "dwa-decremental-1.5-fit-sectors15",
                "dwa-decremental-1.5-fit-sectors25",
                "dwa-decremental-1.5-fit-sectors50"
            ]
        );
        let dims: Vec<usize> = ex
            .arms
            .iter()
            .map(|a| ex.train_config(a, 0).td3.obs_dim)
            .collect();
        assert_eq!(dims, [730, 25, 35, 60]);
        assert_eq!(
            (ex.seeds, ex.test_worlds.len(), ex.eval.runs, ex.eval.trim),
            (3, 225, 20, 5)
        );
        let c = ex.sensing_conditions();
        let noise: Vec<Option<f64>> = c.iter().map(|c| c.noise_fraction).collect();
        assert_eq!(noise, [Some(0.0), Some(0.05), Some(0.1), Some(0.2)]);
        assert!(c.iter().all(|c| c.beams == Some(720) && c.dropout.is_none()));
        assert_eq!(ex.sensing_arms(), [0, 1, 2, 3]);
        assert!(ex.sweep_points().is_empty());
        // The scan arm trains exactly as table1.toml's arm of the same id.
        let t1 = Experiment::load(&path.with_file_name("table1.toml"), &Restrict::default()).unwrap();
        let same = t1.arms.iter().find(|a| a.id() == ids[0]).unwrap();
        assert_eq!(t1.train_config(same, 2), ex.train_config(&ex.arms[0], 2));
    }

    /// A space that sets a planner's gains makes arms with that planner only, and a space
    /// whose planner is not in the experiment is refused by name.
    #[test]
    fn weight_spaces_pair_with_their_planner() {
        let text = "[experiment]\nname = \"t\"\nplanners = [\"dwa\", \"system\"]\nspeeds = [1.5]\n\
                    action_spaces = [\"decremental\", \"weights:dwa\", \"decremental+weights:system\"]\n";
        let ex = parse(text).unwrap();
        let arms: Vec<(PlannerKind, String)> =
            ex.arms.iter().map(|a| (a.planner, a.space.to_string())).collect();
        assert_eq!(
            arms,
            [
                (PlannerKind::Dwa, "decremental".to_string()),
                (PlannerKind::Dwa, "weights:dwa".to_string()),
                (PlannerKind::System, "decremental".to_string()),
                (PlannerKind::System, "decremental+weights:system".to_string()),
            ]
        );
        let e = parse(&text.replace("weights:dwa", "weights:mppi"))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "x.toml: [experiment] action_spaces: `weights:mppi` sets the gains of mppi, which is not in planners"
        );
    }
}
