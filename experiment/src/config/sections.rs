//! The tables of an experiment file as written: `[experiment]` and its groups, `[eval]`,
//! `[constant_search]`, the sweeps, `[shuffle]`, `[stats]`, `[figures]`, `[report]` and
//! `[slurm]`.

use serde::{Deserialize, Serialize};

use super::arm::Start;

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
    pub(super) fn over(&self, ex: &ExperimentSection) -> ExperimentSection {
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

pub(super) fn default_spaces() -> Vec<String> {
    vec!["decremental".into()]
}
pub(super) fn default_train_worlds() -> Vec<String> {
    vec!["fit".into()]
}
pub(super) fn default_test_worlds() -> String {
    "test".into()
}
pub(super) fn default_seeds() -> usize {
    3
}
pub(super) fn default_first_seed() -> u64 {
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
    /// pairs, until `runs` runs of every world are reached ([`crate::controls::halving`]).
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
pub(super) struct RawFile {
    pub(super) experiment: ExperimentSection,
    #[serde(default)]
    pub(super) eval: EvalSection,
    #[serde(default)]
    pub(super) constant_search: SearchSection,
    #[serde(default)]
    pub(super) shuffle: ShuffleSection,
    #[serde(default)]
    pub(super) compute_sweep: SweepSection,
    #[serde(default)]
    pub(super) sensing_sweep: SensingSection,
    #[serde(default)]
    pub(super) stats: StatsSection,
    #[serde(default)]
    pub(super) figures: FiguresSection,
    #[serde(default)]
    pub(super) report: ReportSection,
    #[serde(default)]
    pub(super) slurm: SlurmJob,
    #[serde(default)]
    pub(super) train: toml::Table,
}
