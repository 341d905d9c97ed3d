//! A training run's configuration (`configs/local.toml`, embedded as the default): what to
//! train, the actors' environment, TD3, the learner process, the actor sandbox, the greedy
//! monitor and the shape of a cluster job.

use std::path::Path;
use std::path::PathBuf;

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use actor::EnvConfig;
use learner::{LearnerDevice, Td3Config};
use learner_service::{LearnerOptions, ServiceConfig};
use planner::{ActionSpace, PlannerKind};
use scheduler::{BwrapMode, SandboxConfig};

use eval::config::one_line;
use eval::GreedySection;

use crate::SlurmSection;

/// The embedded default of `configs/local.toml`.
const LOCAL_TOML: &str = include_str!("../../configs/local.toml");

/// `[run]`: what to train.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunSection {
    /// Run name (run directory `runs/<name>`).
    pub name: String,
    /// Agent-step budget.
    pub steps: u64,
    /// Actor processes (0 = one per core).
    pub actors: u32,
    /// Training worlds: a selection (split name, range, list, `generated:N` = the first N
    /// generated worlds), or `generated`: a new generated world for every assignment.
    pub worlds: String,
    /// Planner the actors drive.
    pub planner: PlannerKind,
    /// ADP action space.
    pub action_space: ActionSpace,
    /// The planner's speed cap (m/s).
    pub max_speed: f64,
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            name: "local".into(),
            steps: 40_000,
            actors: 0,
            worlds: "fit".into(),
            planner: PlannerKind::Dwa,
            action_space: ActionSpace::Decremental,
            max_speed: 1.5,
        }
    }
}

/// `[sandbox]`: limits of the actor processes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SandboxSection {
    /// `auto`, `off` or `required`.
    pub bwrap: BwrapMode,
    /// Address-space limit per actor (MiB, 0 = inherited).
    pub address_space_mb: u64,
    /// Open-file limit per actor (0 = inherited).
    pub open_files: u64,
    /// With bubblewrap, actors run in a private network namespace (no network at all) and
    /// reach the learner over its Unix socket in the run directory.
    pub private_network: bool,
}

impl SandboxSection {
    /// The sandbox of one actor process; `private_network` only when the actor reaches the
    /// learner without the network (its Unix socket) and this section asks for it.
    pub fn sandbox_config(&self, private_network: bool) -> SandboxConfig {
        SandboxConfig {
            bwrap: self.bwrap,
            address_space_bytes: self.address_space_mb << 20,
            open_files: self.open_files,
            private_network: self.private_network && private_network,
            // Shared memory (the same-node data plane and iceoryx2's files) stays writable.
            writable_dirs: vec![PathBuf::from("/dev/shm"), PathBuf::from("/tmp")],
        }
    }
}

impl Default for SandboxSection {
    fn default() -> Self {
        Self {
            bwrap: BwrapMode::Auto,
            address_space_mb: 4096,
            open_files: 1024,
            private_network: true,
        }
    }
}

/// `[learner]`: where the learner computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearnerSection {
    /// `cpu` (burn's CPU backend, the default) or `wgpu` (the first GPU wgpu finds; a
    /// software Vulkan driver such as lavapipe counts). `--device` overrides it.
    pub device: LearnerDevice,
}

/// A training run's configuration (`configs/local.toml`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// What to train.
    pub run: RunSection,
    /// The actors' environment.
    pub env: EnvConfig,
    /// TD3.
    pub td3: Td3Config,
    /// Where the learner computes.
    pub learner: LearnerSection,
    /// The learner process.
    pub service: ServiceConfig,
    /// The actor sandbox.
    pub sandbox: SandboxSection,
    /// Greedy evaluation of the newest policy on held-out worlds during `adp train`.
    pub greedy: GreedySection,
    /// The shape of a cluster job (`adp slurm`; ignored by `adp train`).
    pub slurm: SlurmSection,
}

impl TrainConfig {
    /// Reads `path`, or the embedded `configs/local.toml` when `None`, and checks it.
    pub fn load(path: Option<&Path>) -> anyhow::Result<Self> {
        match path {
            Some(p) => Self::parse(
                &p.display().to_string(),
                &std::fs::read_to_string(p).with_context(|| format!("cannot read config {}", p.display()))?,
            ),
            None => Self::parse("configs/local.toml (embedded)", LOCAL_TOML),
        }
    }

