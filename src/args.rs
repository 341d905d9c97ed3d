//! Option groups that several commands share (flattened into their `Args`): where the
//! worlds come from ([`WorldData`]), what the simulating commands read ([`Setup`]) and the
//! options of the commands that evaluate on many worlds ([`EvalRunArgs`]).

use std::borrow::Cow;
use std::path::PathBuf;

use anyhow::Context;
use planner::{ComputeConfig, ComputeModel};
use sim::{Profile, World};

use crate::config::{EvalConfig, UnknownName};

/// Where the worlds come from: the embedded BARN and DynaBARN worlds unless BARN files are
/// given.
#[derive(clap::Args, Clone, Debug)]
pub struct WorldData {
    /// Obstacles file in the BARN JSONL format (default: the embedded BARN and DynaBARN
    /// worlds; with files, only the worlds they hold).
    #[arg(long, requires = "paths")]
    pub obstacles: Option<PathBuf>,
    /// Paths file in the BARN JSONL format (default: the embedded BARN paths).
    #[arg(long, requires = "obstacles")]
    pub paths: Option<PathBuf>,
}

impl WorldData {
    /// The worlds by id: parsed from the files, or the embedded ones (BARN 0..299, DynaBARN
    /// 300..359).
    pub fn load(&self) -> anyhow::Result<Cow<'static, [World]>> {
        match (&self.obstacles, &self.paths) {
            (Some(o), Some(p)) => {
                let ot =
                    std::fs::read_to_string(o).with_context(|| format!("cannot read {}", o.display()))?;
                let pt =
                    std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
                Ok(sim::barn::parse(&o.display().to_string(), &ot, &p.display().to_string(), &pt)?.into())
            }
            _ => Ok(sim::catalog::worlds().into()),
        }
    }

    /// World `id` of `all`, or a one-line error.
    pub fn get(all: &[World], id: usize) -> anyhow::Result<&World> {
        all.get(id).with_context(|| Self::missing(all, id))
    }

    /// Why world `id` is not in `all` (see [`eval::evaluate::missing_world`]).
    pub fn missing(all: &[World], id: usize) -> String {
        eval::evaluate::missing_world(all, id)
    }
}

/// What the simulating commands (eval, calibrate, render) read: the planner configuration, the
/// simulator profile and the worlds.
#[derive(clap::Args, Clone, Debug)]
pub struct Setup {
    /// Configuration file (default: the embedded configs/eval.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Simulator profile (ideal, gazebo-jackal, custom): overrides `[episode]` profile.
    #[arg(long, value_parser = parse_profile)]
    pub profile: Option<Profile>,
    /// Onboard compute model (free, jackal-onboard-v2, jackal-onboard, custom): overrides `[compute]` model, for
    /// every row (a policy's own model otherwise applies to the rows of its evaluation).
    #[arg(long, value_parser = parse_compute)]
    pub compute: Option<ComputeModel>,
    /// Multiplies every planner's cycle budget: overrides `[compute]` budget_scale.
    #[arg(long)]
    pub budget_scale: Option<f64>,
    #[command(flatten)]
    pub data: WorldData,
}

impl Setup {
    /// The evaluation config (`--config` or the embedded one) with `--profile` applied.
    pub fn eval_config(&self) -> anyhow::Result<EvalConfig> {
        let mut cfg = EvalConfig::load(self.config.as_deref())?;
        if let Some(p) = self.profile {
            let custom = cfg.episode.dynamics.filter(|_| p == Profile::Custom);
            cfg.episode = cfg.episode.with_profile(p, custom);
            cfg.episode
                .validate()
                .map_err(|e| anyhow::anyhow!("--profile {}: {e}", p.name()))?;
        }
        self.apply_compute(&mut cfg.compute)?;
        Ok(cfg)
    }

    /// Whether `--compute` or `--budget-scale` was given.
    pub fn compute_given(&self) -> bool {
        self.compute.is_some() || self.budget_scale.is_some()
    }

    /// Applies `--compute` and `--budget-scale` to `compute`.
    pub fn apply_compute(&self, compute: &mut ComputeConfig) -> anyhow::Result<()> {
        if let Some(m) = self.compute {
            compute.model = m;
        }
        if let Some(k) = self.budget_scale {
            compute.budget_scale = k;
        }
        compute
            .validate()
            .map_err(|e| anyhow::anyhow!("--compute / --budget-scale: {e}"))
    }
}

/// Parses a compute model name.
fn parse_compute(s: &str) -> Result<ComputeModel, String> {
    match s {
        "free" => Ok(ComputeModel::Free),
        "jackal-onboard" => Ok(ComputeModel::JackalOnboard),
        "jackal-onboard-v2" => Ok(ComputeModel::JackalOnboardV2),
        "custom" => Ok(ComputeModel::Custom),
        _ => Err(format!(
            "unknown compute model {s:?} (free, jackal-onboard-v2, jackal-onboard, custom)"
        )),
    }
}

/// The options of the commands that evaluate on many worlds (eval, calibrate).
#[derive(clap::Args, Clone, Debug)]
pub struct EvalRunArgs {
    /// Base seed of every run's noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Also write the results as JSON here (eval: the rows and per-world results; calibrate:
    /// the comparison, the checks and every eval row).
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub setup: Setup,
}

impl EvalRunArgs {
    /// The worker pool of `--jobs`.
    pub fn pool(&self) -> anyhow::Result<rayon::ThreadPool> {
        rayon::ThreadPoolBuilder::new()
            .num_threads(self.jobs.unwrap_or(0))
            .build()
            .context("cannot start worker threads")
    }

    /// Writes `value` as pretty JSON to `--out`, when given.
    pub fn write_json(&self, value: &impl serde::Serialize) -> anyhow::Result<()> {
        if let Some(path) = &self.out {
            std::fs::write(path, serde_json::to_string_pretty(value)?)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(())
    }
}

/// Parses a simulator profile name.
fn parse_profile(s: &str) -> Result<Profile, UnknownName> {
    serde_json::from_value(serde_json::Value::String(s.to_string())).map_err(|_| UnknownName {
        kind: "profile",
        name: s.to_string(),
        expected: "ideal, gazebo-jackal or custom",
    })
}
