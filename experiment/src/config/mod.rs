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

use actor::LaserLayout;
use planner::ActionSpace;

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

mod arm;
mod checks;
mod sections;
#[cfg(test)]
mod tests;
mod train;

pub use arm::{planner_name, space_label, speed_label, Arm, Start};
pub use sections::{
    ArmGroup, EvalSection, ExperimentSection, FiguresSection, ReportSection, SearchSection, SensingSection,
    ShuffleSection, SlurmJob, StatsSection, SweepSection,
};
pub use train::{train_base, MAIN_JOB_KEYS};

use checks::{
    check_sensing, check_sweep, check_tables, observation_layouts, planners_and_spaces, restricted_arms,
    restricted_seeds, world_splits,
};
use sections::RawFile;
use train::{group_recipes, parse_train};

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