    /// Parses and checks the TOML `text`; errors are one line and start with `name`.
    ///
    /// `[td3] obs_dim`, `act_dim` and `laser_dim` that the text leaves out are derived from
    /// `[run] action_space` and `[env] observation` / `observe_tracks`; values it gives are
    /// kept (and the learner refuses them if they do not fit, naming both sizes).
    pub fn parse(name: &str, text: &str) -> anyhow::Result<Self> {
        let mut cfg: Self =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{name}: {}", one_line(&e.to_string())))?;
        let raw: toml::Table =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{name}: {}", one_line(&e.to_string())))?;
        let given = |key: &str| {
            raw.get("td3")
                .and_then(toml::Value::as_table)
                .is_some_and(|t| t.contains_key(key))
        };
        let (obs_dim, act_dim, laser_dim) = cfg.td3_sizes();
        if !given("obs_dim") {
            cfg.td3.obs_dim = obs_dim;
        }
        if !given("act_dim") {
            cfg.td3.act_dim = act_dim;
        }
        if !given("laser_dim") {
            cfg.td3.laser_dim = laser_dim;
        }
        cfg.td3.validate().with_context(|| format!("{name}: [td3]"))?;
        cfg.env
            .validate()
            .map_err(|e| anyhow::anyhow!("{name}: [env]: {e}"))?;
        if !(cfg.run.max_speed.is_finite() && cfg.run.max_speed > 0.0) {
            bail!("{name}: [run] max_speed = {} must be positive", cfg.run.max_speed);
        }
        cfg.service
            .check_init_action(cfg.run.action_space)
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        cfg.greedy
            .check_selection()
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        if let Some(g) = cfg.run.action_space.gains() {
            if g.planner() != cfg.run.planner.name() {
                bail!(
                    "{name}: [run] action_space = \"{}\" sets the gains of {}, but planner = \"{}\": \
                     the space must name the planner it drives",
                    cfg.run.action_space,
                    g.planner(),
                    cfg.run.planner.name()
                );
            }
        }
        Ok(cfg)
    }

    /// The `[td3]` sizes `(obs_dim, act_dim, laser_dim)` that `[run] action_space` and `[env]
    /// observation` / `observe_tracks` need.
    pub fn td3_sizes(&self) -> (usize, usize, usize) {
        let (space, env) = (self.run.action_space, &self.env);
        (
            actor::obs_dim(env.observation, space, env.observe_tracks),
            space.dim(),
            env.observation.size(),
        )
    }

    /// The training worlds of `[run] worlds`: a selection, or `generated` (a fresh generated
    /// world for every assignment).
    pub fn worlds(&self) -> anyhow::Result<scheduler::WorldPool> {
        if self.run.worlds.trim() == sim::splits::FRESH_GENERATED {
            return Ok(scheduler::WorldPool::Fresh {
                first: sim::catalog::GENERATED_FIRST,
            });
        }
        sim::splits::select(&self.run.worlds)
            .map(scheduler::WorldPool::Listed)
            .map_err(|e| anyhow::anyhow!("[run] worlds = {:?}: {e}", self.run.worlds))
    }
}

impl TrainConfig {
    /// The learner options of this config for `run_dir`.
    pub fn learner_options(
        &self,
        run_dir: &Path,
        token: String,
        resume: bool,
    ) -> anyhow::Result<LearnerOptions> {
        let worlds = self.worlds()?;
        Ok(LearnerOptions {
            run_dir: run_dir.to_owned(),
            run_id: run_id(&self.run.name),
            td3: self.td3.clone(),
            device: self.learner.device,
            service: self.service.clone(),
            planner: self.run.planner,
            max_speed: self.run.max_speed,
            space: self.run.action_space,
            env: self.env,
            worlds,
            budget_steps: self.run.steps,
            token,
            resume,
            handle_signals: true,
        })
    }
}

/// A run id: the name plus the start time, unique per fresh run.
fn run_id(name: &str) -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!("{name}-{secs}-{}", std::process::id())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objective_weight_spaces_name_the_run_planner() {
        let parse = |planner: &str, space: &str| {
            TrainConfig::parse(
                "t.toml",
                &format!("[run]\nplanner = \"{planner}\"\naction_space = \"{space}\"\n"),
            )
        };
        let cfg = parse("dwa", "decremental+weights:dwa").unwrap();
        assert_eq!(
            cfg.run.action_space,
            ActionSpace::DecrementalWeights(planner::Gains::Dwa)
        );
        assert_eq!(
            parse("dwa", "velocity").unwrap().run.action_space,
            ActionSpace::Velocity
        );
        let e = parse("mppi", "weights:dwa").unwrap_err().to_string();
        assert_eq!(
            e,
            "t.toml: [run] action_space = \"weights:dwa\" sets the gains of dwa, but planner = \"mppi\": \
             the space must name the planner it drives"
        );
        let e = parse("dwa", "weights").unwrap_err().to_string();
        assert!(e.contains("needs the planner: write `weights:dwa`"), "{e}");
        let e = parse("log-mppi", "weights:log-mppi").unwrap_err().to_string();
        assert!(e.contains("`log-mppi` has no objective gains"), "{e}");
    }

    /// Held-out selection on worlds that meet the test split is refused when the config is
    /// read, before anything runs; on `val` it is accepted.
    #[test]
    fn selection_on_test_worlds_is_refused_at_config_time() {
        let parse = |worlds: &str| {
            TrainConfig::parse(
                "t.toml",
                &format!("[greedy]\nselect = true\nworlds = \"{worlds}\"\n"),
            )
        };
        assert!(parse("val").unwrap().greedy.select);
        for worlds in ["test", "val,hardest50", "0..300"] {
            let e = parse(worlds).unwrap_err().to_string();
            assert!(
                e.starts_with("t.toml: [greedy] select = true") && e.contains("test world"),
                "{worlds}: {e}"
            );
        }
        // Without select, the greedy curve may be drawn anywhere (as before).
        TrainConfig::parse("t.toml", "[greedy]\nworlds = \"test\"\n").unwrap();
        assert!(!TrainConfig::parse("t.toml", "").unwrap().greedy.select);
    }

    /// `[service] init_action` is checked against the run's action space when the config is
    /// read, naming the index and value.
    #[test]
    fn init_action_is_checked_against_the_space() {
        let parse = |text: &str| TrainConfig::parse("t.toml", text);
        let cfg = parse("[service]\ninit_action = [1.0, 0.0, 0.0, -1.0]\n").unwrap();
        assert_eq!(cfg.service.init_action, Some(vec![1.0, 0.0, 0.0, -1.0]));
        let e = parse("[service]\ninit_action = [1.0, 0.0, -2.0, -1.0]\n")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "t.toml: [service] init_action[2] = -2 is outside [-1, 1] (normalized actions)"
        );
        let e = parse("[run]\naction_space = \"velocity\"\n[service]\ninit_action = [0.0, 0.0, 0.0, 0.0]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("has 4 values") && e.contains("2 dimensions"), "{e}");
    }

    /// The network sizes follow the action space and the observation layout unless the file
    /// gives them; a given size that does not fit is kept for the learner to refuse.
    #[test]
    fn td3_sizes_follow_the_space_and_the_layout_unless_given() {
        let dims = |text: &str| {
            let c = TrainConfig::parse("t.toml", text).unwrap();
            (c.td3.obs_dim, c.td3.act_dim, c.td3.laser_dim)
        };
        // 720 laser values + the previous action + v, w and two goal pairs.
        assert_eq!(dims(""), (730, 4, 720));
        assert_eq!(dims("[run]\naction_space = \"velocity\"\n"), (728, 2, 720));
        assert_eq!(dims("[env]\nobservation = \"sectors:25\"\n"), (35, 4, 25));
        // Four tracks of four floats each.
        assert_eq!(dims("[env]\nobserve_tracks = 4\n"), (746, 4, 720));
        // DWA's four gains after the four schedule values.
        assert_eq!(
            dims("[run]\nplanner = \"dwa\"\naction_space = \"decremental+weights:dwa\"\n"),
            (734, 8, 720)
        );
        assert_eq!(dims("[td3]\nobs_dim = 731\n"), (731, 4, 720));
    }
}
